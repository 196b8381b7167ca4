import numpy as np
import pytest
import scipy.linalg as sla
from conftest import rotation

import matdeform as md


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.5, 3.0, np.pi - 1e-9, np.pi])
def test_log_exp_round_trip(angle):
    R = 2.5 * rotation([0.3, -1.0, 2.0], angle)
    ls, r = md.transform_log(R)
    assert np.isfinite(r).all()
    np.testing.assert_allclose(ls, np.log(2.5) * np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(r), angle, atol=1e-7)
    np.testing.assert_allclose(md.transform_exp(ls, r), R, atol=1e-12)


def test_blend_matches_scipy_logm_expm_for_similarities():
    T = np.stack([1.5 * rotation([1, 0, 0], 0.4), 0.7 * rotation([0, 1, 1], 2.0), np.eye(3)])
    W = np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [0.0, 0.5, 0.5]])
    out = md.blend_transforms(T, W)
    logs = [sla.logm(t).real for t in T]
    for i, row in enumerate(W):
        np.testing.assert_allclose(
            out[i], sla.expm(sum(w * L for w, L in zip(row, logs, strict=True))), atol=1e-11
        )


def test_general_matrix_without_real_log_round_trips():
    M = np.diag([-1.0, -2.0, 1.0])  # det > 0, no real matrix log exists
    np.testing.assert_allclose(md.transform_exp(*md.transform_log(M)), M, atol=1e-12)
    S, R = md.polar_decompose(M)
    np.testing.assert_allclose(S @ R, M, atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0 and np.all(np.linalg.eigvalsh(S) > 0)


def test_negative_determinant_is_rejected():
    with pytest.raises(ValueError, match="det"):
        md.transform_log(np.diag([1.0, 1.0, -1.0]))
