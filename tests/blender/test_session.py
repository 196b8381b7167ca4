"""What the session guarantees for every method: no result is ever written from a stale rest
shape, the reference key is never written, the output key is followed through a rename, anchor
faces follow their Empty in world space (parented or not), and Bind is atomic."""

import bmesh
import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    add_anchor,
    anchor_vertices,
    expect_error,
    output,
    paint,
    rest,
    tube,
    two_end_anchors,
    update,
)
from material_deform import methods, session


def bound_bar():
    obj = tube()
    top, bottom = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    return obj, top, bottom


def world(obj, local):
    m = np.array(obj.matrix_world)
    return local @ m[:3, :3].T + m[:3, 3]


def moved_then(obj, top, change):
    """Move the top Empty (the key is written), apply ``change``, move it again: returns the key
    after the first move, after the change and after the second move."""
    top.empty.location.x += 1.0
    update()
    first = output(obj).copy()
    change()
    update()
    changed = output(obj).copy()
    top.empty.location.x += 0.5
    update()
    return first, changed, output(obj)


def test_apply_scale_after_bind_stops_live_updates():
    obj, top, _ = bound_bar()

    def apply_scale():
        activate(obj)
        obj.scale = (2.0, 2.0, 2.0)
        assert bpy.ops.object.transform_apply(location=False, rotation=False, scale=True) == {
            "FINISHED"
        }

    first, changed, after = moved_then(obj, top, apply_scale)
    assert np.abs(first - rest(obj) / 2.0).max() > 0.5  # it had moved
    np.testing.assert_array_equal(after, changed)  # nothing written from the old rest
    assert "Rest shape changed" in session.stale_reason(obj)


def test_basis_written_from_script_stops_live_updates():
    obj, top, _ = bound_bar()

    def nudge_basis():
        obj.data.shape_keys.reference_key.data[5].co.y += 0.25

    first, changed, after = moved_then(obj, top, nudge_basis)
    np.testing.assert_array_equal(after, first)
    assert "Rest shape changed" in session.stale_reason(obj)


def test_vertices_reordered_in_object_mode_stop_live_updates():
    obj, top, _ = bound_bar()

    def reverse_vertices():
        bm = bmesh.new()
        bm.from_mesh(obj.data)
        n = len(bm.verts)
        for i, v in enumerate(bm.verts):
            v.index = n - 1 - i
        bm.verts.sort()
        bm.to_mesh(obj.data)
        bm.free()
        obj.data.update()

    first, changed, after = moved_then(obj, top, reverse_vertices)
    np.testing.assert_array_equal(changed, first[::-1])  # reordered by Blender
    np.testing.assert_array_equal(after, changed)  # and not re-solved from the old order
    assert "Rest shape changed" in session.stale_reason(obj)


def test_removed_basis_is_refused_and_the_reference_key_never_written():
    obj, top, _ = bound_bar()
    top.empty.location.x += 1.0
    update()
    obj.shape_key_remove(obj.data.shape_keys.reference_key)
    assert obj.data.shape_keys.reference_key.name == "Material Deform"
    before = rest(obj).copy()
    top.empty.location.x += 0.5
    update()
    np.testing.assert_array_equal(rest(obj), before)
    assert "rest shape" in session.stale_reason(obj)
    expect_error(bpy.ops.object.material_deform_update, "rest shape|Basis")
    np.testing.assert_array_equal(rest(obj), before)


