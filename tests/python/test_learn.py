"""Closed-form checks of matdeform.learn (paper Sec. 6)."""

from pathlib import Path

import numpy as np
import pytest
from conftest import rotation as rot

import matdeform as md

# shared/ sits beside the repository clone (as in CI).
CAT = Path(__file__).resolve().parents[2] / "data" / "cat-poses"


def grid(nx, ny):
    """Flat unit-spaced (nx x ny)-quad grid in z = 0, two triangles per quad."""
    j, i = np.mgrid[0 : ny + 1, 0 : nx + 1]
    v = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1).astype(float)
    a = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]).ravel()
    b, c = a + 1, a + nx + 1
    d = c + 1
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return v, f.astype(np.int32)


def fold(v, x0, angle):
    """Rigidly fold everything right of the line x = x0 about the y axis."""
    out = v.copy()
    right = v[:, 0] > x0
    c = np.array([x0, 0.0, 0.0])
    out[right] = (v[right] - c) @ rot([0, 1, 0], angle).T + c
    return out


def hinge_edges(v, f, x0):
    """Mask over dual_edges(f) of the face pairs whose shared edge lies on x = x0."""
    pairs = md.dual_edges(f)
    mask = np.zeros(len(pairs), bool)
    for e, (g, h) in enumerate(pairs):
        shared = np.intersect1d(f[g], f[h])
        mask[e] = np.all(v[shared, 0] == x0)
    return mask


@pytest.fixture
def hinge():
    v, f = grid(10, 3)
    poses = [fold(v, 3.0, 0.4), fold(v, 7.0, -1.1), fold(v, 3.0, -0.7)]
    return v, f, poses


def gap(angle):
    """|I - R(angle)|_F^2 for a rotation by angle."""
    return 8 * np.sin(angle / 2) ** 2


def test_distortion_is_max_over_poses_at_the_hinges(hinge):
    v, f, poses = hinge
    bend, shear = md.learn_distortions(v, f, poses)
    at3, at7 = hinge_edges(v, f, 3.0), hinge_edges(v, f, 7.0)
    assert bend.shape == (len(md.dual_edges(f)),) and shear.shape == (len(f),)
    assert at3.sum() == 3 and at7.sum() == 3
    np.testing.assert_allclose(bend[at3], gap(0.7), atol=1e-12)
    np.testing.assert_allclose(bend[at7], gap(1.1), atol=1e-12)
    np.testing.assert_allclose(bend[~(at3 | at7)], 0, atol=1e-12)
    assert shear.max() < 1e-20


def test_learned_bending_is_minimal_exactly_at_the_hinge(hinge):
    v, f, poses = hinge
    bend, shear = md.learn_stiffness(v, f, poses, eps=0.05, clamp_percent=0)
    at3, at7 = hinge_edges(v, f, 3.0), hinge_edges(v, f, 7.0)
    np.testing.assert_allclose(bend[at7], 0.05, atol=1e-12)
    np.testing.assert_allclose(bend[at3], 0.05 + 0.95 * (1 - gap(0.7) / gap(1.1)), atol=1e-12)
    np.testing.assert_array_equal(bend[~(at3 | at7)], 1.0)
    assert np.argmin(bend) in np.flatnonzero(at7)
    np.testing.assert_array_equal(shear, 1.0)


def test_anisotropic_sees_only_the_hinge_axis(hinge):
    v, f, poses = hinge
    at3, at7 = hinge_edges(v, f, 3.0), hinge_edges(v, f, 7.0)
    for frame in ("rest", "world"):
        bend, _ = md.learn_distortions(v, f, poses, anisotropic=True, frame=frame)
        assert bend.shape == (len(at3), 3)
        np.testing.assert_allclose(bend[:, [0, 2]], 0, atol=1e-20)
        np.testing.assert_allclose(bend[at3, 1], 0.49, atol=1e-12)
        np.testing.assert_allclose(bend[at7, 1], 1.21, atol=1e-12)
    stiff, _ = md.learn_stiffness(v, f, poses, anisotropic=True, eps=0.1, clamp_percent=0)
    np.testing.assert_allclose(stiff[at7, 1], 0.1)
    np.testing.assert_array_equal(stiff[:, [0, 2]], 1.0)


def test_invariant_to_rigid_motion_of_each_pose(hinge):
    v, f, poses = hinge
    rng = np.random.default_rng(4)
    moved = [
        p @ rot(rng.normal(size=3), rng.uniform(0, np.pi)).T + rng.normal(size=3) for p in poses
    ]
    for aniso in (False, True):
        b0, s0 = md.learn_distortions(v, f, poses, anisotropic=aniso)
        b1, s1 = md.learn_distortions(v, f, moved, anisotropic=aniso)
        np.testing.assert_allclose(b1, b0, atol=1e-12)
        np.testing.assert_allclose(s1, s0, atol=1e-12)


