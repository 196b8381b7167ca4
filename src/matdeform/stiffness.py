"""Stiffness field conversions (Popa et al. 2006, Sec. 4.1). Stiffness is unitless, > 0."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_float_array, as_stiffness, as_triangles


def _faces(faces) -> np.ndarray:
    f = as_triangles(faces)
    if len(f) == 0:
        raise ValueError("faces: expected at least one triangle, got shape (0,3)")
    return f


def bend_from_shear(faces, shear) -> np.ndarray:
    """phi_fg = (psi_f + psi_g)/2 per dual edge. shear (m,) -> bend (E,)."""
    f = _faces(faces)
    pairs, _ = _core.dual_edges(f)
    return _core.bend_from_shear(pairs, as_stiffness(shear, f.shape[0], "shear"))


def bend_from_vertex(faces, stiffness) -> np.ndarray:
    """Per-vertex stiffness (n,) -> bend (E,): mean over the shared edge's two vertices."""
    f = _faces(faces)
    s = as_float_array(stiffness, "stiffness")
    if s.ndim != 1 or s.shape[0] <= f.max():
        raise ValueError(f"stiffness: expected shape (n,) with n > {f.max()}, got {s.shape}")
    pairs, shared = _core.dual_edges(f)
    return _core.bend_from_vertex(pairs, shared, as_stiffness(s, s.shape[0], "stiffness"))


def shear_from_vertex(faces, stiffness) -> np.ndarray:
    """Per-vertex stiffness (n,) -> shear (m,): mean over each face's three vertices."""
    f = _faces(faces)
    s = as_float_array(stiffness, "stiffness")
    if s.ndim != 1 or s.shape[0] <= f.max():
        raise ValueError(f"stiffness: expected shape (n,) with n > {f.max()}, got {s.shape}")
    return _core.shear_from_vertex(f, as_stiffness(s, s.shape[0], "stiffness"))
