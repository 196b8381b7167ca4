"""The only module that reads or writes Blender data (meshes, groups, attributes, shape keys,
Empties). Everything here converts between bpy and flat numpy arrays."""

from __future__ import annotations

import contextlib
import ctypes
from dataclasses import dataclass

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Vector

from .errors import BindError
from .stiffness_map import loop_polygon_index

OUTPUT_KEY = "Material Deform"
BAKE_PREFIX = "MD Bake "
SHEAR_ATTR = "md_shear_stiffness"
BEND_ATTR = "md_bend_stiffness"
BEND_AXES_ATTR = "md_bend_stiffness_xyz"  # anisotropic: one bending stiffness per axis x, y, z
DISPLAY_ATTR = "md_stiffness_display"


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


def _get(seq, attr, n, dtype, width=1):
    out = np.empty(n * width, dtype=dtype)
    seq.foreach_get(attr, out)
    return out.reshape(n, width) if width > 1 else out


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


def attribute_kind(mesh, name):
    """(domain, data_type) of a mesh attribute, None if there is none of that name."""
    attr = mesh.attributes.get(name)
    return None if attr is None else (attr.domain, attr.data_type)


def rest_positions(mesh) -> np.ndarray:
    return rest_positions_f32(mesh).astype(np.float64)


def mesh_arrays(mesh) -> MeshArrays:
    mesh.calc_loop_triangles()
    m = len(mesh.loop_triangles)
    n_loops = len(mesh.loops)
    p = len(mesh.polygons)
    return MeshArrays(
        rest=rest_positions(mesh),
        tris=_get(mesh.loop_triangles, "vertices", m, np.int32, 3).astype(np.int64),
        tri_poly=_get(mesh.loop_triangles, "polygon_index", m, np.int32).astype(np.int64),
        loop_start=_get(mesh.polygons, "loop_start", p, np.int32).astype(np.int64),
        loop_total=_get(mesh.polygons, "loop_total", p, np.int32).astype(np.int64),
        loop_vert=_get(mesh.loops, "vertex_index", n_loops, np.int32).astype(np.int64),
        loop_edge=_get(mesh.loops, "edge_index", n_loops, np.int32).astype(np.int64),
        edge_verts=_get(mesh.edges, "vertices", len(mesh.edges), np.int32, 2).astype(np.int64),
    )


def counts(mesh) -> tuple[int, int, int, int]:
    """Cheap topology signature checked on every live update."""
    return len(mesh.vertices), len(mesh.edges), len(mesh.loops), len(mesh.polygons)


# --- vertex groups / attributes -------------------------------------------------------------


def vertex_group_weights(obj, names) -> dict[str, np.ndarray]:
    """Weights of the named vertex groups, one pass over the vertices. Missing groups are left
    out of the result; vertices not in a group get -1 so membership (>= 0) stays visible."""
    n = len(obj.data.vertices)
    index = {}
    for name in names:
        vg = obj.vertex_groups.get(name)
        if vg is not None:
            index[vg.index] = name
    out = {name: np.full(n, -1.0) for name in index.values()}
    if not index:
        return out
    for v in obj.data.vertices:
        for g in v.groups:
            name = index.get(g.group)
            if name is not None:
                out[name][v.index] = g.weight
    return out


def has_vertex_group(obj, name) -> bool:
    return obj.vertex_groups.get(name) is not None


def color_attribute_vertex_rgba(mesh, name):
    """Per-vertex sRGB colour of a colour attribute (corner colours averaged per vertex);
    None if the attribute does not exist."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        return None
    n = len(attr.data)
    field = "color_srgb" if hasattr(attr.data[0] if n else None, "color_srgb") else "color"
    rgba = _get(attr.data, field, n, np.float32, 4).astype(np.float64)
    if attr.domain == "POINT":
        return rgba
    nv = len(mesh.vertices)
    lv = _get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)
    out = np.zeros((nv, 4))
    for c in range(4):
        out[:, c] = np.bincount(lv, weights=rgba[:, c], minlength=nv)
    cnt = np.bincount(lv, minlength=nv)
    return out / np.maximum(cnt, 1)[:, None]


def color_attribute_writable(obj, name) -> bool:
    """True if ``name`` is a colour attribute or free (vertex groups share the attribute
    namespace in Blender 4+, so a group of that name blocks a new colour attribute)."""
    mesh = obj.data
    if mesh.color_attributes.get(name) is not None:
        return True
    return mesh.attributes.get(name) is None and obj.vertex_groups.get(name) is None


def write_color_attribute_vertex_rgb(mesh, name, rgb) -> None:
    """Write per-vertex sRGB colours (n,3) into a colour attribute, the inverse of
    :func:`color_attribute_vertex_rgba` (a corner attribute gets its vertex's colour on every
    corner; alpha 1). Creates a point FLOAT_COLOR attribute if there is none."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        attr = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
        if attr is None:
            raise ValueError(f"cannot create color attribute '{name}'")
    rgba = np.ones((len(mesh.vertices), 4), dtype=np.float32)
    rgba[:, :3] = np.clip(rgb, 0.0, 1.0)
    if attr.domain != "POINT":
        rgba = rgba[_get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)]
    n = len(attr.data)
    field = "color_srgb" if n and hasattr(attr.data[0], "color_srgb") else "color"
    attr.data.foreach_set(field, rgba.ravel())
    mesh.update()


