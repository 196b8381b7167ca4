"""EdgeDeformer bad input: a ValueError naming the argument (and the expected shape), never a
crash, and a failed call changes nothing."""

import numpy as np
import pytest

import matdeform as md
from matdeform import _core


@pytest.fixture
def sheet():
    j, i = np.mgrid[0:6, 0:6]
    v = np.stack([i.ravel(), j.ravel(), np.zeros(36)], 1).astype(float)
    a = (np.arange(5)[:, None] * 6 + np.arange(5)[None, :]).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + 7], 1), np.stack([a, a + 7, a + 6], 1)])
    return v, f, np.array([0, 5, 30, 35])


def test_constructor_arguments(sheet):
    v, f, c = sheet
    with pytest.raises(ValueError, match=r"vertices: expected shape \(n,3\)"):
        md.EdgeDeformer(v[:, :2], f, c)
    bad = v.copy()
    bad[4, 2] = np.inf
    with pytest.raises(ValueError, match="vertices: contains NaN"):
        md.EdgeDeformer(bad, f, c)
    with pytest.raises(ValueError, match=r"faces: indices must lie in \[0, 36\)"):
        md.EdgeDeformer(v, np.vstack([f, [0, 1, 36]]), c)
    with pytest.raises(ValueError, match=r"faces: indices must be >= 0, got -1"):
        md.EdgeDeformer(v, np.vstack([f, [0, -1, 2]]), c)
    with pytest.raises(ValueError, match="faces: face 3 repeats a vertex"):
        md.EdgeDeformer(v, np.vstack([f[:3], [2, 2, 3]]), c)
    with pytest.raises(ValueError, match="constrained: indices must lie in"):
        md.EdgeDeformer(v, f, [0, 36])
    with pytest.raises(ValueError, match="constrained: indices must lie in"):
        md.EdgeDeformer(v, f, [-1, 3])
    with pytest.raises(ValueError, match="constrained: indices must be unique"):
        md.EdgeDeformer(v, f, [0, 3, 3])
    with pytest.raises(ValueError, match="constrained: expected at least one vertex"):
        md.EdgeDeformer(v, f, np.array([], dtype=int))
    with pytest.raises(ValueError, match="constrained: expected an integer array"):
        md.EdgeDeformer(v, f, [0.5, 2.0])
    with pytest.raises(ValueError, match=r"stretch: expected a finite value in \[0, inf\)"):
        md.EdgeDeformer(v, f, c, stretch=-1e-4)
    with pytest.raises(ValueError, match="stretch: expected a finite value"):
        md.EdgeDeformer(v, f, c, stretch=np.nan)
    with pytest.raises(ValueError, match=r"bend: expected a finite value in \(0, inf\)"):
        md.EdgeDeformer(v, f, c, bend=0.0)
    for name, lo in (("stretch", r"\[0"), ("bend", r"\(0")):
        msg = rf"{name}: expected a finite value in {lo}, inf\)"
        for bad in (None, "stiff", "1", [1.0], True, np.nan, -np.inf, np.inf, -1.0):
            with pytest.raises(ValueError, match=msg):
                md.EdgeDeformer(v, f, c, **{name: bad})
    # only the products reach the matrix: each alone may be huge, not stiffness x weight
    e = len(md.mesh_edges(f))
    md.EdgeDeformer(v, f, c, stretch=1e300, bend=1e300)
    with pytest.raises(ValueError, match="stretch, bend, edge_weight: their products exceed 1e300"):
        md.EdgeDeformer(v, f, c, stretch=1e300, edge_weight=np.full(e, 10.0))
    with pytest.raises(ValueError, match="their products exceed 1e300"):
        md.EdgeDeformer(v, f, c, bend=1e200, edge_weight=np.full(e, 1e101))
    with pytest.raises(ValueError, match="vertices: the mesh is 5e.155 across.*rescale the mesh"):
        md.EdgeDeformer(v * 1e155, f, c)
    with pytest.raises(ValueError, match="vertices: the mesh is 5e-200 across.*rescale the mesh"):
        md.EdgeDeformer(v * 1e-200, f, c)
    with pytest.raises(ValueError, match=rf"edge_weight: expected shape \({e},\)"):
        md.EdgeDeformer(v, f, c, edge_weight=np.ones(e + 1))
    with pytest.raises(ValueError, match="edge_weight: stiffness must be > 0"):
        md.EdgeDeformer(v, f, c, edge_weight=np.zeros(e))
    with pytest.raises(ValueError, match="edge_weight: contains NaN"):
        md.EdgeDeformer(v, f, c, edge_weight=np.full(e, np.nan))
    with pytest.raises(ValueError, match=r"direction: expected shape \(36,3\)"):
        md.EdgeDeformer(v, f, c, direction=np.ones((35, 3)))
    with pytest.raises(ValueError, match="direction: contains NaN"):
        md.EdgeDeformer(v, f, c, direction=np.full((36, 3), np.nan))


def test_undetermined_system_is_refused(sheet):
    v, f, _ = sheet
    # stretch 0 on a flat sheet: one constrained vertex leaves the sheet free to tilt
    with pytest.raises(ValueError, match="singular system"):
        md.EdgeDeformer(v, f, [14], stretch=0.0)
    # with two the sheet can still turn about the line through them
    with pytest.raises(ValueError, match="singular system"):
        md.EdgeDeformer(v, f, [0, 35], stretch=0.0)
    md.EdgeDeformer(v, f, [0, 5, 35], stretch=0.0)  # three, not in a line: determined