def test_renamed_output_key_keeps_updating_with_no_second_key(tmp_path):
    obj, top, _ = bound_bar()
    obj.data.shape_keys.key_blocks["Material Deform"].name = "Pose"
    top.empty.location.x += 1.0
    update()
    keys = obj.data.shape_keys.key_blocks
    assert [k.name for k in keys] == ["Basis", "Pose"]
    moved = keys["Pose"].data[len(keys["Pose"].data) - 1].co.x - rest(obj)[-1, 0]
    assert moved == pytest.approx(1.0, abs=1e-5)  # the top ring follows the Empty
    # the name is kept with the bind: after saving and reloading the same key is written
    path = str(tmp_path / "renamed.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    bpy.data.objects[obj.material_deform.anchors[0].empty.name].location.x += 0.5
    update()
    assert [k.name for k in obj.data.shape_keys.key_blocks] == ["Basis", "Pose"]
    assert session.stale_reason(obj) == ""


def test_deleted_output_key_is_reported_not_silently_recreated():
    obj, top, _ = bound_bar()
    obj.shape_key_remove(obj.data.shape_keys.key_blocks["Material Deform"])
    session.clear_cache()  # as after reloading: the key block's identity is unknown
    top.empty.location.x += 1.0
    update()
    assert [k.name for k in obj.data.shape_keys.key_blocks] == ["Basis"]
    assert "is gone" in session.stale_reason(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}  # Bind makes a new one
    assert "Material Deform" in obj.data.shape_keys.key_blocks


def anchor_world(obj, anchor, positions):
    return world(obj, positions[anchor_vertices(obj, anchor)])


def follows_empty(anchor, bind_world):
    """Where faces at ``bind_world`` (world, at bind) are when they follow the Empty exactly:
    E_now inv(E_bind) applied to them."""
    e_bind = np.array(tuple(anchor.bind_matrix)).reshape(4, 4)
    m = np.array(anchor.empty.matrix_world) @ np.linalg.inv(e_bind)
    return bind_world @ m[:3, :3].T + m[:3, 3]


def test_anchor_faces_follow_parented_empties_exactly_in_world_space():
    obj = tube()
    top, bottom = two_end_anchors(obj)
    for anc in (top, bottom):
        e = anc.empty
        m = e.matrix_world.copy()
        e.parent = obj
        e.matrix_parent_inverse = obj.matrix_world.inverted()
        e.matrix_world = m
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    r = rest(obj).astype(np.float64)
    bind_world = {a.name: anchor_world(obj, a, r) for a in (top, bottom)}
    # moving the object carries the parented Empties along: a rigid move, no deformation
    obj.location = (3.0, -1.0, 0.5)
    obj.rotation_euler = (0.0, 0.3, 0.0)
    update()
    np.testing.assert_allclose(output(obj), r, atol=2e-5)
    # then turning one Empty: its faces follow it exactly in world space, the other's stay
    top.empty.rotation_euler.x += 0.4
    top.empty.location.z += 0.3
    update()
    x = output(obj).astype(np.float64)
    for a in (top, bottom):
        np.testing.assert_allclose(
            anchor_world(obj, a, x), follows_empty(a, bind_world[a.name]), atol=2e-5
        )
    assert np.abs(x - r).max() > 0.1


def test_unparented_empties_hold_their_faces_when_the_object_moves():
    obj = tube()
    top, bottom = two_end_anchors(obj)
    for anc in (top, bottom):  # Add Anchor parents them to the mesh: unparent, keep the place
        m = anc.empty.matrix_world.copy()
        anc.empty.parent = None
        anc.empty.matrix_world = m
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    r = rest(obj).astype(np.float64)
    before = {a.name: anchor_world(obj, a, r) for a in (top, bottom)}
    obj.location = (2.0, 0.0, 1.0)
    update()
    x = output(obj).astype(np.float64)
    for a in (top, bottom):  # the anchor faces stay with their Empties, which did not move
        np.testing.assert_allclose(anchor_world(obj, a, x), before[a.name], atol=2e-5)


def test_vertices_added_from_a_script_are_refused_and_bind_writes_nothing():
    obj, top, _ = bound_bar()
    s = obj.material_deform
    saved = (s.fp_topology, s.fp_anchors, s.fp_stiffness, s.fp_method, tuple(s.obj_bind_matrix))
    obj.data.vertices.add(3)
    expect_error(bpy.ops.object.material_deform_bind, "vertices were added outside Edit Mode")
    assert (
        s.fp_topology,
        s.fp_anchors,
        s.fp_stiffness,
        s.fp_method,
        tuple(s.obj_bind_matrix),
    ) == saved
    top.empty.location.x += 1.0
    update()
    assert session.stale_reason(obj) != ""


def test_stiffness_attribute_of_the_wrong_type_is_reported():
    obj = tube()
    two_end_anchors(obj)
    obj.data.attributes.new("md_shear_stiffness", "INT", "FACE")
    expect_error(bpy.ops.object.material_deform_bind, "is INT on FACE, expected FLOAT")


def test_nan_stiffness_is_named_as_nan():
    obj = tube()
    two_end_anchors(obj)
    a = obj.data.attributes.new("md_shear_stiffness", "FLOAT", "FACE")
    vals = np.ones(len(a.data), np.float32)
    vals[3] = np.nan
    a.data.foreach_set("value", vals)
    expect_error(bpy.ops.object.material_deform_bind, "NaN or infinite")


def test_method_menu_lists_the_registered_methods():
    obj = tube()
    keys = [m.key for m in methods.all_methods()]
    assert "MATERIAL" in keys
    items = obj.material_deform.bl_rna.properties["method"].enum_items
    assert [i.identifier for i in items] == keys
    assert len({m.number for m in methods.all_methods()}) == len(keys)


def test_changing_the_method_after_bind_needs_rebind():
    obj, top, _ = bound_bar()
    keys = [m.key for m in methods.all_methods()]
    if len(keys) < 2:
        pytest.skip("one method registered")
    obj.material_deform.method = keys[1]
    assert "Changed since bind: method" in session.stale_reason(obj)
    obj.material_deform.method = keys[0]  # changed back: compared with the bound state
    assert session.stale_reason(obj) == ""


# --- the bind pose (issue 16, trap 2) -----------------------------------------------------------


def pose(top):
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.5
    update()


def test_rebind_keeps_the_bind_pose_so_the_mesh_keeps_its_pose():
    obj, top, bottom = bound_bar()
    bind_m = [tuple(a.bind_matrix) for a in (top, bottom)]
    pose(top)
    posed = output(obj).copy()
    assert np.abs(posed - rest(obj)).max() > 0.5
    assert bpy.ops.object.material_deform_rebind() == {"FINISHED"}
    assert [tuple(a.bind_matrix) for a in (top, bottom)] == bind_m
    np.testing.assert_allclose(output(obj), posed, atol=1e-5)  # no snap back to rest
    # and the Empties still sit on their faces: the bind pose gives the rest shape again
    top.empty.location.x -= 1.0
    top.empty.rotation_euler.y = 0.0
    update()
    np.testing.assert_allclose(output(obj), rest(obj), atol=1e-5)


def test_rebind_at_a_later_frame_keeps_earlier_frames_right():
    obj, top, _ = bound_bar()
    scene = bpy.context.scene
    e = top.empty
    e.keyframe_insert("location", frame=1)  # the bind pose
    e.location.x += 1.5
    e.keyframe_insert("location", frame=10)
    scene.frame_set(10)
    at10 = output(obj).copy()
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}  # Bind again = Rebind
    scene.frame_set(1)
    np.testing.assert_allclose(output(obj), rest(obj), atol=1e-5)  # not bent the wrong way
    scene.frame_set(10)
    np.testing.assert_allclose(output(obj), at10, atol=1e-5)


