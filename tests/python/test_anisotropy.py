"""Anisotropic bending (paper Sec. 5): one stiffness field per rotation axis."""

import numpy as np
import pytest
import reference
from conftest import affine, rotation

import matdeform as md


def _rot_logs(v, X, f):
    """Per-face rotation log (m,3) of the deformation, from the geometry."""
    T = md.deformation_gradients(v, X, f)
    U, _, Vt = np.linalg.svd(T)
    return np.array([md.transform_log(r)[1] for r in U @ Vt])


def test_three_equal_fields_equal_isotropic(small_tube):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(3)
    bend = rng.uniform(0.1, 1.0, len(md.dual_edges(f)))
    T = np.stack([np.eye(4), affine(1.2 * rotation([1, 2, 0.3], 1.3), [0.2, 0.5, 0.0])])
    iso = md.MaterialDeformer(v, f, [lo, hi], bend=bend)
    ani = md.MaterialDeformer(v, f, [lo, hi], bend=np.stack([bend] * 3, axis=1))
    assert ani.anisotropic and not iso.anisotropic
    np.testing.assert_allclose(ani.deform(T), iso.deform(T), atol=1e-12)


def test_per_axis_split_matches_paper_figure_5c(long_bar):
    """Middle third stiff to twist (x) but soft to bend (z); outer thirds the opposite.

    A rotation about x and z at one end: twisting must happen in the outer thirds, bending in
    the middle third.
    """
    v, f, lo, hi = long_bar
    L = v[:, 0].max()
    pairs = md.dual_edges(f)
    xe = v[f].mean(axis=1)[:, 0][pairs].mean(axis=1)
    middle_e = (xe > L / 3) & (xe < 2 * L / 3)
    stiff, soft = 100.0, 1.0
    bend = np.empty((len(pairs), 3))
    bend[:, 0] = np.where(middle_e, stiff, soft)  # twist stiffness
    bend[:, 1] = soft
    bend[:, 2] = np.where(middle_e, soft, stiff)  # bend (about z) stiffness
    theta = 0.9
    Q = md.transform_exp(np.zeros((3, 3)), [theta, 0.0, theta])
    d = md.MaterialDeformer(v, f, [lo, hi], bend=bend, pinned=np.unique(f[lo]))
    X = d.deform(np.stack([np.eye(3), Q]))
    # Blended transforms (Eq. 2 with Sec. 5 weights): the per-axis split is exact there.
    logs = np.array([md.transform_log(t)[1] for t in d.face_transforms])
    xc = v[f].mean(axis=1)[:, 0]
    mid = (xc > 0.36 * L) & (xc < 0.64 * L)
    left, right = xc < 0.3 * L, xc > 0.7 * L
    assert np.ptp(logs[mid, 0]) < 0.02 * theta  # no twist inside the middle third
    assert np.ptp(logs[left, 2]) < 0.02 * theta and np.ptp(logs[right, 2]) < 0.02 * theta
    assert np.ptp(logs[left | right, 0]) > 0.95 * theta  # all the twist is outside
    # mid spans 28% of the bar; uniform stiffness would give it 0.28 theta of the bend.
    assert np.ptp(logs[mid, 2]) > 0.8 * theta
    # Geometry: the centre line (ring centroids) turns about z inside the middle third only.
    rings = X[: 12 * 61].reshape(61, 12, 3).mean(axis=1)
    tangent = np.diff(rings, axis=0)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    x_mid = 0.5 * (v[: 12 * 61 : 12, 0][1:] + v[: 12 * 61 : 12, 0][:-1])
    outer = (x_mid < 0.3 * L) | (x_mid > 0.7 * L)
    inner = (x_mid > 0.36 * L) & (x_mid < 0.64 * L)
    # (uniform stiffness would turn each outer part by ~0.3 theta)
    assert np.ptp(heading[x_mid < 0.3 * L]) < 0.1 * theta
    assert np.ptp(heading[x_mid > 0.7 * L]) < 0.1 * theta
    assert np.ptp(heading[inner]) > 0.6 * theta, (np.ptp(heading[inner]), outer.sum())


