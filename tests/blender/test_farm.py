"""Point-cache bakes on a render farm (farm.py, farm/material_deform_bake.yaml, docs/farm.md):
frames baked in chunks by separate Blender processes, in shuffled order, equal one bake, for
every method; the OpenJD job run here with `openjd run` bakes and merges the same cache and a
.blend that reads it; a failing chunk fails its task and blocks the merge; a Blender without the
add-on says so first and bakes nothing; Write Farm Bake Job writes the job."""

import json
import os
import random
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import RecordingLayout, evaluated, rest, tube, two_end_anchors
from material_deform import bake, bridge, farm, farm_job
from material_deform.pointcache import read_pc2

REPO = Path(__file__).resolve().parents[2]
LEGACY = REPO / "build" / "addon" / "legacy"  # the add-on as built (scripts/build_addon.sh)
OPENJD = Path(os.environ.get("MD_OPENJD", REPO / ".venv" / "bin" / "openjd"))
FRAMES = range(1, 13)  # 12 frames: 3 chunks of 4
METHODS = ("MATERIAL", "EDGE", "POSE_SPACE", "PYRAMID")
TIMEOUT = 300


def animate(empty, dx=1.5, turn=0.8, last=FRAMES[-1]):
    """Move and turn the Empty from the first frame to the last (linear keys)."""
    empty.keyframe_insert("location", frame=FRAMES[0])
    empty.keyframe_insert("rotation_euler", frame=FRAMES[0])
    empty.location.x += dx
    empty.rotation_euler.y = turn
    empty.keyframe_insert("location", frame=last)
    empty.keyframe_insert("rotation_euler", frame=last)
    for fc in bridge.action_fcurves(empty.animation_data):  # slotted in 4.4+, no .fcurves in 5.0
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"


def bound_bar(method, name):
    """A bar of the given method, bound, its top Empty animated over FRAMES."""
    if method == "POSE_SPACE":
        from test_pose_space import example_bar  # a bar with two example shape keys

        obj, top, _bottom = example_bar()
        obj.name = name
    else:
        obj = tube(name=name, rings=13)
        obj.material_deform.method = method
        top, _bottom = two_end_anchors(obj)
    if method == "EDGE":
        e = obj.material_deform.edge
        e.stretch, e.gravity_strength = 1e-2, 1.0
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    animate(top.empty, turn=-0.9 if method == "POSE_SPACE" else 0.8)
    bpy.context.scene.frame_set(FRAMES[0])
    return obj


def saved_scene(path, methods=METHODS):
    objs = [bound_bar(m, m.title()) for m in methods]
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return objs


def python_command(code, *args):
    """A fresh Blender process running ``code`` (with this suite's add-on and core) and ``args``
    after '--': the Blender executable, or the bpy module's Python."""
    paths = [p for p in os.environ.get("MD_TEST_SYS_PATH", "").split(os.pathsep) if p]
    paths.append(str(REPO / "addon"))
    setup = (
        "import sys, os\n"
        f"sys.path[:0] = {paths!r}\n"
        "import bpy, addon_utils\n"
        "assert addon_utils.enable('material_deform')\n"
    )
    if bpy.app.binary_path:
        cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1"]
        return [*cmd, "--python-expr", setup + code, "--", *args]
    return [sys.executable, "-c", setup + code, "--", *args]


def run(cmd, env=None):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT, env=env)


# --- determinism: every method ------------------------------------------------------------------


