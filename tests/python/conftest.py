import numpy as np
import pytest

from matdeform import shapes


def rotation(axis, angle):
    """Rodrigues rotation matrix (3,3) about a unit-normalised axis, angle in radians."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def ring_angles(v, X, n_around, n_along):
    """(n_along+1,) turn of each ring of an md.shapes.tube about its axis (x), from the rest
    positions v and the deformed X, unwrapped along the tube from the first ring, so any whole
    number of turns shows. Each ring's turn is the circular mean of its vertices' turns."""
    rings = slice(0, (n_along + 1) * n_around)
    rest = np.arctan2(v[rings, 2], v[rings, 1]).reshape(n_along + 1, n_around)
    now = np.arctan2(X[rings, 2], X[rings, 1]).reshape(n_along + 1, n_around)
    return np.unwrap(np.angle(np.exp(1j * (now - rest)).mean(axis=1)))


def affine(R, t=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


@pytest.fixture
def small_tube():
    """A short closed tube (~200 faces) with anchor faces at both ends."""
    v, f = shapes.tube(length=4.0, radius=0.6, n_around=8, n_along=10)
    lo, hi = shapes.end_faces(v, f, fraction=0.01)
    return v, f, lo, hi


@pytest.fixture
def long_bar():
    """A long tube for distribution tests: 60 segments along x, length 12."""
    v, f = shapes.tube(length=12.0, radius=0.5, n_around=12, n_along=60)
    lo, hi = shapes.end_faces(v, f, fraction=0.001)
    return v, f, lo, hi
