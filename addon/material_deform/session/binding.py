"""Bind and the solver cache: building the active method's solver, Rebind and Reset, and
whether a cached or saved bind still fits the object (its fingerprints), after a file is
loaded, after undo and when a setting the bind depends on changes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import anchor_math as am
from .. import bridge
from ..inputs import gather, method_of, shared_mesh_message
from ..model import BindError, Entry, Inputs, settings
from . import twist
from .output import _record
from .pose import _bind_pose, _empty_reason, _matrix_key, has_bind_pose
from .state import _cache, _stale, _stop, _unsettled


def _build(inp: Inputs, obj) -> Entry:
    method = method_of(obj)
    solver = method.build(inp)
    return Entry(
        method=method.key,
        solver=solver,
        fp=inp.fp,
        counts=bridge.counts(obj.data),
        rest=inp.arrays.rest,
        rest_f32=inp.arrays.rest.astype(np.float32),
        used=inp.used,
        n_anchors=len(inp.anchor_faces),
    )


def _stored_fp(obj) -> tuple:
    s = settings(obj)
    return s.fp_topology, s.fp_anchors, s.fp_stiffness, s.fp_method


def _diff_reason(obj, stored, current) -> str:
    try:
        what_method = method_of(obj).fingerprint_what
    except BindError:
        what_method = "method"
    what = ("mesh (topology or rest shape)", "anchors", "stiffness", what_method)
    changed = [w for w, a, b in zip(what, stored, current, strict=True) if a != b]
    return "Changed since bind: " + ", ".join(changed) + " - click Rebind"


def _pose_positions(
    obj, scene, entry: Entry, m_obj_bind, bind_m, frames, shown, budget=None
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n,3) of the full mesh for the Empties' current placement, measured from the
    given bind pose (bind frames ``frames`` (k,); ``shown``: the vectors to continue followed
    anchors from, or None), and the anchors' rotation vectors (k,3)."""
    m_obj = bridge.world_matrix(obj)
    now = np.stack([bridge.world_matrix(a.empty) for a in settings(obj).anchors])
    at_rest = np.array_equal(now, bind_m) and np.array_equal(m_obj, m_obj_bind)
    tw = entry.extra["twist"] = twist.Twist(shown)
    try:
        t = None if at_rest else am.anchor_transforms(m_obj, now, bind_m, m_obj_bind)
        bind = (bind_m, m_obj_bind, b"", np.asarray(frames, dtype=np.int64))
        frame, mkey = bridge.scene_frame(scene), _matrix_key(obj, None)
        v, rotations = tw.vectors(obj, scene, frame, mkey, lambda: t, bind, m_obj, full=True)
        if t is None and rotations is None:
            return entry.rest.copy(), v
        if t is None:
            t = np.tile(np.eye(4), (len(bind_m), 1, 1))
        res = method_of(obj).solve(entry.solver, t, entry.state, budget, rotations=rotations)
    except ValueError as exc:  # e.g. an Empty scaled to zero or mirrored (det <= 0)
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None
    if entry.used is None:
        return res.positions, v
    out = entry.rest.copy()
    out[entry.used] = res.positions
    return out, v


