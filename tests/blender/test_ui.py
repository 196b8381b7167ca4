"""The panel, menus and operator ids as a user meets them (issue 16). Headless Blender cannot
draw a panel, so it is drawn into a recording layout that checks every property and operator
name against RNA and lays the rows out as Blender does, to find labels the default sidebar
width would cut (helpers.cut_texts)."""

import bpy
import pytest
from helpers import (
    RecordingLayout,
    activate,
    cut_texts,
    draw_panel,
    paint,
    select_faces,
    tube,
    two_end_anchors,
    update,
)
from material_deform import bridge, operators, properties, session, ui

OBJECT_OPS = (
    "bind",
    "rebind",
    "update",
    "settle",
    "reset",
    "reset_empties",
    "select_mesh",
    "bake",
    "bake_point_cache",
    "clear_bake",
)


def bound_bar():
    obj = tube()
    top, bottom = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    return obj, top, bottom


def labels(log):
    return [x[1] for x in log if isinstance(x, tuple)]


def test_panel_draws_before_and_after_bind():
    obj = tube()
    assert bpy.types.VIEW3D_PT_material_deform.poll(bpy.context)
    log = draw_panel()
    assert "object.material_deform_bind" in log and "live" not in log
    assert "object.material_deform_rebind" not in log
    two_end_anchors(obj)
    bpy.ops.object.material_deform_bind()
    log = draw_panel()
    assert "live" in log and "object.material_deform_update" in log and "mode" in log
    assert "object.material_deform_rebind" in log and "object.material_deform_reset_empties" in log
    ul = bpy.types.MESH_UL_material_deform_anchors
    ulog = []
    ul.draw_item(
        None, None, RecordingLayout(ulog), None, obj.material_deform.anchors[0], 0, None, None, 0
    )
    assert ulog == ["name", "mode"]


def _scenes():
    """Panel states a user meets, each yielded after it is set up."""
    obj = tube()
    yield "fresh mesh"
    obj.material_deform.stiffness_source = "COLOR_ATTRIBUTE"
    yield "color source, no paint layer"
    obj.material_deform.stiffness_source = "VERTEX_GROUP"
    paint(obj, "Stiffness", lambda v: 0.5)
    top, _ = two_end_anchors(obj)
    yield "anchors"
    select_faces(obj, lambda p: p.center.z > 1.99)
    yield "edit mode"
    bpy.ops.object.mode_set(mode="OBJECT")
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    yield "bound"
    obj.material_deform.anisotropic = True  # no per-axis stiffness: a long stale message
    update()
    yield "stale, anisotropic"
    obj.material_deform.anisotropic = False
    obj.material_deform.bake_start, obj.material_deform.bake_end = 1, 3
    assert bpy.ops.object.material_deform_bake() == {"FINISHED"}
    yield "baked"
    obj.material_deform.bake_output = "SHAPE_KEYS"
    yield "bake to shape keys"
    activate(top.empty)
    yield "posing: an anchor Empty selected"


def test_every_label_fits_the_default_sidebar_width():
    cut = {}
    for name in _scenes():
        draw_panel()
        texts = cut_texts(draw_panel.tree)
        if texts:
            cut[name] = texts
    assert cut == {}


def test_long_messages_wrap_to_the_sidebar_width():
    msg = session.binding._diff_reason(tube(), ("a", "b", "c", "d"), ("x", "y", "z", "w"))
    lines = ui.wrap(msg, ui.DEFAULT_SIDEBAR_WIDTH - 56 - 26)
    assert len(lines) >= 3 and " ".join(lines) == msg


def test_posing_view_with_an_anchor_empty_selected():
    obj, top, _ = bound_bar()
    activate(top.empty)
    assert bpy.types.VIEW3D_PT_material_deform.poll(bpy.context)
    log = draw_panel()
    for name in (
        "live",
        "object.material_deform_update",
        "object.material_deform_reset_empties",
        "object.material_deform_select_mesh",
    ):
        assert name in log
    assert "stiffness_source" not in log and "anchors" not in log  # compact: no subpanels
    assert any("Bound" in t for t in labels(log))
    # the object operators act on the mesh the Empty drives
    top.empty.location.x += 1.0
    obj.material_deform.live = False
    assert bpy.ops.object.material_deform_update() == {"FINISHED"}
    assert bpy.ops.object.material_deform_select_mesh() == {"FINISHED"}
    assert bpy.context.object == obj and not top.empty.select_get()
    # an Empty that drives nothing gets no panel
    other = bpy.data.objects.new("Loose", None)
    bpy.context.scene.collection.objects.link(other)
    activate(other)
    assert not bpy.types.VIEW3D_PT_material_deform.poll(bpy.context)
    assert not bpy.ops.object.material_deform_update.poll()


def _menu_log(menu_cls):
    log = []
    fake = type("M", (), {"layout": RecordingLayout(log)})()
    for fn in menu_cls._dyn_ui_initialize():
        if fn.__module__.startswith("material_deform") or "material_deform" in fn.__qualname__:
            fn(fake, bpy.context)
    return log


