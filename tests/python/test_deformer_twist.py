"""Turns past half a turn: MaterialDeformer.deform(rotation_vectors=...) and unwrap_rotations.

Closed form: a uniform tube anchored at its two end caps, the top cap turned by theta about the
tube's axis, twists linearly along its length: the ring at height x turns by theta * x / L.
The rings' angles are measured from the output positions (not from the blended transforms) and
unwrapped along the tube from the fixed bottom ring, so any whole number of turns shows.
"""

import numpy as np
import pytest
from conftest import affine, rotation

import matdeform as md
from matdeform import shapes

L, N_AROUND, N_ALONG = 10.0, 16, 60
MIDDLE = N_ALONG // 2


@pytest.fixture(scope="module")
def tube():
    """The issue's tube: length 10 along x, radius 1, anchors at the two caps only."""
    v, f = shapes.tube(length=L, radius=1.0, n_around=N_AROUND, n_along=N_ALONG)
    lo, hi = shapes.end_faces(v, f, fraction=0.01)
    return v, f, md.MaterialDeformer(v, f, [lo, hi])


def twist(theta):
    """(2,4,4) transforms: bottom fixed, top turned by theta about the x axis (the tube's)."""
    return np.stack([np.eye(4), affine(rotation([1, 0, 0], theta))])


def twist_vectors(theta):
    return np.array([[0.0, 0.0, 0.0], [theta, 0.0, 0.0]])


def ring_angles(v, X):
    """(N_ALONG+1,) turn of each ring about x, from positions, unwrapped along the tube."""
    rings = slice(0, (N_ALONG + 1) * N_AROUND)
    rest = np.arctan2(v[rings, 2], v[rings, 1]).reshape(N_ALONG + 1, N_AROUND)
    now = np.arctan2(X[rings, 2], X[rings, 1]).reshape(N_ALONG + 1, N_AROUND)
    # Circular mean of the ring's vertex turns (they agree to ~1e-3 rad).
    turn = np.angle(np.exp(1j * (now - rest)).mean(axis=1))
    return np.unwrap(turn)


@pytest.mark.parametrize("degrees", [0, 90, 180, 210, 360, 540, 720])
def test_twist_of_a_uniform_tube_is_linear_along_its_length(tube, degrees):
    v, f, d = tube
    theta = np.radians(degrees)
    X = d.deform(twist(theta), rotation_vectors=twist_vectors(theta))
    dev = np.abs(ring_angles(v, X) - theta * np.linspace(0.0, 1.0, N_ALONG + 1))
    # Measured (fraction of theta): all rings 0.25 % up to 210 degrees, then 1.0, 2.1, 3.2 % at
    # 360, 540, 720, the largest next to the caps; the middle half 0.65 % at most. Past a turn
    # the twisted middle contracts (radius 0.40 at 720: the turned rest triangles only fit
    # together smaller) while the pinned caps keep radius 1, which bends the law near the ends.
    assert dev.max() <= 0.04 * theta + 1e-12, f"{degrees} deg: {dev.max() / theta:.4f}"
    assert dev[15:46].max() <= 0.01 * theta + 1e-12, f"{degrees} deg: middle half"
    # The middle ring turns by exactly half (the tube is symmetric end for end; measured 1e-12).
    assert abs(dev[MIDDLE]) <= 1e-8 * max(theta, 1.0)
    # Rings stay round and in place along the axis (measured 3e-14 and 3e-13).
    r = np.hypot(X[:-2, 1], X[:-2, 2]).reshape(N_ALONG + 1, N_AROUND)
    assert np.ptp(r, axis=1).max() < 1e-9
    np.testing.assert_allclose(X[:, 0], v[:, 0], atol=1e-9)


