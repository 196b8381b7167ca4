"""The sidebar panel (3D Viewport > N > Material Deform), its anchor list and the menus.

The panel follows the selection: with the mesh selected it shows everything, in subpanels in
workflow order (Stiffness, Learn, Anchors, Deform, Bake); with one of its anchor Empties selected
it shows a compact posing view of that mesh (status, Live, Update, Reset Empties, Select Mesh).
Labels fit the default sidebar width; long messages are wrapped to the sidebar's width."""

from __future__ import annotations

import bpy

from . import bake, bridge, core, session
from .model import BindError

DEFAULT_SIDEBAR_WIDTH = 229  # px at UI scale 1 (Blender 3.4 to 4.5), with the tab column
_MARGIN = 56  # px of the sidebar a panel's rows never get: the tabs and the panel margins
_LABEL_PAD = 10  # px around a label's text
_ICON = 26  # px a label's icon takes


def _text_width(text: str, scale: float) -> float:
    try:
        import blf

        try:
            blf.size(0, 11 * scale)
        except TypeError:  # Blender < 4.0 also takes the dpi (deprecated since 3.4)
            blf.size(0, 11 * scale, 72)
        return blf.dimensions(0, text)[0]
    except Exception:  # no font (some background builds): a typical character width
        return 6.5 * scale * len(text)


def wrap(text: str, width_px: float, scale: float = 1.0) -> list[str]:
    """``text`` split at spaces into lines that fit ``width_px`` (a word longer than a line
    gets a line of its own)."""
    lines, line = [], ""
    for word in text.split():
        trial = f"{line} {word}" if line else word
        if line and _text_width(trial, scale) > width_px:
            lines.append(line)
            line = word
        else:
            line = trial
    if line:
        lines.append(line)
    return lines


def wrapped_label(layout, context, text: str, icon: str = "NONE") -> None:
    """A label over as many lines as the sidebar's width needs."""
    region = getattr(context, "region", None)
    prefs = getattr(context, "preferences", None)
    scale = prefs.view.ui_scale if prefs is not None else 1.0
    width = region.width if region is not None and region.width > 1 else None
    width = (width or DEFAULT_SIDEBAR_WIDTH * scale) - (_MARGIN + _LABEL_PAD) * scale
    if icon != "NONE":
        width -= _ICON * scale
    col = layout.column(align=True)
    for i, line in enumerate(wrap(text, width, scale)):
        col.label(text=line, icon=icon if i == 0 else ("BLANK1" if icon != "NONE" else "NONE"))


def _target(context):
    """(mesh object the panel is about, True when reached through one of its Empties)."""
    obj = context.object
    if bridge.is_mesh(obj):
        return obj, False
    owner = session.owner_of(obj, context.scene)
    return owner, owner is not None


def _method(layout, obj):
    try:
        return session.method_of(obj)
    except BindError as exc:
        layout.label(text=str(exc), icon="ERROR")
        return None


def draw_status(layout, context, obj) -> None:
    """Bound / not bound / why it does not update / which bake drives the mesh."""
    s = obj.material_deform
    baked = bake.state(obj)
    if not s.bound:
        wrapped_label(layout, context, "Not bound: add anchors, then Bind", icon="INFO")
    else:
        reason = session.stale_reason(obj)
        if reason:
            wrapped_label(layout, context, reason, icon="ERROR")
        elif not baked:
            layout.label(text="Bound, Live" if s.live else "Bound, Live off", icon="CHECKMARK")
    if baked:
        wrapped_label(layout, context, f"{baked}: the bake drives the mesh", icon="REC")


def draw_posing(layout, context, obj, method) -> None:
    """Live / Update (/ Settle) and Reset Empties: what posing needs."""
    s = obj.material_deform
    if not s.bound:
        return
    row = layout.row(align=True)
    row.prop(s, "live", toggle=True, icon="PLAY" if s.live else "PAUSE")
    row.operator("object.material_deform_update", icon="FILE_REFRESH")
    if method is not None and method.iterative:
        layout.operator("object.material_deform_settle")
        status = session.solve_status(obj)
        if status is not None:  # the last solve's sweeps and move; a warning if it stopped
            wrapped_label(layout, context, status[1], icon="CHECKMARK" if status[0] else "ERROR")
    layout.operator("object.material_deform_reset_empties", icon="EMPTY_AXIS")


