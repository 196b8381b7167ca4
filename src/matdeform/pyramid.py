"""Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy).

Each vertex is described relative to its one-ring (its "pyramid") by angles and projected
lengths, which do not change under rotation and uniform scale. A pose given by a few control
vertices is the configuration in which every pyramid is, in least squares, a rotated and scaled
copy of its rest shape; it is found by Newton's method on all free vertices at once. See
docs/pyramid.md.
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import (
    as_count,
    as_faces,
    as_index_set,
    as_real,
    as_rotation_vectors,
    as_vertices,
)

#: Vertex kinds in ``pyramid_coordinates(...)["kind"]``.
KIND_INTERIOR, KIND_BOUNDARY, KIND_FOLLOWER, KIND_ISOLATED = 0, 1, 2, 3

#: How strongly each pyramid keeps its rest size by default (``scale_weight``, docs/pyramid.md).
DEFAULT_SCALE_WEIGHT = 0.003
#: Newton iterations of ``deform(iterations=None)``.
DEFAULT_ITERATIONS = 100


def pyramid_coordinates(vertices, faces) -> dict:
    """The per-vertex pyramid description of a mesh at rest, for inspection and tests.

    vertices : (n,3) float, any length unit. faces : (m,3) int triangles.

    Returns a dict of numpy arrays. Per-neighbour arrays are CSR: vertex v owns slots
    ``offsets[v]:offsets[v+1]``, its neighbours in cyclic order around it.

    * ``offsets`` (n+1,) int, ``neighbors`` (S,) int: v_1..v_m of each vertex.
    * ``alpha`` (S,) radians: signed angle at v' from v'_i to v'_{i+1} about n (the last slot
      wraps to the first neighbour; for a boundary vertex it spans the closing edge).
    * ``beta`` (S,) radians in [0, pi]: angle between n and the edge vector v - v_i.
    * ``length`` (S,): l_i = |v' - v'_i|, projected edge lengths (mesh unit).
    * ``weight`` (S,): mean value weights from alpha and length, summing to 1 per vertex.
    * ``normal`` (n,3): unit n, the direction of the neighbour polygon's vector area.
    * ``offset`` (n,): plane offset d = -mean_i n.v_i (P passes through the neighbours' mean).
    * ``height`` (n,): n.v + d, the height of v above P.
    * ``kind`` (n,) int8: 0 interior, 1 boundary, 2 follower (non-manifold or degenerate fan:
      no description, see docs/pyramid.md), 3 isolated (in no face). Followers and isolated
      vertices have zero normal, angles, lengths and weights.
    """
    v = as_vertices(vertices)
    f = as_faces(faces, v.shape[0])
    return _core.pyramid_coordinates(v, f)


class PyramidDeformer:
    """Pose a mesh by a few control vertices, preserving its local shape (pyramid coordinates).

    The constructor describes every vertex relative to its one-ring (its pyramid: the vertex
    and its neighbours), finds the free vertices (those the controls reach through edges),
    and prepares the Newton solver (the Hessian's sparsity pattern and its symbolic
    factorisation) and the start (two graph-Laplacian factorisations). deform() then minimises

        E(X) = sum over pyramids  min over s, R  |pyramid(X) - s R pyramid(rest)|^2
                                                  + scale_weight s0 (s - 1)^2

    (s a scale, R a rotation, both pyramids centred; s0 the pyramid's squared rest size) over
    the free vertices, with the controls at their targets.

    Parameters
    ----------
    vertices : (n,3) float, rest positions (any length unit; output uses the same unit).
    faces : (m,3) int, triangles.
    control : (k,) int, k >= 1 unique vertex indices whose positions deform() prescribes.

    Defined behaviour: vertices in no face, and parts of the mesh that no control vertex
    reaches through edges, stay exactly at rest. Pyramids whose rest points lie on a line
    (degenerate fans) carry no shape and are left out. The output never contains NaN.
    """

    def __init__(self, vertices, faces, control):
        v = as_vertices(vertices)
        f = as_faces(faces, v.shape[0])
        c = as_index_set(np.atleast_1d(np.asarray(control)), v.shape[0], "control")
        if c.size == 0:
            raise ValueError("control: expected at least one vertex index, got shape (0,)")
        self._n = v.shape[0]
        self._control = c
        self._core = _core.PyramidDeformer(v, f, c.tolist())

    def deform(
        self,
        control_positions,
        iterations: int | None = None,
        tol: float = 1e-6,
        initial=None,
        *,
        scale_weight: float = DEFAULT_SCALE_WEIGHT,
        progress=None,
        progress_seconds: float = 0.1,
        rotation_vectors=None,
        lbfgs_iterations: int | None = None,
    ) -> np.ndarray:
        """Deformed positions (n,3) float64 with the control vertices at control_positions.

        control_positions : (k,3) float, in the order of ``control`` (mesh unit), each
            coordinate within +-1e50.
        iterations : most Newton iterations, int in [0, 2**31 - 1]; None: 100. Each one
            factors the Hessian at most once (twice where the exact Hessian is not positive
            definite). Before them an L-BFGS phase (about 1 ms per iteration at 5k faces) runs
            until a step moves no vertex by more than 1e-4 x diagonal (docs/pyramid.md).
        tol : converged once a full Newton step moves no vertex by more than tol x the rest
            bounding-box diagonal (float >= 0; 0 runs the whole budget). That last step is
            applied, which leaves the result about tol^2 x diagonal from the minimum.
        initial : (n,3) start positions, e.g. the previous result for a live update with a
            small budget; None starts from the controls alone (their clusters' similarities
            blended harmonically, docs/pyramid.md), so the result depends on the pose only.
            Control rows are replaced, vertices no control reaches are put at rest.
        scale_weight : how strongly each pyramid keeps its rest size, float in [0, 1e6]: 0 keeps
            only its shape up to scale (what the description fixes), large values approach
            rigid pyramids.
        progress : None, or a callable ``progress(iterations, step)`` (int, float: that
            iteration's largest vertex move as a fraction of the diagonal; iterations is 0 in
            the L-BFGS phase), called after an iteration at most every ``progress_seconds``
            (float >= 0, 0: after every one) and after the last one, on the calling thread.
            An exception it raises ends the call and propagates. The result does not depend
            on it.
        rotation_vectors : None, or (k,3) float, one rotation vector (axis * angle, radians,
            any length, e.g. from ``unwrap_rotations``) per control in the order of
            ``control``, typically its anchor's. The start then blends each control cluster's
            rotation as the log these vectors give, so it carries turns past half a turn (a
            540-degree twist starts twisted, not at 180). Each vector of a cluster that carries
            a rotation (at least three controls joined by edges, not on a line) must be a log
            of the rotation fitted to that cluster: its exp within 1e-4 rad of it, else
            ValueError; other controls' vectors are not used. Not used with ``initial``.
        lbfgs_iterations : most L-BFGS iterations before the Newton ones, int in
            [0, 2**31 - 1]; None: 50 per Newton iteration of ``iterations``, at most 1000
            (so ``iterations=0`` returns the start). 0 goes straight to Newton's method.

        After the call ``last_iterations`` is the number of Newton iterations
        (``last_lbfgs_iterations`` those of the phase before them), ``last_step``
        the last one's largest vertex move (fraction of the diagonal; NaN after 0 iterations),
        ``last_converged`` whether the stopping rule was met, ``last_energy`` the energy.
        Raises ValueError for bad input and RuntimeError if the energy stops being finite.
        """
        k = len(self._control)
        x = as_vertices(control_positions, "control_positions", rows=k)
        it = DEFAULT_ITERATIONS if iterations is None else as_count(iterations, "iterations")
        t = as_real(tol, "tol", 0.0)
        x0 = None if initial is None else as_vertices(initial, "initial", rows=self._n)
        w = as_real(scale_weight, "scale_weight", 0.0, 1e6)
        if progress is not None and not callable(progress):
            raise ValueError(f"progress: expected a callable or None, got {progress!r}")
        every = as_real(progress_seconds, "progress_seconds", 0.0)
        rv = None if rotation_vectors is None else as_rotation_vectors(rotation_vectors, k)
        lb = -1 if lbfgs_iterations is None else as_count(lbfgs_iterations, "lbfgs_iterations")
        return self._core.deform(x, it, t, x0, w, progress, every, rv, lb)

    def start(self, control_positions, rotation_vectors=None) -> np.ndarray:
        """The start deform() uses without ``initial`` (n,3), from control_positions (k,3) and
        optional rotation_vectors (k,3) as in deform()."""
        k = len(self._control)
        x = as_vertices(control_positions, "control_positions", rows=k)
        rv = None if rotation_vectors is None else as_rotation_vectors(rotation_vectors, k)
        return self._core.start(x, rv)

    def energy(self, positions, scale_weight: float = DEFAULT_SCALE_WEIGHT):
        """The energy deform() minimises (float, squared mesh units) and its gradient (n,3) at
        positions (n,3), for inspection and tests."""
        x = as_vertices(positions, "positions", rows=self._n)
        w = as_real(scale_weight, "scale_weight", 0.0, 1e6)
        return self._core.energy(x, w)

    def reconstruct(self, positions, stretch: bool = False) -> np.ndarray:
        """Every vertex placed once from its neighbours in positions (n,3) by the paper's
        Eq. 1-2 (stretch: its weight scaling by |v' - v'_i| / l_i).

        Controls are placed too. ``reconstruct(rest)`` gives back the rest mesh (followers and
        isolated vertices exactly, the others to round-off).
        """
        x = as_vertices(positions, "positions", rows=self._n)
        return self._core.reconstruct(x, bool(stretch))

    @property
    def last_iterations(self) -> int:
        """Newton iterations of the last deform()."""
        return self._core.last_iterations

    @property
    def last_step(self) -> float:
        """Largest vertex move of the last iteration, as a fraction of the rest diagonal."""
        return self._core.last_step

    @property
    def last_steps(self) -> np.ndarray:
        """Every iteration's largest vertex move (fraction of the diagonal), (iterations,)."""
        return np.asarray(self._core.last_steps)

    @property
    def last_converged(self) -> bool:
        """Whether the last deform() met the stopping rule."""
        return self._core.last_converged

    @property
    def last_energy(self) -> float:
        """The energy of the last deform()'s result (squared mesh units)."""
        return self._core.last_energy

    @property
    def last_factorizations(self) -> int:
        """Numeric factorisations of the Hessian in the last deform()."""
        return self._core.last_factorizations

    @property
    def last_lbfgs_iterations(self) -> int:
        """L-BFGS iterations of the last deform() before its Newton iterations (the cheap
        first phase, docs/pyramid.md)."""
        return self._core.last_lbfgs_iterations

    @property
    def coordinates(self) -> dict:
        """The rest description, as returned by :func:`pyramid_coordinates`."""
        return self._core.coordinates

    @property
    def control(self) -> np.ndarray:
        """The control vertex indices (k,)."""
        return self._control.copy()

    @property
    def diagonal(self) -> float:
        """Bounding-box diagonal of the rest mesh (mesh unit): tol is relative to it."""
        return self._core.diagonal

    @property
    def num_free(self) -> int:
        """Vertices the solve moves (reached from a control, not controls)."""
        return self._core.num_free

    @property
    def num_passive(self) -> int:
        """Vertices that never move (isolated, or in a part no control reaches)."""
        return self._core.num_passive

    @property
    def num_vertices(self) -> int:
        return self._n
