"""Sidebar panel (3D Viewport > N > Material Deform) and the anchor list."""

from __future__ import annotations

import bpy

from . import core, session
from .model import BindError
from .stiffness_map import stiffness_range


class MESH_UL_material_deform_anchors(bpy.types.UIList):
    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "name", text="", emboss=False, icon="EMPTY_AXIS")
        row.prop(item, "empty", text="")
        row.prop(item, "mode", text="", icon_only=True)


class VIEW3D_PT_material_deform(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Material Deform"
    bl_label = "Material Deform"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.type == "MESH"

    def draw(self, context):
        obj = context.object
        s = obj.material_deform
        layout = self.layout
        if not core.available():
            layout.label(text="matdeform core missing: reinstall the add-on", icon="ERROR")

        box = layout.box()
        box.label(text="Stiffness", icon="BRUSH_DATA")
        box.prop(s, "stiffness_source", text="")
        if s.stiffness_source == "VERTEX_GROUP":
            box.prop_search(s, "stiffness_group", obj, "vertex_groups", text="Group")
        else:
            box.prop_search(s, "color_attribute", obj.data, "color_attributes", text="Color")
        box.prop(s, "stiffness_span")
        lo, hi = stiffness_range(s.stiffness_span)
        box.label(text=f"paint 0 = {lo:.0e} (flexible)  ..  1 = {hi:g} (stiff)")
        row = box.row(align=True)
        row.operator("mesh.material_deform_stiffness_from_paint")
        row.operator("mesh.material_deform_show_stiffness", text="Show", icon="HIDE_OFF")
        row = box.row(align=True)
        row.operator("mesh.material_deform_learn_stiffness", icon="SHAPEKEY_DATA")
        row.prop(s, "learn_filter")
        box.prop(s, "learn_region")

        box = layout.box()
        box.label(text="Anchors", icon="EMPTY_AXIS")
        row = box.row()
        row.template_list(
            "MESH_UL_material_deform_anchors", "", s, "anchors", s, "active_anchor_index", rows=3
        )
        col = row.column(align=True)
        col.operator("mesh.material_deform_add_anchor", text="", icon="ADD")
        col.operator("mesh.material_deform_remove_anchor", text="", icon="REMOVE")
        col.operator("mesh.material_deform_select_anchor", text="", icon="RESTRICT_SELECT_OFF")
        if 0 <= s.active_anchor_index < len(s.anchors):
            anc = s.anchors[s.active_anchor_index]
            box.prop_search(anc, "vertex_group", obj, "vertex_groups")
            box.prop(anc, "empty")
            box.prop(anc, "mode")

        box = layout.box()
        box.label(text="Deform", icon="MOD_SIMPLEDEFORM")
        box.prop(s, "method", text="")
        try:
            method = session.method_of(obj)
        except BindError as exc:
            box.label(text=str(exc), icon="ERROR")
            method = None
        if method is not None:
            method.draw(box.column(), obj)
        row = box.row(align=True)
        row.operator("mesh.material_deform_bind", text="Rebind" if s.bound else "Bind")
        row.operator("mesh.material_deform_reset", icon="LOOP_BACK")
        if s.bound:
            reason = session.stale_reason(obj)
            if reason:
                box.label(text=reason, icon="ERROR")
            else:
                box.label(text="Bound", icon="CHECKMARK")
            row = box.row(align=True)
            row.prop(s, "live", toggle=True)
            row.operator("mesh.material_deform_update")
            if method is not None and method.iterative:
                row.operator("mesh.material_deform_settle")

        box = layout.box()
        box.label(text="Bake", icon="REC")
        row = box.row(align=True)
        row.prop(s, "bake_start")
        row.prop(s, "bake_end")
        box.operator("mesh.material_deform_bake")


classes = (MESH_UL_material_deform_anchors, VIEW3D_PT_material_deform)


register, unregister = bpy.utils.register_classes_factory(classes)
