"""Stiffness conversions (paper Sec. 4.1) against their closed forms."""

import numpy as np
import pytest
import reference

import matdeform as md
from matdeform import shapes


@pytest.fixture
def tube():
    return shapes.tube(n_around=6, n_along=5)


def test_bend_from_shear_is_the_mean_over_the_two_faces(tube):
    v, f = tube
    shear = np.random.default_rng(1).uniform(0.1, 5.0, len(f))
    pairs = reference.dual_pairs(f)
    np.testing.assert_allclose(
        md.bend_from_shear(f, shear), 0.5 * (shear[pairs[:, 0]] + shear[pairs[:, 1]]), rtol=1e-15
    )


def test_bend_from_shear_on_two_triangles():
    f = np.array([[0, 1, 2], [2, 1, 3]])
    np.testing.assert_array_equal(md.bend_from_shear(f, [1.0, 3.0]), [2.0])


def test_bend_from_vertex_is_the_mean_over_the_shared_edge(tube):
    v, f = tube
    s = np.random.default_rng(2).uniform(0.1, 5.0, len(v))
    pairs = reference.dual_pairs(f)
    shared = np.array([np.intersect1d(f[a], f[b]) for a, b in pairs])
    np.testing.assert_allclose(md.bend_from_vertex(f, s), s[shared].mean(axis=1), rtol=1e-15)


def test_shear_from_vertex_is_the_mean_over_the_three_vertices(tube):
    v, f = tube
    s = np.random.default_rng(3).uniform(0.1, 5.0, len(v))
    np.testing.assert_allclose(md.shear_from_vertex(f, s), s[f].mean(axis=1), rtol=1e-15)
    # One triangle, by hand; vertices beyond the faces' are allowed and ignored.
    np.testing.assert_allclose(md.shear_from_vertex([[2, 0, 1]], [1.0, 2.0, 6.0, 100.0]), [3.0])
    with pytest.raises(ValueError, match="stiffness: expected shape"):
        md.shear_from_vertex(f, s[:-3])
