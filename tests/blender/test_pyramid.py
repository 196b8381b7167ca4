"""The pyramid-coordinates method in the add-on: the anchor faces' vertices are the control
vertices, placed by their Empty's full transform; the result after Settle is the numpy library's
on the same inputs; live updates spend a budget of Newton iterations and keep settling; rest,
rigid motions, bad input, the panel and undo."""

import math
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import (
    add_anchor,
    anchor_vertices,
    draw_panel,
    expect_error,
    output,
    rest,
    snapshot,
    triangles,
    tube,
    two_end_anchors,
    update,
)
from material_deform import bake, bridge, handlers, methods, session
from material_deform.core import load
from mathutils import Euler, Matrix, Vector


def pyramid_bar(rings=13, length=4.0):
    obj = tube(rings=rings, length=length)
    obj.material_deform.method = "PYRAMID"
    top, bottom = two_end_anchors(obj, half_length=length / 2)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    return obj, top, bottom


def compute(obj):
    """Float64 positions the add-on computes now, run to convergence (what Settle writes)."""
    return session.compute(obj, bpy.context.scene, budget=None)


def library_result(obj, anchors, tol, scale_weight=0.003, initial=None):
    """What matdeform.PyramidDeformer gives on the same mesh, controls and Empty motions."""
    md = load()
    tris, _ = triangles(obj)
    v = rest(obj).astype(np.float64)
    ctrl, targets = [], []
    for anc in anchors:
        m = np.array(anc.empty.matrix_world) @ np.linalg.inv(
            np.array(tuple(anc.bind_matrix)).reshape(4, 4)
        )
        for i in anchor_vertices(obj, anc):
            if i not in ctrl:
                ctrl.append(int(i))
                targets.append(m[:3, :3] @ v[i] + m[:3, 3])
    order = np.argsort(ctrl)
    d = md.PyramidDeformer(v, tris, np.asarray(ctrl)[order])
    x = d.deform(np.asarray(targets)[order], tol=tol, scale_weight=scale_weight, initial=initial)
    return x, d


def diagonal(v):
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))


def test_registered_as_the_fourth_method_with_its_saved_number():
    m = methods.get("PYRAMID")
    assert m.number == 3 and m.iterative
    items = bpy.types.Object.bl_rna  # registered: the enum knows the key
    assert items is not None
    obj = tube()
    obj.material_deform.method = "PYRAMID"
    assert obj.material_deform.method == "PYRAMID"
    p = obj.material_deform.pyramid
    assert p.live_iterations >= 1 and 0 < p.tolerance < 1e-3 and p.max_iterations >= 50
    assert p.scale_weight == pytest.approx(0.003)  # the library's default


def test_settle_equals_the_numpy_library_on_the_same_inputs():
    obj, top, bottom = pyramid_bar()
    obj.material_deform.live = False  # no live update: Settle starts where the library does
    obj.material_deform.pyramid.tolerance = 1e-9
    top.empty.location = (0.8, 0.3, 2.4)
    top.empty.rotation_euler = (0.3, 0.7, -0.2)
    bottom.empty.rotation_euler = (0.0, -0.4, 0.1)
    bottom.empty.scale = (1.1, 1.1, 1.1)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    want, d = library_result(obj, (top, bottom), tol=1e-9)
    got = compute(obj)  # the same computation again, in float64
    diag = diagonal(rest(obj))
    assert d.last_converged
    assert np.abs(got - want).max() < 1e-9 * diag
    np.testing.assert_allclose(output(obj), want, atol=1e-6 * diag)  # the key, float32
    assert np.abs(want - rest(obj)).max() > 0.5  # really posed


