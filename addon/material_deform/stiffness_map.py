"""Pure numpy helpers (no bpy): paint value -> stiffness, and mapping of per-polygon / per-edge
stiffness onto the triangles and dual edges the solver works on.

Kept bpy-free so it can be unit tested outside Blender and later move into ``matdeform``.
"""

from __future__ import annotations

import numpy as np

DEFAULT_SPAN = 3.0  # decades: paint 0 -> 1e-3, paint 1 -> 1


def paint_to_stiffness(paint, span: float = DEFAULT_SPAN) -> np.ndarray:
    """Paint value in [0, 1] -> stiffness on a log scale: ``10 ** (span * (p - 1))``.

    0 is the most flexible (``10**-span``), 1 is stiff (1.0). Values outside [0, 1] are clipped
    so a stray brush stroke can never produce a zero or negative stiffness.
    """
    if span <= 0:
        raise ValueError("span: must be > 0")
    p = np.clip(np.asarray(paint, dtype=np.float64), 0.0, 1.0)
    return 10.0 ** (span * (p - 1.0))


def stiffness_to_paint(stiffness, span: float = DEFAULT_SPAN) -> np.ndarray:
    """Inverse of :func:`paint_to_stiffness` (clipped to [0, 1])."""
    s = np.asarray(stiffness, dtype=np.float64)
    return np.clip(1.0 + np.log10(np.maximum(s, 1e-300)) / span, 0.0, 1.0)


def stiffness_range(span: float = DEFAULT_SPAN) -> tuple[float, float]:
    return 10.0**-span, 1.0


def color_to_paint(rgba) -> np.ndarray:
    """Colour (sRGB, 0..1) -> paint value: plain mean of R, G, B, so black = flexible and
    white = stiff, and a mid grey picked in the UI gives 0.5."""
    c = np.asarray(rgba, dtype=np.float64)
    return np.clip(c[:, :3].mean(axis=1), 0.0, 1.0)


def loop_polygon_index(loop_start, loop_total) -> np.ndarray:
    """Polygon index of every loop (corner), for polygons given by loop_start/loop_total."""
    loop_start = np.asarray(loop_start, dtype=np.int64)
    loop_total = np.asarray(loop_total, dtype=np.int64)
    n_loops = int(loop_total.sum())
    poly = np.repeat(np.arange(len(loop_start), dtype=np.int64), loop_total)
    out = np.empty(n_loops, dtype=np.int64)
    # loops of a polygon are contiguous but polygons need not be stored in loop order
    offs = np.cumsum(loop_total) - loop_total
    loop_idx = np.arange(n_loops, dtype=np.int64) - np.repeat(offs, loop_total)
    loop_idx += np.repeat(loop_start, loop_total)
    out[loop_idx] = poly
    return out


def polygon_mean(loop_values, loop_poly, n_polys: int) -> np.ndarray:
    """Mean over each polygon's corners of a per-loop value."""
    s = np.bincount(loop_poly, weights=loop_values, minlength=n_polys)
    c = np.bincount(loop_poly, minlength=n_polys)
    return s / np.maximum(c, 1)


def face_paint_from_vertex(vertex_paint, loop_vert, loop_poly, n_polys: int) -> np.ndarray:
    """Per-polygon paint = mean of its corner vertices' paint (averaged in paint space, i.e. a
    geometric mean of stiffness, so one stiff corner does not dominate a flexible face)."""
    vp = np.asarray(vertex_paint, dtype=np.float64)
    return polygon_mean(vp[np.asarray(loop_vert)], loop_poly, n_polys)


def edge_stiffness(face_stiffness, loop_edge, loop_poly, n_edges: int) -> np.ndarray:
    """Bending stiffness per mesh edge = mean shear stiffness of the polygons using it
    (the paper's phi_ij = (psi_i + psi_j) / 2). Loose edges get 1."""
    psi = np.asarray(face_stiffness, dtype=np.float64)
    s = np.bincount(loop_edge, weights=psi[loop_poly], minlength=n_edges)
    c = np.bincount(loop_edge, minlength=n_edges)
    out = np.ones(n_edges)
    used = c > 0
    out[used] = s[used] / c[used]
    return out


def dual_to_mesh_edge(tris, dual, edge_verts) -> np.ndarray:
    """Blender edge index crossed by each dual edge (pair of adjacent triangles), -1 when the
    two triangles share no Blender edge (the internal diagonal of a quad or n-gon)."""
    tris = np.asarray(tris, dtype=np.int64)
    dual = np.asarray(dual, dtype=np.int64).reshape(-1, 2)
    ev = np.sort(np.asarray(edge_verts, dtype=np.int64).reshape(-1, 2), axis=1)
    out = np.full(len(dual), -1, dtype=np.int64)
    if len(dual) == 0 or len(ev) == 0:
        return out
    a, b = tris[dual[:, 0]], tris[dual[:, 1]]
    shared = (a[:, :, None] == b[:, None, :]).any(axis=2)
    ok = shared.sum(axis=1) == 2
    pair = np.sort(a[ok][shared[ok]].reshape(-1, 2), axis=1)
    nv = int(max(tris.max(), ev.max()) + 1)
    ekey = ev[:, 0] * nv + ev[:, 1]
    order = np.argsort(ekey)
    key = pair[:, 0] * nv + pair[:, 1]
    pos = np.clip(np.searchsorted(ekey[order], key), 0, len(ekey) - 1)
    found = ekey[order][pos] == key
    idx = np.full(len(key), -1, dtype=np.int64)
    idx[found] = order[pos[found]]
    out[np.flatnonzero(ok)] = idx
    return out


def dual_edge_bend(tris, dual, tri_poly, face_stiffness, edge_verts, edge_phi) -> np.ndarray:
    """Bending stiffness per dual edge (triangle pair) from per-polygon psi and per-edge phi.

    Two triangles of the same polygon share an internal triangulation edge, which has no
    Blender edge: use that polygon's psi. Otherwise use the phi of the Blender edge they share.
    """
    tris = np.asarray(tris, dtype=np.int64)
    dual = np.asarray(dual, dtype=np.int64).reshape(-1, 2)
    tri_poly = np.asarray(tri_poly, dtype=np.int64)
    psi = np.asarray(face_stiffness, dtype=np.float64)
    phi = np.asarray(edge_phi, dtype=np.float64)
    f, g = dual[:, 0], dual[:, 1]
    out = 0.5 * (psi[tri_poly[f]] + psi[tri_poly[g]])
    same = tri_poly[f] == tri_poly[g]
    out[same] = psi[tri_poly[f[same]]]
    if len(phi):
        edge = dual_to_mesh_edge(tris, dual, edge_verts)
        use = ~same & (edge >= 0)
        out[use] = phi[edge[use]]
    return out


def stiffness_colors(paint) -> np.ndarray:
    """Display ramp for paint values: blue (flexible) -> green -> red (stiff), RGBA in 0..1."""
    p = np.clip(np.asarray(paint, dtype=np.float64), 0.0, 1.0)
    r = np.clip(2.0 * p - 1.0, 0.0, 1.0)
    b = np.clip(1.0 - 2.0 * p, 0.0, 1.0)
    g = 1.0 - r - b
    return np.stack([r, g, b, np.ones_like(p)], axis=1)
