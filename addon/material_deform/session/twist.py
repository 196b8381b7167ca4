"""Turns past half a turn: which branch of each anchor's rotation log the methods blend.

A rotation by 200 degrees is also one by -160 degrees; the solve needs to know which one the
artist meant. Per anchor, the rotation vector (axis times angle, any length) of its anchor
transform's rotation factor (``inv(M_obj) M_empty inv(M_empty_bind) M_obj_bind``):

- **Animated** (the anchor's motion relative to its mesh comes from F-curves only, and the live
  matrix agrees with them at this frame): unwrapped along the animation from the anchor's bind
  frame to the current frame. Samples at every whole frame in between, each step halved (down
  to 1/1024 frame) while the channels or the rotations say it may turn by more than 90 degrees,
  then ``md.unwrap_rotations`` along them. This depends only on the scene and the frame, never
  on which frames were evaluated before: the same in any order and in any process (a farm).
  Cached on whole frames per anchor, dropped when the animation changes.
- **Followed** (no F-curves, or what moves it cannot be evaluated here: constraints, drivers,
  NLA, bone parents; or the live matrix disagrees with the animation: the Empty is being
  dragged): the log nearest the vector shown last. Only this depends on the order of
  evaluation. The vectors shown are saved with the output key, so reloading the file, undo and a
  farm's fresh process continue from what the key shows.

A step of more than half a turn that the sampler cannot split (a constant-interpolation key, a
jump) reads as the shorter opposite step: that case cannot be decided.

The methods get ``None`` instead when every vector is its principal log (all anchors turned by
less than half a turn): their own logs are then the right branch, bit for bit as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import anchor_math as am
from .. import bridge
from ..model import load_core, settings

STEP_LIMIT = 0.5 * math.pi  # no sampled step may turn further (radians)
MAX_DEPTH = 10  # halvings of a one-frame step: 1/1024 frame
LOOKAHEAD = 48  # whole frames sampled past the one asked for (playback then finds them cached)
MATCH_TOLERANCE = 2e-5  # live vs animated (3,3), relative to its largest entry
PRINCIPAL = math.pi - 1e-3  # below this every vector is the principal log
UNKNOWN_FRAME = -(2**31)  # an anchor bound before bind frames were stored

# What the depsgraph handler saw change (note_changes): a generation number per batch of
# updates, the generation at which each object (by pointer) last changed, and the last
# generation in which an Action changed.
_generation = 0
_touched: dict[int, int] = {}
_curves_generation = 0


def note_changes(depsgraph) -> None:
    """``depsgraph_update_post``: remember the objects and Actions that changed (an F-curve or
    keyframe edit, a parent, constraint, rotation mode or channel change), so that the next
    update checks the cached animations of the anchors they move. Frame changes are not edits
    and never come here."""
    global _generation, _curves_generation
    objects, actions = bridge.changed_objects(depsgraph)
    if not objects and not actions:
        return
    _generation += 1
    for ptr in objects:
        _touched[ptr] = _generation
    if actions:
        _curves_generation = _generation


def forget_changes() -> None:
    """A file was loaded: the pointers seen before mean nothing now."""
    _touched.clear()


@dataclass
class _Anchor:
    """What is known of one anchor's motion."""

    ptrs: frozenset  # the objects that move it relative to the mesh
    structure: tuple  # bridge.structure_fingerprint
    curves: tuple  # bridge.curves_fingerprint (empty when followed)
    followed: str  # why its animation is not used ('' when it is)
    span: tuple | None  # Motion.span: the motion is constant outside these whole frames
    grid: dict = field(default_factory=dict)  # whole frame -> (vector (3,), matrix (3,3))
    lo: int = 0
    hi: int = -1  # the grid holds lo..hi (empty when hi < lo)
    broken: str = ""  # why sampling failed (followed until the animation changes)


