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


def _turns(axis, angles, scale=(1.0, 1.0, 1.0)):
    """(N,3,3) turns by each angle about axis, scaled along the turned axes (M = R @ D)."""
    return np.stack([rotation(axis, a) @ np.diag(scale) for a in angles])


def test_unwrap_rotations_follows_a_twist_of_several_turns():
    """0..720 degrees in 25 frames, float32 matrices of a scaled Empty: angle * axis."""
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    angles = np.radians(np.linspace(0, 720, 25))
    frames = _turns(axis, angles, (1.3, 1.0, 0.8)).astype(np.float32)
    v = md.unwrap_rotations(frames)
    assert v.shape == (25, 3) and v.dtype == np.float64
    np.testing.assert_allclose(v, angles[:, None] * axis, atol=2e-6)
    # Backwards, from a start one turn on: the same motion, one turn further.
    back = md.unwrap_rotations(frames[::-1], start=(4 * np.pi + 0.3) * axis)
    np.testing.assert_allclose(back, angles[::-1, None] * axis, atol=2e-6)
    up = md.unwrap_rotations(frames, start=2 * np.pi * axis)
    np.testing.assert_allclose(up, (angles[:, None] + 2 * np.pi) * axis, atol=2e-6)


def test_unwrap_rotations_of_several_sequences():
    """(N,k,3,3) -> (N,k,3): each sequence on its own, start (k,3)."""
    angles = np.radians(np.linspace(0, 600, 21))
    frames = np.stack([_turns([0, 0, 1], angles), _turns([1, 1, 0], -angles)], axis=1)
    v = md.unwrap_rotations(frames, start=[[0, 0, 0], [0, 0, 0]])
    assert v.shape == (21, 2, 3)
    np.testing.assert_allclose(v[:, 0], angles[:, None] * [0, 0, 1], atol=1e-9)
    diagonal = np.array([1, 1, 0]) / np.sqrt(2)
    np.testing.assert_allclose(v[:, 1], -angles[:, None] * diagonal, atol=1e-9)
    for a in range(2):
        np.testing.assert_array_equal(md.unwrap_rotations(frames[:, a]), v[:, a])


def test_unwrap_rotations_accumulates_uneven_steps_about_one_axis():
    """Steps of -60..90 degrees about one axis (a turn back and forth, 200 frames): the vectors
    are the running sum of the steps times the axis, however many turns that makes."""
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angles = np.concatenate([[0.0], np.cumsum(rng.uniform(np.radians(-60), np.radians(90), 200))])
    v = md.unwrap_rotations(_turns(axis, angles))
    np.testing.assert_allclose(v, angles[:, None] * axis, atol=1e-9)
    assert angles.max() > 8 * np.pi  # several turns


def test_unwrap_rotations_picks_the_log_nearest_the_previous_vector():
    """Property on a motion about a drifting axis (steps up to 60 degrees): every vector is a
    log of its frame's rotation, and the other logs on its axis (a turn more or less) are
    farther from the previous vector."""
    rng = np.random.default_rng(4)
    R, axis = [np.eye(3)], np.array([0.0, 0.0, 1.0])
    for _ in range(200):
        axis = axis + rng.normal(scale=0.1, size=3)
        axis /= np.linalg.norm(axis)
        R.append(rotation(axis, rng.uniform(0, np.radians(60))) @ R[-1])
    R = np.stack(R)
    v = md.unwrap_rotations(R)
    for t in range(1, len(R)):
        np.testing.assert_allclose(md.transform_exp(np.zeros((3, 3)), v[t]), R[t], atol=1e-9)
        u = v[t] / np.linalg.norm(v[t])
        d = np.linalg.norm(v[t] - v[t - 1])
        for other in (v[t] + 2 * np.pi * u, v[t] - 2 * np.pi * u):
            assert d <= np.linalg.norm(other - v[t - 1]) + 1e-12
    assert np.linalg.norm(v, axis=1).max() > np.pi  # past half a turn somewhere


def test_unwrap_rotations_steps_over_half_a_turn_are_read_as_the_shorter_step():
    """Documented: a 200-degree step is indistinguishable from a -160-degree one."""
    v = md.unwrap_rotations(_turns([0, 0, 1], np.radians([0, 200, 400, 600])))
    np.testing.assert_allclose(v[:, 2], np.radians([0, -160, -320, -480]), atol=1e-12)


def test_unwrap_rotations_keeps_the_axis_through_a_whole_turn():
    """At 360 degrees every axis is a log of the identity; float noise there must not steal
    the turns or tilt the axis (the next frames continue the twist)."""
    angles = np.radians([300, 330, 360, 390, 420])
    frames = _turns([0, 0, 1], angles)
    frames[2] = rotation([1, 0, 0], 3e-7)  # the identity up to float32 noise, about another axis
    v = md.unwrap_rotations(frames, start=np.radians(300) * np.array([0, 0, 1]))
    np.testing.assert_allclose(v, angles[:, None] * [0, 0, 1], atol=1e-6)


@pytest.mark.parametrize(
    "rotations, start, match",
    [
        (np.zeros((4, 3)), None, "rotations: expected shape \\(N,3,3\\) or \\(N,k,3,3\\)"),
        (np.tile(np.eye(3), (2, 1, 1))[:, :2], None, "rotations: expected shape"),
        (np.full((2, 3, 3), np.nan), None, "rotations: contains NaN"),
        (np.stack([np.eye(3), np.diag([1.0, 1, -1])]), None, "rotations: transform 1 has det"),
        (np.zeros((2, 0, 3, 3)), None, "at least one sequence"),
        (np.tile(np.eye(3), (2, 1, 1)), np.zeros(4), "start: expected shape \\(3,\\)"),
        (np.tile(np.eye(3), (2, 2, 1, 1)), np.zeros(3), "start: expected shape \\(2, 3\\)"),
        (np.tile(np.eye(3), (2, 1, 1)), [np.inf, 0, 0], "start: contains NaN"),
        ([["x"]], None, "rotations: expected a float array"),
    ],
)
def test_unwrap_rotations_bad_input(rotations, start, match):
    with pytest.raises(ValueError, match=match):
        md.unwrap_rotations(rotations, start=start)


def test_unwrap_rotations_of_no_frames_is_empty():
    assert md.unwrap_rotations(np.zeros((0, 3, 3))).shape == (0, 3)
    assert md.unwrap_rotations(np.zeros((0, 2, 3, 3))).shape == (0, 2, 3)
