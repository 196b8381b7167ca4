"""Per-triangle frames and deformation gradients (Sumner & Popovic 2004)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_faces, as_mesh_vertices, as_vertices


def deformation_gradients(rest, deformed, faces) -> np.ndarray:
    """Per-face 3x3 gradients T_i = frame(deformed_i) @ inv(frame(rest_i)).

    rest, deformed: (n,3) positions (any length unit); faces: (m,3) triangles.
    The frame of triangle (a,b,c) is [b-a, c-a, d-a] with the fourth vertex
    d = a + n/sqrt(|n|), n = (b-a) x (c-a). Returns (m,3,3) float64 (unitless).
    Raises ValueError for a zero-area rest face.
    """
    v0 = as_mesh_vertices(rest, "rest")
    v1 = as_vertices(deformed, "deformed", rows=v0.shape[0])
    f = as_faces(faces, v0.shape[0])
    return _core.deformation_gradients(v0, v1, f)