class _Frame:
    """Every anchor's animation at one frame, and what each update's check needs of it."""

    __slots__ = ("v", "m", "ok", "tol", "all_animated", "rotations")

    def __init__(self, v, m, ok):
        self.v, self.m, self.ok = v, m, ok  # (k,3), (k,3,3), (k,) sampled
        # how far a live matrix may be from the animation's and still be it (float32 round-off)
        self.tol = MATCH_TOLERANCE * np.abs(m).max(axis=(1, 2))[:, None, None]
        self.all_animated = bool(ok.all())
        self.rotations = principal_or(v)


class Twist:
    """One bound object's rotation vectors (kept in ``entry.extra['twist']``).

    ``shown``: (k,3) vectors to continue from where an anchor is followed, e.g. those saved with
    the output key."""

    def __init__(self, shown=None):
        self.bind_src = None  # the bind tuple last taken
        self.unknown = False  # some anchor has no bind frame (the scene's start is used)
        self.bind_key = None
        self.right = None  # (k,4,4) inv(M_empty_bind) M_obj_bind
        self.frames = None  # (k,) bind frames
        self.anchors: list[_Anchor] | None = None
        self.seen = (-1, -1)
        self.epoch = 0  # bumped whenever a cached animation was dropped
        self.last = None  # ((frame, mkey, epoch), vectors) of the last update
        self.shown = None if shown is None else np.array(shown, dtype=np.float64)
        self.followed = None  # (key, vectors, principal) of the last followed anchors
        self.unsaved = False  # followed vectors changed since the key last saved them
        self.moved = ()  # sampled anchors the last update found away from their animation
        self.by_frame: dict = {}  # frame -> _Frame

    # --- what moves each anchor --------------------------------------------------------------

    def _bind(self, scene, bind, m_obj) -> None:
        """Take the bind of this update: ``bind`` as :func:`pose._bind_matrices` keeps it (the
        same tuple until a bind changes it)."""
        bind_m, m_obj_bind, _bytes, frames = bind
        if bind is self.bind_src and m_obj_bind is not None and not self.unknown:
            return
        if m_obj_bind is None:  # bound before the object's matrix was kept: as if never moved
            m_obj_bind = m_obj
        frames = np.asarray(frames, dtype=np.int64)
        self.unknown = bool((frames == UNKNOWN_FRAME).any())
        if self.unknown:  # bound by an older version: the scene's start frame, as it is now
            frames = np.where(frames == UNKNOWN_FRAME, scene.frame_start, frames)
        key = (bind_m.tobytes(), m_obj_bind.tobytes(), frames.tobytes())
        if key != self.bind_key:
            self.bind_key = key
            self.right = am.affine_inverse(bind_m) @ m_obj_bind
            self.frames = frames
            self.anchors = None
        self.bind_src = bind

    def _build(self, obj, a: int) -> _Anchor:
        empty = settings(obj).anchors[a].empty
        mesh_side, empty_side = bridge.relevant_objects(obj, empty)
        motion = bridge.Motion(obj, empty, self.right[a])
        followed = motion.unsupported or ("" if motion.animated else "not animated")
        return _Anchor(
            ptrs=frozenset(o.as_pointer() for o in mesh_side + empty_side),
            structure=bridge.structure_fingerprint(obj, empty),
            curves=() if followed else bridge.curves_fingerprint(obj, empty),
            followed=followed,
            span=None if followed else motion.span(),
        )

    def _validate(self, obj, full: bool) -> None:
        """Drop the cached animation of every anchor whose objects or F-curves changed since it
        was cached. ``full``: compare everything now (renders, bakes, Update), not only what
        the depsgraph reported."""
        if self.anchors is None:
            self.anchors = [self._build(obj, a) for a in range(len(self.right))]
            self._dropped()
        elif full or self.seen != (_generation, _curves_generation):
            since, curves = self.seen[0], self.seen[1] != _curves_generation
            for a, info in enumerate(self.anchors):
                touched = full or any(_touched.get(p, -1) > since for p in info.ptrs)
                if not (touched or (curves and not info.followed)):
                    continue
                empty = settings(obj).anchors[a].empty
                if bridge.structure_fingerprint(obj, empty) != info.structure or (
                    not info.followed and bridge.curves_fingerprint(obj, empty) != info.curves
                ):
                    self.anchors[a] = self._build(obj, a)
                    self._dropped()
        self.seen = (_generation, _curves_generation)

    def _dropped(self) -> None:
        self.by_frame.clear()
        self.epoch += 1

    # --- the animation, sampled --------------------------------------------------------------

    def _animated(self, obj, a: int, frame: float):
        """(vector (3,), matrix (3,3)) of anchor a's animation at ``frame``, None if it cannot
        be sampled (it is then followed until its animation changes)."""
        info = self.anchors[a]
        b = int(self.frames[a])
        if info.span is not None:  # constant outside the keys: no need to sample out there
            lo, hi = info.span
            b = min(max(b, lo), hi)
            frame = min(max(frame, lo), hi)
        whole = frame == math.floor(frame)
        # a sub-frame continues from the whole frame next to it on the bind frame's side
        base = int(frame) if whole else int(math.floor(frame) if frame > b else math.ceil(frame))
        try:
            motion = None
            if base not in info.grid:
                motion = self._motion(obj, a)
                self._extend(motion, info, b, base)
            if whole:
                return info.grid[base]
            v, m = _unwrap(motion or self._motion(obj, a), [base, frame], info.grid[base][0])
            return v[-1], m[-1]
        except ValueError as exc:  # a sample scaled to zero or mirrored
            info.broken = f"cannot sample its animation ({exc})"
            return None

    def _motion(self, obj, a: int):
        return bridge.Motion(obj, settings(obj).anchors[a].empty, self.right[a])

    def _extend(self, motion, info: _Anchor, b: int, target: int) -> None:
        """Sample the whole frames from the cached ones (or the bind frame) to ``target`` and
        LOOKAHEAD past it, away from the bind frame."""
        if info.hi < info.lo:
            m = bridge.Motion.matrices([motion.at(b)])
            info.grid[b] = (_core().unwrap_rotations(m)[0], m[0])
            info.lo = info.hi = b
        if target > info.hi:
            start, end = info.hi, target + LOOKAHEAD
        elif target < info.lo:
            start, end = info.lo, target - LOOKAHEAD
        else:
            return
        if info.span is not None:
            end = min(max(end, info.span[0]), info.span[1])
        d = 1 if end > start else -1
        frames = list(range(start, end + d, d))
        vs, ms = _unwrap(motion, frames, info.grid[start][0])
        for n, v, m in zip(frames[1:], vs, ms, strict=True):
            info.grid[n] = (v, m)
        info.lo, info.hi = min(info.lo, end), max(info.hi, end)

    def _frame(self, obj, frame: float) -> _Frame:
        """The animation of every anchor at ``frame`` (cached)."""
        got = self.by_frame.get(frame)
        if got is None:
            k = len(self.anchors)
            vs, ms, ok = np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros(k, bool)
            for a, info in enumerate(self.anchors):
                if info.followed or info.broken:
                    continue
                value = self._animated(obj, a, frame)
                if value is not None:
                    vs[a], ms[a], ok[a] = value[0], value[1], True
            if len(self.by_frame) > 4096:
                self.by_frame.clear()
            got = self.by_frame[frame] = _Frame(vs, ms, ok)
        return got

    # --- per update ----------------------------------------------------------------------------

    def vectors(self, obj, scene, frame, mkey, transforms, bind, m_obj, full=False):
        """(vectors (k,3), rotations) of the anchors now: ``rotations`` is what the methods get,
        the vectors or None when every one is its principal log (:func:`principal_or`).

        ``frame``: the scene's frame (with its sub-frame); ``mkey``: bytes of this update's
        live matrices; ``transforms``: a callable returning this update's (k,4,4) anchor
        transforms (None at the bind pose), called only when the vectors may have changed;
        ``bind``: :func:`pose._bind_matrices`; ``m_obj``: the object's matrix now (4,4);
        ``full``: compare the animation with what is cached in full first (renders, bakes,
        Update)."""
        self._bind(scene, bind, m_obj)
        self._validate(obj, full)
        key = (frame, mkey, self.epoch)
        if not full and self.last is not None and self.last[0] == key:
            return self.last[1]
        t = transforms()
        k = len(self.anchors)
        live = np.broadcast_to(np.eye(3), (k, 3, 3)) if t is None else t[:, :3, :3]
        got = self._frame(obj, frame)
        # where the live matrix is not the animation's, the Empty is being dragged
        close = np.abs(got.m - live) <= got.tol
        if got.all_animated and close.all():
            out, rotations = got.v, got.rotations
            self.followed = None
            self.moved = ()
        else:
            idx = np.flatnonzero(~(got.ok & close.all(axis=(1, 2))))
            self.moved = idx[got.ok[idx]]  # sampled, but not where the keys put them
            fv, principal = self._follow(idx, live)
            out = got.v.copy()
            out[idx] = fv
            rotations = None if principal and got.rotations is None else out
        self.shown = out
        self.last = (key, (out, rotations))
        return out, rotations

    def _follow(self, idx, live) -> tuple[np.ndarray, bool]:
        """Vectors of the followed anchors ``idx``: the logs nearest the vectors shown last;
        and whether all of them are principal logs. Kept while the same anchors are followed
        and their live matrices stay as they were."""
        key = idx.tobytes() + np.ascontiguousarray(live[idx]).tobytes()
        if self.followed is not None and self.followed[0] == key:
            return self.followed[1], self.followed[2]
        k = len(live)
        prev = self.shown if self.shown is not None and self.shown.shape == (k, 3) else None
        start = np.zeros((len(idx), 3)) if prev is None else prev[idx]
        try:
            rot = np.ascontiguousarray(live[idx])[None]
            fv = _core().unwrap_rotations(rot, start=start)[0]
        except ValueError:  # an Empty scaled to zero: the solve says so (or ignores it)
            fv = start
        principal = principal_or(fv) is None
        self.followed = (key, fv, principal)
        self.unsaved = True
        return fv, principal

    def why_followed(self) -> list[str]:
        """Per anchor: why the last update did not take its vector from its animation ('' where
        it did), for scripts and the tests."""
        if self.anchors is None:
            return []
        out = [info.followed or info.broken for info in self.anchors]
        for a in self.moved:
            out[a] = "not where its keys put it"
        return out


