"""Edge-based iterative deformation (cloth, membrane, shell): ``matdeform.EdgeDeformer``.

Anchor vertices (the vertices of the anchor faces) follow their Empty's full transform as hard
position constraints; every other vertex is solved by the E-M iteration (docs/edge.md). What
the matrix depends on (stretch lambda, bend mu, the edge weights, the direction field) is in the
fingerprint: changing it marks the bind stale. The live settings (the responses p_rho, p_sigma,
gravity, relaxation, the iteration counts) are read on every update and passed to each solve:
changing them costs no rebind.

Live updates run ``live_iterations`` iterations warm-started from the previous result and say
``done=False`` until the largest move is below tolerance, so the session keeps updating from a
timer until the mesh has settled; Settle, renders and Bake run to convergence (up to
``settle_iterations``) from the frame's own start. Past half a turn the session's rotation
vectors give that start its turns (``EdgeDeformer.solve(rotation_vectors=...)``), and live
updates also start each new pose from it (docs/edge.md, "Twists past half a turn").
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from .. import bridge, updates
from ..model import BindError, load_core, settings
from .base import Method, Result, convergence_status, register_method

DIRECTION_ATTR = "md_direction"  # default vector point attribute of the direction field
_AXES = {"X": 0, "Y": 1, "Z": 2}
# gravity: g = Strength x GRAVITY_UNIT x bend x diagonal / vertices (docs/edge.md, "In Blender")
GRAVITY_UNIT = 1e-3


def _is_empty(_self, obj):
    return obj.type == "EMPTY"


def _settings_changed(self, context):
    """A setting the bind depends on: the session compares the object with its bound state."""
    updates.bind_setting(self, context)


def _live_changed(self, context):
    """A live setting changed: solve again with it now (no rebind). The session keeps calling
    the live update from a timer until the new result has settled."""
    obj = self.id_data
    scene = getattr(context, "scene", None)
    if scene is None or not bridge.is_mesh(obj):
        return
    s = settings(obj)
    if not (s.bound and s.live and s.method == EdgeMethod.key and obj.mode == "OBJECT"):
        return
    updates.solve_now(obj, scene)


class EdgeSettings(bpy.types.PropertyGroup):
    stretch: FloatProperty(
        name="Stretch",
        description="Lambda: how strongly edges keep their rest length. Small: a membrane that "
        "stretches; large: cloth. Only stretch / bend and the mesh resolution matter (rebind)",
        default=1e-4,
        min=0.0,
        soft_max=1.0,
        precision=5,
        step=0.01,
        update=_settings_changed,
    )
    bend: FloatProperty(
        name="Bend",
        description="Mu: how strongly every interior edge keeps its rest fold (rebind)",
        default=1.0,
        min=1e-6,
        soft_max=10.0,
        precision=4,
        update=_settings_changed,
    )
    use_paint_weights: BoolProperty(
        name="Paint Weights",
        description="Scale each edge by the stored painted stiffness ('Stiffness from Paint'): "
        "soft paint stretches and folds more (rebind)",
        default=True,
        update=_settings_changed,
    )
    p_stretch: FloatProperty(
        name="Stretch Response",
        description="p_rho in [0,1]: how far each iteration pulls edges to their rest length "
        "(at convergence it scales Stretch). Live, no rebind",
        default=1.0,
        min=0.0,
        max=1.0,
        update=_live_changed,
    )
    p_bend: FloatProperty(
        name="Bend Response",
        description="p_sigma in [0,1]: how far each iteration pulls edges to their rest fold "
        "(at convergence it scales Bend). Live, no rebind",
        default=1.0,
        min=0.0,
        max=1.0,
        update=_live_changed,
    )
    gravity_strength: FloatProperty(
        name="Gravity",
        description="Pseudo gravity strength (0 = none): the total pull is Strength x 0.001 x "
        "bend x mesh diagonal, spread over the vertices. Live",
        default=0.0,
        min=0.0,
        soft_max=10.0,
        update=_live_changed,
    )
    use_scene_gravity: BoolProperty(
        name="Scene Direction",
        description="Pull along the scene's gravity direction (Scene > Gravity); off: along "
        "Direction, in world space. Live",
        default=True,
        update=_live_changed,
    )
    gravity_direction: FloatVectorProperty(
        name="Direction",
        description="World-space direction gravity pulls to, when Scene Direction is off",
        size=3,
        default=(0.0, 0.0, -1.0),
        subtype="DIRECTION",
        update=_live_changed,
    )
    live_iterations: IntProperty(
        name="Iterations",
        description="Iterations per live update, warm-started from the previous result: the "
        "mesh settles over a few updates (Settle runs to convergence)",
        default=5,
        min=1,
        soft_max=50,
    )
    settle_iterations: IntProperty(
        name="Settle Max",
        description="Iteration limit of Settle and Bake (run until the largest move is below "
        "Tolerance)",
        default=1000,
        min=1,
        soft_max=20000,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description="Converged when the estimated distance to the solution (the last move "
        "scaled by how slowly the moves shrink) is below this fraction of the mesh's "
        "bounding-box diagonal",
        default=1e-5,
        min=0.0,
        soft_max=1e-2,
        precision=6,
        step=0.001,
        update=_live_changed,
    )
    relaxation: FloatProperty(
        name="Relaxation",
        description="Fraction of each iteration's step taken (1 = the paper). Below 1 (e.g. "
        "0.8) damps the back-and-forth of poses far from rest. Live",
        default=1.0,
        min=0.05,
        max=1.0,
        update=_live_changed,
    )
    direction_source: EnumProperty(
        name="Directions",
        description="Direction field: edges along it keep their length and fold, edges across "
        "it go soft (rebind)",
        items=(
            ("NONE", "None", "Isotropic material", 0),
            (
                "ATTRIBUTE",
                "Attribute",
                f"Per-vertex vectors from a FLOAT_VECTOR point attribute (default "
                f"'{DIRECTION_ATTR}'), in the mesh's local space",
                1,
            ),
            ("EMPTY", "Empty Axis", "One direction everywhere: an axis of an Empty", 2),
        ),
        default="NONE",
        update=_settings_changed,
    )
    direction_attribute: StringProperty(
        name="Attribute",
        description="FLOAT_VECTOR point attribute holding the direction field (mesh local space)",
        default=DIRECTION_ATTR,
        update=_settings_changed,
    )
    direction_empty: PointerProperty(
        name="Empty",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Empty whose axis gives the direction (read at Bind; turning it afterwards "
        "asks for a Rebind)",
        update=_settings_changed,
    )
    direction_axis: EnumProperty(
        name="Axis",
        items=(("X", "X", "", 0), ("Y", "Y", "", 1), ("Z", "Z", "", 2)),
        default="Z",
        update=_settings_changed,
    )
    # the Empty axis in mesh coordinates, frozen at bind (solvers rebuilt after loading a file
    # use it: world matrices are not evaluated during load)
    bind_direction: FloatVectorProperty(size=3, default=(0.0, 0.0, 1.0), options={"HIDDEN"})


def edge_settings(obj) -> EdgeSettings:
    return getattr(settings(obj), EdgeMethod.settings_name)


@dataclass
class Solver:
    deformer: object
    rest: np.ndarray  # (n_c,3) rest positions of the compacted mesh
    constrained: np.ndarray  # (k,) compacted vertex indices, the order solve() expects
    owner: np.ndarray  # (k,) anchor of each constrained vertex
    anchor_ids: np.ndarray  # (A,) the session anchor of each solver anchor
    diagonal: float
    n: int
    bend: float  # mu: the unit of the gravity strength


def empty_axis(obj, s: EdgeSettings, depsgraph=None) -> np.ndarray:
    """(3,) unit axis of the direction Empty in the mesh's local coordinates."""
    emp = s.direction_empty
    m_obj = bridge.world_matrix(obj, depsgraph)
    m_emp = bridge.world_matrix(emp, depsgraph)
    if m_obj is None or m_emp is None:
        raise BindError(f"Direction Empty '{emp.name}' is not evaluated here")
    axis = m_emp[:3, _AXES[s.direction_axis]]
    try:
        d = np.linalg.solve(m_obj[:3, :3], axis)
    except np.linalg.LinAlgError:
        raise BindError("Object is scaled to zero: cannot read the direction Empty") from None
    norm = float(np.linalg.norm(d))
    if not np.isfinite(norm) or norm <= 1e-12:
        raise BindError(f"Direction Empty '{emp.name}' is scaled to zero along its axis")
    return d / norm


