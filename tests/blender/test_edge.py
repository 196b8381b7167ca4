"""The edge-based method in the add-on (methods/edge.py): the same numbers as the numpy library
on the same inputs, anchors exactly on their Empties, live settings without rebind, the settling
timer, bad input and undo."""

import bpy
import numpy as np
import pytest
from helpers import add_anchor, anchor_vertices, co, mesh_object, output, rest, snapshot, update
from material_deform import handlers, session
from material_deform.core import load
from mathutils import Matrix

N = 12  # quads per side


def sheet(name="Sheet", size=2.0):
    """An N x N quad sheet in z = 0, centred; two anchors at the corner faces of one side."""
    xs = np.linspace(-size / 2, size / 2, N + 1)
    verts = [(x, y, 0.0) for y in xs for x in xs]
    faces = [
        (r * (N + 1) + c, r * (N + 1) + c + 1, (r + 1) * (N + 1) + c + 1, (r + 1) * (N + 1) + c)
        for r in range(N)
        for c in range(N)
    ]
    obj = mesh_object(name, verts, faces)
    h = size / 2 - size / N
    left = add_anchor(obj, lambda p: p.center.x < -h and p.center.y > h)
    right = add_anchor(obj, lambda p: p.center.x > h and p.center.y > h)
    s = obj.material_deform
    s.method = "EDGE"
    e = s.edge
    e.stretch, e.bend = 1e-2, 1.0
    return obj, left, right


def triangles(obj):
    me = obj.data
    me.calc_loop_triangles()
    t = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", t)
    return t.reshape(-1, 3).astype(np.int64)


def constraint_set(obj, anchors, moves):
    """Library inputs: the anchor vertices (sorted) and where their Empty's motion puts them."""
    r = rest(obj).astype(np.float64)
    idx, pos = [], []
    for anc, m in zip(anchors, moves, strict=True):
        v = anchor_vertices(obj, anc)
        idx.append(v)
        pos.append(r[v] @ m[:3, :3].T + m[:3, 3])
    idx, pos = np.concatenate(idx), np.concatenate(pos)
    order = np.argsort(idx)
    return idx[order], pos[order]


def motion(empty, before):
    # float64 as the add-on computes it (np.array of a Matrix is float32 from Blender 5.0 on)
    return np.array(empty.matrix_world, np.float64) @ np.linalg.inv(before)


def bind(obj):
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}


def pose(left, right):
    b = [np.array(a.empty.matrix_world, np.float64) for a in (left, right)]
    left.empty.location.x += 0.4
    right.empty.location.x -= 0.3
    right.empty.location.z += 0.2
    right.empty.rotation_euler.y = 0.5
    return b


def library(obj, anchors, before, e, **kw):
    md = load()
    idx, pos = constraint_set(
        obj, anchors, [motion(a.empty, b) for a, b in zip(anchors, before, strict=True)]
    )
    v = rest(obj).astype(np.float64)
    d = md.EdgeDeformer(v, triangles(obj), idx, stretch=e.stretch, bend=e.bend, **kw)
    return d, idx, pos


def test_settle_equals_the_numpy_library_and_anchors_follow_exactly():
    obj, left, right = sheet()
    e = obj.material_deform.edge
    e.tolerance, e.settle_iterations = 0.0, 40  # exactly 40 iterations from rest
    e.gravity_strength = 2.0
    bind(obj)
    obj.material_deform.live = False  # the first solve after the move is the one compared
    before = pose(left, right)
    update()
    d, idx, pos = library(obj, (left, right), before, e)
    diag = d.diagonal
    n = len(rest(obj))
    g = np.array([0.0, 0.0, -1.0]) * (2.0 * 1e-3 * e.bend * diag / n)
    want = d.solve(pos, iterations=40, tol=0.0, gravity=g)
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}  # into the shape key
    x = output(obj).astype(np.float64)
    assert np.abs(x - want).max() <= 1e-6 * diag  # float32 key
    assert want[:, 2].min() < -0.05 * diag  # gravity does sag the sheet (not a no-op compare)
    # in float64: the same solve again from rest (no warm start)
    session.state._cache[obj.as_pointer()].state.pop("x")
    got = session.compute(obj, bpy.context.scene, budget=None)
    assert np.abs(got - want).max() <= 1e-9 * diag
    np.testing.assert_array_equal(got[idx], pos)  # hard constraints: exactly the Empty's motion
    # the anchor vertices sit where the Empty's world motion puts them
    for anc, b in zip((left, right), before, strict=True):
        v = anchor_vertices(obj, anc)
        m = motion(anc.empty, b)
        r = rest(obj)[v].astype(np.float64)
        np.testing.assert_allclose(x[v], r @ m[:3, :3].T + m[:3, 3], atol=2e-7 * diag)


