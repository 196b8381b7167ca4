"""Ctrl+Z: every operator is one undo step. Undo really runs headless: operators get the undo
flag (``op('EXEC_DEFAULT', True)``, what the UI does), hand-made edits get an explicit
``ed.undo_push`` (what the UI does after a transform or a property change), and ``ed.undo`` /
``ed.redo`` load the steps back. Memfile undo replaces the datablocks, so objects are fetched
again by name after each step."""

import bpy
import numpy as np
from helpers import (
    activate,
    add_anchor,
    anchor_vertices,
    output,
    rest,
    select_faces,
    tube,
    two_end_anchors,
    update,
)
from material_deform import session

SHEAR, BEND = "md_shear_stiffness", "md_bend_stiffness"


def push(message):
    assert bpy.ops.ed.undo_push(message=message) == {"FINISHED"}


def undo(name="Bar"):
    assert bpy.ops.ed.undo() == {"FINISHED"}
    return bpy.data.objects[name]


def redo(name="Bar"):
    assert bpy.ops.ed.redo() == {"FINISHED"}
    return bpy.data.objects[name]


def run(op, **kw):
    """Run an operator as the UI does: registered as an undo step."""
    return op("EXEC_DEFAULT", True, **kw)


def attr(obj, name):
    a = obj.data.attributes.get(name)
    if a is None:
        return None
    out = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", out)
    return out


def paint(obj, weight_of_z):
    vg = obj.vertex_groups.get("Stiffness") or obj.vertex_groups.new(name="Stiffness")
    for v in obj.data.vertices:
        vg.add([v.index], float(weight_of_z(v.co.z)), "REPLACE")


def key_names(obj):
    keys = obj.data.shape_keys
    return None if keys is None else [k.name for k in keys.key_blocks]


def bound_bar():
    obj = tube()
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    return obj


def top_empty(obj):
    return obj.material_deform.anchors[0].empty


def test_undo_stiffness_from_paint_restores_attributes():
    obj = tube(rings=5)
    paint(obj, lambda z: (z + 2.0) / 4.0)
    push("painted")
    assert run(bpy.ops.mesh.material_deform_stiffness_from_paint) == {"FINISHED"}
    psi1, phi1 = attr(obj, SHEAR), attr(obj, BEND)
    assert psi1 is not None and phi1 is not None

    obj = undo()  # no attributes before the first conversion
    assert attr(obj, SHEAR) is None and attr(obj, BEND) is None
    obj = redo()
    assert attr(obj, SHEAR).tobytes() == psi1.tobytes()
    assert attr(obj, BEND).tobytes() == phi1.tobytes()

    paint(obj, lambda z: 1.0 - (z + 2.0) / 4.0)  # repaint and convert again
    push("repainted")
    assert run(bpy.ops.mesh.material_deform_stiffness_from_paint) == {"FINISHED"}
    assert not np.array_equal(attr(obj, SHEAR), psi1)
    obj = undo()  # the repaint is still there, the conversion is undone
    obj = undo()  # and now the paint too
    assert attr(obj, SHEAR).tobytes() == psi1.tobytes()
    assert attr(obj, BEND).tobytes() == phi1.tobytes()
    assert obj.data.attributes[SHEAR].domain == "FACE"
    assert obj.data.attributes[BEND].domain == "EDGE"


def test_undo_add_anchor_in_edit_mode():
    obj = tube()
    add_anchor(obj, lambda p: p.center.z > 1.999)
    first_empty = obj.material_deform.anchors[0].empty.name
    select_faces(obj, lambda p: p.center.z < -1.999)  # leaves Edit Mode on
    push("selected")
    assert run(bpy.ops.mesh.material_deform_add_anchor) == {"FINISHED"}
    assert obj.mode == "EDIT" and len(obj.material_deform.anchors) == 2
    second_empty = obj.material_deform.anchors[1].empty.name
    assert "Anchor.001" in obj.vertex_groups

    obj = undo()  # an edit-mesh step: Empty, list entry and vertex group all go
    assert obj.mode == "EDIT"
    s = obj.material_deform
    assert [a.name for a in s.anchors] == ["Anchor"]
    assert second_empty not in bpy.data.objects
    assert list(obj.vertex_groups.keys()) == ["Anchor"]
    bpy.ops.object.mode_set(mode="OBJECT")
    assert s.anchors[0].empty.name == first_empty  # the first anchor is untouched
    assert len(anchor_vertices(obj, s.anchors[0])) == 8

    bpy.ops.object.mode_set(mode="EDIT")
    obj = redo()
    s = obj.material_deform
    assert [a.name for a in s.anchors] == ["Anchor", "Anchor.001"]
    assert s.anchors[1].empty is bpy.data.objects[second_empty]
    bpy.ops.object.mode_set(mode="OBJECT")
    assert len(anchor_vertices(obj, s.anchors[1])) == 8
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}  # the redone anchor works