def test_settle_shows_its_progress_while_it_iterates(monkeypatch):
    """Settle's status text and progress fraction move during the solve, one report per L-BFGS
    and per Newton iteration, and the result is the same bits."""
    obj, top, bottom = pyramid_bar()
    obj.material_deform.live = False
    obj.material_deform.pyramid.tolerance = 1e-9
    top.empty.location = (0.8, 0.3, 2.4)
    top.empty.rotation_euler = (0.3, 0.7, -0.2)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    quiet = output(obj).copy()
    texts, fractions = [], []
    monkeypatch.setattr(bridge, "status", lambda _c, text: texts.append(text))
    monkeypatch.setattr(_pyramid_module(), "PROGRESS_SECONDS", 0.0)
    real = _pyramid_module()._settle_report

    def recording(progress, budget, tol):
        def both(fraction, text):
            fractions.append(fraction)
            progress(fraction, text)

        return real(both, budget, tol)

    monkeypatch.setattr(_pyramid_module(), "_settle_report", recording)
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    # the L-BFGS phase first, then one report per Newton iteration
    phases = [t.split(", ")[1] for t in texts if t and "settling, " in t]
    first = phases.count("L-BFGS")
    assert first > 0 and phases[:first] == ["L-BFGS"] * first
    counts = [int(p.split()[0]) for p in phases[first:]]
    iterations = session.entry_for(obj, bpy.context.scene).state["iterations"]
    assert counts == list(range(1, iterations + 1)) and iterations >= 2
    assert fractions == sorted(fractions) and 0 <= fractions[0] < fractions[-1] <= 1
    assert fractions[-1] > 0.9  # converged: the log-scale share of the way to tol
    assert texts[-1] is None  # cleared at the end
    assert output(obj).tobytes() == quiet.tobytes()


def _pyramid_module():
    import importlib

    return importlib.import_module(type(methods.get("PYRAMID")).__module__)


def test_keep_size_setting_reaches_the_solver():
    obj, top, bottom = pyramid_bar()
    obj.material_deform.live = False
    obj.material_deform.pyramid.tolerance = 1e-9
    obj.material_deform.pyramid.scale_weight = 0.5
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.6
    update()
    want, _ = library_result(obj, (top, bottom), tol=1e-9, scale_weight=0.5)
    default, _ = library_result(obj, (top, bottom), tol=1e-9)
    got = compute(obj)
    diag = diagonal(rest(obj))
    assert np.abs(want - default).max() > 1e-4 * diag  # the setting matters here
    assert np.abs(got - want).max() < 1e-9 * diag


def test_anchor_vertices_follow_their_empty_exactly():
    obj, top, bottom = pyramid_bar()
    top.empty.location = (0.5, -0.2, 2.3)
    top.empty.rotation_euler = (0.4, 0.2, 0.9)
    top.empty.scale = (0.8, 0.8, 0.8)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    x = output(obj)
    r = rest(obj)
    for anc in (top, bottom):
        m = np.array(anc.empty.matrix_world) @ np.linalg.inv(
            np.array(tuple(anc.bind_matrix)).reshape(4, 4)
        )
        idx = anchor_vertices(obj, anc)
        want = r[idx] @ m[:3, :3].T + m[:3, 3]
        np.testing.assert_allclose(x[idx], want, atol=1e-5)


def test_at_rest_the_mesh_stays_at_rest():
    obj, top, _ = pyramid_bar()
    assert output(obj).tobytes() == rest(obj).tobytes()  # Bind writes the rest shape
    loc = tuple(top.empty.location)
    top.empty.location.x += 0.7
    update()
    assert np.abs(output(obj) - rest(obj)).max() > 0.3
    top.empty.location = loc  # back to the bind pose exactly
    update()
    assert output(obj).tobytes() == rest(obj).tobytes()
    # and the solver itself, asked for the bind pose, does not move the mesh
    entry = session.entry_for(obj, bpy.context.scene)
    m = methods.get("PYRAMID")
    eye = np.broadcast_to(np.eye(4), (2, 4, 4)).copy()
    res = m.solve(entry.solver, eye, {}, None)
    assert res.done
    assert np.abs(res.positions - rest(obj)).max() < 1e-9 * diagonal(rest(obj))


def test_a_rigid_motion_of_all_anchors_moves_the_mesh_rigidly():
    obj, top, bottom = pyramid_bar()
    rot = Euler((0.7, -0.3, 1.1)).to_matrix().to_4x4()
    motion = Matrix.Translation(Vector((1.5, -0.5, 0.8))) @ rot
    for anc in (top, bottom):
        anc.empty.matrix_world = motion @ anc.empty.matrix_world
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    m = np.array(motion)
    want = rest(obj) @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(compute(obj), want, atol=1e-6 * diagonal(want))
    np.testing.assert_allclose(output(obj), want, atol=1e-5)