def test_middle_ring_follows_half_the_twist_without_a_jump(tube):
    """25 steps 0..720 degrees: the middle ring turns by half, monotonically, in equal steps."""
    v, f, d = tube
    thetas = np.radians(np.linspace(0, 720, 25))
    mid = np.array(
        [ring_angles(v, d.deform(twist(t), rotation_vectors=twist_vectors(t))) for t in thetas]
    )[:, MIDDLE]
    np.testing.assert_allclose(mid, thetas / 2, atol=1e-3 * np.pi)
    steps = np.diff(mid)
    assert steps.min() > 0.99 * np.radians(15) and steps.max() < 1.01 * np.radians(15), steps
    # Without the vectors, the principal log unwinds past 180 degrees: the measurement
    # (210 -> -75 degrees), which the test above would catch if the vectors were ignored.
    none = ring_angles(v, d.deform(twist(np.radians(210))))[MIDDLE]
    assert abs(np.degrees(none) + 75) < 0.5


def test_unwrapped_animation_drives_the_twist(tube):
    """The intended use: unwrap the top anchor's matrices along the animation, then deform."""
    v, f, d = tube
    thetas = np.radians(np.linspace(0, 720, 25))
    frames = np.stack([twist(t)[1, :3, :3] for t in thetas]).astype(np.float32)
    vectors = md.unwrap_rotations(frames)
    np.testing.assert_allclose(vectors[:, 0], thetas, atol=1e-6)
    np.testing.assert_allclose(vectors[:, 1:], 0.0, atol=1e-6)
    for t, rv in zip(thetas[::6], vectors[::6], strict=True):
        T = twist(t)
        T[1, :3, :3] = T[1, :3, :3].astype(np.float32)
        X = d.deform(T, rotation_vectors=np.stack([np.zeros(3), rv]))
        assert abs(ring_angles(v, X)[MIDDLE] - t / 2) < 1e-3 * np.pi


def test_rigid_motion_of_everything_moves_the_result(tube):
    """Mesh moved by G, transforms conjugated, vectors turned by G's rotation: X moved by G."""
    v, f, d = tube
    theta = np.radians(540)
    T = twist(theta)
    T[1, :3, 3] = [0.3, -0.2, 0.5]
    rv = twist_vectors(theta)
    X = d.deform(T, rotation_vectors=rv)
    G = affine(rotation([1, 2, -1], 0.9), [4.0, -1.0, 2.0])
    v2 = v @ G[:3, :3].T + G[:3, 3]
    lo, hi = shapes.end_faces(v, f, fraction=0.01)
    T2 = np.stack([G @ t @ np.linalg.inv(G) for t in T])
    X2 = md.MaterialDeformer(v2, f, [lo, hi]).deform(T2, rotation_vectors=rv @ G[:3, :3].T)
    np.testing.assert_allclose(X2, X @ G[:3, :3].T + G[:3, 3], atol=1e-9)
    assert ring_angles(v, X)[MIDDLE] > np.radians(260)  # the turns are really there


@pytest.mark.parametrize("kind", ["4x4", "3x3", "scaled", "anisotropic", "out"])
def test_principal_vectors_give_bit_identical_results(tube, kind):
    """Vectors equal to the logs deform() computes itself (md.transform_log of each 3x3 part)
    give the same bits as rotation_vectors=None, on every blend path."""
    v, f, d = tube
    T = np.stack(
        [affine(1.2 * rotation([0, 1, 1], 0.7), [0, 1, 0]), affine(rotation([1, 0.3, 0], 3.0))]
    )
    if kind == "scaled":  # the general (non-similarity) path
        T[1, :3, :3] = T[1, :3, :3] @ np.diag([1.3, 1.0, 0.8])
    if kind == "3x3":
        T = T[:, :3, :3]
    if kind == "anisotropic":
        lo, hi = shapes.end_faces(v, f, fraction=0.01)
        bend = np.tile([1.0, 3.0, 0.5], (len(md.dual_edges(f)), 1))
        d = md.MaterialDeformer(v, f, [lo, hi], bend=bend)
    rv = np.stack([md.transform_log(t[:3, :3])[1] for t in T])
    if kind == "out":
        a, b = np.empty((len(v), 3), np.float32), np.empty((len(v), 3), np.float32)
        d.deform(T, out=a)
        d.deform(T, out=b, rotation_vectors=rv)
        assert np.array_equal(a, b)
        return
    X0 = d.deform(T)
    F0 = d.face_transforms
    X1 = d.deform(T, rotation_vectors=rv)
    assert np.array_equal(X0, X1)
    assert np.array_equal(F0, d.face_transforms)


