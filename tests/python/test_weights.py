"""md.harmonic_weights (paper Eq. 1) against closed forms."""

import numpy as np
import pytest

import matdeform as md


def strip(n):
    """A one-square-wide strip of n squares along x: 2n faces whose dual graph is a path, in
    face order 0, 1, ..., 2n - 1 from one end to the other."""
    v = np.array([[i, j, 0.0] for i in range(n + 1) for j in (0, 1)])
    f = []
    for i in range(n):
        a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
        f += [[a, c, b], [b, c, d]]
    return v, np.array(f)


def test_path_graph_is_series_resistance():
    v, f = strip(8)
    m = len(f)
    pairs = md.dual_edges(f)
    np.testing.assert_array_equal(pairs, np.stack([np.arange(m - 1), np.arange(1, m)], 1))
    # Uniform bending: linear along the path.
    W = md.harmonic_weights(f, [[0], [m - 1]])
    t = np.arange(m) / (m - 1)
    np.testing.assert_allclose(W, np.stack([1 - t, t], 1), atol=1e-12)
    # Any bending: weight of the first end = resistance (sum of 1/phi) to the far end / total.
    phi = np.random.default_rng(0).uniform(0.05, 5.0, m - 1)
    W = md.harmonic_weights(f, [[0], [m - 1]], bend=phi)
    r = np.concatenate([np.cumsum((1 / phi)[::-1])[::-1], [0.0]])
    np.testing.assert_allclose(W[:, 0], r / r[0], atol=1e-12)
    np.testing.assert_allclose(W[:, 1], 1 - r / r[0], atol=1e-12)


def test_three_anchors_on_a_path_interpolate_between_neighbours_only():
    v, f = strip(6)
    m = len(f)
    W = md.harmonic_weights(f, [[0], [5], [m - 1]])
    np.testing.assert_allclose(
        W[:6], np.stack([1 - np.arange(6) / 5, np.arange(6) / 5, 0 * W[:6, 0]], 1), atol=1e-12
    )
    t = (np.arange(5, m) - 5) / (m - 1 - 5)
    np.testing.assert_allclose(W[5:], np.stack([0 * t, 1 - t, t], 1), atol=1e-12)


def test_unreached_component_gets_zero_rows_and_bad_bend_is_rejected():
    v, f = strip(3)
    f2 = np.vstack([f, f + len(v)])
    W = md.harmonic_weights(f2, [[0], [5]])
    np.testing.assert_array_equal(W[6:], 0.0)
    np.testing.assert_allclose(W[:6].sum(axis=1), 1.0, atol=1e-14)
    with pytest.raises(ValueError, match="bend"):
        md.harmonic_weights(f, [[0]], bend=np.zeros(len(f) - 1))