def test_custom_axes_are_covariant(small_tube):
    """Rotating the mesh, the transforms and the anisotropy axes together rotates the result."""
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(9)
    bend = rng.uniform(0.05, 1.0, (len(md.dual_edges(f)), 3))
    T = np.stack([np.eye(4), affine(rotation([0.2, 1.0, 0.5], 1.0), [0.0, 0.4, 0.1])])
    X = md.MaterialDeformer(v, f, [lo, hi], bend=bend).deform(T)
    G = rotation([1, -1, 2], 0.7)
    G4 = affine(G)
    T2 = np.stack([G4 @ t @ G4.T for t in T])
    X2 = md.MaterialDeformer(v @ G.T, f, [lo, hi], bend=bend, axes=G).deform(T2)
    np.testing.assert_allclose(X2, X @ G.T, atol=1e-9)
    # With the default (global) axes the answer differs: the decomposition is frame-dependent.
    X3 = md.MaterialDeformer(v @ G.T, f, [lo, hi], bend=bend).deform(T2)
    assert np.abs(X3 - X @ G.T).max() > 1e-3


def test_per_vertex_anisotropic_bend_and_validation(small_tube):
    v, f, lo, hi = small_tube
    s = np.linspace(0.1, 1.0, len(v))
    sv = np.stack([s, s[::-1], np.ones_like(s)], axis=1)
    a = md.MaterialDeformer(v, f, [lo, hi], bend=sv)
    b = md.MaterialDeformer(
        v, f, [lo, hi], bend=np.stack([md.bend_from_vertex(f, c) for c in sv.T], axis=1)
    )
    for ax in range(3):
        np.testing.assert_allclose(a.axis_weights(ax), b.axis_weights(ax), atol=1e-14)
    with pytest.raises(ValueError, match="axes: columns must be orthonormal"):
        md.MaterialDeformer(v, f, [lo, hi], bend=sv, axes=np.diag([1.0, 1.0, 2.0]))
    with pytest.raises(ValueError, match=r"bend: expected shape"):
        md.MaterialDeformer(v, f, [lo, hi], bend=np.ones((len(v), 2)))


def _aniso_setup(small_tube):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(21)
    pairs = reference.dual_pairs(f)
    # Per-axis fields far apart, so that each axis' weights differ from the others'.
    bend = np.stack(
        [
            rng.uniform(0.01, 0.1, len(pairs)),
            rng.uniform(1, 10, len(pairs)),
            rng.uniform(0.1, 10, len(pairs)),
        ],
        axis=1,
    )
    mid = np.flatnonzero(np.abs(v[f].mean(axis=1)[:, 0] - 2.0) < 0.15)[:3]
    return v, f, [lo, mid, hi], pairs, bend


def test_axis_weights_and_their_mean_match_the_dense_reference(small_tube):
    v, f, anchors, pairs, bend = _aniso_setup(small_tube)
    d = md.MaterialDeformer(v, f, anchors, bend=bend)
    ref = [reference.weights(len(f), pairs, bend[:, a], anchors) for a in range(3)]
    for a in range(3):
        np.testing.assert_allclose(d.axis_weights(a), ref[a], atol=1e-10)
    assert np.abs(ref[0] - ref[1]).max() > 0.05 and np.abs(ref[1] - ref[2]).max() > 0.05
    # `weights` of an anisotropic deformer is the mean over the axes (documented), not one axis.
    np.testing.assert_allclose(d.weights, sum(ref) / 3, atol=1e-10)


def test_stretched_anchor_blends_per_axis_like_the_dense_reference(small_tube):
    """An anchor scaled non-uniformly (not a similarity): rotations blend per axis (Sec. 5), the
    log-stretch with the mean weights; positions are the dense solve of those targets."""
    v, f, anchors, pairs, bend = _aniso_setup(small_tube)
    axes = rotation([1, 2, 0.5], 0.7)
    shear = np.random.default_rng(22).uniform(0.2, 2.0, len(f))
    T = np.stack(
        [
            np.eye(4),
            affine(0.9 * rotation([0, 0, 1], 0.4), [0.0, 0.2, 0.0]),
            affine(np.diag([1.5, 1.0, 0.8]) @ rotation([1, 0.5, 0], 1.2), [0.3, 0.5, -0.2]),
        ]
    )
    d = md.MaterialDeformer(v, f, anchors, shear=shear, bend=bend, axes=axes)
    X = d.deform(T)
    Ws = [reference.weights(len(f), pairs, bend[:, a], anchors) for a in range(3)]
    Tf = reference.blend_anisotropic(T[:, :3, :3], Ws, axes)
    np.testing.assert_allclose(d.face_transforms, Tf, atol=1e-9)
    fixed, fixed_pos = reference.follow_positions(v, f, anchors, T)
    np.testing.assert_allclose(
        X, reference.reposition(v, f, shear, Tf, fixed, fixed_pos), atol=1e-8
    )
