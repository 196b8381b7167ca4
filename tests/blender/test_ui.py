"""The sidebar panel cannot be drawn headless, so draw it into a recording layout that checks
every property name against the RNA of the data it is given (catches typos and API drift)."""

import bpy
from helpers import tube, two_end_anchors


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
