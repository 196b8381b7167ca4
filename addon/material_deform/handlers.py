"""Live updates: Empties moved interactively (depsgraph) or by animation (frame change, also
in background renders), rebuilding solvers after a .blend is loaded and re-validating them after
undo/redo; and the session's answers to changed settings (``updates``)."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from . import bake, session, stiffness, updates

_busy = False  # our own shape-key write triggers another depsgraph update


def _run(scene, depsgraph, budget="live"):
    global _busy
    if _busy or scene is None:
        return
    _busy = True
    try:
        session.live_update(scene, depsgraph, budget)
    finally:
        _busy = False
    if session.unsettled() and not bpy.app.timers.is_registered(_keep_settling):
        bpy.app.timers.register(_keep_settling, first_interval=_SETTLE_INTERVAL)


_SETTLE_INTERVAL = 0.02  # s between the live updates that let an iterative result settle


def _keep_settling():
    """Timer: an iterative method stopped on its per-update budget before converging, so the
    mesh keeps settling after the user stops dragging (each call spends one more budget)."""
    scene = bpy.context.scene
    if scene is None or not session.unsettled():
        return None
    _run(scene, None)
    return _SETTLE_INTERVAL if session.unsettled() else None


_paint_mode_seen: dict[int, str] = {}  # object pointer -> its mode at the last check


def _guard_paint():
    """Vertex Paint must never paint into the stiffness display (Show makes it the active
    colour attribute so Solid > Attribute shading shows it), and entering Weight Paint with an
    anchor's group active paints the stiffness instead (once on entering: picking the anchor's
    group in Weight Paint afterwards is the user's choice)."""
    obj = getattr(bpy.context, "object", None)
    if obj is None or obj.type != "MESH":
        return
    key = obj.as_pointer()
    entered = _paint_mode_seen.get(key) != obj.mode
    _paint_mode_seen[key] = obj.mode
    try:
        if obj.mode == "VERTEX_PAINT":
            stiffness.keep_display_out_of_paint(obj)
        elif obj.mode == "WEIGHT_PAINT" and entered:
            stiffness.weight_paint_into_stiffness(obj)
    except Exception as exc:  # a handler must never take Blender down
        print(f"Material Deform: could not switch the paint layer of '{obj.name}': {exc}")


_MSGBUS_OWNER = object()


def _subscribe():
    """Entering Vertex Paint is seen at once in the GUI (the depsgraph handler also covers
    scripts and background runs)."""
    bpy.msgbus.clear_by_owner(_MSGBUS_OWNER)
    bpy.msgbus.subscribe_rna(
        key=(bpy.types.Object, "mode"), owner=_MSGBUS_OWNER, args=(), notify=_guard_paint
    )


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    if not _busy:
        _guard_paint()
        session.note_changes(depsgraph)  # an edited animation: its cached turns are checked
    _run(scene, None)


def _rendering() -> bool:
    """Frames that nobody watches settle: a background run (``blender -b``, a farm node) has no
    timers to keep an iterative result settling, and a render job renders what the frame
    change wrote."""
    running = getattr(bpy.app, "is_job_running", None)  # Blender 3.3+
    return bool(bpy.app.background or (running is not None and running("RENDER")))


@persistent
def on_frame_change(scene, depsgraph=None):
    # While rendering, iterative methods solve each frame to convergence from their own start,
    # as Bake does (so a rendered frame equals the baked one); playback spends the live budget.
    _run(scene, depsgraph, None if _rendering() else "live")


@persistent
def on_load(_filepath=None, *_args):
    # Pointers from the previous file are meaningless now. Rebuild solvers (only if the saved
    # fingerprints still match) but do not deform yet: world matrices are not evaluated during
    # load_post, the first depsgraph update after loading does that.
    session.clear_cache()
    session.forget_changes()
    _subscribe()  # loading a file clears the subscriptions
    scene = bpy.context.scene
    if scene is not None:
        bake.prepare_scene(scene)


@persistent
def on_undo(scene=None, *_args):
    # Memfile undo replaced the datablocks but kept their addresses: re-validate what is cached
    # under them (a solver for a bind that was undone must not be used).
    scene = scene if isinstance(scene, bpy.types.Scene) else bpy.context.scene
    if scene is not None:
        session.after_undo(scene, bpy.data.objects)


_HANDLERS = (
    ("depsgraph_update_post", on_depsgraph_update),
    ("frame_change_post", on_frame_change),
    ("load_post", on_load),
    ("undo_post", on_undo),
    ("redo_post", on_undo),
)


def register():
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        if fn not in lst:
            lst.append(fn)
    _subscribe()
    updates.connect(session.LISTENER)


def unregister():
    updates.disconnect()
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        if fn in lst:
            lst.remove(fn)
    if bpy.app.timers.is_registered(_keep_settling):
        bpy.app.timers.unregister(_keep_settling)
    bpy.msgbus.clear_by_owner(_MSGBUS_OWNER)
    session.clear_cache()
