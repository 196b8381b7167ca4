"""Seeded fuzz of every public function of matdeform (issue 11, "keep it found").

Case i of seed s is a function of (s, i) alone: a random mesh (soup, partial grid, tube or fan;
randomly scaled, moved and relabelled), random arguments (anchors, stiffness, pinned vertices,
regions, transforms, poses, ...) and, for about a quarter of the cases, one hostile mutation
(NaN, negative or out-of-range index, wrong shape or dtype, extreme scale, overlapping anchors,
det <= 0, ...). A case passes when the call either returns finite numbers or raises ValueError
(or a RuntimeError that says to rescale the mesh: a solve refused after the fact), and, for
meshes that are not soups, when a random relabelling of vertices, faces and corners gives the
same result, permuted back (positions to 1e-9 of the bounding-box diagonal; EdgeDeformer to
EDGE_RELABEL_TOL of the larger of the rest and result diagonals).

Worker protocol (tests/python/test_fuzz.py drives it in subprocesses, so a crash is counted):
    python tests/python/fuzz.py SEED START COUNT
prints "start i function" before case i and one JSON line {"i", "function", "status", "detail"}
after it.
Statuses: ok, rejected (ValueError, or RuntimeError saying to rescale), and the failures error,
nan, permutation.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

import numpy as np
from conftest import rotation
from permutation import Relabelling, grid

import matdeform as md
from matdeform import shapes

FUNCTIONS = [
    "MaterialDeformer",
    "EdgeDeformer",
    "harmonic_weights",
    "dual_edges",
    "face_components",
    "faces_inside",
    "boundary_and_nonmanifold_edges",
    "bend_from_shear",
    "bend_from_vertex",
    "shear_from_vertex",
    "deformation_gradients",
    "learn_distortions",
    "learn_stiffness",
    "rotation_spread",
    "smooth_distortions",
    "stiffness_from_distortion",
    "transform_log",
    "transform_exp",
    "polar_decompose",
    "blend_transforms",
    "obj_round_trip",
    "set_num_threads",
    "unwrap_rotations",
    "PoseSpaceDeformer",
    "PyramidDeformer",
]
# Checked for relabelling on soups too: they only count and sort.
TOPOLOGY = {"dual_edges", "face_components", "faces_inside", "boundary_and_nonmanifold_edges"}
# Solvers get more cases: they have the most arguments.
WEIGHTS = np.array([6, 6, 2] + [1] * (len(FUNCTIONS) - 3), dtype=float)
# EdgeDeformer under relabelling, x the larger of the rest and result bounding-box diagonals:
# another numbering orders the factor differently, and stretch down to 1e-6 of bend leaves
# in-plane motions weakly determined (condition numbers ~1e7), so round-off differs by ~1e-9
# of the result; up to 30 iterations, some not settled (a result many rest diagonals away),
# carry it on. Measured: at most 2.3e-9 (median 5e-16) over 1,290 relabelled cases of seeds
# 0-5; an edge turned by one end's rotation instead of both (a real slip) differs by 1e-4 to 1.
EDGE_RELABEL_TOL = 1e-8
WEIGHTS[FUNCTIONS.index("PoseSpaceDeformer")] = 6
WEIGHTS[FUNCTIONS.index("PyramidDeformer")] = 4


class Failure(Exception):
    def __init__(self, status, detail):
        super().__init__(detail)
        self.status, self.detail = status, detail


# ---- random inputs -------------------------------------------------------------------------


def random_rotation(rng, max_angle=np.pi):
    a = rng.normal(size=3)
    return rotation(a / np.linalg.norm(a), rng.uniform(0, max_angle))


def random_mesh(rng):
    """(kind, vertices, faces): not relabelled yet."""
    kind = rng.choice(["soup", "grid", "tube", "fan"], p=[0.3, 0.35, 0.2, 0.15])
    if kind == "soup":
        n = int(rng.integers(3, 25))
        v = rng.normal(size=(n, 3))
        if rng.random() < 0.2:  # coincident vertices
            v[rng.integers(0, n, n // 3)] = v[0]
        f = rng.integers(0, n, (int(rng.integers(1, 30)), 3))
        if rng.random() < 0.7:  # mostly proper triangles
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
            if len(f) == 0:
                f = np.array([[0, 1, 2]])
    elif kind == "grid":
        v, f = grid(int(rng.integers(1, 8)), int(rng.integers(1, 8)))
        v[:, 2] = rng.normal(scale=0.2, size=len(v))
        keep = rng.random(len(f)) < rng.uniform(0.5, 1.0)
        keep[rng.integers(0, len(f))] = True
        f = f[keep]
    elif kind == "tube":
        v, f = shapes.tube(
            length=rng.uniform(1, 6),
            radius=rng.uniform(0.2, 1.5),
            n_around=int(rng.integers(3, 9)),
            n_along=int(rng.integers(1, 7)),
        )
    else:
        c = int(rng.integers(1, 8))
        step = min(1.5, 5.2 / c)
        a = step * np.arange(c + 1)
        v = np.vstack([[0, 0, 0.3], np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)])
        f = np.stack([np.zeros(c, int), np.arange(1, c + 1), np.arange(2, c + 2)], 1)
    scale = 10.0 ** rng.uniform(-3, 3)
    v = (v @ random_rotation(rng).T) * scale + rng.normal(scale=scale, size=3)
    return str(kind), v, np.asarray(f, dtype=np.int64)


def disjoint_face_sets(rng, m, k, max_size=4):
    order = rng.permutation(m)
    sizes = rng.integers(1, max_size + 1, k)
    out, at = [], 0
    for s in sizes:
        if at >= m:
            break
        out.append(order[at : at + s])
        at += s
    return out


def random_transforms(rng, k, diag, affine=True):
    T = np.tile(np.eye(4), (k, 1, 1))
    for a in range(k):
        S = np.eye(3) * 10.0 ** rng.uniform(-0.5, 0.5)
        if rng.random() < 0.3:  # non-uniform stretch
            S = np.diag(10.0 ** rng.uniform(-0.5, 0.5, 3))
        T[a, :3, :3] = S @ random_rotation(rng, 3.5)
        T[a, :3, 3] = rng.normal(scale=diag, size=3)
    return T if affine else T[:, :3, :3].copy()


def random_stiffness(rng, size):
    lo = 10.0 ** -rng.uniform(0, 3)
    return rng.uniform(lo, 1.0, size)


# ---- hostile mutations ---------------------------------------------------------------------

MUTATIONS = [
    "nan_vertex",
    "negative_index",
    "big_index",
    "float_faces",
    "flat_faces",
    "tiny_mesh",
    "huge_mesh",
    "argument",
]


def mutate_mesh(rng, what, v, f):
    v, f = v.copy(), f.copy()
    if what == "nan_vertex":
        v[rng.integers(0, len(v)), rng.integers(0, 3)] = rng.choice([np.nan, np.inf, -np.inf])
    elif what == "negative_index":
        f[rng.integers(0, len(f)), rng.integers(0, 3)] = -int(rng.integers(1, 2**31 - 1))
    elif what == "big_index":
        f[rng.integers(0, len(f)), rng.integers(0, 3)] = int(rng.integers(len(v), 2**31 - 1))
    elif what == "float_faces":
        f = f.astype(float) + 0.5
    elif what == "flat_faces":
        f = f[:, :2]
    elif what == "tiny_mesh":
        v = v * 1e-60
    elif what == "huge_mesh":
        v = v * 1e60
    return v, f


# ---- checks --------------------------------------------------------------------------------


def finite(name, *arrays):
    for a in arrays:
        a = np.asarray(a)
        if a.dtype.kind in "fc" and not np.isfinite(a).all():
            raise Failure("nan", f"{name}: non-finite output")


def close(name, a, b, tol):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise Failure("permutation", f"{name}: shape {a.shape} vs {b.shape} after relabelling")
    err = float(np.abs(a - b).max()) if a.size else 0.0
    if not err <= tol:
        raise Failure("permutation", f"{name}: differs by {err:.3g} (tol {tol:.3g})")


def same_partition(name, a, b):
    """Labels a (original order) and b (permuted back) define the same partition."""
    first = {}
    ca = np.array([first.setdefault(x, len(first)) for x in a])
    first = {}
    cb = np.array([first.setdefault(x, len(first)) for x in b])
    if not np.array_equal(ca, cb):
        raise Failure("permutation", f"{name}: components change under relabelling")


def edge_set(edges, vertex_map=None):
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if vertex_map is not None:
        e = vertex_map[e]
    return {tuple(sorted(x)) for x in e.tolist()}


# ---- one case ------------------------------------------------------------------------------


def case_function(seed: int, i: int):
    """(rng, function name) of case i: the rng continues into the case's inputs."""
    rng = np.random.default_rng([seed, i])
    return rng, FUNCTIONS[rng.choice(len(FUNCTIONS), p=WEIGHTS / WEIGHTS.sum())]