def _write_attribute(mesh, name, domain, data_type, field, values) -> None:
    """(Re)create attribute ``name`` with this domain and type if it differs, then bulk-write."""
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.domain != domain or attr.data_type != data_type):
        mesh.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = mesh.attributes.new(name, data_type, domain)
    attr.data.foreach_set(field, np.asarray(values, dtype=np.float32).ravel())
    mesh.update()


def write_float_attribute(mesh, name, domain, values) -> None:
    """values: (n,) for the n elements of ``domain``."""
    _write_attribute(mesh, name, domain, "FLOAT", "value", values)


def read_float_attribute(mesh, name, domain, n):
    attr = mesh.attributes.get(name)
    if attr is None or attr.domain != domain or attr.data_type != "FLOAT" or len(attr.data) != n:
        return None
    return _get(attr.data, "value", n, np.float32).astype(np.float64)


def write_vector_attribute(mesh, name, domain, values) -> None:
    """values: (n,3) for the n elements of ``domain``."""
    _write_attribute(mesh, name, domain, "FLOAT_VECTOR", "vector", values)


def read_vector_attribute(mesh, name, domain, n):
    attr = mesh.attributes.get(name)
    if (
        attr is None
        or attr.domain != domain
        or attr.data_type != "FLOAT_VECTOR"
        or len(attr.data) != n
    ):
        return None
    return _get(attr.data, "vector", n, np.float32, 3).astype(np.float64)


def set_vertex_group_weights(obj, name, weights) -> str:
    """Create or overwrite a vertex group with one weight per vertex (all vertices)."""
    vg = obj.vertex_groups.get(name)
    if vg is None:
        vg = obj.vertex_groups.new(name=name)
    w = np.clip(np.asarray(weights, dtype=np.float32), 0.0, 1.0)  # weights are float32
    values, inverse = np.unique(w, return_inverse=True)
    order = np.argsort(inverse, kind="stable")  # one add() per distinct weight
    bounds = np.searchsorted(inverse[order], np.arange(len(values) + 1))
    for k, value in enumerate(values.tolist()):
        vg.add(order[bounds[k] : bounds[k + 1]].tolist(), value, "REPLACE")
    return vg.name


def shape_key_info(obj) -> list[tuple[str, bool, bool]]:
    """(name, muted, is the reference key) of every shape key, in list order."""
    keys = obj.data.shape_keys
    if keys is None:
        return []
    ref = keys.reference_key
    return [(kb.name, bool(kb.mute), kb == ref) for kb in keys.key_blocks]


def shape_key_positions(obj, name) -> np.ndarray:
    """Absolute coordinates stored in a shape key (float64)."""
    kb = obj.data.shape_keys.key_blocks[name]
    return _get(kb.data, "co", len(kb.data), np.float32, 3).astype(np.float64)


def active_color_name(mesh) -> str:
    attr = getattr(mesh.color_attributes, "active_color", None)
    return "" if attr is None else attr.name


def set_active_color(mesh, name) -> bool:
    """Make colour attribute ``name`` the active one (the one Vertex Paint paints and Solid >
    Attribute shading shows). False if there is none of that name."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        return False
    with contextlib.suppress(AttributeError, TypeError):
        mesh.color_attributes.active_color = attr
    with contextlib.suppress(AttributeError, TypeError):
        mesh.attributes.active_color = attr
    return True


def write_corner_colors(mesh, name, corner_rgba) -> None:
    """Colours (loops,4) as a corner colour attribute (created if missing), made active so
    Attribute viewport shading shows it."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        attr = mesh.color_attributes.new(name, "BYTE_COLOR", "CORNER")
    rgba = np.asarray(corner_rgba, dtype=np.float32)
    field = "color_srgb" if len(attr.data) and hasattr(attr.data[0], "color_srgb") else "color"
    attr.data.foreach_set(field, rgba.ravel())
    set_active_color(mesh, name)
    mesh.update()


