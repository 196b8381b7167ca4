"""Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy):
``matdeform.PyramidDeformer``.

The anchors' faces give the control vertices; each is placed by its Empty's full transform
(rest position moved by the anchor's motion since bind), and the rest of the mesh is found by
iterating the local reconstructions. Iterative: a live update spends the per-update budget,
warm-started from the previous result; Settle and Bake run to convergence. No stiffness: the
painted stiffness is ignored (and not part of what this bind depends on beyond the session's
common fingerprint). See docs/pyramid.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty

from .. import anchor_math as am
from .. import updates
from ..model import BindError, load_core, settings
from .base import Method, Result, convergence_status, register_method


def _live_changed(self, context):
    """A live setting (no rebind): solve the current pose again with it."""
    updates.live_setting(self, context)


class PyramidSettings(bpy.types.PropertyGroup):
    live_iterations: IntProperty(
        name="Iterations per Update",
        description=(
            "Sweeps spent on each live update; the mesh keeps settling after you stop dragging "
            "(more: closer to the result while dragging, slower updates)"
        ),
        # the acceleration restarts with every update: below ~10 sweeps it has too little
        # history and the plain sweeps can drift off on long thin parts (docs/pyramid.md)
        default=30,
        min=10,
        soft_max=500,
        update=_live_changed,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description=(
            "Converged when no vertex moves more than this fraction of the mesh's "
            "bounding-box diagonal in one sweep"
        ),
        default=1e-6,
        min=1e-12,
        max=1e-2,
        precision=8,
        step=0.0001,
        update=_live_changed,
    )
    stretch: BoolProperty(
        name="Stretch Correction",
        description=(
            "Scale the reconstruction weights by how much each edge is stretched (the paper's "
            "correction): keeps edge lengths; try it off if a pose does not settle"
        ),
        # on: it converged on all cat poses measured, off missed two (docs/pyramid.md); off
        # converged where it did not on a bar turned 0.8 rad
        default=True,
        update=_live_changed,
    )
    max_iterations: IntProperty(
        name="Max Sweeps",
        description=(
            "Most sweeps spent on one pose (Settle, each baked frame, and the live updates "
            "after a drag); stops there if it has not converged"
        ),
        default=20000,
        min=10,
        update=_live_changed,
    )


@dataclass
class Solver:
    deformer: object
    rest: np.ndarray  # (k,3) rest positions of the control vertices (compacted order)
    owner: np.ndarray  # (k,) the anchor that places each control vertex
    diagonal: float


def control_vertices(inputs) -> tuple[np.ndarray, np.ndarray]:
    """(control vertex indices into the compacted mesh (k,), anchor of each (k,)): the vertices
    of every anchor's faces, sorted. Anchors own disjoint faces, but may share a vertex where
    their faces touch: that vertex goes to the first anchor."""
    tris = inputs.arrays.tris
    idx, owner = [], []
    seen = set()
    for a, faces in enumerate(inputs.anchor_faces):
        for v in np.unique(tris[faces]):
            if int(v) not in seen:
                seen.add(int(v))
                idx.append(int(v))
                owner.append(a)
    idx = np.asarray(idx, np.int64)
    order = np.argsort(idx)
    return inputs.compact_index(idx[order]), np.asarray(owner, np.int64)[order]


PROGRESS_SECONDS = 0.1  # s between progress reports of a long solve (tests set 0)


def _settle_report(progress, budget: int, tol: float):
    """The library's progress(sweeps, move) as the operator's progress(fraction, text): the
    fraction is the larger of the budget spent and the way from the first reported move down
    to tol on a log scale, never decreasing. A failing progress display never fails the solve
    (a RuntimeError from it would read as a diverged iteration)."""
    seen = {"first": None, "fraction": 0.0}

    def report(sweeps: int, move: float) -> None:
        first = seen["first"] = seen["first"] or move
        by_move = 0.0
        if first > tol > 0 and move > 0:
            by_move = math.log(first / max(move, tol)) / math.log(first / tol)
        seen["fraction"] = max(seen["fraction"], sweeps / max(budget, 1), by_move)
        try:
            progress(
                min(seen["fraction"], 1.0),
                f"Material Deform: settling, {sweeps} sweeps, move {move:.1e} (tolerance {tol:g})",
            )
        except Exception as exc:  # the display only
            print(f"Material Deform: progress display failed: {exc}")

    return report


def _extent(p: np.ndarray) -> float:
    """Bounding-box diagonal of points (m,3)."""
    return float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))) if len(p) else 0.0


def _stretch_of(solver: Solver, targets: np.ndarray) -> float:
    """How much the controls spread relative to rest (>= 1)."""
    r = _extent(solver.rest)
    return max(1.0, _extent(targets) / r) if r > 0 else 1.0


class PyramidMethod(Method):
    key = "PYRAMID"
    number = 3
    label = "Pyramid coordinates"
    description = (
        "Sheffer and Kraevoy: shape-preserving pyramid coordinates. The anchor faces' vertices "
        "are control vertices; the rest keeps its local shape (angles and projected lengths), "
        "no stiffness painting (iterative: settles over several updates)"
    )
    anchor_modes = frozenset({am.POSITION})
    iterative = True
    settings_name = "pyramid"
    settings_class = PyramidSettings

    def build(self, inputs) -> Solver:
        md = load_core()
        control, owner = control_vertices(inputs)
        verts = inputs.verts_c
        try:
            d = md.PyramidDeformer(verts, inputs.tris_c, control)
        except (ValueError, RuntimeError) as exc:
            raise BindError(f"Solver rejected the mesh: {exc}") from exc
        return Solver(d, verts[control].copy(), owner, float(d.diagonal))

    @staticmethod
    def targets(solver: Solver, transforms: np.ndarray) -> np.ndarray:
        """(k,3) control positions: each rest position moved by its anchor's (4,4) motion."""
        t = np.asarray(transforms, np.float64)[solver.owner]
        return np.einsum("kij,kj->ki", t[:, :3, :3], solver.rest) + t[:, :3, 3]

    def solve(self, solver, transforms, state, budget, progress=None, rotations=None) -> Result:
        # rotations: ignored for now (the control vertices sit alike at 180 and 540 degrees; the
        # turns are to give the iteration its start)
        # the object's settings, handed over by check_live (Bind's solve of a kept pose runs
        # before any live update: the defaults then)
        tol, stretch, most = state.get("settings", (1e-6, True, 20000))
        targets = self.targets(solver, transforms)
        pose = (targets.tobytes(), tol, stretch, most)
        if state.get("pose") != pose:
            state["spent"] = 0  # a new pose or new settings: a new allowance of sweeps
        spent = state.get("spent", 0)
        # Live updates warm-start from the last result and share Max Sweeps per pose. Settle
        # and Bake start from the solver's own start (the controls' best-fit similarity of the
        # rest mesh) with the whole allowance: the iteration has several fixed points, and warm
        # starts from another frame reached a poorer one (edges 0.36-1.49x rest instead of
        # 0.92-1.10x, docs/pyramid.md). So a baked frame depends on its pose only (a farm can
        # bake frames in any order) and Settle equals the library.
        if budget is None:
            it, x0 = most, None
        else:
            it, x0 = min(budget, max(most - spent, 1)), state.get("x")
        d = solver.deformer
        try:
            x = d.deform(
                targets,
                iterations=it,
                tol=tol,
                initial=x0,
                stretch=stretch,
                progress=None if progress is None else _settle_report(progress, it, tol),
                progress_seconds=PROGRESS_SECONDS,
            )
            # The library's runaway test is relative to the start, and a live chain starts
            # from the last result: so also bound the result by the pose itself. A result
            # spans about the rest diagonal times the controls' spread relative to rest; 3x
            # that plus the controls' own extent is a runaway (the review's cylinder chain
            # went 8x, 17x, 21x ... the rest size in 30-sweep steps, then 1e18)
            if _extent(x) > 3.0 * (
                solver.diagonal * _stretch_of(solver, targets) + _extent(targets)
            ):
                raise RuntimeError("the iteration diverged (the mesh grew 3x beyond its pose)")
        except RuntimeError as exc:  # diverged: keep the last good result, start over next time
            for k in ("x", "pose", "spent", "converged"):
                state.pop(k, None)
            raise ValueError(f"pyramid iteration failed ({exc})") from None
        spent = d.last_iterations if budget is None else spent + d.last_iterations
        converged = bool(d.last_move < tol) or d.last_iterations < it
        state.update(x=x, pose=pose, spent=spent, move=d.last_move, converged=converged)
        state["iterations"] = d.last_iterations
        # out of sweeps for this pose: final (not converged) rather than updating forever
        return Result(x, done=converged or spent >= most)

    def status(self, state) -> tuple[bool, str] | None:
        return convergence_status(
            state, "sweeps", "raise Max Sweeps, or try Stretch Correction off"
        )

    def seed(self, solver, state, positions) -> None:
        state["x"] = np.array(positions, dtype=np.float64)

    def live_budget(self, obj) -> int | None:
        return int(settings(obj).pyramid.live_iterations)

    def check_live(self, obj, entry, depsgraph) -> None:
        """Hand the live settings to ``solve`` (which sees only the solver and its state)."""
        p = settings(obj).pyramid
        entry.state["settings"] = (float(p.tolerance), bool(p.stretch), int(p.max_iterations))

    def draw(self, layout, obj, entry) -> None:
        p = settings(obj).pyramid
        layout.prop(p, "live_iterations", text="Per Update")
        layout.prop(p, "tolerance")
        layout.prop(p, "max_iterations")
        layout.prop(p, "stretch")


register_method(PyramidMethod())
