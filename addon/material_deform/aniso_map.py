"""Pure numpy helpers (no bpy) for issue 4: anisotropic bending stiffness (paper Sec. 5),
anisotropy axes from an Empty, region-of-interest masks (Sec. 7) and moving learned stiffness
(Sec. 6) between the solver's triangles / dual edges and Blender's polygons / edges / vertices.
"""

from __future__ import annotations

import numpy as np

from . import stiffness_map as sm

AXES = ("X", "Y", "Z")
OUTPUT_KEY = "Material Deform"  # the add-on's own shape keys (kept in sync with bridge)
BAKE_PREFIX = "MD Bake "


def axis_group_names(base: str) -> tuple[str, str, str]:
    """Vertex groups painted per rotation axis: 'Stiffness' -> 'Stiffness X', 'Stiffness Y'..."""
    return tuple(f"{base} {a}" for a in AXES)


def axes_from_matrices(m_obj, m_axes) -> np.ndarray:
    """Anisotropy axes in the mesh's local coordinates: the rotation part of
    ``inv(M_obj) @ M_axes`` (closest rotation, so object/Empty scale and shear are ignored).
    Columns are the x, y, z axes."""
    m = np.linalg.solve(np.asarray(m_obj, dtype=np.float64), np.asarray(m_axes, dtype=np.float64))
    return nearest_rotation(m[:3, :3])


def nearest_rotation(a) -> np.ndarray:
    """Closest rotation to a 3x3 matrix (polar part via SVD; a mirror is flipped back to a
    right-handed frame). Also re-orthonormalises axes stored in float32."""
    a = np.asarray(a, dtype=np.float64)
    if not np.isfinite(a).all() or abs(np.linalg.det(a)) < 1e-12:
        raise ValueError("the axes Empty's orientation is degenerate (zero scale?)")
    u, _s, vt = np.linalg.svd(a)
    r = u @ vt
    if np.linalg.det(r) < 0:  # a mirrored Empty: keep right-handed axes
        u[:, -1] *= -1
        r = u @ vt
    return r


def per_axis_face_paint(vertex_paint3, loop_vert, loop_poly, n_polys: int) -> np.ndarray:
    """(n,3) per-vertex paint -> (P,3) per-polygon paint (mean over corners, per axis)."""
    vp = np.asarray(vertex_paint3, dtype=np.float64)
    return np.stack(
        [sm.face_paint_from_vertex(vp[:, c], loop_vert, loop_poly, n_polys) for c in range(3)],
        axis=1,
    )


def per_axis_edge_stiffness(face_stiffness3, loop_edge, loop_poly, n_edges: int) -> np.ndarray:
    """(P,3) per-polygon stiffness -> (e,3) per-edge bending stiffness (mean of the adjacent
    polygons, per axis; the isotropic rule applied to each axis)."""
    f = np.asarray(face_stiffness3, dtype=np.float64)
    return np.stack(
        [sm.edge_stiffness(f[:, c], loop_edge, loop_poly, n_edges) for c in range(3)], axis=1
    )


def polygon_mean_of_edges(edge_values, loop_edge, loop_poly, n_polys: int) -> np.ndarray:
    """Per-polygon mean of its edges' values ((e,) or (e,k))."""
    v = np.asarray(edge_values, dtype=np.float64)
    v2 = v.reshape(len(v), -1)
    le = np.asarray(loop_edge)
    out = np.stack(
        [sm.polygon_mean(v2[le, c], loop_poly, n_polys) for c in range(v2.shape[1])], axis=1
    )
    return out.reshape((n_polys,) + v.shape[1:])


def dual_edge_bend_axes(
    tris, dual, tri_poly, edge_verts, edge_phi3, loop_edge, loop_poly, n_polys: int
) -> np.ndarray:
    """(E,3) bending stiffness per dual edge from (e,3) per Blender edge. A dual edge inside a
    polygon (between two triangles of one quad / n-gon) has no Blender edge: it gets the mean
    of that polygon's edges."""
    phi = np.asarray(edge_phi3, dtype=np.float64)
    inner = polygon_mean_of_edges(phi, loop_edge, loop_poly, n_polys)
    cols = [
        sm.dual_edge_bend(tris, dual, tri_poly, inner[:, c], edge_verts, phi[:, c])
        for c in range(3)
    ]
    return np.stack(cols, axis=1)