def run_case(seed: int, i: int) -> dict:
    rng, fn = case_function(seed, i)
    kind, v, f = random_mesh(rng)
    mutation = rng.choice(MUTATIONS) if rng.random() < 0.25 else None
    if mutation is not None and mutation != "argument":
        v, f = mutate_mesh(rng, mutation, v, f)
    # Relabelling checks: every function on unmutated meshes; the solvers not on soups, whose
    # near-degenerate faces make the result depend on round-off (and folded face pairs make
    # the hinge vertices of bend_from_vertex order-dependent, as documented).
    perm = mutation is None and kind != "soup"
    topology = mutation is None
    try:
        CASES[fn](rng, v, f, mutation == "argument", perm if fn not in TOPOLOGY else topology, kind)
    except ValueError as e:
        return {"function": fn, "status": "rejected", "detail": str(e)[:200]}
    except RuntimeError as e:  # a solve refused after the fact: only with a clear remedy
        if "rescale the mesh" not in str(e):
            return {"function": fn, "status": "error", "detail": f"RuntimeError: {e}"[:300]}
        return {"function": fn, "status": "rejected", "detail": str(e)[:200]}
    except Failure as e:
        return {"function": fn, "status": e.status, "detail": e.detail}
    except Exception as e:  # noqa: BLE001 - any other exception is a finding
        return {"function": fn, "status": "error", "detail": f"{type(e).__name__}: {e}"[:300]}
    return {"function": fn, "status": "ok", "detail": kind}


def relabel_for(rng, v, f):
    return Relabelling(v, f, np.random.default_rng(rng.integers(2**32)))


