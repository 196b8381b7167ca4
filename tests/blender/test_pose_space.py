"""Method 3, pose space from example shapes (methods/pose_space.py): the add-on against the
numpy library on the same inputs, examples reproduced, the weights readout, staleness when an
example key changes, bad input, the frozen group and undo."""

import math

import bpy
import numpy as np
import pytest
from helpers import activate, add_anchor, anchor_vertices, expect_error, output, snapshot, tube
from helpers import update as view_update
from material_deform import anchor_math as am
from material_deform import bridge, core, session
from material_deform.methods import pose_space as ps

HALF = 2.0  # the helper's bar runs along z over [-2, 2]


def bend(v, angle, bulge=0.0):
    """The bar bent by ``angle`` (radians, sign = direction) in the xz plane about its base,
    every z = const section moved rigidly (so the end caps are exactly rigid); ``bulge`` widens
    the middle (compact support: zero within 1 of either end)."""
    v = np.asarray(v, np.float64).copy()
    s = v[:, 2] + HALF
    g = 1.0 + bulge * np.clip(1.0 - (s - HALF) ** 2, 0.0, None) ** 2
    x, y = v[:, 0] * g, v[:, 1] * g
    rho = 2 * HALF / angle
    a = s / rho
    out = np.empty_like(v)
    out[:, 0] = rho - (rho - x) * np.cos(a)
    out[:, 1] = y
    out[:, 2] = -HALF + (rho - x) * np.sin(a)
    return out


def add_key(obj, name, coords):
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.data.foreach_set("co", np.asarray(coords, np.float32).ravel())
    kb.value = 0.0
    return kb


def rest64(obj):
    me = obj.data
    src = me.shape_keys.reference_key.data if me.shape_keys else me.vertices
    x = np.empty(len(src) * 3, np.float32)
    src.foreach_get("co", x)
    return x.reshape(-1, 3).astype(np.float64)


def shown_weights(obj):
    return ps.weights_readout(session.cached_entry(obj))


def example_bar(frame=True):
    """Bar with two example keys (bent +90 degrees; bent -90 degrees with a bulge), the bottom
    cap a Frame (or Follow Empty) anchor, the top cap a Follow Empty anchor; method Pose space."""
    obj = tube()
    v = rest64(obj)
    add_key(obj, "Bend", bend(v, 0.5 * math.pi))
    add_key(obj, "Bulge", bend(v, -0.5 * math.pi, bulge=0.4))
    top = add_anchor(obj, lambda p: p.center.z > HALF - 1e-4)
    bottom = add_anchor(
        obj, lambda p: p.center.z < -HALF + 1e-4, mode="FRAME" if frame else "POSITION"
    )
    obj.material_deform.method = "POSE_SPACE"
    activate(obj)
    return obj, top, bottom


def bind(obj):
    activate(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}


def diag(v):
    return float(np.linalg.norm(v.max(0) - v.min(0)))


def transform_of(obj, anchor):
    """The anchor's motion since bind in the mesh's space (what the session gives the method)."""
    m_obj = np.array(obj.matrix_world, np.float64)
    now = np.array(anchor.empty.matrix_world, np.float64)[None]
    bind_m = np.array(tuple(anchor.bind_matrix), np.float64).reshape(1, 4, 4)
    m_obj_bind = np.array(tuple(obj.material_deform.obj_bind_matrix), np.float64).reshape(4, 4)
    return am.anchor_transforms(m_obj, now, bind_m, m_obj_bind)[0]


def reference(obj, anchors, coarse=None, frozen=None, rest_example=True, frame_anchor=None):
    """The numpy library on the same inputs: returns (positions, weights)."""
    md = core.load()
    v = rest64(obj)
    tris = bridge.mesh_arrays(obj.data).tris
    keys = obj.data.shape_keys.key_blocks
    ex = [np.array([k.co[:] for k in keys[n].data], np.float64) for n in ("Bend", "Bulge")]
    if rest_example:
        ex = [v, *ex]
    handles = [anchor_vertices(obj, a) for a in anchors]
    frame = None
    if frame_anchor is not None:
        fv = anchor_vertices(obj, frame_anchor)
        frame = int(np.flatnonzero(np.isin(tris, fv).all(1))[0])
    d = md.PoseSpaceDeformer(
        v, tris, np.stack(ex), handles, frame=frame, coarse=coarse, frozen=frozen
    )
    hp = []
    for a, h in zip(anchors, handles, strict=True):
        t = transform_of(obj, a)
        hp.append(v[h] @ t[:3, :3].T + t[:3, 3])
    x = d.deform(hp)
    return x, d.example_weights


