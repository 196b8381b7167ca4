"""The live update: solving the pose the Empties give now and writing it into the output key,
skipped when nothing moved; an iterative method keeps settling over later updates. Also Update,
Settle and the handler body that updates every bound object of a scene."""

from __future__ import annotations

import numpy as np

from .. import bridge
from ..inputs import method_of
from ..model import BindError, Entry, settings
from . import twist
from .binding import entry_for, full_check
from .output import _check_rest, _output_key, _record, check_finite
from .pose import _bind_matrices, _live_matrices, _matrix_key, transforms_now
from .state import _cache, _last_mode, _stale, _unsettled, mark_stale, record_failure


def compute(
    obj,
    scene,
    depsgraph=None,
    budget: int | str | None = "live",
    entry=None,
    mats=None,
    progress=None,
    members=None,
    pose=None,
) -> np.ndarray:
    """Deformed positions (n,3) (float64, or float32 from a method that rounds for the key)
    for the current Empty transforms. ``budget``: "live"
    (the method's per-update iteration budget), an int, or None (run to convergence).
    ``entry`` (from :func:`entry_for`) and ``mats`` (:func:`_live_matrices`): already at hand
    in :func:`apply`. ``progress``: see :meth:`methods.Method.solve`. ``members``: see
    :func:`transforms_now`. ``pose``: :func:`_pose`'s (transforms, rotations), if at hand."""
    if entry is None:
        entry = entry_for(obj, scene)
    key = obj.as_pointer()
    method = _live_checks(obj, entry, depsgraph)
    if pose is None:
        if mats is None:
            mats = _live_matrices(obj, depsgraph)
        mkey = _matrix_key(obj, depsgraph, mats)
        pose = _pose(obj, entry, scene, depsgraph, mats, members, mkey, full=budget is None)
    transforms, rotations = pose
    t = transforms()
    if t is None and rotations is None:
        # the bind pose is the rest shape exactly, as Bind writes it (the solver would add
        # round-off): re-evaluating it after undo or reloading leaves the key as it was
        entry.state.clear()
        _unsettled.discard(key)
        return entry.rest.copy()
    if t is None:  # the bind matrices, with whole turns: not the rest shape
        t = np.tile(np.eye(4), (entry.n_anchors, 1, 1))
    if budget == "live":
        budget = method.live_budget(obj)
    try:
        res = method.solve(entry.solver, t, entry.state, budget, progress, rotations=rotations)
    except ValueError as exc:  # e.g. an Empty scaled to zero or mirrored (det <= 0)
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None
    if res.done:
        _unsettled.discard(key)
    else:
        _unsettled.add(key)
    if entry.used is None:
        return res.positions
    out = entry.rest.copy()
    out[entry.used] = res.positions
    return out


def _pose(obj, entry: Entry, scene, depsgraph, mats, members, mkey: bytes, full=False):
    """(transforms, rotations) of this update: a callable giving the anchor transforms
    (:func:`transforms_now`, computed once, when first asked for) and the (k,3) rotation
    vectors the methods blend (:mod:`twist`), None when every anchor turned by less than half
    a turn. ``full``: check the anchors' animation against the cached one in full."""
    got = []

    def transforms():
        if not got:
            got.append(transforms_now(obj, entry, scene, depsgraph, mats, members))
        return got[0]

    m_obj, anchors, _axes = mats
    if m_obj is None or (not isinstance(anchors, np.ndarray) and any(m is None for m in anchors)):
        transforms()  # says what is missing
    tw = entry.extra.get("twist")
    if tw is None:
        tw = entry.extra["twist"] = twist.Twist(bridge.key_rotations(obj, entry.n_anchors))
    bind = _bind_matrices(obj, entry)
    if len(bind[0]) != entry.n_anchors:
        transforms()  # "Anchors changed since bind"
    frame = bridge.scene_frame(scene)
    _v, rotations = tw.vectors(obj, scene, frame, mkey, transforms, bind, m_obj, full)
    return transforms, rotations


def _live_checks(obj, entry: Entry, depsgraph):
    """What every solve checks first (the rest shape, the method's live inputs); returns the
    method."""
    _check_rest(obj, entry)
    method = method_of(obj)
    try:
        method.check_live(obj, entry, depsgraph)
    except BindError as exc:
        mark_stale(obj, str(exc))
        raise
    return method


def _resume(obj, entry: Entry, scene, kb, pkey: bytes, depsgraph, mats, members=None) -> bool:
    """A fresh cache entry of an iterative method (the file was loaded, or undo restored the
    key): True if the key holds the settled result of this very pose, which is then kept bit
    for bit (solving again could reach another fixed point). If it holds an unsettled one, the
    method continues from it instead of starting over. Direct methods just solve again."""
    if not method_of(obj).iterative:
        return False  # a direct solve gives the same bits again (and refills the method state)
    held = bridge.key_record(obj)
    if not held or held.rsplit(":", 1)[0] != _record(obj, entry, pkey, True).rsplit(":", 1)[0]:
        return False
    method = _live_checks(obj, entry, depsgraph)
    transforms_now(obj, entry, scene, depsgraph, mats, members)  # what a solve refuses: raises
    if held.endswith(":1"):
        entry.last_key = pkey
        _unsettled.discard(obj.as_pointer())
        return True
    flat = np.empty(3 * len(kb.data), np.float32)
    bridge.read_key_into(kb, flat)
    pos = flat.reshape(-1, 3).astype(np.float64)
    method.seed(entry.solver, entry.state, pos if entry.used is None else pos[entry.used])
    return False


