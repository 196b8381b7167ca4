"""Transform animation evaluated at any frame without changing the scene's frame (``frame_set``
is not allowed inside depsgraph and frame-change handlers): the rotation-and-scale part of an
anchor's motion relative to its mesh, read from the F-curves of the objects between them.

What is evaluated is ``inv(P_obj(t)) @ P_empty(t)`` (3,3): each side's product of
``matrix_parent_inverse @ matrix_basis`` (3,3 parts) below the nearest object both parent
chains share, which cancels (Empties parented to the mesh, as Add Anchor makes them, need only
their own channels). ``matrix_basis`` is Blender's: rotation (delta rotation applied after it)
times scale (times delta scale). Channels without an F-curve keep their current values.
Anything else that can move one of these objects (constraints, drivers on rotation or scale,
NLA strips, a bone or vertex parent, a rigid body) makes the motion one this module cannot
evaluate (:attr:`Motion.unsupported` says why).
"""

from __future__ import annotations

import hashlib
import math

import bpy
import numpy as np
from mathutils import Euler, Matrix, Quaternion, Vector

from .arrays import _get

# channels that turn or scale an object (locations do not change the rotation factor)
ROTATION_PATHS = (
    "rotation_euler",
    "rotation_quaternion",
    "rotation_axis_angle",
    "delta_rotation_euler",
    "delta_rotation_quaternion",
)
SCALE_PATHS = ("scale", "delta_scale")
_PATHS = ROTATION_PATHS + SCALE_PATHS
_SIZES = {"rotation_quaternion": 4, "delta_rotation_quaternion": 4, "rotation_axis_angle": 4}


def fcurve_collection(anim_data):
    """The collection of F-curves the assigned action applies to the animated ID (it has
    ``remove``), None without any: Blender 4.4+ slotted actions keep them in the channelbag of
    the assigned slot (none without a slot; 5.0 has no ``Action.fcurves``), older versions in
    ``action.fcurves``."""
    act = None if anim_data is None else anim_data.action
    if act is None:
        return None
    if hasattr(anim_data, "action_slot"):
        from bpy_extras import anim_utils

        get = getattr(anim_utils, "action_get_channelbag_for_slot", None)
        if get is not None:
            slot = anim_data.action_slot
            bag = None if slot is None else get(act, slot)
            return None if bag is None else bag.fcurves
    return getattr(act, "fcurves", None)


def action_fcurves(anim_data) -> tuple:
    """The F-curves the assigned action applies to the animated ID (see
    :func:`fcurve_collection`), as a tuple."""
    got = fcurve_collection(anim_data)
    return () if got is None else tuple(got)


def _muted(fc) -> bool:
    group = fc.group
    return fc.mute or (group is not None and group.mute)


def _curves(obj) -> list:
    """(path, index, fcurve) of the object's live rotation and scale F-curves."""
    out = []
    for fc in action_fcurves(obj.animation_data):
        path, i = fc.data_path, fc.array_index
        if path in _PATHS and 0 <= i < _SIZES.get(path, 3) and not _muted(fc):
            out.append((path, i, fc))
    return out


def _constraint_active(c) -> bool:
    on = c.enabled if hasattr(c, "enabled") else not c.mute
    return bool(on) and c.influence > 0.0


def unsupported(obj) -> str:
    """Why the rotation and scale of ``obj`` cannot be read from its F-curves alone ('' if they
    can)."""
    if obj.parent is not None and obj.parent_type != "OBJECT":
        return f"'{obj.name}' has a {obj.parent_type.lower()} parent"
    if any(_constraint_active(c) for c in obj.constraints):
        return f"'{obj.name}' has constraints"
    if getattr(obj, "rigid_body", None) is not None:
        return f"'{obj.name}' is a rigid body"
    ad = obj.animation_data
    if ad is None:
        return ""
    if any(d.data_path in _PATHS and not d.mute for d in ad.drivers):
        return f"'{obj.name}' has drivers on its rotation or scale"
    if getattr(ad, "use_tweak_mode", False) or (
        ad.use_nla and any(not t.mute and len(t.strips) for t in ad.nla_tracks)
    ):
        return f"'{obj.name}' has NLA strips"
    if ad.action is not None and (
        getattr(ad, "action_influence", 1.0) != 1.0
        or getattr(ad, "action_blend_type", "REPLACE") != "REPLACE"
    ):
        return f"'{obj.name}' blends its action"
    return ""