def test_live_updates_spend_the_budget_and_keep_settling():
    obj, top, bottom = pyramid_bar(rings=21)
    p = obj.material_deform.pyramid
    p.live_iterations = 1
    p.tolerance = 1e-8
    top.empty.location.x += 1.2
    top.empty.rotation_euler.y = 0.8
    update()  # one live update: one Newton iteration, not converged yet
    key = obj.as_pointer()
    assert key in session.state._unsettled
    entry = session.entry_for(obj, bpy.context.scene)
    assert entry.state["iterations"] == 1 and entry.state["move"] >= 1e-8
    first = output(obj).copy()
    timer = 0
    for _ in range(5000):  # what the handlers' timer does until the result has settled
        if not session.unsettled():
            break
        handlers._keep_settling()
        timer += 1
    assert not session.unsettled(), entry.state["move"]
    settled = output(obj).copy()
    # it kept moving after the drag (the L-BFGS phase takes the first update most of the way)
    assert timer >= 1 and np.abs(settled - first).max() > 0
    assert entry.state["move"] < 1e-8 and entry.state["converged"]
    # a fixed point: one more live update from there moves nothing
    entry.last_key = None
    update()
    np.testing.assert_allclose(output(obj), settled, atol=1e-6)


def test_changing_a_live_setting_solves_again_without_rebind():
    obj, top, _ = pyramid_bar()
    p = obj.material_deform.pyramid
    p.tolerance = 1e-9
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.6
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    on = output(obj).copy()
    p.scale_weight = 0.5  # a live setting: no stale bind, the next update re-solves
    assert session.stale_reason(obj) == ""
    for _ in range(5000):
        update()
        if not session.unsettled():
            break
        handlers._keep_settling()
    assert session.stale_reason(obj) == ""
    assert np.abs(output(obj) - on).max() > 1e-5


def test_rotation_anchor_mode_is_refused_and_nothing_changes():
    obj = tube(rings=13)
    obj.material_deform.method = "PYRAMID"
    add_anchor(obj, lambda p: p.center.z > 2 - 1e-4, mode="ROTATION")
    add_anchor(obj, lambda p: p.center.z < -2 + 1e-4)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "not used by")
    assert snapshot(obj) == before and not obj.material_deform.bound


def test_a_part_without_anchor_is_refused_and_nothing_changes():
    import bmesh

    obj = tube(rings=13)
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    quad = [bm.verts.new(c) for c in [(5, 0, 0), (6, 0, 0), (6, 1, 0), (5, 1, 0)]]
    bm.faces.new(quad)  # a loose quad far away: no anchor reaches it
    bm.to_mesh(obj.data)
    bm.free()
    obj.material_deform.method = "PYRAMID"
    two_end_anchors(obj)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "no anchor")
    assert snapshot(obj) == before and not obj.material_deform.bound


def test_nan_empty_is_reported_as_an_error_and_the_key_keeps_its_pose():
    obj, top, _ = pyramid_bar()
    top.empty.location.x += 0.5
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    before = output(obj).copy()
    top.empty.location.x = float("nan")
    expect_error(bpy.ops.object.material_deform_settle, "Cannot pose|NaN|non-finite|finite")
    assert output(obj).tobytes() == before.tobytes()
    update()  # the live update does not write either
    assert output(obj).tobytes() == before.tobytes()
    assert np.all(np.isfinite(output(obj)))


def test_a_flattened_empty_is_refused_and_the_key_keeps_its_pose():
    obj, top, _ = pyramid_bar()
    before = output(obj).copy()
    top.empty.scale = (0.0, 1.0, 1.0)  # the top anchor's vertices would collapse onto a plane
    update()
    expect_error(bpy.ops.object.material_deform_settle, "scaled to zero")
    assert output(obj).tobytes() == before.tobytes()


def test_live_updates_recover_from_an_extreme_pose_by_themselves():
    """An Empty scaled by 1e30 and back: the live update after it warm-started from the 1e30
    result and was refused as diverged, and with nothing else changing the key stayed at
    5e29 until Update. A diverged warm start is retried from the pose's own start at once."""
    obj, top, _ = pyramid_bar()
    top.empty.rotation_euler.z += math.radians(45)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    posed = output(obj).copy()
    top.empty.scale = (1e30, 1e30, 1e30)
    update()
    assert np.abs(output(obj)).max() > 1e20
    top.empty.scale = (1.0, 1.0, 1.0)
    update()  # one live update, nothing after it
    assert np.abs(output(obj) - posed).max() < 1e-4 * diagonal(posed)