def test_undo_add_anchor_while_bound_keeps_the_bind():
    obj = bound_bar()
    select_faces(obj, lambda p: abs(p.center.z - 0.1) < 0.01)  # a ring in the middle
    push("selected")
    assert run(bpy.ops.mesh.material_deform_add_anchor) == {"FINISHED"}
    assert "Changed since bind: anchors" in session.stale_reason(obj)

    obj = undo()  # in Edit Mode: the bind is valid again once we leave it
    assert obj.mode == "EDIT" and len(obj.material_deform.anchors) == 2
    assert obj.material_deform.rebind_reason == "" and session.stale_reason(obj) == ""
    bpy.ops.object.mode_set(mode="OBJECT")
    top_empty(obj).location.x += 1.0
    update()
    idx = anchor_vertices(obj, obj.material_deform.anchors[0])
    np.testing.assert_allclose(output(obj)[idx, 0] - rest(obj)[idx, 0], 1.0, atol=1e-5)
    assert session.stale_reason(obj) == ""


def test_undo_bind_unbinds_and_drops_the_solver():
    obj = tube()
    two_end_anchors(obj)
    before = rest(obj).copy()
    push("anchors")
    assert run(bpy.ops.object.material_deform_bind) == {"FINISHED"}
    assert obj.as_pointer() in session.state._cache

    obj = undo()
    assert not obj.material_deform.bound and obj.data.shape_keys is None
    assert rest(obj).tobytes() == before.tobytes()
    assert obj.as_pointer() not in session.state._cache  # no solver kept for a bind that is gone
    top_empty(obj).location.x += 1.0
    update()  # the live handler must leave an unbound object alone
    assert obj.data.shape_keys is None and session.stale_reason(obj) == ""
    top_empty(obj).location.x -= 1.0  # (not an undo step: put it back before redoing)
    update()

    obj = redo()  # bound again; the Empty is back where it was at bind
    assert obj.material_deform.bound
    assert key_names(obj) == ["Basis", "Material Deform"]
    np.testing.assert_array_equal(output(obj), before)
    top_empty(obj).location.x += 1.0
    update()
    idx = anchor_vertices(obj, obj.material_deform.anchors[0])
    np.testing.assert_allclose(output(obj)[idx, 0] - before[idx, 0], 1.0, atol=1e-5)
    push("moved")

    obj = undo()
    obj = undo()
    assert not obj.material_deform.bound and top_empty(obj).location.x == 0.0
    assert run(bpy.ops.object.material_deform_bind) == {"FINISHED"}  # and binding again works
    top_empty(obj).location.x += 0.5
    update()
    np.testing.assert_allclose(output(obj)[idx, 0] - before[idx, 0], 0.5, atol=1e-5)


def test_undo_live_deformation_restores_output_bit_for_bit():
    obj = bound_bar()
    basis = rest(obj).copy()
    top_empty(obj).location.x += 0.5
    update()
    push("first move")  # what the UI pushes after a transform
    first = output(obj).copy()
    top_empty(obj).location.x += 0.5
    top_empty(obj).rotation_euler.y = 0.4
    update()
    push("second move")
    second = output(obj).copy()
    assert np.abs(second - first).max() > 0.1

    obj = undo()
    assert top_empty(obj).location.x == 0.5
    assert output(obj).tobytes() == first.tobytes()
    assert rest(obj).tobytes() == basis.tobytes()
    update()  # the live handler runs again after undo: it must write the same result
    assert output(obj).tobytes() == first.tobytes()
    assert session.stale_reason(obj) == ""

    obj = redo()
    assert output(obj).tobytes() == second.tobytes()
    assert rest(obj).tobytes() == basis.tobytes()
    obj = undo()
    top_empty(obj).rotation_euler.y = 0.4  # live updates still use the right solver
    top_empty(obj).location.x += 0.5
    update()
    assert output(obj).tobytes() == second.tobytes()