def test_chunks_baked_in_separate_processes_in_any_order_equal_one_bake(tmp_path):
    """Frames 1-12 of a bar of every method, baked as 3 chunks by 3 separate Blender processes
    run in shuffled order, merge into exactly the cache one local bake writes (bit for bit: each
    frame starts from a start that depends on that frame only, bake.frame_start)."""
    blend = tmp_path / "scene.blend"
    objs = saved_scene(blend)
    single = {}
    for obj in objs:
        bpy.context.view_layer.objects.active = obj
        path = tmp_path / f"{obj.name}.single.pc2"
        op = bpy.ops.object.material_deform_bake_point_cache
        assert op(frame_start=1, frame_end=12, filepath=str(path)) == {"FINISHED"}
        single[obj.name] = read_pc2(str(path))[2]
        moved = np.abs(single[obj.name] - rest(obj)).max(axis=(1, 2))
        assert moved[0] < 1e-6 and moved[-1] > 0.3, (obj.name, moved)  # a real animation
    out = tmp_path / "out"
    chunks = ["9-12", "1-4", "5-8"]  # shuffled: each chunk's first frame is solved first
    code = (
        "import importlib\n"
        "farm = importlib.import_module('material_deform.farm')\n"
        "blend, frames, out, *names = sys.argv[sys.argv.index('--') + 1:]\n"
        "codes = [farm.main(['chunk', blend, n, frames, out]) for n in names]\n"
        "sys.stdout.flush()\n"
        "os._exit(max(codes))\n"  # the bpy module can hang in its exit handlers
    )
    for frames in chunks:
        done = run(python_command(code, str(blend), frames, str(out), *single))
        assert done.returncode == 0, done.stdout + done.stderr
    for name, want in single.items():
        assert len(farm_job.find_chunks(str(out), name)) == 3
        merged = read_pc2(farm_job.merge(str(out), name, 1, 12, want.shape[1]))[2]
        diff = np.abs(merged - want).max()
        assert np.array_equal(merged, want), f"{name}: chunks differ from one bake by {diff}"


def test_frames_baked_in_any_order_in_one_process_equal_the_forward_bake(tmp_path):
    """The same rule inside one process: frames in reverse or shuffled order give the bits of
    the forward bake (an iterative method never continues from the frame solved before)."""
    objs = saved_scene(tmp_path / "scene.blend", ("EDGE", "PYRAMID"))
    scene = bpy.context.scene
    for obj in objs:
        forward = dict(bake._solved_frames(obj, scene, list(FRAMES), None))
        order = list(FRAMES)
        random.Random(7).shuffle(order)
        for frames in (order, list(reversed(FRAMES))):
            for f, x in bake._solved_frames(obj, scene, frames, None):
                assert np.array_equal(x, forward[f]), (obj.name, f)


# --- the OpenJD job, run here -------------------------------------------------------------------


def openjd_or_skip():
    if not os.access(OPENJD, os.X_OK):
        pytest.skip(f"no openjd at {OPENJD} (scripts/setup.sh installs openjd-cli into .venv)")
    if not (LEGACY / "material_deform" / "_vendor").is_dir():
        pytest.skip(f"no built add-on in {LEGACY} (scripts/build_addon.sh)")


def blender_for_openjd(tmp_path):
    """The Blender executable the job runs: this one, or for the bpy module a small stand-in
    that runs the task script with the module's Python (it has no Blender command line)."""
    if bpy.app.binary_path:
        return bpy.app.binary_path
    shim = tmp_path / "blender"
    shim.write_text(
        "#!/bin/sh\n"
        "# Blender's command line on the bpy module: run the file after --python\n"
        'while [ $# -gt 0 ] && [ "$1" != "--python" ]; do shift; done\n'
        "shift\n"
        f'exec "{sys.executable}" "$@"\n'
    )
    shim.chmod(0o755)
    return str(shim)