def test_paint_weights_and_direction_attribute_reach_the_solver():
    """Edge weights from the stored stiffness (phi on mesh edges, psi on the quad diagonals)
    and a direction attribute: the same result as the library given them."""
    obj, left, right = sheet()
    vg = obj.vertex_groups.new(name="Stiffness")
    for v in obj.data.vertices:
        vg.add([v.index], 0.5 + 0.5 * np.tanh(3 * v.co.x), "REPLACE")
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    me = obj.data
    dirs = np.zeros((len(me.vertices), 3), np.float32)
    dirs[:, 0] = 1.0
    dirs[:, 1] = np.linspace(0, 1, len(dirs))
    attr = me.attributes.new("md_direction", "FLOAT_VECTOR", "POINT")
    attr.data.foreach_set("vector", dirs.ravel())
    e = obj.material_deform.edge
    e.direction_source = "ATTRIBUTE"
    e.tolerance, e.settle_iterations = 0.0, 30
    bind(obj)
    obj.material_deform.live = False
    before = pose(left, right)
    update()

    # independent weights: per triangle edge the polygon's psi; mesh edges take phi
    md = load()
    psi = np.empty(len(me.polygons), np.float32)
    me.attributes["md_shear_stiffness"].data.foreach_get("value", psi)
    phi = np.empty(len(me.edges), np.float32)
    me.attributes["md_bend_stiffness"].data.foreach_get("value", phi)
    tris = triangles(obj)
    tri_poly = np.empty(len(tris), np.int32)
    me.loop_triangles.foreach_get("polygon_index", tri_poly)
    edges = md.mesh_edges(tris)
    w = {}
    for t, p in zip(tris, tri_poly, strict=True):
        for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])):
            w.setdefault((min(a, b), max(a, b)), []).append(float(psi[p]))
    for ed, value in zip(me.edges, phi, strict=True):
        a, b = sorted(ed.vertices)
        w[(a, b)] = [float(value)]
    weight = np.array([np.mean(w[(int(a), int(b))]) for a, b in edges])
    assert weight.min() < 0.1 and weight.max() > 0.5  # the paint does vary

    d, idx, pos = library(
        obj, (left, right), before, e, edge_weight=weight, direction=dirs.astype(np.float64)
    )
    want = d.solve(pos, iterations=30, tol=0.0)
    got = session.compute(obj, bpy.context.scene, budget=None)
    assert np.abs(got - want).max() <= 1e-9 * d.diagonal
    uniform, _, _ = library(obj, (left, right), before, e)
    assert np.abs(uniform.solve(pos, iterations=30, tol=0.0) - want).max() > 1e-3


def test_live_budget_returns_early_and_the_timer_settles():
    obj, left, right = sheet()
    e = obj.material_deform.edge
    e.live_iterations, e.tolerance, e.settle_iterations = 2, 1e-6, 5000
    bind(obj)
    before = pose(left, right)
    update()  # one live update: 2 iterations, not converged
    assert session.unsettled()
    assert bpy.app.timers.is_registered(handlers._keep_settling)
    first = output(obj).copy()
    d, _, pos = library(obj, (left, right), before, e)
    converged = d.solve(pos, iterations=5000, tol=1e-6)
    two = d.solve(pos, iterations=2, tol=0.0)
    np.testing.assert_allclose(first, two, atol=1e-6)  # exactly the budget, from rest
    diag = d.diagonal
    assert np.abs(first - converged).max() > 1e-2 * diag
    calls = 0
    while session.unsettled() and calls < 5000:
        handlers._keep_settling()  # what the timer calls
        calls += 1
    assert not session.unsettled() and calls > 3
    # settled: within the convergence tolerance's reach of the converged result
    assert np.abs(output(obj) - converged).max() < 1e-3 * diag


