"""Pose-space surface manipulation from example shapes: ``matdeform.PoseSpaceDeformer``.

Its own inputs (docs/pose_space.md, "In Blender"):

- Examples: the object's shape keys, by the rule of Learn from Shape Keys: every key except the
  reference (Basis), muted keys, the add-on's own output and bake keys, whose name contains the
  Keys filter. A key's stored coordinates are the example (its value and relative key are not
  used). Mute a key to leave it out.
- Handles: the anchors. Follow Empty and Frame anchors are translational handles (their
  vertices follow the Empty exactly); the Frame anchor's first triangle is the frame in which
  the pose is measured, so turning the whole rig does not change the inferred pose. A Rotation
  anchor is a rotational handle: its Empty's rotation relative to the Frame anchor's Empty bends
  or twists the joint between them (the anchor's vertices are not held in place).
- Settings: multiresolution (coarse face count) and the frozen faces (a vertex group, or a
  boolean face attribute / face map of that name).

The example set and every example's coordinates are in the fingerprint, and the live update
compares them with the bound ones bit for bit, so editing a key makes the bind stale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, StringProperty

from .. import anchor_math as am
from .. import aniso_map as amap
from .. import bridge, updates
from .. import stiffness_map as sm
from ..model import BindError, load_core, settings
from .base import Method, Result, register_method

FRAME = "FRAME"


def _changed(self, context):
    """A setting the bind depends on changed: the session compares the object with its bound
    state."""
    updates.bind_setting(self, context)


class MaterialDeformPoseSpaceSettings(bpy.types.PropertyGroup):
    rest_example: BoolProperty(
        name="Rest as Example",
        description="The rest shape (Basis) is the first example: at the bind pose the mesh "
        "is at rest and the weights are 1 for it, so posing starts smoothly from rest",
        default=True,
        update=_changed,
    )
    multiresolution: BoolProperty(
        name="Multiresolution",
        description="Solve on a coarse copy of the mesh (quadric simplification) and carry the "
        "details to the full mesh: much faster on dense meshes, slightly less exact",
        default=False,
        update=_changed,
    )
    coarse_faces: IntProperty(
        name="Coarse Faces",
        description="Triangle count of the coarse mesh (below the mesh's own count)",
        default=1000,
        min=4,
        soft_max=20000,
        update=_changed,
    )
    frozen_group: StringProperty(
        name="Frozen",
        description="Faces that keep their rest shape and place: polygons whose vertices are "
        "all in this vertex group (or a boolean face attribute / face map of this name; empty "
        "= none)",
        update=_changed,
    )


@dataclass
class Solver:
    deformer: object
    names: list  # example shape keys, in the order of the weights
    handles: list  # per translational anchor: (anchor index, compacted vertex indices)
    rest_c: np.ndarray  # (n_c,3) rest positions of the compacted mesh
    joints: list  # per Rotation anchor: its anchor index (paired with the frame anchor)
    frame_anchor: int | None
    rest_example: bool  # the weights start with the rest shape's
    examples_f32: np.ndarray  # (p,n,3) the example keys as bound, compared on live updates
    rest_weights: np.ndarray | None = field(default=None)


REST = "(rest)"  # the readout's name of the Basis as example


def example_names(obj) -> list[str]:
    """The shape keys used as examples (the rule of Learn from Shape Keys)."""
    s = settings(obj)
    return amap.learn_key_names(bridge.shape_key_info(obj), s.learn_filter, s.output_key_name)


def _no_examples(obj) -> BindError:
    f = settings(obj).learn_filter.strip()
    extra = f" whose name contains '{f}'" if f else ""
    return BindError(
        f"Pose space needs example shapes: add unmuted shape keys{extra} besides the Basis "
        "(the add-on's own 'Material Deform' and 'MD Bake' keys are ignored)"
    )


def _frozen_faces(obj, a: bridge.MeshArrays) -> np.ndarray | None:
    """Triangles of the frozen polygons, None when none are set."""
    name = settings(obj).pose_space.frozen_group.strip()
    if not name:
        return None
    if bridge.has_vertex_group(obj, name):
        w = bridge.vertex_group_weights(obj, [name])[name]
        lp = sm.loop_polygon_index(a.loop_start, a.loop_total)
        polys = am.anchor_polygons(w >= 0, a.loop_vert, lp, a.n_polys)
    else:
        polys = _face_set(obj, name, a.n_polys)
        if polys is None:
            raise BindError(f"Frozen: no vertex group, face map or boolean face attribute '{name}'")
    faces = np.flatnonzero(polys[a.tri_poly]).astype(np.int64)
    if len(faces) == 0:
        raise BindError(f"Frozen: '{name}' contains no whole face")
    return faces


def _face_set(obj, name, n_polys) -> np.ndarray | None:
    """(P,) bool: a boolean face attribute (what Blender 4 made of face maps) or a face map."""
    mesh = obj.data
    attr = mesh.attributes.get(name)
    if attr is not None and attr.domain == "FACE" and attr.data_type == "BOOLEAN":
        out = np.zeros(n_polys, bool)
        attr.data.foreach_get("value", out)
        return out
    fmaps = getattr(obj, "face_maps", None)  # Blender < 4.0
    fmap = None if fmaps is None else fmaps.get(name)
    if fmap is None:
        return None
    layer = mesh.face_maps.active if len(mesh.face_maps) else None
    if layer is None:
        return np.zeros(n_polys, bool)
    idx = np.zeros(n_polys, np.int32)
    layer.data.foreach_get("value", idx)
    return idx == fmap.index


def _read_examples(obj, names) -> np.ndarray:
    """(p,n,3) float32 coordinates of the example keys, exactly as stored."""
    keys = obj.data.shape_keys
    out = []
    for name in names:
        kb = keys.key_blocks[name]
        x = np.empty(len(kb.data) * 3, np.float32)
        kb.data.foreach_get("co", x)
        if not np.all(np.isfinite(x)):
            raise BindError(f"Shape key '{name}' has non-finite coordinates")
        out.append(x.reshape(-1, 3))
    return np.stack(out)


def _unique_verts(tris, faces) -> np.ndarray:
    return np.unique(tris[faces].ravel()).astype(np.int64)


def _rotation(t) -> np.ndarray:
    """Nearest rotation of the 3x3 part of a (4,4) transform (the Empty may be scaled)."""
    u, _s, vt = np.linalg.svd(t[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        raise ValueError("an anchor Empty is mirrored (negative scale)")
    return r


class PoseSpaceMethod(Method):
    key = "POSE_SPACE"
    number = 2
    label = "Pose space"
    description = (
        "Pose from example shapes (the shape keys): the anchors pick the blend of examples, so "
        "muscles bulge and joints bend as the examples show (MeshIK, rotation-invariant)"
    )
    anchor_modes = frozenset({am.POSITION, am.ROTATION, FRAME})
    settings_name = "pose_space"
    settings_class = MaterialDeformPoseSpaceSettings
    fingerprint_what = "method, example shape keys or pose-space settings"

    def gather(self, obj, inputs, binding) -> None:
        s = settings(obj).pose_space
        a = inputs.arrays
        names = example_names(obj)
        if not names and binding:
            # (a check of an existing bind just compares: no examples is a changed example set)
            raise _no_examples(obj)
        frames = [i for i, m in enumerate(inputs.modes) if m == FRAME]
        if len(frames) > 1:
            raise BindError(
                f"Anchors '{inputs.names[frames[0]]}' and '{inputs.names[frames[1]]}' are both "
                "Frame: one anchor can be the frame"
            )
        joints = [i for i, m in enumerate(inputs.modes) if m == am.ROTATION]
        if joints and not frames:
            raise BindError(
                f"Anchor '{inputs.names[joints[0]]}' is Rotation: its Empty turns the joint "
                "relative to a Frame anchor - set one anchor (e.g. on the trunk) to Frame"
            )
        frozen = _frozen_faces(obj, a)
        if len(inputs.modes) == 1 and not frames and not joints and frozen is None:
            raise BindError(
                f"Anchor '{inputs.names[0]}' alone cannot tell which pose is meant: add anchors, "
                "make one of them Frame, or freeze faces"
            )
        if frozen is not None:
            fv = np.zeros(len(a.rest), bool)
            fv[a.tris[frozen].ravel()] = True
            for faces, name, mode in zip(
                inputs.anchor_faces, inputs.names, inputs.modes, strict=True
            ):
                if mode != am.ROTATION and fv[a.tris[faces].ravel()].any():
                    raise BindError(
                        f"Anchor '{name}' has vertices on frozen faces, which keep their rest "
                        "place: take them out of the frozen group"
                    )
        m = len(a.tris)
        # a coarse mesh as large as the mesh is the mesh: single resolution (the panel says so)
        coarse = int(s.coarse_faces) if s.multiresolution and s.coarse_faces < m else None
        inputs.extra["examples"] = (
            _read_examples(obj, names) if names else np.zeros((0, len(a.rest), 3), np.float32)
        )
        inputs.extra["example_names"] = names
        inputs.extra["frozen"] = frozen
        inputs.extra["coarse"] = coarse
        inputs.extra["rest_example"] = bool(s.rest_example)

    def fingerprint(self, obj, inputs) -> list:
        x = inputs.extra
        return [
            "\0".join(x["example_names"]),
            x["examples"],
            "single" if x["coarse"] is None else f"coarse {x['coarse']}",
            "none" if x["frozen"] is None else x["frozen"],
            "rest example" if x["rest_example"] else "keys only",
        ]

    def build(self, inputs) -> Solver:
        md = load_core()
        x = inputs.extra
        if not x["example_names"]:  # (gather refuses this at Bind; a later check compares)
            raise BindError("Pose space needs example shapes: add shape keys, then Rebind")
        tris = inputs.arrays.tris
        used = inputs.used
        examples = x["examples"].astype(np.float64)
        if x["rest_example"]:
            examples = np.concatenate([inputs.arrays.rest[None], examples])
        if used is not None:
            examples = examples[:, used]
        handles, joints, frame_anchor, frame_face = [], [], None, None
        for i, (faces, mode) in enumerate(zip(inputs.anchor_faces, inputs.modes, strict=True)):
            if mode == am.ROTATION:
                joints.append(i)
                continue
            handles.append((i, inputs.compact_index(_unique_verts(tris, faces))))
            if mode == FRAME:
                frame_anchor, frame_face = i, int(faces[0])
        pairs = [(frame_face, int(inputs.anchor_faces[j][0])) for j in joints]
        try:
            d = md.PoseSpaceDeformer(
                inputs.verts_c,
                inputs.tris_c,
                examples,
                [h for _i, h in handles],
                frame=frame_face,
                rotational=pairs or None,
                coarse=x["coarse"],
                frozen=x["frozen"],
            )
        except (ValueError, RuntimeError) as exc:
            raise BindError(f"Solver rejected the mesh or examples: {exc}") from exc
        return Solver(
            d,
            list(x["example_names"]),
            handles,
            inputs.verts_c.copy(),
            joints,
            frame_anchor,
            x["rest_example"],
            x["examples"],
        )

    def _targets(self, solver, transforms):
        hp = []
        for i, idx in solver.handles:
            t = transforms[i]
            hp.append(solver.rest_c[idx] @ t[:3, :3].T + t[:3, 3])
        rot = None
        if solver.joints:
            rf = _rotation(transforms[solver.frame_anchor])
            rot = np.stack([rf.T @ _rotation(transforms[j]) for j in solver.joints])
        return hp, rot

    def solve(self, solver, transforms, state, budget, progress=None, rotations=None) -> Result:
        # rotations ignored: the core takes joints as matrices (docs/pose_space.md, turns)
        hp, rot = self._targets(solver, transforms)
        x = solver.deformer.deform(hp, rot)
        state["weights"] = solver.deformer.example_weights
        return Result(x)

    def rest_weights(self, solver) -> np.ndarray:
        """Example weights at the bind pose (cached: the readout before the first drag)."""
        if solver.rest_weights is None:
            t = np.broadcast_to(np.eye(4), (max(len(solver.handles) + len(solver.joints), 1), 4, 4))
            hp, rot = self._targets(solver, np.array(t))
            solver.rest_weights = solver.deformer.pose_weights(hp, rot)
        return solver.rest_weights

    def check_live(self, obj, entry, depsgraph) -> None:
        """The example keys as bound, bit for bit: a key edited, muted, renamed or added from a
        script (no Edit Mode round trip the session would see) makes the bind stale."""
        solver = entry.solver
        if example_names(obj) != solver.names:
            raise BindError(
                "Example shape keys changed since bind (added, muted or renamed) - click Rebind"
            )
        bound = solver.examples_f32
        buf = entry.extra.setdefault("examples_buf", np.empty_like(bound[0]))
        keys = obj.data.shape_keys
        for name, ex in zip(solver.names, bound, strict=True):
            bridge.read_key_into(keys.key_blocks[name], buf.reshape(-1))
            if not np.array_equal(buf, ex):
                raise BindError(f"Example shape key '{name}' changed since bind - click Rebind")

    def draw(self, layout, obj, entry) -> None:
        s = settings(obj)
        ps = s.pose_space
        names = example_names(obj)
        layout.label(text="Examples (shape keys):")
        layout.prop(s, "learn_filter", text="Keys")
        readout = weights_readout(entry)
        if not names:
            layout.label(text="No example keys", icon="ERROR")
        elif readout is None:
            col = layout.column(align=True)
            for n in ([REST] if ps.rest_example else []) + names:
                col.label(text=n, icon="SHAPEKEY_DATA")
        else:
            col = layout.column(align=True)
            for n, w in readout:
                row = col.row()
                row.label(text=n, icon="SHAPEKEY_DATA")
                row.label(text=f"{w:.2f}")
        layout.prop(ps, "rest_example")
        layout.prop(ps, "multiresolution")
        if ps.multiresolution:
            layout.prop(ps, "coarse_faces")
            m = _triangle_count(obj.data)
            if ps.coarse_faces >= m:
                layout.label(text=f"Mesh has {m} triangles:", icon="INFO")
                layout.label(text="single resolution")
        layout.label(text="Frozen (vertex group):")
        layout.prop_search(ps, "frozen_group", obj, "vertex_groups", text="", icon="FREEZE")


def _triangle_count(mesh) -> int:
    n = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", n)
    return int(n.sum()) - 2 * len(n)


def weights_readout(entry) -> list[tuple[str, float]] | None:
    """(example key, weight) of the last live update (at the bind pose: the weights there), or
    None when there is no built pose-space solver. ``entry``: the object's cache entry
    (``session.cached_entry(obj)``, None when there is none)."""
    if entry is None or not isinstance(entry.solver, Solver):
        return None
    w = entry.state.get("weights")
    if w is None:
        w = _METHOD.rest_weights(entry.solver)
    names = ([REST] if entry.solver.rest_example else []) + entry.solver.names
    return [(n, float(x)) for n, x in zip(names, w, strict=True)]


_METHOD = register_method(PoseSpaceMethod())
