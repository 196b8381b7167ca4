"""What carrying turns past half a turn costs a live update (session/twist.py): playback of an
animation in which 6 anchor Empties turn freely, several of them by whole turns, at 10k faces.

    MD_SYS_PATH=build/addon/legacy/material_deform/_vendor .venv-bpy/bin/python \\
        bench/bench_blender_twist.py [--faces 10000] [--anchors 6] [--rounds 8]
    (or: blender -b --factory-startup --python bench/bench_blender_twist.py -- [args])

Each live update here is one frame of playback: ``scene.frame_set(f)`` (the animation
evaluated, the frame-change handler solving with the live budget, as in the GUI) and
``view_layer.update()`` (the mesh re-evaluated with the new key). Timed, as medians over
alternating blocks of frames:

  update, turns on    the live update as the add-on runs it
  update, turns off   the same frames with the rotation vectors looked up from a table made
                      beforehand (the solver gets the same vectors: only the unwrapping is gone)
  vectors()           inside the "on" updates: the unwrapping itself (Twist.vectors: cached
                      frames, the check against the live matrices, the principal test; not
                      the anchor transforms it asks for, which the solve needs anyway)
  first pass          vectors() the first time each frame is played after an edit of the
                      animation (samples 48 frames ahead when it runs out: median and worst)

The machine is shared: the blocks alternate so that both variants see the same load; the
medians are still noisy.
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
import numpy as np  # noqa: E402

FRAMES = range(1, 121)


def animate(empties, rng):
    """Keys every 20 frames: each Empty twists about the tube's axis (its Z) by 1.5 to 2.5 rad
    per key, past half a turn and on to about two turns, and moves; every other one also tilts
    (up to 0.3 rad about X and Y); the last one is also scaled along its own axes."""
    for a, e in enumerate(empties):
        base = e.rotation_euler.copy()
        loc = e.location.copy()
        speed = rng.uniform(1.5, 2.5)
        for f in range(FRAMES[0], FRAMES[-1] + 2, 20):
            tilt = rng.uniform(-0.3, 0.3, 2) if a % 2 else (0.0, 0.0)
            e.rotation_euler = (base.x + tilt[0], base.y + tilt[1], base.z + (f - 1) / 20 * speed)
            e.location = loc + type(loc)(rng.uniform(-0.2, 0.2, 3).tolist())
            e.keyframe_insert("rotation_euler", frame=f)
            e.keyframe_insert("location", frame=f)
            if a == len(empties) - 1:
                e.scale = (1.3, 1.0, 0.8)
                e.keyframe_insert("scale", frame=f)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", type=int, default=10000)
    ap.add_argument("--anchors", type=int, default=6)
    ap.add_argument("--rounds", type=int, default=8, help="alternating block pairs")
    ap.add_argument("--block", type=int, default=15, help="frames per block")
    args = ap.parse_args(argv)

    import addon_utils

    addon_utils.enable("material_deform", default_set=True)
    from material_deform import handlers, session
    from material_deform.session import twist

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene, vl = bpy.context.scene, bpy.context.view_layer
    scene.frame_set(1)
    rings, sides = bb.tube_dims(args.faces)
    obj = bb.tube("MD", rings, sides)
    empties, _ = bb.setup_md(obj, sides, max(1, (rings - 1) // 50), args.anchors)
    animate(empties, np.random.default_rng(5))
    handlers._rendering = lambda: False  # playback in the GUI: the live path, not a render's
    vl.update()

    tw_vectors = twist.Twist.vectors
    inside = []

    def timed(self, obj, scene, frame, mkey, transforms, *a, **k):
        # the anchor transforms it asks for are the solve's anyway: their time is not counted
        spent = [0.0]

        def counted():
            t = time.perf_counter()
            out = transforms()
            spent[0] += time.perf_counter() - t
            return out

        t = time.perf_counter()
        out = tw_vectors(self, obj, scene, frame, mkey, counted, *a, **k)
        inside.append(time.perf_counter() - t - spent[0])
        return out

    # first pass after an edit: nothing cached yet
    twist.Twist.vectors = timed
    entry = session.entry_for(obj, scene)
    entry.extra.pop("twist", None)
    table = {}
    for f in FRAMES:
        scene.frame_set(f)
        vl.update()
        table[f] = entry.extra["twist"].last[1]
    first = list(inside)
    turned = max(float(np.linalg.norm(v, axis=1).max()) for v, _rot in table.values())

    def looked_up(self, obj, scene, frame, *a, **k):
        return table[int(frame)]

    frames = list(FRAMES)
    on, off = [], []
    inside.clear()
    i = 0
    for _ in range(args.rounds):
        for variant, store in ((timed, on), (looked_up, off)):
            twist.Twist.vectors = variant
            for _ in range(args.block + 1):  # the first of a block is a warm-up
                f = frames[i % len(frames)]
                i += 1
                t = time.perf_counter()
                scene.frame_set(f)
                vl.update()
                store.append(time.perf_counter() - t)
            store.pop(-args.block - 1)
    twist.Twist.vectors = tw_vectors

    def us(xs):
        return 1e6 * statistics.median(xs)

    print(
        f"Blender {bpy.app.version_string}, {2 * len(obj.data.polygons)} triangles, "
        f"{args.anchors} animated Empties (turning up to {math.degrees(turned):.0f} degrees), "
        f"{len(on)} + {len(off)} frames in {args.rounds} alternating block pairs"
    )
    print(f"live update, turns on (us):    {us(on):8.1f}")
    print(f"live update, turns off (us):   {us(off):8.1f}")
    print(f"  difference (us):             {us(on) - us(off):8.1f}")
    print(
        f"vectors() inside (us):         {us(inside):8.1f}  "
        f"({100 * statistics.median(inside) / statistics.median(on):.1f} % of the update)"
    )
    print(
        f"first pass: vectors() (us):    {us(first):8.1f}  median, "
        f"{1e6 * max(first):.0f} worst (sampling 48 frames ahead)"
    )
    sys.stdout.flush()
    os._exit(0)  # the bpy module can hang in its exit handlers


if __name__ == "__main__":
    main()