def user_env(tmp_path, installed):
    """Environment of a worker with its own empty Blender user folders, where the add-on is
    ``installed`` as a legacy add-on (a link to the built one) or not at all."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MD_TEST_SYS_PATH")}
    home = tmp_path / ("installed" if installed else "bare")
    for key, scripts in (
        ("BLENDER_USER_SCRIPTS", home / "scripts"),  # 3.x
        ("BLENDER_USER_RESOURCES", home / "res"),  # 4.2+: <res>/scripts
    ):
        addons = (scripts if key == "BLENDER_USER_SCRIPTS" else scripts / "scripts") / "addons"
        addons.mkdir(parents=True, exist_ok=True)
        if installed and not (addons / "material_deform").exists():
            (addons / "material_deform").symlink_to(LEGACY / "material_deform")
        env[key] = str(scripts)
    env["BLENDER_USER_CONFIG"] = str(home / "config")
    return env


def openjd_run(bundle, env, *extra, params=None):
    cmd = [str(OPENJD), "run", str(bundle / "template.yaml"), *extra]
    cmd += ["-p", f"file://{params or bundle / 'openjd_params.json'}"]
    return run(cmd, env)


def task_outputs(log):
    """The output of every task of an openjd run, one list of lines per task (timestamps and
    Blender's one-line banner removed)."""
    tasks, cur = [], None
    for line in log.splitlines():
        text = line.split("\t", 1)[-1]
        if text == "Output:":
            cur = []
            tasks.append(cur)
        elif cur is not None and text.startswith("Process pid "):
            cur = None
        elif cur is not None and text.strip():
            cur.append(text)
    for t in tasks:  # "Blender 3.4.1", "Blender 4.3.2 (hash 32f5fdce0a0a built ...)"
        if t and re.fullmatch(r"Blender \d+\.\d+(\.\d+)?( \(hash .*\))?", t[0]):
            del t[0]
    return tasks


def write_job(tmp_path, obj, blender, **kw):
    """Write Farm Bake Job for ``obj`` (the file saved); returns the bundle folder."""
    bpy.context.view_layer.objects.active = obj
    out = tmp_path / "out"
    op = bpy.ops.object.material_deform_farm_job
    assert op(directory=str(out), chunk_size=4, frame_start=1, frame_end=12, blender=blender, **kw)
    return out / "job"


def test_openjd_run_bakes_the_chunks_and_merges_them_like_one_bake(tmp_path):
    """`openjd run` of the written job on this machine: 3 chunk tasks (separate background
    Blender processes, the add-on installed as on a worker), then the merge: the merged cache
    equals one local bake bit for bit, and the saved copy of the .blend reads it."""
    openjd_or_skip()
    (obj,) = saved_scene(tmp_path / "scene.blend", ("EDGE",))
    bundle = write_job(tmp_path, obj, blender_for_openjd(tmp_path))
    params = json.loads((bundle / "openjd_params.json").read_text())
    assert params["BlendFile"] == str(tmp_path / "scene.blend") and params["Object"] == "Edge"
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=12, filepath=str(tmp_path / "single.pc2")) == {"FINISHED"}
    single = read_pc2(str(tmp_path / "single.pc2"))[2]

    done = openjd_run(
        bundle, user_env(tmp_path, installed=True), "--step", "Merge", "--run-dependencies"
    )
    assert done.returncode == 0, done.stdout + done.stderr
    tasks = task_outputs(done.stdout)
    assert len(tasks) == 4  # three chunks, then the merge
    for t in tasks:  # the first line says which add-on and Blender run it
        assert t[0].startswith("Material Deform farm: add-on 0.1.0"), t
    out = tmp_path / "out"
    assert [c[:2] for c in farm_job.find_chunks(str(out), "Edge")] == [(1, 4), (5, 8), (9, 12)]
    start, _rate, merged = read_pc2(str(out / "Edge.pc2"))
    assert start == 1.0
    assert np.array_equal(merged, single), np.abs(merged - single).max()

    copy = out / "scene_Edge_baked.blend"
    bpy.ops.wm.open_mainfile(filepath=str(copy))
    obj = bpy.data.objects["Edge"]
    mod = obj.modifiers[0]
    assert mod.type == "MESH_CACHE" and mod.filepath == "//Edge.pc2" and mod.frame_start == 1
    assert not obj.material_deform.live
    bpy.context.scene.frame_set(7)
    np.testing.assert_allclose(evaluated(obj), merged[6], atol=1e-6)


