"""Bakes (one keyframed shape key per frame, or a .pc2 point cache read by a Mesh Cache
modifier), clearing a bake, and rebuilding the solvers of a loaded scene."""

from __future__ import annotations

import hashlib
import os

from . import bridge, session
from .model import BindError, settings
from .pointcache import PC2Writer


def state(obj) -> str:
    """What bake drives the mesh ('' when none), as the panel says it."""
    mod = bridge.cache_modifier(obj)
    if mod is not None:
        return f"Baked to {os.path.basename(mod.filepath) or 'a point cache'}"
    n = len(bridge.bake_key_names(obj))
    return f"Baked {n} frame(s) to shape keys" if n else ""


def frame_start(entry) -> None:
    """The rule that makes a baked frame depend on its frame only, for every method: each frame
    is solved from an empty method state, as the first frame a fresh process solves (a farm
    bakes chunks of frames in other processes, in any order). An iterative method then starts
    from its own start, never from the previous frame's result (Edge: the rest mesh; Pyramid:
    the controls' best-fit similarity of the rest mesh); the direct methods keep no result.
    Called before each baked frame; the method's settings are read again by the solve's own
    checks. The anchors' rotation vectors (``session.twist``) are not state: for keyframed
    anchors they follow from the frame alone (what is cached is the animation's), and only an
    anchor the sampler cannot evaluate continues from the pose shown before."""
    entry.state.clear()


def _solved_frames(obj, scene, frames, progress, unsettled=None):
    """(frame, positions (n,3)) for every frame, each solved to convergence from a start that
    depends on that frame only (:func:`frame_start`), so the frames may come in any order and
    a chunk of them gives the same positions as the whole range. Never a non-finite frame
    (BindError). The scene's frame is restored afterwards. ``unsettled``: a list that gets
    (frame, status text) of every frame an iterative method wrote without converging (it ran
    out of Max Iterations / Settle Max)."""
    progress = progress or (lambda _f, _t: None)
    entry = session.entry_for(obj, scene)
    old = scene.frame_current
    try:
        for i, f in enumerate(frames):
            progress(i / len(frames), f"Material Deform: baking frame {f} ({i + 1}/{len(frames)})")
            bridge.frame_set(scene, f)
            dg = bridge.evaluated_depsgraph_from_scene(scene)
            frame_start(session.entry_for(obj, scene))
            x = session.compute(obj, scene, dg, budget=None)
            session.check_finite(obj, entry, x)
            status = session.solve_status(obj)
            if unsettled is not None and status is not None and not status[0]:
                unsettled.append((f, status[1]))
            yield f, x
    finally:
        bridge.frame_set(scene, old)


def _hand_over(obj) -> None:
    """The bake drives the mesh now: Live off and the live output at 0."""
    s = settings(obj)
    s.live = False
    bridge.set_output_value(obj, 0.0, s.output_key_name or bridge.OUTPUT_KEY)


def bake(obj, scene, frames, progress=None, unsettled=None) -> list[str]:
    """Write one keyframed shape key per frame (replacing an earlier bake); turns Live off and
    mutes the live output. Every frame is solved before anything is written, so an error
    leaves the object as it was. ``unsettled``: see :func:`_solved_frames`."""
    frames = list(frames)
    s = settings(obj)
    live, s.live = s.live, False  # our own frame changes must not write the live key
    try:
        solved = [
            (f, x.astype("float32"))
            for f, x in _solved_frames(obj, scene, frames, progress, unsettled)
        ]
    except BaseException:
        s.live = live
        raise
    clear(obj, scene, restore_live=False)
    names = [bridge.bake_key(obj, f, x) for f, x in solved]
    _hand_over(obj)
    return names


def baked_from(obj) -> str:
    """A digest of what a bake of ``obj`` is made of: the bind (mesh, anchors, stiffness,
    method), the method's settings, and everything that moves the anchors. Two processes that
    open the same saved file get the same digest; any change that can change a baked frame
    gives another."""
    s = settings(obj)
    parts = (
        (s.fp_topology, s.fp_anchors, s.fp_stiffness, s.fp_method),
        session.settings_signature(obj),
        bridge.motion_record(obj, [a.empty for a in s.anchors]),
    )
    return hashlib.blake2b(repr(parts).encode(), digest_size=16).hexdigest()