def case_deformer(rng, v, f, hostile, perm, kind):
    n, m = len(v), len(f)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    k = int(rng.integers(1, 4))
    anchors = disjoint_face_sets(rng, max(m, 1), k)
    kw = {}
    if rng.random() < 0.7:
        kw["shear"] = random_stiffness(rng, m)
    e = len(md.dual_edges(f)) if f.ndim == 2 and f.shape[-1] == 3 and f.dtype.kind == "i" else 0
    b = str(rng.choice(["none", "edge", "vertex", "edge3", "vertex3"]))
    if b.startswith("vertex") and n == e:
        b = b.replace("vertex", "edge")  # (E,) wins when E == n (documented)
    if b != "none":
        rows = e if b.startswith("edge") else n
        kw["bend"] = random_stiffness(rng, (rows, 3) if b.endswith("3") else rows)
    if rng.random() < 0.3:
        kw["pinned"] = rng.permutation(n)[: int(rng.integers(0, 4))]
    if rng.random() < 0.3:
        extra = rng.permutation(m)[: int(rng.integers(1, m + 1))]
        kw["region"] = np.unique(np.concatenate([extra, *anchors]))
    if rng.random() < 0.2:
        kw["axes"] = random_rotation(rng)
    affine = rng.random() < 0.6
    T = random_transforms(rng, len(anchors), diag, affine)
    pp = None
    if kw.get("pinned") is not None and rng.random() < 0.5:
        pp = v[kw["pinned"]] + rng.normal(scale=0.1 * diag, size=(len(kw["pinned"]), 3))
    if hostile:
        what = rng.choice(
            ["overlap", "empty", "det", "nan_T", "count", "shear0", "ratio", "pp_nan", "roi"]
        )
        if what == "overlap" and m:
            anchors = anchors + [anchors[0][:1]]
            T = random_transforms(rng, len(anchors), diag, affine)
        elif what == "empty":
            anchors = anchors + [np.zeros(0, int)]
        elif what == "det":
            T[0, :3, :3] = T[0, :3, :3] @ np.diag([1, 1, -1])
        elif what == "nan_T":
            T[0, 0, 0] = np.nan
        elif what == "count":
            T = T[:-1] if len(T) > 1 else np.concatenate([T, T])
        elif what == "shear0":
            kw["shear"] = np.zeros(m)
        elif what == "ratio":
            kw["shear"] = np.ones(m)
            kw["shear"][0] = 1e-15
        elif what == "pp_nan":
            kw["pinned"] = np.array([0])
            pp = np.full((1, 3), np.nan)
        elif what == "roi":
            kw["region"] = np.setdiff1d(np.arange(m), anchors[0])
    d = md.MaterialDeformer(v, f, anchors, **kw)
    X = d.deform(T, pp)
    finite("deform", X, d.weights, d.face_transforms, d.axis_weights(2))
    if X.shape != (n, 3):
        raise Failure("error", f"deform: shape {X.shape}")
    if not perm:
        return
    r = relabel_for(rng, v, f)
    kw2 = dict(kw)
    if "shear" in kw:
        kw2["shear"] = r.per_face(kw["shear"])
    if "bend" in kw:
        kw2["bend"] = (
            r.per_dual_edge(kw["bend"]) if b.startswith("edge") else r.per_vertex(kw["bend"])
        )
    if "pinned" in kw:
        kw2["pinned"] = r.vertex_ids(kw["pinned"])
    if "region" in kw:
        kw2["region"] = r.face_ids(kw["region"])
    d2 = md.MaterialDeformer(r.vertices, r.faces, r.anchors(anchors), **kw2)
    close("deform", r.to_original(d2.deform(T, pp)), X, 1e-9 * max(diag, 1e-300))
    close("weights", r.faces_to_original(d2.weights), d.weights, 1e-9)


def case_edge(rng, v, f, hostile, perm, kind):
    """EdgeDeformer: anchors (vertex sets of random faces, each moved by its own random motion,
    so the carried first step runs) and loose constrained vertices; every option at random."""
    n, m = len(v), len(f)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    groups = [np.unique(f[a]) for a in disjoint_face_sets(rng, max(m, 1), int(rng.integers(1, 4)))]
    groups.append(rng.permutation(n)[: int(rng.integers(0, 3))])
    c, owner = np.unique(np.concatenate(groups), return_index=True)
    owner = np.searchsorted(np.cumsum([len(g) for g in groups]), owner, side="right")
    motions = random_transforms(rng, len(groups), diag)
    rest = v[np.clip(c.astype(np.int64), 0, n - 1)]  # mutated faces may index outside v
    pos = np.einsum("kij,kj->ki", motions[owner, :3, :3], rest) + motions[owner, :3, 3]
    pos += rng.normal(scale=0.01 * diag, size=pos.shape)
    kw = dict(stretch=0.0 if rng.random() < 0.2 else 10.0 ** rng.uniform(-6, 0))
    kw["bend"] = 10.0 ** rng.uniform(-2, 1)
    e = len(md.mesh_edges(f)) if f.ndim == 2 and f.shape[-1] == 3 and f.dtype.kind == "i" else 0
    if rng.random() < 0.3:
        kw["edge_weight"] = random_stiffness(rng, e)
    if rng.random() < 0.3:
        kw["direction"] = rng.normal(size=(n, 3))
    opts = dict(iterations=int(rng.integers(1, 30)), tol=float(rng.choice([0.0, 1e-6, 1e-3])))
    opts.update(p_stretch=float(rng.uniform(0, 1)), p_bend=float(rng.uniform(0.2, 1)))
    opts["gravity"] = rng.normal(scale=1e-3 * diag, size=3) if rng.random() < 0.3 else np.zeros(3)
    opts["relaxation"] = float(rng.choice([1.0, rng.uniform(0.3, 1.0)]))
    if rng.random() < 0.3:
        opts["initial"] = v + rng.normal(scale=0.1 * diag, size=v.shape)
    if hostile:
        what = str(
            rng.choice(["count", "real", "far", "far_start", "gravity", "product", "nan", "repeat"])
        )
        if what == "count":
            opts["iterations"] = rng.choice([0, -1, 2**31, 2**63, 2.0, None, "5"])
        elif what == "real":
            name = str(rng.choice(["tol", "p_stretch", "p_bend", "relaxation", "stretch", "bend"]))
            bad = rng.choice([None, "0.5", np.nan, np.inf, -1.0, 2.0, True])
            (kw if name in ("stretch", "bend") else opts)[name] = bad
        elif what == "far":  # extreme scales: "rescale the mesh", never NaN
            pos = pos * 1e155 if rng.random() < 0.5 else pos + 1e200
        elif what == "far_start":
            opts["initial"] = v * 1e200
        elif what == "gravity":
            opts["gravity"] = np.array([0.0, 0.0, -1e300])
        elif what == "product":
            kw.update(stretch=1e300, edge_weight=np.full(e, 10.0))
        elif what == "nan":
            pos[0, 1] = np.nan
        elif what == "repeat":
            c = np.append(c, c[0])
    d = md.EdgeDeformer(v, f, c, **kw)
    X = d.solve(pos, **opts)
    finite("EdgeDeformer.solve", X, d.last_move, d.bend_coefficients[d.opposite[:, 0] >= 0])
    if X.shape != (n, 3):
        raise Failure("error", f"EdgeDeformer.solve: shape {X.shape}")
    if not perm:
        return
    r = relabel_for(rng, v, f)
    kw2 = dict(kw)
    if "edge_weight" in kw:
        new = {tuple(x): k for k, x in enumerate(md.mesh_edges(r.faces).tolist())}
        old = np.sort(r.vertex[md.mesh_edges(f)], axis=1).tolist()
        kw2["edge_weight"] = np.empty(e)
        kw2["edge_weight"][[new[tuple(x)] for x in old]] = kw["edge_weight"]
    if "direction" in kw:
        kw2["direction"] = r.per_vertex(kw["direction"])
    opts2 = dict(opts)
    if "initial" in opts:
        opts2["initial"] = r.per_vertex(opts["initial"])
    X2 = md.EdgeDeformer(r.vertices, r.faces, r.vertex_ids(c), **kw2).solve(pos, **opts2)
    size = max(diag, float(np.linalg.norm(np.ptp(X, axis=0))), 1e-300)
    # Round-off grows with the condition number, about bend / stretch (with their responses):
    # below the 1e-6 the tolerance was measured at, it grows in proportion (seed 36 case 2699:
    # an effective ratio 2.8e-7, 1.3e-8 of the result apart).
    ratio = (kw["stretch"] * opts.get("p_stretch", 1.0)) / (kw["bend"] * opts.get("p_bend", 1.0))
    loose = 1e-6 / ratio if 0.0 < ratio < 1e-6 else 1.0
    close("EdgeDeformer.solve", r.to_original(X2), X, EDGE_RELABEL_TOL * loose * size)


