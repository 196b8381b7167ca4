"""What the session guarantees for every method: no result is ever written from a stale rest
shape, the reference key is never written, the output key is followed through a rename, anchor
faces follow their Empty in world space (parented or not), and Bind is atomic."""

import bmesh
import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    anchor_vertices,
    expect_error,
    output,
    rest,
    tube,
    two_end_anchors,
    update,
)
from material_deform import methods, session


def bound_bar():
    obj = tube()
    top, bottom = two_end_anchors(obj)
    assert bpy.ops.mesh.material_deform_bind() == {"FINISHED"}
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
    expect_error(bpy.ops.mesh.material_deform_update, "rest shape|Basis")
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
    assert bpy.ops.mesh.material_deform_bind() == {"FINISHED"}  # Bind makes a new one
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
    assert bpy.ops.mesh.material_deform_bind() == {"FINISHED"}
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
    obj, top, bottom = bound_bar()
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
    expect_error(bpy.ops.mesh.material_deform_bind, "vertices were added outside Edit Mode")
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
    expect_error(bpy.ops.mesh.material_deform_bind, "is INT on FACE, expected FLOAT")


def test_nan_stiffness_is_named_as_nan():
    obj = tube()
    two_end_anchors(obj)
    a = obj.data.attributes.new("md_shear_stiffness", "FLOAT", "FACE")
    vals = np.ones(len(a.data), np.float32)
    vals[3] = np.nan
    a.data.foreach_set("value", vals)
    expect_error(bpy.ops.mesh.material_deform_bind, "NaN or infinite")


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
    assert "Method changed" in session.stale_reason(obj)
