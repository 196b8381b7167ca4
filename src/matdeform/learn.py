"""Learning bending and shearing stiffness from example poses (Popa et al. 2006, Sec. 6).

For every example pose s and face i the deformation gradient T_si = Vt_si V_0i^-1 is split by
polar decomposition into T_si = S_si Q_si (S symmetric stretch, Q rotation). Then

* bending distortion of dual edge (i, j):  max_s |Q_si - Q_sj|_F^2, or, anisotropic, per axis
  a in (x, y, z): max_s (a-th component of the relative rotation vector of faces i and j)^2;
* shearing distortion of face i:  max_s |S_si - I|_F^2.

Distortions are dimensionless and invariant to rigid motions of each pose. They are mapped to
stiffness in [eps, 1] by :func:`stiffness_from_distortion` (large distortion -> flexible -> eps).

Beyond the paper, :func:`rotation_spread` measures bending at the scale of a region instead of a
dual edge (``learn_stiffness(..., region=passes)``): how far the face rotations of a neighbourhood
spread around their mean. A body that bends gently but as a whole (a torso) then reads as
flexible, while rigid segments (bones) stay stiff however much they move.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import _core
from ._validate import (
    MAX_MESH_SIZE,
    as_faces,
    as_float_array,
    as_mesh_vertices,
    as_triangles,
    as_vertices,
)
from .mesh import dual_edges

__all__ = [
    "learn_distortions",
    "learn_stiffness",
    "rotation_spread",
    "smooth_distortions",
    "stiffness_from_distortion",
]

_FRAMES = ("rest", "world")


def _poses(poses, n: int) -> list[np.ndarray]:
    if isinstance(poses, np.ndarray):
        if poses.ndim != 3 or poses.shape[1:] != (n, 3):
            raise ValueError(f"poses: expected shape (l,{n},3), got {poses.shape}")
        items = list(poses)
    elif isinstance(poses, Sequence):
        items = list(poses)
    else:
        raise ValueError("poses: expected an (l,n,3) array or a sequence of (n,3) arrays")
    if not items:
        raise ValueError("poses: need at least one pose")
    out = [as_vertices(p, f"poses[{s}]", rows=n) for s, p in enumerate(items)]
    for s, p in enumerate(out):
        if len(p) and np.ptp(p, axis=0).max() > MAX_MESH_SIZE:
            raise ValueError(f"poses[{s}]: larger than 1e50 across: rescale it with the mesh")
    return out


def learn_distortions(
    vertices, faces, poses, *, anisotropic: bool = False, frame: str = "rest"
) -> tuple[np.ndarray, np.ndarray]:
    """Raw per-edge bending and per-face shearing distortion over example poses.

    Args:
        vertices: (n,3) reference (rest) positions, any length unit.
        faces: (m,3) integer vertex indices, shared by the reference and every pose.
        poses: (l,n,3) array or sequence of l (n,3) arrays, l >= 1.
        anisotropic: per-axis bending instead of one value per dual edge.
        frame: axes of the anisotropic components. "rest": relative rotation Q_i^T Q_j in the
            reference mesh's coordinates (the same hinge axis in every pose; rigid-motion
            invariant). "world": log Q_j - log Q_i in world coordinates (what Sec. 5 blends).

    Returns:
        bend: (E,) or, anisotropic, (E,3), dimensionless, in ``dual_edges(faces)`` order.
        shear: (m,) dimensionless.

    Faces collapsed to zero area in a pose are skipped for that pose.
    """
    v = as_mesh_vertices(vertices)
    f = as_faces(faces, v.shape[0])
    p = _poses(poses, v.shape[0])
    if frame not in _FRAMES:
        raise ValueError(f"frame: expected one of {_FRAMES}, got {frame!r}")
    pairs = np.ascontiguousarray(dual_edges(f), dtype=np.int32)
    bend, shear = _core.learn_distortions(v, f, pairs, p, bool(anisotropic), frame)
    bend = np.asarray(bend)
    return (bend if anisotropic else bend[:, 0].copy()), np.asarray(shear)


def smooth_distortions(faces, bend, shear, passes: int) -> tuple[np.ndarray, np.ndarray]:
    """Spread distortions over the face graph (regional instead of per-edge flexibility).

    Args:
        faces: (m,3) int triangles (defines the dual edges).
        bend: (E,) or (E,k) per dual edge in ``dual_edges(faces)`` order.
        shear: (m,) per face.
        passes: >= 0. Each pass replaces every face value by the mean of itself and its dual-edge
            neighbours; bending is moved to faces first (mean over the face's dual edges) and back
            to edges at the end (mean of the two faces). 0 returns copies of the input.

    Returns:
        bend with the shape given, shear (m,).
    """
    f = as_triangles(faces)
    pairs = np.ascontiguousarray(dual_edges(f), dtype=np.int32)
    b = as_float_array(bend, "bend")
    s = as_float_array(shear, "shear")
    if b.ndim not in (1, 2) or b.shape[0] != len(pairs):
        raise ValueError(f"bend: expected shape ({len(pairs)},) or ({len(pairs)},k), got {b.shape}")
    if s.shape != (len(f),):
        raise ValueError(f"shear: expected shape ({len(f)},), got {s.shape}")
    for name, x in (("bend", b), ("shear", s)):
        if not np.isfinite(x).all():
            raise ValueError(f"{name}: contains NaN or infinity")
    if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 0:
        raise ValueError(f"passes: expected an integer >= 0, got {passes!r}")
    b2 = np.ascontiguousarray(b.reshape(len(pairs), b.shape[1] if b.ndim == 2 else 1))
    sb, ss = _core.smooth_distortions(b2, np.ascontiguousarray(s), pairs, int(passes))
    return np.asarray(sb).reshape(b.shape), np.asarray(ss)


def rotation_spread(vertices, faces, poses, passes: int) -> np.ndarray:
    """Per-face spread of the rotations of a neighbourhood around their mean, per pose.

    For pose s with per-face polar rotations Q_s (T_s = S_s Q_s, as in :func:`learn_distortions`),
    ``spread[i, s] = 3 - |mean_{j~i} Q_sj|_F^2 = mean_{j~i} |Q_sj - mean Q_s|_F^2``, where the mean
    over the neighbourhood j ~ i is ``passes`` passes of the face-graph averaging of
    :func:`smooth_distortions` (each pass: mean of a face and its dual-edge neighbours). A rigidly
    moving part has spread 0; the more a region bends as a whole, the larger (at most 3 for
    opposite rotations at 180 degrees). Faces collapsed in a pose get weight 0 in its averages.

    Args:
        vertices: (n,3) reference positions; faces: (m,3) int; poses: (l,n,3) or l x (n,3).
        passes: >= 0, the neighbourhood size (radius grows like sqrt(passes) faces); 0 gives
            zeros.

    Returns:
        (m,l) dimensionless, in [0, 3]; invariant to a rigid motion of each pose.
    """
    v = as_mesh_vertices(vertices)
    f = as_faces(faces, v.shape[0])
    p = _poses(poses, v.shape[0])
    if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 0:
        raise ValueError(f"passes: expected an integer >= 0, got {passes!r}")
    pairs = np.ascontiguousarray(dual_edges(f), dtype=np.int32)
    return np.asarray(_core.rotation_spread(v, f, pairs, p, int(passes)))


def stiffness_from_distortion(
    distortion, *, eps: float = 0.01, clamp_percent: float = 1.0, sharpness: float = 0.0
) -> np.ndarray:
    """Map distortion >= 0 to stiffness in [eps, 1] (the paper's scaling, generalised).

    Args:
        distortion: (N,) or (N,k) non-negative values, e.g. from :func:`learn_distortions`.
        eps: stiffness floor, 0 < eps <= 1; the most distorted entries get exactly eps.
        clamp_percent: "clamping the bottom 1%": the clamp_percent % most flexible entries are
            raised to the stiffness at the (100 - clamp_percent)-th percentile of distortion
            (numpy's linear percentile over all entries, all columns together), i.e. distortion
            is clipped from above there, so a few near-degenerate triangles cannot squash the
            scale. 0 disables.
        sharpness: 0 gives the paper's linear map stiffness = eps + (1-eps)(1-u) with
            u = clipped distortion / its max; a > 0 gives the exponential falloff
            eps + (1-eps)(exp(-a u) - exp(-a)) / (1 - exp(-a)).

    Returns:
        Stiffness with the shape of ``distortion``. A field with maximum below 1e-12 (round-off)
        maps to ones.
    """
    d = as_float_array(distortion, "distortion")
    if d.ndim not in (1, 2):
        raise ValueError(f"distortion: expected shape (N,) or (N,k), got {d.shape}")
    if not np.all(np.isfinite(d)) or (d.size and d.min() < 0):
        raise ValueError("distortion: expected finite values >= 0")
    if not 0 < eps <= 1:
        raise ValueError(f"eps: expected 0 < eps <= 1, got {eps}")
    if not 0 <= clamp_percent < 100:
        raise ValueError(f"clamp_percent: expected 0 <= clamp_percent < 100, got {clamp_percent}")
    if not (np.isfinite(sharpness) and sharpness >= 0):
        raise ValueError(f"sharpness: expected a finite value >= 0, got {sharpness}")
    d2 = np.ascontiguousarray(d.reshape(d.shape[0], d.shape[1] if d.ndim == 2 else 1))
    s = np.asarray(
        _core.stiffness_from_distortion(d2, float(eps), float(clamp_percent), float(sharpness))
    )
    return s.reshape(d.shape)


def learn_stiffness(
    vertices,
    faces,
    poses,
    *,
    anisotropic: bool = False,
    eps: float = 0.01,
    clamp_percent: float = 1.0,
    sharpness: float = 0.0,
    frame: str = "rest",
    smoothing: int = 0,
    region: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Learn bending and shearing stiffness from example poses (paper Sec. 6).

    Args:
        vertices: (n,3) reference positions; faces: (m,3) int; poses: (l,n,3) or l x (n,3).
        anisotropic, frame: see :func:`learn_distortions`.
        smoothing: passes of :func:`smooth_distortions` applied to the distortions before
            mapping (0 = the paper's per-edge values).
        region: 0 (default) learns bending from the paper's per-edge distortion. > 0 learns it
            from the region-level :func:`rotation_spread` with ``region`` passes instead: the
            bending distortion of dual edge (i, j) is the mean over i and j of
            max over poses of the spread (``smoothing`` then only applies to shear). Isotropic
            only.
        eps, clamp_percent, sharpness: see :func:`stiffness_from_distortion`; the same map is
            applied to bend and shear, each normalised by its own maximum.

    Returns:
        bend: (E,) per dual edge in ``dual_edges(faces)`` order, or (E,3) per axis x, y, z when
            anisotropic; values in [eps, 1], ready for ``MaterialDeformer(bend=...)``.
        shear: (m,) per face in [eps, 1], ready for ``MaterialDeformer(shear=...)``.
    """
    if isinstance(smoothing, bool) or not isinstance(smoothing, (int, np.integer)) or smoothing < 0:
        raise ValueError(f"smoothing: expected an integer >= 0, got {smoothing!r}")
    if isinstance(region, bool) or not isinstance(region, (int, np.integer)) or region < 0:
        raise ValueError(f"region: expected an integer >= 0, got {region!r}")
    if region and anisotropic:
        raise ValueError("region > 0 learns isotropic bending only (anisotropic=False)")
    bend_d, shear_d = learn_distortions(
        vertices, faces, poses, anisotropic=anisotropic, frame=frame
    )
    if smoothing:
        bend_d, shear_d = smooth_distortions(faces, bend_d, shear_d, smoothing)
    if region:
        face_d = rotation_spread(vertices, faces, poses, region).max(axis=1)
        pairs = dual_edges(faces)
        bend_d = 0.5 * (face_d[pairs[:, 0]] + face_d[pairs[:, 1]])
    kw = dict(eps=eps, clamp_percent=clamp_percent, sharpness=sharpness)
    return stiffness_from_distortion(bend_d, **kw), stiffness_from_distortion(shear_d, **kw)