def pose_top(top, angle=0.9, dx=0.8, dz=-0.5):
    e = top.empty
    from mathutils import Matrix, Vector

    c = e.matrix_world.translation.copy()
    turn = Matrix.Translation(c) @ Matrix.Rotation(angle, 4, "Y") @ Matrix.Translation(-c)
    e.matrix_world = Matrix.Translation(Vector((dx, 0.0, dz))) @ turn @ e.matrix_world
    view_update()


def test_method_is_registered_with_its_saved_number():
    m = ps.PoseSpaceMethod
    assert (m.key, m.number) == ("POSE_SPACE", 2)
    from material_deform import properties

    rna = properties.MaterialDeformSettings.bl_rna.properties["method"]
    items = {i.identifier: i.value for i in rna.enum_items}
    assert items["POSE_SPACE"] == 2 and items["MATERIAL"] == 0


@pytest.mark.parametrize("coarse", [None, 120])
def test_bound_pose_equals_the_numpy_library_and_the_readout_its_weights(coarse):
    obj, top, bottom = example_bar()
    if coarse is not None:
        obj.material_deform.pose_space.multiresolution = True
        obj.material_deform.pose_space.coarse_faces = coarse
    bind(obj)
    v = rest64(obj)
    np.testing.assert_array_equal(output(obj), v.astype(np.float32))  # bind pose: rest
    w0 = shown_weights(obj)
    assert [n for n, _w in w0] == ["(rest)", "Bend", "Bulge"]
    np.testing.assert_allclose([w for _n, w in w0], [1, 0, 0], atol=1e-9)  # rest = example 1

    pose_top(top)
    got = output(obj).astype(np.float64)
    want, weights = reference(obj, [top, bottom], coarse=coarse, frame_anchor=bottom)
    err = np.abs(got - want).max()
    # the output key is float32: its round-off (~1e-7 of the size) is all that may differ
    assert err <= 1e-9 * diag(v) + 4 * np.finfo(np.float32).eps * np.abs(want).max(), err
    assert np.abs(got - v).max() > 0.3  # it moved
    readout = shown_weights(obj)
    w = np.array([x for _n, x in readout])
    np.testing.assert_allclose(w, weights, atol=1e-12)
    assert abs(w.sum() - 1.0) < 1e-9
    # the top turned towards the Bend side: Bend weighs more than Bulge
    assert w[1] > w[2]


def test_solve_itself_matches_the_library_to_1e9_of_the_diagonal():
    """The method's solve on the session's transforms against the library, both float64."""
    obj, top, bottom = example_bar()
    bind(obj)
    pose_top(top, angle=-1.2, dx=-1.0, dz=-0.3)
    entry = session.entry_for(obj, bpy.context.scene)
    t = session.transforms_now(obj, entry, bpy.context.scene)
    got = ps.PoseSpaceMethod().solve(entry.solver, t, {}, None).positions
    want, _w = reference(obj, [top, bottom], frame_anchor=bottom)
    assert np.abs(got - want).max() <= 1e-9 * diag(rest64(obj))


@pytest.mark.parametrize("key", ["Bend", "Bulge"])
def test_anchors_posed_at_an_example_reproduce_that_shape_key(key):
    obj, top, bottom = example_bar()
    bind(obj)
    v = rest64(obj)
    keys = obj.data.shape_keys.key_blocks
    target = np.array([k.co[:] for k in keys[key].data], np.float64)
    idx = anchor_vertices(obj, top)
    k = am.rigid_fit(v[idx], target[idx])  # rest top cap -> its place in the example
    m_obj = np.array(obj.matrix_world)
    from mathutils import Matrix

    e_bind = np.array(tuple(top.bind_matrix)).reshape(4, 4)
    top.empty.matrix_world = Matrix((m_obj @ k @ np.linalg.inv(m_obj) @ e_bind).tolist())
    view_update()
    got = output(obj).astype(np.float64)
    err = np.abs(got - target).max() / diag(v)
    assert err <= 1e-6, err  # the bound; float32 keys and Empty matrices: ~1e-8 here
    names = [n for n, _w in shown_weights(obj)]
    w = np.array([x for _n, x in shown_weights(obj)])
    np.testing.assert_allclose(w, np.eye(3)[names.index(key)], atol=1e-6)
    if key == "Bulge":  # the bulge came along: the middle section is wider than at rest
        mid = np.abs(v[:, 2]) < 0.1
        assert np.ptp(got[mid, 1]) > 1.3 * np.ptp(v[mid, 1])