def direction_field(obj, s: EdgeSettings, a: bridge.MeshArrays, binding: bool):
    """(n,3) direction field of the full mesh in local coordinates, or None (isotropic)."""
    if s.direction_source == "ATTRIBUTE":
        name = s.direction_attribute
        d = bridge.read_vector_attribute(obj.data, name, "POINT", len(a.rest))
        if d is None:
            found = bridge.attribute_kind(obj.data, name) if name else None
            what = "not found" if found is None else f"is {found[1]} on {found[0]}"
            raise BindError(
                f"Directions: point attribute '{name}' {what}; expected FLOAT_VECTOR on POINT"
            )
        if not np.all(np.isfinite(d)):
            raise BindError(f"Directions: attribute '{name}' has NaN or infinite values")
        return d
    if s.direction_source == "EMPTY":
        if s.direction_empty is None:
            raise BindError("Directions: no Empty set (pick one, or set Directions to None)")
        if binding:  # as it will read back from the float32 property
            axis = empty_axis(obj, s).astype(np.float32).astype(np.float64)
        else:
            axis = np.array(tuple(s.bind_direction), dtype=np.float64)
        return np.broadcast_to(axis, a.rest.shape).copy()
    return None


def edge_weights(inputs, edges_c: np.ndarray) -> np.ndarray | None:
    """(E,) weight per solver edge (``mesh_edges`` order of the compacted triangles) from the
    stored stiffness: the stored per-edge bending stiffness phi where the edge is a mesh edge,
    else (triangulation diagonals, or no phi) the mean shear psi of its triangles. None when
    no stiffness was ever stored (uniform)."""
    if inputs.psi is None:
        return None
    a = inputs.arrays
    n = len(a.rest)
    full = edges_c if inputs.used is None else inputs.used[edges_c]
    key = full.min(axis=1) * n + full.max(axis=1)  # sorted by construction
    psi_t = inputs.psi[a.tri_poly]
    t = inputs.tris_c
    tri_e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    tri_e = tri_e if inputs.used is None else inputs.used[tri_e]
    tk = tri_e.min(axis=1) * n + tri_e.max(axis=1)
    idx = np.searchsorted(key, tk)
    s = np.bincount(idx, weights=np.tile(psi_t, 3), minlength=len(key))
    c = np.bincount(idx, minlength=len(key))
    w = s / np.maximum(c, 1)
    if inputs.phi is not None:
        ev = np.sort(a.edge_verts, axis=1)
        ek = ev[:, 0] * n + ev[:, 1]
        pos = np.searchsorted(key, ek)
        pos = np.minimum(pos, len(key) - 1)
        hit = key[pos] == ek
        w[pos[hit]] = inputs.phi[hit]
    return w


