"""Pure numpy helpers (no bpy) for anchors, solver inputs and bind fingerprints."""

from __future__ import annotations

import hashlib

import numpy as np

POSITION = "POSITION"  # anchor follows the Empty's full transform (pinned vertices)
ROTATION = "ROTATION"  # paper mode: only rotation + scale prescribed


def anchor_transform(m_obj, m_empty_now, m_empty_bind) -> np.ndarray:
    """Empty motion since bind, expressed in the mesh object's local space:
    ``inv(M_obj) @ M_now @ inv(M_bind) @ M_obj``."""
    m_obj = np.asarray(m_obj, dtype=np.float64)
    return np.linalg.solve(m_obj, m_empty_now @ np.linalg.solve(m_empty_bind, m_obj))


def anchor_transforms(m_obj, now, bind) -> np.ndarray:
    """Vectorised :func:`anchor_transform` for (k,4,4) stacks."""
    m_obj = np.asarray(m_obj, dtype=np.float64)
    now = np.asarray(now, dtype=np.float64).reshape(-1, 4, 4)
    bind = np.asarray(bind, dtype=np.float64).reshape(-1, 4, 4)
    return affine_inverse(m_obj) @ now @ affine_inverse(bind) @ m_obj


def affine_inverse(m) -> np.ndarray:
    """Inverse of (..., 4, 4) transforms. One batched LAPACK call (~10 us for a few matrices;
    the adjugate written out in numpy took ~20x longer per live update). Raises ValueError for
    a singular one (an object or Empty scaled to zero)."""
    try:
        return np.linalg.inv(np.asarray(m, dtype=np.float64))
    except np.linalg.LinAlgError:
        raise ValueError("a transform is singular (an object or Empty scaled to zero?)") from None


def anchor_polygons(vertex_in_group, loop_vert, loop_poly, n_polys: int) -> np.ndarray:
    """Boolean mask of polygons whose vertices are ALL in the group."""
    member = np.asarray(vertex_in_group, dtype=bool)[np.asarray(loop_vert)]
    bad = np.bincount(loop_poly, weights=~member, minlength=n_polys)
    total = np.bincount(loop_poly, minlength=n_polys)
    return (bad == 0) & (total > 0)


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