def test_panel_draws_the_pyramid_settings_below_the_common_controls():
    obj, _, _ = pyramid_bar()
    log = draw_panel()
    for name in ("live_iterations", "tolerance", "scale_weight", "object.material_deform_settle"):
        assert name in log, name
    assert log.index("method") < log.index("live_iterations")
    assert "anisotropic" not in log  # the material method's settings are not shown
    from helpers import cut_texts

    assert cut_texts(draw_panel.tree) == []


def run(op, **kw):
    return op("EXEC_DEFAULT", True, **kw)


def test_undo_of_a_settle_and_of_a_bind():
    obj, top, _ = pyramid_bar()
    obj.material_deform.live = False
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.5
    update()
    bpy.ops.ed.undo_push(message="moved, live off")
    before = output(obj).copy()
    assert run(bpy.ops.object.material_deform_settle) == {"FINISHED"}
    settled = output(obj).copy()
    assert np.abs(settled - before).max() > 0.3
    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    assert output(obj).tobytes() == before.tobytes()
    assert bpy.ops.ed.redo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    assert output(obj).tobytes() == settled.tobytes()
    # the solver is rebuilt for the restored state and gives the same result again
    assert run(bpy.ops.object.material_deform_settle) == {"FINISHED"}
    np.testing.assert_allclose(output(obj), settled, atol=1e-5)


def test_undo_bind_unbinds():
    obj = tube(rings=13)
    obj.material_deform.method = "PYRAMID"
    two_end_anchors(obj)
    bpy.ops.ed.undo_push(message="anchors")
    assert run(bpy.ops.object.material_deform_bind) == {"FINISHED"}
    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    assert not obj.material_deform.bound and obj.material_deform.method == "PYRAMID"
    assert run(bpy.ops.object.material_deform_bind) == {"FINISHED"}
    assert obj.material_deform.bound


def animated_pyramid_bar():
    """The bar with its top Empty moved 1.0 and turned 0.5 rad from frame 1 to frame 3."""
    obj, top, bottom = pyramid_bar()
    obj.material_deform.pyramid.tolerance = 1e-9
    e = top.empty
    e.keyframe_insert("location", frame=1)
    e.location.x += 1.0
    e.rotation_euler.y = 0.5
    e.keyframe_insert("location", frame=3)
    e.keyframe_insert("rotation_euler", frame=3)
    return obj, top, bottom


def test_bake_converges_each_frame():
    obj, top, bottom = animated_pyramid_bar()
    s = obj.material_deform
    s.bake_start, s.bake_end, s.bake_output = 1, 3, "SHAPE_KEYS"
    assert bpy.ops.object.material_deform_bake() == {"FINISHED"}
    baked = obj.data.shape_keys.key_blocks
    names = [k.name for k in baked if k.name not in ("Basis", "Material Deform")]
    assert len(names) == 3
    bpy.context.scene.frame_set(3)
    want, _ = library_result(obj, (top, bottom), tol=1e-9)
    last = np.empty(len(obj.data.vertices) * 3, np.float32)
    baked[names[-1]].data.foreach_get("co", last)
    # each frame from the solver's own start, not from the previous frame: the library's result
    np.testing.assert_allclose(last.reshape(-1, 3), want, atol=1e-6 * diagonal(want))
    assert math.isfinite(float(last.sum()))


@pytest.mark.parametrize("output", ["SHAPE_KEYS", "POINT_CACHE"])
def test_bake_warns_about_frames_that_did_not_converge(monkeypatch, tmp_path, output):
    """Audit: a frame that ran out of Max Iterations was baked with only "Baked N frame(s)"."""
    obj, top, bottom = animated_pyramid_bar()
    s = obj.material_deform
    s.pyramid.max_iterations = 1
    s.bake_start, s.bake_end = 1, 3
    warned = []
    real = bake.unsettled_warning
    monkeypatch.setattr(
        bake, "unsettled_warning", lambda u, n: warned.append((list(u), n)) or real(u, n)
    )
    if output == "SHAPE_KEYS":
        assert bpy.ops.object.material_deform_bake() == {"FINISHED"}
    else:
        path = str(tmp_path / "bar.pc2")
        op = bpy.ops.object.material_deform_bake_point_cache
        assert op(frame_start=1, frame_end=3, filepath=path) == {"FINISHED"}
    ((unsettled, n),) = warned
    most = s.pyramid.max_iterations
    assert most == 1
    assert n == 3 and [f for f, _ in unsettled] == [1, 2, 3]  # the top Empty is turned on all
    assert all(f"Not converged after {most} iterations" in text for _, text in unsettled)
    text = real(unsettled, n)
    assert text.startswith("3 of 3 frame(s) did not converge (frames 1, 2, 3)") and "Max" in text
    # converging frames: no warning
    warned.clear()
    s.pyramid.max_iterations = 100
    assert bpy.ops.object.material_deform_bake() == {"FINISHED"}
    assert warned == []


