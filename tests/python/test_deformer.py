import numpy as np
import pytest
import reference
from conftest import affine, rotation

import matdeform as md


def test_identity_transforms_return_rest(small_tube):
    v, f, lo, hi = small_tube
    d = md.MaterialDeformer(v, f, [lo, hi])
    np.testing.assert_allclose(d.deform(np.tile(np.eye(4), (2, 1, 1))), v, atol=1e-10)
    np.testing.assert_allclose(d.deform(np.tile(np.eye(3), (2, 1, 1))), v, atol=1e-10)


@pytest.mark.parametrize("angle", [0.3, 2.0, np.pi - 1e-6, np.pi])
def test_common_rigid_transform_is_reproduced(small_tube, angle):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(5)
    shear = rng.uniform(0.01, 1.0, len(f))
    d = md.MaterialDeformer(v, f, [lo, hi], shear=shear)
    R = rotation([1, -2, 0.5], angle)
    t = np.array([3.0, -1.0, 2.0])
    X = d.deform(np.stack([affine(R, t)] * 2))
    np.testing.assert_allclose(X, v @ R.T + t, atol=1e-8)
    # Scaled similarity too: every face gets s R, so the mesh is exactly scaled and rotated.
    X = d.deform(np.stack([affine(1.7 * R, t)] * 2))
    np.testing.assert_allclose(X, 1.7 * v @ R.T + t, atol=1e-8)


def test_rotation_only_mode_keeps_vertex_mean(small_tube):
    v, f, lo, hi = small_tube
    d = md.MaterialDeformer(v, f, [lo, hi])
    R = rotation([0, 1, 1], 1.1)
    X = d.deform(np.stack([R, R]))
    c = v.mean(axis=0)
    np.testing.assert_allclose(X, (v - c) @ R.T + c, atol=1e-8)


def test_result_is_covariant_under_rigid_motion_of_the_input(small_tube):
    """Deforming a moved mesh with conjugated transforms gives the moved result."""
    v, f, lo, hi = small_tube
    T = np.stack([np.eye(4), affine(rotation([0, 0, 1], 1.2), [0.5, 1.0, 0.0])])
    X = md.MaterialDeformer(v, f, [lo, hi]).deform(T)
    G = affine(rotation([1, 1, 0], 0.8), [2.0, -3.0, 1.0])
    v2 = v @ G[:3, :3].T + G[:3, 3]
    T2 = np.stack([G @ Ta @ np.linalg.inv(G) for Ta in T])
    X2 = md.MaterialDeformer(v2, f, [lo, hi]).deform(T2)
    np.testing.assert_allclose(X2, X @ G[:3, :3].T + G[:3, 3], atol=1e-8)


def test_matches_dense_reference_follow_mode(small_tube):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(7)
    shear = rng.uniform(0.05, 2.0, len(f))
    pairs = md.dual_edges(f)
    bend = rng.uniform(0.05, 2.0, len(pairs))
    mid = np.flatnonzero(np.abs(v[f].mean(axis=1)[:, 0] - 2.0) < 0.15)[:3]
    anchors = [lo, hi, mid]
    T = np.stack(
        [
            affine(rotation([0, 0, 1], 0.2), [0.0, 0.1, 0.0]),
            affine(1.3 * rotation([1, 0.2, 0], 2.4), [0.5, 1.0, -0.3]),
            affine(0.8 * rotation([0, 1, 0], -1.0), [0.0, 0.5, 0.2]),
        ]
    )
    d = md.MaterialDeformer(v, f, anchors, shear=shear, bend=bend)
    X = d.deform(T)

    ref_pairs = reference.dual_pairs(f)
    np.testing.assert_array_equal(ref_pairs, pairs)
    W = reference.weights(len(f), ref_pairs, bend, anchors)
    np.testing.assert_allclose(d.weights, W, atol=1e-10)
    Tf = reference.blend(T[:, :3, :3], W)
    np.testing.assert_allclose(d.face_transforms, Tf, atol=1e-9)
    fixed, fixed_pos = reference.follow_positions(v, f, anchors, T)
    Xref = reference.reposition(v, f, shear, Tf, fixed, fixed_pos)
    np.testing.assert_allclose(X, Xref, atol=1e-8)


def _ring(v, f, x0, x1):
    """Side faces of the tube whose centroids lie in x0 < x < x1."""
    x = v[f].mean(axis=1)[:, 0]
    return np.flatnonzero((x > x0) & (x < x1))