class MESH_UL_material_deform_anchors(bpy.types.UIList):
    """Anchors: name, and the mode as an icon (its tooltip names it)."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "name", text="", emboss=False, icon="EMPTY_AXIS")
        row.prop(item, "mode", text="", icon_only=True, emboss=False)


class VIEW3D_PT_material_deform(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Material Deform"
    bl_label = "Material Deform"

    @classmethod
    def poll(cls, context):
        return _target(context)[0] is not None

    def draw(self, context):
        layout = self.layout
        obj, posing = _target(context)
        if not core.available():
            wrapped_label(layout, context, "matdeform core missing: reinstall the add-on", "ERROR")
        if posing:
            wrapped_label(layout, context, f"Anchor Empty of {obj.name}", icon="EMPTY_AXIS")
            layout.operator("object.material_deform_select_mesh", icon="RESTRICT_SELECT_OFF")
        draw_status(layout, context, obj)
        method = _method(layout, obj) if obj.material_deform.bound else None
        draw_posing(layout, context, obj, method)


class _MeshSubpanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Material Deform"
    bl_parent_id = "VIEW3D_PT_material_deform"

    @classmethod
    def poll(cls, context):
        return bridge.is_mesh(context.object)  # hidden in the posing view


class VIEW3D_PT_material_deform_stiffness(_MeshSubpanel, bpy.types.Panel):
    bl_label = "Stiffness"

    def draw(self, context):
        obj = context.object
        s = obj.material_deform
        col = self.layout.column()
        col.prop(s, "stiffness_source", text="")
        if s.stiffness_source == "VERTEX_GROUP":
            col.prop_search(
                s, "stiffness_group", obj, "vertex_groups", text="", icon="GROUP_VERTEX"
            )
            missing = obj.vertex_groups.get(s.stiffness_group) is None
        else:
            col.prop_search(
                s, "color_attribute", obj.data, "color_attributes", text="", icon="GROUP_VCOL"
            )
            missing = obj.data.color_attributes.get(s.color_attribute) is None
        if missing:
            col.operator(
                "mesh.material_deform_add_paint_layer", text="Create Paint Layer", icon="ADD"
            )
        col.prop(s, "stiffness_softest")
        col.label(text="paint 0 = Softest, 1 = stiff")
        col.operator("mesh.material_deform_stiffness_from_paint", icon="BRUSH_DATA")
        row = col.row(align=True)
        row.prop(s, "display_field", text="")
        row.operator("mesh.material_deform_show_stiffness", text="Show", icon="HIDE_OFF")
        row.operator("mesh.material_deform_hide_stiffness", text="Hide", icon="HIDE_ON")


class VIEW3D_PT_material_deform_learn(_MeshSubpanel, bpy.types.Panel):
    bl_label = "Learn from Poses"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.object.material_deform
        col = self.layout.column()
        col.prop(s, "learn_filter", icon="VIEWZOOM")
        col.prop(s, "learn_region")
        col.operator("mesh.material_deform_learn_stiffness", icon="SHAPEKEY_DATA")


class VIEW3D_PT_material_deform_anchors(_MeshSubpanel, bpy.types.Panel):
    bl_label = "Anchors"

    def draw(self, context):
        obj = context.object
        s = obj.material_deform
        layout = self.layout
        row = layout.row()
        row.template_list(
            "MESH_UL_material_deform_anchors", "", s, "anchors", s, "active_anchor_index", rows=3
        )
        col = row.column(align=True)
        col.operator("mesh.material_deform_add_anchor", text="", icon="ADD")
        col.operator("mesh.material_deform_remove_anchor", text="", icon="REMOVE")
        if obj.mode != "EDIT":
            wrapped_label(layout, context, "+ adds the faces selected in Edit Mode", icon="INFO")
        if 0 <= s.active_anchor_index < len(s.anchors):
            anc = s.anchors[s.active_anchor_index]
            col = layout.column()
            col.label(text="Faces (vertex group):")
            col.prop_search(anc, "vertex_group", obj, "vertex_groups", text="")
            col.operator(
                "mesh.material_deform_select_anchor",
                text="Select Faces",
                icon="RESTRICT_SELECT_OFF",
            )
            col.label(text="Empty:")
            col.prop(anc, "empty", text="")
            col.label(text="Follows the Empty's:")
            col.prop(anc, "mode", text="")


class VIEW3D_PT_material_deform_deform(_MeshSubpanel, bpy.types.Panel):
    bl_label = "Deform"

    def draw(self, context):
        obj = context.object
        s = obj.material_deform
        layout = self.layout
        col = layout.column()
        col.prop(s, "method", text="")
        row = col.row(align=True)
        if s.bound:
            row.operator("object.material_deform_rebind", icon="FILE_REFRESH")
        else:
            row.operator("object.material_deform_bind", icon="LINKED")
        row.operator("object.material_deform_reset", icon="LOOP_BACK")
        if s.bound:
            op = col.operator(
                "object.material_deform_bind", text="Bind at Current Pose", icon="ARMATURE_DATA"
            )
            op.at_current_pose = True
        method = _method(col, obj)
        if method is not None:
            col.separator()
            method.draw(col.column(), obj, session.cached_entry(obj))


class VIEW3D_PT_material_deform_bake(_MeshSubpanel, bpy.types.Panel):
    bl_label = "Bake"

    def draw(self, context):
        obj = context.object
        s = obj.material_deform
        col = self.layout.column()
        col.row().prop(s, "bake_output", expand=True)
        row = col.row(align=True)
        row.prop(s, "bake_start")
        row.prop(s, "bake_end")
        if s.bake_output == "POINT_CACHE":
            col.label(text="Cache File (.pc2):")
            col.prop(s, "bake_cache_path", text="")
            col.operator("object.material_deform_bake_point_cache", text="Bake", icon="REC")
        else:
            col.operator("object.material_deform_bake", text="Bake", icon="REC")
        if bake.state(obj):
            col.operator("object.material_deform_clear_bake", icon="TRASH")


# --- menus (F3 finds what is in a menu) ---------------------------------------------------------


class VIEW3D_MT_material_deform(bpy.types.Menu):
    bl_label = "Material Deform"

    def draw(self, _context):
        layout = self.layout
        layout.operator("object.material_deform_bind")
        layout.operator("object.material_deform_rebind")
        op = layout.operator("object.material_deform_bind", text="Bind at Current Pose")
        op.at_current_pose = True
        layout.operator("object.material_deform_update")
        layout.operator("object.material_deform_settle")
        layout.operator("object.material_deform_reset_empties")
        layout.operator("object.material_deform_select_mesh")
        layout.operator("object.material_deform_reset")
        layout.separator()
        layout.operator("mesh.material_deform_add_anchor")
        layout.operator("mesh.material_deform_remove_anchor")
        layout.operator("mesh.material_deform_select_anchor")
        layout.operator("mesh.material_deform_assign_empty")
        layout.separator()
        layout.operator("mesh.material_deform_add_paint_layer")
        layout.operator("mesh.material_deform_stiffness_from_paint")
        layout.operator("mesh.material_deform_show_stiffness")
        layout.operator("mesh.material_deform_hide_stiffness")
        layout.operator("mesh.material_deform_learn_stiffness")
        layout.separator()
        layout.operator("object.material_deform_bake_point_cache")
        layout.operator("object.material_deform_bake")
        layout.operator("object.material_deform_clear_bake")
        layout.operator("object.material_deform_farm_job", text="Write Farm Bake Job...")


def draw_object_menu(self, _context):
    self.layout.separator()
    self.layout.menu("VIEW3D_MT_material_deform")


def draw_face_menu(self, _context):
    self.layout.separator()
    self.layout.operator("mesh.material_deform_add_anchor", text="Add Material Deform Anchor")


MENUS = (
    ("VIEW3D_MT_object", draw_object_menu),
    ("VIEW3D_MT_edit_mesh_context_menu", draw_face_menu),  # right click in Edit Mode
    ("VIEW3D_MT_edit_mesh_faces", draw_face_menu),  # Face menu (Ctrl+F)
)

classes = (
    MESH_UL_material_deform_anchors,
    VIEW3D_PT_material_deform,
    VIEW3D_PT_material_deform_stiffness,
    VIEW3D_PT_material_deform_learn,
    VIEW3D_PT_material_deform_anchors,
    VIEW3D_PT_material_deform_deform,
    VIEW3D_PT_material_deform_bake,
    VIEW3D_MT_material_deform,
)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    for menu, fn in MENUS:
        getattr(bpy.types, menu).append(fn)


def unregister():
    for menu, fn in reversed(MENUS):
        getattr(bpy.types, menu).remove(fn)
    _unregister_classes()