def test_other_branches_differ_only_where_they_should(tube):
    """The branch matters: one more turn about the same axis changes the result; a vector off
    by less than the tolerance is accepted and moves vertices by about that angle at most."""
    v, f, d = tube
    theta = 1.0
    X = d.deform(twist(theta), rotation_vectors=twist_vectors(theta))
    X2 = d.deform(twist(theta), rotation_vectors=twist_vectors(theta + 2 * np.pi))
    assert np.degrees(ring_angles(v, X2)[MIDDLE] - ring_angles(v, X)[MIDDLE]) == pytest.approx(
        180, abs=0.5
    )
    tol = md.ROTATION_VECTOR_TOLERANCE
    assert tol == 1e-4
    Xc = d.deform(twist(theta), rotation_vectors=twist_vectors(theta + 0.9 * tol))
    assert 0 < np.abs(Xc - X).max() < 2 * tol


BAD = {
    "shape (2,4)": (np.zeros((2, 4)), "expected shape \\(2,3\\)"),
    "shape (3,3)": (np.zeros((3, 3)), "expected shape \\(2,3\\)"),
    "shape (3,)": (np.zeros(3), "expected shape \\(2,3\\)"),
    "NaN": (np.array([[0, 0, np.nan], [1.0, 0, 0]]), "NaN"),
    "inf": (np.array([[0, 0, 0], [np.inf, 0, 0]]), "NaN or infinity"),
    "strings": ([["a", "b", "c"], ["d", "e", "f"]], "float array"),
    "off by 2x tolerance": (np.array([[0, 0, 0], [1.0 + 2e-4, 0, 0]]), "differs .* by 0.0002"),
    "half a turn more": (np.array([[0, 0, 0], [1.0 + np.pi, 0, 0]]), "by 3.14"),
    "the other sign": (np.array([[0, 0, 0], [-1.0, 0, 0]]), "rotation_vectors\\[1\\]"),
    "wrong axis": (np.array([[0, 0, 0], [0, 1.0 + 2 * np.pi, 0]]), "rotation_vectors\\[1\\]"),
    "extra turn off the axis": (np.array([[0, 2 * np.pi, 0.1], [1.0, 0, 0]]), "vectors\\[0\\]"),
    "too long": (np.array([[0, 0, 0], [1e200, 0, 0]]), "too long"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_rotation_vectors_raise_and_change_nothing(tube, name):
    v, f, d = tube
    T = twist(1.0 + 2 * np.pi)  # the matrix of a 1 rad turn; the good vector has one more turn
    good = twist_vectors(1.0 + 2 * np.pi)
    X = d.deform(T, rotation_vectors=good)
    F = d.face_transforms
    bad, match = BAD[name]
    with pytest.raises(ValueError, match="rotation_vectors"):
        d.deform(T, rotation_vectors=bad)
    with pytest.raises(ValueError, match=match):
        d.deform(T, rotation_vectors=bad)
    out = np.full((len(v), 3), 7.0, np.float32)
    with pytest.raises(ValueError, match="rotation_vectors"):
        d.deform(T, out=out, rotation_vectors=bad)
    assert (out == 7.0).all()
    assert np.array_equal(F, d.face_transforms)
    assert np.array_equal(X, d.deform(T, rotation_vectors=good))


def test_the_core_checks_the_vectors_too(tube):
    """matdeform._core directly (no Python checks): a ValueError, never a crash."""
    v, f, d = tube
    T = twist(1.0)
    with pytest.raises(ValueError, match="rotation_vectors: expected shape \\(2,3\\)"):
        d._core.deform(T, None, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="NaN"):
        d._core.deform(T, None, np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="differs"):
        d._core.deform_into(T, None, np.empty((len(v), 3), np.float32), np.ones((2, 3)))