def test_anchors_sharing_vertices_take_the_mean_of_their_transforms(small_tube):
    """Two anchors on neighbouring rings share the ring of vertices between them, with
    different transforms: those vertices go to the mean of the two images (docs/methods.md)."""
    v, f, lo, hi = small_tube
    a, b = _ring(v, f, 1.6, 2.0), _ring(v, f, 2.0, 2.4)
    shared = np.intersect1d(f[a], f[b])
    assert len(shared) == 8  # the ring at x = 2
    anchors = [lo, a, b, hi]
    T = np.stack(
        [
            np.eye(4),
            affine(rotation([0, 0, 1], 0.5), [0.0, 0.4, 0.0]),
            affine(1.2 * rotation([0, 1, 0], -0.7), [0.3, 0.0, 0.5]),
            affine(rotation([1, 0, 0], 1.0), [0.0, 1.0, 0.0]),
        ]
    )
    rng = np.random.default_rng(11)
    shear = rng.uniform(0.2, 2.0, len(f))
    d = md.MaterialDeformer(v, f, anchors, shear=shear)
    X = d.deform(T)
    image = lambda k, i: v[i] @ T[k, :3, :3].T + T[k, :3, 3]  # noqa: E731
    np.testing.assert_allclose(X[shared], 0.5 * (image(1, shared) + image(2, shared)), atol=1e-12)
    only_a = np.setdiff1d(f[a], shared)
    np.testing.assert_allclose(X[only_a], image(1, only_a), atol=1e-12)
    # The rest of the mesh: the dense reference with those fixed positions.
    W = reference.weights(len(f), *reference.default_bend(f, shear), anchors)
    fixed, fixed_pos = reference.follow_positions(v, f, anchors, T)
    Xref = reference.reposition(v, f, shear, reference.blend(T[:, :3, :3], W), fixed, fixed_pos)
    np.testing.assert_allclose(X, Xref, atol=1e-8)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("turn", [0.0, 1.1], ids=["diag(1.5,1,1)", "diag(1.5,1,1) turned"])
def test_non_uniformly_scaled_anchor_matches_dense_reference(small_tube, dtype, turn):
    """A non-uniformly scaled Empty: its anchor blend is not a similarity. Per-face transforms
    are expm(sum w log S) expm(sum w log R) (scipy reference), positions the dense solve."""
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(12)
    shear = rng.uniform(0.2, 2.0, len(f))
    S = np.diag([1.5, 1.0, 1.0])
    T = np.stack([np.eye(4), affine(S @ rotation([0.3, 1, 0.2], turn), [0.4, -0.2, 0.1])])
    T = T.astype(dtype).astype(np.float64)  # what the core sees of float32 input
    d = md.MaterialDeformer(v, f, [lo, hi], shear=shear)
    X = d.deform(T.astype(dtype))
    W = reference.weights(len(f), *reference.default_bend(f, shear), [lo, hi])
    Tf = reference.blend_polar(T[:, :3, :3], W)
    tol = 1e-9 if dtype == np.float64 else 1e-7
    np.testing.assert_allclose(
        d.face_transforms[hi], np.broadcast_to(T[1, :3, :3], (len(hi), 3, 3)), atol=tol
    )
    np.testing.assert_allclose(d.face_transforms, Tf, atol=tol)
    fixed, fixed_pos = reference.follow_positions(v, f, [lo, hi], T)
    np.testing.assert_allclose(X, reference.reposition(v, f, shear, Tf, fixed, fixed_pos), atol=tol)


def test_matches_dense_reference_rotation_only_with_pins(small_tube):
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(8)
    shear = rng.uniform(0.1, 1.0, len(f))
    pinned = np.unique(f[lo])
    pinned_pos = v[pinned] + np.array([0.1, -0.2, 0.05])
    T = np.stack([np.eye(3), 0.9 * rotation([0, 1, 0], 1.4)])
    d = md.MaterialDeformer(v, f, [lo, hi], shear=shear, pinned=pinned)
    X = d.deform(T, pinned_positions=pinned_pos)
    # The default bending stiffness, computed by the reference, not by the core.
    W = reference.weights(len(f), *reference.default_bend(f, shear), [lo, hi])
    np.testing.assert_allclose(d.weights, W, atol=1e-10)
    Tf = reference.blend(T, W)
    Xref = reference.reposition(v, f, shear, Tf, pinned, pinned_pos)
    np.testing.assert_allclose(X, Xref, atol=1e-8)