def remove_attribute(mesh, name) -> bool:
    attr = mesh.attributes.get(name)
    if attr is None:
        return False
    mesh.attributes.remove(attr)
    mesh.update()
    return True


def create_color_attribute(mesh, name, rgba=(0.0, 0.0, 0.0, 1.0)) -> None:
    """A point colour attribute filled with ``rgba``, made active for Vertex Paint."""
    attr = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
    if attr is None:
        raise BindError(f"Cannot create color attribute '{name}'")
    attr.data.foreach_set("color", np.tile(np.asarray(rgba, np.float32), len(attr.data)))
    set_active_color(mesh, name)
    mesh.update()


def _view3d_spaces(context):
    wm = getattr(context, "window_manager", None)
    for win in wm.windows if wm is not None else ():
        for area in win.screen.areas:
            if area.type == "VIEW_3D":
                for space in area.spaces:
                    if space.type == "VIEW_3D":
                        yield space


def viewport_shading(context) -> str:
    """'TYPE COLOR_TYPE' of the first 3D viewport, '' if there is none."""
    for space in _view3d_spaces(context):
        return f"{space.shading.type} {space.shading.color_type}"
    return ""


def set_viewport_shading(context, shading: str) -> int:
    """Set every 3D viewport to 'TYPE COLOR_TYPE'; returns how many were set."""
    kind, _, color = shading.partition(" ")
    n = 0
    for space in _view3d_spaces(context):
        with contextlib.suppress(TypeError, ValueError):
            space.shading.type = kind
            if color:
                space.shading.color_type = color
            n += 1
    return n


def show_attribute_shading(context) -> bool:
    """Switch open 3D viewports to Solid + Attribute colour. False if there is none."""
    return set_viewport_shading(context, "SOLID VERTEX") > 0


# --- selection, groups, Empties ---------------------------------------------------------------


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


def set_vertex_group(obj, name, vertex_indices):
    vg = obj.vertex_groups.get(name)
    if vg is None:
        vg = obj.vertex_groups.new(name=name)
    vg.add([int(i) for i in vertex_indices], 1.0, "REPLACE")
    return vg.name


def ensure_vertex_group(obj, name) -> bool:
    """Create an empty vertex group ``name`` if there is none; True if created."""
    if obj.vertex_groups.get(name) is not None:
        return False
    obj.vertex_groups.new(name=name)
    return True


def set_active_vertex_group(obj, name) -> None:
    vg = obj.vertex_groups.get(name)
    if vg is not None:
        obj.vertex_groups.active_index = vg.index


def unique_group_name(obj, base) -> str:
    name, i = base, 1
    while obj.vertex_groups.get(name) is not None:
        name = f"{base}.{i:03d}"
        i += 1
    return name


def activate(obj, view_layer=None) -> None:
    """Make obj the only selected object of the view layer and its active object."""
    layer = view_layer if view_layer is not None else bpy.context.view_layer
    for o in layer.objects:
        o.select_set(False)
    layer.objects.active = obj
    obj.select_set(True)


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


def object_in_scene(obj, scene, members=None) -> bool:
    """True if ``obj`` is one of the scene's objects. ``members``: the scene's objects as a set,
    if the caller has it (``scene.objects.get`` is a linear search: ~25 us with 1000 objects)."""
    if obj is None:
        return False
    if members is not None:
        return obj in members  # bpy structs hash and compare by the pointer they wrap
    return scene.objects.get(obj.name) is obj


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


# --- shape keys -------------------------------------------------------------------------------


def ensure_output_key(obj, name=OUTPUT_KEY):
    """Return (key_block, created_basis). Creates a Basis (copy of the mesh) if there were no
    shape keys, so the rest shape itself is never written to. Raises BindError if the key of
    that name is the reference key (the Basis was removed)."""
    created = False
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
        created = True
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(name)
    if kb is not None and kb == keys.reference_key:
        raise BindError(
            f"Shape key '{name}' is the reference (Basis) key: rename it, or add a Basis above "
            "it, then Bind"
        )
    if kb is None:
        kb = obj.shape_key_add(name=name, from_mix=False)
        # keep edits going to the Basis, not to the output
        obj.active_shape_key_index = 0
    kb.value = 1.0
    kb.mute = False
    return kb, created