def bind(
    obj,
    scene,
    progress: Callable[[float, str], None] | None = None,
    at_current_pose: bool = False,
) -> Entry:
    """Build the active method's solver. A first bind makes the Empties' current placement
    the bind pose (the mesh stays at rest). A rebind keeps the bind pose, so the mesh keeps
    its pose and the Empties stay on their faces; ``at_current_pose`` makes the current
    placement the new bind pose instead (the mesh goes back to its rest shape where the
    Empties are now). Atomic: nothing on the object changes unless every step succeeds."""
    progress = progress or (lambda _f, _t: None)
    s = settings(obj)
    keep = s.bound and not at_current_pose
    progress(0.05, "Material Deform: reading mesh")
    inp = gather(obj, scene, binding=True)
    progress(0.3, "Material Deform: precomputing the solver")
    entry = _build(inp, obj)
    for anc, faces in zip(s.anchors, inp.anchor_faces, strict=True):
        n = am.face_regions(inp.arrays.tris[faces])
        if n > 1:  # e.g. stiffness painted into the anchor's group by mistake
            entry.warnings.append(
                f"Anchor '{anc.name}' holds {n} separate regions of faces, all pinned to one "
                "Empty: if that is not meant, fix its vertex group and Rebind"
            )
    m_obj_bind, bind_m = _bind_pose(obj, keep)
    # an anchor keeping its bind pose keeps its bind frame and its turns; the others start now
    kept = np.array([keep and has_bind_pose(a) for a in s.anchors], dtype=bool)
    now = scene.frame_current
    frames = [a.bind_frame if k else now for a, k in zip(s.anchors, kept, strict=True)]
    shown = bridge.key_rotations(obj, len(s.anchors)) if s.bound else None
    if shown is not None:
        shown[~kept] = 0.0
    progress(0.8, "Material Deform: solving the current pose")
    x, vectors = _pose_positions(obj, scene, entry, m_obj_bind, bind_m, frames, shown)
    kb_name = s.output_key_name or bridge.OUTPUT_KEY
    if bridge.output_key(obj, kb_name) is None and bridge.output_key(obj) is not None:
        kb_name = bridge.OUTPUT_KEY  # an old key of the default name: reuse it
    progress(0.9, "Material Deform: writing shape key")
    # Everything above only read; from here on only writes that cannot fail on bad input.
    # The old solver goes first: it keeps the old bind matrices (_bind_matrices), which must
    # not outlive a write phase that stops half way.
    _cache.pop(obj.as_pointer(), None)
    method_of(obj).commit(obj, inp)
    for anc, m, f in zip(s.anchors, bind_m, frames, strict=True):
        anc.bind_matrix = m.ravel().tolist()
        anc.bind_frame = f
        anc.bound_empty = anc.empty
    s.obj_bind_matrix = m_obj_bind.ravel().tolist()
    s.fp_topology, s.fp_anchors, s.fp_stiffness, s.fp_method = inp.fp
    had_keys = obj.data.shape_keys is not None
    kb, created = bridge.ensure_output_key(obj, kb_name)
    if not s.bound or not had_keys:
        s.created_basis = created
    s.output_key_name = kb.name
    bridge.write_key(obj, kb, x)  # at the bind pose: the rest shape exactly
    bridge.set_key_rotations(obj, vectors)
    s.bound = True
    rotations = twist.principal_or(vectors)
    entry.last_key = _matrix_key(obj, None) + (b"" if rotations is None else rotations.tobytes())
    entry.extra["twist"].unsaved = False
    # Bind solves a kept pose without the live settings (they reach an iterative method only
    # through the live checks): its result counts as settled only at the bind pose itself
    at_rest = x is entry.rest or np.array_equal(x, entry.rest)
    settled = at_rest or not method_of(obj).iterative
    bridge.set_key_record(obj, _record(obj, entry, entry.last_key, settled=settled))
    s.rebind_reason = ""
    key = obj.as_pointer()
    entry.key_pointer = kb.as_pointer()
    _cache[key] = entry
    _stale.pop(key, None)
    _unsettled.discard(key)
    progress(1.0, "")
    return entry


def unbind(obj) -> None:
    """Remove the output and forget the bind: the mesh is back to its rest shape bit for bit.
    Refused when another object uses the mesh: its keys would go with this object's."""
    why = bridge.not_editable(obj)
    if why:
        raise BindError(why)
    shared = bridge.mesh_sharers(obj)
    if shared:
        raise BindError(shared_mesh_message(obj, shared, then="Reset"))
    s = settings(obj)
    key = obj.as_pointer()
    entry = _cache.get(key)
    name = s.output_key_name or bridge.OUTPUT_KEY
    bridge.remove_output(obj, s.created_basis, name, entry.key_pointer if entry else 0)
    s.bound = False
    s.rebind_reason = ""
    s.created_basis = False
    s.fp_topology = s.fp_anchors = s.fp_stiffness = s.fp_method = ""
    _cache.pop(key, None)
    _stale.pop(key, None)
    _unsettled.discard(key)


