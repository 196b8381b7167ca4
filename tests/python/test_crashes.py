"""Issue 11, items 2-3: indices from Python never crash the interpreter or read garbage. Each
case runs in a fresh interpreter, so a segfault fails its test instead of ending pytest."""

import pytest
from isolated import outcome

BIG = 2**31 - 10  # far outside any array: a read there segfaulted
SETUP = f"""
P = np.array([[0, {BIG}]], np.int32)
F = np.array([[0, 1, {BIG}]], np.int32)
V = np.eye(3)
tri = np.array([[0, 1, 2], [0, 2, 3]])
quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
neg = np.array([[0, 1, -1], [0, 1, 2]])
"""

CORE = {
    "face_components": "_core.face_components(2, P)",
    "harmonic_weights": "_core.harmonic_weights(2, P, np.ones(1), [[0]])",
    "bend_from_shear": "_core.bend_from_shear(P, np.ones(2))",
    "bend_from_vertex": "_core.bend_from_vertex(P, P, np.ones(2))",
    "shear_from_vertex": "_core.shear_from_vertex(F, np.ones(3))",
    "deformation_gradients": "_core.deformation_gradients(V, V, F)",
    "double_areas": "_core.double_areas(V, F)",
    "dual_edges negative": "_core.dual_edges(np.array([[0, 1, -5]], np.int32))",
    "smooth_distortions": "_core.smooth_distortions(np.ones((1, 1)), np.ones(2), P, 1)",
    "learn_distortions": "_core.learn_distortions(V, np.array([[0,1,2]], np.int32), P, [V],"
    " False, 'rest')",
    "rotation_spread": "_core.rotation_spread(V, np.array([[0,1,2]], np.int32), P, [V], 2)",
    "MaterialDeformer faces": "_core.MaterialDeformer(V, F, [[0]], np.ones(1), np.ones((0, 1)))",
    "MaterialDeformer anchors": "_core.MaterialDeformer(V, np.array([[0,1,2]], np.int32),"
    f" [[{BIG}]], np.ones(1), np.ones((0, 1)))",
    "MaterialDeformer pinned": "_core.MaterialDeformer(V, np.array([[0,1,2]], np.int32), [[0]],"
    f" np.ones(1), np.ones((0, 1)), [{BIG}])",
    "MaterialDeformer region": "_core.MaterialDeformer(V, np.array([[0,1,2]], np.int32), [[0]],"
    f" np.ones(1), np.ones((0, 1)), None, [0, {BIG}])",
    "deform NaN pinned_positions": "_core.MaterialDeformer(quad, tri.astype(np.int32), [[0]],"
    " np.ones(2), np.ones((1, 1)), [2]).deform(np.eye(4)[None], np.full((1, 3), np.nan))",
}

PUBLIC = {
    "shear_from_vertex large negative": f"md.shear_from_vertex([[0, 1, -{BIG}], [0, 1, 2]],"
    " np.ones(3))",
    "bend_from_vertex large negative": f"md.bend_from_vertex([[0, 1, -{BIG}], [0, 1, 2]],"
    " np.ones(3))",
    "shear_from_vertex -1": "md.shear_from_vertex(neg, np.ones(3))",
    "bend_from_vertex -1": "md.bend_from_vertex(neg, np.ones(3))",
    "dual_edges": "md.dual_edges(neg)",
    "boundary_and_nonmanifold_edges": "md.boundary_and_nonmanifold_edges(neg)",
    "faces_inside faces": "md.faces_inside(neg, [0, 1])",
    "faces_inside vertex_ids": "md.faces_inside(tri, [0, -1])",
    "face_components": "md.face_components(neg)",
    "bend_from_shear": "md.bend_from_shear(neg, np.ones(2))",
    "harmonic_weights": "md.harmonic_weights(neg, [[0]])",
    "smooth_distortions": "md.smooth_distortions(neg, np.ones(0), np.ones(2), 1)",
    "deformation_gradients": "md.deformation_gradients(quad, quad, neg)",
    "learn_distortions": "md.learn_distortions(quad, neg, [quad])",
    "rotation_spread": "md.rotation_spread(quad, neg, [quad], 1)",
    "learn_stiffness": "md.learn_stiffness(quad, neg, [quad])",
    "MaterialDeformer faces": "md.MaterialDeformer(quad, neg, [[0]])",
    "MaterialDeformer anchors": "md.MaterialDeformer(quad, tri, [[-1]])",
    "MaterialDeformer pinned": "md.MaterialDeformer(quad, tri, [[0]], pinned=[-1])",
    "MaterialDeformer region": "md.MaterialDeformer(quad, tri, [[0]], region=[0, -2])",
    "deform NaN pinned_positions": "md.MaterialDeformer(quad, tri, [[0]], pinned=[2]).deform("
    "np.eye(4)[None], np.full((1, 3), np.nan))",
}


@pytest.mark.parametrize("call", CORE.values(), ids=CORE.keys())
def test_core_rejects_out_of_range_indices(call):
    assert outcome(call, SETUP).startswith("ValueError")


@pytest.mark.parametrize("call", PUBLIC.values(), ids=PUBLIC.keys())
def test_public_api_rejects_negative_and_out_of_range_indices(call):
    result = outcome(call, SETUP)
    assert result.startswith("ValueError"), result
