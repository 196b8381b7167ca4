"""Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy).

Each vertex is described relative to its one-ring by angles and projected lengths (invariant
under rigid motion); a pose given by a few control vertices is found by re-placing the other
vertices from their descriptions until they settle. See docs/pyramid.md.
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_faces, as_index_set, as_vertices

_METHODS = ("gauss-seidel", "jacobi")

#: Vertex kinds in ``pyramid_coordinates(...)["kind"]``.
KIND_INTERIOR, KIND_BOUNDARY, KIND_FOLLOWER, KIND_ISOLATED = 0, 1, 2, 3


def _is_count(x) -> bool:
    """An integer >= 0 (numpy integers too, bools not)."""
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool) and x >= 0


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

    The constructor builds the description of every vertex (angles alpha_i, beta_i and lengths
    l_i relative to its one-ring), colours the vertex graph for parallel Gauss-Seidel and links
    the controls to their neighbours. deform() then iterates the paper's steps 1-3 from a start
    (the rest mesh moved by the similarity that best maps the controls' rest positions onto
    their targets, or ``initial``) until the largest move of a sweep is below
    ``tol`` x the rest bounding-box diagonal.

    Parameters
    ----------
    vertices : (n,3) float, rest positions (any length unit; output uses the same unit).
    faces : (m,3) int, triangles.
    control : (k,) int, k >= 1 unique vertex indices whose positions deform() prescribes.

    Defined behaviour: vertices in no face, and parts of the mesh that no control vertex
    reaches through edges, keep their start positions. Non-manifold and degenerate fans
    (fewer than three neighbours, zero area, folded projections) follow the best-fit
    similarity of their one-ring instead of a description. The output never contains NaN.
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
        stretch: bool = True,
        *,
        push: bool = True,
        method: str = "gauss-seidel",
        anderson: int = 20,
        record_moves: bool = False,
        progress=None,
        progress_seconds: float = 0.1,
    ) -> np.ndarray:
        """Deformed positions (n,3) float64 with the control vertices at control_positions.

        control_positions : (k,3) float, in the order of ``control`` (mesh unit).
        iterations : sweep budget, int >= 0; None runs until converged (at most 100000).
        tol : stop once the largest vertex move of a sweep < tol x the rest bounding-box
            diagonal (0 runs the whole budget).
        initial : (n,3) start positions, e.g. the previous result for a live update with a
            small budget; None starts from the rest mesh moved by the controls' best-fit
            similarity (rotation, uniform scale, translation). Control rows are replaced.
        stretch : scale the mean value weights by |v' - v'_i| / l_i (the paper's stretch
            correction: keeps edge lengths better; not faster in our measurements,
            docs/pyramid.md).
        push : the paper's step 2, control vertices push their neighbours to the height their
            own description predicts.
        method : "gauss-seidel" (graph-coloured, parallel) or "jacobi".
        anderson : Anderson acceleration window over the sweeps, int >= 0 (0: plain sweeps).
        record_moves : keep every sweep's move in ``last_moves``.
        progress : None, or a callable ``progress(sweeps, move)`` (int, float: that sweep's
            largest move as a fraction of the diagonal), called after a sweep at most every
            ``progress_seconds`` (float >= 0, 0: after every sweep) on the calling thread, for
            a progress bar. An exception it raises ends the call and propagates. The result
            does not depend on it.

        After the call ``last_iterations`` is the number of sweeps and ``last_move`` the largest
        move of the last one, as a fraction of the rest diagonal (NaN after 0 sweeps). The
        result never contains NaN or runaway coordinates: once a sweep moves a vertex by more
        than 100x the extent of the start and the controls (the iteration is diverging, e.g. a
        strong pose on a mesh with sliver faces), it raises RuntimeError instead, and
        ``last_iterations`` is 0, ``last_move`` NaN.
        """
        k = len(self._control)
        x = as_vertices(control_positions, "control_positions", rows=k)
        if iterations is not None and not _is_count(iterations):
            raise ValueError(f"iterations: expected an integer >= 0 or None, got {iterations!r}")
        it = 100_000 if iterations is None else int(iterations)
        try:
            t = float(tol)
        except (TypeError, ValueError):
            raise ValueError(f"tol: expected a finite float >= 0, got {tol!r}") from None
        if not np.isfinite(t) or t < 0:
            raise ValueError(f"tol: expected a finite float >= 0, got {tol!r}")
        x0 = None if initial is None else as_vertices(initial, "initial", rows=self._n)
        if method not in _METHODS:
            raise ValueError(f"method: expected one of {_METHODS}, got {method!r}")
        if not _is_count(anderson):
            raise ValueError(f"anderson: expected an integer >= 0, got {anderson!r}")
        if progress is not None and not callable(progress):
            raise ValueError(f"progress: expected a callable or None, got {progress!r}")
        try:
            every = float(progress_seconds)
        except (TypeError, ValueError):
            every = float("nan")
        if not every >= 0:  # also NaN
            raise ValueError(f"progress_seconds: expected a float >= 0, got {progress_seconds!r}")
        return self._core.deform(
            x,
            it,
            t,
            x0,
            bool(stretch),
            bool(push),
            method,
            bool(record_moves),
            int(anderson),
            progress,
            every,
        )

    def reconstruct(self, positions, stretch: bool = False) -> np.ndarray:
        """Every vertex placed once from its neighbours in positions (n,3) by Eq. 1-2.

        No iteration and no step 2; controls are placed too. ``reconstruct(rest)`` gives back
        the rest mesh (followers and isolated vertices exactly, the others to round-off).
        """
        x = as_vertices(positions, "positions", rows=self._n)
        return self._core.reconstruct(x, bool(stretch))

    @property
    def last_iterations(self) -> int:
        """Sweeps done by the last deform()."""
        return self._core.last_iterations

    @property
    def last_move(self) -> float:
        """Largest vertex move of the last sweep, as a fraction of the rest diagonal."""
        return self._core.last_move

    @property
    def last_moves(self) -> np.ndarray:
        """Every sweep's largest move (fraction of the diagonal), with record_moves=True."""
        return np.asarray(self._core.last_moves)

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
    def num_colors(self) -> int:
        """Colours of the Gauss-Seidel colouring (parallel steps per sweep)."""
        return self._core.num_colors

    @property
    def num_passive(self) -> int:
        """Vertices that never move (isolated, or in a part no control reaches)."""
        return self._core.num_passive

    @property
    def num_vertices(self) -> int:
        return self._n
