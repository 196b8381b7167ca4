"""Operators. Each one validates first and reports a clear error without touching the mesh.

Ids: what acts on the object (Bind, Rebind, Update, Settle, Reset, Reset Empties, the bakes) is
``object.material_deform_*`` and also works with one of the object's anchor Empties selected;
what works on mesh data or in Edit Mode is ``mesh.material_deform_*``. The ``mesh.`` ids the
object actions had in 0.1 stay as hidden aliases for one release, so scripts keep working."""

from __future__ import annotations

import time

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from . import bake, bridge, learn, session, stiffness
from .anchor_math import anchor_polygons
from .model import BindError
from .stiffness_map import loop_polygon_index

# '//' paths are relative to the .blend (4.5+ warns unless a path property says it takes them)
_BLEND_RELATIVE = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


def _poll_message(cls, text) -> None:
    if hasattr(cls, "poll_message_set"):  # Blender 3.0+
        cls.poll_message_set(text)


class _Operator:
    """Base of every operator: ``run(context, obj)`` does the work and raises BindError for
    anything the user has to fix, which is reported as an error and cancels the operator."""

    bl_options = {"REGISTER", "UNDO"}

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.__doc__ and "bl_description" not in cls.__dict__:  # tooltips on one line
            cls.bl_description = " ".join(cls.__doc__.split())

    @classmethod
    def target(cls, context):
        obj = context.object
        return obj if bridge.is_mesh(obj) else None

    @classmethod
    def poll(cls, context):
        if cls.target(context) is not None:
            return True
        _poll_message(cls, "Select a mesh object")
        return False

    def execute(self, context):
        try:
            return self.run(context, self.target(context))
        except BindError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}

    def run(self, context, obj):
        raise NotImplementedError


class _ObjectOperator(_Operator):
    """Acts on the mesh object, found also from one of its anchor Empties (posing)."""

    @classmethod
    def target(cls, context):
        obj = context.object
        if bridge.is_mesh(obj):
            return obj
        return session.owner_of(obj, context.scene)

    @classmethod
    def poll(cls, context):
        if cls.target(context) is not None:
            return True
        _poll_message(cls, "Select a mesh object or one of its anchor Empties")
        return False


def _to_object_mode(context, obj) -> None:
    if obj.mode != "OBJECT" and context.view_layer.objects.active == obj:
        bpy.ops.object.mode_set(mode="OBJECT")


class _Progress:
    """wm.progress_* (the number in the mouse cursor) plus status-bar text, with the window
    redrawn now and then so the text shows while the operator runs; safe in background mode."""

    REDRAW_EVERY = 0.1  # s: a redraw costs a few ms, a bake of a small mesh a few ms a frame

    def __init__(self, context):
        self.context = context
        self.wm = context.window_manager
        self._drawn = None

    def __enter__(self):
        self.wm.progress_begin(0, 100)
        return self

    def __call__(self, fraction, text):
        self.wm.progress_update(int(100 * fraction))
        bridge.status(self.context, text or None)
        now = time.perf_counter()
        if text and (self._drawn is None or now - self._drawn > self.REDRAW_EVERY):
            bridge.redraw(self.context)
            self._drawn = now

    def __exit__(self, *_exc):
        self.wm.progress_end()
        bridge.status(self.context, None)
        return False


# --- stiffness --------------------------------------------------------------------------------


class MESH_OT_material_deform_stiffness_from_paint(_Operator, bpy.types.Operator):
    """Convert the painted vertex group / color attribute into per-face shear and per-edge
    bending stiffness attributes (log scale: paint 0 = Softest, 1 = stiff)"""

    bl_idname = "mesh.material_deform_stiffness_from_paint"
    bl_label = "Stiffness from Paint"

    def run(self, context, obj):
        with bridge.object_mode(context, obj):
            _paint, psi, _phi = stiffness.stiffness_from_paint(obj)
            reason = session.full_check(obj, context.scene)
        msg = f"Stiffness: {len(psi)} faces, range {psi.min():.3g} .. {psi.max():.3g}"
        self.report({"WARNING"} if reason else {"INFO"}, reason or msg)
        return {"FINISHED"}


