"""Transformation algebra for blending (Alexa 2002, Popa et al. 2006 Eq. 2).

A 3x3 map M with det M > 0 is polar-decomposed into M = S @ R (S symmetric positive definite,
R a rotation). Its log is the pair (log S, axis-angle of R with angle in [0, pi]); blending with
weights w is exp(sum w log S) @ exp(sum w log R). For rotation times uniform scale this is
exactly Alexa's exp(sum w log M).
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_float_array, as_transforms


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
