"""Scene builders and measurements shared by the Blender tests (tests may use bpy freely)."""

import math

import bpy
import numpy as np
import pytest


def tube(name="Bar", rings=21, length=4.0, radius=0.5, sides=8, square=True):
    """A bar along Z: quads around, one n-gon cap at each end (polygons 0 and 1)."""
    verts, faces = [], []
    for r in range(rings):
        z = -length / 2 + length * r / (rings - 1)
        for s in range(sides):
            a = 2 * math.pi * s / sides + math.pi / sides
            if square:
                c, d = math.cos(a), math.sin(a)
                m = max(abs(c), abs(d))
                verts.append((radius * c / m, radius * d / m, z))
            else:
                verts.append((radius * math.cos(a), radius * math.sin(a), z))
    faces.append(tuple(reversed(range(sides))))  # bottom cap
    faces.append(tuple(range((rings - 1) * sides, rings * sides)))  # top cap
    for r in range(rings - 1):
        for s in range(sides):
            a, b = r * sides + s, r * sides + (s + 1) % sides
            faces.append((a, b, b + sides, a + sides))
    return mesh_object(name, verts, faces)


def mesh_object(name, verts, faces):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    activate(obj)
    return obj


def activate(obj):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def select_faces(obj, pred):
    """Select exactly the polygons for which pred(polygon) is true; leaves Edit Mode on.
    (The add-on's bmesh route: writing edge selection through RNA segfaults Blender 5.0.1.)"""
    from material_deform.bridge import select_polygons_edit

    activate(obj)
    if obj.mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")
    mask = [bool(pred(p)) for p in obj.data.polygons]
    bpy.ops.object.mode_set(mode="EDIT")
    select_polygons_edit(obj, mask)


def add_anchor(obj, pred, mode="POSITION"):
    select_faces(obj, pred)
    assert bpy.ops.mesh.material_deform_add_anchor(mode=mode) == {"FINISHED"}
    bpy.ops.object.mode_set(mode="OBJECT")
    return obj.material_deform.anchors[-1]


def two_end_anchors(obj, half_length=2.0):
    top = add_anchor(obj, lambda p: p.center.z > half_length - 1e-4)
    bottom = add_anchor(obj, lambda p: p.center.z < -half_length + 1e-4)
    return top, bottom


def co(seq):
    out = np.empty(len(seq) * 3, np.float32)
    seq.foreach_get("co", out)
    return out.reshape(-1, 3)


def output(obj):
    return co(obj.data.shape_keys.key_blocks["Material Deform"].data)


def rest(obj):
    keys = obj.data.shape_keys
    return co(keys.reference_key.data if keys else obj.data.vertices)


def evaluated(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        return co(me.vertices)
    finally:
        ev.to_mesh_clear()


def anchor_vertices(obj, anchor):
    vg = obj.vertex_groups[anchor.vertex_group]
    idx = []
    for v in obj.data.vertices:
        if any(g.group == vg.index for g in v.groups):
            idx.append(v.index)
    return np.array(idx)


def triangles(obj):
    me = obj.data
    me.calc_loop_triangles()
    t = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", t)
    p = np.empty(len(me.loop_triangles), np.int32)
    me.loop_triangles.foreach_get("polygon_index", p)
    return t.reshape(-1, 3), p


def face_rotation_angles(rest_v, def_v, tris):
    """Rotation angle (radians) of each triangle's best-fit deformation gradient: the polar
    rotation of  [e1 e2 n]' [e1 e2 n]^-1  (Sumner-Popovic frame)."""

    def frame(v):
        e1 = v[tris[:, 1]] - v[tris[:, 0]]
        e2 = v[tris[:, 2]] - v[tris[:, 0]]
        n = np.cross(e1, e2)
        n /= np.sqrt(np.linalg.norm(n, axis=1))[:, None]
        return np.stack([e1, e2, n], axis=2)

    a = frame(np.asarray(def_v, float)) @ np.linalg.inv(frame(np.asarray(rest_v, float)))
    u, _s, vt = np.linalg.svd(a)
    r = u @ vt
    c = np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.arccos(c)


def update():
    bpy.context.view_layer.update()


# --- paint and attributes ---------------------------------------------------------------------


def paint(obj, name, weight_of_vertex):
    vg = obj.vertex_groups.get(name) or obj.vertex_groups.new(name=name)
    for v in obj.data.vertices:
        vg.add([v.index], float(weight_of_vertex(v)), "REPLACE")
    return vg


def attr(obj, name, width=1):
    a = obj.data.attributes[name]
    out = np.empty(len(a.data) * width, np.float32)
    a.data.foreach_get("vector" if width == 3 else "value", out)
    return out.reshape(-1, width) if width > 1 else out


def group_weights(obj, name):
    vg = obj.vertex_groups[name]
    return np.array([vg.weight(i) for i in range(len(obj.data.vertices))])


def edge_faces(me):
    out = {}
    for p in me.polygons:
        for k in p.edge_keys:
            out.setdefault(k, []).append(p.index)
    return out


# --- checks -----------------------------------------------------------------------------------


def snapshot(obj):
    me = obj.data
    keys = me.shape_keys
    return (
        rest(obj).tobytes(),
        None if keys is None else [k.name for k in keys.key_blocks],
        len(me.vertices),
        len(me.polygons),
        [a.name for a in me.attributes],
    )


def expect_error(op, match, **kw):
    with pytest.raises(RuntimeError, match=match):
        op(**kw)


# --- the panel, drawn into a recording layout ---------------------------------------------------


class RecordingLayout:
    def __init__(self, log):
        self.log = log

    def _check(self, data, prop):
        assert prop in data.bl_rna.properties, f"{data!r} has no property {prop!r}"
        self.log.append(prop)

    def prop(self, data, prop, **_kw):
        self._check(data, prop)

    def prop_search(self, data, prop, search_data, search_prop, **_kw):
        self._check(data, prop)
        self._check(search_data, search_prop)

    def operator(self, idname, **_kw):
        mod, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, mod), name), idname
        self.log.append(idname)

    def template_list(self, list_type, _list_id, data, prop, active_data, active_prop, **_kw):
        assert hasattr(bpy.types, list_type), list_type
        self._check(data, prop)
        self._check(active_data, active_prop)

    def label(self, **_kw):
        pass

    def box(self):
        return self

    def row(self, **_kw):
        return self

    def column(self, **_kw):
        return self


def draw_panel():
    log = []
    panel = bpy.types.VIEW3D_PT_material_deform
    fake = type("P", (), {"layout": RecordingLayout(log)})()
    panel.draw(fake, bpy.context)
    return log
