"""Objects and Empties: modes, the Edit-Mode face selection, anchor Empties, world matrices and
scene membership."""

from __future__ import annotations

import contextlib

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Vector

from ..stiffness_map import loop_polygon_index
from .arrays import _get


@contextlib.contextmanager
def object_mode(context, obj):
    """Temporarily leave Edit Mode so mesh and vertex-group data are in sync."""
    mode = obj.mode
    if mode == "EDIT":
        bpy.ops.object.mode_set(mode="OBJECT")
    try:
        yield
    finally:
        if mode == "EDIT" and context.view_layer.objects.active == obj:
            bpy.ops.object.mode_set(mode="EDIT")


def selected_polygons(mesh) -> np.ndarray:
    return _get(mesh.polygons, "select", len(mesh.polygons), bool)


def polygon_centers_normals_areas(mesh):
    p = len(mesh.polygons)
    return (
        _get(mesh.polygons, "center", p, np.float32, 3).astype(np.float64),
        _get(mesh.polygons, "normal", p, np.float32, 3).astype(np.float64),
        _get(mesh.polygons, "area", p, np.float32).astype(np.float64),
    )


def selection_frame(obj, sel):
    """Vertices of the selected polygons, their area-weighted centroid and average normal in
    world space, and a radius for sizing the Empty."""
    mesh = obj.data
    centers, normals, areas = polygon_centers_normals_areas(mesh)
    w = areas[sel] / max(areas[sel].sum(), 1e-30)
    c_local = (centers[sel] * w[:, None]).sum(axis=0)
    n_local = (normals[sel] * areas[sel][:, None]).sum(axis=0)
    m = world_matrix(obj)
    c_world = (m @ np.append(c_local, 1.0))[:3]
    n_world = np.linalg.inv(m[:3, :3]).T @ n_local
    p = len(mesh.polygons)
    lv = _get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)
    starts = _get(mesh.polygons, "loop_start", p, np.int32)
    lp = loop_polygon_index(starts, _get(mesh.polygons, "loop_total", p, np.int32))
    verts = np.unique(lv[sel[lp]])
    radius = float(np.linalg.norm(centers[sel] - c_local, axis=1).max(initial=0.0))
    return verts, c_world, n_world, radius


def select_polygons_edit(obj, mask) -> None:
    """Select exactly the masked polygons; the object must be in Edit Mode. Goes through
    bmesh: writing edge selection through RNA segfaults Blender 5.0.1."""
    mask = np.asarray(mask, dtype=bool)
    bm = bmesh.from_edit_mesh(obj.data)
    for seq in (bm.verts, bm.edges, bm.faces):
        for elem in seq:
            elem.select = False
    bm.faces.ensure_lookup_table()
    for i in np.flatnonzero(mask):
        bm.faces[int(i)].select_set(True)
    bm.select_flush_mode()
    bmesh.update_edit_mesh(obj.data)


def activate(obj, view_layer=None) -> None:
    """Make obj the only selected object of the view layer and its active object."""
    layer = view_layer if view_layer is not None else bpy.context.view_layer
    for o in layer.objects:
        o.select_set(False)
    layer.objects.active = obj
    obj.select_set(True)


def create_empty(context, name, location, normal, size, near_obj):
    """Empty at ``location`` (world) with its Z axis along ``normal`` (world), linked into the
    mesh object's first collection and parented to the mesh object (keeping that world
    transform), so moving the object carries its anchors along."""
    empty = bpy.data.objects.new(name, None)
    empty.empty_display_type = "ARROWS"
    empty.empty_display_size = max(float(size), 1e-3)
    n = Vector(normal)
    rot = n.to_track_quat("Z", "Y").to_matrix().to_4x4() if n.length > 1e-12 else Matrix()
    m = Matrix.Translation(Vector(location)) @ rot
    coll = near_obj.users_collection[0] if near_obj.users_collection else context.collection
    coll.objects.link(empty)
    parent = near_obj.matrix_world
    if abs(parent.to_3x3().determinant()) > 1e-12:  # an object scaled to zero cannot parent
        empty.parent = near_obj
        empty.matrix_parent_inverse = parent.inverted()
    empty.matrix_basis = m
    empty.matrix_world = m  # right away, before the depsgraph evaluates the parenting
    return empty


def set_world_matrix(obj, m) -> None:
    """Place ``obj`` at world matrix ``m`` (4,4), parented or not."""
    obj.matrix_world = Matrix([list(r) for r in np.asarray(m, dtype=np.float64)])


def world_matrix(obj, depsgraph=None):
    """World matrix, evaluated in ``depsgraph`` if given. None if the object is not part of that
    depsgraph (e.g. an Empty disabled for renders, in a render's depsgraph)."""
    if depsgraph is not None:
        ev = obj.evaluated_get(depsgraph)
        if not ev.is_evaluated:
            return None
        obj = ev
    return world_matrices((obj,))[0]


def world_matrices(objs) -> np.ndarray:
    """(k,4,4) world matrices of ``objs`` (none None), read into one array: one array and no
    stacking per live update."""
    # Row by row: np.array(Matrix) goes through the sequence protocol entry by entry, 4-8x
    # slower (15 us against 3.5 us on bpy 4.5), and the live path reads k + 1 of these.
    rows = []
    for obj in objs:
        m = obj.matrix_world
        rows += (m[0][:], m[1][:], m[2][:], m[3][:])
    return np.array(rows, dtype=np.float64).reshape(-1, 4, 4)


def object_in_scene(obj, scene, members=None) -> bool:
    """True if ``obj`` is one of the scene's objects. ``members``: the scene's objects as a set,
    if the caller has it (``scene.objects.get`` is a linear search: ~25 us with 1000 objects)."""
    if obj is None:
        return False
    if members is not None:
        return obj in members  # bpy structs hash and compare by the pointer they wrap
    return scene.objects.get(obj.name) is obj
