"""Transformation algebra for blending (Alexa 2002, Popa et al. 2006 Eq. 2).

A 3x3 map M with det M > 0 is polar-decomposed into M = S @ R (S symmetric positive definite,
R a rotation). Its log is the pair (log S, axis-angle of R with angle in [0, pi]); blending with
weights w is exp(sum w log S) @ exp(sum w log R). For rotation times uniform scale this is
exactly Alexa's exp(sum w log M). R's other logs (the principal one plus whole turns about its
axis) give turns past half a turn: ``unwrap_rotations`` picks them along an animation.
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_float_array, as_transforms

# Largest angle (rad) by which exp of a given rotation vector may differ from the rotation it
# stands for (MaterialDeformer.deform(rotation_vectors=...)): float32 matrices and vectors of a
# few turns are rounded by ~1e-6 rad, real mistakes are far above it.
ROTATION_VECTOR_TOLERANCE: float = _core.ROTATION_VECTOR_TOLERANCE


def _as_matrix(m, name: str) -> np.ndarray:
    a = as_float_array(m, name)
    if a.shape != (3, 3):
        hint = " (pass M[:3, :3] for the linear part of a 4x4)" if a.shape == (4, 4) else ""
        raise ValueError(f"{name}: expected shape (3,3), got {a.shape}{hint}")
    return as_transforms(a[None], 1, name)[0]


def transform_log(matrix) -> tuple[np.ndarray, np.ndarray]:
    """(log_stretch (3,3) symmetric, rotation (3,) axis*angle in radians) of a (3,3) map."""
    return _core.transform_log(_as_matrix(matrix, "matrix"))


def transform_exp(log_stretch, rotation) -> np.ndarray:
    """Inverse of transform_log: expm(log_stretch) @ Rodrigues(rotation). Returns (3,3).

    The eigenvalues of the symmetric part of log_stretch must lie in [-709, 709] (exp of more
    overflows a double).
    """
    ls = as_float_array(log_stretch, "log_stretch")
    r = as_float_array(rotation, "rotation")
    if ls.shape != (3, 3) or not np.isfinite(ls).all():
        raise ValueError(f"log_stretch: expected a finite (3,3) array, got shape {ls.shape}")
    if r.shape != (3,) or not np.isfinite(r).all():
        raise ValueError(f"rotation: expected a finite (3,) axis-angle vector, got {r.shape}")
    return _core.transform_exp(ls, r)


def polar_decompose(matrix) -> tuple[np.ndarray, np.ndarray]:
    """(S, R) with matrix = S @ R, S symmetric positive definite, R a rotation."""
    return _core.polar_decompose(_as_matrix(matrix, "matrix"))


def blend_transforms(transforms, weights) -> np.ndarray:
    """Blend k (3,3) transforms with per-row weights (m,k). Returns (m,3,3)."""
    w = np.ascontiguousarray(as_float_array(weights, "weights"))
    if w.ndim != 2 or not np.isfinite(w).all():
        raise ValueError(f"weights: expected a finite (m,k) array, got shape {w.shape}")
    t = as_transforms(transforms, w.shape[1], "transforms")
    if t.shape[1] != 3:
        raise ValueError(f"transforms: expected shape ({w.shape[1]},3,3), got {t.shape}")
    return _core.blend_transforms(t, w)


def unwrap_rotations(rotations, start=None) -> np.ndarray:
    """Rotation vectors (axis * angle, radians) continuous along a sequence of rotations.

    rotations : (N,3,3), one sequence of N frames, or (N,k,3,3), k sequences (e.g. k anchors
        over N frames). Any maps with det > 0: each one's rotation factor R (polar
        decomposition M = S @ R) is used, so scaled Empty matrices can be passed as they are.
    start : (3,) or (k,3) vectors, or None. Frame 0 takes the log of its rotation nearest to
        start (None: the principal log, angle <= pi), e.g. the vector shown last.

    Returns (N,3) or (N,k,3): every frame's vector is the log of its rotation nearest to the
    previous frame's vector, i.e. the principal log plus the whole turns about the same axis
    that keep the sequence continuous. Each can be passed as ``rotation_vectors`` to
    ``MaterialDeformer.deform``.

    A step of more than half a turn between two frames cannot be told from the opposite step of
    less than half a turn; the shorter is taken, so sample the motion finely enough that no
    step exceeds about 90 degrees. At a whole number of turns the axis is undefined (every axis
    turned by 2 pi is the identity): a frame within ``ROTATION_VECTOR_TOLERANCE`` of the
    identity keeps the previous vector's axis, but a motion that passes a whole turn tilted off
    that axis by more has no log near the previous vector, and its vectors change fast there.
    """
    a = as_float_array(rotations, "rotations")
    if a.ndim not in (3, 4) or a.shape[-2:] != (3, 3):
        raise ValueError(f"rotations: expected shape (N,3,3) or (N,k,3,3), got {a.shape}")
    k = 1 if a.ndim == 3 else a.shape[1]
    lead = a.shape[:-2]
    if k == 0:
        raise ValueError(f"rotations: expected at least one sequence, got shape {a.shape}")
    flat = np.ascontiguousarray(a.reshape(-1, 3, 3))
    if not np.isfinite(flat).all():
        raise ValueError("rotations: contains NaN or infinity")
    s = None
    if start is not None:
        s = as_float_array(start, "start")
        want = (3,) if a.ndim == 3 else (k, 3)
        if s.shape != want:
            raise ValueError(f"start: expected shape {want}, got {s.shape}")
        if not np.isfinite(s).all():
            raise ValueError("start: contains NaN or infinity")
        s = np.ascontiguousarray(s.reshape(k, 3))
    if flat.shape[0]:
        as_transforms(flat, flat.shape[0], "rotations")  # det > 0 for every frame
    return _core.unwrap_rotations(flat, k, s).reshape(*lead, 3)
