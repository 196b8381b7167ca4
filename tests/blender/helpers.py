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
    """The add-on's bridge.activate (imported late: the add-on is enabled by a fixture)."""
    from material_deform.bridge import activate

    activate(obj)


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
    add_anchor(obj, lambda p: p.center.z > half_length - 1e-4)
    add_anchor(obj, lambda p: p.center.z < -half_length + 1e-4)
    # fetched after both adds: adding to a collection may move its items, and a Python
    # reference to an item taken before would point at freed memory
    anchors = obj.material_deform.anchors
    return anchors[-2], anchors[-1]


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
#
# Headless Blender cannot draw a panel, so it is drawn into a layout that records what it holds
# (checking every property and operator name against RNA) and then lays it out the way Blender
# does in a panel: a row gives its items equal shares (an icon-only item one icon's width; a
# nested row as many shares as it has items), and an item whose text needs more than its share
# is cut ("…"). Widths are in pixels at UI scale 1, text measured with Blender's own UI font
# (blf, 11 px); the margins were measured on screenshots of the 3.4 GUI under Xvfb
# (scripts/screenshots_blender.sh).

SIDEBAR_WIDTH = 229  # Blender's default sidebar width, with its tab column
PANEL_WIDTH = 173  # what a panel's rows get of it
UNIT = 20  # UI_UNIT_X: an icon, an icon-only button
PAD = 12  # a button's text margins
LABEL_PAD = 10  # a label's text margins
SPLIT = 0.4  # share of a named field that its label gets


def text_width(text):
    import blf

    try:
        blf.size(0, 11)
    except TypeError:
        blf.size(0, 11, 72)
    return blf.dimensions(0, text)[0]


class _OperatorProps:
    """What ``layout.operator`` returns: only the operator's own properties can be set."""

    def __init__(self, idname):
        mod, name = idname.split(".")
        self._names = {
            p.identifier for p in getattr(getattr(bpy.ops, mod), name).get_rna_type().properties
        }

    def __setattr__(self, key, value):
        if key != "_names":
            assert key in self._names, f"operator has no property {key!r}"
        object.__setattr__(self, key, value)


class RecordingLayout:
    def __init__(self, log, node=None):
        self.log = log
        self.node = node if node is not None else {"kind": "column", "items": []}

    def __setattr__(self, key, value):  # use_property_split, enabled, alert, scale_y, ...
        object.__setattr__(self, key, value)

    def _check(self, data, prop):
        assert prop in data.bl_rna.properties, f"{data!r} has no property {prop!r}"
        self.log.append(prop)

    def _add(self, **item):
        self.node["items"].append(item)

    def _child(self, kind, **kw):
        node = {"kind": kind, "items": [], **kw}
        self.node["items"].append(node)
        return RecordingLayout(self.log, node)

    def prop(
        self, data, prop, text=None, icon="NONE", icon_only=False, toggle=False, expand=False, **_kw
    ):
        self._check(data, prop)
        self._add(
            kind="prop",
            data=data,
            prop=prop,
            text=text,
            icon=icon,
            icon_only=icon_only,
            toggle=toggle,
            expand=expand,
        )

    def prop_search(self, data, prop, search_data, search_prop, text=None, icon="NONE", **_kw):
        self._check(data, prop)
        self._check(search_data, search_prop)
        self._add(kind="search", data=data, prop=prop, text=text, icon=icon)

    def operator(self, idname, text=None, icon="NONE", **_kw):
        mod, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, mod), name), idname
        self.log.append(idname)
        if text is None:
            text = getattr(bpy.ops, mod).__getattr__(name).get_rna_type().name
        self._add(kind="operator", text=text, icon=icon, idname=idname)
        return _OperatorProps(idname)

    def menu(self, menu, text=None, icon="NONE", **_kw):
        assert hasattr(bpy.types, menu), menu
        self.log.append(menu)
        self._add(kind="operator", text=text or getattr(bpy.types, menu).bl_label, icon=icon)

    def template_list(self, list_type, _list_id, data, prop, active_data, active_prop, **_kw):
        assert hasattr(bpy.types, list_type), list_type
        self._check(data, prop)
        self._check(active_data, active_prop)
        self._add(kind="list")

    def label(self, text="", icon="NONE", **_kw):
        self.log.append(("label", text))
        self._add(kind="label", text=text, icon=icon)

    def separator(self, **_kw):
        pass

    def box(self):
        return self._child("box")

    def row(self, **_kw):
        return self._child("row")

    def column(self, **_kw):
        return self._child("column")

    def split(self, factor=0.5, **_kw):
        return self._child("split", factor=factor)


