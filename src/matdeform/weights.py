"""Harmonic blending weights under bending stiffness (Popa et al. 2006, Eq. 1)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_anchors, as_stiffness, as_triangles


def harmonic_weights(faces, anchors, bend=None) -> np.ndarray:
    """Minimise sum_(f,g) bend_fg |w_f - w_g|^2 with anchor faces fixed to unit vectors.

    faces: (m,3) int triangles. anchors: k non-empty, disjoint face index arrays.
    bend: (E,) stiffness > 0 per dual edge in dual_edges(faces) order (default 1).
    Returns W (m,k): rows sum to 1 and lie in [0,1] on faces an anchor reaches; faces in a
    component no anchor reaches get all-zero rows (they keep the identity transform).
    """
    f = as_triangles(faces)
    m = f.shape[0]
    pairs, _ = _core.dual_edges(f)
    if bend is None:
        phi = np.ones(len(pairs))
    else:
        phi = as_stiffness(bend, len(pairs), "bend", solved=True)
    return _core.harmonic_weights(m, pairs, phi, as_anchors(anchors, m))
