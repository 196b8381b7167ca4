import numpy as np
import pytest
from conftest import rotation

import matdeform as md
from matdeform import shapes


def test_dual_edges_closed_tube_counts():
    v, f = shapes.tube(n_around=8, n_along=5)
    pairs, shared = md.dual_edges(f, return_shared=True)
    # Closed manifold: every mesh edge is shared by exactly two faces -> E = 3m/2.
    assert len(pairs) == 3 * len(f) // 2
    assert (pairs[:, 0] < pairs[:, 1]).all()
    assert (np.diff(pairs[:, 0]) >= 0).all()
    for (a, b), (p, q) in zip(pairs, shared, strict=True):
        assert {p, q} <= set(f[a]) and {p, q} <= set(f[b])
    boundary, nonmanifold = md.boundary_and_nonmanifold_edges(f)
    assert len(boundary) == 0 and len(nonmanifold) == 0


def test_deformation_gradients_of_similarity():
    v, f = shapes.tube(n_around=6, n_along=4)
    A = 2.0 * rotation([1, 2, 3], 0.9)
    T = md.deformation_gradients(v, v @ A.T + 1.0, f)
    np.testing.assert_allclose(T, np.broadcast_to(A, T.shape), atol=1e-12)


def test_obj_round_trip(tmp_path):
    v, f = shapes.tube(n_around=5, n_along=3)
    md.write_obj(tmp_path / "t.obj", v, f)
    v2, f2 = md.read_obj(tmp_path / "t.obj")
    np.testing.assert_allclose(v2, v, atol=1e-8)
    np.testing.assert_array_equal(f2, f)


def test_faces_inside_a_vertex_selection():
    # A 3x2 grid of squares, two triangles each; vertex (i, j) is number 4 j + i.
    f = []
    for j in range(2):
        for i in range(3):
            a = 4 * j + i
            f += [[a, a + 1, a + 5], [a, a + 5, a + 4]]
    f = np.array(f)
    # The left two squares' vertices (columns 0-2 of the bottom row and the middle row).
    ids = [0, 1, 2, 4, 5, 6]
    np.testing.assert_array_equal(md.faces_inside(f, ids), [0, 1, 2, 3])
    # Order and repeats do not matter; ids beyond every face are ignored.
    np.testing.assert_array_equal(md.faces_inside(f, [6, 5, 5, 4, 2, 1, 0, 99]), [0, 1, 2, 3])
    # A triangle needs all three: without vertex 5 only face 2 = (1, 2, 6) is left.
    np.testing.assert_array_equal(md.faces_inside(f, [0, 1, 2, 4, 6]), [2])
    np.testing.assert_array_equal(md.faces_inside(f, np.arange(12)), np.arange(12))
    assert md.faces_inside(f, []).dtype == np.int64 and len(md.faces_inside(f, [])) == 0
    with pytest.raises(ValueError, match="vertex_ids"):
        md.faces_inside(f, [-1])


def test_mesh_edges_refuses_negative_indices():
    """A negative id is no vertex: it used to come back as an edge (-5, 0)."""
    with pytest.raises(ValueError, match="faces: indices must be >= 0, got -5"):
        md.mesh_edges([[0, 1, -5]])
    assert md.mesh_edges([[0, 1, 5]]).tolist() == [[0, 1], [0, 5], [1, 5]]
