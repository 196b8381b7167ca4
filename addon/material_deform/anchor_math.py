"""Pure numpy helpers (no bpy) for anchors, solver inputs and bind fingerprints."""

from __future__ import annotations

import hashlib

import numpy as np

POSITION = "POSITION"  # anchor follows the Empty's full transform (pinned vertices)
ROTATION = "ROTATION"  # paper mode: only rotation + scale prescribed


def anchor_transform(m_obj, m_empty_now, m_empty_bind, m_obj_bind=None) -> np.ndarray:
    """Motion of an anchor since bind in the mesh object's local space:
    ``inv(M_obj) @ M_now @ inv(M_bind) @ M_obj_bind`` (``M_obj_bind`` = the object's world
    matrix at bind, default ``M_obj``). The anchor faces then follow the Empty exactly in world
    space, also when the Empty is parented to the object or the object moved since bind."""
    m_obj = np.asarray(m_obj, dtype=np.float64)
    m_obj_bind = m_obj if m_obj_bind is None else np.asarray(m_obj_bind, dtype=np.float64)
    return np.linalg.solve(m_obj, m_empty_now @ np.linalg.solve(m_empty_bind, m_obj_bind))


def anchor_transforms(m_obj, now, bind, m_obj_bind=None) -> np.ndarray:
    """Vectorised :func:`anchor_transform` for (k,4,4) stacks."""
    m_obj = np.asarray(m_obj, dtype=np.float64)
    m_obj_bind = m_obj if m_obj_bind is None else np.asarray(m_obj_bind, dtype=np.float64)
    now = np.asarray(now, dtype=np.float64).reshape(-1, 4, 4)
    bind = np.asarray(bind, dtype=np.float64).reshape(-1, 4, 4)
    return affine_inverse(m_obj) @ now @ affine_inverse(bind) @ m_obj_bind


class PoseTransforms:
    """:func:`anchor_transforms` for live updates: the inverses depend only on the object's
    matrices and the bind matrices, which stay put while an Empty is dragged, so they are kept
    until either changes (two small matmuls per update instead of ~0.2 ms of numpy calls)."""

    def __init__(self):
        self._key = None
        self._left = self._right = None

    def __call__(self, m_obj, now, bind, m_obj_bind=None) -> np.ndarray:
        m_obj = np.asarray(m_obj, dtype=np.float64)
        m_obj_bind = m_obj if m_obj_bind is None else np.asarray(m_obj_bind, dtype=np.float64)
        bind = np.asarray(bind, dtype=np.float64).reshape(-1, 4, 4)
        key = m_obj.tobytes() + bind.tobytes() + m_obj_bind.tobytes()
        if key != self._key:
            self._left, self._right = affine_inverse(m_obj), affine_inverse(bind) @ m_obj_bind
            self._key = key
        return self._left @ np.asarray(now, dtype=np.float64).reshape(-1, 4, 4) @ self._right


# Cyclic index shifts for cross products of rows: (u x v)_j = u_{j+1} v_{j+2} - u_{j+2} v_{j+1}.
_NEXT = [1, 2, 0]
_PREV = [2, 0, 1]


def affine_inverse(m) -> np.ndarray:
    """Inverse of (..., 4, 4) affine transforms (bottom row 0 0 0 1) via the 3x3 adjugate.

    Deliberately no LAPACK on the live-update path: a single ``np.linalg.inv`` makes the
    OpenBLAS bundled with PyPI numpy (bpy 4.x) keep a thread spinning on the second core for as
    long as updates keep coming, which halves the solver's speed there. Raises ValueError for a
    singular transform (an object or Empty scaled to zero)."""
    m = np.asarray(m, dtype=np.float64)
    a = m[..., :3, :3]
    r1, r2 = a[..., _NEXT, :], a[..., _PREV, :]  # row i of the cofactors is a_{i+1} x a_{i+2}
    cof = r1[..., _NEXT] * r2[..., _PREV] - r1[..., _PREV] * r2[..., _NEXT]
    det = np.einsum("...j,...j->...", a[..., 0, :], cof[..., 0, :])
    scale = np.abs(a).max(axis=(-2, -1)) ** 3
    if not np.all(np.abs(det) > 1e-12 * scale):
        raise ValueError("a transform is singular (an object or Empty scaled to zero?)")
    inv3 = np.swapaxes(cof, -1, -2) / det[..., None, None]
    out = np.zeros_like(m)
    out[..., :3, :3] = inv3
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", inv3, m[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def singular(m) -> np.ndarray:
    """Indices of the (k,4,4) transforms whose 3x3 part has no inverse (|det| <= 1e-12 of its
    largest entry cubed: an Empty scaled to zero). No LAPACK (see :func:`affine_inverse`)."""
    # Runs on every live update: the nine entries as rows of a (9, k) array and the rule of
    # Sarrus cost ~8 us for six anchors (np.cross, or affine_inverse's cofactors, ~20-25 us).
    a = np.asarray(m, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3].reshape(-1, 9).T
    det = a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6])
    det += a[2] * (a[3] * a[7] - a[4] * a[6])
    scale = np.abs(a).max(axis=0) ** 3
    return np.flatnonzero(~(np.abs(det) > 1e-12 * scale))