def test_solve_arguments_and_failed_calls_change_nothing(sheet):
    v, f, c = sheet
    d = md.EdgeDeformer(v, f, c, stretch=0.1)
    pos = v[c] + [0.0, 0.0, 1.0]
    x = d.solve(pos, iterations=3, tol=0)
    bad_calls = [
        (dict(constrained_positions=np.zeros((3, 3))), r"constrained_positions: expected shape"),
        (dict(constrained_positions=np.full((4, 3), np.nan)), "constrained_positions: contains"),
        (dict(tol=np.inf), "tol: expected a finite value"),
        (dict(gravity=(0.0, np.nan, 0.0)), "gravity: contains NaN"),
        (dict(gravity=(0.0, -9.8)), r"gravity: expected shape \(3,\)"),
        (dict(gravity=None), r"gravity: expected shape \(3,\)"),
        (dict(gravity="down"), "gravity: expected a float array"),
        (dict(initial=np.zeros((35, 3))), r"initial: expected shape \(36,3\)"),
        (dict(initial=np.full((36, 3), np.inf)), "initial: contains NaN"),
        (dict(constrained_positions=pos * 1e155), "constrained_positions: lies beyond 1e50 mesh"),
        (dict(constrained_positions=pos + 1e200), "constrained_positions: lies beyond"),
        (dict(initial=v * 1e200), "initial: lies beyond 1e50 mesh sizes.*rescale the mesh"),
    ]
    # counts: a C int, so at most 2**31 - 1 (not pybind's TypeError beyond)
    its = r"iterations: expected an integer in \[1, 2147483647\]"
    for bad in (0, -3, 2**31, 2**63, np.int64(2**40), 2.5, 5.0, True, None, "5", np.nan):
        bad_calls.append((dict(iterations=bad), its))
    # reals: a finite number in range, not None, a string, NaN or out of range
    for name, hi in (("tol", None), ("p_stretch", 1.0), ("p_bend", 1.0)):
        rng = r"\[0, " + (r"inf\)" if hi is None else r"1\]")
        for bad in (None, "0.5", [0.5], False, np.nan, -1.0, 1.5 if hi else -np.inf):
            bad_calls.append((dict({name: bad}), rf"{name}: expected a finite value in {rng}"))
    for bad in (None, "1", 0.0, -0.5, 1.5, np.nan, np.inf):
        bad_calls.append((dict(relaxation=bad), r"relaxation: expected a finite value in \(0, 1\]"))
    for kw, msg in bad_calls:
        args = dict(constrained_positions=pos, iterations=5, tol=0)
        args.update(kw)
        with pytest.raises(ValueError, match=msg):
            d.solve(**args)
        assert d.last_iterations == 3
    move = d.last_move
    # the largest count passes validation (and tol stops it as soon as the moves give a rate,
    # after at most 6 iterations, or at a fixed point to round-off)
    d.solve(pos, iterations=2**31 - 1, tol=1e300)
    assert 1 <= d.last_iterations <= 6 and d.last_converged
    d.solve(pos, iterations=3, tol=0)
    # gravity far too strong for the stiffness: the iterate leaves the representable range
    with pytest.raises(RuntimeError, match="left the range the solver represents.*weaken gravity"):
        d.solve(pos, iterations=5, tol=0, gravity=(0.0, 0.0, -1e300))
    assert d.last_iterations == 3 and d.last_move == move
    np.testing.assert_array_equal(d.solve(pos, iterations=3, tol=0), x)


def test_core_rechecks_indices_without_crashing(sheet):
    """The compiled layer validates on its own: bad data straight into _core raises."""
    v, f, c = sheet
    with pytest.raises(ValueError):
        _core.EdgeDeformer(v, f.astype(np.int32), [0, 99], 1e-4, 1.0, None, None)
    with pytest.raises(ValueError):
        _core.EdgeDeformer(v, f.astype(np.int32), [0, -7], 1e-4, 1.0, None, None)
    bad = f.astype(np.int32).copy()
    bad[2, 1] = 1000
    with pytest.raises(ValueError):
        _core.EdgeDeformer(v, bad, [0], 1e-4, 1.0, None, None)
    with pytest.raises(ValueError):
        _core.EdgeDeformer(v, f.astype(np.int32), [0], -1.0, 1.0, None, None)
    with pytest.raises(ValueError):
        _core.EdgeDeformer(v, f.astype(np.int32), [0], 1e-4, 1.0, np.ones(3), None)
    d = _core.EdgeDeformer(v, f.astype(np.int32), c.tolist(), 1e-4, 1.0, None, None)
    with pytest.raises(ValueError):
        d.solve(np.zeros((2, 3)), 3, 0.0, 1.0, 1.0, np.zeros(3), None)
    with pytest.raises(ValueError):
        d.solve(v[c], 3, 0.0, 2.0, 1.0, np.zeros(3), None)
    with pytest.raises(ValueError):
        d.solve(v[c], 3, 0.0, 1.0, 1.0, np.zeros(3), np.zeros((4, 3)))
    with pytest.raises(ValueError):
        d.solve(v[c], 3, 0.0, 1.0, 1.0, np.zeros(3), None, 0.0)


def test_mesh_edges_validation():
    with pytest.raises(ValueError, match=r"faces: expected triangles of shape \(m,3\)"):
        md.mesh_edges(np.zeros((4, 2), dtype=int))
    with pytest.raises(ValueError, match="faces: expected an integer array"):
        md.mesh_edges(np.zeros((4, 3)))
