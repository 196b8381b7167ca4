"""Triangles of a polygon without flat ones (no bpy). Blender's own tessellation of an n-gon
with collinear corners (a cylinder cap with a vertex in the middle of an edge) can hold a
triangle of zero area, or of float32 round-off's area (a sliver whose cotangent weights blow
up), depending on the Blender version; such polygons are triangulated again here by ear
clipping that never cuts a flat ear, so the same mesh binds, and alike, on every version."""

from __future__ import annotations

import numpy as np

# Flat: a triangle whose height is below this part of its longest side. Round-off in float32
# coordinates leaves collinear corners about 1e-7 of a side apart; real thin triangles are far
# thicker than this.
FLAT_RATIO = 1e-4


def flat_area(rest: np.ndarray) -> float:
    """Triangles of at most this area (the unit of ``rest`` (n,3), squared) count as flat:
    a 1e-12 part of the squared bounding-box diagonal."""
    diag = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(rest) else 0.0
    return 1e-12 * max(diag, 1e-30) ** 2


def _ear_area(p2: np.ndarray, a: int, b: int, c: int) -> float:
    (ax, ay), (bx, by), (cx, cy) = p2[a], p2[b], p2[c]
    return 0.5 * ((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))


def _flat(p2: np.ndarray, corners, area: float, min_area: float) -> bool:
    a, b, c = (p2[i] for i in corners)
    longest = max(np.sum((a - b) ** 2), np.sum((b - c) ** 2), np.sum((c - a) ** 2))
    return not area > max(min_area, 0.5 * FLAT_RATIO * longest)


def _inside(p2: np.ndarray, a: int, b: int, c: int, q: int) -> bool:
    """q in the closed triangle a, b, c (counter-clockwise)."""
    return min(_ear_area(p2, a, b, q), _ear_area(p2, b, c, q), _ear_area(p2, c, a, q)) >= 0.0


def polygon_triangles(points: np.ndarray, min_area: float) -> np.ndarray | None:
    """Triangles (k-2, 3) of the polygon whose corners are ``points`` (k,3), in order, as
    indices into ``points`` and in the polygon's winding, each of area above ``min_area``
    (same unit as points, squared) and not flat (FLAT_RATIO); None if there is no such
    triangulation by ear clipping
    (the polygon itself is degenerate). The ear cut at each step is the fattest one (largest
    area over squared perimeter), which keeps slivers out where it can."""
    k = len(points)
    p = np.asarray(points, dtype=np.float64)
    # Newell's normal: the polygon runs counter-clockwise in the plane it spans
    nxt = np.roll(p, -1, axis=0)
    normal = np.array(
        [
            np.sum((p[:, 1] - nxt[:, 1]) * (p[:, 2] + nxt[:, 2])),
            np.sum((p[:, 2] - nxt[:, 2]) * (p[:, 0] + nxt[:, 0])),
            np.sum((p[:, 0] - nxt[:, 0]) * (p[:, 1] + nxt[:, 1])),
        ]
    )
    length = np.linalg.norm(normal)
    if not length > 0.0:
        return None
    normal /= length
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    p2 = np.stack([(p - p[0]) @ u, (p - p[0]) @ v], axis=1)
    left = list(range(k))
    out = []
    while len(left) > 3:
        best, best_quality = None, -1.0
        n = len(left)
        for j in range(n):
            a, b, c = left[j - 1], left[j], left[(j + 1) % n]
            area = _ear_area(p2, a, b, c)
            if _flat(p2, (a, b, c), area, min_area):
                continue  # flat, or a reflex corner (negative area)
            if any(_inside(p2, a, b, c, q) for q in left if q not in (a, b, c)):
                continue
            perimeter = sum(np.linalg.norm(p2[x] - p2[y]) for x, y in ((a, b), (b, c), (c, a)))
            quality = area / perimeter**2
            if quality > best_quality:
                best, best_quality = j, quality
        if best is None:
            return None
        out.append((left[best - 1], left[best], left[(best + 1) % n]))
        del left[best]
    if _flat(p2, left, _ear_area(p2, *left), min_area):
        return None
    out.append(tuple(left))
    return np.array(out, dtype=np.int64)


def without_flat_triangles(
    rest: np.ndarray,
    tris: np.ndarray,
    tri_poly: np.ndarray,
    loop_start: np.ndarray,
    loop_total: np.ndarray,
    loop_vert: np.ndarray,
    min_area: float,
) -> np.ndarray:
    """``tris`` (m,3) with the triangles of every polygon that holds a flat one (area at most
    ``min_area``, or FLAT_RATIO) replaced by :func:`polygon_triangles` of it, in the same rows
    (same polygon per row). Polygons that cannot be triangulated so keep theirs (the mesh check
    refuses those of zero area)."""
    a, b, c = (rest[tris[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max([np.sum((a - b) ** 2, 1), np.sum((b - c) ** 2, 1), np.sum((c - a) ** 2, 1)], 0)
    flat = area <= np.maximum(min_area, 0.5 * FLAT_RATIO * longest)
    if not flat.any():
        return tris
    out = tris.copy()
    for poly in np.unique(tri_poly[flat]):
        verts = loop_vert[loop_start[poly] : loop_start[poly] + loop_total[poly]]
        local = polygon_triangles(rest[verts], min_area)
        rows = np.flatnonzero(tri_poly == poly)
        if local is not None and len(local) == len(rows):
            out[rows] = verts[local]
    return out