def changed_objects(depsgraph) -> tuple[list[int], bool]:
    """(pointers of the objects an edit changed, whether an Action changed) in a depsgraph
    update. Geometry-only updates (the output key written) do not count."""
    if depsgraph is None:
        return [], False
    actions = depsgraph.id_type_updated("ACTION")
    if not depsgraph.id_type_updated("OBJECT"):
        return [], actions
    out = []
    for u in depsgraph.updates:
        ob = u.id
        if isinstance(ob, bpy.types.Object) and (
            u.is_updated_transform or not u.is_updated_geometry
        ):
            out.append(getattr(ob, "original", ob).as_pointer())
    return out, actions


def scene_frame(scene) -> float:
    """The frame being evaluated, with its sub-frame (motion blur)."""
    return scene.frame_current_final


def _chain(obj) -> list:
    out = []
    while obj is not None:
        out.append(obj)
        obj = obj.parent
    return out


def relevant_objects(obj, empty) -> tuple[list, list]:
    """(mesh side, Empty side): the objects of each parent chain below the nearest object both
    share, each from the top down to ``obj`` / ``empty``. Only these move the anchor relative to
    the mesh; the shared part cancels."""
    a, b = _chain(obj), _chain(empty)
    shared = {o.as_pointer() for o in a} & {o.as_pointer() for o in b}
    a = [o for o in a if o.as_pointer() not in shared]
    b = [o for o in b if o.as_pointer() not in shared]
    return a[::-1], b[::-1]


def _static_values(obj, animated: set) -> tuple:
    """Current values of the rotation and scale channels no F-curve drives."""
    out = []
    for path in _PATHS:
        v = tuple(getattr(obj, path))
        out.append(tuple(x for i, x in enumerate(v) if (path, i) not in animated))
    return tuple(out)


def structure_fingerprint(obj, empty) -> tuple:
    """What makes the evaluated motion of this anchor change apart from keyframe data:
    which objects move it, how they are parented, their rotation modes, what cannot be
    evaluated, the assigned actions and slots, and the channels without F-curves. Cheap
    (RNA reads only): recomputed when one of the objects was updated."""
    out = []
    for side in relevant_objects(obj, empty):
        for o in side:
            curves = _curves(o)
            ad = o.animation_data
            act = None if ad is None else ad.action
            slot = getattr(ad, "action_slot", None) if ad is not None else None
            animated = {(p, i) for p, i, _ in curves}
            pinv = o.matrix_parent_inverse if o.parent is not None else None
            out.append(
                (
                    o.as_pointer(),
                    o.rotation_mode,
                    unsupported(o),
                    None if pinv is None else tuple(tuple(r[:3]) for r in pinv[:3]),
                    0 if act is None else act.as_pointer(),
                    None if slot is None else slot.as_pointer(),
                    tuple(sorted((p, i) for p, i in animated)),
                    _static_values(o, animated),
                )
            )
        out.append("|")
    return tuple(out)


def _curve_data(fc) -> tuple:
    kp = fc.keyframe_points
    n = len(kp)
    parts = [fc.data_path, fc.array_index, fc.extrapolation, n]
    for prop, width, dtype in (
        ("co", 2, np.float32),
        ("handle_left", 2, np.float32),
        ("handle_right", 2, np.float32),
        ("interpolation", 1, np.int32),
        ("easing", 1, np.int32),
        ("back", 1, np.float32),
        ("amplitude", 1, np.float32),
        ("period", 1, np.float32),
    ):
        parts.append(_get(kp, prop, n, dtype, width).tobytes() if n else b"")
    for m in fc.modifiers:
        props = tuple(
            (p.identifier, repr(getattr(m, p.identifier, None)))
            for p in m.bl_rna.properties
            if p.identifier != "rna_type" and p.type not in {"POINTER", "COLLECTION"}
        )
        parts.append((m.type, props))
    return tuple(parts)


def curves_fingerprint(obj, empty) -> tuple:
    """The keyframes (and F-curve modifiers) of every rotation and scale F-curve that moves this
    anchor: recomputed when an Action was updated."""
    return tuple(
        tuple(_curve_data(fc) for _p, _i, fc in _curves(o))
        for side in relevant_objects(obj, empty)
        for o in side
    )


def _driver_data(d) -> tuple:
    drv = d.driver
    variables = tuple(
        (v.name, v.type, tuple((t.id.name if t.id else "", t.data_path, t.transform_type,
                                t.transform_space, t.rotation_mode) for t in v.targets))
        for v in drv.variables
    )  # fmt: skip
    return (d.data_path, d.array_index, drv.type, drv.expression, variables, _curve_data(d))