class EdgeMethod(Method):
    key = "EDGE"
    number = 1
    label = "Edge-based"
    description = (
        "Edge-based iterative deformation: edges keep their length (cloth) and fold (shells) "
        "as Stretch and Bend say, with pseudo gravity and direction fields; settles over a few "
        "live updates"
    )
    iterative = True
    settings_name = "edge"
    settings_class = EdgeSettings

    def gather(self, obj, inputs, binding) -> None:
        s = edge_settings(obj)
        inputs.extra["edge_settings"] = {
            "stretch": float(s.stretch),
            "bend": float(s.bend),
            "paint": bool(s.use_paint_weights),
        }
        inputs.extra["direction"] = direction_field(obj, s, inputs.arrays, binding)
        if s.direction_source == "EMPTY":
            inputs.extra["axis"] = inputs.extra["direction"][0].copy()

    def commit(self, obj, inputs) -> None:
        axis = inputs.extra.get("axis")
        if axis is not None:
            edge_settings(obj).bind_direction = axis.tolist()

    def fingerprint(self, obj, inputs) -> list:
        s = edge_settings(obj)
        d = inputs.extra.get("direction")
        return [
            np.array([s.stretch, s.bend], dtype=np.float64),
            "paint weights" if s.use_paint_weights else "uniform weights",
            # integers: rounding floats could give -0.0 and 0.0 (different bytes)
            "isotropic" if d is None else np.rint(d * 1e6).astype(np.int64),
        ]

    fingerprint_what = "method, Stretch, Bend, weights or directions"

    def build(self, inputs) -> Solver:
        md = load_core()
        rest = inputs.verts_c
        tris = inputs.tris_c
        # anchor vertices: those of the anchor faces; a vertex shared by two anchors follows
        # the first
        owner_full = np.full(len(inputs.arrays.rest), -1, dtype=np.int64)
        for i in reversed(range(len(inputs.anchor_faces))):
            owner_full[np.unique(inputs.arrays.tris[inputs.anchor_faces[i]])] = i
        verts = np.flatnonzero(owner_full >= 0)
        constrained = inputs.compact_index(verts)
        # the solver's anchors are the Empties' (numbered by first appearance), so that each
        # fits one rotation and takes its Empty's turns
        ids, anchor_of = np.unique(owner_full[verts], return_inverse=True)
        d = inputs.extra.get("direction")
        if d is not None and inputs.used is not None:
            d = d[inputs.used]
        s = inputs.extra["edge_settings"]
        w = None
        if s["paint"]:
            w = edge_weights(inputs, np.asarray(md.mesh_edges(tris), dtype=np.int64))
        try:
            dfm = md.EdgeDeformer(
                rest,
                tris,
                constrained,
                stretch=s["stretch"],
                bend=s["bend"],
                edge_weight=w,
                direction=d,
                anchors=anchor_of,
            )
        except (ValueError, RuntimeError) as exc:
            raise BindError(f"Solver rejected the mesh: {exc}") from exc
        return Solver(
            dfm, rest, constrained, owner_full[verts], ids, dfm.diagonal, len(rest), s["bend"]
        )

    def solve(self, solver, transforms, state, budget, progress=None, rotations=None) -> Result:
        p = state.get("params") or _default_params()
        t = np.asarray(transforms, dtype=np.float64)
        r = solver.rest[solver.constrained]
        m = t[solver.owner]
        pos = np.einsum("kij,kj->ki", m[:, :3, :3], r) + m[:, :3, 3]
        # the pose: anchor matrices, turns and the live settings
        key = t.tobytes() + repr(sorted((k, np.asarray(v).tolist()) for k, v in p.items())).encode()
        if rotations is not None:
            key += np.asarray(rotations, dtype=np.float64).tobytes()
        # The start. Settle, renders and bakes (budget None), and every update past half a turn
        # (rotations given), start from the frame alone: the rest mesh, its first step carrying
        # the anchors' turns (docs/edge.md, "Twists past half a turn"); positions alone cannot
        # tell 180 from 540 degrees, and a start from the previous frame would make the result
        # depend on the order frames were evaluated in. Live updates past half a turn continue
        # only this very pose's own iteration (iterations compose bit for bit); below half a
        # turn they warm-start from the last result, whatever pose it was.
        seeded = state.pop("seeded", False)
        x0 = state.get("x")
        if x0 is not None and x0.shape != solver.rest.shape:
            x0 = None
        own = state.get("chain") == key or seeded
        rv = None
        if budget is None or rotations is not None:
            if not (budget is not None and own):
                x0 = None
                if rotations is not None:
                    rv = anchor_vectors(solver, pos, rotations)
        its = p["settle_iterations"] if budget is None else int(budget)
        g = p["gravity"] * (GRAVITY_UNIT * solver.bend * solver.diagonal / solver.n)
        d = solver.deformer
        x = d.solve(
            pos,
            iterations=its,
            tol=p["tol"],
            p_stretch=p["p_stretch"],
            p_bend=p["p_bend"],
            gravity=g,
            initial=x0,
            relaxation=p["relaxation"],
            rotation_vectors=rv,
        )
        state["x"] = x
        # the pose whose frame-only iteration x continues (None: x came from a warm start)
        state["chain"] = key if (x0 is None or own) else None
        # live iterations spent on this very pose and these settings: a pose that never meets
        # the tolerance (a two-cycle, docs/edge.md) stops the settling timer at Settle Max
        spent = (state.get("spent", 0) if state.get("pose_key") == key else 0) + d.last_iterations
        state["pose_key"], state["spent"] = key, spent
        converged = d.last_converged or p["tol"] == 0.0
        state.update(move=d.last_move, error=d.last_error, converged=converged)
        done = budget is None or converged or spent >= p["settle_iterations"]
        return Result(x, done)

    def status(self, state) -> tuple[bool, str] | None:
        return convergence_status(
            state, "iterations", "raise Settle Max, or see the Edge docs on two-cycles"
        )

    def seed(self, solver, state, positions) -> None:
        # the output key's unsettled result of the pose about to be solved (the session checks
        # its record): the next live update continues it
        state["x"] = np.array(positions, dtype=np.float64)
        state["seeded"] = True

    def watched_objects(self, obj) -> tuple:
        s = edge_settings(obj)
        return (s.direction_empty,) if s.direction_source == "EMPTY" else ()

    def check_live(self, obj, entry, depsgraph) -> None:
        """Reads the live settings for the next solve (they are not part of the bind), and
        stops updating if the direction Empty turned since bind."""
        s = edge_settings(obj)
        entry.state["params"] = live_params(obj, s, depsgraph)
        if s.direction_source == "EMPTY" and s.direction_empty is not None:
            now = empty_axis(obj, s, depsgraph)
            if not np.allclose(now, tuple(s.bind_direction), atol=1e-6):
                raise BindError("Direction Empty turned since bind - click Rebind")

    def live_budget(self, obj) -> int:
        return int(edge_settings(obj).live_iterations)

    def draw(self, layout, obj, entry) -> None:
        s = edge_settings(obj)
        col = layout.column(align=True)
        col.prop(s, "stretch")
        col.prop(s, "bend")
        col = layout.column(align=True)
        col.prop(s, "p_stretch", text="Stretch Resp.")
        col.prop(s, "p_bend", text="Bend Resp.")
        col = layout.column(align=True)
        col.prop(s, "gravity_strength")
        col.prop(s, "use_scene_gravity")
        if not s.use_scene_gravity:
            col.prop(s, "gravity_direction", text="")
        col = layout.column(align=True)
        col.prop(s, "live_iterations")
        col.prop(s, "settle_iterations")
        col.prop(s, "tolerance")
        col.prop(s, "relaxation")
        layout.prop(s, "use_paint_weights")
        layout.prop(s, "direction_source")
        if s.direction_source == "ATTRIBUTE":
            layout.label(text="Point attribute (vector):")
            layout.prop(s, "direction_attribute", text="")
        elif s.direction_source == "EMPTY":
            layout.prop(s, "direction_empty")
            layout.prop(s, "direction_axis", expand=True)