def test_bake_warning_names_only_the_frames_that_did_not_converge(monkeypatch):
    """Frames 1-2 at the bind pose (the rest shape, no solve), frame 3 posed beyond a small
    Max Iterations: only frame 3 is named, whatever an earlier solve left in the method's
    state."""
    obj, top, _ = pyramid_bar()
    s = obj.material_deform
    s.pyramid.max_iterations = 1
    e = top.empty
    for f in (1, 2):
        e.keyframe_insert("location", frame=f)
        e.keyframe_insert("rotation_euler", frame=f)
    e.location.x += 1.0
    e.rotation_euler.y = 0.5
    e.keyframe_insert("location", frame=3)
    e.keyframe_insert("rotation_euler", frame=3)
    bpy.context.scene.frame_set(3)
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}  # leaves "not converged"
    assert not session.solve_status(obj)[0]
    unsettled = []
    bake.bake(obj, bpy.context.scene, [1, 2, 3], unsettled=unsettled)
    assert [f for f, _ in unsettled] == [3]


@pytest.mark.parametrize("budget", [1, 2])
def test_budget_is_the_number_of_iterations_per_update(budget):
    obj, top, _ = pyramid_bar()
    obj.material_deform.pyramid.live_iterations = budget
    obj.material_deform.pyramid.tolerance = 1e-12
    top.empty.location.x += 1.0
    update()
    entry = session.entry_for(obj, bpy.context.scene)
    assert entry.state["iterations"] == budget


def test_a_pose_that_does_not_converge_stops_after_max_iterations():
    obj, top, _ = pyramid_bar(rings=21)
    p = obj.material_deform.pyramid
    # two Newton iterations (after the L-BFGS phase) do not reach 1e-12: three do
    p.tolerance, p.live_iterations, p.max_iterations = 1e-12, 1, 2
    top.empty.location.x += 1.2
    top.empty.rotation_euler.y = 0.8
    update()
    entry = session.entry_for(obj, bpy.context.scene)
    calls = 0
    while session.unsettled() and calls < 100:
        handlers._keep_settling()
        calls += 1
    assert not session.unsettled() and calls == 1  # 1 + 1 iterations
    assert entry.state["spent"] == 2 and not entry.state["converged"]
    # Settle starts over from the solver's own start (no initial) with the whole allowance,
    # and says that it did not converge
    spy = Spy(entry)
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    assert spy.calls == [None]
    entry.solver.deformer = spy.inner
    assert entry.state["iterations"] == 2 and entry.state["spent"] == 2
    status = session.solve_status(obj)
    assert status is not None and not status[0]
    assert "Not converged after 2 iterations" in status[1]
    # a changed setting is a new problem: a new allowance for the live updates too
    p.scale_weight = 0.01
    update()
    assert entry.state["iterations"] == 1 and entry.state["spent"] == 1


class Spy:
    """Wraps a solver's deformer and records the ``initial`` of every deform() call."""

    def __init__(self, entry):
        self.entry, self.inner, self.calls = entry, entry.solver.deformer, []
        entry.solver.deformer = self

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def deform(self, *a, **k):
        self.calls.append(k.get("initial"))
        return self.inner.deform(*a, **k)


def settle_live():
    for _ in range(200):
        if not session.unsettled():
            return
        handlers._keep_settling()
    raise AssertionError("did not settle")