def test_editing_an_example_key_makes_the_bind_stale():
    obj, top, _bottom = example_bar()
    bind(obj)
    pose_top(top)
    assert session.stale_reason(obj) == ""
    kb = obj.data.shape_keys.key_blocks["Bulge"]
    kb.data[5].co.x += 0.01  # a script edit in Object Mode: caught on the next update
    pose_top(top, angle=0.1, dx=0.1, dz=0.0)
    assert "Example shape key 'Bulge' changed since bind" in session.stale_reason(obj)
    before = output(obj).copy()
    pose_top(top, angle=0.2)
    np.testing.assert_array_equal(output(obj), before)  # no longer updated
    bind(obj)  # Rebind takes the new shape
    assert session.stale_reason(obj) == "" and obj.material_deform.rebind_reason == ""


def test_edit_mode_change_and_added_or_muted_keys_make_the_bind_stale():
    obj, top, _bottom = example_bar()
    bind(obj)
    # Edit Mode round trip on the example key: the fingerprint names the example keys
    obj.active_shape_key_index = list(obj.data.shape_keys.key_blocks).index(
        obj.data.shape_keys.key_blocks["Bend"]
    )
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.transform.translate(value=(0.0, 0.05, 0.0))
    bpy.ops.object.mode_set(mode="OBJECT")
    reason = session.full_check(obj, bpy.context.scene)
    assert "example shape keys" in reason, reason
    obj.data.shape_keys.key_blocks["Bend"].data.foreach_set(
        "co", bend(rest64(obj), 0.5 * math.pi).astype(np.float32).ravel()
    )
    assert session.full_check(obj, bpy.context.scene) == ""  # back as bound: valid again

    obj.data.shape_keys.key_blocks["Bulge"].mute = True
    pose_top(top)
    assert "example shape keys" in session.stale_reason(obj).lower()
    bind(obj)  # rebind with one key fewer
    assert [n for n, _w in shown_weights(obj)] == ["(rest)", "Bend"]


def test_without_example_keys_bind_is_an_error_and_changes_nothing():
    obj = tube()
    add_anchor(obj, lambda p: p.center.z > HALF - 1e-4)
    add_anchor(obj, lambda p: p.center.z < -HALF + 1e-4, mode="FRAME")
    obj.material_deform.method = "POSE_SPACE"
    activate(obj)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "Pose space needs example shapes")
    assert snapshot(obj) == before and not obj.material_deform.bound
    # a Basis and only the add-on's own key: still none
    obj.shape_key_add(name="Basis", from_mix=False)
    obj.shape_key_add(name="Material Deform", from_mix=False)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "Pose space needs example shapes")
    assert snapshot(obj) == before and not obj.material_deform.bound


def test_bad_anchor_setups_are_errors_that_change_nothing():
    obj, top, bottom = example_bar()
    top.mode = "FRAME"  # two frames
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "one anchor can be the frame")
    top.mode = "ROTATION"
    bottom.mode = "POSITION"  # a Rotation anchor needs a frame
    expect_error(bpy.ops.object.material_deform_bind, "Frame anchor")
    bottom.mode = "FRAME"
    obj.material_deform.pose_space.frozen_group = "Nope"
    expect_error(bpy.ops.object.material_deform_bind, "Frozen: no vertex group")
    obj.material_deform.pose_space.frozen_group = ""
    top.mode = "POSITION"
    obj.material_deform.anchors.remove(1)  # one Follow Empty anchor alone
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "alone cannot tell which pose")
    assert snapshot(obj) == before and not obj.material_deform.bound


def test_a_filtered_key_is_no_example():
    obj, top, bottom = example_bar()
    obj.material_deform.learn_filter = "bend"
    bind(obj)
    assert [n for n, _w in shown_weights(obj)] == ["(rest)", "Bend"]
    obj.material_deform.learn_filter = ""  # the example set changed: stale
    assert "example shape keys" in session.stale_reason(obj)