class MESH_OT_material_deform_add_paint_layer(_Operator, bpy.types.Operator):
    """Create the stiffness paint layer if it is missing (the vertex group of the Paint Source,
    or its color attribute, black = flexible) and make it the one Weight / Vertex Paint paints"""

    bl_idname = "mesh.material_deform_add_paint_layer"
    bl_label = "Create Paint Layer"

    def run(self, context, obj):
        with bridge.object_mode(context, obj):
            names, created = stiffness.add_paint_layer(obj)
        verb = "Created" if created else "Already there, made active:"
        self.report({"INFO"}, f"{verb} {', '.join(names)}")
        return {"FINISHED"}


class MESH_OT_material_deform_learn_stiffness(_Operator, bpy.types.Operator):
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


class MESH_OT_material_deform_show_stiffness(_Operator, bpy.types.Operator):
    """Colour the mesh by the stored stiffness chosen in Show (blue = flexible, red = stiff) and
    switch the viewports to Solid > Attribute shading; Hide puts both back"""

    bl_idname = "mesh.material_deform_show_stiffness"
    bl_label = "Show Stiffness"

    field: EnumProperty(
        name="Field",
        items=(
            ("PANEL", "As in the Panel", "The field chosen in the panel's Show menu"),
            ("SHEAR", "Shear", ""),
            ("BEND", "Bend", ""),
            ("BEND_X", "Bend X", ""),
            ("BEND_Y", "Bend Y", ""),
            ("BEND_Z", "Bend Z", ""),
        ),
        default="PANEL",
        options={"SKIP_SAVE"},
    )

    def run(self, context, obj):
        s = obj.material_deform
        field = (s.display_field or "SHEAR") if self.field == "PANEL" else self.field
        with bridge.object_mode(context, obj):
            stiffness.show_stiffness(obj, field)
        if not s.display_prev_shading:  # keep what was there before the first Show
            s.display_prev_shading = bridge.viewport_shading(context)
        bridge.show_attribute_shading(context)
        return {"FINISHED"}


class MESH_OT_material_deform_hide_stiffness(_Operator, bpy.types.Operator):
    """Remove the stiffness colours and give the viewports their shading from before Show"""

    bl_idname = "mesh.material_deform_hide_stiffness"
    bl_label = "Hide Stiffness"

    def run(self, context, obj):
        s = obj.material_deform
        with bridge.object_mode(context, obj):
            stiffness.hide_stiffness(obj)
        if s.display_prev_shading:
            bridge.set_viewport_shading(context, s.display_prev_shading)
        s.display_prev_shading = ""
        return {"FINISHED"}


# --- anchors (mesh data, Edit Mode) -------------------------------------------------------------


class MESH_OT_material_deform_add_anchor(_Operator, bpy.types.Operator):
    """Make the faces selected in Edit Mode an anchor: a vertex group plus an Empty at their
    centroid, oriented along their average normal and parented to the mesh object"""

    bl_idname = "mesh.material_deform_add_anchor"
    bl_label = "Add Anchor"

    mode: EnumProperty(
        name="Mode",
        description="How the anchor faces follow their Empty",
        items=(
            ("POSITION", "Follow Empty", "The faces follow the Empty's full transform"),
            ("ROTATION", "Rotation + Scale", "Only the Empty's rotation and scale are used"),
            ("FRAME", "Frame", "Pose space: the frame in which the pose is measured"),
        ),
        default="POSITION",
    )

    def run(self, context, obj):
        if obj.mode != "EDIT":
            # in Object Mode the faces last selected in Edit Mode would be used unseen
            raise BindError(
                "Add Anchor uses the faces selected in Edit Mode: press Tab, select the anchor "
                "faces, then Add Anchor"
            )
        s = obj.material_deform
        with bridge.object_mode(context, obj):
            mesh = obj.data
            sel = bridge.selected_polygons(mesh)
            if not sel.any():
                raise BindError("Select the anchor faces in Edit Mode first")
            verts, c_world, n_world, radius = bridge.selection_frame(obj, sel)
            active = obj.vertex_groups.active  # a new group becomes the active (painted) one
            painted = active.name if active is not None else None
            group = bridge.set_vertex_group(obj, bridge.unique_group_name(obj, "Anchor"), verts)
            if painted is not None:
                bridge.set_active_vertex_group(obj, painted)
            empty = bridge.create_empty(
                context, f"{obj.name} {group}", c_world, n_world, max(radius, 0.1), obj
            )
            anc = s.anchors.add()
            anc.name = group
            anc.vertex_group = group
            anc.empty = empty
            anc.mode = self.mode
            s.active_anchor_index = len(s.anchors) - 1
            session.place_new_anchor(obj, empty, verts, context.scene.frame_current)
        if s.bound:
            self.report({"WARNING"}, "Anchor added: click Rebind to use it")
        return {"FINISHED"}