def test_undo_rebind_at_current_pose_restores_the_old_bind_pose():
    # The live path keeps the bind matrices with the cached solver, and a rebind at the current
    # pose keeps the solver (same mesh, anchors and stiffness): undoing it must bring the old
    # bind pose back into the deformation, not only into the file.
    obj = bound_bar()
    top_empty(obj).location.x += 0.5
    update()
    push("moved")
    first = output(obj).copy()
    assert np.abs(first - rest(obj)).max() > 0.3
    assert run(bpy.ops.object.material_deform_bind, at_current_pose=True) == {"FINISHED"}
    np.testing.assert_allclose(output(obj), rest(obj), atol=1e-6)  # the new bind pose
    top_empty(obj).location.x += 0.3
    update()
    push("moved again")
    obj = undo()  # the second move
    obj = undo()  # the rebind
    assert top_empty(obj).location.x == 0.5
    top_empty(obj).location.x = 0.6  # a live update relative to the first bind
    update()
    top_empty(obj).location.x = 0.5
    update()
    np.testing.assert_allclose(output(obj), first, atol=1e-6)


def test_undo_update_operator_then_live_on_recomputes():
    obj = bound_bar()
    obj.material_deform.live = False
    top_empty(obj).location.x += 0.7
    update()
    push("moved, live off")
    at_rest = output(obj).copy()
    assert run(bpy.ops.object.material_deform_update) == {"FINISHED"}
    moved = output(obj).copy()
    assert np.abs(moved - at_rest).max() > 0.5

    obj = undo()  # the Update is undone, the Empty stays moved
    assert output(obj).tobytes() == at_rest.tobytes()
    assert top_empty(obj).location.x == np.float32(0.7)
    obj = redo()
    assert output(obj).tobytes() == moved.tobytes()
    obj = undo()
    assert output(obj).tobytes() == at_rest.tobytes()
    obj.material_deform.live = True
    obj.update_tag()  # (setting Live from Python tags nothing) the next live update must not
    update()  # skip the write as if the undone Update's result were still in the key
    assert output(obj).tobytes() == moved.tobytes()


def test_undo_reset_brings_the_deformation_back():
    obj = tube()
    before = rest(obj).copy()
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top_empty(obj).location.z += 0.7
    update()
    push("deformed")
    deformed = output(obj).copy()
    assert run(bpy.ops.object.material_deform_reset) == {"FINISHED"}
    assert obj.data.shape_keys is None
    assert rest(obj).tobytes() == before.tobytes()

    obj = undo()
    s = obj.material_deform
    assert s.bound and key_names(obj) == ["Basis", "Material Deform"]
    assert output(obj).tobytes() == deformed.tobytes()
    assert rest(obj).tobytes() == before.tobytes()
    update()  # solver rebuilt for the restored bind: same result bit for bit
    assert output(obj).tobytes() == deformed.tobytes()
    assert session.stale_reason(obj) == ""

    obj = redo()  # Reset again: exact rest shape
    assert not obj.material_deform.bound and obj.data.shape_keys is None
    assert rest(obj).tobytes() == before.tobytes()
    obj = undo()
    assert output(obj).tobytes() == deformed.tobytes()
    top_empty(obj).location.z -= 0.7  # back to the bind pose: exactly the rest shape
    update()
    np.testing.assert_allclose(output(obj), before, atol=1e-5)