def _face_rotation_about(v, X, f, axis):
    """Signed rotation angle (rad) of each face's deformation about `axis`, from the geometry."""
    T = md.deformation_gradients(v, X, f)
    U, _, Vt = np.linalg.svd(T)
    R = U @ Vt
    logs = np.array([md.transform_log(r)[1] for r in R])
    return logs @ np.asarray(axis, dtype=float)


def _segment_profile(v, f, values, n_bins=30):
    """Mean of a per-face value in bins along x (caps excluded)."""
    x = v[f].mean(axis=1)[:, 0]
    lo, hi = v[:, 0].min(), v[:, 0].max()
    side = (x > lo + 1e-6) & (x < hi - 1e-6)
    bins = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.digitize(x, bins) - 1, 0, n_bins - 1)
    centers = 0.5 * (bins[:-1] + bins[1:])
    prof = np.array([values[side & (idx == b)].mean() for b in range(n_bins)])
    return centers, prof


@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0, 0]], ids=["bend", "twist"])
def test_uniform_bar_spreads_rotation_evenly(long_bar, axis):
    v, f, lo, hi = long_bar
    theta = 1.2
    d = md.MaterialDeformer(v, f, [lo, hi], pinned=np.unique(f[lo]))
    X = d.deform(np.stack([np.eye(3), rotation(axis, theta)]))
    ang = _face_rotation_about(v, X, f, axis)
    x, prof = _segment_profile(v, f, ang)
    L = v[:, 0].max()
    # Even spread: the rotation grows linearly from 0 to theta along the bar.
    dev = np.abs(prof - theta * x / L).max()
    assert dev < 0.03 * theta, f"max deviation from linear {dev:.4f} rad"
    assert abs(prof[-1] - theta * x[-1] / L) < 0.03 * theta


@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0, 0]], ids=["bend", "twist"])
def test_stiff_middle_third_stays_rigid(long_bar, axis):
    v, f, lo, hi = long_bar
    theta = 1.2
    L = v[:, 0].max()
    xc = v[f].mean(axis=1)[:, 0]
    middle = (xc > L / 3) & (xc < 2 * L / 3)
    shear = np.where(middle, 100.0, 1.0)
    d = md.MaterialDeformer(v, f, [lo, hi], shear=shear, pinned=np.unique(f[lo]))
    X = d.deform(np.stack([np.eye(3), rotation(axis, theta)]))
    ang = _face_rotation_about(v, X, f, axis)
    mid_spread = np.ptp(ang[middle])
    soft1 = np.median(ang[(xc > 0.3 * L) & (xc < L / 3)]) - np.median(ang[xc < 0.03 * L])
    soft2 = np.median(ang[xc > 0.97 * L]) - np.median(ang[(xc > 2 * L / 3) & (xc < 0.7 * L)])
    # Series resistance with a 100x stiffer middle: the middle takes 1/201 of the turn.
    assert mid_spread < 0.03 * theta, f"middle third turns by {mid_spread:.4f} rad"
    assert soft1 > 0.4 * theta and soft2 > 0.4 * theta, (soft1, soft2)
    # Compared with uniform stiffness the middle third is at least 10x more rigid.
    Xu = md.MaterialDeformer(v, f, [lo, hi], pinned=np.unique(f[lo])).deform(
        np.stack([np.eye(3), rotation(axis, theta)])
    )
    uni = _face_rotation_about(v, Xu, f, axis)
    assert np.ptp(uni[middle]) > 10 * mid_spread


def test_weights_partition_of_unity_and_anchor_rows(small_tube):
    v, f, lo, hi = small_tube
    d = md.MaterialDeformer(v, f, [lo, hi])
    W = d.weights
    assert W.shape == (len(f), 2)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert W.min() >= -1e-14 and W.max() <= 1 + 1e-14
    np.testing.assert_array_equal(W[lo], [[1.0, 0.0]] * len(lo))
    np.testing.assert_array_equal(W[hi], [[0.0, 1.0]] * len(hi))