def motion_record(obj, empties) -> str:
    """A digest of everything in the file that moves these anchor Empties relative to the mesh
    (every object of their parent chains below the shared part: transforms, parenting,
    constraints, F-curves of every channel, drivers), the same in every process that opens the
    file: farm chunks baked from other versions of the animation tell themselves apart by it."""
    h = hashlib.blake2b(digest_size=16)
    for empty in empties:
        for side in relevant_objects(obj, empty):
            for o in side:
                ad = o.animation_data
                curves = action_fcurves(ad)
                drivers = tuple(ad.drivers) if ad is not None else ()
                # the values of animated channels are the current frame's: left out
                animated = {(c.data_path, c.array_index) for c in (*curves, *drivers)}
                static = tuple(
                    tuple(x for i, x in enumerate(getattr(o, p)) if (p, i) not in animated)
                    for p in ("location", "delta_location", *_PATHS)
                )
                h.update(repr((
                    o.name, o.parent_type, o.rotation_mode, static,
                    tuple(tuple(r) for r in o.matrix_parent_inverse),
                    tuple((c.type, c.name, getattr(getattr(c, "target", None), "name", ""))
                          for c in o.constraints),
                    tuple((fc.data_path, fc.array_index, _muted(fc), _curve_data(fc))
                          for fc in curves),
                    tuple(_driver_data(d) for d in drivers),
                )).encode())  # fmt: skip
            h.update(b"|")
        h.update(b"||")
    return h.hexdigest()


def _qangle(a, b) -> float:
    """Angle between two quaternions on the double cover, 0..2 pi: half of it is how far the
    rotation turns along the shortest path between them, the rest tells q from -q (a whole
    turn)."""
    na = math.sqrt(sum(x * x for x in a))
    nb = math.sqrt(sum(x * x for x in b))
    if na < 1e-12 or nb < 1e-12:
        return math.pi
    c = sum(x * y for x, y in zip(a, b, strict=True)) / (na * nb)
    return 2.0 * math.acos(max(-1.0, min(1.0, c)))


def _axis_angle_quat(v) -> tuple:
    angle, axis = v[0], Vector(v[1:])
    if axis.length < 1e-12:
        return (1.0, 0.0, 0.0, 0.0)
    axis.normalize()
    s = math.sin(0.5 * angle)
    return (math.cos(0.5 * angle), s * axis.x, s * axis.y, s * axis.z)


class _Part:
    """One object's ``matrix_parent_inverse @ matrix_basis`` (3,3) at any frame."""

    def __init__(self, obj):
        self.mode = obj.rotation_mode
        self.values = {p: list(getattr(obj, p)) for p in _PATHS}
        self.curves = _curves(obj)
        self.pinv = obj.matrix_parent_inverse.to_3x3() if obj.parent is not None else None
        self.constant = None if self.curves else self._basis(self.values)

    def _basis(self, v) -> Matrix:
        mode = self.mode
        if mode == "QUATERNION":
            rot = Quaternion(v["delta_rotation_quaternion"]).normalized().to_matrix()
            rot = rot @ Quaternion(v["rotation_quaternion"]).normalized().to_matrix()
        elif mode == "AXIS_ANGLE":
            angle, *axis = v["rotation_axis_angle"]
            axis = Vector(axis)
            rot = Matrix.Identity(3) if axis.length < 1e-12 else Matrix.Rotation(angle, 3, axis)
        else:
            rot = Euler(v["delta_rotation_euler"], mode).to_matrix()
            rot = rot @ Euler(v["rotation_euler"], mode).to_matrix()
        s = [a * b for a, b in zip(v["scale"], v["delta_scale"], strict=True)]
        m = rot @ Matrix.Diagonal(s)
        return m if self.pinv is None else self.pinv @ m

    def at(self, t: float) -> tuple[Matrix, tuple]:
        """(3,3) part at frame t, and the rotation channel values there (for the step bound)."""
        if self.constant is not None:
            return self.constant, ()
        v = {p: list(x) for p, x in self.values.items()}
        for path, i, fc in self.curves:
            v[path][i] = fc.evaluate(t)
        mode = self.mode
        if mode == "QUATERNION":
            ch = (tuple(v["rotation_quaternion"]), tuple(v["delta_rotation_quaternion"]))
        elif mode == "AXIS_ANGLE":
            ch = (tuple(v["rotation_axis_angle"]),)
        else:
            ch = (tuple(v["rotation_euler"]) + tuple(v["delta_rotation_euler"]),)
        return self._basis(v), ch

    def turn_bound(self, a: tuple, b: tuple) -> float:
        """An upper bound of how far this part turns between two samples, from its channels:
        Euler angles add up; quaternions are compared on the double cover; an axis-angle by its
        angle and its quaternion. Whole turns in the channels count in full."""
        if not a:
            return 0.0
        if self.mode == "QUATERNION":
            return _qangle(a[0], b[0]) + _qangle(a[1], b[1])
        if self.mode == "AXIS_ANGLE":
            qa, qb = _axis_angle_quat(a[0]), _axis_angle_quat(b[0])
            return abs(b[0][0] - a[0][0]) + _qangle(qa, qb)
        return sum(abs(x - y) for x, y in zip(a[0], b[0], strict=True))


