"""Edge-based iterative material deformation: cloth, membranes and shells (see docs/edge.md)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import (
    as_count,
    as_faces,
    as_float_array,
    as_index_set,
    as_int_array,
    as_mesh_vertices,
    as_real,
    as_rotation_vectors,
    as_stiffness,
    as_vertices,
)


class EdgeDeformer:
    """Pose a mesh by moving constrained vertices; the rest follows like cloth, membrane or shell.

    Edge-based iterative deformation: every mesh edge carries a stretch term (its edge vector,
    weight ``stretch`` = lambda) and every interior manifold edge a bending term (a point on the
    edge minus a point on the segment joining the two opposite vertices, weight ``bend`` = mu).
    Each iteration rotates the rest quantities into the current edge frames and solves one
    sparse linear system whose matrix never changes: it is factored once, here, and every
    iteration of ``solve`` only assembles a right-hand side and back-substitutes. Large
    ``stretch`` / ``bend`` keeps edge lengths (cloth); small ``stretch`` lets edges stretch
    (membrane); ``bend`` resists folding (shells). Only the ratio stretch / bend and the mesh
    resolution matter: the paper's cloth is stretch 1e-4 at ~100 x 100 vertices.

    Parameters
    ----------
    vertices : (n,3) float, rest positions (any length unit; results use the same unit).
    faces : (m,3) int, triangles.
    constrained : (k,) int, unique vertex indices whose positions ``solve`` prescribes (k >= 1).
    stretch : float >= 0, lambda (unitless).
    bend : float > 0, mu (unitless).
    edge_weight : (E,) float > 0 per mesh edge in ``mesh_edges(faces)`` order, scaling both
        terms of the edge (a painted stiffness map), or None for 1.
    direction : (n,3) float direction field f, or None. Each edge's terms are scaled by
        kappa = |<f_i + f_j, v_i - v_j>| / (|f_i + f_j| |v_i - v_j|) (Eq. 13), computed from the
        field's part tangent to the rest surface; where f_i + f_j vanishes the edge is
        isotropic (kappa = 1). Edges along the field stay stiff, edges across it go soft.
    anchors : (k,) int, the anchor id in [0, k) of each constrained vertex (in ``constrained``
        order), or None: the constrained vertices joined by mesh edges, numbered by first
        appearance. The first step fits one rotation per anchor, and ``solve``'s
        ``rotation_vectors`` has one row per anchor (``num_anchors`` rows; ids may be unused).

    Defined behaviour: boundary edges, non-manifold edges and edges whose rest faces are
    degenerate have no bending term; vertices in no face, or in a connected part without a
    constrained vertex, are passive (they stay at rest bit for bit, whatever ``initial`` holds).
    A set-up that leaves some vertex undetermined raises ValueError (e.g. stretch = 0 on a flat
    part with fewer than three non-collinear constrained vertices).
    """

    def __init__(
        self,
        vertices,
        faces,
        constrained,
        stretch: float = 1e-4,
        bend: float = 1.0,
        edge_weight=None,
        direction=None,
        anchors=None,
    ):
        v = as_mesh_vertices(vertices)
        n = v.shape[0]
        f = as_faces(faces, n)
        c = as_index_set(constrained, n, "constrained")
        if c.size == 0:
            raise ValueError("constrained: expected at least one vertex index, got shape (0,)")
        lam = as_real(stretch, "stretch", 0.0)
        mu = as_real(bend, "bend", 0.0, lo_open=True)
        w = None
        if edge_weight is not None:
            e = len(_core.mesh_edges(f))
            w = as_stiffness(edge_weight, e, "edge_weight")
        d = None if direction is None else as_vertices(direction, "direction", rows=n)
        a = None
        if anchors is not None:
            a = as_int_array(anchors, "anchors", 1)
            if a.shape != c.shape:
                raise ValueError(
                    f"anchors: expected shape ({c.size},), one id per constrained vertex, "
                    f"got {a.shape}"
                )
            if a.min() < 0 or a.max() >= c.size:
                raise ValueError(
                    f"anchors: ids must lie in [0, {c.size}), got [{a.min()}, {a.max()}]"
                )
            a = a.tolist()
        self._n, self._m = n, f.shape[0]
        self._constrained = c
        self._core = _core.EdgeDeformer(v, f, c.tolist(), lam, mu, w, d, a)

    def solve(
        self,
        constrained_positions,
        iterations: int = 15,
        tol: float = 1e-5,
        p_stretch: float = 1.0,
        p_bend: float = 1.0,
        gravity=(0.0, 0.0, 0.0),
        initial=None,
        relaxation: float = 1.0,
        *,
        rotation_vectors=None,
    ) -> np.ndarray:
        """Run up to ``iterations`` E-M iterations; returns the last iterate (n,3) float64.

        constrained_positions : (k,3) positions of the constrained vertices, in the order given
            to the constructor (mesh length unit).
        iterations : int in [1, 2**31 - 1], the iteration budget.
        tol : float >= 0. Stop early once the estimated distance to the fixed point
            (``last_error``: the last move times rho / (1 - rho), rho the slowest contraction
            of moves over the last 4 iterations) is at most tol x the rest bounding-box
            diagonal; 0 runs exactly ``iterations``.
        p_stretch, p_bend : floats in [0,1] (paper Eq. 15): how far each iteration pulls the
            edges towards their rest length / rest bending. 1 is the full material, 0 leaves the
            term where the previous iterate has it. Changing them needs no refactorisation.
        gravity : (3,) float, g pointing the way things fall, in length units per unit
            stiffness: the energy gains -sum_i <g, v_i> (Eq. 8).
        initial : (n,3) float warm start (e.g. the previous result), or None for the rest mesh.
            Iterations compose: solve(x, iterations=a+b) equals solving ``b`` iterations from the
            result of ``a``. When an anchor (constrained vertices joined by edges) turns by more
            than 15 degrees from here to ``constrained_positions``, the first iteration carries
            the anchors' fitted rotations over the mesh (docs/edge.md), so a large turn from
            rest does not fold the mesh the wrong way round.
        relaxation : float in (0,1], omega: each iteration moves the free vertices by omega
            times the E-M step (1 is the paper's iteration; a carried first step is taken in
            full). The fixed points are the same; a value below 1 (e.g. 0.8) damps the
            two-cycles the plain iteration can fall into when constraints are far from rest.
        rotation_vectors : (num_anchors,3) axis * angle (radians, any length), each anchor's
            turn from rest, e.g. 4 pi about the axis for two whole turns (see
            ``unwrap_rotations``), or None. Positions alone cannot tell 180 from 540 degrees;
            with the vectors the start is the rest mesh and the first step carries these turns
            (when some vector exceeds 15 degrees) instead of the fitted ones, so the result
            depends on the arguments only, never on an earlier solve. ``initial`` must then be
            None (continue with ``initial=`` and no vectors: calls compose as before). Row a
            must be a log of the rotation fitted to anchor a from rest to
            ``constrained_positions`` within ``ROTATION_VECTOR_TOLERANCE`` (1e-4 rad), for
            anchors with such a fit (3+ vertices not in a line); else ValueError.

        ``last_iterations``, ``last_move``, ``last_error`` and ``last_converged`` report the
        iterations run, the last move, the estimated distance to the fixed point and whether
        it met ``tol``.
        Positions beyond 1e50 rest diagonals of the rest mesh raise ValueError; a result that
        would leave that range (gravity far too strong) raises RuntimeError. Either way the call
        changes nothing.
        """
        x = as_vertices(constrained_positions, "constrained_positions", rows=len(self._constrained))
        its = as_count(iterations, "iterations", 1)
        t = as_real(tol, "tol", 0.0)
        ps = as_real(p_stretch, "p_stretch", 0.0, 1.0)
        pb = as_real(p_bend, "p_bend", 0.0, 1.0)
        g = as_float_array(gravity, "gravity")
        if g.shape != (3,):
            raise ValueError(f"gravity: expected shape (3,), got {g.shape}")
        if not np.isfinite(g).all():
            raise ValueError("gravity: contains NaN or infinity")
        x0 = None if initial is None else as_vertices(initial, "initial", rows=self._n)
        w = as_real(relaxation, "relaxation", 0.0, 1.0, lo_open=True)
        rv = None
        if rotation_vectors is not None:
            rv = as_rotation_vectors(rotation_vectors, self._core.num_anchors)
            if x0 is not None:
                raise ValueError(
                    "initial: must be None with rotation_vectors (the start is then the rest "
                    "mesh carried by the vectors)"
                )
        return self._core.solve(x, its, t, ps, pb, g, x0, w, rv)

    @property
    def last_iterations(self) -> int:
        """Iterations run by the last ``solve`` (0 before the first)."""
        return self._core.last_iterations

    @property
    def last_move(self) -> float:
        """Largest vertex move of the last iteration of the last ``solve`` / bbox diagonal."""
        return self._core.last_move

    @property
    def last_error(self) -> float:
        """The last ``solve``'s estimated distance to the fixed point / bbox diagonal: the last
        move times rho / (1 - rho), rho the slowest contraction of successive moves over the
        last 4 iterations; infinity while the moves do not contract (fewer than 6 iterations,
        a two-cycle)."""
        return self._core.last_error

    @property
    def last_converged(self) -> bool:
        """Whether the last ``solve`` stopped because ``last_error`` met ``tol``."""
        return self._core.last_converged

    @property
    def factorizations(self) -> int:
        """Sparse factorisations this object has done (1: in the constructor, never after)."""
        return self._core.factorizations

    @property
    def constrained(self) -> np.ndarray:
        """(k,) the constrained vertex indices, in the order ``solve`` expects positions."""
        return self._constrained.copy()

    @property
    def edges(self) -> np.ndarray:
        """(E,2) int64 mesh edges a < b, the order of ``edge_weight`` (= ``mesh_edges``)."""
        return self._core.edges.astype(np.int64)

    @property
    def opposite(self) -> np.ndarray:
        """(E,2) int64 opposite vertices (l, m) of each edge's bending term; -1 where none."""
        return self._core.opposite.astype(np.int64)

    @property
    def bend_coefficients(self) -> np.ndarray:
        """(E,2) alpha, beta of Eq. 5: sigma = alpha v_a + (1-alpha) v_b - beta v_l - (1-beta) v_m
        with (a, b) = ``edges[e]`` and (l, m) = ``opposite[e]``; NaN where there is no term."""
        return self._core.bend_coefficients

    @property
    def anisotropy(self) -> np.ndarray:
        """(E,) kappa in [0,1] per edge (all 1 without a direction field)."""
        return self._core.anisotropy

    @property
    def num_anchors(self) -> int:
        """Anchors: the rows of ``solve``'s ``rotation_vectors``."""
        return self._core.num_anchors

    @property
    def anchors(self) -> np.ndarray:
        """(k,) int64 anchor id of each constrained vertex (``constrained`` order)."""
        return np.asarray(self._core.anchors, dtype=np.int64)

    @property
    def num_vertices(self) -> int:
        return self._n

    @property
    def num_free(self) -> int:
        """Vertices solved for (not constrained, not passive)."""
        return self._core.num_free

    @property
    def diagonal(self) -> float:
        """Rest bounding-box diagonal, the unit of ``tol`` and ``last_move``."""
        return self._core.diagonal