def test_undo_restores_a_settled_live_pose_bit_for_bit_without_solving():
    """Found by review: after undo the live update re-solved the restored pose warm-started
    from the undone one and overwrote the restored key (2.8 % of the diagonal off)."""
    obj, top, _ = pyramid_bar()
    top.empty.location.x += 0.6
    update()
    settle_live()
    bpy.ops.ed.undo_push(message="first pose")
    first = output(obj).copy()
    top.empty.rotation_euler.y = 0.5
    update()
    settle_live()
    bpy.ops.ed.undo_push(message="second pose")
    assert np.abs(output(obj) - first).max() > 0.05
    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    assert output(obj).tobytes() == first.tobytes()
    spy = Spy(session.entry_for(obj, bpy.context.scene))
    update()
    assert output(obj).tobytes() == first.tobytes() and spy.calls == []
    assert not session.unsettled() and session.stale_reason(obj) == ""


def test_undo_of_an_unsettled_live_pose_continues_from_the_restored_key():
    """The key restored by undo held a result still settling: the live updates continue from
    it (not from the undone pose's iterate, not from a cold start)."""
    obj, top, _ = pyramid_bar()
    p = obj.material_deform.pyramid
    p.live_iterations, p.tolerance = 1, 1e-12  # never settles within one update
    top.empty.location.x += 0.6
    update()
    bpy.ops.ed.undo_push(message="first pose")
    first = output(obj).copy()
    top.empty.rotation_euler.y = 0.5
    update()
    bpy.ops.ed.undo_push(message="second pose")
    entry = session.entry_for(obj, bpy.context.scene)
    spy = Spy(entry)  # the cache entry outlives the undo (memfile undo keeps the addresses)
    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    update()
    assert session.entry_for(obj, bpy.context.scene) is entry and len(spy.calls) >= 1
    used = slice(None) if entry.used is None else entry.used
    np.testing.assert_array_equal(spy.calls[0], first[used].astype(np.float64))
    assert session.unsettled()  # and it keeps settling