def test_a_failing_chunk_fails_its_task_blocks_the_merge_and_runs_again(tmp_path):
    """A frame that cannot be posed (the Empty scaled to zero at frame 6) fails the chunk 5-8
    with the reason in the log; the merge then refuses (no chunk for 5-8) and writes nothing.
    Fixed and run again chunk by chunk, with the add-on shipped with the job (AddonZip) to
    workers that do not have it, a re-run chunk replaces the old file and the merge succeeds."""
    openjd_or_skip()
    blend = tmp_path / "scene.blend"
    (obj,) = saved_scene(blend, ("MATERIAL",))
    empty = obj.material_deform.anchors[0].empty
    empty.keyframe_insert("scale", frame=5)
    empty.scale = (0.0, 0.0, 0.0)
    empty.keyframe_insert("scale", frame=6)
    empty.scale = (1.0, 1.0, 1.0)
    empty.keyframe_insert("scale", frame=7)
    bpy.ops.wm.save_mainfile()
    bundle = write_job(tmp_path, obj, blender_for_openjd(tmp_path))
    out = tmp_path / "out"
    env = user_env(tmp_path, installed=True)

    done = openjd_run(bundle, env, "--step", "Merge", "--run-dependencies")
    assert done.returncode != 0
    failed = task_outputs(done.stdout)[-1]
    assert any("Material Deform farm: ERROR: Cannot pose 'Material'" in t for t in failed), failed
    assert [c[:2] for c in farm_job.find_chunks(str(out), "Material")] == [(1, 4)]
    merge = openjd_run(bundle, env, "--step", "Merge")
    assert merge.returncode != 0
    assert "ERROR: no chunk holds frame(s) 5-12 of 'Material'" in merge.stdout, merge.stdout
    assert not (out / "Material.pc2").exists() and not list(out.glob("*.blend"))

    fcurves = bridge.fcurve_collection(empty.animation_data)
    for fc in [fc for fc in fcurves if fc.data_path == "scale"]:
        fcurves.remove(fc)  # fixed
    empty.scale = (1.0, 1.0, 1.0)
    bpy.ops.wm.save_mainfile()
    shipped = json.loads((bundle / "openjd_params.json").read_text())
    shipped["AddonZip"] = str(LEGACY)  # the legacy add-on (a folder here; the zip in use)
    (tmp_path / "shipped.json").write_text(json.dumps(shipped))
    bare = user_env(tmp_path, installed=False)
    first = farm_job.chunk_path(str(out), "Material", 1, 4)
    with open(first, "r+b") as f:
        f.truncate(64)  # the old chunk 1-4, cut short
    tasks = json.dumps([{"Frames": f} for f in ("9-12", "5-8", "1-4")])  # one process each
    again = openjd_run(
        bundle, bare, "--step", "BakeChunks", "--tasks", tasks, params=tmp_path / "shipped.json"
    )
    assert again.returncode == 0, again.stdout + again.stderr
    assert len(task_outputs(again.stdout)) == 3
    assert len(read_pc2(first)[2]) == 4  # replaced whole
    done = openjd_run(bundle, bare, "--step", "Merge", params=tmp_path / "shipped.json")
    assert done.returncode == 0, done.stdout + done.stderr
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=12, filepath=str(tmp_path / "single.pc2")) == {"FINISHED"}
    want = read_pc2(str(tmp_path / "single.pc2"))[2]
    assert np.array_equal(read_pc2(str(out / "Material.pc2"))[2], want)


def test_without_the_add_on_the_task_says_so_first_and_bakes_nothing(tmp_path):
    openjd_or_skip()
    (obj,) = saved_scene(tmp_path / "scene.blend", ("MATERIAL",))
    bundle = write_job(tmp_path, obj, blender_for_openjd(tmp_path))
    done = openjd_run(
        bundle, user_env(tmp_path, installed=False), "--step", "BakeChunks", "-tp", "Frames=1-4"
    )
    assert done.returncode != 0
    (task,) = task_outputs(done.stdout)
    assert task[0].startswith(
        "Material Deform farm: ERROR: the Material Deform add-on is not installed in this "
        f"Blender ({bpy.app.version_string}"
    ), task
    assert "ship the legacy zip with the job (parameter AddonZip); nothing baked" in task[0]
    assert not (tmp_path / "out" / "chunks").exists()


