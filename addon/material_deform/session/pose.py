"""The anchors' Empties and the bind pose: where the Empties were at bind, putting them back or
onto a new anchor's faces, and each anchor's motion since bind (the transforms every method
solves for), read once per live update."""

from __future__ import annotations

import numpy as np

from .. import anchor_math as am
from .. import bridge
from ..inputs import method_of
from ..methods import all_methods
from ..model import BindError, Entry, settings
from .state import _cache


def owner_of(obj, scene):
    """The mesh whose anchor (or a method's watched Empty, e.g. anisotropy axes) ``obj``
    drives, None if there is none: the panel and the object operators then act on that mesh
    while an Empty is selected."""
    if obj is None or obj.type != "EMPTY" or scene is None:
        return None
    for o in scene.objects:
        if o.type != "MESH":
            continue
        if any(a.empty == obj for a in settings(o).anchors) or any(
            obj in m.watched_objects(o) for m in all_methods()
        ):
            return o
    return None


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


def _empty_reason(obj) -> str:
    """Why the stored bind pose no longer fits: an anchor was given another Empty."""
    for anc in settings(obj).anchors:
        if anc.bound_empty is not None and anc.bound_empty != anc.empty:
            return f"Anchor '{anc.name}' uses another Empty since bind - click Rebind"
    return ""


def place_new_anchor(obj, empty, vertices, frame: int) -> None:
    """An anchor added to a bound, posed mesh: move its new Empty (made at the faces' rest
    place) onto the faces as the mesh shows them, by the rigid motion that best fits their
    rest positions to their posed ones, and give it the rest place as its bind pose (at
    ``frame``, the scene's). A rebind then keeps the mesh as it is instead of pulling these
    faces back to rest."""
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
    anc.bind_frame = frame
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


def _anchor_empties(obj, scene, members=None):
    s = settings(obj)
    out = []
    for anc in s.anchors:
        if anc.empty is None:
            raise BindError(
                f"Anchor '{anc.name}' has no Empty (removed or never assigned): assign one in "
                "the Anchors list, then Bind"
            )
        if not bridge.object_in_scene(anc.empty, scene, members):
            raise BindError(
                f"Anchor '{anc.name}': Empty '{anc.empty.name}' is not in the scene: link it "
                "back, or assign another and Bind"
            )
        out.append(anc)
    return out


def _live_matrices(obj, depsgraph) -> tuple:
    """The world matrices one update needs, read once (each RNA read costs ~3.5 us): the
    object's, one per anchor (None without an Empty or when not evaluated; a (k,4,4) array
    when every anchor has one and no depsgraph is given) and a list, one per object the
    active method watches (:meth:`methods.Method.watched_objects`)."""
    s = settings(obj)
    empties = [a.empty for a in s.anchors]
    if depsgraph is None and None not in empties:
        anchors = bridge.world_matrices(empties)
    else:
        anchors = [None if e is None else bridge.world_matrix(e, depsgraph) for e in empties]
    watched = [
        bridge.world_matrix(o, depsgraph)
        for o in method_of(obj).watched_objects(obj)
        if o is not None
    ]
    return bridge.world_matrix(obj, depsgraph), anchors, watched


def _matrix_key(obj, depsgraph, mats=None) -> bytes:
    """Bytes that change when the object, an anchor's Empty or a watched object moved (turning
    e.g. the axes Empty after bind makes the bind stale)."""
    m_obj, anchors, watched = _live_matrices(obj, depsgraph) if mats is None else mats
    return b"".join(b"-" if m is None else m.tobytes() for m in (m_obj, *anchors, *watched))


def _bind_matrices(obj, entry: Entry) -> tuple:
    """(k,4,4) anchor and (4,4) object matrices at bind (None for files bound before the latter
    was kept), the anchors' bytes and their (k,) bind frames; kept in the entry: they change
    only when binding (a new entry), placing an anchor and on undo, which drop them."""
    got = entry.extra.get("bind_matrices")
    if got is None:
        s = settings(obj)
        bind_m = np.array([tuple(a.bind_matrix) for a in s.anchors], dtype=np.float64)
        m_obj_bind = np.array(tuple(s.obj_bind_matrix), dtype=np.float64).reshape(4, 4)
        if not m_obj_bind.any():  # bound before the object's matrix was kept: never moved
            m_obj_bind = None
        bind_m = bind_m.reshape(-1, 4, 4)
        frames = np.array([a.bind_frame for a in s.anchors], dtype=np.int64)
        got = (bind_m, m_obj_bind, (bind_m + 0.0).tobytes(), frames)
        entry.extra["bind_matrices"] = got
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
    bind_m, m_obj_bind, bind_bytes, _frames = _bind_matrices(obj, entry)
    if m_obj_bind is None:  # as if the object never moved
        m_obj_bind = m_obj
    # Compared as bytes, 3 us less than np.array_equal; + 0.0 turns -0.0 into 0.0 first.
    if (now + 0.0).tobytes() == bind_bytes and (
        m_obj is m_obj_bind or (m_obj + 0.0).tobytes() == (m_obj_bind + 0.0).tobytes()
    ):
        return None
    try:
        t = entry.extra.setdefault("pose", am.PoseTransforms())(m_obj, now, bind_m, m_obj_bind)
    except ValueError as exc:  # e.g. the object scaled to zero
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None
    # An Empty scaled to zero would collapse its anchor faces to a point: refused for every
    # method alike (the material-aware core needs det > 0 anyway).
    flat = am.singular(t)
    if len(flat):
        a = ancs[int(flat[0])]
        raise BindError(
            f"Cannot pose '{obj.name}': Empty '{a.empty.name}' of anchor '{a.name}' is scaled "
            "to zero along some axis; give it a non-zero scale"
        )
    return t