def test_disconnected_part_without_anchor_stays_at_rest(small_tube):
    """The rule for every method: a part with no control keeps its rest positions bit for bit
    (solved, it came back up to ~1e-13)."""
    v, f, lo, hi = small_tube
    n = len(v)
    v2 = np.vstack([v, v @ rotation([1, 1, 0], 0.4).T + [0.1, 5.0, 0.3]])
    f2 = np.vstack([f, f + n])
    d = md.MaterialDeformer(v2, f2, [lo, hi])
    T = np.stack([np.eye(4), affine(rotation([0.3, 1, 0.2], 1.0), [0.5, 1, 0.2])])
    X = d.deform(T)
    assert np.abs(X[:n] - v).max() > 0.5
    np.testing.assert_array_equal(X[n:], v2[n:])
    np.testing.assert_allclose(d.weights[len(f) :], 0.0)
    X3 = d.deform(T[:, :3, :3])  # rotation-only: free parts keep their centroid
    assert np.abs(X3[:n] - v).max() > 0.5
    np.testing.assert_array_equal(X3[n:], v2[n:])
    out = np.empty((len(v2), 3), np.float32)
    d.deform(T, out=out)
    np.testing.assert_array_equal(out[n:], v2[n:].astype(np.float32))
    # a pinned vertex is control too: with one pinned vertex moved, the second part follows it
    pins = np.r_[np.unique(f[lo]), n + 3]
    dp = md.MaterialDeformer(v2, f2, [lo, hi], pinned=pins)
    pos = v2[pins].copy()
    pos[-1] += [0.0, 0.0, 0.5]
    assert np.abs(dp.deform(T, pinned_positions=pos)[n:] - v2[n:]).max() > 0.4
    # ... and an anchor face: anchored, the second part moves
    da = md.MaterialDeformer(v2, f2, [lo, len(f) + hi])
    assert np.abs(da.deform(T)[n:] - v2[n:]).max() > 0.5


def test_degenerate_face_drops_out_of_the_energy(small_tube):
    v, f, lo, hi = small_tube
    # Collapse one side face to zero area: it drops out, neighbours place its vertices.
    v2 = v.copy()
    bad = len(f) // 3
    tri = f[bad]
    v2[tri[2]] = 0.5 * (v2[tri[0]] + v2[tri[1]])
    d = md.MaterialDeformer(v2, f, [lo, hi])
    # A common rigid motion still moves every vertex rigidly, the collapsed face's too.
    R, t = rotation([1, 2, 0], 0.9), np.array([0.5, -1.0, 2.0])
    X = d.deform(np.stack([affine(R, t)] * 2))
    np.testing.assert_allclose(X, v2 @ R.T + t, atol=1e-9)
    # Otherwise: the dense reference without that face (its weights still count it: Eq. 1 is
    # over the dual graph, which the collapse does not change).
    T = np.stack([np.eye(4), affine(rotation([0, 1, 0], 0.7), [0.0, 0.3, 0.0])])
    X = d.deform(T)
    W = reference.weights(len(f), *reference.default_bend(f, np.ones(len(f))), [lo, hi])
    np.testing.assert_allclose(d.weights, W, atol=1e-10)
    keep = np.arange(len(f)) != bad
    Tf = reference.blend(T[:, :3, :3], W)
    fixed, fixed_pos = reference.follow_positions(v2, f, [lo, hi], T)
    Xref = reference.reposition(v2, f[keep], np.ones(keep.sum()), Tf[keep], fixed, fixed_pos)
    np.testing.assert_allclose(X, Xref, atol=1e-8)
    assert np.abs(X - v2).max() > 0.5  # it did deform


def test_per_vertex_bend_is_averaged_over_shared_edges(small_tube):
    v, f, lo, hi = small_tube
    s = np.linspace(0.1, 1.0, len(v))
    d1 = md.MaterialDeformer(v, f, [lo, hi], bend=s)
    d2 = md.MaterialDeformer(v, f, [lo, hi], bend=md.bend_from_vertex(f, s))
    np.testing.assert_allclose(d1.weights, d2.weights, atol=1e-14)
    pairs, shared = md.dual_edges(f, return_shared=True)
    np.testing.assert_allclose(md.bend_from_vertex(f, s), s[shared].mean(axis=1))


def test_all_degenerate_mesh_is_rejected():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    f = np.array([[0, 1, 2], [1, 2, 3]])
    with pytest.raises(ValueError, match="every face is degenerate"):
        md.MaterialDeformer(v, f, [[0]])


