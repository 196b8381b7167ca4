"""What every method shares: anchors and their Empties, the solver cache, staleness, the live
update and the output shape key.

Talks to Blender only through ``bridge``. Built solvers live in a module-level cache (never
saved) keyed by object pointer and validated by fingerprints that are saved on the object. The
active method (``methods``) is asked to gather its own inputs, to build a solver and to solve
for the anchor transforms; the session never branches on which method it is.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable

import numpy as np

from . import anchor_math as am
from . import bridge
from .inputs import gather, method_of
from .model import BindError, Entry, Inputs, settings

_cache: dict[int, Entry] = {}
_stale: dict[int, str] = {}  # object pointer -> why it cannot update
_last_mode: dict[int, str] = {}
_unsettled: set[int] = set()  # objects whose last live solve stopped on its iteration budget

# re-exported for the operators and the panel
__all__ = ["BindError", "Inputs", "Entry", "settings", "gather", "method_of"]


def stale_reason(obj) -> str:
    return _stale.get(obj.as_pointer(), "")


def cached_entry(obj) -> Entry | None:
    """The built solver of a bound object, None if there is none now (read-only use: a
    method's panel readout)."""
    return _cache.get(obj.as_pointer())


def clear_cache() -> None:
    _cache.clear()
    _stale.clear()
    _last_mode.clear()
    _unsettled.clear()


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


def mark_stale(obj, reason: str) -> None:
    """Something the fingerprints do not cover changed (e.g. the axes Empty turned): stop
    updating until the next Bind. Settings the fingerprints cover call
    :func:`settings_changed` instead, so that changing them back makes the bind valid again."""
    s = settings(obj) if bridge.is_mesh(obj) else None
    if s is not None and s.bound:
        s.rebind_reason = reason  # saved, so it also holds after reloading the file
        key = obj.as_pointer()
        _stale[key] = reason
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


def owner_of(obj, scene):
    """The mesh whose anchor (or anisotropy axes) ``obj`` drives, None if there is none: the
    panel and the object operators then act on that mesh while an Empty is selected."""
    if obj is None or obj.type != "EMPTY" or scene is None:
        return None
    for o in scene.objects:
        if o.type != "MESH":
            continue
        s = settings(o)
        if s.axes_empty == obj or any(a.empty == obj for a in s.anchors):
            return o
    return None


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


# --- public operations -------------------------------------------------------------------------


def _stored_obj_bind(obj) -> np.ndarray | None:
    m = np.array(tuple(settings(obj).obj_bind_matrix), dtype=np.float64).reshape(4, 4)
    return m if m.any() else None  # all zeros: bound before the object's matrix was kept


def has_bind_pose(anc) -> bool:
    """True if the anchor's stored bind matrix belongs to its current Empty."""
    return anc.empty is not None and anc.bound_empty == anc.empty


def _bind_pose(obj, keep: bool) -> tuple[np.ndarray, np.ndarray]:
    """(object matrix at bind (4,4), Empty matrices at bind (k,4,4)) for a bind. ``keep``:
    keep the bind pose stored by the last bind for every anchor that still has the same Empty
    (Rebind); an anchor without one (added since, or given another Empty) gets its Empty's
    current placement, carried back to where the object was at bind, so it starts at rest."""
    s = settings(obj)
    m_obj = bridge.world_matrix(obj)
    m_obj_bind = _stored_obj_bind(obj) if keep else None
    if m_obj_bind is None:
        m_obj_bind = m_obj
    # the object where it was at bind: exactly the Empties' matrices (no round-off, so the bind
    # pose evaluates to the rest shape bit for bit)
    back = None if np.array_equal(m_obj_bind, m_obj) else m_obj_bind @ am.affine_inverse(m_obj)
    mats = []
    for anc in s.anchors:
        if keep and has_bind_pose(anc):
            mats.append(np.array(tuple(anc.bind_matrix), dtype=np.float64).reshape(4, 4))
        else:
            m = bridge.world_matrix(anc.empty)
            mats.append(m if back is None else back @ m)
    return m_obj_bind, np.stack(mats)


def _pose_positions(obj, entry: Entry, m_obj_bind, bind_m, budget=None) -> np.ndarray:
    """Positions (n,3) of the full mesh for the Empties' current placement, measured from the
    given bind pose."""
    m_obj = bridge.world_matrix(obj)
    now = np.stack([bridge.world_matrix(a.empty) for a in settings(obj).anchors])
    if np.array_equal(now, bind_m) and np.array_equal(m_obj, m_obj_bind):
        return entry.rest.copy()
    try:
        t = am.anchor_transforms(m_obj, now, bind_m, m_obj_bind)
        res = method_of(obj).solve(entry.solver, t, entry.state, budget)
    except ValueError as exc:  # e.g. an Empty scaled to zero or mirrored (det <= 0)
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None
    if entry.used is None:
        return res.positions
    out = entry.rest.copy()
    out[entry.used] = res.positions
    return out


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
    m_obj_bind, bind_m = _bind_pose(obj, keep)
    progress(0.8, "Material Deform: solving the current pose")
    x = _pose_positions(obj, entry, m_obj_bind, bind_m)
    kb_name = s.output_key_name or bridge.OUTPUT_KEY
    if bridge.output_key(obj, kb_name) is None and bridge.output_key(obj) is not None:
        kb_name = bridge.OUTPUT_KEY  # an old key of the default name: reuse it
    progress(0.9, "Material Deform: writing shape key")
    # Everything above only read; from here on only writes that cannot fail on bad input.
    # The old solver goes first: it keeps the old bind matrices (_bind_matrices), which must
    # not outlive a write phase that stops half way.
    _cache.pop(obj.as_pointer(), None)
    method_of(obj).commit(obj, inp)
    for anc, m in zip(s.anchors, bind_m, strict=True):
        anc.bind_matrix = m.ravel().tolist()
        anc.bound_empty = anc.empty
    s.obj_bind_matrix = m_obj_bind.ravel().tolist()
    s.fp_topology, s.fp_anchors, s.fp_stiffness, s.fp_method = inp.fp
    had_keys = obj.data.shape_keys is not None
    kb, created = bridge.ensure_output_key(obj, kb_name)
    if not s.bound or not had_keys:
        s.created_basis = created
    s.output_key_name = kb.name
    bridge.write_key(obj, kb, x)  # at the bind pose: the rest shape exactly
    s.bound = True
    entry.last_key = _matrix_key(obj, None)
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


def place_new_anchor(obj, empty, vertices) -> None:
    """An anchor added to a bound, posed mesh: move its new Empty (made at the faces' rest
    place) onto the faces as the mesh shows them, by the rigid motion that best fits their
    rest positions to their posed ones, and give it the rest place as its bind pose. A rebind
    then keeps the mesh as it is instead of pulling these faces back to rest."""
    s = settings(obj)
    key = bridge.output_key(obj, s.output_key_name or bridge.OUTPUT_KEY)
    if not s.bound or key is None or bridge.is_reference_key(obj, key):
        return
    idx = np.asarray(vertices, dtype=np.int64)
    r = bridge.rest_positions(obj.data)[idx]
    x = bridge.shape_key_positions(obj, key.name)[idx]
    if len(idx) < 3 or not np.all(np.isfinite(x)) or np.allclose(x, r, atol=1e-7):
        return
    k = am.rigid_fit(r, x)  # (4,4) local rest -> posed
    m_obj = bridge.world_matrix(obj)
    m_obj_bind = _stored_obj_bind(obj)
    if m_obj_bind is None:
        m_obj_bind = m_obj
    rest_world = bridge.world_matrix(empty)
    inv_obj = am.affine_inverse(m_obj)
    bridge.set_world_matrix(empty, m_obj @ k @ inv_obj @ rest_world)
    anc = next(a for a in s.anchors if a.empty == empty)
    anc.bind_matrix = (m_obj_bind @ inv_obj @ rest_world).ravel().tolist()
    anc.bound_empty = empty
    entry = _cache.get(obj.as_pointer())
    if entry is not None:
        entry.extra.pop("bind_matrices", None)


def reset_empties(obj) -> int:
    """Put every anchor Empty back to its bind pose (relative to where the object is now), so
    the mesh is at its rest shape again. Returns how many Empties were moved."""
    s = settings(obj)
    m_obj = bridge.world_matrix(obj)
    m_obj_bind = _stored_obj_bind(obj)
    if m_obj_bind is None:
        m_obj_bind = m_obj
    ancs = [a for a in s.anchors if has_bind_pose(a)]
    if not ancs:
        raise BindError("No bind pose stored: click Bind first")
    carry = None  # the object has not moved: the stored matrices exactly (the rest shape)
    if not np.array_equal(m_obj, m_obj_bind):
        try:
            carry = m_obj @ am.affine_inverse(m_obj_bind)
        except ValueError as exc:
            raise BindError(f"Cannot place the Empties: {exc}") from None
    for anc in ancs:
        bind_m = np.array(tuple(anc.bind_matrix), dtype=np.float64).reshape(4, 4)
        bridge.set_world_matrix(anc.empty, bind_m if carry is None else carry @ bind_m)
    return len(ancs)


def _empty_reason(obj) -> str:
    """Why the stored bind pose no longer fits: an anchor was given another Empty."""
    for anc in settings(obj).anchors:
        if anc.bound_empty is not None and anc.bound_empty != anc.empty:
            return f"Anchor '{anc.name}' uses another Empty since bind - click Rebind"
    return ""


def unbind(obj) -> None:
    """Remove the output and forget the bind: the mesh is back to its rest shape bit for bit."""
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


def _anchor_empties(obj, scene, members=None):
    s = settings(obj)
    out = []
    for anc in s.anchors:
        if anc.empty is None or not bridge.object_in_scene(anc.empty, scene, members):
            raise BindError(
                f"Anchor '{anc.name}' has no Empty (removed or never assigned): assign one in "
                "the Anchors list, then Bind"
            )
        out.append(anc)
    return out


def _live_matrices(obj, depsgraph) -> tuple:
    """The world matrices one update needs, read once (each RNA read costs ~3.5 us): the
    object's, one per anchor (None without an Empty or when not evaluated; a (k,4,4) array
    when every anchor has one and no depsgraph is given) and the axes Empty's."""
    s = settings(obj)
    empties = [a.empty for a in s.anchors]
    if depsgraph is None and None not in empties:
        anchors = bridge.world_matrices(empties)
    else:
        anchors = [None if e is None else bridge.world_matrix(e, depsgraph) for e in empties]
    axes = None if s.axes_empty is None else bridge.world_matrix(s.axes_empty, depsgraph)
    return bridge.world_matrix(obj, depsgraph), anchors, axes


def _matrix_key(obj, depsgraph, mats=None) -> bytes:
    """Bytes that change when the object, an anchor's Empty or the axes Empty moved (turning the
    axes Empty after bind makes the bind stale)."""
    m_obj, anchors, axes = _live_matrices(obj, depsgraph) if mats is None else mats
    return b"".join(b"-" if m is None else m.tobytes() for m in (m_obj, *anchors, axes))


def _stop(obj, reason: str) -> BindError:
    """Record why this object cannot update until it is bound again; returns the error."""
    key = obj.as_pointer()
    _stale[key] = reason
    _cache.pop(key, None)
    return BindError(reason)


def _check_rest(obj, entry: Entry) -> None:
    """The live path's guard against a rest shape changed under the bind (Apply Scale, a
    script writing the Basis, vertices reordered): the Basis is compared with the bound rest
    bit for bit on every update (about 30 us at 25k vertices, docs/performance.md)."""
    buf = entry.extra.get("rest_buf")
    if buf is None:
        buf = entry.extra["rest_buf"] = np.empty_like(entry.rest_f32)
    if bridge.counts(obj.data) != entry.counts or not bridge.rest_unchanged(
        obj.data, entry.rest_f32, buf
    ):
        raise _stop(
            obj,
            "Rest shape changed since bind (Apply Scale, a script, or reordered vertices) - "
            "click Rebind",
        )


def _output_key(obj, entry: Entry):
    """The output key block, followed through a rename. Never the reference key."""
    s = settings(obj)
    kb = bridge.output_key(obj, s.output_key_name or bridge.OUTPUT_KEY, entry.key_pointer)
    if kb is None:
        raise _stop(
            obj,
            f"Output shape key '{s.output_key_name}' is gone (deleted or renamed before the "
            "file was saved): click Rebind to create it again",
        )
    if bridge.is_reference_key(obj, kb):
        raise _stop(
            obj,
            f"The Basis shape key was removed, so '{kb.name}' became the rest shape: undo "
            "(Ctrl+Z), or Reset and Bind again",
        )
    if kb.name != s.output_key_name:
        s.output_key_name = kb.name  # renamed by the user: keep writing to the same key
    entry.key_pointer = kb.as_pointer()
    return kb


def _bind_matrices(obj, entry: Entry) -> tuple:
    """(k,4,4) anchor and (4,4) object matrices at bind (None for files bound before the latter
    was kept), and the anchors' bytes; kept in the entry: they change only when binding (a new
    entry), placing an anchor and on undo, which drop them."""
    got = entry.extra.get("bind_matrices")
    if got is None:
        s = settings(obj)
        bind_m = np.array([tuple(a.bind_matrix) for a in s.anchors], dtype=np.float64)
        m_obj_bind = np.array(tuple(s.obj_bind_matrix), dtype=np.float64).reshape(4, 4)
        if not m_obj_bind.any():  # bound before the object's matrix was kept: never moved
            m_obj_bind = None
        bind_m = bind_m.reshape(-1, 4, 4)
        got = entry.extra["bind_matrices"] = (bind_m, m_obj_bind, (bind_m + 0.0).tobytes())
    return got


def transforms_now(
    obj, entry: Entry, scene, depsgraph=None, mats=None, members=None
) -> np.ndarray | None:
    """(k,4,4) motion of every anchor since bind in the mesh's local space, None at the bind
    pose exactly. Anchor faces follow their Empty in world space: for a vertex at local x,
    ``inv(M_obj) M_now inv(M_bind) M_obj_bind x``, right also for Empties parented to the mesh
    and for an object moved or animated since bind. ``mats``: this update's
    :func:`_live_matrices`, if already read; ``members``: the scene's objects as a set (see
    :func:`bridge.object_in_scene`)."""
    ancs = _anchor_empties(obj, scene, members)
    if len(ancs) != entry.n_anchors:
        raise BindError("Anchors changed since bind - click Rebind")
    m_obj, mats, _ = _live_matrices(obj, depsgraph) if mats is None else mats
    for a, m in zip(ancs, mats, strict=True):
        if m is None:
            raise BindError(
                f"Anchor '{a.name}': Empty '{a.empty.name}' is not evaluated here "
                "(disabled in renders?)"
            )
    if m_obj is None:
        raise BindError("Object is not evaluated here")
    now = mats if isinstance(mats, np.ndarray) else np.stack(mats)
    bind_m, m_obj_bind, bind_bytes = _bind_matrices(obj, entry)
    if m_obj_bind is None:  # as if the object never moved
        m_obj_bind = m_obj
    # Compared as bytes, 3 us less than np.array_equal; + 0.0 turns -0.0 into 0.0 first.
    if (now + 0.0).tobytes() == bind_bytes and (
        m_obj is m_obj_bind or (m_obj + 0.0).tobytes() == (m_obj_bind + 0.0).tobytes()
    ):
        return None
    try:
        return entry.extra.setdefault("pose", am.PoseTransforms())(m_obj, now, bind_m, m_obj_bind)
    except ValueError as exc:  # e.g. the object scaled to zero
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None


def compute(
    obj,
    scene,
    depsgraph=None,
    budget: int | str | None = "live",
    entry=None,
    mats=None,
    progress=None,
    members=None,
) -> np.ndarray:
    """Deformed positions (n,3) (float64, or float32 from a method that rounds for the key)
    for the current Empty transforms. ``budget``: "live"
    (the method's per-update iteration budget), an int, or None (run to convergence).
    ``entry`` (from :func:`entry_for`) and ``mats`` (:func:`_live_matrices`): already at hand
    in :func:`apply`. ``progress``: see :meth:`methods.Method.solve`. ``members``: see
    :func:`transforms_now`."""
    if entry is None:
        entry = entry_for(obj, scene)
    key = obj.as_pointer()
    method = _live_checks(obj, entry, depsgraph)
    t = transforms_now(obj, entry, scene, depsgraph, mats, members)
    if t is None:
        # the bind pose is the rest shape exactly, as Bind writes it (the solver would add
        # round-off): re-evaluating it after undo or reloading leaves the key as it was
        entry.state.clear()
        _unsettled.discard(key)
        return entry.rest.copy()
    if budget == "live":
        budget = method.live_budget(obj)
    try:
        res = method.solve(entry.solver, t, entry.state, budget, progress)
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


def _settings_signature(obj) -> bytes:
    """The method and the values of its own settings (what a live result depends on beyond
    the bind and the matrices)."""
    method = method_of(obj)
    vals: list = [method.key]
    group = getattr(settings(obj), method.settings_name) if method.settings_name else None
    if group is not None:
        for prop in group.bl_rna.properties:
            if prop.identifier == "rna_type":
                continue
            v = getattr(group, prop.identifier)
            if hasattr(v, "name"):  # an ID (an Empty)
                v = v.name
            elif hasattr(v, "__len__") and not isinstance(v, str):
                v = tuple(v)
            vals.append((prop.identifier, v))
    return repr(vals).encode()


def _record(obj, entry: Entry, mkey: bytes, settled: bool) -> str:
    """What the output key holds: a digest of the pose (the matrices) and the settings, and
    whether the result had settled. Saved with the key, so after undo or reloading the file
    the session knows whether the key already holds this pose."""
    sig = entry.extra.get("settings_sig")
    if sig is None:
        sig = entry.extra["settings_sig"] = _settings_signature(obj)
    digest = hashlib.blake2b(mkey + b"|" + sig, digest_size=16).hexdigest()
    return f"{digest}:{int(settled)}"


def _resume(obj, entry: Entry, scene, kb, mkey: bytes, depsgraph, mats, members=None) -> bool:
    """A fresh cache entry of an iterative method (the file was loaded, or undo restored the
    key): True if the key holds the settled result of this very pose, which is then kept bit
    for bit (solving again could reach another fixed point). If it holds an unsettled one, the
    method continues from it instead of starting over. Direct methods just solve again."""
    if not method_of(obj).iterative:
        return False  # a direct solve gives the same bits again (and refills the method state)
    held = bridge.key_record(obj)
    if not held or held.rsplit(":", 1)[0] != _record(obj, entry, mkey, True).rsplit(":", 1)[0]:
        return False
    method = _live_checks(obj, entry, depsgraph)
    transforms_now(obj, entry, scene, depsgraph, mats, members)  # what a solve refuses: raises
    if held.endswith(":1"):
        entry.last_key = mkey
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
    """Write the deformation into the output shape key if any driver moved (or the last solve
    had not converged yet). True if written. Never writes a non-finite result (BindError).
    ``progress``: see :meth:`methods.Method.solve`. ``members``: the scene's objects as a set,
    if at hand (:func:`live_update`)."""
    entry = entry_for(obj, scene)
    mats = _live_matrices(obj, depsgraph)
    mkey = _matrix_key(obj, depsgraph, mats)
    kb = _output_key(obj, entry)
    key = obj.as_pointer()
    if not force and mkey == entry.last_key and key not in _unsettled:
        return False
    if force:
        entry.extra.pop("settings_sig", None)  # Update, Settle, a setting's callback
    elif entry.last_key is None and not entry.state:
        if _resume(obj, entry, scene, kb, mkey, depsgraph, mats, members):
            return False
    x = compute(obj, scene, depsgraph, budget, entry, mats, progress, members)
    bridge.write_key(obj, kb, check_finite(obj, entry, x))
    bridge.set_key_record(obj, _record(obj, entry, mkey, settled=key not in _unsettled))
    entry.last_key = mkey
    return True


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_finite(obj, entry: Entry, x: np.ndarray) -> np.ndarray:
    """x as the contiguous float32 (n,3) array that keys and point caches store; BindError
    unless every coordinate of it is finite (a float64 beyond float32's range becomes inf).
    The method's state is dropped then: an iterative method must not continue from that
    iterate."""
    if x.dtype == np.float32:  # rounded by the solver already (errstate costs ~10 us)
        x32 = np.ascontiguousarray(x)
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            x32 = np.ascontiguousarray(x, dtype=np.float32)
    flat = x32.reshape(-1)
    # Two reductions on the float32 copy the key write needs anyway (~10 us at 50k faces);
    # NaN propagates through both and fails the comparison. Not a dot product: numpy hands one
    # of 75k entries to OpenBLAS's threads, and OpenBLAS's worker then competes for the two
    # cores with the solver's task pool (the median 50k live update went from ~4 to ~2 ms).
    lo, hi = (float(flat.min()), float(flat.max())) if flat.size else (0.0, 0.0)
    if not (-_FLOAT32_MAX <= lo and hi <= _FLOAT32_MAX):
        entry.state.clear()
        _unsettled.discard(obj.as_pointer())
        raise BindError(
            f"Cannot pose '{obj.name}': the solver returned coordinates that are not finite "
            "(the shape key keeps its last result)"
        )
    return x32


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


def settle(obj, scene, depsgraph=None, progress=None) -> None:
    """Solve the current pose to convergence and write it (Settle; plain update for direct
    methods). ``progress(fraction, text)``: called now and then by iterative methods."""
    apply(obj, scene, depsgraph, force=True, budget=None, progress=progress)


def record_failure(obj, reason: str) -> None:
    """Keep ``reason`` as why ``obj`` does not update (shown in the panel)."""
    _stale[obj.as_pointer()] = reason


def unsettled() -> bool:
    """True while some object's live result is still converging: the handlers then keep
    calling :func:`live_update` from a timer until every result has settled."""
    return bool(_unsettled)


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
