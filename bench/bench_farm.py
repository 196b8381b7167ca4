"""Farm bake timings (docs/farm.md): one local background bake of an animation against the same
frames split into chunks run as parallel tasks of the OpenJD job (farm/material_deform_bake.yaml,
`openjd run`, one process per chunk, all at once), then the merge. Checks that the merged cache
equals the single bake bit for bit.

    .venv/bin/python bench/bench_farm.py [--methods MATERIAL EDGE PYRAMID] [--frames 48]
        [--chunks 3] [--rings 161 --sides 64] [--repeat 3] [--blender blender]

Needs the built add-on (scripts/build_addon.sh -> build/addon/legacy) and openjd-cli in the
project venv (scripts/setup.sh). Wall-clock medians over --repeat runs; every run includes
starting Blender, loading the file and rebuilding the solver, as a farm task does. "task start"
is the first chunk's task run alone minus its frames (openjd, Blender, the add-on, the file, the
solver), "frame" the one bake's own time per frame (the operator alone): a farm of W workers
takes about start + frames / W x frame + merge. The scene: a
bar (rings x sides vertices, round caps) with two end anchors, the top Empty moving and turning
over the frames; Edge with Stretch 1e-2 and gravity 1.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LEGACY = REPO / "build" / "addon" / "legacy"
OPENJD = Path(sys.executable).parent / "openjd"
TEMPLATE = REPO / "farm" / "material_deform_bake.yaml"
sys.path.insert(0, str(REPO / "addon"))

from material_deform.pointcache import read_pc2  # noqa: E402

SCENE = """
import sys, math
sys.path.insert(0, {tests!r})
import bpy, addon_utils
assert addon_utils.enable("material_deform")
bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
from helpers import tube, two_end_anchors
obj = tube(rings={rings}, sides={sides}, square=False)
obj.material_deform.method = {method!r}
if {method!r} == "EDGE":
    obj.material_deform.edge.stretch = 1e-2
    obj.material_deform.edge.gravity_strength = 1.0
top, _ = two_end_anchors(obj)
assert bpy.ops.object.material_deform_bind() == {{"FINISHED"}}
e = top.empty
e.keyframe_insert("location", frame=1)
e.keyframe_insert("rotation_euler", frame=1)
e.location.x += 1.5
e.rotation_euler.y = 0.8
e.keyframe_insert("location", frame={frames})
e.keyframe_insert("rotation_euler", frame={frames})
bpy.context.scene.frame_set(1)
bpy.ops.wm.save_as_mainfile(filepath={blend!r})
"""

BAKE = (
    "import addon_utils as a; a.enable(next(m.__name__ for m in a.modules() "
    "if m.__name__.rsplit('.', 1)[-1] == 'material_deform')); import bpy, time; "
    "bpy.context.view_layer.objects.active = bpy.data.objects['Bar']; t = time.perf_counter(); "
    "bpy.ops.object.material_deform_bake_point_cache(frame_start=1, frame_end={frames}, "
    "filepath={path!r}); print('BAKE_S', time.perf_counter() - t)"
)


def env_with_addon(home: Path) -> dict:
    """A worker's environment: its own Blender user folders with the built legacy add-on."""
    env = dict(os.environ)
    for key, scripts in (
        ("BLENDER_USER_SCRIPTS", home / "scripts"),
        ("BLENDER_USER_RESOURCES", home / "res"),
    ):
        addons = (scripts if key == "BLENDER_USER_SCRIPTS" else scripts / "scripts") / "addons"
        addons.mkdir(parents=True, exist_ok=True)
        link = addons / "material_deform"
        if not link.exists():
            link.symlink_to(LEGACY / "material_deform")
        env[key] = str(scripts)
    env["BLENDER_USER_CONFIG"] = str(home / "config")
    return env


def chunks_of(frames: int, n: int) -> list[str]:
    size = -(-frames // n)
    return [f"{a}-{min(a + size - 1, frames)}" for a in range(1, frames + 1, size)]


def timed(cmds, env) -> tuple[float, list[str]]:
    """Run the commands at once; (wall seconds until the last ends, their outputs)."""
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for c in cmds
    ]
    outs = [p.communicate()[0] for p in procs]
    wall = time.perf_counter() - t0
    for p, o in zip(procs, outs, strict=True):
        if p.returncode != 0:
            raise SystemExit(f"failed ({p.returncode}):\n{o[-3000:]}")
    return wall, outs