def rigid_fit(rest, posed) -> np.ndarray:
    """(4,4) rotation + translation that best maps points ``rest`` (n,3) onto ``posed`` (n,3)
    in the least-squares sense (Kabsch; no reflection)."""
    a = np.asarray(rest, dtype=np.float64)
    b = np.asarray(posed, dtype=np.float64)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _s, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = cb - rot @ ca
    return out


def anchor_polygons(vertex_in_group, loop_vert, loop_poly, n_polys: int) -> np.ndarray:
    """Boolean mask of polygons whose vertices are ALL in the group."""
    member = np.asarray(vertex_in_group, dtype=bool)[np.asarray(loop_vert)]
    bad = np.bincount(loop_poly, weights=~member, minlength=n_polys)
    total = np.bincount(loop_poly, minlength=n_polys)
    return (bad == 0) & (total > 0)


def face_regions(tris) -> int:
    """How many separate regions the triangles ``tris`` (m,3) of vertex indices make, two
    triangles being in one region when a chain of shared vertices joins them."""
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if len(tris) == 0:
        return 0
    verts, local = np.unique(tris, return_inverse=True)
    label = np.arange(len(verts))
    local = local.reshape(-1, 3)
    while True:  # each triangle takes its corners' smallest label, until nothing changes
        low = label[local].min(axis=1)
        new = label.copy()
        np.minimum.at(new, local.ravel(), np.repeat(low, 3))
        new = new[new]  # jump along the labels: halves the remaining passes
        if np.array_equal(new, label):
            return len(np.unique(label))
        label = new


def solve_plan(modes, anchor_faces, tris):
    """How to call the solver for the given anchor modes.

    Returns ``(use_4x4, pinned)``: all-position anchors -> (k,4,4) without pins (the core pins
    every anchor vertex to its transform); all-rotation -> (k,3,3) and no pins; mixed ->
    (k,4,4) with the position anchors' vertices pinned.
    """
    modes = list(modes)
    if all(m == POSITION for m in modes):
        return True, None
    if all(m == ROTATION for m in modes):
        return False, None
    tris = np.asarray(tris)
    pins = [tris[f].ravel() for f, m in zip(anchor_faces, modes, strict=True) if m == POSITION]
    return True, np.unique(np.concatenate(pins)).astype(np.int64)


def compact(tris, n_vertices: int):
    """Drop vertices no triangle uses (loose verts would make the solve singular).
    Returns ``(used, remapped_tris)``; ``used`` is None when nothing was dropped."""
    tris = np.asarray(tris, dtype=np.int64)
    used = np.unique(tris)
    if len(used) == n_vertices:
        return None, tris
    remap = np.full(n_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return used, remap[tris]


def triangle_areas(vertices, tris) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(tris, dtype=np.int64)
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    return 0.5 * np.linalg.norm(n, axis=1)


def fingerprint(*parts) -> str:
    """Short stable hash of arrays / strings (shape and dtype included)."""
    h = hashlib.blake2b(digest_size=12)
    for p in parts:
        if isinstance(p, str):
            h.update(b"s" + p.encode())
            continue
        a = np.ascontiguousarray(p)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()