def test_undo_bake_removes_baked_keys():
    obj = bound_bar()
    scene = bpy.context.scene
    e = top_empty(obj)
    e.keyframe_insert("location", frame=1)
    e.location.x += 1.0
    e.keyframe_insert("location", frame=3)
    scene.frame_set(1)
    push("animated")
    at1 = output(obj).copy()
    assert run(bpy.ops.object.material_deform_bake, frame_start=1, frame_end=3) == {"FINISHED"}
    assert all(f"MD Bake {f:04d}" in key_names(obj) for f in (1, 2, 3))
    assert obj.data.shape_keys.animation_data is not None

    obj = undo()
    assert key_names(obj) == ["Basis", "Material Deform"]
    keys = obj.data.shape_keys
    assert keys.animation_data is None or keys.animation_data.action is None
    assert obj.material_deform.live and keys.key_blocks["Material Deform"].value == 1.0
    assert output(obj).tobytes() == at1.tobytes()

    obj = redo()
    assert all(f"MD Bake {f:04d}" in key_names(obj) for f in (1, 2, 3))
    assert not obj.material_deform.live
    obj = undo()
    bpy.context.scene.frame_set(3)  # live again: the animation drives the output
    idx = anchor_vertices(obj, obj.material_deform.anchors[0])
    np.testing.assert_allclose(output(obj)[idx, 0] - rest(obj)[idx, 0], 1.0, atol=1e-5)


def test_undo_of_a_setting_change_clears_the_stale_verdict():
    obj = bound_bar()
    push("bound")
    obj.material_deform.anchors[0].mode = "ROTATION"  # makes the bind stale
    push("mode")
    assert "Changed since bind: anchors" in session.stale_reason(obj)

    obj = undo()
    s = obj.material_deform
    assert s.anchors[0].mode == "POSITION" and s.rebind_reason == ""
    assert session.stale_reason(obj) == ""
    top_empty(obj).location.x += 1.0
    update()
    idx = anchor_vertices(obj, s.anchors[0])
    np.testing.assert_allclose(output(obj)[idx, 0] - rest(obj)[idx, 0], 1.0, atol=1e-5)
    top_empty(obj).location.x -= 1.0  # (not an undo step: put it back before redoing)
    update()

    obj = redo()  # stale again: no update
    assert "Changed since bind: anchors" in session.stale_reason(obj)
    frozen = output(obj).copy()
    top_empty(obj).location.x += 1.0
    update()
    assert output(obj).tobytes() == frozen.tobytes()


def test_redo_of_a_stiffness_change_never_uses_the_old_solver():
    obj = tube()
    paint(obj, lambda z: 1.0 if abs(z) < 0.7 else 0.0)
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    push("bound")
    paint(obj, lambda z: 0.0)
    push("repainted")
    assert run(bpy.ops.mesh.material_deform_stiffness_from_paint) == {"FINISHED"}
    assert "Changed since bind" in session.stale_reason(obj)

    obj = undo()
    obj = undo()  # back to the bound stiffness: the bind is valid again
    assert session.stale_reason(obj) == ""
    top_empty(obj).location.x += 1.0
    update()
    moved = output(obj).copy()
    assert np.abs(moved - rest(obj)).max() > 0.5
    top_empty(obj).location.x -= 1.0  # (not an undo step: put it back before redoing)
    update()

    obj = redo()
    obj = redo()  # the new stiffness is back: the solver cached for the bound one is stale
    assert "Changed since bind" in session.stale_reason(obj)
    frozen = output(obj).copy()
    top_empty(obj).location.x += 1.0
    update()
    assert output(obj).tobytes() == frozen.tobytes()
    activate(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}  # rebinding clears it
    assert session.stale_reason(obj) == ""


def test_undo_clear_bake_and_reset_empties():
    obj = bound_bar()
    scene = bpy.context.scene
    e = top_empty(obj)
    e.keyframe_insert("location", frame=1)
    e.location.x += 1.0
    e.keyframe_insert("location", frame=3)
    scene.frame_set(3)
    push("animated")
    assert run(bpy.ops.object.material_deform_bake, frame_start=1, frame_end=3) == {"FINISHED"}
    assert run(bpy.ops.object.material_deform_clear_bake) == {"FINISHED"}
    assert key_names(obj) == ["Basis", "Material Deform"] and obj.material_deform.live
    obj = undo()  # the bake is back, Live off
    assert "MD Bake 0003" in key_names(obj) and not obj.material_deform.live
    obj = redo()
    assert key_names(obj) == ["Basis", "Material Deform"] and obj.material_deform.live
    moved = np.array(top_empty(obj).matrix_world)
    assert run(bpy.ops.object.material_deform_reset_empties) == {"FINISHED"}
    assert not np.allclose(np.array(top_empty(obj).matrix_world), moved)
    obj = undo()
    np.testing.assert_allclose(np.array(top_empty(obj).matrix_world), moved, atol=1e-6)
