"""Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy):
``matdeform.PyramidDeformer``.

The anchors' faces give the control vertices; each is placed by its Empty's full transform
(rest position moved by the anchor's motion since bind), and the rest of the mesh is found by
Newton's method on the pyramids' least-squares energy. Iterative: a live update spends the
per-update budget of Newton iterations, warm-started from the previous result; Settle and Bake
run to convergence from the solver's own start. No stiffness: the painted stiffness is ignored
(and not part of what this bind depends on beyond the session's common fingerprint). See
docs/pyramid.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import bpy
import numpy as np
from bpy.props import FloatProperty, IntProperty

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
            "Newton iterations spent on each live update; the mesh keeps settling after you "
            "stop dragging (more: closer to the result while dragging, slower updates)"
        ),
        default=1,
        min=1,
        soft_max=20,
        update=_live_changed,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description=(
            "Converged when a Newton step moves no vertex more than this fraction of the mesh's "
            "bounding-box diagonal"
        ),
        default=1e-6,
        min=1e-12,
        max=1e-2,
        precision=8,
        step=0.0001,
        update=_live_changed,
    )
    scale_weight: FloatProperty(
        name="Keep Size",
        description=(
            "How strongly each vertex's neighbourhood keeps its size: 0 keeps only its shape "
            "(parts may grow or shrink), larger values keep lengths more"
        ),
        default=0.003,
        min=0.0,
        soft_max=1.0,
        precision=4,
        step=0.01,
        update=_live_changed,
    )
    max_iterations: IntProperty(
        name="Max Iterations",
        description=(
            "Most Newton iterations spent on one pose (Settle, each baked frame, and the live "
            "updates after a drag); stops there if it has not converged"
        ),
        default=100,
        min=1,
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
    """The library's progress(iterations, step) as the operator's progress(fraction, text): the
    fraction is the larger of the budget spent and the way from the first reported move down
    to tol on a log scale, never decreasing. A failing progress display never fails the solve
    (a RuntimeError from it would read as a diverged iteration)."""
    seen = {"first": None, "fraction": 0.0}

    def report(iterations: int, move: float) -> None:
        first = seen["first"] = seen["first"] or move
        by_move = 0.0
        if first > tol > 0 and move > 0:
            by_move = math.log(first / max(move, tol)) / math.log(first / tol)
        seen["fraction"] = max(seen["fraction"], iterations / max(budget, 1), by_move)
        # The library reports its L-BFGS phase with 0 Newton iterations.
        phase = f"{iterations} iterations" if iterations else "L-BFGS"
        try:
            progress(
                min(seen["fraction"], 1.0),
                f"Material Deform: settling, {phase}, step {move:.1e} (tolerance {tol:g})",
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
        # rotations: the anchors' unwrapped vectors; each control gets its anchor's, so a start
        # built from the controls (Settle, Bake) carries turns past half a turn. A warm start
        # carries them already.
        # the object's settings, handed over by check_live (Bind's solve of a kept pose runs
        # before any live update: the defaults then)
        tol, weight, most = state.get("settings", (1e-6, 0.003, 100))
        targets = self.targets(solver, transforms)
        pose = (targets.tobytes(), tol, weight, most)
        if state.get("pose") != pose:
            state["spent"] = 0  # a new pose or new settings: a new allowance of iterations
        spent = state.get("spent", 0)
        # Live updates warm-start from the last result and share Max Iterations per pose.
        # Settle and Bake start from the solver's own start (built from the controls alone)
        # with the whole allowance: the energy can have several minima, so a baked frame then
        # depends on its pose only (a farm can bake frames in any order) and Settle equals the
        # library.
        if budget is None:
            it, x0 = most, None
        else:
            it, x0 = min(budget, max(most - spent, 1)), state.get("x")
        d = solver.deformer

        def attempt(x0):
            vectors = (
                None if rotations is None or x0 is not None else np.asarray(rotations)[solver.owner]
            )
            try:
                x = d.deform(
                    targets,
                    iterations=it,
                    tol=tol,
                    initial=x0,
                    scale_weight=weight,
                    progress=None if progress is None else _settle_report(progress, it, tol),
                    progress_seconds=PROGRESS_SECONDS,
                    rotation_vectors=vectors,
                )
            except ValueError as exc:
                # A sheared or unevenly scaled anchor has no rotation its controls' fit
                # reproduces to 1e-4 rad: start from the principal logs instead.
                if vectors is None or not str(exc).startswith("rotation_vectors"):
                    raise
                x = d.deform(
                    targets,
                    iterations=it,
                    tol=tol,
                    scale_weight=weight,
                    progress=None if progress is None else _settle_report(progress, it, tol),
                    progress_seconds=PROGRESS_SECONDS,
                )
            # A safety net: the library only lowers the energy from its start, but a live chain
            # starts from the last result (or an undone key), so bound the result by the pose
            # itself. A result spans about the rest diagonal times the controls' spread
            # relative to rest; 3x that plus the controls' own extent is a runaway.
            if _extent(x) > 3.0 * (
                solver.diagonal * _stretch_of(solver, targets) + _extent(targets)
            ):
                raise RuntimeError("the iteration diverged (the mesh grew 3x beyond its pose)")
            return x

        try:
            try:
                x = attempt(x0)
            except RuntimeError:
                # A warm start can be the cause (the last result of an extreme pose, e.g. an
                # Empty scaled by 1e30 and back): this pose from its own start, at once, since
                # no further update may come to retry it.
                if x0 is None:
                    raise
                x = attempt(None)
        except RuntimeError as exc:  # diverged: keep the last good result, start over next time
            for k in ("x", "pose", "spent", "converged"):
                state.pop(k, None)
            raise ValueError(f"pyramid iteration failed ({exc})") from None
        spent = d.last_iterations if budget is None else spent + d.last_iterations
        converged = bool(d.last_converged)
        state.update(x=x, pose=pose, spent=spent, move=d.last_step, converged=converged)
        state["iterations"] = d.last_iterations
        # out of iterations for this pose: final (not converged) rather than updating forever
        return Result(x, done=converged or spent >= most)

    def status(self, state) -> tuple[bool, str] | None:
        return convergence_status(state, "iterations", "raise Max Iterations, or add anchors")

    def seed(self, solver, state, positions) -> None:
        state["x"] = np.array(positions, dtype=np.float64)

    def live_budget(self, obj) -> int | None:
        return int(settings(obj).pyramid.live_iterations)

    def check_live(self, obj, entry, depsgraph) -> None:
        """Hand the live settings to ``solve`` (which sees only the solver and its state)."""
        p = settings(obj).pyramid
        entry.state["settings"] = (float(p.tolerance), float(p.scale_weight), int(p.max_iterations))

    def draw(self, layout, obj, entry) -> None:
        p = settings(obj).pyramid
        layout.prop(p, "live_iterations", text="Per Update")
        layout.prop(p, "tolerance")
        layout.prop(p, "max_iterations")
        layout.prop(p, "scale_weight")


register_method(PyramidMethod())