def settled_sheet():
    """The sheet bound, posed and settled; returns it and its edge settings."""
    obj, left, right = sheet()
    e = obj.material_deform.edge
    e.tolerance, e.settle_iterations = 1e-7, 20000
    bind(obj)
    pose(left, right)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    return obj, e


def test_a_live_setting_solves_the_pose_again_at_once_unless_live_is_off():
    obj, e = settled_sheet()
    settled = output(obj).copy()
    obj.material_deform.live = False
    e.p_bend = 0.5  # Live off: the key keeps its result
    np.testing.assert_array_equal(output(obj), settled)
    obj.material_deform.live = True
    e.p_stretch = 0.3  # written by the setting's own update, before any depsgraph update
    assert np.abs(output(obj) - settled).max() > 1e-4
    assert session.stale_reason(obj) == ""


def test_live_response_changes_the_result_without_rebind():
    obj, e = settled_sheet()
    full = output(obj).copy()
    solver = session.state._cache[obj.as_pointer()].solver
    fp = obj.material_deform.fp_method
    e.p_stretch = 0.3  # live: same solver, same bind, a different result
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    soft = output(obj).copy()
    assert session.state._cache[obj.as_pointer()].solver is solver
    assert solver.deformer.factorizations == 1
    assert obj.material_deform.fp_method == fp and session.stale_reason(obj) == ""
    assert np.abs(soft - full).max() > 1e-3
    # p scales the material at convergence (docs/edge.md): p_rho 0.3 = stretch x 0.3
    strain = [
        np.abs(
            np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
            / np.linalg.norm(r[edges[:, 0]] - r[edges[:, 1]], axis=1)
            - 1
        ).mean()
        for x, r, edges in [(x, rest(obj), load().mesh_edges(triangles(obj))) for x in (full, soft)]
    ]
    assert strain[1] > strain[0]  # softer stretch response: edges stretch more


def test_stretch_change_marks_the_bind_stale_and_back_makes_it_valid():
    obj, left, right = sheet()
    bind(obj)
    e = obj.material_deform.edge
    e.stretch = 0.5
    assert "Stretch" in session.stale_reason(obj)
    left.empty.location.x += 0.3
    update()
    np.testing.assert_array_equal(output(obj), rest(obj))  # not updated while stale
    e.stretch = 1e-2  # back to what was bound
    assert session.stale_reason(obj) == ""
    update()
    assert np.abs(output(obj) - rest(obj)).max() > 0.1


def test_missing_direction_attribute_is_an_error_and_changes_nothing():
    obj, _, _ = sheet()
    e = obj.material_deform.edge
    e.direction_source = "ATTRIBUTE"
    e.direction_attribute = "flow"
    before = snapshot(obj)
    with pytest.raises(RuntimeError, match="point attribute 'flow' not found"):
        bpy.ops.object.material_deform_bind()
    assert snapshot(obj) == before and not obj.material_deform.bound
    obj.data.attributes.new("flow", "FLOAT", "POINT")  # wrong type: also refused
    with pytest.raises(RuntimeError, match="'flow' is FLOAT on POINT"):
        bpy.ops.object.material_deform_bind()
    assert not obj.material_deform.bound


def test_direction_empty_turned_after_bind_asks_for_rebind():
    obj, left, _ = sheet()
    emp = bpy.data.objects.new("Flow", None)
    bpy.context.scene.collection.objects.link(emp)
    e = obj.material_deform.edge
    e.direction_source, e.direction_empty, e.direction_axis = "EMPTY", emp, "X"
    bind(obj)
    np.testing.assert_allclose(tuple(e.bind_direction), (1, 0, 0), atol=1e-7)
    left.empty.location.x += 0.2
    update()
    assert session.stale_reason(obj) == ""
    assert session.owner_of(emp, bpy.context.scene) == obj  # the panel follows it
    # turning the Empty alone (no anchor moved) is noticed: it is part of the update check
    emp.matrix_world = Matrix.Rotation(0.7, 4, "Z")
    update()
    assert "Direction Empty turned" in session.stale_reason(obj)