def output_key(obj, name=OUTPUT_KEY, pointer: int = 0):
    """The output key block: the one named ``name``, else the one at ``pointer`` (the block
    the session last wrote; found after a rename). None if neither exists."""
    keys = obj.data.shape_keys
    if keys is None:
        return None
    kb = keys.key_blocks.get(name)
    if kb is None and pointer:
        kb = next((k for k in keys.key_blocks if k.as_pointer() == pointer), None)
    return kb


POSE_RECORD = "material_deform_pose"  # custom property of the Key: what the output key holds


def key_record(obj) -> str:
    """The record the session wrote with the output key ("" if none): saved in the .blend and
    restored by undo together with the key's coordinates."""
    keys = obj.data.shape_keys
    return "" if keys is None else str(keys.get(POSE_RECORD, ""))


def set_key_record(obj, text: str) -> None:
    keys = obj.data.shape_keys
    if keys is not None:
        keys[POSE_RECORD] = text


def is_reference_key(obj, kb) -> bool:
    keys = obj.data.shape_keys
    return keys is not None and kb == keys.reference_key


def write_key(obj, kb, positions) -> None:
    """Hot path: one bulk copy into the shape key, then the Key tagged for re-evaluation.

    ``KeyBlock.data.foreach_set`` goes item by item (~8 ms for 25k vertices), too slow for
    live use. Blender 4.1+ has ``KeyBlock.points`` with a bulk path; older versions get a
    memmove into the key's float[3] array after checking that it really is one contiguous
    block of the expected size, else the slow path.
    """
    flat = np.ascontiguousarray(positions, dtype=np.float32).ravel()
    points = getattr(kb, "points", None)
    if points is not None:
        points.foreach_set("co", flat)
    elif not _raw_copy_into_key(kb, flat):
        kb.data.foreach_set("co", flat)
    # The RNA update of the points: a copy-on-write tag of the Key alone, which re-evaluates the
    # geometry (the bulk write does the same itself from Blender 4.3 on; before, nothing does).
    # Not Key.update_tag(): that legacy tag also makes Blender flush visibility flags over the
    # whole depsgraph, +1 to +1.5 ms per update with 1000 other objects in the scene
    # (docs/performance.md, session 14). Also spares a copy-on-write of the whole mesh.
    kb.data.update()


def _key_array(kb, size: int) -> int:
    """Address of the key block's float[3] array if it is one contiguous block of ``size``
    floats (what Blender < 4.1 keeps), else 0."""
    data = kb.data
    n = len(data)
    if n == 0 or size != 3 * n:
        return 0
    first, last = data[0].as_pointer(), data[n - 1].as_pointer()
    return first if first != 0 and last - first == 12 * (n - 1) else 0


def _raw_copy_into_key(kb, flat) -> bool:
    if flat.size == 0:
        return len(kb.data) == 0
    addr = _key_array(kb, flat.size)
    if addr:
        ctypes.memmove(addr, flat.ctypes.data, flat.nbytes)
    return bool(addr)


def read_key_into(kb, flat) -> None:
    """A key block's coordinates into ``flat`` ((3n,) float32) by the fastest route there is
    (the bulk ``points`` of Blender >= 4.1, raw memory before, else ``data``): live checks."""
    points = getattr(kb, "points", None)
    if points is not None:
        points.foreach_get("co", flat)
    elif not _raw_copy_from_key(kb, flat):
        kb.data.foreach_get("co", flat)


def _raw_copy_from_key(kb, flat) -> bool:
    if flat.size == 0:
        return len(kb.data) == 0
    addr = _key_array(kb, flat.size)
    if addr:
        ctypes.memmove(flat.ctypes.data, addr, flat.nbytes)
    return bool(addr)


def remove_output(obj, remove_basis: bool, name=OUTPUT_KEY, pointer: int = 0) -> None:
    kb = output_key(obj, name, pointer)
    if kb is not None and not is_reference_key(obj, kb):  # never the rest shape itself
        obj.shape_key_remove(kb)
    keys = obj.data.shape_keys
    if remove_basis and keys is not None and len(keys.key_blocks) == 1:
        # removing the last (reference) key writes its coordinates back to the mesh verbatim
        obj.shape_key_remove(keys.key_blocks[0])