def case_harmonic_weights(rng, v, f, hostile, perm, kind):
    m = len(f)
    anchors = disjoint_face_sets(rng, max(m, 1), int(rng.integers(1, 4)))
    e = len(md.dual_edges(f))
    bend = random_stiffness(rng, e) if rng.random() < 0.7 else None
    if hostile:
        bend = -np.ones(e) if rng.random() < 0.5 else np.full(e + 1, 1.0)
    W = md.harmonic_weights(f, anchors, bend)
    finite("harmonic_weights", W)
    if perm:
        r = relabel_for(rng, v, f)
        b2 = None if bend is None else r.per_dual_edge(bend)
        W2 = md.harmonic_weights(r.faces, r.anchors(anchors), b2)
        close("harmonic_weights", r.faces_to_original(W2), W, 1e-9)


def case_dual_edges(rng, v, f, hostile, perm, kind):
    pairs, shared = md.dual_edges(f, return_shared=True)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= len(f)):
        raise Failure("error", "dual_edges: pair out of range")
    if perm:
        r = relabel_for(rng, v, f)
        p2 = md.dual_edges(r.faces)
        if edge_set(pairs, r.face) != edge_set(p2):
            raise Failure("permutation", "dual_edges: pairs change under relabelling")


def case_face_components(rng, v, f, hostile, perm, kind):
    labels, count = md.face_components(f)
    if len(labels) and (labels.min() < 0 or labels.max() >= count):
        raise Failure("error", "face_components: label out of range")
    if perm:
        r = relabel_for(rng, v, f)
        labels2, count2 = md.face_components(r.faces)
        if count2 != count:
            raise Failure("permutation", "face_components: count changes")
        same_partition("face_components", labels, r.faces_to_original(labels2))


def case_faces_inside(rng, v, f, hostile, perm, kind):
    ids = rng.permutation(max(len(v), 1))[: int(rng.integers(0, len(v) + 1))]
    if hostile:
        ids = np.append(ids, -int(rng.integers(1, 100)))
    inside = md.faces_inside(f, ids)
    if perm:
        r = relabel_for(rng, v, f)
        inside2 = md.faces_inside(r.faces, r.vertex_ids(ids))
        if set(r.face[inside].tolist()) != set(inside2.tolist()):
            raise Failure("permutation", "faces_inside changes under relabelling")


def case_boundary(rng, v, f, hostile, perm, kind):
    b, nm = md.boundary_and_nonmanifold_edges(f)
    if perm:
        r = relabel_for(rng, v, f)
        b2, nm2 = md.boundary_and_nonmanifold_edges(r.faces)
        if edge_set(b, r.vertex) != edge_set(b2) or edge_set(nm, r.vertex) != edge_set(nm2):
            raise Failure("permutation", "boundary edges change under relabelling")


def case_bend_from_shear(rng, v, f, hostile, perm, kind):
    shear = random_stiffness(rng, len(f))
    if hostile:
        shear = np.append(shear, 1.0)
    phi = md.bend_from_shear(f, shear)
    finite("bend_from_shear", phi)
    if perm:
        r = relabel_for(rng, v, f)
        close(
            "bend_from_shear",
            r.dual_edges_to_original(md.bend_from_shear(r.faces, r.per_face(shear))),
            phi,
            1e-12,
        )


def case_bend_from_vertex(rng, v, f, hostile, perm, kind):
    s = random_stiffness(rng, len(v))
    if hostile:
        s = s[:-1]
    phi = md.bend_from_vertex(f, s)
    finite("bend_from_vertex", phi)
    if perm:
        r = relabel_for(rng, v, f)
        phi2 = md.bend_from_vertex(r.faces, r.per_vertex(s))
        close("bend_from_vertex", r.dual_edges_to_original(phi2), phi, 1e-12)


def case_shear_from_vertex(rng, v, f, hostile, perm, kind):
    s = random_stiffness(rng, len(v))
    if hostile:
        s = np.where(rng.random(len(s)) < 0.5, np.nan, s)
    psi = md.shear_from_vertex(f, s)
    finite("shear_from_vertex", psi)
    if perm:
        r = relabel_for(rng, v, f)
        psi2 = md.shear_from_vertex(r.faces, r.per_vertex(s))
        close("shear_from_vertex", r.faces_to_original(psi2), psi, 1e-12)


