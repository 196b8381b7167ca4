"""Operators. Each one validates first and reports a clear error without touching the mesh."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from . import bake, bridge, learn, session, stiffness
from .anchor_math import anchor_polygons
from .model import BindError
from .stiffness_map import loop_polygon_index


def _mesh_object(context):
    obj = context.object
    return obj if bridge.is_mesh(obj) else None


class _MeshOperator:
    """Base of every operator: ``run(context, obj)`` does the work and raises BindError for
    anything the user has to fix, which is reported as an error and cancels the operator."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _mesh_object(context) is not None

    def execute(self, context):
        try:
            return self.run(context, _mesh_object(context))
        except BindError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}

    def run(self, context, obj):
        raise NotImplementedError


class _Progress:
    """wm.progress_* plus status-bar text; safe in background mode."""

    def __init__(self, context):
        self.context = context
        self.wm = context.window_manager

    def __enter__(self):
        self.wm.progress_begin(0, 100)
        return self

    def __call__(self, fraction, text):
        self.wm.progress_update(int(100 * fraction))
        bridge.status(self.context, text or None)

    def __exit__(self, *_exc):
        self.wm.progress_end()
        bridge.status(self.context, None)
        return False


class MESH_OT_material_deform_stiffness_from_paint(_MeshOperator, bpy.types.Operator):
    """Convert the painted vertex group / color attribute into per-face shear and per-edge
    bending stiffness attributes (log scale: 0 = flexible, 1 = stiff)"""

    bl_idname = "mesh.material_deform_stiffness_from_paint"
    bl_label = "Stiffness from Paint"

    def run(self, context, obj):
        with bridge.object_mode(context, obj):
            _paint, psi, _phi = stiffness.stiffness_from_paint(obj)
            reason = session.full_check(obj, context.scene)
        msg = f"Stiffness: {len(psi)} faces, range {psi.min():.3g} .. {psi.max():.3g}"
        self.report({"WARNING"} if reason else {"INFO"}, reason or msg)
        return {"FINISHED"}


class MESH_OT_material_deform_learn_stiffness(_MeshOperator, bpy.types.Operator):
    """Learn bending and shear stiffness from the shape keys (example poses of the Basis): all
    unmuted keys whose name contains the Keys filter. Writes the stiffness attributes and the
    paint vertex groups, so you can refine the result by painting"""

    bl_idname = "mesh.material_deform_learn_stiffness"
    bl_label = "Learn from Shape Keys"

    def run(self, context, obj):
        with bridge.object_mode(context, obj), _Progress(context) as progress:
            res = learn.learn_from_shape_keys(obj, progress)
            reason = session.full_check(obj, context.scene)
        msg = (
            f"Learned from {len(res['keys'])} shape key(s); bending {res['phi'].min():.3g} .. "
            f"{res['phi'].max():.3g}; paint written to: {', '.join(res['groups'].values())}"
        )
        self.report({"WARNING"} if reason else {"INFO"}, reason or msg)
        return {"FINISHED"}


class MESH_OT_material_deform_show_stiffness(_MeshOperator, bpy.types.Operator):
    """Show the stored stiffness as colours (blue = flexible, red = stiff)"""

    bl_idname = "mesh.material_deform_show_stiffness"
    bl_label = "Show Stiffness"

    def run(self, context, obj):
        with bridge.object_mode(context, obj):
            stiffness.show_stiffness(obj)
        bridge.show_attribute_shading(context)
        return {"FINISHED"}


class MESH_OT_material_deform_add_anchor(_MeshOperator, bpy.types.Operator):
    """Make the selected faces an anchor: a vertex group plus an Empty at their centroid,
    oriented along their average normal"""

    bl_idname = "mesh.material_deform_add_anchor"
    bl_label = "Add Anchor"

    mode: EnumProperty(
        name="Mode",
        items=(("POSITION", "Follow Empty", ""), ("ROTATION", "Rotation + Scale", "")),
        default="POSITION",
    )

    def run(self, context, obj):
        s = obj.material_deform
        with bridge.object_mode(context, obj):
            mesh = obj.data
            sel = bridge.selected_polygons(mesh)
            if not sel.any():
                raise BindError("Select the anchor faces in Edit Mode first")
            verts, c_world, n_world, radius = bridge.selection_frame(obj, sel)
            group = bridge.set_vertex_group(obj, bridge.unique_group_name(obj, "Anchor"), verts)
            empty = bridge.create_empty(
                context, f"{obj.name} {group}", c_world, n_world, max(radius, 0.1), obj
            )
            anc = s.anchors.add()
            anc.name = group
            anc.vertex_group = group
            anc.empty = empty
            anc.mode = self.mode
            s.active_anchor_index = len(s.anchors) - 1
        if s.bound:
            self.report({"WARNING"}, "Anchor added: click Bind again to use it")
        return {"FINISHED"}


class MESH_OT_material_deform_remove_anchor(_MeshOperator, bpy.types.Operator):
    """Remove the active anchor (its vertex group and Empty are kept)"""

    bl_idname = "mesh.material_deform_remove_anchor"
    bl_label = "Remove Anchor"

    index: IntProperty(default=-1, options={"SKIP_SAVE"})

    def run(self, context, obj):
        s = obj.material_deform
        i = self.index if self.index >= 0 else s.active_anchor_index
        if not 0 <= i < len(s.anchors):
            raise BindError("No anchor to remove")
        s.anchors.remove(i)
        s.active_anchor_index = max(0, min(i, len(s.anchors) - 1))
        return {"FINISHED"}