def test_uniform_stretch_closed_form():
    v, f = grid(4, 4)
    p = v * [2.0, 1.0, 1.0]
    # In-plane x doubles, the fourth vertex offset n/sqrt|n| grows by sqrt 2 (area doubles).
    _, shear = md.learn_distortions(v, f, p[None])
    np.testing.assert_allclose(shear, 1 + (np.sqrt(2) - 1) ** 2, atol=1e-12)


def test_map_matches_numpy_percentile_and_stays_in_range():
    rng = np.random.default_rng(0)
    d = rng.exponential(size=1000) ** 3
    s = md.stiffness_from_distortion(d, eps=0.02, clamp_percent=1.0)
    top = np.percentile(d, 99)
    np.testing.assert_allclose(s, 0.02 + 0.98 * (1 - np.minimum(d, top) / top), atol=1e-13)
    assert s.min() == pytest.approx(0.02) and s.max() <= 1.0
    s = md.stiffness_from_distortion(d, eps=0.02, clamp_percent=1.0, sharpness=4.0)
    u = np.minimum(d, top) / top
    want = 0.02 + 0.98 * (np.exp(-4 * u) - np.exp(-4)) / (1 - np.exp(-4))
    np.testing.assert_allclose(s, want, atol=1e-13)
    d3 = rng.exponential(size=(50, 3))
    s3 = md.stiffness_from_distortion(d3, clamp_percent=2.0)
    assert s3.shape == (50, 3)
    top = np.percentile(d3, 98)  # one scale for all three axes
    np.testing.assert_allclose(s3, 0.01 + 0.99 * (1 - np.minimum(d3, top) / top), atol=1e-13)


def test_smoothing_keeps_constants_and_spreads_around_the_fold(hinge):
    v, f, poses = hinge
    e = len(md.dual_edges(f))
    b, s = md.smooth_distortions(f, np.full((e, 3), 0.25), np.full(len(f), 0.75), 5)
    np.testing.assert_allclose(b, 0.25, atol=1e-14)
    np.testing.assert_allclose(s, 0.75, atol=1e-14)
    bend, _ = md.learn_stiffness(v, f, poses, clamp_percent=0, smoothing=2)
    pairs = md.dual_edges(f)
    shared = [np.intersect1d(f[g], f[h]) for g, h in pairs]
    x = np.array([v[sh, 0].mean() for sh in shared])
    assert bend.min() == pytest.approx(0.01)
    assert 6 <= x[np.argmin(bend)] <= 8  # next to the larger fold (x = 7)
    assert np.all(bend[np.array([v[sh, 0].max() for sh in shared]) <= 1] == 1.0)
    assert np.sum(bend < 1) > 12  # more than the 6 hinge edges


def test_array_and_list_of_poses_agree(hinge):
    v, f, poses = hinge
    a = md.learn_stiffness(v, f, np.stack(poses))
    b = md.learn_stiffness(v, f, poses)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(poses=[]), "poses"),
        (dict(poses=np.zeros((2, 5, 3))), "poses"),
        (dict(poses=[np.zeros((3, 3))]), r"poses\[0\]"),
        (dict(vertices=np.zeros((4, 2))), "vertices"),
        (dict(faces=np.zeros((4, 4), int)), "faces"),
        (dict(frame="body"), "frame"),
        (dict(eps=0.0), "eps"),
        (dict(clamp_percent=100.0), "clamp_percent"),
        (dict(smoothing=-1), "smoothing"),
    ],
)
def test_bad_input_names_the_argument(hinge, kwargs, match):
    v, f, poses = hinge
    args = dict(vertices=v, faces=f, poses=poses)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        md.learn_stiffness(**args)


def test_nan_pose_rejected(hinge):
    v, f, poses = hinge
    bad = poses[1].copy()
    bad[5, 2] = np.nan
    with pytest.raises(ValueError, match=r"poses\[1\]"):
        md.learn_stiffness(v, f, [poses[0], bad])


def _face_rotations(rest, pose, f):
    """Per-face rotation (m,3,3) of a pose: polar part of its frame (fourth vertex at
    n / sqrt|n|) times the inverse rest frame, computed here with numpy."""

    def frames(x):
        a, b, c = x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]
        n = np.cross(b - a, c - a)
        return np.stack([b - a, c - a, n / np.sqrt(np.linalg.norm(n, axis=1))[:, None]], axis=2)

    U, _, Vt = np.linalg.svd(frames(pose) @ np.linalg.inv(frames(rest)))
    return U @ Vt


def _joint_edges(v, f, poses, pairs, parts=12, reach=2):
    """Mask over the dual edges near a joint, defined from the poses without the learning code:
    faces are grouped into `parts` body parts by how they rotate over all poses (k-means on
    the per-face rotations), and a joint is where two parts meet, widened by `reach` dual-graph
    hops on each side."""
    from scipy.cluster.vq import kmeans2
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    m = len(f)
    X = np.concatenate([_face_rotations(v, p, f).reshape(m, 9) for p in poses], axis=1)
    _, label = kmeans2(X, parts, seed=1, minit="++")
    between = label[pairs[:, 0]] != label[pairs[:, 1]]
    A = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    hops = dijkstra(A + A.T, indices=np.unique(pairs[between]), unweighted=True, min_only=True)
    near = hops <= reach
    return near[pairs[:, 0]] & near[pairs[:, 1]]


