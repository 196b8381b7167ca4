"""Bad input: a ValueError that names the argument, never a crash."""

import numpy as np
import pytest

import matdeform as md


@pytest.fixture
def mesh(small_tube):
    return small_tube


def test_vertices_shape_and_nan(mesh):
    v, f, lo, hi = mesh
    with pytest.raises(ValueError, match=r"vertices: expected shape \(n,3\)"):
        md.MaterialDeformer(v[:, :2], f, [lo])
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="vertices: contains NaN"):
        md.MaterialDeformer(bad, f, [lo])


def test_faces_dtype_range_and_repeats(mesh):
    v, f, lo, hi = mesh
    with pytest.raises(ValueError, match="faces: expected an integer array"):
        md.MaterialDeformer(v, f.astype(float), [lo])
    with pytest.raises(ValueError, match=r"faces: indices must lie in \[0,"):
        md.MaterialDeformer(v, np.vstack([f, [0, 1, len(v)]]), [lo])
    with pytest.raises(ValueError, match="faces: face 1 repeats a vertex"):
        md.MaterialDeformer(v, np.vstack([f[:1], [4, 4, 5], f[2:]]), [lo])
    with pytest.raises(ValueError, match=r"faces: expected triangles of shape \(m,3\)"):
        md.MaterialDeformer(v, f[:, :2], [lo])
    with pytest.raises(ValueError, match="faces: expected at least one triangle"):
        md.MaterialDeformer(v, np.zeros((0, 3), dtype=int), [lo])


def test_anchor_errors(mesh):
    v, f, lo, hi = mesh
    with pytest.raises(ValueError, match="anchors: expected at least one anchor"):
        md.MaterialDeformer(v, f, [])
    with pytest.raises(ValueError, match=r"anchors\[1\]: anchor has no faces"):
        md.MaterialDeformer(v, f, [lo, np.array([], dtype=int)])
    with pytest.raises(ValueError, match="anchors 0 and 1 overlap"):
        md.MaterialDeformer(v, f, [lo, np.concatenate([hi, lo[:1]])])
    with pytest.raises(ValueError, match=r"anchors\[0\]: indices must lie in"):
        md.MaterialDeformer(v, f, [[len(f)]])
    with pytest.raises(ValueError, match=r"anchors\[0\]: indices must be unique"):
        md.MaterialDeformer(v, f, [[0, 0]])


def test_stiffness_errors(mesh):
    v, f, lo, hi = mesh
    with pytest.raises(ValueError, match=r"shear: expected shape"):
        md.MaterialDeformer(v, f, [lo], shear=np.ones(len(f) - 1))
    with pytest.raises(ValueError, match="shear: stiffness must be > 0"):
        md.MaterialDeformer(v, f, [lo], shear=np.zeros(len(f)))
    with pytest.raises(ValueError, match="shear: contains NaN"):
        md.MaterialDeformer(v, f, [lo], shear=np.full(len(f), np.nan))
    with pytest.raises(
        ValueError, match=r"bend: expected shape \(\d+,\) or \(\d+,3\) per dual edge"
    ):
        md.MaterialDeformer(v, f, [lo], bend=np.ones(3))
    with pytest.raises(ValueError, match="bend: stiffness must be > 0"):
        md.MaterialDeformer(v, f, [lo], bend=-np.ones(len(md.dual_edges(f))))


def test_pinned_errors(mesh):
    v, f, lo, hi = mesh
    with pytest.raises(ValueError, match="pinned: indices must lie in"):
        md.MaterialDeformer(v, f, [lo], pinned=[len(v)])
    with pytest.raises(ValueError, match="pinned: indices must be unique"):
        md.MaterialDeformer(v, f, [lo], pinned=[1, 1])
    d = md.MaterialDeformer(v, f, [lo, hi], pinned=[0, 1])
    with pytest.raises(ValueError, match=r"pinned_positions: expected shape \(2,3\)"):
        d.deform(np.tile(np.eye(3), (2, 1, 1)), pinned_positions=np.zeros((3, 3)))
    d2 = md.MaterialDeformer(v, f, [lo, hi])
    with pytest.raises(ValueError, match="pinned_positions: given, but"):
        d2.deform(np.tile(np.eye(3), (2, 1, 1)), pinned_positions=np.zeros((2, 3)))


def test_transform_errors_leave_deformer_usable(mesh):
    v, f, lo, hi = mesh
    d = md.MaterialDeformer(v, f, [lo, hi])
    with pytest.raises(ValueError, match=r"transforms: expected shape \(2,3,3\) or \(2,4,4\)"):
        d.deform(np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(ValueError, match="transforms: contains NaN"):
        d.deform(np.full((2, 3, 3), np.nan))
    with pytest.raises(ValueError, match="transforms: transform 1 has det"):
        d.deform(np.stack([np.eye(3), np.diag([1.0, 1.0, -1.0])]))
    with pytest.raises(ValueError, match="transforms: transform 0 has det"):
        d.deform(np.stack([np.zeros((3, 3)), np.eye(3)]))
    bad = np.tile(np.eye(4), (2, 1, 1))
    bad[0, 3, 0] = 1.0
    with pytest.raises(ValueError, match="bottom row"):
        d.deform(bad)
    np.testing.assert_allclose(d.deform(np.tile(np.eye(4), (2, 1, 1))), v, atol=1e-10)


def test_core_rejects_bad_input_without_crashing():
    """The compiled layer re-checks: calling it directly with bad data raises, never crashes."""
    from matdeform import _core

    v = np.zeros((3, 3))
    f = np.array([[0, 1, 5]], dtype=np.int32)
    with pytest.raises(ValueError):
        _core.MaterialDeformer(v, f, [[0]], np.ones(1), np.ones(0), None)
    f = np.array([[0, 1, 2]], dtype=np.int32)
    with pytest.raises(ValueError):
        _core.MaterialDeformer(v, f, [[1]], np.ones(1), np.ones(0), None)


def test_transform_determinant_matches_lapack():
    # the validation computes det without LAPACK (see _validate._det3); same values
    from matdeform._validate import _det3

    a = np.random.default_rng(4).normal(size=(7, 3, 3))
    np.testing.assert_allclose(_det3(a), np.linalg.det(a), rtol=1e-12, atol=1e-14)
