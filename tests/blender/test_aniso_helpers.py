"""bpy-free helpers of issue 4 (aniso_map): axes from an Empty, dual edge <-> Blender edge
mapping, learned values to polygons / vertices, choice of shape keys."""

import numpy as np
import pytest
from material_deform import aniso_map as amap
from material_deform import stiffness_map as sm


def test_axes_are_the_rotation_part_in_object_space():
    rng = np.random.default_rng(3)
    q_obj = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    q_obj *= np.sign(np.linalg.det(q_obj))
    q_rel = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    q_rel *= np.sign(np.linalg.det(q_rel))
    m_obj = np.eye(4)
    m_obj[:3, :3] = 2.0 * q_obj  # scaled object
    m_obj[:3, 3] = (1, 2, 3)
    m_emp = np.eye(4)
    m_emp[:3, :3] = q_obj @ q_rel @ np.diag([0.5, 3.0, 1.0])  # non-uniformly scaled Empty
    m_emp[:3, 3] = (-4, 0, 1)
    r = amap.axes_from_matrices(m_obj, m_emp)
    np.testing.assert_allclose(r, q_rel, atol=1e-12)
    m_emp[:3, 0] *= -1  # mirrored Empty: still a proper rotation
    r = amap.axes_from_matrices(m_obj, m_emp)
    assert np.linalg.det(r) == pytest.approx(1.0) and np.allclose(r.T @ r, np.eye(3))
    m_emp[:3, 1] = 0
    with pytest.raises(ValueError, match="degenerate"):
        amap.axes_from_matrices(m_obj, m_emp)


def test_dual_edges_map_to_blender_edges_and_back():
    # quad 0 = triangles 0,1 (diagonal 0-2, no Blender edge), triangle polygon 1 = triangle 2
    tris = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [1, 4], [4, 2]])
    dual = np.array([[0, 1], [0, 2]])
    de = sm.dual_to_mesh_edge(tris, dual, edges)
    assert de.tolist() == [-1, 1]
    vals, has = amap.dual_values_to_edges(np.array([[0.5, 0.2, 0.1], [0.3, 0.4, 0.9]]), de, 6)
    assert has.tolist() == [False, True, False, False, False, False]
    np.testing.assert_allclose(vals[1], [0.3, 0.4, 0.9])
    np.testing.assert_allclose(vals[0], [1, 1, 1])  # no dual edge: fill
    # vertices 1 and 2 touch the only learned edge, the others keep the fill
    vp = amap.edge_paint_to_vertices(np.arange(6.0) / 10, edges, has, 5, fill=-1.0)
    np.testing.assert_allclose(vp, [-1, 0.1, 0.1, -1, -1])
    has[4] = True  # vertex 1 then averages edges 1 and 4
    vp = amap.edge_paint_to_vertices(np.arange(6.0) / 10, edges, has, 5, fill=-1.0)
    np.testing.assert_allclose(vp, [-1, 0.25, 0.1, -1, 0.4])
    # per-triangle -> polygon: geometric mean
    np.testing.assert_allclose(
        amap.triangle_to_polygon_stiffness([0.01, 1.0, 0.5], [0, 0, 1], 2), [0.1, 0.5]
    )


def test_per_axis_bend_inside_polygons_uses_the_polygon_edge_mean():
    tris = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    tri_poly = np.array([0, 0, 1])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [1, 4], [4, 2]])
    loop_edge = np.array([0, 1, 2, 3, 4, 5, 1])  # quad loops 0..3, triangle loops 4..6
    loop_poly = np.array([0, 0, 0, 0, 1, 1, 1])
    phi3 = np.array([[1, 2, 3], [7, 8, 9], [1, 2, 3], [1, 2, 3], [5, 5, 5], [5, 5, 5.0]])
    out = amap.dual_edge_bend_axes(
        tris, np.array([[0, 1], [0, 2]]), tri_poly, edges, phi3, loop_edge, loop_poly, 2
    )
    np.testing.assert_allclose(out[0], [2.5, 3.5, 4.5])  # quad diagonal: mean of its 4 edges
    np.testing.assert_allclose(out[1], [7, 8, 9])  # across the shared Blender edge 1


def test_learn_key_names_skip_basis_muted_own_and_filter():
    keys = [
        ("Basis", False, True),
        ("Walk 1", False, False),
        ("walk 2", True, False),  # muted: not selected
        ("Run", False, False),
        ("Material Deform", False, False),
        ("MD Bake 0001", False, False),
    ]
    assert amap.learn_key_names(keys) == ["Walk 1", "Run"]
    assert amap.learn_key_names(keys, " WALK ") == ["Walk 1"]
    assert amap.learn_key_names(keys, "jump") == []
    assert amap.learn_key_names(keys, output="Run") == ["Walk 1"]  # a renamed output key
    assert amap.axis_group_names("Stiffness") == ("Stiffness X", "Stiffness Y", "Stiffness Z")
