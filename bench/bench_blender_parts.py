"""Where one live update's time goes inside Blender (companion to bench_blender.py).

Times, on the same tube and anchors as bench_blender.py and with no Laplacian object:
Blender's re-evaluation after the add-on writes and tags the output shape key, the handler body
(``session.apply``), the part of it that checks the Basis against the bound rest, and the full
live update.

Usage (see docs/performance.md):
  MD_SYS_PATH=build/addon/legacy/material_deform/_vendor .venv-bpy/bin/python \
      bench/bench_blender_parts.py [--faces 50000] [--reps 60] [--keep-cpus-awake]
  MD_SYS_PATH=$PWD/build/addon/legacy/material_deform/_vendor blender -b --factory-startup \
      --python bench/bench_blender_parts.py -- [--faces 50000]
"""

import argparse
import math
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_blender as bb  # noqa: E402  (also puts MD_SYS_PATH on sys.path)
import bpy  # noqa: E402


def median_ms(fn, reps):
    times = []
    for i in range(reps):
        t = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - t)
    return 1000 * statistics.median(times)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", type=int, default=50000)
    ap.add_argument("--reps", type=int, default=60)
    ap.add_argument("--keep-cpus-awake", action="store_true")
    ap.add_argument("--anchors", type=int, default=2, help="anchor rings (bench_blender.py's)")
    ap.add_argument("--motion", choices=("shift", "free", "scaled"), default="shift")
    ap.add_argument(
        "--update-button",
        action="store_true",
        help="also time the Update button on a mesh with a painted Stiffness group, and profile it",
    )
    args = ap.parse_args(argv)

    import addon_utils

    addon_utils.enable("material_deform", default_set=True)
    from material_deform import bridge, session

    spinners = bb.keep_cpus_awake() if args.keep_cpus_awake else []
    try:
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene, vl = bpy.context.scene, bpy.context.view_layer
        rings, sides = bb.tube_dims(args.faces)
        obj = bb.tube("MD", rings, sides)
        empties, _ = bb.setup_md(obj, sides, max(1, (rings - 1) // 50), args.anchors)
        empty = empties[0]  # the top ring
        rest_m = [e.matrix_world.copy() for e in empties]
        kb = bridge.output_key(obj)
        x = session.compute(obj, scene, None)
        s = obj.material_deform

        s.live = False
        vl.update()
        reeval = median_ms(
            lambda i: (bridge.write_key(obj, kb, x + 0.001 * (i % 7)), vl.update()), args.reps
        )

        def move(i):
            if args.motion == "shift":
                # matrix_world directly: a location change only reaches it on evaluation
                m = empty.matrix_world.copy()
                m.translation.x = 0.3 * math.sin(0.7 * (i + 1))
                empty.matrix_world = m
            else:
                bb.pose(empties, rest_m, i, args.motion)

        def handler_step(i):
            move(i)
            session.apply(obj, scene, None, force=True)

        handler = median_ms(handler_step, args.reps)
        entry = session.entry_for(obj, scene)
        rest_check = median_ms(lambda i: session.output._check_rest(obj, entry), 5 * args.reps)
        # Blender alone: the same Empty moves and updates with the object not live
        floor = median_ms(lambda i: (move(i + 500), vl.update(), vl.update()), args.reps)
        s.live = True
        vl.update()
        full = median_ms(lambda i: (move(i + 1000), vl.update(), vl.update()), args.reps)
        # the same live updates again, timing the solver's deform() and session.apply inside them
        inside = {"deform": [], "apply": []}
        deformer = entry.solver.deformer
        apply_fn = session.live.apply  # what live_update calls

        class Timed:
            def __getattr__(self, name):
                return getattr(deformer, name)

            def deform(self, *a, **k):
                t = time.perf_counter()
                out = deformer.deform(*a, **k)
                inside["deform"].append(time.perf_counter() - t)
                return out

        def timed_apply(*a, **k):
            t = time.perf_counter()
            out = apply_fn(*a, **k)
            inside["apply"].append(time.perf_counter() - t)
            return out

        entry.solver.deformer, session.live.apply = Timed(), timed_apply
        try:
            full2 = median_ms(lambda i: (move(i + 2000), vl.update(), vl.update()), args.reps)
        finally:
            entry.solver.deformer, session.live.apply = deformer, apply_fn
        button = update_button(obj, scene, vl) if args.update_button else None
    finally:
        for p in spinners:
            p.kill()
    print(
        f"Blender {bpy.app.version_string}, {2 * len(obj.data.polygons)} triangles, "
        f"{len(obj.data.vertices)} vertices, {args.anchors} anchors, motion {args.motion!r}"
        + (", CPUs kept awake" if spinners else "")
    )
    print(f"re-evaluation after the shape-key write (ms): {reeval:.2f}")
    print(f"handler body, session.apply (ms):           {handler:.2f}")
    print(f"  of which the rest check (ms):              {rest_check:.3f}")
    print(f"full live update (ms):                       {full:.2f}")
    print(f"  the same Empty moves, object not live (ms):  {floor:.3f}")
    d_in = 1000 * statistics.median(inside["deform"])
    a_in = 1000 * statistics.median(inside["apply"])
    print(f"  timed inside the live updates ({full2:.2f} ms each):")
    print(f"    session.apply (ms):                      {a_in:.3f}")
    print(f"    of which deform() (ms):                  {d_in:.3f}")
    if button:
        print(button)


def update_button(obj, scene, vl, reps=3):
    """The Update button (re-read mesh, anchors and paint, compare with the bind, solve) on the
    same mesh after painting every vertex into the Stiffness group, as an artist's mesh has it;
    its median and where the time goes (cProfile, the add-on's functions by cumulative time)."""
    import cProfile
    import io
    import pstats

    import numpy as np

    group = obj.vertex_groups.get("Stiffness") or obj.vertex_groups.new(name="Stiffness")
    n = len(obj.data.vertices)
    w = 0.2 + 0.6 * (np.arange(n) % 5) / 4.0
    for value in np.unique(w):
        group.add([int(i) for i in np.flatnonzero(w == value)], float(value), "REPLACE")
    bpy.ops.object.material_deform_rebind()
    vl.update()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        assert bpy.ops.object.material_deform_update() == {"FINISHED"}
        times.append(time.perf_counter() - t)
    prof = cProfile.Profile()
    prof.enable()
    bpy.ops.object.material_deform_update()
    prof.disable()
    out = io.StringIO()
    stats = pstats.Stats(prof, stream=out).sort_stats("cumulative")
    stats.print_stats(r"material_deform|numpy|matdeform", 14)
    lines = [ln for ln in out.getvalue().splitlines() if ln.strip()]
    return (
        f"Update button, Stiffness group painted (ms): {1000 * statistics.median(times):.1f}"
        + "\n  profile of one click (cumulative s, add-on functions):\n    "
        + "\n    ".join(lines[-15:])
    )


if __name__ == "__main__":
    main()
