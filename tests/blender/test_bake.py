"""Bakes: the point cache a Mesh Cache modifier reads back to the same positions, the shape-key
bake kept as an option, Clear Bake, and the panel saying a bake drives the mesh (issue 16)."""

import os

import bpy
import numpy as np
from helpers import draw_panel, evaluated, expect_error, output, rest, tube, two_end_anchors
from material_deform import bridge
from material_deform.pointcache import PC2Writer, read_pc2

FRAMES = (1, 2, 3, 4, 5)


def animated_bar():
    """A bound bar whose top Empty moves and turns over frames 1..5; returns the bar and the
    live result at every frame."""
    obj = tube()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    e = top.empty
    e.keyframe_insert("location", frame=1)
    e.keyframe_insert("rotation_euler", frame=1)
    e.location.x += 1.5
    e.rotation_euler.y = 0.8
    e.keyframe_insert("location", frame=5)
    e.keyframe_insert("rotation_euler", frame=5)
    scene = bpy.context.scene
    live = {}
    for f in FRAMES:
        scene.frame_set(f)
        live[f] = output(obj).copy()
    scene.frame_set(1)
    assert np.abs(live[5] - live[1]).max() > 1.0
    return obj, live


def panel_text(log=None):
    """The panel's labels as one text (long ones are wrapped over several labels)."""
    return " ".join(x[1] for x in (log or draw_panel()) if isinstance(x, tuple))


def test_point_cache_reads_back_in_blender_to_the_same_positions(tmp_path):
    obj, live = animated_bar()
    obj.modifiers.new("Subdivision", "SUBSURF")  # the cache must go before it
    path = str(tmp_path / "bar.pc2")
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=5, filepath=path) == {"FINISHED"}
    start, rate, frames = read_pc2(path)
    assert (start, rate, frames.shape) == (1.0, 1.0, (5, len(obj.data.vertices), 3))
    for i, f in enumerate(FRAMES):
        np.testing.assert_array_equal(frames[i], live[f])
    mod = obj.modifiers[0]
    assert mod.type == "MESH_CACHE" and mod.cache_format == "PC2" and mod.filepath == path
    assert not obj.material_deform.live
    # Blender's own modifier reads it back: the evaluated mesh at each frame is the live result
    obj.modifiers["Subdivision"].show_viewport = False
    scene = bpy.context.scene
    for f in FRAMES:
        scene.frame_set(f)
        np.testing.assert_allclose(evaluated(obj), live[f], atol=1e-6)
    assert "Baked to bar.pc2: the bake drives the mesh" in panel_text()


def test_point_cache_path_relative_to_the_saved_blend(tmp_path):
    obj, live = animated_bar()
    op = bpy.ops.object.material_deform_bake_point_cache
    expect_error(op, "Save the .blend first", frame_start=1, frame_end=5)
    assert bridge.cache_modifier(obj) is None and obj.material_deform.live
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    obj = bpy.data.objects["Bar"]
    assert op(frame_start=1, frame_end=5) == {"FINISHED"}
    assert bridge.cache_modifier(obj).filepath == "//scene_Bar.pc2"
    assert os.path.exists(tmp_path / "scene_Bar.pc2")
    bpy.context.scene.frame_set(3)
    np.testing.assert_allclose(evaluated(obj), live[3], atol=1e-6)


def test_shots_in_one_folder_and_objects_named_alike_keep_their_own_caches(tmp_path):
    """Two shots of the same character in one folder, and objects whose names clean to one file
    name ('Arm.L' / 'Arm L' / 'Arm_L'): each default bake writes its own file, and the first
    still plays its own motion after the others baked."""
    obj, live = animated_bar()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot_010.blend"))
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=5) == {"FINISHED"}
    first = read_pc2(str(tmp_path / "shot_010_Bar.pc2"))[2]
    np.testing.assert_array_equal(first[4], live[5])
    # shot_020: the same file saved under another name, the Empty moved elsewhere, baked again
    bpy.ops.object.material_deform_clear_bake()
    scene = bpy.context.scene
    scene.frame_set(5)
    top = bpy.data.objects["Bar"].material_deform.anchors[0].empty
    top.location.y -= 1.0
    top.keyframe_insert("location", frame=5)
    scene.frame_set(1)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot_020.blend"))
    assert op(frame_start=1, frame_end=5) == {"FINISHED"}
    second = read_pc2(str(tmp_path / "shot_020_Bar.pc2"))[2]
    assert np.abs(second[4] - first[4]).max() > 0.5  # another motion, in another file
    np.testing.assert_array_equal(read_pc2(str(tmp_path / "shot_010_Bar.pc2"))[2], first)
    # objects named alike, in one file: three bakes, three files
    files = set()
    obj = bpy.data.objects["Bar"]
    for name in ("Arm.L", "Arm L", "Arm_L"):
        obj.name = name
        bpy.ops.object.material_deform_clear_bake()
        assert op(frame_start=1, frame_end=2) == {"FINISHED"}
        files.add(os.path.basename(bpy.path.abspath(bridge.cache_modifier(obj).filepath)))
    assert len({f.casefold() for f in files}) == 3, files
    assert all(os.path.exists(tmp_path / f) for f in files), files


