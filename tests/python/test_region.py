"""Region of interest (paper Sec. 7)."""

import numpy as np
import pytest
from conftest import affine, rotation

import matdeform as md
from matdeform import shapes


@pytest.fixture
def tube_and_region():
    v, f = shapes.tube(length=8.0, radius=0.5, n_around=10, n_along=40)
    xc = v[f].mean(axis=1)[:, 0]
    region = np.flatnonzero((xc > 2.0) & (xc < 6.0))
    ring = lambda x0: np.flatnonzero(np.abs(xc - x0) < 0.1)  # noqa: E731
    return v, f, region, ring(2.6), ring(5.4)


def _submesh(v, f, region):
    """(vs, fs, inside vertices, remap, face map, boundary vertices) of a region."""
    inside_v = np.unique(f[region])
    remap = -np.ones(len(v), dtype=int)
    remap[inside_v] = np.arange(len(inside_v))
    fmap = -np.ones(len(f), dtype=int)
    fmap[region] = np.arange(len(region))
    outside_faces = np.setdiff1d(np.arange(len(f)), region)
    boundary = np.intersect1d(inside_v, np.unique(f[outside_faces]))
    return v[inside_v], remap[f[region]], inside_v, remap, fmap, boundary


def test_outside_untouched_boundary_at_rest_inside_matches_submesh(tube_and_region):
    v, f, region, a0, a1 = tube_and_region
    T = np.stack([np.eye(4), affine(rotation([0, 0, 1], 0.6), [0.0, 0.3, 0.0])])
    d = md.MaterialDeformer(v, f, [a0, a1], region=region)
    X = d.deform(T)
    vs, fs, inside_v, remap, fmap, boundary = _submesh(v, f, region)
    outside_v = np.setdiff1d(np.arange(len(v)), inside_v)
    assert np.array_equal(X[outside_v], v[outside_v])  # bit for bit
    assert len(boundary) > 0
    np.testing.assert_array_equal(X[boundary], v[boundary])
    # Reference: the extracted sub-mesh with its boundary pinned at rest and the anchors'
    # vertices pinned to their transforms.
    anchors = [fmap[a0], fmap[a1]]
    av = [np.unique(fs[a]) for a in anchors]
    pins = np.concatenate([av[0], av[1], remap[boundary]])
    pos = np.vstack(
        [
            vs[av[0]] @ T[0, :3, :3].T + T[0, :3, 3],
            vs[av[1]] @ T[1, :3, :3].T + T[1, :3, 3],
            vs[remap[boundary]],
        ]
    )
    ref = md.MaterialDeformer(vs, fs, anchors, pinned=pins).deform(T, pinned_positions=pos)
    np.testing.assert_allclose(X[inside_v], ref, atol=1e-9)
    assert np.abs(X[inside_v] - v[inside_v]).max() > 0.1  # it did deform


def test_region_rotation_only_mode(tube_and_region):
    v, f, region, a0, a1 = tube_and_region
    d = md.MaterialDeformer(v, f, [a0, a1], region=region)
    T = np.stack([np.eye(3), rotation([0, 1, 0], 0.5)])
    X = d.deform(T)
    vs, fs, inside_v, remap, fmap, boundary = _submesh(v, f, region)
    outside_v = np.setdiff1d(np.arange(len(v)), inside_v)
    assert np.array_equal(X[outside_v], v[outside_v])
    np.testing.assert_allclose(d.weights[np.setdiff1d(np.arange(len(f)), region)], 0.0)
    # Inside: the sub-mesh with only its boundary pinned, at rest (3x3: no anchor vertex fixed).
    ref = md.MaterialDeformer(vs, fs, [fmap[a0], fmap[a1]], pinned=remap[boundary])
    np.testing.assert_allclose(X[inside_v], ref.deform(T, pinned_positions=v[boundary]), atol=1e-9)
    assert np.abs(X[inside_v] - v[inside_v]).max() > 0.1


def test_region_errors(tube_and_region):
    v, f, region, a0, a1 = tube_and_region
    outside = np.setdiff1d(np.arange(len(f)), region)[:2]
    with pytest.raises(ValueError, match="outside the region"):
        md.MaterialDeformer(v, f, [a0, outside], region=region)
    with pytest.raises(ValueError, match="region: expected at least one face"):
        md.MaterialDeformer(v, f, [a0], region=np.array([], dtype=int))
    with pytest.raises(ValueError, match="region: indices must lie in"):
        md.MaterialDeformer(v, f, [a0], region=[len(f)])
    with pytest.raises(ValueError, match="pinned: vertex .* is not part of the region"):
        md.MaterialDeformer(v, f, [a0], region=region, pinned=[0])


def test_thread_count_does_not_change_results():
    # Large enough for the parallel paths: the blend (8192 faces per task) and the threaded
    # back-substitution (from ~400k factor entries, about 15k region faces).
    v, f = shapes.tube(length=8.0, radius=0.5, n_around=64, n_along=400)
    xc = v[f].mean(axis=1)[:, 0]
    region = np.flatnonzero((xc > 1.0) & (xc < 7.0))
    assert len(region) > 30000
    a0, a1 = (np.flatnonzero(np.abs(xc - x0) < 0.02) for x0 in (1.5, 6.5))
    T = np.stack([np.eye(4), affine(1.1 * rotation([0, 0, 1], 0.6), [0.0, 0.3, 0.0])])
    before = md.num_threads()
    X, used = [], []
    try:
        for threads in (1, 2):
            md.set_num_threads(threads)
            d = md.MaterialDeformer(v, f, [a0, a1], region=region)
            X.append(d.deform(T))
            used.append(d._core.substitution_threads)
    finally:
        md.set_num_threads(before)
    assert used == [1, 2]  # the second run did take the threaded path
    np.testing.assert_allclose(X[0], X[1], rtol=0, atol=1e-12)
    assert np.abs(X[0] - v).max() > 0.1
    with pytest.raises(ValueError, match="n: expected an integer >= 1"):
        md.set_num_threads(0)
