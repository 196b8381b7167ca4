"""MaterialDeformer under random vertex numberings, face orders and corner rotations (issue 11:
the repositioning union-find used to leave vertices behind for some orders)."""

import numpy as np
import pytest
from conftest import affine, rotation
from permutation import Relabelling, assert_permutation_invariant, catalogue

import matdeform as md

MODES = ["(k,4,4)", "(k,3,3)", "pinned", "region", "anisotropic"]
MESHES = catalogue()


def problem(v, f, mode, rng):
    """Inputs in the original numbering: anchors at both ends of the longest extent (the second
    one inside the region for "region"), random stiffness and transforms."""
    m = len(f)
    axis = int(np.argmax(np.ptp(v, axis=0)))
    order = np.argsort(v[f, axis].sum(axis=1), kind="stable")
    size = max(1, m // 25)
    p = dict(region=None, pinned=None, pinned_positions=None)
    second = m - size
    if mode == "region":
        keep = (7 * m + 9) // 10
        p["region"] = order[:keep]
        second = keep // 2
    p["anchors"] = [order[:size], order[second : second + size]]
    p["shear"] = rng.uniform(0.3, 3.0, m)
    e = len(md.dual_edges(f))
    p["bend"] = rng.uniform(0.3, 3.0, (e, 3) if mode == "anisotropic" else e)
    p["axes"] = rotation([1, 2, 0.5], 0.7) if mode == "anisotropic" else None
    diag = np.linalg.norm(np.ptp(v, axis=0))
    T = []
    for _ in p["anchors"]:
        R = (0.8 + 0.4 * rng.uniform()) * rotation(rng.normal(size=3), rng.uniform(-2.5, 2.5))
        T.append(affine(R, diag * rng.uniform(-1, 1, 3)))
    p["transforms"] = np.array(T) if mode != "(k,3,3)" else np.array(T)[:, :3, :3]
    if mode == "pinned":
        free = np.setdiff1d(np.arange(len(v)), f[np.concatenate(p["anchors"])].ravel())
        p["pinned"] = rng.permutation(free)[:3]
        offset = 0.1 * diag * rng.uniform(-1, 1, (len(p["pinned"]), 3))
        p["pinned_positions"] = v[p["pinned"]] + offset
    return p


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name,v,f", MESHES, ids=[m[0] for m in MESHES])
def test_material_deformer_is_invariant_to_relabelling(name, v, f, mode):
    if mode == "region" and len(f) < 8:
        pytest.skip("too few faces for a region with an anchor inside")
    p = problem(v, f, mode, np.random.default_rng(11))

    def solve(r):
        d = md.MaterialDeformer(
            r.vertices,
            r.faces,
            r.anchors(p["anchors"]),
            shear=r.per_face(p["shear"]),
            bend=r.per_dual_edge(p["bend"]),
            pinned=r.vertex_ids(p["pinned"]),
            region=r.face_ids(p["region"]),
            axes=p["axes"],
        )
        return d.deform(p["transforms"], p["pinned_positions"])

    trials = 2 if name == "cat" else 8
    assert_permutation_invariant(solve, v, f, seed=5, trials=trials, label=f"{name} {mode}")


@pytest.mark.parametrize("faces", [[[3, 0, 2], [3, 1, 0]], [[0, 2, 3], [0, 3, 1]]])
def test_two_triangles_follow_their_only_anchor(faces):
    """The issue's repro: both orders move every vertex by the anchor's translation."""
    v = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0.0]])
    T = np.eye(4)
    T[0, 3] = 1.0
    X = md.MaterialDeformer(v, np.array(faces), [[0]]).deform(T[None])
    np.testing.assert_allclose(X - v, [[1, 0, 0]] * 4, atol=1e-12)


def test_helper_detects_an_order_dependent_solver():
    """The check itself can fail: a 'solver' that moves the first vertex only is caught."""
    v, f = catalogue(include_cat=False)[2][1:]

    def solve(r):
        x = r.vertices.copy()
        x[0] += 1.0
        return x

    with pytest.raises(AssertionError, match="changes the result"):
        assert_permutation_invariant(solve, v, f, seed=1, trials=2)


LEARN = [m for m in MESHES if m[0] in ("grid", "tube", "cat")]


@pytest.mark.parametrize("frame", ["rest", "world"])
@pytest.mark.parametrize("name,v,f", LEARN, ids=[m[0] for m in LEARN])
def test_learning_is_invariant_to_relabelling(name, v, f, frame):
    """Learned distortions per dual edge and face; poses turned by nearly pi, where the world
    frame's log differences choose between representatives of the logs."""
    rng = np.random.default_rng(2)
    diag = np.linalg.norm(np.ptp(v, axis=0))
    poses = []
    for s in range(3):
        R = rotation(rng.normal(size=3), np.pi - 0.05 * s)
        a = 0.4 * (v[:, 0] - v[:, 0].min()) / np.ptp(v[:, 0])  # bend about z along x
        c, sn = np.cos(a), np.sin(a)
        p = np.stack([c * v[:, 0] - sn * v[:, 1], sn * v[:, 0] + c * v[:, 1], v[:, 2]], 1) @ R.T
        poses.append(p + rng.normal(scale=1e-3 * diag, size=v.shape))
    ref = md.learn_distortions(v, f, poses, anisotropic=True, frame=frame)
    spread = md.rotation_spread(v, f, poses, 2)
    for t in range(2 if name == "cat" else 4):
        r = Relabelling(v, f, np.random.default_rng(t))
        p2 = [r.per_vertex(p) for p in poses]
        bend, shear = md.learn_distortions(r.vertices, r.faces, p2, anisotropic=True, frame=frame)
        np.testing.assert_allclose(r.dual_edges_to_original(bend), ref[0], atol=1e-9)
        np.testing.assert_allclose(r.faces_to_original(shear), ref[1], atol=1e-9)
        s2 = md.rotation_spread(r.vertices, r.faces, p2, 2)
        np.testing.assert_allclose(r.faces_to_original(s2), spread, atol=1e-9)