class MESH_OT_material_deform_remove_anchor(_Operator, bpy.types.Operator):
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


class MESH_OT_material_deform_select_anchor(_Operator, bpy.types.Operator):
    """Select the faces of the active anchor in Edit Mode"""

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


class MESH_OT_material_deform_assign_empty(_Operator, bpy.types.Operator):
    """Assign an existing Empty to the active anchor (from a menu: the selected Empty, or one
    chosen by name)"""

    bl_idname = "mesh.material_deform_assign_empty"
    bl_label = "Assign Empty"

    # SKIP_SAVE: from the menu, the last run's Empty must not be reused silently
    empty: StringProperty(name="Empty", options={"SKIP_SAVE"})

    def invoke(self, context, event):
        if not self.empty:
            picked = [o for o in context.selected_objects if o.type == "EMPTY"]
            if len(picked) != 1:  # none or several selected: ask for the name
                return context.window_manager.invoke_props_dialog(self)
            self.empty = picked[0].name
        return self.execute(context)

    def draw(self, context):
        self.layout.prop_search(self, "empty", context.scene, "objects")

    def run(self, context, obj):
        s = obj.material_deform
        emp = bpy.data.objects.get(self.empty)
        if emp is None or emp.type != "EMPTY":
            raise BindError(f"'{self.empty}' is not an Empty")
        if not 0 <= s.active_anchor_index < len(s.anchors):
            raise BindError("No active anchor")
        s.anchors[s.active_anchor_index].empty = emp
        return {"FINISHED"}


# --- binding and posing (the object) ------------------------------------------------------------

_AT_CURRENT_POSE = (
    "Make where the Empties are now the new bind pose: the mesh goes back to its rest shape "
    "and the Empties stay where they are, so they no longer sit on their faces"
)


class _Bind(_ObjectOperator):
    at_current_pose: BoolProperty(
        name="Bind at Current Pose", description=_AT_CURRENT_POSE, options={"SKIP_SAVE"}
    )

    @classmethod
    def description(cls, _context, properties):
        if properties.at_current_pose:
            return "Bind at Current Pose. " + _AT_CURRENT_POSE
        return cls.bl_description

    def run(self, context, obj):
        _to_object_mode(context, obj)
        rebind = obj.material_deform.bound
        with _Progress(context) as progress:
            entry = session.bind(obj, context.scene, progress, self.at_current_pose)
        what = f"{len(entry.rest)} vertices, {entry.n_anchors} anchor(s)"
        if self.at_current_pose:
            msg = f"Bound at the current pose ({what}): the mesh is at its rest shape"
        elif rebind:
            msg = f"Rebound {what}, keeping the bind pose"
        else:
            msg = f"Bound {what}"
        self.report({"INFO"}, msg)
        for warning in entry.warnings:
            self.report({"WARNING"}, warning)
        return {"FINISHED"}


class OBJECT_OT_material_deform_bind(_Bind, bpy.types.Operator):
    """Precompute the deformation for the current anchors and stiffness. The first Bind takes
    the Empties' placement as the bind pose; binding again keeps that pose"""

    bl_idname = "object.material_deform_bind"
    bl_label = "Bind"


class OBJECT_OT_material_deform_rebind(_Bind, bpy.types.Operator):
    """Bind again after changing the mesh, anchors, stiffness or settings, keeping the bind
    pose: the mesh keeps its pose and the Empties stay on their faces"""

    bl_idname = "object.material_deform_rebind"
    bl_label = "Rebind"

    @classmethod
    def poll(cls, context):
        obj = cls.target(context)
        if obj is not None and obj.material_deform.bound:
            return True
        _poll_message(cls, "Not bound yet: use Bind")
        return False