def test_bind_at_current_pose_makes_where_the_empties_are_the_bind_pose():
    obj, top, _ = bound_bar()
    pose(top)
    op = bpy.ops.object.material_deform_bind
    assert op(at_current_pose=True) == {"FINISHED"}
    np.testing.assert_array_equal(output(obj), rest(obj))  # back at rest, Empties stay
    np.testing.assert_allclose(
        np.array(tuple(top.bind_matrix)).reshape(4, 4), np.array(top.empty.matrix_world)
    )
    desc = op.get_rna_type().properties["at_current_pose"].description
    assert "rest shape" in desc and "no longer sit on their faces" in desc


def test_an_anchor_added_to_a_posed_mesh_sits_on_its_faces_and_rebind_keeps_the_pose():
    obj, top, _ = bound_bar()
    obj.location = (0.5, 0.0, 0.0)  # the object moved since bind, too
    update()
    pose(top)
    posed = output(obj).astype(np.float64)
    mid = add_anchor(obj, lambda p: abs(p.center.z - 0.1) < 0.01)  # a middle ring
    idx = anchor_vertices(obj, mid)
    shown = world(obj, posed[idx]).mean(axis=0)  # where the user sees those faces
    np.testing.assert_allclose(np.array(mid.empty.matrix_world.translation), shown, atol=1e-4)
    assert "Changed since bind: anchors" in session.stale_reason(obj)
    assert bpy.ops.object.material_deform_rebind() == {"FINISHED"}
    assert session.stale_reason(obj) == ""
    # the mesh keeps its pose: the old anchor exactly, the new ring up to its rigid fit
    top_idx = anchor_vertices(obj, top)
    np.testing.assert_allclose(output(obj)[top_idx], posed[top_idx], atol=1e-5)
    np.testing.assert_allclose(output(obj)[idx], posed[idx], atol=0.05)
    # and Reset Empties brings all three back to the rest shape
    assert bpy.ops.object.material_deform_reset_empties() == {"FINISHED"}
    update()
    np.testing.assert_allclose(output(obj), rest(obj), atol=1e-5)


def test_bind_of_a_turned_scaled_object_gives_the_rest_bit_for_bit():
    obj = tube()
    obj.rotation_euler = (0.3, 0.2, 0.9)
    obj.scale = (1.3, 0.7, 1.1)
    update()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    np.testing.assert_array_equal(output(obj), rest(obj))
    pose(top)
    assert bpy.ops.object.material_deform_reset_empties() == {"FINISHED"}
    update()
    # (a parented Empty's world matrix goes through Blender's float32 parent products)
    np.testing.assert_allclose(output(obj), rest(obj), rtol=0, atol=1e-6)