def test_menus_hold_the_operators_so_f3_finds_them():
    """F3 searches the menus: the Object menu gets a Material Deform submenu, the Edit Mode
    face context menu and Face menu get Add Anchor."""
    assert "VIEW3D_MT_material_deform" in _menu_log(bpy.types.VIEW3D_MT_object)
    log = []
    fake = type("M", (), {"layout": RecordingLayout(log)})()
    bpy.types.VIEW3D_MT_material_deform.draw(fake, bpy.context)
    for op in OBJECT_OPS:
        assert f"object.material_deform_{op}" in log
    for op in ("stiffness_from_paint", "show_stiffness", "learn_stiffness", "add_paint_layer"):
        assert f"mesh.material_deform_{op}" in log
    for menu in ("VIEW3D_MT_edit_mesh_context_menu", "VIEW3D_MT_edit_mesh_faces"):
        assert "mesh.material_deform_add_anchor" in _menu_log(getattr(bpy.types, menu))
    # every operator a user can call is in one of the menus (the old aliases are INTERNAL)
    from material_deform import operators

    everywhere = " ".join(map(str, log))
    for menu in ("VIEW3D_MT_edit_mesh_context_menu", "VIEW3D_MT_edit_mesh_faces"):
        everywhere += " ".join(map(str, _menu_log(getattr(bpy.types, menu))))
    public = [c.bl_idname for c in operators.classes if "INTERNAL" not in c.bl_options]
    assert [op for op in public if op not in everywhere] == []


def test_object_actions_have_object_ids_and_the_old_ids_still_work():
    for op in OBJECT_OPS:
        assert hasattr(bpy.ops.object, f"material_deform_{op}"), op
    for op in ("add_anchor", "remove_anchor", "select_anchor", "stiffness_from_paint"):
        assert hasattr(bpy.ops.mesh, f"material_deform_{op}"), op  # mesh data / Edit Mode
    for old in operators.ALIASES:
        cls = getattr(bpy.types, "MESH_OT_" + old.split(".")[1])
        assert "INTERNAL" in cls.bl_options  # hidden from search, so F3 lists one of each
    obj = tube()
    two_end_anchors(obj)
    assert bpy.ops.mesh.material_deform_bind() == {"FINISHED"}  # the 0.1 id
    assert obj.material_deform.bound
    assert bpy.ops.mesh.material_deform_update() == {"FINISHED"}
    assert bpy.ops.mesh.material_deform_reset() == {"FINISHED"}
    assert not obj.material_deform.bound


def test_plain_words_instead_of_jargon():
    obj = tube()
    s = obj.material_deform
    log = draw_panel()
    assert "stiffness_softest" in log and "stiffness_span" not in log
    rna = s.bl_rna.properties
    assert rna["stiffness_softest"].name == "Softest"
    s.stiffness_softest = 0.01
    assert s.stiffness_span == pytest.approx(2.0)
    assert s.stiffness_softest == pytest.approx(0.01)
    # the two "Region" settings have names of their own
    assert rna["region_group"].name != rna["learn_region"].name
    assert "Region" not in (rna["region_group"].name, rna["learn_region"].name)
    # the anchor list's Mode column shows an icon per mode, and its tooltip names it
    mode = properties.MaterialDeformAnchor.bl_rna.properties["mode"]
    assert mode.description and all(i.icon != "NONE" and i.description for i in mode.enum_items)
    for op in ("select_anchor", "add_anchor", "remove_anchor"):
        assert getattr(bpy.ops.mesh, f"material_deform_{op}").get_rna_type().description


def _descriptions():
    for cls in operators.classes:
        yield cls.bl_idname, cls.bl_rna.description
        for p in cls.bl_rna.properties:
            yield f"{cls.bl_idname}.{p.identifier}", p.description
    for cls in properties.classes:
        for p in cls.bl_rna.properties:
            yield f"{cls.__name__}.{p.identifier}", p.description
            for item in getattr(p, "enum_items", ()):
                yield f"{cls.__name__}.{p.identifier}.{item.identifier}", item.description


def test_no_tooltip_cites_a_file_the_zip_does_not_ship():
    bad = [(k, d) for k, d in _descriptions() if ".md" in d or "docs/" in d]
    assert bad == []
    assert all("\n" not in d for _k, d in _descriptions())  # one-line tooltips


def test_bake_redo_panel_shows_the_range_it_baked():
    obj, top, _ = bound_bar()
    s = obj.material_deform
    s.bake_start, s.bake_end = 3, 5
    op = bpy.ops.object.material_deform_bake
    assert op("EXEC_DEFAULT", True) == {"FINISHED"}  # registered for redo, as in the UI
    last = bpy.context.window_manager.operators[-1]
    assert last.bl_idname == "OBJECT_OT_material_deform_bake"
    assert (last.properties.frame_start, last.properties.frame_end) == (3, 5)


@pytest.mark.parametrize("what", ["bind", "learn", "bake", "bake_point_cache"])
def test_long_operators_show_progress_while_they_run(monkeypatch, tmp_path, what):
    """The status text is set and the window redrawn before the heavy step (Blender would
    otherwise only show it after the operator returned); the cursor number comes from
    wm.progress_update, which runs in the same call."""
    obj = tube()
    two_end_anchors(obj)
    if what == "learn":
        obj.shape_key_add(name="Basis")
        kb = obj.shape_key_add(name="Pose")
        kb.data[0].co.x += 0.1
    elif what != "bind":
        assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    calls = []
    monkeypatch.setattr(bridge, "status", lambda _c, text: calls.append(("status", text)))
    monkeypatch.setattr(bridge, "redraw", lambda _c: calls.append(("redraw", None)))
    if what == "learn":
        assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    elif what == "bake_point_cache":
        path = str(tmp_path / "bar.pc2")
        op = bpy.ops.object.material_deform_bake_point_cache
        assert op(frame_start=1, frame_end=3, filepath=path) == {"FINISHED"}
    else:
        op = getattr(bpy.ops.object, f"material_deform_{what}")
        assert op() == {"FINISHED"}
    assert calls[0][0] == "status" and calls[0][1]  # text first ...
    assert calls[1] == ("redraw", None)  # ... drawn at once
    assert calls[-1] == ("status", None)  # and cleared at the end