def bake_key(obj, frame, positions) -> str:
    name = f"{BAKE_PREFIX}{frame:04d}"
    keys = obj.data.shape_keys
    old = keys.key_blocks.get(name) if keys is not None else None
    if old is not None:
        obj.shape_key_remove(old)
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.data.foreach_set("co", np.asarray(positions, dtype=np.float32).ravel())
    for f, v in ((frame - 1, 0.0), (frame, 1.0), (frame + 1, 0.0)):
        kb.value = v
        kb.keyframe_insert("value", frame=f)
    obj.active_shape_key_index = 0
    return name


def set_output_value(obj, value: float, name=OUTPUT_KEY) -> None:
    kb = output_key(obj, name)
    if kb is not None:
        kb.value = value


def _fcurves(id_data):
    """The F-curves animating ``id_data`` (slotted actions in 4.4+), None without any."""
    ad = id_data.animation_data
    if ad is None or ad.action is None:
        return None
    slot = getattr(ad, "action_slot", None)
    if slot is not None:
        try:
            from bpy_extras.anim_utils import action_get_channelbag_for_slot
        except ImportError:
            pass
        else:
            bag = action_get_channelbag_for_slot(ad.action, slot)
            return None if bag is None else bag.fcurves
    return getattr(ad.action, "fcurves", None)


def bake_key_names(obj) -> list[str]:
    keys = obj.data.shape_keys
    if keys is None:
        return []
    return [kb.name for kb in keys.key_blocks if kb.name.startswith(BAKE_PREFIX)]


def remove_bake_keys(obj) -> int:
    """Remove the baked shape keys and their keyframes; returns how many keys went."""
    names = bake_key_names(obj)
    if not names:
        return 0
    keys = obj.data.shape_keys
    fcurves = _fcurves(keys)
    if fcurves is not None:
        paths = {f'key_blocks["{n}"].value' for n in names}
        for fc in [fc for fc in fcurves if fc.data_path in paths]:
            fcurves.remove(fc)
        if len(fcurves) == 0:
            keys.animation_data.action = None  # nothing else animated: no empty action left
    for n in names:
        obj.shape_key_remove(keys.key_blocks[n])
    obj.active_shape_key_index = 0
    return len(names)


CACHE_MODIFIER = "Material Deform Cache"


def cache_modifier(obj):
    mod = obj.modifiers.get(CACHE_MODIFIER)
    return mod if mod is not None and mod.type == "MESH_CACHE" else None


def add_cache_modifier(obj, filepath: str, frame_start: int):
    """A Mesh Cache modifier at the top of the stack reading ``filepath`` (.pc2), frame
    ``frame_start`` = the file's first sample; it replaces the shape-key result exactly."""
    mod = cache_modifier(obj) or obj.modifiers.new(CACHE_MODIFIER, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = filepath
    mod.play_mode = "SCENE"
    mod.time_mode = "FRAME"
    mod.frame_start = float(frame_start)
    mod.frame_scale = 1.0
    mod.deform_mode = "OVERWRITE"
    mod.interpolation = "LINEAR"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"  # the file is in the mesh's own axes
    index = list(obj.modifiers).index(mod)
    if index:
        if hasattr(obj.modifiers, "move"):  # 4.0+
            obj.modifiers.move(index, 0)
        else:
            with bpy.context.temp_override(object=obj, active_object=obj):
                bpy.ops.object.modifier_move_to_index(modifier=mod.name, index=0)
    return mod


def remove_cache_modifier(obj) -> bool:
    mod = cache_modifier(obj)
    if mod is None:
        return False
    obj.modifiers.remove(mod)
    return True


def abspath(path: str) -> str:
    return bpy.path.abspath(path)


def clean_name(name: str) -> str:
    return bpy.path.clean_name(name)


def blend_saved() -> bool:
    return bool(bpy.data.filepath)


def frame_set(scene, frame) -> None:
    scene.frame_set(frame)


def status(context, text) -> None:
    ws = getattr(context, "workspace", None)
    if ws is not None:
        with contextlib.suppress(Exception):
            ws.status_text_set(text)


def redraw(context) -> None:
    """Draw the window now, so the status text set inside a long operator shows before the
    operator returns (Blender only redraws between events). Nothing in background mode."""
    if bpy.app.background or getattr(context, "window", None) is None:
        return
    with contextlib.suppress(Exception):
        bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)


def evaluated_depsgraph_from_scene(scene):
    """Depsgraph of the current view layer (the one frame_set just evaluated)."""
    return bpy.context.evaluated_depsgraph_get()
