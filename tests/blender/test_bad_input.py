"""Bad input: a clear operator error and the mesh left exactly as it was."""

import bpy
import numpy as np
import pytest
from helpers import (
    add_anchor,
    expect_error,
    mesh_object,
    output,
    rest,
    snapshot,
    tube,
    two_end_anchors,
    update,
)


def test_no_anchors():
    obj = tube()
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "No anchors")
    assert snapshot(obj) == before and not obj.material_deform.bound


def test_empty_vertex_group():
    obj = tube()
    anc = add_anchor(obj, lambda p: p.center.z > 1.999)
    add_anchor(obj, lambda p: p.center.z < -1.999)
    obj.vertex_groups[anc.vertex_group].remove(list(range(len(obj.data.vertices))))
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "contains no whole face")
    assert snapshot(obj) == before


def test_missing_vertex_group_and_missing_stiffness_group():
    obj = tube()
    anc = add_anchor(obj, lambda p: p.center.z > 1.999)
    obj.vertex_groups.remove(obj.vertex_groups[anc.vertex_group])
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "not found")
    expect_error(bpy.ops.mesh.material_deform_stiffness_from_paint, "No vertex group 'Stiffness'")
    assert snapshot(obj) == before


def test_add_anchor_without_selection():
    obj = tube()
    obj.data.polygons.foreach_set("select", [False] * len(obj.data.polygons))
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    expect_error(bpy.ops.mesh.material_deform_add_anchor, "Select the anchor faces")
    bpy.ops.object.mode_set(mode="OBJECT")
    assert len(obj.vertex_groups) == 0 and len(obj.material_deform.anchors) == 0


def _bound_and_moved(method="MATERIAL"):
    """A bound tube whose top anchor moved once: (object, top anchor, output after the move)."""
    obj = tube()
    obj.material_deform.method = method
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.empty.location.x += 0.5
    update()
    return obj, top, output(obj).copy()


def test_deleted_empty_before_and_after_bind():
    obj, top, result = _bound_and_moved()
    bpy.data.objects.remove(top.empty)
    update()
    np.testing.assert_array_equal(output(obj), result)  # no garbage written
    expect_error(bpy.ops.object.material_deform_update, "Empty")
    np.testing.assert_array_equal(output(obj), result)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "has no Empty")
    assert snapshot(obj) == before


@pytest.mark.parametrize("method", ["MATERIAL", "EDGE", "POSE_SPACE", "PYRAMID"])
def test_empty_scaled_to_zero_after_bind(method):
    """Refused alike by every method (the positions-only ones would collapse the anchor faces
    to a point), naming the Empty; nothing written."""
    if method == "POSE_SPACE":
        from test_pose_space import example_bar

        obj, top, _ = example_bar()
        bpy.context.view_layer.objects.active = obj
        assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
        top.empty.location.x += 0.2
        update()
        result = output(obj).copy()
    else:
        obj, top, result = _bound_and_moved(method)
    top.empty.scale = (1.0, 0.0, 1.0)
    update()
    np.testing.assert_array_equal(output(obj), result)  # the live update wrote nothing
    expect_error(bpy.ops.object.material_deform_update, f"Empty '{top.empty.name}'.*scaled to zero")
    np.testing.assert_array_equal(output(obj), result)


def test_empty_unlinked_from_scene():
    obj = tube()
    top, _ = two_end_anchors(obj)
    for c in list(top.empty.users_collection):
        c.objects.unlink(top.empty)
    expect_error(bpy.ops.object.material_deform_bind, "not in the scene")


def test_empty_unlinked_after_bind_stops_live_updates_until_linked_again():
    """The live path checks the anchor Empties against one set of the scene's objects (not a
    name lookup each): an Empty taken out of the scene, even one still in another scene, stops
    the updates with a reason, and putting it back resumes them."""
    from material_deform import session

    obj, top, result = _bound_and_moved()
    empty = top.empty
    other = bpy.data.scenes.new("Elsewhere")
    other.collection.objects.link(empty)
    for c in list(empty.users_collection):
        if c != other.collection:
            c.objects.unlink(empty)
    obj.location.z += 0.1  # an update for the mesh that must not use the Empty
    update()
    np.testing.assert_array_equal(output(obj), result)  # nothing written
    assert top.name in session.stale_reason(obj)
    assert "not in the scene" in session.stale_reason(obj)  # what Update and Bind say too
    bpy.context.scene.collection.objects.link(empty)
    empty.location.x += 0.5
    update()
    assert np.abs(output(obj) - result).max() > 0.2  # live again, the anchor moved on
    assert session.stale_reason(obj) == ""
    bpy.data.scenes.remove(other)