def dual_values_to_edges(values, dual_edge, n_edges: int, fill: float = 1.0):
    """Per-dual-edge values ((E,) or (E,k)) -> per Blender edge (mean over the dual edges that
    cross it); edges no dual edge crosses (boundary, loose) get ``fill``. Also returns the mask
    of edges that received a value."""
    v = np.asarray(values, dtype=np.float64)
    v2 = v.reshape(len(v), -1)
    de = np.asarray(dual_edge, dtype=np.int64)
    use = de >= 0
    cnt = np.bincount(de[use], minlength=n_edges)
    out = np.full((n_edges, v2.shape[1]), float(fill))
    has = cnt > 0
    for c in range(v2.shape[1]):
        s = np.bincount(de[use], weights=v2[use, c], minlength=n_edges)
        out[has, c] = s[has] / cnt[has]
    return out.reshape((n_edges,) + v.shape[1:]), has


def triangle_to_polygon_stiffness(tri_values, tri_poly, n_polys: int) -> np.ndarray:
    """Per-triangle stiffness -> per polygon: geometric mean over the polygon's triangles (the
    paint-space mean the add-on uses everywhere)."""
    lv = np.log(np.maximum(np.asarray(tri_values, dtype=np.float64), 1e-300))
    return np.exp(sm.polygon_mean(lv, np.asarray(tri_poly, dtype=np.int64), n_polys))


def edge_paint_to_vertices(edge_paint, edge_verts, edge_mask, n_vertices: int, fill: float = 1.0):
    """Per-edge paint ((e,) or (e,k)) -> per vertex: mean over the vertex's edges in
    ``edge_mask``; vertices without such an edge get ``fill``."""
    p = np.asarray(edge_paint, dtype=np.float64)
    p2 = p.reshape(len(p), -1)
    ev = np.asarray(edge_verts, dtype=np.int64).reshape(-1, 2)[edge_mask]
    vals = p2[edge_mask]
    idx = ev.ravel()
    cnt = np.bincount(idx, minlength=n_vertices)
    out = np.full((n_vertices, p2.shape[1]), float(fill))
    has = cnt > 0
    for c in range(p2.shape[1]):
        s = np.bincount(idx, weights=np.repeat(vals[:, c], 2), minlength=n_vertices)
        out[has, c] = s[has] / cnt[has]
    return out.reshape((n_vertices,) + p.shape[1:])


def face_paint_to_vertices(face_paint, loop_vert, loop_poly, n_vertices: int, fill: float = 1.0):
    """Per-polygon paint -> per vertex: mean over the polygons using the vertex."""
    fp = np.asarray(face_paint, dtype=np.float64)
    lv = np.asarray(loop_vert, dtype=np.int64)
    cnt = np.bincount(lv, minlength=n_vertices)
    s = np.bincount(lv, weights=fp[np.asarray(loop_poly)], minlength=n_vertices)
    out = np.full(n_vertices, float(fill))
    out[cnt > 0] = s[cnt > 0] / cnt[cnt > 0]
    return out


def learn_key_names(keys, name_filter: str = "", output: str = OUTPUT_KEY) -> list[str]:
    """Shape keys used as example poses: ``keys`` is a list of (name, muted, is_reference).
    Takes every key except the reference (Basis), muted keys (the mute checkbox in the shape
    key list deselects a key) and the add-on's own output (named ``output``, it may have been
    renamed) and bake keys, whose name contains ``name_filter`` (case-insensitive; empty =
    all)."""
    f = name_filter.strip().lower()
    out = []
    for name, muted, is_ref in keys:
        if is_ref or muted or name in (output, OUTPUT_KEY) or name.startswith(BAKE_PREFIX):
            continue
        if f and f not in name.lower():
            continue
        out.append(name)
    return out