class MESH_OT_material_deform_select_anchor(_MeshOperator, bpy.types.Operator):
    """Select the faces of the active anchor (and its Empty)"""

    bl_idname = "mesh.material_deform_select_anchor"
    bl_label = "Select Anchor Faces"

    def run(self, context, obj):
        s = obj.material_deform
        if not 0 <= s.active_anchor_index < len(s.anchors):
            raise BindError("No active anchor")
        anc = s.anchors[s.active_anchor_index]
        if obj.mode == "EDIT":
            bpy.ops.object.mode_set(mode="OBJECT")  # sync groups before reading them
        w = bridge.vertex_group_weights(obj, [anc.vertex_group]).get(anc.vertex_group)
        if w is None:
            raise BindError(f"Vertex group '{anc.vertex_group}' not found")
        a = bridge.mesh_arrays(obj.data)
        lp = loop_polygon_index(a.loop_start, a.loop_total)
        mask = anchor_polygons(w >= 0, a.loop_vert, lp, a.n_polys)
        bpy.ops.object.mode_set(mode="EDIT")
        bridge.select_polygons_edit(obj, mask)
        return {"FINISHED"}


class MESH_OT_material_deform_bind(_MeshOperator, bpy.types.Operator):
    """Precompute the material-aware deformation for the current anchors and stiffness"""

    bl_idname = "mesh.material_deform_bind"
    bl_label = "Bind"

    def run(self, context, obj):
        if obj.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        with _Progress(context) as progress:
            entry = session.bind(obj, context.scene, progress)
        self.report({"INFO"}, f"Bound {len(entry.rest)} vertices, {entry.n_anchors} anchor(s)")
        return {"FINISHED"}


class MESH_OT_material_deform_update(_MeshOperator, bpy.types.Operator):
    """Recompute the deformation from the current Empty transforms now"""

    bl_idname = "mesh.material_deform_update"
    bl_label = "Update"

    def run(self, context, obj):
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        session.apply(obj, context.scene, context.evaluated_depsgraph_get(), force=True)
        return {"FINISHED"}


class MESH_OT_material_deform_settle(_MeshOperator, bpy.types.Operator):
    """Solve the current pose to convergence now (iterative methods settle over several live
    updates while you drag; this finishes at once)"""

    bl_idname = "mesh.material_deform_settle"
    bl_label = "Settle"

    def run(self, context, obj):
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        with _Progress(context) as progress:
            progress(0.1, "Material Deform: settling")
            session.settle(obj, context.scene, context.evaluated_depsgraph_get())
        return {"FINISHED"}


class MESH_OT_material_deform_reset(_MeshOperator, bpy.types.Operator):
    """Remove the deformation and the bind: the mesh gets its exact rest shape back"""

    bl_idname = "mesh.material_deform_reset"
    bl_label = "Reset"

    def run(self, context, obj):
        if obj.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        session.unbind(obj)
        return {"FINISHED"}


class MESH_OT_material_deform_bake(_MeshOperator, bpy.types.Operator):
    """Bake the deformation over a frame range into keyframed shape keys (one per frame)"""

    bl_idname = "mesh.material_deform_bake"
    bl_label = "Bake"

    frame_start: IntProperty(name="Start", default=-1, options={"SKIP_SAVE"})
    frame_end: IntProperty(name="End", default=-1, options={"SKIP_SAVE"})

    def run(self, context, obj):
        s = obj.material_deform
        start = self.frame_start if self.frame_start >= 0 else s.bake_start
        end = self.frame_end if self.frame_end >= 0 else s.bake_end
        if end < start:
            raise BindError(f"Bake range is empty ({start}..{end})")
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        with _Progress(context) as progress:
            names = bake.bake(obj, context.scene, range(start, end + 1), progress)
        self.report({"INFO"}, f"Baked {len(names)} frame(s); Live turned off")
        return {"FINISHED"}


class MESH_OT_material_deform_assign_empty(_MeshOperator, bpy.types.Operator):
    """Assign an existing Empty to the active anchor"""

    bl_idname = "mesh.material_deform_assign_empty"
    bl_label = "Assign Empty"

    empty: StringProperty(name="Empty")

    def run(self, context, obj):
        s = obj.material_deform
        emp = bpy.data.objects.get(self.empty)
        if emp is None or emp.type != "EMPTY":
            raise BindError(f"'{self.empty}' is not an Empty")
        if not 0 <= s.active_anchor_index < len(s.anchors):
            raise BindError("No active anchor")
        s.anchors[s.active_anchor_index].empty = emp
        return {"FINISHED"}


classes = (
    MESH_OT_material_deform_stiffness_from_paint,
    MESH_OT_material_deform_show_stiffness,
    MESH_OT_material_deform_add_anchor,
    MESH_OT_material_deform_remove_anchor,
    MESH_OT_material_deform_select_anchor,
    MESH_OT_material_deform_assign_empty,
    MESH_OT_material_deform_bind,
    MESH_OT_material_deform_update,
    MESH_OT_material_deform_settle,
    MESH_OT_material_deform_reset,
    MESH_OT_material_deform_bake,
    MESH_OT_material_deform_learn_stiffness,
)


register, unregister = bpy.utils.register_classes_factory(classes)