def _item_needs(item):
    """[(text, width the text needs, fixed)] of one item: a named field is a label and a field."""
    kind, icon = item["kind"], item.get("icon", "NONE")
    icon_w = UNIT if icon not in ("NONE", "BLANK1", None) else 0
    if kind == "label":
        if not item["text"]:
            return [("<icon>", icon_w)]
        return [(item["text"], text_width(item["text"]) + LABEL_PAD + (icon_w and icon_w + 6))]
    if kind == "operator":
        if not item["text"]:
            return [("<icon>", UNIT)]
        return [(item["text"], text_width(item["text"]) + PAD + (icon_w and 16))]
    if kind == "list":
        return [("<list>", 60)]
    rna = item["data"].bl_rna.properties[item["prop"]]
    name = rna.name if item["text"] is None else item["text"]
    if kind == "search" or rna.type in {"STRING", "POINTER"}:
        if not name:
            return [("<field>", 40 + icon_w)]
        return [(name, (text_width(name) + 6) / SPLIT)]
    if item["icon_only"]:
        return [("<icon>", UNIT)]
    if rna.type == "BOOLEAN":
        w = text_width(name) + (PAD + icon_w if item["toggle"] else UNIT + 6)
        return [(name, w)]
    if rna.type == "ENUM":
        items = [e.name for e in rna.enum_items] or [""]
        if item["expand"]:
            widest = max(text_width(t) for t in items) + PAD
            return [(t, widest) for t in items]
        value = max(text_width(t) for t in items) + PAD + UNIT  # the widest choice and an arrow
        if not name:
            return [(items[0], value)]
        return [(name, max((text_width(name) + 6) / SPLIT, value / (1 - SPLIT)))]
    value = getattr(item["data"], item["prop"])
    shown = f"{name}: {value:.6g}" if name else f"{value:.6g}"
    return [(shown, text_width(shown) + PAD + UNIT)]


def _icon_only(node):
    """An icon-only item, or a layout holding only such items (the + / - column of a list)."""
    kind = node["kind"]
    if kind in {"row", "column", "box", "split"}:
        return bool(node["items"]) and all(_icon_only(c) for c in node["items"])
    if kind in {"operator", "label"}:
        return not node["text"]
    return kind in {"prop", "search"} and node.get("icon_only", False)


def _shares(node):
    """Equal shares a layout asks for in a row (nested rows: one per item)."""
    kind = node["kind"]
    if kind in {"row", "split"}:
        return sum(_shares(c) for c in node["items"] if not _icon_only(c)) or 1
    return 1


def cut_texts(node, width=PANEL_WIDTH):
    """Texts that would be cut at this width: [(text, needs, gets)]."""
    out = []
    kind = node["kind"]
    if kind in {"column", "box"}:
        inner = width - (12 if kind == "box" else 0)
        for c in node["items"]:
            out += cut_texts(c, inner)
    elif kind in {"row", "split"}:
        # icon-only items keep an icon's width, the others share the rest equally
        icons = [c for c in node["items"] if _icon_only(c)]
        rest = width - UNIT * len(icons)
        total = sum(_shares(c) for c in node["items"] if not _icon_only(c)) or 1
        for c in node["items"]:
            out += cut_texts(c, UNIT if _icon_only(c) else rest * _shares(c) / total)
    else:
        parts = _item_needs(node)
        total = sum(w for _t, w in parts)
        for t, w in parts:
            gets = width * w / total if total > width else w
            if gets < w - 0.5:
                out.append((t, round(w), round(gets)))
    return out


def draw_panel(context=None):
    """Draw the Material Deform panel and the subpanels Blender would show with it; returns
    the log of property / operator names (and ("label", text) tuples). ``draw_panel.tree``
    holds the recorded layout of the last call."""
    context = context or bpy.context
    log = []
    root = {"kind": "column", "items": []}
    panels = [bpy.types.VIEW3D_PT_material_deform]
    panels += [
        p
        for p in bpy.types.Panel.__subclasses__()
        if getattr(p, "bl_parent_id", "") == "VIEW3D_PT_material_deform"
    ]
    for panel in panels:
        if hasattr(panel, "poll") and not panel.poll(context):
            continue
        layout = RecordingLayout(log, {"kind": "column", "items": [], "panel": panel.__name__})
        root["items"].append(layout.node)
        fake = type("P", (), {"layout": layout})()
        panel.draw(fake, context)
    draw_panel.tree = root
    return log


def forbid_lapack(monkeypatch):
    """Make every numpy LAPACK entry point raise: the live path must not use them (in bpy 4.x
    one call keeps OpenBLAS's thread spinning on the core the solver needs)."""

    def boom(*_a, **_k):
        raise AssertionError("LAPACK called on the live-update path")

    for name in ("inv", "solve", "svd", "det", "eig", "eigh", "qr", "lstsq", "pinv"):
        monkeypatch.setattr(np.linalg, name, boom)