def test_frozen_group_keeps_its_faces_at_rest_and_matches_the_library():
    obj = tube()
    v = rest64(obj)
    add_key(obj, "Bend", bend(v, 0.5 * math.pi))
    add_key(obj, "Bulge", bend(v, -0.5 * math.pi, bulge=0.4))
    top = add_anchor(obj, lambda p: p.center.z > HALF - 1e-4)
    vg = obj.vertex_groups.new(name="Frozen")
    vg.add([int(i) for i in np.flatnonzero(v[:, 2] < -0.9)], 1.0, "REPLACE")
    s = obj.material_deform
    s.method = "POSE_SPACE"
    s.pose_space.frozen_group = "Frozen"
    bind(obj)
    pose_top(top, angle=0.7, dx=0.6)
    got = output(obj).astype(np.float64)
    a = bridge.mesh_arrays(obj.data)
    inside = np.zeros(len(v), bool)
    inside[v[:, 2] < -0.9] = True
    frozen = np.flatnonzero(inside[a.tris].all(1))
    fv = np.unique(a.tris[frozen])
    np.testing.assert_allclose(got[fv], v[fv], atol=1e-6 * diag(v))
    assert np.abs(got - v).max() > 0.3
    want, _w = reference(obj, [top], frozen=frozen)
    assert np.abs(got - want).max() <= 1e-9 * diag(v) + 4e-7 * np.abs(want).max()

    # the same faces as a boolean face attribute (what Blender 4 made of face maps)
    lp = np.repeat(np.arange(len(obj.data.polygons)), [len(p.vertices) for p in obj.data.polygons])
    in_poly = np.ones(len(obj.data.polygons), bool)
    loops = np.array([lo.vertex_index for lo in obj.data.loops])
    np.logical_and.at(in_poly, lp, inside[loops])
    fa = obj.data.attributes.new("Frozen faces", "BOOLEAN", "FACE")
    fa.data.foreach_set("value", in_poly)
    s.pose_space.frozen_group = "Frozen faces"
    assert "pose-space settings" not in session.stale_reason(obj)  # the very same faces
    bind(obj)  # Rebind keeps the bind pose: the same pose, solved again with these faces
    np.testing.assert_array_equal(output(obj), got.astype(np.float32))
    s.pose_space.frozen_group = "Frozen"

    # a handle on frozen faces is refused, and nothing changes
    vg.add([int(i) for i in anchor_vertices(obj, top)], 1.0, "REPLACE")
    s.pose_space.frozen_group = "Frozen"
    before = output(obj).copy()
    expect_error(bpy.ops.object.material_deform_bind, "vertices on frozen faces")
    np.testing.assert_array_equal(output(obj), before)


def test_bake_writes_the_live_pose_space_results():
    obj, top, _bottom = example_bar()
    bind(obj)
    e = top.empty
    e.keyframe_insert("location", frame=1)
    e.keyframe_insert("rotation_euler", frame=1)
    e.location.x += 1.2
    e.rotation_euler.y = -0.9
    e.keyframe_insert("location", frame=3)
    e.keyframe_insert("rotation_euler", frame=3)
    scene = bpy.context.scene
    live, weights = {}, {}
    for f in (1, 2, 3):
        scene.frame_set(f)
        live[f] = output(obj).copy()
        weights[f] = [w for _n, w in shown_weights(obj)]
    assert np.abs(live[3] - live[1]).max() > 0.5
    assert weights[1] == pytest.approx([1, 0, 0], abs=1e-9) and weights[3][0] < 0.9
    scene.frame_set(1)
    obj.material_deform.bake_output = "SHAPE_KEYS"
    obj.material_deform.bake_start, obj.material_deform.bake_end = 1, 3
    assert bpy.ops.object.material_deform_bake() == {"FINISHED"}
    for f in (1, 2, 3):
        baked = obj.data.shape_keys.key_blocks[f"MD Bake {f:04d}"]
        np.testing.assert_array_equal(np.array([k.co[:] for k in baked.data], np.float32), live[f])
    # the bake keys are no examples (the same rule as Learn from Shape Keys)
    assert ps.example_names(obj) == ["Bend", "Bulge"]