def anchor_vectors(solver: Solver, pos: np.ndarray, rotations) -> np.ndarray:
    """(A,3) the solver anchors' rotation vectors: each Empty's vector (the session's branch),
    moved onto the rotation the solver fits to its vertices (rest -> ``pos``). They differ only
    when an Empty is scaled unevenly (the fit is then not the polar factor's rotation)."""
    v = np.asarray(rotations, dtype=np.float64)[solver.anchor_ids]
    rest = solver.rest[solver.constrained]
    fits, rows = [], []
    for a in range(len(v)):
        sel = solver.owner == solver.anchor_ids[a]
        x, y = rest[sel], pos[sel]
        if len(x) < 3:
            continue
        xc, yc = x - x.mean(0), y - y.mean(0)
        sx = np.linalg.svd(xc, compute_uv=False)
        if sx[1] <= 1e-9 * sx[0]:  # in a line: the solver fits nothing there
            continue
        u, _s, vt = np.linalg.svd(yc.T @ xc)
        fit = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
        fits.append(fit)
        rows.append(a)
    if rows:
        near = load_core().unwrap_rotations(np.stack(fits)[None], start=v[rows])[0]
        v[rows] = near
    return v


def _default_params() -> dict:
    return {
        "p_stretch": 1.0,
        "p_bend": 1.0,
        "gravity": np.zeros(3),
        "tol": 1e-5,
        "relaxation": 1.0,
        "settle_iterations": 1000,
    }