class Sample:
    """The anchor's evaluated motion at one frame: ``m`` (3,3) ``inv(P_obj) P_empty C``, its
    rotation as a quaternion, and the channels of every part."""

    __slots__ = ("frame", "m", "q", "channels")

    def __init__(self, frame, m, q, channels):
        self.frame, self.m, self.q, self.channels = frame, m, q, channels


class Motion:
    """Evaluates one anchor's motion relative to its mesh from F-curves, at any frame.

    ``right`` (3,3): the constant factor after it (the anchor's ``inv(M_empty_bind)
    M_obj_bind``), so that a sample is the (3,3) part of the anchor transform the session
    solves for. Built fresh for each use (it holds F-curves, which an edit may free)."""

    def __init__(self, obj, empty, right):
        mesh_side, empty_side = relevant_objects(obj, empty)
        self.unsupported = next((r for r in map(unsupported, mesh_side + empty_side) if r), "")
        self._mesh = [_Part(o) for o in mesh_side]
        self._empty = [_Part(o) for o in empty_side]
        self.animated = any(p.curves for p in self._mesh + self._empty)
        self._right = Matrix([list(r) for r in np.asarray(right, dtype=np.float64)[:3, :3]])

    def span(self) -> tuple[int, int] | None:
        """(first, last) whole frames outside which the motion stays as it is at them: every
        F-curve holds its first and last keys (constant extrapolation, no modifiers). None when
        some F-curve goes on changing."""
        lo, hi = math.inf, -math.inf
        for part in self._mesh + self._empty:
            for _p, _i, fc in part.curves:
                if fc.extrapolation != "CONSTANT" or len(fc.modifiers):
                    return None
                kp = fc.keyframe_points
                if len(kp):
                    x = _get(kp, "co", len(kp), np.float32, 2)[:, 0]
                    lo, hi = min(lo, float(x.min())), max(hi, float(x.max()))
        if lo > hi:
            return None
        return math.floor(lo), math.ceil(hi)

    def at(self, t: float) -> Sample:
        """The motion at frame t (a float: sub-frames are fine). Raises ValueError where the
        mesh side is singular (an object scaled to zero)."""
        t = float(t)
        channels = []
        left = Matrix.Identity(3)
        for part in self._mesh:
            m, ch = part.at(t)
            left = left @ m
            channels.append(ch)
        if abs(left.determinant()) < 1e-30:
            raise ValueError(f"a parent of the mesh is scaled to zero at frame {t:g}")
        m = left.inverted()
        for part in self._empty:
            pm, ch = part.at(t)
            m = m @ pm
            channels.append(ch)
        m = m @ self._right
        return Sample(t, m, m.to_quaternion(), tuple(channels))

    def step(self, a: Sample, b: Sample) -> float:
        """How far the motion may turn between two samples (radians): the larger of the
        channels' bound (which sees whole turns) and the angle between the two rotations."""
        bound = sum(
            p.turn_bound(x, y)
            for p, x, y in zip(self._mesh + self._empty, a.channels, b.channels, strict=True)
        )
        w = min(1.0, abs(a.q.rotation_difference(b.q).normalized().w))
        return max(bound, 2.0 * math.acos(w))

    @staticmethod
    def matrices(samples) -> np.ndarray:
        """(N,3,3) float64 of the samples' matrices."""
        rows = []
        for s in samples:
            m = s.m
            rows += (m[0][:], m[1][:], m[2][:])
        return np.array(rows, dtype=np.float64).reshape(-1, 3, 3)