def test_another_farm_runs_the_task_script_with_the_bundles_command(tmp_path):
    """What docs/farm.md tells other farms (Flamenco, ...) to run: the task script from the
    bundle, one Blender per chunk. The built add-on carries the farm files it copies."""
    if not (LEGACY / "material_deform" / "_vendor").is_dir():
        pytest.skip(f"no built add-on in {LEGACY} (scripts/build_addon.sh)")
    for name in (farm_job.TEMPLATE, farm_job.TASK):
        built = (LEGACY / "material_deform" / name).read_bytes()
        assert built == (REPO / "farm" / name).read_bytes(), name
    (obj,) = saved_scene(tmp_path / "scene.blend", ("PYRAMID",))
    bundle = write_job(tmp_path, obj, blender_for_openjd(tmp_path))
    params = json.loads((bundle / "openjd_params.json").read_text())
    cmd = farm_job.commands(str(bundle), params)["chunk"]
    done = run(shlex.split(cmd), user_env(tmp_path, installed=True))
    assert done.returncode == 0, done.stdout + done.stderr
    op = bpy.ops.object.material_deform_bake_point_cache
    assert op(frame_start=1, frame_end=4, filepath=str(tmp_path / "single.pc2")) == {"FINISHED"}
    chunk = read_pc2(farm_job.chunk_path(params["OutputFolder"], "Pyramid", 1, 4))
    assert chunk[0] == 1.0
    assert np.array_equal(chunk[2], read_pc2(str(tmp_path / "single.pc2"))[2])


# --- the submit helper ----------------------------------------------------------------------------


def test_write_farm_bake_job_writes_the_bundle_and_says_how_to_run_it(tmp_path):
    (obj,) = saved_scene(tmp_path / "scene.blend", ("MATERIAL",))
    s = obj.material_deform
    s.bake_start, s.bake_end = 3, 40
    bpy.ops.wm.save_mainfile()
    assert bpy.ops.object.material_deform_farm_job(chunk_size=7) == {"FINISHED"}
    folder = tmp_path / "farm_scene_Material" / "job"  # next to the .blend by default
    params = json.loads((folder / "openjd_params.json").read_text())
    assert params == farm_job.job_parameters(
        str(tmp_path / "scene.blend"), "Material", 3, 40, 7, str(tmp_path / "farm_scene_Material")
    )
    assert (folder / "template.yaml").read_bytes() == Path(farm_job.template_path()).read_bytes()
    # in the Object > Material Deform menu (F3 finds it), next to the other bakes
    log = []
    bpy.types.VIEW3D_MT_material_deform.draw(
        type("Menu", (), {"layout": RecordingLayout(log)})(), bpy.context
    )
    assert log.index("object.material_deform_farm_job") > log.index(
        "object.material_deform_bake_point_cache"
    )


def test_write_farm_bake_job_needs_the_saved_file():
    obj = tube()
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    with pytest.raises(RuntimeError, match="Save the .blend first: the farm bakes the saved file"):
        bpy.ops.object.material_deform_farm_job(directory=bpy.app.tempdir)


def test_write_farm_bake_job_refuses_unsaved_changes_and_a_stale_bind(tmp_path, monkeypatch):
    from material_deform import farm

    (obj,) = saved_scene(tmp_path / "scene.blend", ("MATERIAL",))
    with monkeypatch.context() as m:
        m.setattr(farm, "unsaved_changes", lambda: True)  # the GUI's is_dirty (see its doc)
        with pytest.raises(RuntimeError, match="unsaved changes: save it first"):
            bpy.ops.object.material_deform_farm_job(directory=str(tmp_path / "o"))
    obj.material_deform.anisotropic = True  # the bind cannot update now
    bpy.ops.wm.save_mainfile()
    with pytest.raises(RuntimeError, match="Anisotropic is on but there is no per-axis"):
        bpy.ops.object.material_deform_farm_job(directory=str(tmp_path / "o"))
    assert not (tmp_path / "o").exists()