def test_mesh_edited_after_bind_needs_rebind():
    obj = tube()
    top, _ = two_end_anchors(obj)
    bpy.ops.object.material_deform_bind()
    top.empty.location.x += 0.5
    update()
    result = output(obj).copy()
    # topology edit in Edit Mode
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide()
    bpy.ops.object.mode_set(mode="OBJECT")
    top.empty.location.x += 0.5
    update()
    from material_deform import session

    assert "Changed since bind" in session.stale_reason(obj)
    n_old = len(result)
    np.testing.assert_array_equal(output(obj)[:n_old], result)  # old result left alone
    expect_error(bpy.ops.object.material_deform_update, "Changed since bind: mesh")
    # rebinding fixes it
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    assert session.stale_reason(obj) == ""


def test_rest_shape_moved_in_edit_mode_needs_rebind():
    obj = tube()
    two_end_anchors(obj)
    bpy.ops.object.material_deform_bind()
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.transform.translate(value=(0.1, 0, 0))
    bpy.ops.object.mode_set(mode="OBJECT")
    expect_error(bpy.ops.object.material_deform_update, "Changed since bind: mesh")


def test_stiffness_repainted_after_bind_needs_rebind():
    obj = tube()
    two_end_anchors(obj)
    bpy.ops.object.material_deform_bind()
    vg = obj.vertex_groups.new(name="Stiffness")
    vg.add(list(range(8)), 1.0, "REPLACE")
    bpy.ops.mesh.material_deform_stiffness_from_paint()
    expect_error(bpy.ops.object.material_deform_update, "Changed since bind: stiffness")


def test_overlapping_anchors():
    obj = tube()
    add_anchor(obj, lambda p: p.center.z > 1.999)
    add_anchor(obj, lambda p: p.center.z > 1.7)
    expect_error(bpy.ops.object.material_deform_bind, "share faces")


def test_non_manifold_mesh():
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1)]
    obj = mesh_object("Fan", verts, [(0, 1, 2), (1, 0, 3), (0, 1, 4)])
    add_anchor(obj, lambda p: p.index == 0)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "non-manifold")
    assert snapshot(obj) == before


def test_degenerate_face():
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0), (1, 1, 0)]
    obj = mesh_object("Degenerate", verts, [(0, 1, 2), (1, 4, 2), (0, 3, 1)])  # last: collinear
    add_anchor(obj, lambda p: p.index == 0)
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "degenerate")
    assert snapshot(obj) == before


def test_part_without_anchor():
    obj = tube()
    other = tube(name="Other")
    other.location.x = 3
    bpy.ops.object.select_all(action="SELECT")
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.join()
    add_anchor(obj, lambda p: p.center.z > 1.999 and p.center.x < 1.0)
    add_anchor(obj, lambda p: p.center.z < -1.999 and p.center.x < 1.0)
    expect_error(bpy.ops.object.material_deform_bind, "no anchor")


def test_not_a_mesh_has_no_operator():
    bpy.ops.object.empty_add()
    assert not bpy.ops.object.material_deform_bind.poll()


def test_loose_vertices_are_ignored():
    obj = tube()
    me = obj.data
    me.vertices.add(1)
    me.vertices[-1].co = (5, 5, 5)
    me.update()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.empty.location.x += 1
    update()
    np.testing.assert_array_equal(output(obj)[-1], [5, 5, 5])
    assert np.abs(output(obj)[:-1, 0] - rest(obj)[:-1, 0]).max() > 0.9


def test_changing_anchor_mode_or_empty_after_bind_needs_rebind():
    from material_deform import session

    obj = tube()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.mode = "ROTATION"
    assert "Changed since bind: anchors" in session.stale_reason(obj)
    expect_error(bpy.ops.object.material_deform_update, "Changed since bind: anchors")
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    assert session.stale_reason(obj) == ""
    other = bpy.data.objects.new("E2", None)
    bpy.context.scene.collection.objects.link(other)
    top.empty = other
    expect_error(bpy.ops.object.material_deform_update, "uses another Empty")


def test_absolute_shape_keys_are_refused_and_nothing_changes():
    """With Relative unchecked Blender shows one key by Evaluation Time, never the output key
    over the Basis: Bind would succeed and the mesh never move. It says so instead, and binds
    once Relative is checked again."""
    obj = tube()
    two_end_anchors(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    obj.shape_key_add(name="Pose", from_mix=False)
    obj.data.shape_keys.use_relative = False
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "absolute shape keys.*check Relative")
    assert snapshot(obj) == before and not obj.material_deform.bound
    assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "Pose"]
    obj.data.shape_keys.use_relative = True
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}