class OBJECT_OT_material_deform_update(_ObjectOperator, bpy.types.Operator):
    """Recompute the deformation from the current Empty transforms now"""

    bl_idname = "object.material_deform_update"
    bl_label = "Update"

    def run(self, context, obj):
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        session.apply(obj, context.scene, context.evaluated_depsgraph_get(), force=True)
        return {"FINISHED"}


class OBJECT_OT_material_deform_settle(_ObjectOperator, bpy.types.Operator):
    """Solve the current pose to convergence now (iterative methods settle over several live
    updates while you drag; this finishes at once)"""

    bl_idname = "object.material_deform_settle"
    bl_label = "Settle"

    def run(self, context, obj):
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        with _Progress(context) as progress:
            progress(0.0, "Material Deform: settling")  # iterative methods report as they go
            session.settle(obj, context.scene, context.evaluated_depsgraph_get(), progress)
        status = session.solve_status(obj)
        if status is not None:  # iterative methods: say whether it converged
            self.report({"INFO"} if status[0] else {"WARNING"}, f"{obj.name}: {status[1]}")
        return {"FINISHED"}


class OBJECT_OT_material_deform_reset(_ObjectOperator, bpy.types.Operator):
    """Remove the deformation and the bind: the mesh gets its exact rest shape back (the
    Empties stay where they are)"""

    bl_idname = "object.material_deform_reset"
    bl_label = "Reset"

    def run(self, context, obj):
        _to_object_mode(context, obj)
        session.unbind(obj)
        return {"FINISHED"}


class OBJECT_OT_material_deform_reset_empties(_ObjectOperator, bpy.types.Operator):
    """Move every anchor Empty back to its bind pose (following the object if it moved): the
    mesh returns to its rest shape"""

    bl_idname = "object.material_deform_reset_empties"
    bl_label = "Reset Empties"

    def run(self, context, obj):
        n = session.reset_empties(obj)
        self.report({"INFO"}, f"{n} Empty(s) back at the bind pose")
        return {"FINISHED"}


class OBJECT_OT_material_deform_select_mesh(_ObjectOperator, bpy.types.Operator):
    """Select the mesh this anchor Empty drives (and make it active)"""

    bl_idname = "object.material_deform_select_mesh"
    bl_label = "Select Mesh"

    def run(self, context, obj):
        if context.object is not None and context.object.mode != "OBJECT":
            raise BindError("Leave the current mode first")
        bridge.activate(obj, context.view_layer)
        return {"FINISHED"}


# --- bakes ----------------------------------------------------------------------------------------


class _BakeOperator(_ObjectOperator):
    frame_start: IntProperty(name="Start", description="First frame", options={"SKIP_SAVE"})
    frame_end: IntProperty(name="End", description="Last frame", options={"SKIP_SAVE"})

    def frames(self, context, obj) -> range:
        """The frame range (the panel's Start / End unless given), written back into the
        operator's own properties so its redo panel shows what was baked."""
        s = obj.material_deform
        if not self.properties.is_property_set("frame_start"):
            self.frame_start = s.bake_start
        if not self.properties.is_property_set("frame_end"):
            self.frame_end = s.bake_end
        if self.frame_end < self.frame_start:
            raise BindError(f"Bake range is empty ({self.frame_start}..{self.frame_end})")
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        return range(self.frame_start, self.frame_end + 1)


class OBJECT_OT_material_deform_bake(_BakeOperator, bpy.types.Operator):
    """Bake the deformation over a frame range into keyframed shape keys (one per frame),
    replacing an earlier bake; Live turns off"""

    bl_idname = "object.material_deform_bake"
    bl_label = "Bake to Shape Keys"

    def run(self, context, obj):
        _to_object_mode(context, obj)
        frames = self.frames(context, obj)
        unsettled = []
        with _Progress(context) as progress:
            names = bake.bake(obj, context.scene, frames, progress, unsettled)
        self.report({"INFO"}, f"Baked {len(names)} frame(s) to shape keys; Live is off")
        if unsettled:
            self.report({"WARNING"}, bake.unsettled_warning(unsettled, len(names)))
        return {"FINISHED"}