def test_cat_learned_flexible_edges_sit_at_the_joints():
    v, f = np.load(CAT / "reference.npy"), np.load(CAT / "faces.npy")
    poses = list(np.load(CAT / "poses.npy"))
    bend, shear = md.learn_stiffness(v, f, poses, eps=0.01)
    pairs = md.dual_edges(f)
    assert bend.shape == (len(pairs),) and shear.shape == (len(f),)
    for s in (bend, shear):
        assert s.min() == pytest.approx(0.01) and s.max() <= 1.0
    joint = _joint_edges(v, f, poses, pairs)
    flexible = bend <= np.percentile(bend, 1)  # the 1% most flexible dual edges
    # Joints hold about a quarter of the dual edges (0.24), and 86% of the most flexible ones.
    # Shuffled values give the base rate, stiffness and flexibility swapped 0.005, a per-face
    # |Q - I|^2 (the rotation of each part, not between parts) 0.005, values in reversed edge
    # order 0.34.
    assert 0.15 < joint.mean() < 0.35
    assert flexible[joint].sum() / flexible.sum() > 0.75
    assert np.median(bend[joint]) < np.median(bend[~joint])


def face_x(v, f):
    return v[f].mean(1)[:, 0]


def test_rotation_spread_closed_form_on_two_faces():
    # One quad folded along its diagonal by theta: after one pass both faces see the mean of the
    # two rotations, spread = 3 - |Q1 + Q2|^2 / 4 = |Q1 - Q2|^2 / 4.
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    p = v.copy()
    p[3] = rot(axis, 0.9) @ v[3]
    s = md.rotation_spread(v, f, [v, p], 1)
    assert s.shape == (2, 2)
    np.testing.assert_allclose(s[:, 0], 0, atol=1e-14)
    np.testing.assert_allclose(s[:, 1], gap(0.9) / 4, atol=1e-12)
    np.testing.assert_array_equal(md.rotation_spread(v, f, [p], 0), 0.0)


def test_rotation_spread_is_local_bounded_and_rigid_invariant(hinge):
    v, f, poses = hinge
    passes = 4
    s = md.rotation_spread(v, f, poses, passes)
    assert s.shape == (len(f), 3)
    x = face_x(v, f)
    # Two rigid halves: a two-point mix of Q1, Q2 has variance a(1-a)|Q1-Q2|^2 <= |Q1-Q2|^2/4.
    for col, (x0, angle) in enumerate([(3.0, 0.4), (7.0, 1.1), (3.0, 0.7)]):
        assert s[:, col].max() <= gap(angle) / 4 + 1e-12
        assert abs(x[np.argmax(s[:, col])] - x0) < 1  # largest next to the fold
        # The averaging reaches `passes` dual-graph hops (< passes columns of the grid) only.
        np.testing.assert_allclose(s[np.abs(x - x0) > passes, col], 0, atol=1e-12)
    rng = np.random.default_rng(7)
    moved = [
        p @ rot(rng.normal(size=3), rng.uniform(0, np.pi)).T + rng.normal(size=3) for p in poses
    ]
    np.testing.assert_allclose(md.rotation_spread(v, f, moved, passes), s, atol=1e-12)
    # Each column depends on its own pose only.
    np.testing.assert_allclose(md.rotation_spread(v, f, [poses[1]], passes)[:, 0], s[:, 1])


def test_learn_stiffness_region_is_softest_at_the_larger_fold(hinge):
    v, f, poses = hinge
    bend, shear = md.learn_stiffness(v, f, poses, region=2, eps=0.05, clamp_percent=0)
    _, shear0 = md.learn_stiffness(v, f, poses, eps=0.05, clamp_percent=0)
    pairs = md.dual_edges(f)
    xe = face_x(v, f)[pairs].mean(1)
    assert bend.shape == (len(pairs),)
    assert bend.min() == pytest.approx(0.05) and bend.max() <= 1.0
    assert abs(xe[np.argmin(bend)] - 7.0) < 1
    far = np.minimum(np.abs(xe - 3), np.abs(xe - 7)) > 2  # 2 passes reach < 2 grid columns
    assert far.sum() > 0
    np.testing.assert_allclose(bend[far], 1.0, atol=1e-12)
    np.testing.assert_array_equal(shear, shear0)  # shear is not affected by region
    with pytest.raises(ValueError, match="region"):
        md.learn_stiffness(v, f, poses, region=-1)
    with pytest.raises(ValueError, match="region"):
        md.learn_stiffness(v, f, poses, region=2, anisotropic=True)