def test_undo_bind_and_move():
    obj, left, _ = sheet()
    before = rest(obj).copy()
    bpy.ops.ed.undo_push(message="anchors")
    assert bpy.ops.object.material_deform_bind("EXEC_DEFAULT", True) == {"FINISHED"}
    left.empty.location.x += 0.3
    update()
    assert bpy.ops.object.material_deform_settle("EXEC_DEFAULT", True) == {"FINISHED"}
    moved = output(obj).copy()
    assert np.abs(moved - before).max() > 0.1
    assert bpy.ops.ed.undo() == {"FINISHED"}  # the settle
    assert bpy.ops.ed.undo() == {"FINISHED"}  # the bind
    obj = bpy.data.objects["Sheet"]
    assert not obj.material_deform.bound and obj.data.shape_keys is None
    assert obj.material_deform.method == "EDGE"
    assert rest(obj).tobytes() == before.tobytes()
    assert obj.as_pointer() not in session.state._cache
    assert bpy.ops.ed.redo() == {"FINISHED"}
    obj = bpy.data.objects["Sheet"]
    assert obj.material_deform.bound
    left = obj.material_deform.anchors[0]
    left.empty.location.x += 0.3  # (the move was no undo step: the Empty is back at bind)
    update()
    assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
    assert np.abs(output(obj) - before).max() > 0.1  # the rebuilt solver poses again


def test_panel_draws_the_edge_settings():
    from helpers import draw_panel

    obj, _, _ = sheet()
    bpy.context.view_layer.objects.active = obj
    log = draw_panel()
    text = repr(log)
    for prop in ("stretch", "bend", "p_stretch", "gravity_strength", "live_iterations"):
        assert prop in text


def test_bake_solves_every_frame_to_convergence_from_rest():
    """Each baked frame is the converged pose of that frame from the library's own start (the
    rest mesh), never from the previous frame: a baked frame depends on its frame only, so a
    farm may bake the frames in chunks, in any order (docs/farm.md)."""
    obj, left, right = sheet()
    e = obj.material_deform.edge
    e.tolerance, e.settle_iterations, e.gravity_strength = 1e-7, 20000, 1.0
    bind(obj)
    scene = bpy.context.scene
    emp = right.empty
    bind_m = np.array(emp.matrix_world)
    left_m = np.array(left.empty.matrix_world)
    emp.keyframe_insert("location", frame=1)
    emp.location.x -= 0.5
    emp.location.z += 0.3
    emp.keyframe_insert("location", frame=4)
    assert bpy.ops.object.material_deform_bake(frame_start=1, frame_end=4) == {"FINISHED"}
    last = session.state._cache[obj.as_pointer()].solver.deformer.last_iterations  # frame 4
    keys = obj.data.shape_keys.key_blocks
    n = len(rest(obj))
    used = []
    for f in (2, 3, 4):
        scene.frame_set(f)
        d, _, pos = library(obj, (left, right), [left_m, bind_m], e)
        g = np.array([0.0, 0.0, -1.0]) * (1e-3 * e.bend * d.diagonal / n)
        want = d.solve(pos, iterations=20000, tol=1e-7, gravity=g)
        used.append(d.last_iterations)
        baked = [k for k in keys if k.name.startswith("MD Bake") and k.name.endswith(f"{f:04d}")]
        assert len(baked) == 1, [k.name for k in keys]
        assert np.abs(co(baked[0].data) - want).max() < 1e-6 * d.diagonal
    assert min(used) > 20
    assert last == used[-1]  # frame 4 from rest, as the library (from frame 3: fewer)


def test_settling_stops_at_settle_max_when_the_tolerance_is_out_of_reach():
    obj, left, right = sheet()
    e = obj.material_deform.edge
    e.live_iterations, e.tolerance, e.settle_iterations = 3, 1e-15, 12
    bind(obj)
    pose(left, right)
    update()
    calls = 0
    while session.unsettled() and calls < 100:
        handlers._keep_settling()
        calls += 1
    assert not session.unsettled() and calls == 3  # 3 + 3 x 3 = 12 iterations, then it stops