def entry_for(obj, scene) -> Entry:
    """Cached solver for a bound object, rebuilt (e.g. after loading a .blend or undo) only if
    the saved fingerprint still matches. Raises BindError otherwise."""
    s = settings(obj)
    key = obj.as_pointer()
    if not s.bound:
        raise BindError("Not bound: click Bind")
    if s.rebind_reason:
        _stale[key] = s.rebind_reason
        _cache.pop(key, None)
        raise BindError(s.rebind_reason)
    reason = _empty_reason(obj)
    if reason:
        raise _stop(obj, reason)
    entry = _cache.get(key)
    if (
        entry is not None
        and entry.fp == _stored_fp(obj)
        and entry.counts == bridge.counts(obj.data)
        and entry.method == s.method
    ):
        return entry
    _cache.pop(key, None)
    if key in _stale and entry is None:
        raise BindError(_stale[key])
    try:
        inp = gather(obj, scene)
    except BindError as exc:
        _stale[key] = f"Cannot update: {exc}"
        raise BindError(_stale[key]) from exc
    if inp.fp != _stored_fp(obj):
        _stale[key] = _diff_reason(obj, _stored_fp(obj), inp.fp)
        raise BindError(_stale[key])
    entry = _build(inp, obj)
    _cache[key] = entry
    _stale.pop(key, None)
    return entry


def full_check(obj, scene) -> str:
    """Re-read mesh, anchors and stiffness and compare to the bind; returns '' if unchanged."""
    key = obj.as_pointer()
    s = settings(obj)
    if not s.bound:
        return ""
    if s.rebind_reason:
        _stale[key] = s.rebind_reason
        return s.rebind_reason
    reason = _empty_reason(obj)
    if reason:
        _stop(obj, reason)
        return reason
    try:
        inp = gather(obj, scene, build=False)
    except BindError as exc:
        _stale[key] = f"Cannot update: {exc}"
        _cache.pop(key, None)
        return _stale[key]
    if inp.fp != _stored_fp(obj):
        _stale[key] = _diff_reason(obj, _stored_fp(obj), inp.fp)
        _cache.pop(key, None)
        return _stale[key]
    _stale.pop(key, None)
    return ""


def after_undo(scene, objects) -> None:
    """Undo/redo loaded other saved data under the cache. Memfile undo keeps the objects'
    addresses, so cached solvers and stale verdicts would still be found but may belong to
    another state: drop the solvers of objects that are no longer bound, forget every verdict
    and re-check the bound objects of the scene against their mesh (as after the operators).
    Objects in Edit Mode are checked when they leave it (``live_update``)."""
    bound = {o.as_pointer() for o in objects if bridge.is_mesh(o) and settings(o).bound}
    for key in [k for k in _cache if k not in bound]:
        del _cache[key]
    _stale.clear()
    _unsettled.clear()
    for entry in _cache.values():  # every scene's objects: undo restores all of them
        # the output key and its record were restored too: the next update keeps the key if
        # the record says it holds that pose settled, else solves from what the key holds
        entry.last_key = None
        entry.state.clear()
        entry.extra.pop("settings_sig", None)  # and the settings may be other ones
        entry.extra.pop("bind_matrices", None)  # so were the bind matrices
        # and the vectors saved with the key; the animation may be another one too
        entry.extra.pop("twist", None)
        entry.key_pointer = 0  # and its block may live elsewhere now
    for obj in scene.objects:
        key = obj.as_pointer()
        if key not in bound:
            continue
        if obj.mode == "OBJECT":
            try:
                full_check(obj, scene)
            except Exception as exc:  # runs in a handler: never raise into Blender
                _stale[key] = f"Check failed: {exc}"
                _cache.pop(key, None)


def settings_changed(obj, scene=None) -> None:
    """A setting the bind depends on changed (a property's update callback): drop the solver
    and compare the object with its bound state again, now in Object Mode (otherwise when it
    leaves Edit Mode). Ticking and unticking a box leaves the bind as valid as it was."""
    if not bridge.is_mesh(obj) or not settings(obj).bound:
        return
    key = obj.as_pointer()
    _cache.pop(key, None)
    _stale.pop(key, None)
    if scene is not None and obj.mode == "OBJECT":
        try:
            full_check(obj, scene)
        except Exception as exc:  # an update callback must never raise into Blender
            _stale[key] = f"Check failed: {exc}"


def resolve_live(obj) -> None:
    """A live setting changed (one the bind does not depend on, e.g. an iterative method's
    tolerance): the next live update solves the current pose again instead of skipping it."""
    if not bridge.is_mesh(obj) or not settings(obj).bound:
        return
    entry = _cache.get(obj.as_pointer())
    if entry is not None:
        entry.last_key = None
        entry.extra.pop("settings_sig", None)
    obj.update_tag()