def apply(
    obj, scene, depsgraph=None, force: bool = False, budget="live", progress=None, members=None
) -> bool:
    """Write the deformation into the output shape key if any driver moved, an anchor's turns
    changed (or the last solve had not converged yet). True if written. Never writes a
    non-finite result (BindError). ``progress``: see :meth:`methods.Method.solve`.
    ``members``: the scene's objects as a set, if at hand (:func:`live_update`)."""
    entry = entry_for(obj, scene)
    mats = _live_matrices(obj, depsgraph)
    mkey = _matrix_key(obj, depsgraph, mats)
    kb = _output_key(obj, entry)
    key = obj.as_pointer()
    pose = _pose(obj, entry, scene, depsgraph, mats, members, mkey, full=force)
    rotations = pose[1]
    # the pose: the matrices and, past half a turn, the turns (the same matrices at another
    # frame of an animation can carry other turns)
    pkey = mkey if rotations is None else mkey + rotations.tobytes()
    if not force and pkey == entry.last_key and key not in _unsettled:
        return False
    if force:
        entry.extra.pop("settings_sig", None)  # Update, Settle, a setting's callback
    elif entry.last_key is None and not entry.state:
        if _resume(obj, entry, scene, kb, pkey, depsgraph, mats, members):
            return False
    x = compute(obj, scene, depsgraph, budget, entry, mats, progress, members, pose)
    bridge.write_key(obj, kb, check_finite(obj, entry, x))
    bridge.set_key_record(obj, _record(obj, entry, pkey, settled=key not in _unsettled))
    _save_rotations(obj, entry)
    entry.last_key = pkey
    return True


def _save_rotations(obj, entry: Entry) -> None:
    """Save the vectors the key now shows with it when a followed anchor's changed, so that it
    continues from them after undo, reloading, or in a farm's fresh process (an animated
    anchor's come from its animation: playback writes nothing)."""
    tw = entry.extra.get("twist")
    if tw is not None and tw.unsaved and tw.shown is not None:
        bridge.set_key_rotations(obj, tw.shown)
        tw.unsaved = False


def solve_now(obj, scene) -> None:
    """A live setting changed and its effect shows at once: solve the pose again and write it.
    A failure becomes the stale reason (a property's update callback must never raise)."""
    try:
        apply(obj, scene, force=True)
    except Exception as exc:
        record_failure(obj, str(exc))


def settle(obj, scene, depsgraph=None, progress=None) -> None:
    """Solve the current pose to convergence and write it (Settle; plain update for direct
    methods). ``progress(fraction, text)``: called now and then by iterative methods."""
    apply(obj, scene, depsgraph, force=True, budget=None, progress=progress)


def solve_status(obj) -> tuple[bool, str] | None:
    """(converged, text) of the last solve of an iterative method (sweeps, last move), None
    for direct methods or before the first solve."""
    entry = _cache.get(obj.as_pointer())
    if entry is None:
        return None
    try:
        return method_of(obj).status(entry.state)
    except BindError:
        return None


def live_update(scene, depsgraph=None, budget="live") -> None:
    """Handler body: update every bound, live object of the scene. Errors are recorded as
    stale reasons (shown in the panel), never raised into Blender. ``budget``: "live" (the
    methods' per-update budgets) or None: frames of a render, each solved to convergence as
    Bake solves it, even where the key already holds a (live) result of that pose."""
    objs = scene.objects[:]  # one RNA pass, also the membership test of the anchor Empties
    members = None
    for obj in objs:
        if obj.type != "MESH":
            continue
        s = settings(obj)
        if not (s.bound and s.live):
            continue
        if members is None:
            members = set(objs)
        key = obj.as_pointer()
        mode, prev = obj.mode, _last_mode.get(key, "OBJECT")
        _last_mode[key] = mode
        if mode != "OBJECT":
            continue  # never fight Edit/Paint modes
        if prev != "OBJECT" and full_check(obj, scene):
            continue
        try:
            wrote = apply(
                obj, scene, depsgraph, force=budget is None, budget=budget, members=members
            )
        except Exception as exc:  # a handler must never take Blender down
            _unsettled.discard(key)
            msg = str(exc) if isinstance(exc, BindError) else f"Update failed: {exc}"
            if _stale.get(key) != msg:
                print(f"Material Deform: '{obj.name}' not updated: {msg}")  # background runs
            _stale[key] = msg
        else:
            if wrote:  # e.g. a pose that failed (an Empty scaled to zero) is fixed now
                _stale.pop(key, None)
