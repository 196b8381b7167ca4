"""Procedural test and demo meshes (closed tubes and bars)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def tube(
    length: float = 10.0,
    radius: float | Callable[[np.ndarray], np.ndarray] = 1.0,
    n_around: int = 16,
    n_along: int = 40,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube along +x from x=0 to x=length, capped with a centre vertex at each end.

    radius: a constant, or a function of t in [0,1] (along the axis) giving the radius.
    Returns vertices (n_around*(n_along+1)+2, 3) and faces (2*n_around*(n_along+1), 3).
    """
    if n_around < 3 or n_along < 1:
        raise ValueError("n_around must be >= 3 and n_along >= 1")
    t = np.linspace(0.0, 1.0, n_along + 1)
    r = radius(t) if callable(radius) else np.full_like(t, float(radius))
    ang = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    ring = np.stack([np.zeros_like(ang), np.cos(ang), np.sin(ang)], axis=1)
    v = (ring[None, :, :] * r[:, None, None]).copy()
    v[:, :, 0] = (t * length)[:, None]
    v = v.reshape(-1, 3)
    i = np.arange(n_along)[:, None]
    j = np.arange(n_around)[None, :]
    a = i * n_around + j
    b = i * n_around + (j + 1) % n_around
    c, d = a + n_around, b + n_around
    side = np.concatenate(
        [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)]
    )
    start, end = len(v), len(v) + 1
    ring0 = np.arange(n_around)
    ring1 = n_along * n_around + ring0
    cap0 = np.stack([np.full(n_around, start), (ring0 + 1) % n_around, ring0], -1)
    cap1 = np.stack(
        [np.full(n_around, end), ring1, n_along * n_around + (ring0 + 1) % n_around], -1
    )
    v = np.vstack([v, [[0.0, 0.0, 0.0], [length, 0.0, 0.0]]])
    return v, np.vstack([side, cap0, cap1]).astype(np.int64)


def tube_with_faces(target_faces: int, aspect: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """A tube of about target_faces triangles with length/diameter ~ aspect (for benchmarks)."""
    n_around = max(8, int(round(np.sqrt(target_faces * np.pi / (2 * aspect)))))
    n_along = max(1, int(round(target_faces / (2 * n_around))) - 1)
    return tube(length=2.0 * aspect, radius=1.0, n_around=n_around, n_along=n_along)


def end_faces(vertices, faces, fraction: float = 0.02, axis: int = 0) -> tuple[np.ndarray, ...]:
    """Faces whose vertices all lie within `fraction` of the extent from the low / high end."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    x = v[f, axis]
    lo, hi = v[:, axis].min(), v[:, axis].max()
    span = hi - lo
    low = np.flatnonzero((x <= lo + fraction * span).all(axis=1))
    high = np.flatnonzero((x >= hi - fraction * span).all(axis=1))
    return low, high