def test_face_components_of_two_tubes(small_tube):
    v, f, lo, hi = small_tube
    f2 = np.vstack([f, f + len(v)])
    labels, count = md.face_components(f2)
    assert count == 2
    assert (labels[: len(f)] == 0).all() and (labels[len(f) :] == 1).all()


def _float32_cases(small_tube):
    """(deformer, transforms, pinned_positions) over the paths out= has to cover: follow mode,
    rotation-only, pinned, a region, an anisotropic deformer."""
    v, f, lo, hi = small_tube
    rng = np.random.default_rng(11)
    T = np.stack(
        [affine(rotation([1, 2, 0], 0.7), [0.2, 0, 1]), affine(1.3 * rotation([0, 0, 1], -1.1))]
    )
    pins = np.unique(f[lo])
    xc = v[f].mean(axis=1)[:, 0]
    region = np.flatnonzero((xc > 1.0) & (xc < 3.0))
    ring = lambda x0: np.flatnonzero(np.abs(xc - x0) < 0.2)  # noqa: E731
    bend3 = rng.uniform(0.2, 1, (len(md.dual_edges(f)), 3))
    yield md.MaterialDeformer(v, f, [lo, hi], shear=rng.uniform(0.1, 1, len(f))), T, None
    yield md.MaterialDeformer(v, f, [lo, hi]), T[:, :3, :3].copy(), None
    yield md.MaterialDeformer(v, f, [lo, hi], pinned=pins), T, v[pins] + 0.3
    yield md.MaterialDeformer(v, f, [ring(1.4), ring(2.6)], region=region), T, None
    yield md.MaterialDeformer(v, f, [lo, hi], bend=bend3), T, None


def test_out_receives_the_float64_result_rounded_to_float32(small_tube):
    """out= is the same solve: every coordinate is the float64 result's, rounded to float32,
    outside-region vertices included (their rest positions)."""
    for d, T, pp in _float32_cases(small_tube):
        ref = d.deform(T, pinned_positions=pp)
        out = np.full((d.num_vertices, 3), np.nan, np.float32)
        got = d.deform(T, pinned_positions=pp, out=out)
        assert got is out
        assert out.tobytes() == ref.astype(np.float32).tobytes()
        again = d.deform(T, pinned_positions=pp)  # the float64 path is unaffected by the other
        assert again.tobytes() == ref.tobytes()


@pytest.mark.parametrize(
    "bad",
    [
        lambda n: np.zeros((n, 3)),  # float64
        lambda n: np.zeros((n + 1, 3), np.float32),
        lambda n: np.zeros((3, n), np.float32).T,  # not C-contiguous
        lambda n: np.zeros(3 * n, np.float32),
        lambda n: np.zeros((n, 3), np.float32).tolist(),
    ],
)
def test_a_bad_out_names_itself_and_changes_nothing(small_tube, bad):
    v, f, lo, hi = small_tube
    d = md.MaterialDeformer(v, f, [lo, hi])
    T = np.stack([np.eye(4), affine(rotation([1, 0, 0], 0.5))])
    before = d.deform(T)
    blended = d.face_transforms
    with pytest.raises(ValueError, match=rf"out: expected .*float32 array of shape \({len(v)},3\)"):
        d.deform(np.stack([np.eye(4), np.eye(4)]), out=bad(len(v)))
    # the failed call solved nothing: the last solve is still T's
    assert d.face_transforms.tobytes() == blended.tobytes()
    assert d.deform(T).tobytes() == before.tobytes()


def test_a_read_only_out_and_bad_transforms_leave_out_as_it_was(small_tube):
    v, f, lo, hi = small_tube
    d = md.MaterialDeformer(v, f, [lo, hi])
    ro = np.zeros((len(v), 3), np.float32)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="out: expected a writeable"):
        d.deform(np.stack([np.eye(4), np.eye(4)]), out=ro)
    out = np.full((len(v), 3), 7.0, np.float32)
    bad = np.stack([np.eye(4), np.eye(4)])
    bad[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match="transforms"):
        d.deform(bad, out=out)
    assert (out == 7.0).all()
    # the binding refuses what would be written into a converted copy
    with pytest.raises(ValueError, match="out: expected"):
        d._core.deform_into(np.stack([np.eye(4), np.eye(4)]), None, np.zeros((len(v), 3)))
