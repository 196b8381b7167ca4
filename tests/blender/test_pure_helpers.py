"""bpy-free helpers of the add-on (stiffness mapping, anchor maths)."""

import numpy as np
import pytest
from material_deform import anchor_math as am
from material_deform import stiffness_map as sm


def test_paint_to_stiffness_log_scale():
    s = sm.paint_to_stiffness([0.0, 0.5, 1.0, -1.0, 2.0], span=3.0)
    np.testing.assert_allclose(s, [1e-3, 10**-1.5, 1.0, 1e-3, 1.0], rtol=1e-12)
    assert sm.stiffness_range(4.0) == (1e-4, 1.0)
    np.testing.assert_allclose(sm.stiffness_to_paint(s[:3], 3.0), [0, 0.5, 1], atol=1e-12)


def test_dual_edge_bend_inside_polygon_and_across_edges():
    # quad 0 (tris 0,1) next to triangle polygon 1 (tri 2), sharing edge (1,2)
    tris = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    tri_poly = np.array([0, 0, 1])
    psi = np.array([2.0, 8.0])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [1, 4], [4, 2]])
    phi = np.array([1, 7.0, 1, 1, 1, 1])
    dual = np.array([[0, 1], [0, 2]])
    np.testing.assert_allclose(sm.dual_edge_bend(tris, dual, tri_poly, psi, edges, phi), [2, 7])


def test_edge_stiffness_is_mean_of_adjacent_faces():
    # two quads sharing edge 1
    loop_vert = np.array([0, 1, 4, 3, 1, 2, 5, 4])
    loop_edge = np.array([0, 1, 2, 3, 4, 5, 6, 1])
    loop_poly = sm.loop_polygon_index([0, 4], [4, 4])
    phi = sm.edge_stiffness(np.array([1.0, 3.0]), loop_edge, loop_poly, 7)
    assert phi[1] == 2.0 and phi[0] == 1.0 and phi[4] == 3.0
    p = sm.face_paint_from_vertex(np.arange(6.0), loop_vert, loop_poly, 2)
    np.testing.assert_allclose(p, [2.0, 3.0])


def test_anchor_transform_is_relative_motion_in_object_space():
    rng = np.random.default_rng(1)
    m_obj = np.eye(4)
    m_obj[:3, :3] = 2 * np.linalg.qr(rng.normal(size=(3, 3)))[0]
    m_obj[:3, 3] = [1, 2, 3]
    bind = np.eye(4)
    bind[:3, 3] = [0.5, 0, 0]
    move = np.eye(4)
    move[:3, 3] = [0, 0, 1]
    t = am.anchor_transform(m_obj, move @ bind, bind)
    p_local = np.array([0.3, -0.2, 0.7, 1])
    # moving the Empty by `move` in world moves a point of the mesh by `move` in world
    np.testing.assert_allclose(m_obj @ t @ p_local, move @ m_obj @ p_local, atol=1e-12)


def test_compaction():
    used, t = am.compact(np.array([[0, 2, 3]]), 5)
    assert used.tolist() == [0, 2, 3] and t.tolist() == [[0, 1, 2]]


def test_pose_transforms_cache_follows_object_and_bind_matrices():
    rng = np.random.default_rng(3)
    m = np.zeros((6, 4, 4))
    m[:, :3, :] = rng.normal(size=(6, 3, 4))
    m[:, 3, 3] = 1
    pose = am.PoseTransforms()
    for m_obj in (m[0], m[0], m[5]):  # repeat (cached inverses), then the object moved
        np.testing.assert_allclose(
            pose(m_obj, m[1:3], m[3:5]), am.anchor_transforms(m_obj, m[1:3], m[3:5]), atol=1e-12
        )
    np.testing.assert_allclose(  # a rebind (new bind matrices) is picked up too
        pose(m[5], m[1:3], m[2:4]), am.anchor_transforms(m[5], m[1:3], m[2:4]), atol=1e-12
    )


def test_affine_inverse_inverts_and_rejects_zero_scale():
    rng = np.random.default_rng(2)
    m = np.zeros((5, 4, 4))
    m[:, :3, :] = rng.normal(size=(5, 3, 4))
    m[:, 3, 3] = 1
    np.testing.assert_allclose(
        am.affine_inverse(m) @ m, np.broadcast_to(np.eye(4), m.shape), atol=1e-9
    )
    flat = m[:2].copy()
    flat[1, :3, 2] = 0.0  # an Empty scaled to zero along one axis
    with pytest.raises(ValueError, match="singular"):
        am.affine_inverse(flat)
    np.testing.assert_allclose(
        am.anchor_transforms(m[0], m[1:3], m[3:5])[1],
        np.linalg.inv(m[0]) @ m[2] @ np.linalg.inv(m[4]) @ m[0],
        atol=1e-9,
    )