class OBJECT_OT_material_deform_bake_point_cache(_BakeOperator, bpy.types.Operator):
    """Bake the deformation over a frame range into a .pc2 point cache read by a Mesh Cache
    modifier at the top of the stack (replacing an earlier bake); Live turns off"""

    bl_idname = "object.material_deform_bake_point_cache"
    bl_label = "Bake to Point Cache"

    filepath: StringProperty(
        name="File",
        description="The .pc2 file (empty: the panel's File, or '//<object name>.pc2')",
        subtype="FILE_PATH",
        options={"SKIP_SAVE"} | _BLEND_RELATIVE,
    )

    def run(self, context, obj):
        _to_object_mode(context, obj)
        frames = self.frames(context, obj)
        if not self.filepath:
            self.filepath = bake.cache_path(obj, obj.material_deform.bake_cache_path)[0]
        unsettled = []
        with _Progress(context) as progress:
            path = bake.bake_point_cache(
                obj, context.scene, frames, self.filepath, progress, unsettled
            )
        self.report({"INFO"}, f"Baked {len(frames)} frame(s) to {path}; Live is off")
        if unsettled:
            self.report({"WARNING"}, bake.unsettled_warning(unsettled, len(frames)))
        return {"FINISHED"}


class OBJECT_OT_material_deform_clear_bake(_ObjectOperator, bpy.types.Operator):
    """Remove the bake (the baked shape keys with their keyframes, or the Mesh Cache modifier;
    a .pc2 file stays on disk) and turn Live on again"""

    bl_idname = "object.material_deform_clear_bake"
    bl_label = "Clear Bake"

    def run(self, context, obj):
        if not bake.clear(obj, context.scene):
            self.report({"INFO"}, "No bake to clear; Live is on")
        return {"FINISHED"}


# --- the 0.1 ids --------------------------------------------------------------------------------


def _alias(cls, old_idname: str):
    """The same operator under its 0.1 id, hidden from search (INTERNAL). A copy of the class,
    not a subclass: Blender cannot register a subclass of a registered operator."""
    ns = {k: v for k, v in cls.__dict__.items() if k not in ("__dict__", "__weakref__")}
    ns.update(
        bl_idname=old_idname,
        bl_options={"REGISTER", "UNDO", "INTERNAL"},
        bl_description=f"Old name of {cls.bl_idname} (kept until the next release). "
        + cls.bl_description,
    )
    return type("MESH_OT_" + old_idname.split(".", 1)[1], cls.__bases__, ns)


ALIASES = {
    "mesh.material_deform_bind": OBJECT_OT_material_deform_bind,
    "mesh.material_deform_update": OBJECT_OT_material_deform_update,
    "mesh.material_deform_settle": OBJECT_OT_material_deform_settle,
    "mesh.material_deform_reset": OBJECT_OT_material_deform_reset,
    "mesh.material_deform_bake": OBJECT_OT_material_deform_bake,
}

classes = (
    MESH_OT_material_deform_stiffness_from_paint,
    MESH_OT_material_deform_add_paint_layer,
    MESH_OT_material_deform_show_stiffness,
    MESH_OT_material_deform_hide_stiffness,
    MESH_OT_material_deform_learn_stiffness,
    MESH_OT_material_deform_add_anchor,
    MESH_OT_material_deform_remove_anchor,
    MESH_OT_material_deform_select_anchor,
    MESH_OT_material_deform_assign_empty,
    OBJECT_OT_material_deform_bind,
    OBJECT_OT_material_deform_rebind,
    OBJECT_OT_material_deform_update,
    OBJECT_OT_material_deform_settle,
    OBJECT_OT_material_deform_reset,
    OBJECT_OT_material_deform_reset_empties,
    OBJECT_OT_material_deform_select_mesh,
    OBJECT_OT_material_deform_bake,
    OBJECT_OT_material_deform_bake_point_cache,
    OBJECT_OT_material_deform_clear_bake,
    *(_alias(cls, old) for old, cls in ALIASES.items()),
)


register, unregister = bpy.utils.register_classes_factory(classes)
