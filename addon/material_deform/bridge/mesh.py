"""The mesh as the solvers see it: its topology as flat arrays, and the rest shape (the Basis
shape key when there are shape keys), read in bulk and compared bit for bit on live updates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BindError
from ..triangulation import flat_area, without_flat_triangles
from .arrays import _get, _raw_copy_from_key


@dataclass
class MeshArrays:
    """Flat topology of a mesh: triangles (via loop triangles) and polygon/loop/edge arrays."""

    rest: np.ndarray  # (n,3) float64 rest positions (Basis key if there are shape keys)
    tris: np.ndarray  # (m,3) int64
    tri_poly: np.ndarray  # (m,) polygon of each loop triangle
    loop_start: np.ndarray
    loop_total: np.ndarray
    loop_vert: np.ndarray
    loop_edge: np.ndarray
    edge_verts: np.ndarray  # (e,2)

    @property
    def n_polys(self) -> int:
        return len(self.loop_start)


def is_mesh(obj) -> bool:
    return obj is not None and obj.type == "MESH"


def reference_key(mesh):
    keys = mesh.shape_keys
    return None if keys is None else keys.reference_key


def _rest_source(mesh):
    """Where the rest shape lives: the reference (Basis) key if there are shape keys. Raises
    BindError when it does not hold one point per vertex (vertices added from a script after
    the keys were made), so nothing ever reads past its end."""
    ref = reference_key(mesh)
    if ref is None:
        return mesh.vertices
    if len(ref.data) != len(mesh.vertices):
        raise BindError(
            f"The mesh has {len(mesh.vertices)} vertices but its Basis shape key holds "
            f"{len(ref.data)}: vertices were added outside Edit Mode. Enter and leave Edit Mode "
            "to sync the shape keys, then Bind"
        )
    return ref.data


def rest_positions_f32(mesh) -> np.ndarray:
    """Exact stored rest coordinates (float32, as Blender keeps them)."""
    src = _rest_source(mesh)
    return _get(src, "co", len(src), np.float32, 3)


def rest_unchanged(mesh, expected: np.ndarray, buf: np.ndarray) -> bool:
    """True if the rest coordinates equal ``expected`` (n,3) float32 bit for bit. Runs on every
    live update, so the Basis is read in bulk (``buf``: a scratch array of the same shape)."""
    try:
        src = _rest_source(mesh)
    except BindError:
        return False
    if len(src) != len(expected):
        return False
    ref = reference_key(mesh)
    flat = buf.reshape(-1)
    if ref is None:
        mesh.vertices.foreach_get("co", flat)
    else:
        points = getattr(ref, "points", None)
        if points is not None:
            points.foreach_get("co", flat)
        elif not _raw_copy_from_key(ref, flat):
            ref.data.foreach_get("co", flat)
    return np.array_equal(buf, expected)


def rest_positions(mesh) -> np.ndarray:
    return rest_positions_f32(mesh).astype(np.float64)


def mesh_arrays(mesh) -> MeshArrays:
    """The mesh as arrays. Its triangles are Blender's tessellation, except in polygons where
    that holds a flat triangle (a collinear corner, on some Blender versions): those are
    triangulated without one (triangulation.without_flat_triangles)."""
    mesh.calc_loop_triangles()
    m = len(mesh.loop_triangles)
    n_loops = len(mesh.loops)
    p = len(mesh.polygons)
    a = MeshArrays(
        rest=rest_positions(mesh),
        tris=_get(mesh.loop_triangles, "vertices", m, np.int32, 3).astype(np.int64),
        tri_poly=_get(mesh.loop_triangles, "polygon_index", m, np.int32).astype(np.int64),
        loop_start=_get(mesh.polygons, "loop_start", p, np.int32).astype(np.int64),
        loop_total=_get(mesh.polygons, "loop_total", p, np.int32).astype(np.int64),
        loop_vert=_get(mesh.loops, "vertex_index", n_loops, np.int32).astype(np.int64),
        loop_edge=_get(mesh.loops, "edge_index", n_loops, np.int32).astype(np.int64),
        edge_verts=_get(mesh.edges, "vertices", len(mesh.edges), np.int32, 2).astype(np.int64),
    )
    a.tris = without_flat_triangles(
        a.rest, a.tris, a.tri_poly, a.loop_start, a.loop_total, a.loop_vert, flat_area(a.rest)
    )
    return a


def counts(mesh) -> tuple[int, int, int, int]:
    """Cheap topology signature checked on every live update."""
    return len(mesh.vertices), len(mesh.edges), len(mesh.loops), len(mesh.polygons)
