"""Issue 11, item 5: inputs that used to surface internal messages (CHOLMOD, pybind, NaN) get a
ValueError that says what to change."""

import numpy as np
import pytest
from conftest import affine, rotation

import matdeform as md
from matdeform import _core, shapes


@pytest.fixture
def tube():
    v, f = shapes.tube(length=4.0, radius=0.6, n_around=8, n_along=10)
    lo, hi = shapes.end_faces(v, f, fraction=0.01)
    return v, f, lo, hi


@pytest.mark.parametrize("scale", [1e80, 1e-80, 1e-100, 1e60, 1e-60])
def test_mesh_size_outside_the_range_asks_to_rescale(tube, scale):
    v, f, lo, hi = tube
    with pytest.raises(ValueError, match="vertices: the mesh is .* across.*rescale the mesh"):
        md.MaterialDeformer(v * scale, f, [lo, hi])
    with pytest.raises(ValueError, match="rescale the mesh"):  # the core's own check
        _core.MaterialDeformer(
            v * scale, f.astype(np.int32), [lo.tolist()], np.ones(len(f)), np.ones((1, 1))
        )
    with pytest.raises(ValueError, match="rescale the mesh"):
        md.learn_distortions(v * scale, f, [v * scale])


@pytest.mark.parametrize("scale", [1e45, 1e-45])
def test_meshes_inside_the_range_deform_like_the_unit_mesh(tube, scale):
    """Scale invariance near both ends of the accepted range: positions scale with the mesh."""
    v, f, lo, hi = tube
    T = np.stack([np.eye(4), affine(rotation([0, 1, 1], 1.0), [1.0, 2.0, 0.5])])
    Ts = T.copy()
    Ts[:, :3, 3] *= scale
    for t, ts in ((T, Ts), (T[:, :3, :3], Ts[:, :3, :3])):
        X = md.MaterialDeformer(v, f, [lo, hi]).deform(t)
        Xs = md.MaterialDeformer(v * scale, f, [lo, hi]).deform(ts)
        np.testing.assert_allclose(Xs / scale, X, rtol=0, atol=1e-9 * np.ptp(X, axis=0).max())


def test_coincident_vertices_are_named(tube):
    v, f, lo, hi = tube
    with pytest.raises(ValueError, match="vertices: all vertices coincide"):
        md.MaterialDeformer(np.zeros_like(v), f, [lo])


@pytest.mark.parametrize("field", ["shear", "bend"])
def test_stiffness_ratio_above_1e12_is_refused(tube, field):
    v, f, lo, hi = tube
    size = len(f) if field == "shear" else len(md.dual_edges(f))
    x = np.ones(size)
    x[3] = 1e-16
    msg = rf"{field}: stiffness ratio max/min = 1e\+16 is above 1e12"
    with pytest.raises(ValueError, match=msg):
        md.MaterialDeformer(v, f, [lo, hi], **{field: x})
    with pytest.raises(ValueError, match="stiffness ratio"):  # the core checks too
        _core.MaterialDeformer(
            v,
            f.astype(np.int32),
            [lo.tolist(), hi.tolist()],
            x if field == "shear" else np.ones(len(f)),
            (x if field == "bend" else np.ones(len(md.dual_edges(f))))[:, None],
        )
    x[3] = 1e-12  # the limit itself is accepted
    assert np.isfinite(md.MaterialDeformer(v, f, [lo, hi], **{field: x}).weights).all()


def test_harmonic_weights_stiffness_ratio(tube):
    v, f, lo, hi = tube
    bend = np.ones(len(md.dual_edges(f)))
    bend[0] = 1e16
    with pytest.raises(ValueError, match="bend: stiffness ratio"):
        md.harmonic_weights(f, [lo, hi], bend)


@pytest.mark.parametrize("fn", [md.transform_log, md.polar_decompose])
def test_4x4_given_to_a_3x3_function(fn):
    msg = r"matrix: expected shape \(3,3\), got \(4, 4\).*M\[:3, :3\]"
    with pytest.raises(ValueError, match=msg):
        fn(np.eye(4))


@pytest.mark.parametrize("value", [709.5, 800.0, -800.0])
def test_transform_exp_beyond_double_range(value):
    L = np.diag([value, 0.0, 0.0])  # not a similarity
    with pytest.raises(ValueError, match="log_stretch: .* above 709"):
        md.transform_exp(L, np.zeros(3))
    with pytest.raises(ValueError, match="log_stretch: .* above 709"):
        md.transform_exp(value * np.eye(3), [0.0, 0.0, 1.0])  # the similarity path
    np.testing.assert_allclose(md.transform_exp(np.diag([700.0, 0, 0]), np.zeros(3))[1, 1], 1.0)


def test_transform_log_of_an_overflowing_scale():
    with pytest.raises(ValueError, match="scale"):
        md.transform_log(np.diag([1e300, 1e300, 1e-300]) @ rotation([1, 0, 0], 0.3))


def test_blend_weights_that_would_overflow():
    T = np.stack([np.eye(3), 2.0 * np.eye(3)])
    with pytest.raises(ValueError, match="weights: row 1 blends the scales to beyond e\\^709"):
        md.blend_transforms(T, np.array([[0.5, 0.5], [0.0, 2000.0]]))
    np.testing.assert_allclose(md.blend_transforms(T, np.array([[0.0, 2.0]]))[0], 4 * np.eye(3))


def test_smooth_distortions_with_nan():
    f = np.array([[0, 1, 2], [0, 2, 3]])
    with pytest.raises(ValueError, match="bend: contains NaN"):
        md.smooth_distortions(f, [np.nan], [0.0, 0.0], 1)
    with pytest.raises(ValueError, match="shear: contains NaN"):
        md.smooth_distortions(f, [1.0], [0.0, np.inf], 1)
    with pytest.raises(ValueError, match="NaN"):  # the core checks too
        _core.smooth_distortions(
            np.full((1, 1), np.nan), np.zeros(2), np.array([[0, 1]], np.int32), 1
        )