def test_two_merges_at_once_and_an_unwritable_output(tmp_path, capfd):
    """A merge saves its copy of the .blend under a temporary name of its own, so a second
    merge of the same job running at the same time (another node, a re-run) is not disturbed
    and nothing is left behind. Where the output cannot be written, a task says so in one line
    naming the file it wanted, with no traceback."""
    blend = tmp_path / "scene.blend"
    saved_scene(blend, ("MATERIAL",))
    out = tmp_path / "out"
    for frames in ("1-4", "5-12"):
        assert farm.main(["chunk", str(blend), "Material", frames, str(out)]) == 0
    copy = farm_job.baked_blend_path(str(out), str(blend), "Material")
    # what another merge is writing right now: its temporary copy, and the one a fixed name
    # would give
    others = [Path(f"{copy}.tmp-another-node-1.blend"), Path(f"{copy}.tmp.blend")]
    for other in others:
        other.write_bytes(b"another merge's copy")
    assert farm.main(["merge", str(blend), "Material", "1-12", str(out)]) == 0
    assert all(o.read_bytes() == b"another merge's copy" for o in others)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(["chunks", "Material.pc2", Path(copy).name] + [o.name for o in others])
    capfd.readouterr()
    # an output folder in which a file stands where the chunks go, and one where the merged
    # cache goes
    blocked = tmp_path / "blocked"
    blocked.mkdir()
    (blocked / "chunks").write_bytes(b"")
    assert farm.main(["chunk", str(blend), "Material", "1-4", str(blocked)]) == 1
    shutil.rmtree(blocked)
    shutil.copytree(out / "chunks", blocked / "chunks")
    (blocked / "Material.pc2").mkdir()
    assert farm.main(["merge", str(blend), "Material", "1-12", str(blocked)]) == 1
    said = capfd.readouterr()
    errors = [x for x in said.out.splitlines() if "ERROR" in x]
    assert errors == [
        f"{farm_job.PREFIX} ERROR: cannot write {blocked / 'chunks'}: File exists (the output "
        "folder must be writable)",
        f"{farm_job.PREFIX} ERROR: cannot write {blocked / 'Material.pc2'}: Is a directory "
        "(the output folder must be writable)",
    ], said.out
    assert "Traceback" not in said.out + said.err and ".tmp" not in said.out
    assert sorted(p.name for p in blocked.iterdir()) == ["Material.pc2", "chunks"]


def test_a_chunk_baked_again_after_the_file_changed_is_not_merged_with_the_old_ones(
    tmp_path, capfd
):
    """Each chunk keeps what it was baked from (bind, method settings, the anchors' animation).
    After the saved file changes in a way the bind does not see (Edge gravity) or in the
    animation (a moved key), one chunk baked again does not merge with the old ones: the merge
    names them, writes nothing, and merges once they are baked again too."""
    blend = tmp_path / "scene.blend"
    saved_scene(blend, ("EDGE",))
    out = str(tmp_path / "out")

    def chunks(*ranges):
        for frames in ranges:
            assert farm.main(["chunk", str(blend), "Edge", frames, out]) == 0

    def merge():
        return farm.main(["merge", str(blend), "Edge", "1-12", out])

    chunks("1-4", "5-8", "9-12")
    bpy.ops.wm.save_mainfile()  # saved again, unchanged: still one version
    assert merge() == 0
    first = read_pc2(os.path.join(out, "Edge.pc2"))[2]
    capfd.readouterr()
    for change in ("gravity", "key"):
        bpy.ops.wm.open_mainfile(filepath=str(blend))  # the merge left its baked copy open
        obj = bpy.data.objects["Edge"]
        if change == "gravity":
            obj.material_deform.edge.gravity_strength = 5.0
        else:
            empty = obj.material_deform.anchors[0].empty
            fc = next(
                c for c in bridge.action_fcurves(empty.animation_data) if c.data_path == "location"
            )
            fc.keyframe_points[-1].co.y += 0.5
        bpy.ops.wm.save_mainfile()
        assert not bpy.data.objects["Edge"].material_deform.rebind_reason  # the bind holds
        chunks("5-8")
        assert merge() == 1
        said = capfd.readouterr().out
        assert (
            "ERROR: chunk(s) Edge.0001-0004.pc2, Edge.0009-0012.pc2 were baked from another" in said
        )
        chunks("1-4", "9-12")
        assert merge() == 0
        now = read_pc2(os.path.join(out, "Edge.pc2"))[2]
        assert np.abs(now - first).max() > 1e-3  # the change does change the cache
        first = now
