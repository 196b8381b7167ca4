"""Bake (one keyframed shape key per frame) and rebuilding the solvers of a loaded scene."""

from __future__ import annotations

from . import bridge, session
from .model import BindError, settings


def bake(obj, scene, frames, progress=None) -> list[str]:
    """Write one keyframed shape key per frame; turns Live off and mutes the live output. Each
    frame is solved to convergence; iterative methods warm-start from the previous frame."""
    progress = progress or (lambda _f, _t: None)
    session.entry_for(obj, scene)
    s = settings(obj)
    names = []
    frames = list(frames)
    old = scene.frame_current
    s.live = False
    try:
        for i, f in enumerate(frames):
            bridge.frame_set(scene, f)
            dg = bridge.evaluated_depsgraph_from_scene(scene)
            names.append(bridge.bake_key(obj, f, session.compute(obj, scene, dg, budget=None)))
            progress((i + 1) / len(frames), f"Material Deform: baking frame {f}")
    finally:
        bridge.frame_set(scene, old)
    bridge.set_output_value(obj, 0.0, s.output_key_name or bridge.OUTPUT_KEY)
    return names


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