def test_reset_empties_puts_them_back_to_the_bind_pose():
    obj, top, bottom = bound_bar()
    pose(top)
    bottom.empty.rotation_euler.x = 0.3
    obj.location = (1.0, 2.0, 0.0)  # the Empties are parented: they move with the object
    update()
    assert np.abs(output(obj) - rest(obj)).max() > 0.5
    assert bpy.ops.object.material_deform_reset_empties() == {"FINISHED"}
    update()
    np.testing.assert_allclose(output(obj), rest(obj), atol=1e-5)
    # also from the posing view, after Reset (the bind pose stays with the anchors)
    pose(top)
    assert bpy.ops.object.material_deform_reset() == {"FINISHED"}
    activate(top.empty)
    assert bpy.ops.object.material_deform_reset_empties() == {"FINISHED"}
    activate(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    np.testing.assert_array_equal(output(obj), rest(obj))
    top.empty.location.x += 1.0
    update()
    idx = anchor_vertices(obj, top)
    np.testing.assert_allclose(output(obj)[idx, 0] - rest(obj)[idx, 0], 1.0, atol=1e-5)


# --- staleness against the bound state (trap 4) ------------------------------------------------


def test_a_setting_changed_and_changed_back_leaves_the_bind_valid():
    obj, top, _ = bound_bar()
    s = obj.material_deform
    s.anisotropic = True
    assert session.stale_reason(obj) != ""
    s.anisotropic = False
    assert session.stale_reason(obj) == ""
    paint(obj, "Region", lambda v: 1.0)
    s.region_group = "Region"
    assert "region" in session.stale_reason(obj)
    s.region_group = ""
    assert session.stale_reason(obj) == ""
    top.mode = "ROTATION"
    assert "anchors" in session.stale_reason(obj)
    top.mode = "POSITION"
    assert session.stale_reason(obj) == ""
    pose(top)  # and it really updates
    assert np.abs(output(obj) - rest(obj)).max() > 0.5


# --- Add Anchor (traps 1 and 7) ------------------------------------------------------------------


def test_add_anchor_in_object_mode_is_refused():
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    assert all(p.select for p in cube.data.polygons)  # a stale selection would be all faces
    expect_error(bpy.ops.mesh.material_deform_add_anchor, "Edit Mode")
    assert len(cube.vertex_groups) == 0 and len(cube.material_deform.anchors) == 0
    assert [o.type for o in bpy.data.objects] == ["MESH"]


def test_new_anchor_empties_are_parented_to_the_mesh_and_follow_it():
    obj = tube()
    obj.location = (1.0, -2.0, 0.5)
    obj.rotation_euler = (0.2, 0.0, 0.7)
    obj.scale = (1.5, 1.0, 0.8)  # non-uniform
    update()
    top, bottom = two_end_anchors(obj)
    m = np.array(obj.matrix_world)
    for anc in (top, bottom):
        assert anc.empty.parent == obj
        idx = anchor_vertices(obj, anc)
        centre = (m @ np.append(rest(obj)[idx].mean(axis=0), 1.0))[:3]  # a regular ring
        np.testing.assert_allclose(np.array(anc.empty.matrix_world.translation), centre, atol=1e-5)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    # an animated object carries its anchors along: no deformation at any frame
    scene = bpy.context.scene
    obj.keyframe_insert("location", frame=1)
    obj.keyframe_insert("rotation_euler", frame=1)
    obj.location = (4.0, 1.0, -1.0)
    obj.rotation_euler = (1.0, 0.5, 0.0)
    obj.keyframe_insert("location", frame=10)
    obj.keyframe_insert("rotation_euler", frame=10)
    for f in (1, 5, 10):
        scene.frame_set(f)
        np.testing.assert_allclose(output(obj), rest(obj), atol=5e-5)
    # turning an Empty: its faces follow it exactly in world space
    r = rest(obj).astype(np.float64)
    bind_world = anchor_world(obj, top, r)  # the world place of its faces now (at rest)
    e_before = np.array(top.empty.matrix_world)
    top.empty.rotation_euler.x += 0.5
    update()
    moved = np.array(top.empty.matrix_world) @ np.linalg.inv(e_before)
    expect = bind_world @ moved[:3, :3].T + moved[:3, 3]
    np.testing.assert_allclose(anchor_world(obj, top, output(obj)), expect, atol=5e-5)
