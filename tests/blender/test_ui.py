"""The sidebar panel cannot be drawn headless, so draw it into a recording layout that checks
every property name against the RNA of the data it is given (catches typos and API drift)."""

import bpy
from helpers import RecordingLayout, draw_panel, tube, two_end_anchors


def test_panel_draws_before_and_after_bind():
    obj = tube()
    assert bpy.types.VIEW3D_PT_material_deform.poll(bpy.context)
    log = draw_panel()
    assert "mesh.material_deform_bind" in log and "live" not in log
    two_end_anchors(obj)
    bpy.ops.mesh.material_deform_bind()
    log = draw_panel()
    assert "live" in log and "mesh.material_deform_update" in log and "mode" in log
    ul = bpy.types.MESH_UL_material_deform_anchors
    ulog = []
    ul.draw_item(
        None, None, RecordingLayout(ulog), None, obj.material_deform.anchors[0], 0, None, None, 0
    )
    assert ulog == ["name", "empty", "mode"]