def test_a_saved_settled_pose_survives_reopening_and_the_first_frame_change(tmp_path):
    obj, top, _ = pyramid_bar()
    top.empty.location.x += 0.6
    top.empty.rotation_euler.y = 0.4
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    settled = output(obj).copy()
    path = str(tmp_path / "posed.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)
    update()
    assert output(obj).tobytes() == settled.tobytes()
    assert session.stale_reason(obj) == ""


def test_frames_of_a_background_run_converge_like_the_bake():
    """Review: frame changes spent one live budget (background runs have no timers to keep
    settling), so a rendered frame differed from the baked one by up to 8 % of the diagonal."""
    assert bpy.app.background
    obj, top, bottom = animated_pyramid_bar()
    bpy.context.scene.frame_set(3)
    want, _ = library_result(obj, (top, bottom), tol=1e-9)
    np.testing.assert_allclose(output(obj), want, atol=1e-6 * diagonal(want))
    assert not session.unsettled() and session.solve_status(obj)[0]


def _huge(x):
    return x * 1e300


def _one_nan(x):
    x = x.copy()
    x[len(x) // 2, 1] = np.nan
    return x


def _one_below_float32(x):
    x = x.copy()
    x[-1, 2] = -1e39  # finite in float64, -inf once written as float32
    return x


def _one_above_float32(x):
    x = x.copy()
    x[0, 0] = 1e39
    return x


@pytest.mark.parametrize("corrupt", [_huge, _one_nan, _one_below_float32, _one_above_float32])
def test_a_non_finite_result_is_never_written(monkeypatch, corrupt):
    """Review: a diverging solve wrote inf into the key and Settle said nothing. One bad
    coordinate anywhere, of either sign, is enough."""
    obj, top, _ = pyramid_bar()
    top.empty.location.x += 0.6
    update()
    before = output(obj).copy()
    method = methods.get("PYRAMID")
    real = method.solve

    def overflowing(*a, **k):
        res = real(*a, **k)
        res.positions = corrupt(res.positions)
        return res

    monkeypatch.setattr(method, "solve", overflowing)
    top.empty.location.x += 0.2
    update()
    assert output(obj).tobytes() == before.tobytes()
    assert "not finite" in session.stale_reason(obj)
    expect_error(bpy.ops.object.material_deform_settle, "not finite")
    assert output(obj).tobytes() == before.tobytes()
    monkeypatch.setattr(method, "solve", real)
    top.empty.location.x += 0.1
    update()
    assert np.isfinite(output(obj)).all() and session.stale_reason(obj) == ""


def cylinder_with_cap_anchors():
    z = np.load(Path(__file__).parents[1] / "python" / "data" / "cylinder_subdivided_ngon_caps.npz")
    v, tris = z["vertices"], z["triangles"]
    mesh = bpy.data.meshes.new("Cyl")
    mesh.from_pydata(v.tolist(), [], tris.tolist())
    obj = bpy.data.objects.new("Cyl", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.material_deform.method = "PYRAMID"
    bpy.context.view_layer.objects.active = obj
    two_end_anchors(obj, half_length=2.0)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    return obj, obj.material_deform.anchors[0]


def test_the_sliver_capped_cylinder_settles_live_and_in_settle():
    """Review: on this cylinder (n-gon caps subdivided into slivers) the old sweeps ran away,
    live (the key grew to 1e18-1e35) and in Settle. Newton's method only takes steps that lower
    the energy: the live chain settles, Settle converges, both finite and near the pose."""
    obj, top = cylinder_with_cap_anchors()
    r = rest(obj)
    size = float(np.linalg.norm(r.max(0) - r.min(0)))
    top.empty.location.x += 0.8
    top.empty.rotation_euler.y += 0.6
    update()
    for _ in range(300):
        if not session.unsettled():
            break
        handlers._keep_settling()
    assert not session.unsettled() and session.stale_reason(obj) == ""
    assert session.solve_status(obj)[0]
    x = output(obj)
    assert np.isfinite(x).all() and np.linalg.norm(x.max(0) - x.min(0)) < 1.5 * size
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    assert session.solve_status(obj)[0]
    np.testing.assert_allclose(output(obj), x, atol=1e-4 * size)  # the same minimum


def test_a_failing_solve_is_reported_and_the_key_keeps_its_last_result(monkeypatch):
    """The library's RuntimeError (an energy that stops being finite) reaches the user as an
    error; nothing is written, and the next update starts over."""
    obj, top = cylinder_with_cap_anchors()
    obj.material_deform.live = False
    before = output(obj).copy()
    top.empty.location.x += 0.8
    update()
    entry = session.entry_for(obj, bpy.context.scene)
    spy = Spy(entry)

    def failing(*a, **k):
        raise RuntimeError("pyramid deformer: the energy overflowed")

    monkeypatch.setattr(spy, "deform", failing)
    expect_error(bpy.ops.object.material_deform_settle, "iteration failed")
    assert output(obj).tobytes() == before.tobytes()
    monkeypatch.undo()
    entry.solver.deformer = spy.inner
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    assert session.solve_status(obj)[0]


def test_a_rendered_frame_is_the_cold_start_even_after_a_live_settle():
    """Review: a frame change while rendering kept a key that held a live (warm-started)
    result of the same pose, which can be another fixed point than Bake's cold start."""
    obj, top, bottom = pyramid_bar()
    obj.material_deform.pyramid.tolerance = 1e-9
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.5
    for step in range(5):  # a drag: the live chain warm-starts from each previous result
        top.empty.location.y = 0.05 * step
        update()
    settle_live()
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)  # background: renders
    want, _ = library_result(obj, (top, bottom), tol=1e-9)
    np.testing.assert_allclose(output(obj), want, atol=1e-6 * diagonal(want))


def test_assign_empty_from_the_menu_takes_the_selected_empty_not_the_last_one():
    """Review: without SKIP_SAVE a menu call reused the previous run's Empty. Headless Blender
    has no events, so the operator's invoke is called directly here."""
    from material_deform import operators

    obj, top, _ = pyramid_bar()
    for name in ("E1", "E2"):
        bpy.context.scene.collection.objects.link(bpy.data.objects.new(name, None))
    op = bpy.ops.mesh.material_deform_assign_empty
    assert op(empty="E1") == {"FINISHED"}
    s = obj.material_deform
    assert s.anchors[s.active_anchor_index].empty.name == "E1"
    cls = operators.MESH_OT_material_deform_assign_empty
    assert op.get_rna_type().properties["empty"].is_skip_save
    for o in bpy.context.scene.objects:
        o.select_set(o.name in ("E2", "Bar"))
    bpy.context.view_layer.objects.active = obj
    calls = []

    class Fake:
        empty = ""

        def execute(self, context):
            calls.append(self.empty)
            return {"FINISHED"}

    assert cls.invoke(Fake(), bpy.context, None) == {"FINISHED"} and calls == ["E2"]
