"""The transforms a live update in Blender feeds the solver: float32 round-off is treated as
round-off (snapped to the similarity it is), and a genuine non-uniform scale takes the general
blend and is right (against a dense reference of the method)."""

import numpy as np
import pytest
import reference
from conftest import affine, rotation

import matdeform as md


def _setup(small_tube, seed=3):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(seed)
    shear = rng.uniform(0.1, 2.0, len(f))
    mid = np.flatnonzero(np.abs(v[f].mean(axis=1)[:, 0] - 2.0) < 0.15)[:3]
    anchors = [lo, hi, mid]
    return v, f, anchors, shear


SNAP = 1e-6  # the core's kSimilarityTolerance (transforms.hpp)


def _dense(v, f, anchors, shear, T, snap=0.0):
    W = reference.weights(len(f), reference.dual_pairs(f), md.bend_from_shear(f, shear), anchors)
    Tf = reference.polar_blend(T[:, :3, :3], W, snap)
    fixed, pos = reference.follow_positions(v, f, anchors, T)
    return reference.reposition(v, f, shear, Tf, fixed, pos)


def blender_transforms(k, seed):
    """(k,4,4) as the add-on builds them: float32 now @ inv(float32 bind) per Empty."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(k):
        bind = affine(rotation(rng.normal(size=3), rng.uniform(0, 3)), rng.normal(size=3))
        now = affine(rotation(rng.normal(size=3), rng.uniform(0, 2)), rng.normal(size=3)) @ bind
        out.append(
            now.astype(np.float32).astype(np.float64)
            @ np.linalg.inv(bind.astype(np.float32).astype(np.float64))
        )
    return np.stack(out)


def test_float32_rotations_are_snapped_and_the_result_moves_by_under_1e6_of_the_size(
    small_tube,
):
    v, f, anchors, shear = _setup(small_tube)
    diag = np.linalg.norm(v.max(0) - v.min(0))
    d = md.MaterialDeformer(v, f, anchors, shear=shear)
    for seed in range(3):
        T = blender_transforms(3, seed)
        lin = T[:, :3, :3]
        s = np.linalg.svd(lin, compute_uv=False)
        assert 1e-9 < np.ptp(np.log(s), axis=1).max() < 1e-6  # round-off, not a similarity
        for t in lin:  # snapped: the log-stretch is a multiple of I
            ls = md.transform_log(t)[0]
            assert np.array_equal(ls, ls[0, 0] * np.eye(3))
        X = d.deform(T)
        # exactly the snapped model ...
        assert np.abs(X - _dense(v, f, anchors, shear, T, SNAP)).max() < 1e-9 * diag
        # ... and within 1e-6 of the size of the unsnapped one (the general blend of the very
        # same matrices)
        assert np.abs(X - _dense(v, f, anchors, shear, T)).max() < 1e-6 * diag


def test_non_uniform_empty_scale_takes_the_general_blend_and_is_right(small_tube):
    v, f, anchors, shear = _setup(small_tube, seed=4)
    diag = np.linalg.norm(v.max(0) - v.min(0))
    T = blender_transforms(3, 11)
    T[1, :3, :3] = T[1, :3, :3] @ np.diag([1.5, 1.0, 1.0])  # the Empty scaled along its x
    d = md.MaterialDeformer(v, f, anchors, shear=shear)
    X = d.deform(T)
    Xref = _dense(v, f, anchors, shear, T, SNAP)
    assert np.abs(X - Xref).max() < 1e-9 * diag
    # and not the similarity it is not: snapping it would miss by far more than round-off
    T_sim = T.copy()
    u, s, vt = np.linalg.svd(T[1, :3, :3])
    T_sim[1, :3, :3] = np.exp(np.log(s).mean()) * (u @ vt)
    assert np.abs(_dense(v, f, anchors, shear, T_sim, SNAP) - Xref).max() > 1e-3 * diag


@pytest.mark.parametrize("scales", [[(1.3, 1.0, 0.8)], [(1.3, 1.0, 0.8), (0.7, 1.4, 1.0)]])
def test_general_blend_agrees_with_the_per_face_blend(small_tube, scales):
    """deform() blends four faces at a time (one stretched anchor: in its eigenbasis; several:
    scaling and squaring); face_transforms() re-blends face by face with eigen-solves."""
    v, f, anchors, shear = _setup(small_tube, seed=5)
    T = blender_transforms(3, 12)
    for a, sc in enumerate(scales):
        T[a, :3, :3] = T[a, :3, :3] @ np.diag(sc)
    d = md.MaterialDeformer(v, f, anchors, shear=shear)
    X = d.deform(T)
    W = d.weights
    Tf = reference.polar_blend(T[:, :3, :3], W, SNAP)
    np.testing.assert_allclose(d.face_transforms, Tf, atol=1e-10)
    fixed, pos = reference.follow_positions(v, f, anchors, T)
    np.testing.assert_allclose(X, reference.reposition(v, f, shear, Tf, fixed, pos), atol=1e-9)