def gravity_direction(obj, s: EdgeSettings, depsgraph=None) -> np.ndarray:
    """(3,) unit direction gravity pulls to, in the mesh's local coordinates (zero if none)."""
    if s.use_scene_gravity:
        scene = bpy.context.scene
        g = np.array(tuple(scene.gravity), dtype=np.float64) if scene is not None else None
        if g is None or not np.any(g):
            g = np.array([0.0, 0.0, -1.0])
    else:
        g = np.array(tuple(s.gravity_direction), dtype=np.float64)
    m_obj = bridge.world_matrix(obj, depsgraph)
    if m_obj is not None:
        g = np.linalg.solve(m_obj[:3, :3], g)
    norm = float(np.linalg.norm(g))
    return g / norm if np.isfinite(norm) and norm > 0 else np.zeros(3)


def live_params(obj, s: EdgeSettings, depsgraph=None) -> dict:
    """The settings each solve reads (none of them is part of the bind)."""
    strength = float(s.gravity_strength)
    g = gravity_direction(obj, s, depsgraph) * strength if strength > 0 else np.zeros(3)
    return {
        "p_stretch": float(s.p_stretch),
        "p_bend": float(s.p_bend),
        "gravity": g,
        "tol": float(s.tolerance),
        "relaxation": float(s.relaxation),
        "settle_iterations": int(s.settle_iterations),
    }


register_method(EdgeMethod())
