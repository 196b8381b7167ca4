"""Material-aware mesh deformation (Popa, Julius, Sheffer 2006)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import (
    as_anchors,
    as_faces,
    as_float_array,
    as_index_set,
    as_mesh_vertices,
    as_rotation_vectors,
    as_stiffness,
    as_transforms,
    as_vertices,
    check_stiffness_ratio,
)


class MaterialDeformer:
    """Deform a triangle mesh by anchor transforms, placing bending and shear where it is soft.

    The constructor does all the heavy work once: harmonic blending weights (Eq. 1) and the
    sparse Cholesky factorisation of the repositioning system (Eq. 3-4). deform() then only
    blends the anchor transforms (Eq. 2), assembles a right-hand side and back-substitutes.

    Parameters
    ----------
    vertices : (n,3) float, rest positions (any length unit; output uses the same unit).
    faces : (m,3) int, triangles.
    anchors : list of k int arrays of face indices, non-empty and pairwise disjoint.
    shear : (m,) float > 0, per-face shear stiffness psi. Default 1.
    bend : (E,) float > 0 per dual edge in ``dual_edges(faces)`` order, or (n,) per vertex
        (averaged over each shared mesh edge). Default: phi_fg = (psi_f + psi_g)/2. If E == n
        the array is taken per dual edge; use ``bend_from_vertex`` to be explicit.
        Anisotropic (paper Sec. 5): (E,3) or (n,3), one bending field per rotation axis.
    pinned : int array of vertex indices fixed in deform(), or None.
    region : int array of face indices, the region of interest (paper Sec. 7), or None for the
        whole mesh. Only these faces are solved; vertices they share with outside faces stay at
        rest and outside vertices are untouched. Anchors and pinned vertices must lie inside.
    axes : (3,3) rotation whose columns are the anisotropy axes x, y, z in mesh coordinates
        (default: the mesh's own axes, as in the paper). Only used with (.,3) bend.

    Pinning rules
    -------------
    * (k,4,4) transforms, pinned=None: the vertices of every anchor's faces follow that anchor's
      full transform (a vertex shared by anchors takes the mean). Factored in the constructor.
    * (k,3,3) transforms, pinned=None: only rotation and scale are prescribed (paper Sec. 4.3);
      each connected component is placed so that its vertex mean stays at its rest position.
      This system is factored on the first such call and cached.
    * pinned given: exactly those vertices are fixed, at ``pinned_positions`` (len(pinned),3)
      when given; otherwise pinned anchor vertices follow their anchor's 4x4 transform and the
      other pinned vertices stay at rest.

    Defined behaviour: faces in a component no anchor reaches keep the identity transform;
    degenerate (zero-area or needle) faces are left out of the repositioning energy; vertices in
    no usable face keep their rest (or pinned) position. The output never contains NaN.
    """

    def __init__(
        self, vertices, faces, anchors, shear=None, bend=None, pinned=None, region=None, axes=None
    ):
        v = as_mesh_vertices(vertices)
        f = as_faces(faces, v.shape[0])
        n, m = v.shape[0], f.shape[0]
        anchor_list = as_anchors(anchors, m)
        pairs, shared = _core.dual_edges(f)
        psi = np.ones(m) if shear is None else as_stiffness(shear, m, "shear", solved=True)
        phi = _bend_per_dual_edge(bend, psi, pairs, shared, n)
        self._pinned = None if pinned is None else as_index_set(pinned, n, "pinned")
        roi = None if region is None else as_index_set(region, m, "region")
        if roi is not None and roi.size == 0:
            raise ValueError("region: expected at least one face")
        if axes is None:
            ax = np.eye(3)
        else:
            ax = as_float_array(axes, "axes")
            if ax.shape != (3, 3) or not np.isfinite(ax).all():
                raise ValueError(f"axes: expected a finite (3,3) rotation, got shape {ax.shape}")
            if not np.allclose(ax.T @ ax, np.eye(3), atol=1e-9) or np.linalg.det(ax) < 0:
                raise ValueError("axes: columns must be orthonormal with det +1 (a rotation)")
        self._n, self._m, self._k = n, m, len(anchor_list)
        self._core = _core.MaterialDeformer(
            v,
            f,
            anchor_list,
            psi,
            phi,
            None if self._pinned is None else self._pinned.tolist(),
            None if roi is None else roi.tolist(),
            ax,
        )

    def deform(
        self, transforms, pinned_positions=None, out=None, *, rotation_vectors=None
    ) -> np.ndarray:
        """Deformed positions (n,3) float64 for anchor transforms (k,3,3) or (k,4,4).

        transforms are in the mesh's coordinate frame; their linear part needs det > 0.
        pinned_positions: (len(pinned),3), only when the deformer was built with ``pinned``.
        out: a writeable C-contiguous float32 array (n,3) to receive the result rounded to
        float32 (what Blender stores), returned; nothing of mesh size is allocated per call.
        rotation_vectors: (k,3) axis * angle (radians, any length), one per anchor: the branch
            of each anchor's rotation log to blend, e.g. 3*pi about the axis for a turn and a
            half, so that faces between anchors turn by the fraction of the whole twist (see
            ``unwrap_rotations``). Row a must be a log of the rotation factor R of
            transforms[a][:3, :3] (polar decomposition M = S @ R): exp(row a) equals R within
            ``ROTATION_VECTOR_TOLERANCE`` (1e-4 rad), else ValueError. None blends the
            principal logs (angles <= pi): a turn past half a turn then unwinds.
        """
        t = as_transforms(transforms, self._k)
        rv = None
        if rotation_vectors is not None:
            rv = as_rotation_vectors(rotation_vectors, self._k)
        pp = None
        if pinned_positions is not None:
            if self._pinned is None:
                raise ValueError("pinned_positions: given, but the deformer has no pinned vertices")
            pp = as_vertices(pinned_positions, "pinned_positions", rows=len(self._pinned))
        if out is None:
            return self._core.deform(t, pp, rv)
        if not (
            isinstance(out, np.ndarray)
            and out.dtype == np.float32
            and out.shape == (self._n, 3)
            and out.flags.c_contiguous
            and out.flags.writeable
        ):
            got = f"{out.dtype} {out.shape}" if isinstance(out, np.ndarray) else type(out).__name__
            raise ValueError(
                f"out: expected a writeable C-contiguous float32 array of shape ({self._n},3), "
                f"got {got}"
            )
        self._core.deform_into(t, pp, out, rv)
        return out

    @property
    def weights(self) -> np.ndarray:
        """(m,k) blending weights per face and anchor (mean over axes when anisotropic)."""
        return self._core.weights

    def axis_weights(self, axis: int) -> np.ndarray:
        """(m,k) weights of rotation axis 0, 1 or 2 (equal to ``weights`` when isotropic)."""
        if axis not in (0, 1, 2):
            raise ValueError(f"axis: expected 0, 1 or 2, got {axis!r}")
        return self._core.axis_weights(axis)

    @property
    def anisotropic(self) -> bool:
        """True when built with one bending field per rotation axis."""
        return self._core.anisotropic

    @property
    def face_transforms(self) -> np.ndarray:
        """(m,3,3) blended per-face transforms T_i of the last deform() call."""
        return self._core.face_transforms

    @property
    def pinned(self) -> np.ndarray | None:
        """The pinned vertex indices given to the constructor, or None."""
        return None if self._pinned is None else self._pinned.copy()

    @property
    def num_vertices(self) -> int:
        return self._n

    @property
    def num_faces(self) -> int:
        return self._m

    @property
    def num_anchors(self) -> int:
        return self._k


def _bend_per_dual_edge(bend, psi, pairs, shared, n) -> np.ndarray:
    """Resolve the accepted bend layouts to (E,1) or (E,3) per dual edge."""
    e = len(pairs)
    if bend is None:
        return _core.bend_from_shear(pairs, psi)[:, None]
    b = as_float_array(bend, "bend")
    if b.ndim == 1:
        b = b[:, None]
    if b.ndim != 2 or b.shape[1] not in (1, 3) or b.shape[0] not in (e, n):
        raise ValueError(
            f"bend: expected shape ({e},) or ({e},3) per dual edge, or ({n},) or ({n},3) per "
            f"vertex, got {np.shape(bend)}"
        )
    if not np.isfinite(b).all():
        raise ValueError("bend: contains NaN or infinity")
    if (b <= 0).any():
        raise ValueError(f"bend: stiffness must be > 0 (min is {b.min()})")
    check_stiffness_ratio(b, "bend")
    if b.shape[0] == e:  # per dual edge wins when E == n
        return np.ascontiguousarray(b)
    cols = [
        _core.bend_from_vertex(pairs, shared, np.ascontiguousarray(b[:, c]))
        for c in range(b.shape[1])
    ]
    return np.ascontiguousarray(np.stack(cols, axis=1))
