"""Show / Hide of the stored stiffness and the paint layers (issue 16, traps 5 and 6): Show
offers the bending field where a learned joint lives, Hide gives the viewports their shading
back, Vertex Paint never paints into the display, and a button creates the paint layer."""

import bpy
import numpy as np
import pytest
from helpers import draw_panel, tube, update
from material_deform.properties import _field_items

DISPLAY = "md_stiffness_display"


def shading():
    for area in bpy.context.window_manager.windows[0].screen.areas:
        if area.type == "VIEW_3D":
            sh = area.spaces[0].shading
            return sh.type, sh.color_type
    raise AssertionError("no 3D viewport")


def set_shading(kind, color):
    for area in bpy.context.window_manager.windows[0].screen.areas:
        if area.type == "VIEW_3D":
            area.spaces[0].shading.type = kind
            area.spaces[0].shading.color_type = color


def corner_red(obj):
    attr = obj.data.color_attributes[DISPLAY]
    rgba = np.empty(len(attr.data) * 4, np.float32)
    attr.data.foreach_get("color", rgba)
    return rgba.reshape(-1, 4)[:, 0]


def knee_bar():
    """Shear uniform, bending soft on the ring of edges at z = 0: what learning a knee gives."""
    obj = tube(rings=11)
    me = obj.data
    shear = me.attributes.new("md_shear_stiffness", "FLOAT", "FACE")
    shear.data.foreach_set("value", np.ones(len(me.polygons), np.float32))
    bend = me.attributes.new("md_bend_stiffness", "FLOAT", "EDGE")
    ring = np.array(
        [
            abs(me.vertices[a].co.z) < 1e-4 and abs(me.vertices[b].co.z) < 1e-4
            for a, b in (e.vertices for e in me.edges)
        ]
    )
    bend.data.foreach_set("value", np.where(ring, 1e-3, 1.0).astype(np.float32))
    return obj, ring


def test_show_bend_reveals_a_joint_that_shear_hides():
    obj, ring = knee_bar()
    assert ring.sum() == 8
    assert bpy.ops.mesh.material_deform_show_stiffness(field="SHEAR") == {"FINISHED"}
    assert np.ptp(corner_red(obj)) < 1e-2  # uniform: the knee is invisible
    obj.material_deform.display_field = "BEND"
    assert bpy.ops.mesh.material_deform_show_stiffness() == {"FINISHED"}
    red = corner_red(obj)
    me = obj.data
    lv = np.array([lp.vertex_index for lp in me.loops])
    z = np.array([me.vertices[i].co.z for i in lv])
    assert red[np.abs(z) < 1e-4].max() < 0.8 < red[np.abs(z) > 0.5].min()  # the ring shows


def test_show_offers_the_axes_when_anisotropic():
    obj = tube()
    s = obj.material_deform
    assert "display_field" in draw_panel()
    assert [i[0] for i in _field_items(s, None)] == ["SHEAR", "BEND"]
    s.anisotropic = True
    assert [i[0] for i in _field_items(s, None)] == ["SHEAR", "BEND", "BEND_X", "BEND_Y", "BEND_Z"]
    # an axis without per-axis stiffness is refused with the reason
    with pytest.raises(RuntimeError, match="No per-axis bending"):
        bpy.ops.mesh.material_deform_show_stiffness(field="BEND_X")


def test_hide_restores_the_shading_and_the_active_color():
    obj, _ = knee_bar()
    paint_attr = obj.data.color_attributes.new("Stiffness", "FLOAT_COLOR", "POINT")
    obj.data.color_attributes.active_color = paint_attr
    set_shading("MATERIAL", "MATERIAL")
    assert bpy.ops.mesh.material_deform_show_stiffness() == {"FINISHED"}
    assert shading() == ("SOLID", "VERTEX")
    assert obj.data.color_attributes.active_color.name == DISPLAY
    assert bpy.ops.mesh.material_deform_show_stiffness(field="BEND") == {"FINISHED"}  # again
    assert bpy.ops.mesh.material_deform_hide_stiffness() == {"FINISHED"}
    assert shading() == ("MATERIAL", "MATERIAL")  # what it was before the first Show
    assert DISPLAY not in obj.data.color_attributes
    assert obj.data.color_attributes.active_color.name == "Stiffness"
    assert "mesh.material_deform_hide_stiffness" in draw_panel()


def test_vertex_paint_never_paints_into_the_display():
    obj, _ = knee_bar()
    obj.data.color_attributes.new("Stiffness", "FLOAT_COLOR", "POINT")
    assert bpy.ops.mesh.material_deform_show_stiffness() == {"FINISHED"}
    assert obj.data.color_attributes.active_color.name == DISPLAY
    bpy.ops.object.mode_set(mode="VERTEX_PAINT")
    update()
    assert obj.data.color_attributes.active_color.name == "Stiffness"
    bpy.ops.object.mode_set(mode="OBJECT")
    # with no paint layer at all, entering Vertex Paint makes one rather than paint the display
    obj2, _ = knee_bar()
    assert bpy.ops.mesh.material_deform_show_stiffness() == {"FINISHED"}
    bpy.ops.object.mode_set(mode="VERTEX_PAINT")
    update()
    active = obj2.data.color_attributes.active_color
    assert active is not None and active.name != DISPLAY
    bpy.ops.object.mode_set(mode="OBJECT")


def test_create_paint_layer_when_it_is_missing():
    obj = tube()
    s = obj.material_deform
    assert "mesh.material_deform_add_paint_layer" in draw_panel()
    assert bpy.ops.mesh.material_deform_add_paint_layer() == {"FINISHED"}
    assert obj.vertex_groups.active.name == "Stiffness"
    assert "mesh.material_deform_add_paint_layer" not in draw_panel()
    s.stiffness_source = "COLOR_ATTRIBUTE"
    s.color_attribute = "Paint"
    assert "mesh.material_deform_add_paint_layer" in draw_panel()
    assert bpy.ops.mesh.material_deform_add_paint_layer() == {"FINISHED"}
    ca = obj.data.color_attributes["Paint"]
    assert obj.data.color_attributes.active_color.name == "Paint"
    rgba = np.empty(len(ca.data) * 4, np.float32)
    ca.data.foreach_get("color", rgba)
    assert rgba.reshape(-1, 4)[:, :3].max() == 0.0  # black: flexible, paint the stiff parts
    # what it writes is what Stiffness from Paint reads
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    s.stiffness_source = "VERTEX_GROUP"
    s.anisotropic = True
    assert bpy.ops.mesh.material_deform_add_paint_layer() == {"FINISHED"}
    assert {"Stiffness X", "Stiffness Y", "Stiffness Z"} <= set(obj.vertex_groups.keys())