def test_rotation_anchor_turns_the_joint_like_the_library():
    obj, top, bottom = example_bar()
    mid = add_anchor(
        obj, lambda p: abs(p.center.z - 1.1) < 0.05 and p.center.x > 0.45, mode="ROTATION"
    )
    bind(obj)
    pose_top(top, angle=0.6, dx=0.5, dz=-0.2)
    from mathutils import Matrix

    e = mid.empty
    c = e.matrix_world.translation.copy()
    e.matrix_world = (
        Matrix.Translation(c)
        @ Matrix.Rotation(0.5, 4, "Y")
        @ Matrix.Translation(-c)
        @ e.matrix_world
    )
    view_update()
    got = output(obj).astype(np.float64)

    md = core.load()
    v = rest64(obj)
    tris = bridge.mesh_arrays(obj.data).tris
    keys = obj.data.shape_keys.key_blocks
    ex = [v] + [np.array([k.co[:] for k in keys[n].data], np.float64) for n in ("Bend", "Bulge")]
    hv = [anchor_vertices(obj, a) for a in (top, bottom)]
    fb = int(np.flatnonzero(np.isin(tris, hv[1]).all(1))[0])
    fm = int(np.flatnonzero(np.isin(tris, anchor_vertices(obj, mid)).all(1))[0])
    d = md.PoseSpaceDeformer(v, tris, np.stack(ex), hv, frame=fb, rotational=[(fb, fm)])
    ts = [transform_of(obj, a) for a in (top, bottom, mid)]
    hp = [v[h] @ t[:3, :3].T + t[:3, 3] for h, t in zip(hv, ts[:2], strict=True)]

    def rot(t):
        u, _s, vt = np.linalg.svd(t[:3, :3])
        return u @ vt

    want = d.deform(hp, rotations=rot(ts[1]).T @ rot(ts[2])[None])
    assert np.abs(got - want).max() <= 1e-9 * diag(v) + 4e-7 * np.abs(want).max()


def test_panel_draws_the_settings_and_the_weights_and_every_label_fits():
    from helpers import cut_texts, draw_panel

    obj, top, _bottom = example_bar()
    log = draw_panel()
    texts = [x[1] for x in log if isinstance(x, tuple)]
    assert "multiresolution" in log and "frozen_group" in log and "rest_example" in log
    assert "Bend" in texts and "Bulge" in texts  # before bind: the examples it will use
    assert cut_texts(draw_panel.tree) == []
    obj.material_deform.pose_space.multiresolution = True
    bind(obj)
    pose_top(top)
    log = draw_panel()
    assert "coarse_faces" in log
    texts = [x[1] for x in log if isinstance(x, tuple)]
    shown = {n: f"{w:.2f}" for n, w in shown_weights(obj)}
    for n, w in shown.items():
        assert n in texts and w in texts
    assert cut_texts(draw_panel.tree) == []


def test_undo_bind_and_a_pose_space_setting():
    def run(op, **kw):
        return op("EXEC_DEFAULT", True, **kw)

    obj, top, _bottom = example_bar()
    assert bpy.ops.ed.undo_push(message="setup") == {"FINISHED"}
    assert run(bpy.ops.object.material_deform_bind) == {"FINISHED"}
    pose_top(top)
    assert bpy.ops.ed.undo_push(message="moved") == {"FINISHED"}
    posed = output(obj).copy()
    obj.material_deform.pose_space.coarse_faces = 100  # not used: still valid
    assert session.stale_reason(obj) == ""
    obj.material_deform.pose_space.multiresolution = True  # stale: settings changed
    assert bpy.ops.ed.undo_push(message="setting") == {"FINISHED"}
    assert "pose-space settings" in session.stale_reason(obj)

    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects["Bar"]
    assert not obj.material_deform.pose_space.multiresolution
    assert session.stale_reason(obj) == ""
    np.testing.assert_array_equal(output(obj), posed)
    assert bpy.ops.ed.undo() == {"FINISHED"}
    assert bpy.ops.ed.undo() == {"FINISHED"}  # before Bind: unbound, no output key
    obj = bpy.data.objects["Bar"]
    assert not obj.material_deform.bound
    assert "Material Deform" not in obj.data.shape_keys.key_blocks
    assert [k.name for k in obj.data.shape_keys.key_blocks] == ["Basis", "Bend", "Bulge"]
