"""Relabelling invariance, reusable by every solver's tests.

A solver's result must not depend on how the mesh is numbered. ``assert_permutation_invariant``
calls ``solve(r)`` once with the identity relabelling and then with random ones; ``solve`` builds
its inputs from ``r`` (``r.vertices``, ``r.faces`` and the mapped anchors, pinned vertices,
regions, per-face and per-dual-edge values) and returns (n,3) positions in r's numbering. The
results must agree, permuted back, to ``tol`` times the bounding-box diagonal.

    def solve(r):
        d = md.MaterialDeformer(r.vertices, r.faces, r.anchors([base, tip]),
                                shear=r.per_face(psi), pinned=r.vertex_ids(pins))
        return d.deform(T)
    assert_permutation_invariant(solve, V, F, seed=1)

``catalogue()`` gives the meshes the core's own solvers are checked on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import matdeform as md
from matdeform import shapes

CAT = Path(__file__).resolve().parents[2] / "data" / "cat-poses"


class Relabelling:
    """A vertex numbering, face order and per-face corner rotation of a mesh.

    vertex[i] is the new index of original vertex i, face[f] the new index of original face f.
    """

    def __init__(self, vertices, faces, rng=None, rotate_corners=True):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        n, m = len(v), len(f)
        self.original_faces = f
        if rng is None:  # identity
            self.vertex, self.face = np.arange(n), np.arange(m)
            shift = np.zeros(m, dtype=np.int64)
        else:
            self.vertex, self.face = rng.permutation(n), rng.permutation(m)
            shift = rng.integers(0, 3, m) if rotate_corners else np.zeros(m, dtype=np.int64)
        self.vertices = np.empty_like(v)
        self.vertices[self.vertex] = v
        corners = (np.arange(3)[None, :] + shift[:, None]) % 3
        rotated = np.take_along_axis(f, corners, axis=1)
        self.faces = np.empty_like(f)
        self.faces[self.face] = self.vertex[rotated]

    def vertex_ids(self, ids):
        return None if ids is None else self.vertex[np.asarray(ids, dtype=np.int64)]

    def face_ids(self, ids):
        return None if ids is None else self.face[np.asarray(ids, dtype=np.int64)]

    def anchors(self, anchors):
        return [self.face_ids(a) for a in anchors]

    def per_vertex(self, x):
        """(n,...) values in original vertex order -> new order."""
        x = np.asarray(x)
        out = np.empty_like(x)
        out[self.vertex] = x
        return out

    def per_face(self, x):
        """(m,...) values in original face order -> new order."""
        x = np.asarray(x)
        out = np.empty_like(x)
        out[self.face] = x
        return out

    def dual_edge(self):
        """(E,) new row of each dual edge, rows in dual_edges(original faces) order."""
        before = np.sort(self.face[md.dual_edges(self.original_faces)], axis=1)
        after = md.dual_edges(self.faces)
        m = len(self.faces)
        key = after[:, 0] * m + after[:, 1]  # sorted: dual_edges rows are
        return np.searchsorted(key, before[:, 0] * m + before[:, 1])

    def per_dual_edge(self, x):
        """(E,...) values in dual_edges(original faces) order -> dual_edges(faces) order."""
        x = np.asarray(x)
        out = np.empty_like(x)
        out[self.dual_edge()] = x
        return out

    def to_original(self, positions):
        """(n,...) per-vertex values in the new numbering -> original numbering."""
        return np.asarray(positions)[self.vertex]

    def faces_to_original(self, x):
        """(m,...) per-face values in the new order -> original order."""
        return np.asarray(x)[self.face]

    def dual_edges_to_original(self, x):
        """(E,...) per-dual-edge values in the new order -> original order."""
        return np.asarray(x)[self.dual_edge()]


def permuted_error(reference, result, r: Relabelling) -> float:
    """max |reference - result permuted back| over the bounding-box diagonal of reference."""
    ref = np.asarray(reference)
    diag = np.linalg.norm(ref.max(axis=0) - ref.min(axis=0))
    return float(np.abs(ref - r.to_original(result)).max() / max(diag, 1e-300))


def assert_permutation_invariant(
    solve, vertices, faces, *, seed=0, trials=3, rotate_corners=True, tol=1e-9, label=""
):
    """solve(Relabelling) -> (n,3); equal under `trials` random relabellings to tol * diagonal."""
    reference = np.asarray(solve(Relabelling(vertices, faces)))
    assert np.isfinite(reference).all(), f"{label}: non-finite result"
    rng = np.random.default_rng(seed)
    for t in range(trials):
        r = Relabelling(vertices, faces, rng, rotate_corners)
        err = permuted_error(reference, solve(r), r)
        assert err <= tol, f"{label}: relabelling {t} changes the result by {err:.3g} x diagonal"
    return reference


def fan(count=3):
    """Open fan of `count` triangles around a raised centre vertex 0."""
    step = min(1.5, 5.2 / count)
    a = step * np.arange(count + 1)
    v = np.vstack([[0.0, 0.0, 0.3], np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)])
    f = np.stack([np.zeros(count, int), np.arange(1, count + 1), np.arange(2, count + 2)], 1)
    return v, f


def grid(nx, ny):
    j, i = np.mgrid[0 : ny + 1, 0 : nx + 1]
    v = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1).astype(float)
    a = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]).ravel()
    b, c = a + 1, a + nx + 1
    f = np.concatenate([np.stack([a, b, c + 1], 1), np.stack([a, c + 1, c], 1)])
    return v, f


def catalogue(include_cat=True):
    """[(name, vertices, faces)]: two triangles, a fan, a grid, a tube and the cat if present."""
    two = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0.0]])
    out = [
        ("two triangles", two, np.array([[3, 0, 2], [3, 1, 0]])),
        ("fan", *fan(3)),
        ("grid", *grid(8, 8)),
        ("tube", *shapes.tube(length=6.0, radius=0.7, n_around=8, n_along=12)),
    ]
    if include_cat:
        out.append(("cat", np.load(CAT / "reference.npy"), np.load(CAT / "faces.npy")))
    return out