def test_a_failed_bake_leaves_the_old_cache_and_the_object_as_they_were(tmp_path):
    obj, _ = animated_bar()
    path = str(tmp_path / "bar.pc2")
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=3, filepath=path) == {"FINISHED"}
    before = open(path, "rb").read()
    obj.material_deform.anchors[0].empty.scale = (0, 0, 0)  # cannot pose at frame 4+
    obj.material_deform.anchors[0].empty.keyframe_insert("scale", frame=4)
    expect_error(op, "Cannot pose", frame_start=1, frame_end=5, filepath=path)
    assert open(path, "rb").read() == before
    assert [p for p in os.listdir(tmp_path) if ".tmp" in p] == []
    assert bridge.cache_modifier(obj) is not None


def test_shape_key_bake_stays_an_option_and_replaces_an_earlier_bake(tmp_path):
    obj, live = animated_bar()
    path = str(tmp_path / "bar.pc2")
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=5, filepath=path) == {"FINISHED"}
    assert bpy.ops.object.material_deform_bake(frame_start=2, frame_end=4) == {"FINISHED"}
    assert bridge.cache_modifier(obj) is None  # one bake at a time
    keys = obj.data.shape_keys.key_blocks
    assert [k.name for k in keys if k.name.startswith("MD Bake")] == [
        "MD Bake 0002",
        "MD Bake 0003",
        "MD Bake 0004",
    ]
    bpy.context.scene.frame_set(3)
    np.testing.assert_allclose(evaluated(obj), live[3], atol=1e-5)
    assert "Baked 3 frame(s) to shape keys" in panel_text()


def test_clear_bake_removes_keys_and_keyframes_and_turns_live_on(tmp_path):
    obj, live = animated_bar()
    assert bpy.ops.object.material_deform_bake(frame_start=1, frame_end=5) == {"FINISHED"}
    assert not obj.material_deform.live
    log = draw_panel()
    assert "object.material_deform_clear_bake" in log
    assert "the bake drives the mesh" in panel_text(log)
    assert bpy.ops.object.material_deform_clear_bake() == {"FINISHED"}
    keys = obj.data.shape_keys
    assert [k.name for k in keys.key_blocks] == ["Basis", "Material Deform"]
    ad = keys.animation_data
    assert ad is None or ad.action is None  # no keyframes left for the removed keys
    s = obj.material_deform
    assert s.live and keys.key_blocks["Material Deform"].value == 1.0
    assert "object.material_deform_clear_bake" not in draw_panel()
    bpy.context.scene.frame_set(4)  # live again: the animation drives the output
    np.testing.assert_allclose(output(obj), live[4], atol=1e-6)
    # and from a point cache
    path = str(tmp_path / "bar.pc2")
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=5, filepath=path) == {"FINISHED"}
    assert bpy.ops.object.material_deform_clear_bake() == {"FINISHED"}
    assert bridge.cache_modifier(obj) is None and s.live
    assert os.path.exists(path)  # the file is the user's: kept
    bpy.context.scene.frame_set(2)
    np.testing.assert_allclose(evaluated(obj), live[2], atol=1e-6)


def test_pc2_writer_checks_shapes_and_writes_nothing_on_error(tmp_path):
    path = str(tmp_path / "x.pc2")
    with PC2Writer(path, 2, 2, 7.0) as w:
        w.add(np.zeros((2, 3)))
        w.add(np.ones((2, 3)))
    start, _rate, data = read_pc2(path)
    assert start == 7.0 and data.shape == (2, 2, 3) and data[1].min() == 1.0
    try:
        with PC2Writer(path, 2, 2, 1.0) as w:
            w.add(np.zeros((3, 3)))
    except ValueError as exc:
        assert "expected (2, 3)" in str(exc)
    else:
        raise AssertionError("wrong shape accepted")
    assert read_pc2(path)[0] == 7.0 and os.listdir(tmp_path) == ["x.pc2"]


def test_bake_with_rest_untouched():
    obj, _ = animated_bar()
    r = rest(obj).copy()
    assert bpy.ops.object.material_deform_bake(frame_start=1, frame_end=5) == {"FINISHED"}
    assert bpy.ops.object.material_deform_clear_bake() == {"FINISHED"}
    assert rest(obj).tobytes() == r.tobytes()