def cache_path(obj, path: str) -> tuple[str, str]:
    """(path as stored in the modifier, absolute path) of the point cache; '' means
    '//<blend name>_<object name>.pc2', so that shots in one folder keep their own caches
    (bridge.object_file_name). A relative path needs a saved .blend."""
    path = path or f"//{bridge.object_file_name(obj)}.pc2"
    if path.startswith("//") and not bridge.blend_saved():
        raise BindError(
            f"Save the .blend first: the cache path '{path}' is relative to it (or pick an "
            "absolute File)"
        )
    full = os.path.normpath(bridge.abspath(path))
    if not os.path.splitext(full)[1]:
        path, full = path + ".pc2", full + ".pc2"
    folder = os.path.dirname(full)
    if folder and not os.path.isdir(folder):
        raise BindError(f"Folder '{folder}' does not exist")
    return path, full


def write_point_cache(obj, scene, frames, full: str, progress=None, unsettled=None) -> None:
    """Solve the frames (:func:`_solved_frames`) into the .pc2 file ``full`` (an absolute path),
    atomically: on any error an existing file stays as it was, and so does the object. Live is
    off when it succeeds (the caller hands the mesh over to the cache, or discards the file).
    ``unsettled``: see :func:`_solved_frames`."""
    frames = list(frames)
    s = settings(obj)
    live, s.live = s.live, False  # our own frame changes must not write the live key
    try:
        with PC2Writer(full, len(obj.data.vertices), len(frames), frames[0]) as out:
            for _f, x in _solved_frames(obj, scene, frames, progress, unsettled):
                out.add(x)
    except OSError as exc:
        s.live = live
        raise BindError(f"Cannot write '{full}': {exc.strerror or exc}") from exc
    except BaseException:
        s.live = live
        raise


def use_point_cache(obj, scene, stored: str, start: int) -> None:
    """Let the .pc2 file ``stored`` (as the modifier stores it, e.g. '//Bar.pc2'), whose first
    sample is frame ``start``, drive the mesh: replaces an earlier bake, Live off."""
    clear(obj, scene, restore_live=False)
    bridge.add_cache_modifier(obj, stored, start)
    _hand_over(obj)


def bake_point_cache(obj, scene, frames, path: str = "", progress=None, unsettled=None) -> str:
    """Write the frames to a .pc2 file and read it back through a Mesh Cache modifier at the
    top of the stack (replacing an earlier bake); turns Live off. Returns the absolute path.
    ``unsettled``: see :func:`_solved_frames`."""
    frames = list(frames)
    stored, full = cache_path(obj, path)
    write_point_cache(obj, scene, frames, full, progress, unsettled)
    use_point_cache(obj, scene, stored, frames[0])
    return full


def unsettled_warning(unsettled, count: int) -> str:
    """The bake operators' WARNING for frames written before they converged ('' if none)."""
    if not unsettled:
        return ""
    frames = ", ".join(str(f) for f, _ in unsettled[:8]) + (", ..." if len(unsettled) > 8 else "")
    return (
        f"{len(unsettled)} of {count} frame(s) did not converge (frames {frames}); "
        f"frame {unsettled[0][0]}: {unsettled[0][1]}"
    )


def clear(obj, scene, restore_live: bool = True) -> bool:
    """Remove the baked shape keys with their keyframes and the point-cache modifier (the
    file stays on disk). ``restore_live``: turn Live on again and pose the mesh live."""
    removed = bridge.remove_bake_keys(obj) > 0
    removed |= bridge.remove_cache_modifier(obj)
    if restore_live:
        s = settings(obj)
        s.live = True
        bridge.set_output_value(obj, 1.0, s.output_key_name or bridge.OUTPUT_KEY)
        if s.bound:
            try:
                session.apply(obj, scene, force=True)
            except BindError as exc:
                session.record_failure(obj, str(exc))
    return removed


def prepare_scene(scene) -> None:
    """Build the solvers of all bound objects (after loading a file), recording stale ones."""
    for obj in scene.objects:
        if obj.type == "MESH" and settings(obj).bound:
            try:
                session.entry_for(obj, scene)
            except BindError:
                pass  # reason is kept in the session and shown in the panel
            except Exception as exc:  # never break file loading
                session.record_failure(obj, f"Rebuild failed: {exc}")