def random_poses(rng, v, count):
    out = []
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if len(v) else 1.0
    for _ in range(count):
        p = v @ random_rotation(rng).T + rng.normal(scale=diag, size=3)
        out.append(p + rng.normal(scale=0.05 * diag, size=v.shape))
    return out


def case_deformation_gradients(rng, v, f, hostile, perm, kind):
    (w,) = random_poses(rng, v, 1)
    if hostile:
        w = w[:-1]
    T = md.deformation_gradients(v, w, f)
    finite("deformation_gradients", T)
    if perm:
        r = relabel_for(rng, v, f)
        T2 = md.deformation_gradients(r.vertices, r.per_vertex(w), r.faces)
        close("deformation_gradients", r.faces_to_original(T2), T, 1e-8 * max(1, np.abs(T).max()))


def case_learn(rng, v, f, hostile, perm, kind, which):
    poses = random_poses(rng, v, int(rng.integers(1, 4)))
    if hostile:
        poses[0] = poses[0][:, :2]
    aniso = bool(rng.random() < 0.4)
    if which == "distortions":
        frame = str(rng.choice(["rest", "world"]))
        out = md.learn_distortions(v, f, poses, anisotropic=aniso, frame=frame)
    else:
        region = int(rng.integers(0, 3)) if not aniso else 0
        kw = dict(anisotropic=aniso, smoothing=int(rng.integers(0, 3)), region=region)
        out = md.learn_stiffness(v, f, poses, **kw)
    finite(which, *out)
    if not perm:
        return
    r = relabel_for(rng, v, f)
    p2 = [r.per_vertex(p) for p in poses]
    if which == "distortions":
        b = md.learn_distortions(r.vertices, r.faces, p2, anisotropic=aniso, frame=frame)
        close("learn_distortions bend", r.dual_edges_to_original(b[0]), out[0], 1e-8)
        close("learn_distortions shear", r.faces_to_original(b[1]), out[1], 1e-8)
    else:
        b = md.learn_stiffness(r.vertices, r.faces, p2, **kw)
        # The map divides by a percentile of the distortions: a looser tolerance.
        close("learn_stiffness bend", r.dual_edges_to_original(b[0]), out[0], 1e-6)
        close("learn_stiffness shear", r.faces_to_original(b[1]), out[1], 1e-6)


def case_learn_distortions(rng, v, f, hostile, perm, kind):
    case_learn(rng, v, f, hostile, perm, kind, "distortions")


def case_learn_stiffness(rng, v, f, hostile, perm, kind):
    case_learn(rng, v, f, hostile, perm, kind, "stiffness")


def case_rotation_spread(rng, v, f, hostile, perm, kind):
    poses = random_poses(rng, v, int(rng.integers(1, 4)))
    passes = int(rng.integers(0, 4))
    if hostile:
        passes = -1
    s = md.rotation_spread(v, f, poses, passes)
    finite("rotation_spread", s)
    if perm:
        r = relabel_for(rng, v, f)
        s2 = md.rotation_spread(r.vertices, r.faces, [r.per_vertex(p) for p in poses], passes)
        close("rotation_spread", r.faces_to_original(s2), s, 1e-8)


def case_smooth(rng, v, f, hostile, perm, kind):
    e = len(md.dual_edges(f))
    bend = rng.uniform(0, 1, (e, int(rng.integers(1, 4))))
    shear = rng.uniform(0, 1, len(f))
    if hostile:
        bend[..., 0] = np.nan
    passes = int(rng.integers(0, 4))
    b, s = md.smooth_distortions(f, bend, shear, passes)
    finite("smooth_distortions", b, s)
    if perm:
        r = relabel_for(rng, v, f)
        b2, s2 = md.smooth_distortions(r.faces, r.per_dual_edge(bend), r.per_face(shear), passes)
        close("smooth_distortions bend", r.dual_edges_to_original(b2), b, 1e-12)
        close("smooth_distortions shear", r.faces_to_original(s2), s, 1e-12)


def case_stiffness_from_distortion(rng, v, f, hostile, perm, kind):
    d = rng.exponential(10.0 ** rng.uniform(-14, 2), (int(rng.integers(0, 50)), 2))
    eps = float(10.0 ** -rng.uniform(0, 4))
    clamp = float(rng.uniform(0, 10))
    sharp = float(rng.uniform(0, 10)) if rng.random() < 0.5 else 0.0
    if hostile:
        eps, clamp, sharp = rng.choice(
            [(-1.0, clamp, sharp), (eps, 150.0, sharp), (eps, clamp, np.nan)]
        )
    s = md.stiffness_from_distortion(d, eps=eps, clamp_percent=clamp, sharpness=sharp)
    finite("stiffness_from_distortion", s)
    if s.size and (s.min() < eps - 1e-12 or s.max() > 1 + 1e-12):
        raise Failure("error", "stiffness_from_distortion: outside [eps, 1]")


def random_matrix(rng):
    kind = rng.choice(["rotation", "similarity", "general", "huge", "singular", "negative", "4x4"])
    if kind == "rotation":
        return random_rotation(rng)
    if kind == "similarity":
        return 10.0 ** rng.uniform(-3, 3) * random_rotation(rng)
    if kind == "general":
        return rng.normal(size=(3, 3))
    if kind == "huge":
        return np.diag(10.0 ** rng.uniform(-320, 320, 3)) @ random_rotation(rng)
    if kind == "singular":
        return np.outer(rng.normal(size=3), rng.normal(size=3))
    if kind == "negative":
        return random_rotation(rng) @ np.diag([1, 1, -1])
    return np.eye(4)


def case_transform_log(rng, v, f, hostile, perm, kind):
    L, w = md.transform_log(random_matrix(rng))
    finite("transform_log", L, w)


def case_transform_exp(rng, v, f, hostile, perm, kind):
    L = rng.normal(scale=10.0 ** rng.uniform(-2, 3.2), size=(3, 3))
    if rng.random() < 0.5:
        L = (L + L.T) / 2
    M = md.transform_exp(L, rng.normal(scale=10.0 ** rng.uniform(-3, 2), size=3))
    finite("transform_exp", M)


