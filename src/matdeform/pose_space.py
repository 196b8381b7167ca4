"""Pose-space surface manipulation: example shapes + translational and rotational handles.

The MeshIK family (Sumner et al. 2005) with a rotation-invariant encoding (Lipman et al. 2005)
and pose-space interpolation; see docs/pose_space.md for the pipeline and every choice.
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import (
    as_bool,
    as_count,
    as_faces,
    as_index_set,
    as_int_array,
    as_mesh_vertices,
    as_real,
    as_vertices,
)


class PoseSpaceDeformer:
    """Pose a mesh from example shapes with translational and rotational handles.

    The constructor encodes every example rotation-invariantly (per-face stretch S and, per pair
    of adjacent faces, the log of their relative rotation), sets up the pose-space interpolation
    and factors every constant matrix once. ``deform()`` infers the example weights from the
    handles, blends the encodings and reconstructs in two linear steps (rotations, then
    positions).

    Parameters
    ----------
    vertices : (n,3) float, rest positions (any length unit; the output uses the same unit).
    faces : (m,3) int triangles. Every vertex used, no zero-area face. A connected part with
        no handle vertex, frozen face, frame face or rotational face stays exactly at rest.
    examples : (p,n,3) float, p >= 0 example poses with the connectivity of ``faces`` (a list of
        (n,3) arrays works too). With p = 0 this is a plain rotation-invariant handle deformer.
    handles : list of h int arrays of vertex indices (non-empty, disjoint): translational
        handles; ``deform()`` gives each a target position per vertex.
    frame : face index or None. Handle positions are measured in this face's frame (its
        rotation and centroid), so a global rotation does not change the inferred pose. Its
        vertices should belong to handles; otherwise pass ``frame_transform`` to ``deform()``.
        Without a frame the best-fit rigid frame of all handle vertices is used (with a frozen
        region: the mesh's own frame).
    rotational : list of r (face_a, face_b) pairs, or an (r,2) int array: rotational handles.
        ``deform(rotations=...)`` prescribes R_a^T R_b for each pair, bending or twisting the
        joint between them.
    coarse : int or None. Target face count of a coarse mesh (quadric simplification) on which
        the two solves run; dense vertices follow it through harmonic weights and per-example
        detail vectors. None solves on the full mesh.
    frozen : int array of face indices, or None. Frozen faces keep their rest shape and place.

    Keyword options (see docs/pose_space.md):

    position_weight : float > 0, handle position penalty relative to the mean diagonal of the
        position system (default 100; larger holds handles tighter).
    rotation_weight : float > 0, penalty pulling faces inside a handle to the handle's best-fit
        rotation in step 1 (default 1).
    joint_weight : float > 0, penalty of the rotational pairs in step 1 (default 100).
    handle_rotations : bool, whether translational handles constrain step 1 (default True).
    weight_regularization : float >= 0, ridge added to the interpolation kernel relative to its
        largest entry (default 0: exact 1/0 weights at the examples).
    convex_weights : bool, clip negative example weights and renormalise (default False).
    transfer_neighbors : int >= 1, coarse vertices each dense vertex follows (default 8).
    orientation_weight : float >= 0, weight of the handles' own orientations (relative to the
        frame) in the pose vector; 0 uses the handle positions only (default 1).
    rotation_energy : "chordal" (the paper: sum |R_b - R_a Q|^2, then projection; default) or
        "geodesic" (sum |log(R_a Q R_b^T)|^2 by Gauss-Newton, faster, less robust).
    rotation_iterations : int >= 1, most conjugate-gradient iterations (chordal) or
        Gauss-Newton steps (geodesic) per rotation solve (default 10).
    rotation_tolerance : float in (0, 1), relative energy-norm error at which the chordal CG
        stops (default 1e-6; results are independent of the numbering to about this level).
    gauge_steps : int >= 1, Gauss-Newton steps making the chordal solve's gauge, and the whole
        solve of the natural shape when handle rotations follow (default 2).
    area_weights : bool, step 2 weighs each face by its rest area (the integral of
        |grad x - R S|^2) instead of 1 per face as MeshIK does (default False).
    reliability_angle : float > 0 (radians) or inf. Dual edges whose relative rotation reaches
        it in some example weigh 1/2 in step 1, w = 1/(1 + (angle/reliability_angle)^2)
        (default 0.5); inf weighs all edges 1.
    """

    def __init__(
        self,
        vertices,
        faces,
        examples,
        handles,
        frame=None,
        rotational=None,
        coarse=None,
        frozen=None,
        *,
        position_weight: float = 100.0,
        rotation_weight: float = 1.0,
        joint_weight: float = 100.0,
        handle_rotations: bool = True,
        weight_regularization: float = 0.0,
        convex_weights: bool = False,
        transfer_neighbors: int = 8,
        rotation_energy: str = "chordal",
        rotation_iterations: int = 10,
        reliability_angle: float = 0.5,
        orientation_weight: float = 1.0,
        gauge_steps: int = 2,
        area_weights: bool = False,
        rotation_tolerance: float = 1e-6,
    ):
        v = as_mesh_vertices(vertices)
        f = as_faces(faces, v.shape[0])
        n, m = v.shape[0], f.shape[0]
        ex = _as_examples(examples, n)
        hs = _as_handles(handles, n)
        fr = None if frame is None else _as_index(frame, m, "frame")
        rot = _as_pairs(rotational, m)
        cs = None
        if coarse is not None:
            cs = _as_index(coarse, None, "coarse")
            if cs < 4 or cs >= m:
                raise ValueError(f"coarse: expected a face count in [4, {m}), got {cs}")
        fz = np.zeros(0, np.int32) if frozen is None else as_index_set(frozen, m, "frozen")
        if fz.size and hs:
            fv = np.zeros(n, bool)
            fv[f[fz].ravel()] = True
            for j, h in enumerate(hs):
                if fv[h].any():
                    raise ValueError(
                        f"handles[{j}]: vertex {int(h[fv[h]][0])} belongs to a frozen face, "
                        "which keeps its rest position"
                    )
        pos_w = as_real(position_weight, "position_weight", 0.0, lo_open=True)
        rot_w = as_real(rotation_weight, "rotation_weight", 0.0, lo_open=True)
        joint_w = as_real(joint_weight, "joint_weight", 0.0, lo_open=True)
        ridge = as_real(weight_regularization, "weight_regularization", 0.0)
        orient_w = as_real(orientation_weight, "orientation_weight", 0.0)
        tol = as_real(rotation_tolerance, "rotation_tolerance", 0.0, 1.0, True, True)
        angle = as_real(reliability_angle, "reliability_angle", 0.0, lo_open=True, allow_inf=True)
        tn = as_count(transfer_neighbors, "transfer_neighbors", 1)
        iters = as_count(rotation_iterations, "rotation_iterations", 1)
        steps = as_count(gauge_steps, "gauge_steps", 1)
        flags = [
            as_bool(x, name)
            for x, name in (
                (handle_rotations, "handle_rotations"),
                (convex_weights, "convex_weights"),
                (area_weights, "area_weights"),
            )
        ]
        if not isinstance(rotation_energy, str) or rotation_energy not in ("chordal", "geodesic"):
            raise ValueError(
                f"rotation_energy: expected 'chordal' or 'geodesic', got {rotation_energy!r}"
            )
        self._n, self._m, self._p = n, m, len(ex)
        self._sizes = [len(h) for h in hs]
        self._r = len(rot)
        self._frame = fr
        self._core = _core.PoseSpaceDeformer(
            v,
            f,
            ex,
            [h.tolist() for h in hs],
            fr,
            [tuple(int(x) for x in pr) for pr in rot],
            cs,
            fz.tolist(),
            pos_w,
            rot_w,
            joint_w,
            flags[0],
            ridge,
            flags[1],
            tn,
            rotation_energy,
            iters,
            angle,
            orient_w,
            steps,
            flags[2],
            tol,
        )

    def deform(self, handle_positions, rotations=None, frame_transform=None) -> np.ndarray:
        """Deformed positions (n,3) float64.

        handle_positions : list of h arrays, array j of shape (len(handles[j]),3): world
            targets of the handle vertices (same unit as the mesh).
        rotations : (r,3,3) rotations R_a^T R_b of the rotational pairs, or None to leave the
            joints free (the pose is then inferred from the handle positions alone).
        frame_transform : (4,4) rigid transform taking the rest frame face to its place, or
            None (then the frame is measured from the handle positions). Only with ``frame``.
        """
        args = self._deform_args(handle_positions, rotations, frame_transform)
        return self._core.deform(*args)

    def pose_weights(self, handle_positions, rotations=None, frame_transform=None) -> np.ndarray:
        """The example weights (p,) ``deform()`` would use for these inputs (cheap: no solve)."""
        args = self._deform_args(handle_positions, rotations, frame_transform)
        return self._core.pose_weights(*args)

    @property
    def example_weights(self) -> np.ndarray:
        """(p,) example weights of the last ``deform()`` (empty before the first call)."""
        w = self._core.example_weights
        return np.asarray(w, dtype=np.float64).copy()

    @property
    def last_stats(self) -> dict:
        """Iteration counts and per-step times (ms) of the last ``deform()``."""
        return dict(self._core.last_stats)

    @property
    def multiresolution(self) -> bool:
        return self._core.multiresolution

    @property
    def coarse_faces(self) -> np.ndarray:
        """(mc,3) faces of the mesh the solves run on, in ``coarse_vertices`` numbering."""
        return np.asarray(self._core.solve_faces, dtype=np.int64)

    @property
    def coarse_vertices(self) -> np.ndarray:
        """(nc,) dense vertex index of each coarse vertex (all vertices without ``coarse``)."""
        return np.asarray(self._core.solve_vertices, dtype=np.int64)

    @property
    def num_vertices(self) -> int:
        return self._n

    @property
    def num_faces(self) -> int:
        return self._m

    @property
    def num_examples(self) -> int:
        return self._p

    @property
    def num_handles(self) -> int:
        return len(self._sizes)

    @property
    def num_rotational(self) -> int:
        return self._r

    def _deform_args(self, handle_positions, rotations, frame_transform):
        h = len(self._sizes)
        if isinstance(handle_positions, np.ndarray) and handle_positions.dtype != object:
            hp_items = list(handle_positions) if handle_positions.ndim == 3 else [handle_positions]
            if h == 0 and handle_positions.size == 0:
                hp_items = []
        else:
            try:
                hp_items = list(handle_positions)
            except TypeError:
                raise ValueError(
                    f"handle_positions: expected a list of {h} arrays of shape (k,3)"
                ) from None
        if len(hp_items) != h:
            raise ValueError(f"handle_positions: expected {h} arrays, got {len(hp_items)}")
        hp = [
            as_vertices(x, f"handle_positions[{j}]", rows=self._sizes[j])
            for j, x in enumerate(hp_items)
        ]
        rot = None
        if rotations is not None:
            if self._r == 0:
                raise ValueError("rotations: given, but the deformer has no rotational pairs")
            rot = _as_rotations(rotations, self._r, "rotations")
        ft = None
        if frame_transform is not None:
            if self._frame is None:
                raise ValueError("frame_transform: given, but the deformer has no frame face")
            ft = _as_rigid(frame_transform, "frame_transform")
        return hp, rot, ft


def _as_index(x, upper, name: str) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        raise ValueError(f"{name}: expected an int, got {type(x).__name__}")
    i = int(x)
    if upper is not None and not 0 <= i < upper:
        raise ValueError(f"{name}: expected a face index in [0, {upper}), got {i}")
    return i


def _as_examples(examples, n: int) -> list[np.ndarray]:
    if examples is None:
        return []
    if isinstance(examples, np.ndarray) and examples.dtype != object:
        if examples.size == 0 and (examples.ndim != 3 or examples.shape[0] == 0):
            return []
        if examples.ndim != 3 or examples.shape[1:] != (n, 3):
            raise ValueError(f"examples: expected shape (p,{n},3), got {examples.shape}")
        items = list(examples)
    else:
        try:
            items = list(examples)
        except TypeError:
            raise ValueError(f"examples: expected an array of shape (p,{n},3)") from None
    return [as_vertices(x, f"examples[{k}]", rows=n) for k, x in enumerate(items)]


def _as_handles(handles, n: int) -> list[np.ndarray]:
    if handles is None:
        return []
    if isinstance(handles, np.ndarray) and handles.dtype != object:
        handles = list(handles) if handles.ndim == 2 else [handles]
    try:
        items = list(handles)
    except TypeError:
        raise ValueError("handles: expected a list of h integer arrays of vertex indices") from None
    out = []
    owner = np.full(n, -1, dtype=np.int64)
    for j, item in enumerate(items):
        idx = as_index_set(np.atleast_1d(np.asarray(item)), n, f"handles[{j}]")
        if idx.size == 0:
            raise ValueError(f"handles[{j}]: a handle needs at least one vertex")
        clash = owner[idx] >= 0
        if clash.any():
            v = int(idx[clash][0])
            raise ValueError(f"handles: handles {int(owner[v])} and {j} share vertex {v}")
        owner[idx] = j
        out.append(idx)
    return out


def _as_pairs(rotational, m: int) -> np.ndarray:
    if rotational is None:
        return np.zeros((0, 2), np.int32)
    a = np.asarray(rotational)
    if a.size == 0:
        return np.zeros((0, 2), np.int32)
    a = as_int_array(a, "rotational", 2)
    if a.shape[1] != 2:
        raise ValueError(f"rotational: expected (face_a, face_b) pairs, shape (r,2), got {a.shape}")
    if a.min() < 0 or a.max() >= m:
        raise ValueError(f"rotational: face indices must lie in [0, {m}), got {a.min()}..{a.max()}")
    same = np.flatnonzero(a[:, 0] == a[:, 1])
    if same.size:
        raise ValueError(f"rotational[{int(same[0])}]: the two faces must differ")
    return a


def _as_rotations(x, count: int, name: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected shape ({count},3,3)") from None
    if a.shape != (count, 3, 3):
        raise ValueError(f"{name}: expected shape ({count},3,3), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or infinity")
    err = np.abs(np.einsum("kji,kjl->kil", a, a) - np.eye(3)).max(axis=(1, 2))
    r1, r2 = a[:, 1, :], a[:, 2, :]
    det = np.einsum("kj,kj->k", a[:, 0, :], np.cross(r1, r2))
    bad = np.flatnonzero((err > 1e-6) | (det <= 0))
    if bad.size:
        raise ValueError(f"{name}[{int(bad[0])}]: expected a rotation matrix (orthonormal, det +1)")
    return np.ascontiguousarray(a)


def _as_rigid(x, name: str) -> np.ndarray:
    try:
        t = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a (4,4) rigid transform") from None
    if t.shape != (4, 4):
        raise ValueError(f"{name}: expected shape (4,4), got {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError(f"{name}: contains NaN or infinity")
    r = t[:3, :3]
    if (
        np.abs(r.T @ r - np.eye(3)).max() > 1e-6
        or float(np.dot(r[0], np.cross(r[1], r[2]))) <= 0  # no LAPACK on the live path
        or np.abs(t[3] - [0, 0, 0, 1]).max() > 1e-12
    ):
        raise ValueError(
            f"{name}: expected a rigid transform (rotation, translation, bottom row 0 0 0 1)"
        )
    return np.ascontiguousarray(t)