def _core():
    return load_core()


def _refine(motion, a, b, depth: int, out: list) -> None:
    """Samples of (a, b], b last: halved while the step may turn by more than STEP_LIMIT."""
    if depth < MAX_DEPTH and motion.step(a, b) > STEP_LIMIT:
        mid = motion.at(0.5 * (a.frame + b.frame))
        _refine(motion, a, mid, depth + 1, out)
        _refine(motion, mid, b, depth + 1, out)
    else:
        out.append(b)


def _unwrap(motion, frames, start):
    """Vectors (N-1,3) and matrices (N-1,3,3) at frames[1:], unwrapped along the motion from
    ``start``, the vector at frames[0]."""
    samples, ends = [], []
    prev = motion.at(frames[0])
    for f in frames[1:]:
        cur = motion.at(f)
        _refine(motion, prev, cur, 0, samples)
        ends.append(len(samples) - 1)
        prev = cur
    mats = bridge.Motion.matrices(samples)
    vs = _core().unwrap_rotations(mats, start=start)
    return vs[ends], mats[ends]


def principal_or(vectors: np.ndarray | None) -> np.ndarray | None:
    """``vectors`` if some anchor turned by about half a turn or more, else None (every vector
    is then its principal log, which the methods compute themselves)."""
    if vectors is None or float(np.einsum("ij,ij->i", vectors, vectors).max()) < PRINCIPAL**2:
        return None
    return vectors