def case_polar(rng, v, f, hostile, perm, kind):
    S, R = md.polar_decompose(random_matrix(rng))
    finite("polar_decompose", S, R)


def case_blend(rng, v, f, hostile, perm, kind):
    k = int(rng.integers(1, 4))
    T = random_transforms(rng, k, 1.0, affine=False)
    if rng.random() < 0.3:  # hostile matrices among them
        T[0] = random_matrix(rng)[:3, :3]
    W = rng.normal(scale=10.0 ** rng.uniform(-1, 3), size=(int(rng.integers(0, 20)), k))
    out = md.blend_transforms(T, W)
    finite("blend_transforms", out)


def case_obj(rng, v, f, hostile, perm, kind):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "m.obj")
        md.write_obj(path, v, f)
        v2, f2 = md.read_obj(path)
    finite("read_obj", v2)


def case_threads(rng, v, f, hostile, perm, kind):
    before = md.num_threads()
    try:
        md.set_num_threads(rng.choice([-1, 0, 1, 2, 3]).item())
        if md.num_threads() < 1:
            raise Failure("error", "num_threads below 1")
    finally:
        md.set_num_threads(before)


def pinned_parts(v, f, ctrl, diag):
    """Whether every part (vertices joined by faces) holding a control has three non-collinear
    controls in its faces. A control in no face holds nothing, and a part with fewer leaves the
    turn about them free (a family of minima, docs/pyramid.md): no unique result to compare."""
    part = np.arange(len(v))

    def root(a):
        while part[a] != a:
            part[a] = part[part[a]]
            a = part[a]
        return a

    for face in np.asarray(f).reshape(-1, 3):
        for a in face[1:]:
            part[root(a)] = root(face[0])
    used = np.zeros(len(v), bool)
    used[np.asarray(f).ravel()] = True
    held = {}
    for c in ctrl:
        if used[c]:
            held.setdefault(root(c), []).append(c)
    for ids in held.values():
        p = v[ids] - v[ids].mean(0)
        if len(ids) < 3 or not np.linalg.svd(p, compute_uv=False)[1] > 1e-6 * diag:
            return False
    return bool(held)