def run_method(a, method: str, work: Path, env: dict) -> dict:
    blend = work / f"{method}.blend"
    code = SCENE.format(
        tests=str(REPO / "tests" / "blender"),
        rings=a.rings,
        sides=a.sides,
        method=method,
        frames=a.frames,
        blend=str(blend),
    )
    blender = [a.blender, "-b", "--factory-startup", "--python-exit-code", "1"]
    timed([[*blender, "--python-expr", code]], env)
    single_path = work / f"{method}.single.pc2"
    bake = BAKE.format(frames=a.frames, path=str(single_path))
    params = {
        "BlendFile": str(blend),
        "Object": "Bar",
        "FrameStart": 1,
        "FrameEnd": a.frames,
        "ChunkSize": -(-a.frames // a.chunks),
        "OutputFolder": str(work / f"{method}_out"),
        "Blender": a.blender,
    }
    pfile = work / f"{method}.json"
    pfile.write_text(json.dumps(params))
    run = [str(OPENJD), "run", str(TEMPLATE), "-p", f"file://{pfile}"]
    singles, farms, merges, start_s, bakes = [], [], [], [], []
    for _ in range(a.repeat):
        t, (out,) = timed([[a.blender, "-b", str(blend), "--python-expr", bake]], env)
        singles.append(t)
        bakes.append(float(re.search(r"BAKE_S ([\d.]+)", out)[1]))
        shutil.rmtree(work / f"{method}_out", ignore_errors=True)
        tasks = [
            ["--step", "BakeChunks", "-tp", f"Frames={c}"] for c in chunks_of(a.frames, a.chunks)
        ]
        t, outs = timed([[*run, *task] for task in tasks], env)
        farms.append(t)
        # the first chunk again, alone: what a task costs besides its frames
        t, (out,) = timed([[*run, *tasks[0]]], env)
        (done,) = [float(x) for x in re.findall(r"chunk \S+ done in ([\d.]+) s", out)]
        start_s.append(t - done)
        t, _o = timed([[*run, "--step", "Merge"]], env)
        merges.append(t)
    merged = read_pc2(str(work / f"{method}_out" / "Bar.pc2"))[2]
    single = read_pc2(str(single_path))[2]
    return {
        "method": method,
        "vertices": merged.shape[1],
        "frames": a.frames,
        "single_s": statistics.median(singles),
        "chunks_s": statistics.median(farms),
        "merge_s": statistics.median(merges),
        "task_start_s": statistics.median(start_s),
        # the one bake's frames, all of them (far from rest costs more than the first chunk)
        "solve_per_frame_s": statistics.median(bakes) / a.frames,
        "equal": bool((merged == single).all()),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=["MATERIAL", "EDGE", "PYRAMID"])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--chunks", type=int, default=3)
    ap.add_argument("--rings", type=int, default=161)
    ap.add_argument("--sides", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--blender", default=shutil.which("blender") or "blender")
    a = ap.parse_args()
    if not (LEGACY / "material_deform" / "_vendor").is_dir():
        raise SystemExit(f"no built add-on in {LEGACY}: run scripts/build_addon.sh")
    with tempfile.TemporaryDirectory(prefix="bench_farm_") as tmp:
        work = Path(tmp)
        env = env_with_addon(work / "home")
        print(f"cpus {os.cpu_count()}, {a.chunks} chunks at once, medians of {a.repeat} runs")
        print(
            f"| method | vertices | frames | one bake (s) | {a.chunks} chunks at once (s) "
            "| merge (s) | task start (s) | frame (s) | merged == one bake |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for m in a.methods:
            r = run_method(a, m, work, env)
            print(
                f"| {r['method']} | {r['vertices']} | {r['frames']} | {r['single_s']:.1f} | "
                f"{r['chunks_s']:.1f} | {r['merge_s']:.1f} | {r['task_start_s']:.1f} | "
                f"{r['solve_per_frame_s']:.3f} | {r['equal']} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