def test_a_linked_duplicate_is_refused_and_the_original_keeps_its_result():
    """Alt+D makes an object that shares the mesh, and so its shape keys, with the original:
    Bind and Reset on it would drive or delete the original's result. Both say so; once the copy
    is made single-user it binds on its own and the original's result stays as it was."""
    obj = tube()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.empty.location.x += 1.0
    update()
    posed = output(obj).copy()
    assert np.abs(posed - rest(obj)).max() > 0.5
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.ops.object.duplicate(linked=True)
    copy = bpy.context.view_layer.objects.active
    assert copy != obj and copy.data == obj.data
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "shares its mesh with 'Bar'.*then Bind")
    expect_error(bpy.ops.object.material_deform_reset, "shares its mesh with 'Bar'.*then Reset")
    assert snapshot(obj) == before
    np.testing.assert_array_equal(output(obj), posed)
    copy.data = copy.data.copy()  # Make Single User > Object & Data
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    assert bpy.ops.object.material_deform_reset() == {"FINISHED"}
    assert copy.data.shape_keys is None or "Material Deform" not in copy.data.shape_keys.key_blocks
    np.testing.assert_array_equal(output(obj), posed)


def test_a_cap_with_corners_in_the_middle_of_its_edges_binds_without_slivers():
    """A cylinder whose cap edges were cut in the middle: Blender's tessellation of that n-gon
    holds triangles of round-off area (or none at all on some versions, which Bind refused as
    degenerate). The triangles Bind uses have none, and the bar bends as one without it."""
    import bmesh
    from material_deform import bridge
    from material_deform.triangulation import FLAT_RATIO

    bpy.ops.mesh.primitive_cylinder_add(vertices=12, depth=4, radius=0.5, end_fill_type="NGON")
    obj = bpy.context.object
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    top = [e for e in bm.edges if all(v.co.z > 1.99 for v in e.verts)]
    bmesh.ops.subdivide_edges(bm, edges=top[:3], cuts=1)
    bm.to_mesh(obj.data)
    bm.free()
    a = bridge.mesh_arrays(obj.data)
    p = a.rest[a.tris]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    longest = np.max(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), axis=1)
    assert (2 * area / longest > 10 * FLAT_RATIO * longest).all()
    assert len(a.tris) == sum(len(q.vertices) - 2 for q in obj.data.polygons)
    add_anchor(obj, lambda q: q.center.z > 1.99)
    bottom = add_anchor(obj, lambda q: q.center.z < -1.99)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    bottom.empty.location.x += 1.0
    update()
    x, r = output(obj), rest(obj)
    low = r[:, 2] < -1.99
    assert np.isfinite(x).all()
    np.testing.assert_allclose(x[low] - r[low], [[1.0, 0.0, 0.0]] * int(low.sum()), atol=1e-5)
    np.testing.assert_allclose(x[~low & (r[:, 2] > 1.99)], r[r[:, 2] > 1.99], atol=1e-5)


def test_linked_and_overridden_objects_are_refused_and_nothing_changes(tmp_path):
    """A bound bar in a library file, linked into a shot: its data is read-only here, and a
    library override keeps neither the mesh's keys nor the add-on's settings on reopen. Bind,
    Rebind and Reset say so and change nothing; the live update leaves the linked key alone."""
    obj = tube()
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    empties = [a.empty for a in obj.material_deform.anchors]
    names = ["Bar", *(e.name for e in empties)]
    lib = tmp_path / "lib.blend"
    bpy.data.libraries.write(str(lib), {obj, *empties}, fake_user=True)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    with bpy.data.libraries.load(str(lib), link=True) as (_src, dst):
        dst.objects = list(names)
    for o in dst.objects:
        bpy.context.scene.collection.objects.link(o)
    linked = bpy.data.objects["Bar"]
    assert linked.library is not None and linked.material_deform.bound
    bpy.context.view_layer.objects.active = linked
    before = snapshot(linked)
    expect_error(
        bpy.ops.object.material_deform_bind,
        "mesh is linked from 'lib.blend'|object is linked from 'lib.blend'",
    )
    expect_error(bpy.ops.object.material_deform_bind, "Make it local", at_current_pose=True)
    expect_error(bpy.ops.object.material_deform_reset, "linked from 'lib.blend'")
    bake = bpy.ops.object.material_deform_bake_point_cache
    expect_error(bake, "linked from 'lib.blend'", filepath=str(tmp_path / "x.pc2"))
    assert not (tmp_path / "x.pc2").exists()
    bpy.data.objects[names[1]].location.x += 1.0  # its Empty: the linked key stays as saved
    update()
    assert snapshot(linked) == before
    override = linked.override_create(remap_local_usages=True)
    bpy.context.view_layer.objects.active = override
    expect_error(bpy.ops.object.material_deform_bind, "is a library override|linked from")