def case_pyramid(rng, v, f, hostile, perm, kind):
    """Controls: a few random vertices, or a random ball of them; targets: their rest places
    moved by a random similarity and noise. Every numeric argument of deform() is drawn, and a
    hostile case breaks one of them (or the positions' scale)."""
    n = len(v)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    if rng.random() < 0.5:
        ctrl = rng.permutation(n)[: int(rng.integers(1, min(n, 6) + 1))]
    else:
        centre = v[rng.integers(0, n)] if n else np.zeros(3)
        near = np.argsort(np.linalg.norm(v - centre, axis=1))
        ctrl = np.sort(near[: int(rng.integers(1, max(2, n // 3) + 1))])
    R = random_rotation(rng) * 10.0 ** rng.uniform(-0.3, 0.3)
    target = v[ctrl] @ R.T + rng.normal(scale=diag, size=3)
    target = target + rng.normal(scale=rng.choice([0.0, 0.05, 0.3]) * diag, size=target.shape)
    kw = {
        "iterations": [None, 0, 1, 5, int(rng.integers(0, 200))][int(rng.integers(0, 5))],
        "tol": float(10.0 ** rng.uniform(-10, -2)),
        "scale_weight": float(rng.choice([0.0, 0.003, 10.0 ** rng.uniform(-4, 2)])),
    }
    if rng.random() < 0.3:
        kw["initial"] = v * 10.0 ** rng.uniform(-1, 1) + rng.normal(scale=0.1 * diag, size=v.shape)
    if rng.random() < 0.3:
        kw["lbfgs_iterations"] = int(rng.choice([0, 1, 7, 60]))
    if hostile:
        what = rng.choice(
            ["iterations", "lbfgs_iterations", "tol", "scale_weight"]
            + ["initial", "target", "control"]
        )
        if what in ("iterations", "lbfgs_iterations"):
            kw[what] = rng.choice([-1, 2**31, 2**40, 1.5, "x"]).item()
        elif what == "tol":
            kw["tol"] = rng.choice([-1e-6, np.nan, np.inf, "x"]).item()
        elif what == "scale_weight":
            kw["scale_weight"] = rng.choice([-1.0, np.nan, 1e300, "x"]).item()
        elif what == "initial":
            kw["initial"] = rng.choice([1e200, np.nan, -1]).item() * (v if n else np.zeros((0, 3)))
        elif what == "target":
            target = target * rng.choice([1e200, np.inf, np.nan]).item()
        else:
            ctrl = np.concatenate([ctrl, ctrl[:1]])
            target = np.vstack([target, target[:1]])
    d = md.PyramidDeformer(v, f, ctrl)
    X = d.deform(target, **kw)
    finite("PyramidDeformer.deform", X, d.last_energy)
    if X.shape != (n, 3):
        raise Failure("error", f"deform: shape {X.shape}")
    # Relabelling: when converged from the start deform() builds, and when the controls pin the
    # pose (one or two controls, or controls on a line, leave the turn about them free: a family
    # of minima, docs/pyramid.md). Converged means within ~tol^2 of the minimum.
    if not perm or not pinned_parts(v, f, ctrl, diag) or not d.last_converged or "initial" in kw:
        return
    r = relabel_for(rng, v, f)
    d2 = md.PyramidDeformer(r.vertices, r.faces, r.vertex_ids(ctrl))
    X2 = d2.deform(target, **kw)
    if d2.last_converged:
        tol = max(1e-9, 10 * kw["tol"] ** 2) * max(diag, 1e-300)
        close("PyramidDeformer.deform", r.to_original(X2), X, tol)


def case_unwrap(rng, v, f, hostile, perm, kind):
    """An animation of k anchors (turns of up to ~115 degrees per frame about wobbling axes,
    scaled, sometimes float32) unwrapped, then its last frame deformed with those vectors on a
    small tube; hostile: NaN or det <= 0 frames, bad or huge starts, a vector off its rotation."""
    count, k = int(rng.integers(0, 30)), int(rng.integers(1, 4))
    axes, speed = rng.normal(size=(k, 3)), rng.uniform(-2, 2, k)
    frames = np.empty((count, k, 3, 3))
    for t in range(count):
        for a in range(k):
            turn = rotation(axes[a] + 0.2 * rng.normal(size=3), speed[a] * t)
            frames[t, a] = turn @ np.diag(10.0 ** rng.uniform(-0.5, 0.5, 3))
    if rng.random() < 0.3:
        frames = frames.astype(np.float32)
    start = (
        rng.normal(scale=10.0 ** rng.uniform(-1, 3), size=(k, 3)) if rng.random() < 0.3 else None
    )
    what = rng.choice(["nan", "det", "start_shape", "start_inf", "start_huge", "vector"])
    if hostile and count and what == "nan":
        frames[rng.integers(0, count), rng.integers(0, k), 1, 1] = np.nan
    elif hostile and count and what == "det":
        frames[rng.integers(0, count), rng.integers(0, k)] *= -1
    elif hostile and what == "start_shape":
        start = np.zeros((k + 1, 3))
    elif hostile and what == "start_inf":
        start = np.full((k, 3), np.inf)
    elif hostile and what == "start_huge":
        start = np.full((k, 3), 10.0 ** rng.uniform(15, 300))
    vectors = md.unwrap_rotations(frames, start=start)
    finite("unwrap_rotations", vectors)
    if vectors.shape != (count, k, 3):
        raise Failure("error", f"unwrap_rotations: shape {vectors.shape}")
    if not count:
        return
    tv, tf = shapes.tube(length=4.0, radius=0.5, n_around=5, n_along=3 * k)
    ring = 2 * 5  # faces per segment
    anchors = [np.arange(3 * a * ring, (3 * a + 1) * ring) for a in range(k)]
    T = np.tile(np.eye(4), (k, 1, 1))
    T[:, :3, :3] = frames[-1]
    rv = vectors[-1].copy()
    if hostile and what == "vector":
        rv[0] += 0.5
    X = md.MaterialDeformer(tv, tf, anchors).deform(T, rotation_vectors=rv)
    finite("deform(rotation_vectors)", X)


def smooth_field(rng, v, diag, amount):
    """(n,3) smooth displacement: a few random sine waves over the mesh, amplitude ~amount*diag."""
    W = rng.normal(size=(3, 3)) * (np.pi / max(diag, 1e-300))
    phase = rng.uniform(0, 2 * np.pi, 3)
    return np.sin(v @ W + phase) @ rng.normal(scale=amount * diag, size=(3, 3))


POSE_SPACE_BAD = {
    "rotation_iterations": [2**31, 0, 2.0, "3", True],
    "gauge_steps": [2**31, -1, None],
    "transfer_neighbors": [2**40, 0, np.float64(8)],
    "position_weight": ["1", None, 0.0, -1.0, np.inf, np.nan, [1.0]],
    "rotation_weight": [None, 0.0, np.nan],
    "joint_weight": [None, -2.0],
    "rotation_tolerance": [None, 0.0, 1.0, np.nan],
    "reliability_angle": [None, 0.0, -np.inf, np.nan],
    "orientation_weight": [None, -1.0, np.inf],
    "weight_regularization": ["x", -0.5],
    "handle_rotations": ["no", None, 1],
    "convex_weights": [None, 0],
    "area_weights": [2],
    "rotation_energy": [None, "exact"],
}


def case_pose_space(rng, v, f, hostile, perm, kind):
    """PoseSpaceDeformer on the random mesh, its unused vertices dropped (a partial grid falls
    into parts, which are solved or, without a handle, kept at rest): random examples (smooth
    non-rigid fields), handles, frame, rotational pairs, frozen faces, coarse level and options;
    hostile: a bad option, bad handles or positions far beyond double range."""
    valid = f.ndim == 2 and f.shape[1] == 3 and f.dtype.kind == "i" and f.size > 0
    valid = valid and 0 <= f.min() and f.max() < len(v)
    if valid and rng.random() < 0.9:  # mostly compact, sometimes with unused vertices
        used = np.unique(f)
        remap = np.full(len(v), -1)
        remap[used] = np.arange(len(used))
        v, f = v[used], remap[f]
    n, m = len(v), len(f)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    p = int(rng.integers(0, 4))
    with np.errstate(all="ignore"):  # mutated meshes: NaN or 1e60 vertices
        fields = [smooth_field(rng, v, diag, rng.uniform(0.02, 0.15)) for _ in range(p - 1)]
    examples = [v] + [v + x for x in fields]
    examples = np.stack(examples)[:p] if p else np.zeros((0, n, 3))
    sizes = rng.integers(1, 7, int(rng.integers(1, 4)))
    order = rng.permutation(n)
    handles, at = [], 0
    for s in sizes:
        if at + s <= n:
            handles.append(order[at : at + s])
            at += s
    kw = {}
    if rng.random() < 0.3 and m:
        kw["frame"] = int(rng.integers(0, m))
    if rng.random() < 0.25 and m >= 2:
        kw["rotational"] = [tuple(int(x) for x in rng.choice(m, 2, replace=False))]
    if rng.random() < 0.2 and valid:
        hv = np.zeros(n, bool)
        for h in handles:
            hv[h] = True
        free = np.flatnonzero(~hv[f].any(axis=1))
        if len(free):
            kw["frozen"] = rng.choice(free, min(len(free), int(rng.integers(1, 4))), replace=False)
    if rng.random() < 0.25 and m >= 24:
        kw["coarse"] = int(rng.integers(max(4, m // 4), m))
    if rng.random() < 0.5:
        kw["position_weight"] = 10.0 ** rng.uniform(-2, 4)
        kw["rotation_weight"] = 10.0 ** rng.uniform(-2, 2)
        kw["orientation_weight"] = rng.choice([0.0, 0.5, 1.0, 3.0])
        kw["weight_regularization"] = rng.choice([0.0, 0.0, 0.01])
        kw["convex_weights"] = bool(rng.random() < 0.3)
        kw["rotation_energy"] = str(rng.choice(["chordal", "geodesic"]))
        kw["reliability_angle"] = rng.choice([0.2, 0.5, np.inf])
        kw["area_weights"] = bool(rng.random() < 0.2)
        kw["transfer_neighbors"] = int(rng.integers(1, 12))
    if perm:  # converged rotations (the default cap leaves a numbering-dependent residual)
        kw.update(rotation_iterations=500, gauge_steps=50, rotation_tolerance=1e-12)
    # An edit: a blend of the examples (a little beyond), rigidly moved, with noise.
    w = rng.dirichlet(np.ones(p)) * 1.4 - 0.4 / p if p else None
    shape = np.einsum("k,kvc->vc", w, examples) if p else v.copy()
    R, t = random_rotation(rng), rng.normal(scale=diag, size=3)
    with np.errstate(all="ignore"):
        shape = shape @ R.T + t + rng.normal(scale=0.01 * diag, size=shape.shape)
    hp = [shape[h] for h in handles]
    rot = None
    if "rotational" in kw and rng.random() < 0.6:
        rot = random_rotation(rng, 1.0)[None]
    ft = None
    if "frame" in kw and rng.random() < 0.5:
        ft = np.eye(4)
        ft[:3, :3], ft[:3, 3] = R, t
    if hostile or rng.random() < 0.15:  # its own hostile arguments, more often than the rest
        what = str(rng.choice(["option", "handles", "positions", "examples", "far", "count"]))
        if what == "option":
            name = str(rng.choice(list(POSE_SPACE_BAD)))
            bad = POSE_SPACE_BAD[name]
            kw[name] = bad[int(rng.integers(0, len(bad)))]
        elif what == "handles" and handles:
            handles = handles + [handles[0][:1]] if rng.random() < 0.5 else [np.array([n + 3])]
            hp = [shape[np.clip(h, 0, n - 1)] for h in handles]
        elif what == "positions" and hp:
            hp[0] = hp[0].copy()
            hp[0][0, 0] = rng.choice([np.nan, np.inf])
        elif what == "examples" and p:
            examples = examples.copy()
            with np.errstate(over="ignore"):  # 1e300: infinite, refused as such
                examples[-1] = examples[-1] * rng.choice([1e155, 1e300])
        elif what == "far" and hp:
            hp = [h * 1e155 if rng.random() < 0.5 else h + 1e200 for h in hp]
        elif hp:
            hp = hp[:-1]
    d = md.PoseSpaceDeformer(v, f, examples, handles, **kw)
    X = d.deform(hp, rot, ft)
    finite("PoseSpaceDeformer.deform", X, d.example_weights, d.pose_weights(hp, rot, ft))
    if X.shape != (n, 3):
        raise Failure("error", f"deform: shape {X.shape}")
    if not perm:
        return
    r = relabel_for(rng, v, f)
    kw2 = dict(kw)
    if "frame" in kw:
        kw2["frame"] = int(r.face_ids([kw["frame"]])[0])
    if "rotational" in kw:
        kw2["rotational"] = [tuple(int(x) for x in r.face_ids(list(q))) for q in kw["rotational"]]
    if "frozen" in kw:
        kw2["frozen"] = r.face_ids(kw["frozen"])
    ex2 = np.stack([r.per_vertex(x) for x in examples]) if p else examples
    d2 = md.PoseSpaceDeformer(r.vertices, r.faces, ex2, [r.vertex_ids(h) for h in handles], **kw2)
    # The result's own scale: handles far from the rest mesh stretch it.
    scale = max(diag, float(np.linalg.norm(np.ptp(X, axis=0))))
    close("PoseSpaceDeformer.deform", r.to_original(d2.deform(hp, rot, ft)), X, 1e-9 * scale)
    close("example_weights", d2.example_weights, d.example_weights, 1e-9)


CASES = {
    "MaterialDeformer": case_deformer,
    "EdgeDeformer": case_edge,
    "harmonic_weights": case_harmonic_weights,
    "dual_edges": case_dual_edges,
    "face_components": case_face_components,
    "faces_inside": case_faces_inside,
    "boundary_and_nonmanifold_edges": case_boundary,
    "bend_from_shear": case_bend_from_shear,
    "bend_from_vertex": case_bend_from_vertex,
    "shear_from_vertex": case_shear_from_vertex,
    "deformation_gradients": case_deformation_gradients,
    "learn_distortions": case_learn_distortions,
    "learn_stiffness": case_learn_stiffness,
    "rotation_spread": case_rotation_spread,
    "smooth_distortions": case_smooth,
    "stiffness_from_distortion": case_stiffness_from_distortion,
    "transform_log": case_transform_log,
    "transform_exp": case_transform_exp,
    "polar_decompose": case_polar,
    "blend_transforms": case_blend,
    "obj_round_trip": case_obj,
    "set_num_threads": case_threads,
    "unwrap_rotations": case_unwrap,
    "PoseSpaceDeformer": case_pose_space,
    "PyramidDeformer": case_pyramid,
}
assert set(CASES) == set(FUNCTIONS)


def main(argv):
    seed, start, count = (int(x) for x in argv[1:4])
    crash_at = int(os.environ.get("MD_FUZZ_CRASH_AT", "-1"))  # tests the harness
    for i in range(start, start + count):
        print(f"start {i} {case_function(seed, i)[1]}", flush=True)
        if i == crash_at:
            os.abort()
        print(json.dumps({"i": i, **run_case(seed, i)}), flush=True)


if __name__ == "__main__":
    main(sys.argv)
