"""Live update time of the add-on's Pose space method inside Blender, with and without
multiresolution: a tube with 10 example shape keys (bends in several directions), the bottom
ring a Frame anchor, the top ring a Follow Empty anchor that turns freely and moves each update.

    MD_SYS_PATH=build/addon/legacy/material_deform/_vendor \\
        .venv-bpy/bin/python bench/bench_blender_pose_space.py [--sizes 17000 51000] [--reps 30]
    (or: blender -b --factory-startup --python bench/bench_blender_pose_space.py -- [args])

Timed per update (medians): "check" = the method's live check of the example keys (bulk reads,
compared bit for bit), "solve" = the method's solve (handle targets + deform()) for the same
pose, "full update" = move the Empty, view_layer.update() (the handler solves
and writes the output key; Blender re-evaluates the mesh), what the user waits for.
"""

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in reversed(os.environ.get("MD_SYS_PATH", "").split(os.pathsep)):
    if p:
        sys.path.insert(0, p)
sys.path.insert(0, str(ROOT / "addon"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Euler, Matrix, Vector  # noqa: E402


def tube(rings, sides, length=4.0, radius=0.5):
    """Round tube along z over [-length/2, length/2], quads, n-gon caps."""
    verts = [
        (radius * math.cos(2 * math.pi * s / sides), radius * math.sin(2 * math.pi * s / sides), z)
        for z in np.linspace(-length / 2, length / 2, rings)
        for s in range(sides)
    ]
    faces = [tuple(reversed(range(sides))), tuple(range((rings - 1) * sides, rings * sides))]
    for r in range(rings - 1):
        for s in range(sides):
            a, b = r * sides + s, r * sides + (s + 1) % sides
            faces.append((a, b, b + sides, a + sides))
    me = bpy.data.meshes.new("Tube")
    me.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new("Tube", me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def bend(v, angle, azimuth, length=4.0):
    c, s = math.cos(azimuth), math.sin(azimuth)
    u, w, t = v[:, 0] * c + v[:, 1] * s, -v[:, 0] * s + v[:, 1] * c, v[:, 2] + length / 2
    rho = length / angle
    u2, z2 = rho - (rho - u) * np.cos(t / rho), (rho - u) * np.sin(t / rho) - length / 2
    return np.stack([u2 * c - w * s, u2 * s + w * c, z2], axis=1)


def activate(obj):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def add_anchor(obj, pick, mode):
    from material_deform.bridge import select_polygons_edit

    activate(obj)
    bpy.ops.object.mode_set(mode="EDIT")
    select_polygons_edit(obj, [bool(pick(p)) for p in obj.data.polygons])
    assert bpy.ops.mesh.material_deform_add_anchor(mode=mode) == {"FINISHED"}
    bpy.ops.object.mode_set(mode="OBJECT")
    return obj.material_deform.anchors[-1]


def run(faces, reps, coarse):
    import addon_utils

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    addon_utils.enable("material_deform", default_set=True)
    from material_deform import session
    from material_deform.methods import pose_space

    sides = 64
    rings = max(3, round(faces / (2 * sides)) + 1)
    obj = tube(rings, sides)
    v = np.array([p.co[:] for p in obj.data.vertices])
    obj.shape_key_add(name="Basis", from_mix=False)
    for k in range(10):
        kb = obj.shape_key_add(name=f"Pose {k}", from_mix=False)
        kb.data.foreach_set(
            "co", bend(v, 0.4 + 0.12 * k, 2 * math.pi * k / 10).astype("f4").ravel()
        )
        kb.value = 0.0
    add_anchor(obj, lambda p: p.center.z < -2 + 1e-4, "FRAME")
    top = add_anchor(obj, lambda p: p.center.z > 2 - 1e-4, "POSITION")
    s = obj.material_deform
    s.method = "POSE_SPACE"
    s.pose_space.multiresolution = coarse is not None
    if coarse is not None:
        s.pose_space.coarse_faces = coarse
    activate(obj)
    t0 = time.perf_counter()
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    t_bind = time.perf_counter() - t0
    entry = session.entry_for(obj, bpy.context.scene)
    method = pose_space.PoseSpaceMethod()
    rng = np.random.default_rng(1)
    e_bind = top.empty.matrix_world.copy()
    checks, fulls, solves = [], [], []
    for i in range(reps + 1):
        ang = rng.uniform(-1.0, 1.0, 3)
        move = Vector(rng.uniform(-0.8, 0.8, 3))
        top.empty.matrix_world = Matrix.Translation(move) @ e_bind @ Euler(ang).to_matrix().to_4x4()
        t0 = time.perf_counter()
        bpy.context.view_layer.update()
        t1 = time.perf_counter()
        method.check_live(obj, entry, None)
        t2 = time.perf_counter()
        tr = session.transforms_now(obj, entry, bpy.context.scene)
        t3 = time.perf_counter()
        method.solve(entry.solver, tr, {}, None)
        t4 = time.perf_counter()
        if i:  # the first is a warm-up
            fulls.append(t1 - t0)
            checks.append(t2 - t1)
            solves.append(t4 - t3)
    assert session.stale_reason(obj) == "", session.stale_reason(obj)
    if os.environ.get("MD_BENCH_STATS"):
        print(entry.solver.deformer.last_stats)
    n_tri = sum(len(p.vertices) - 2 for p in obj.data.polygons)
    med = statistics.median
    return n_tri, len(v), t_bind, med(checks), med(solves), med(fulls)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[17000, 51000])
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--coarse", type=int, default=1000)
    args = ap.parse_args(argv)
    print(f"Blender {bpy.app.version_string}, {os.cpu_count()} CPU(s), 10 examples")
    cols = ("triangles", "vertices", "resolution", "bind (s)", "check (ms)", "solve (ms)")
    print("| " + " | ".join(cols) + " | full update (ms) |")
    print("|---:|---:|---|---:|---:|---:|---:|")
    for faces in args.sizes:
        for coarse in (None, args.coarse):
            n_tri, n_v, tb, tc, ts, tf = run(faces, args.reps, coarse)
            res = "single" if coarse is None else f"coarse {coarse}"
            print(
                f"| {n_tri} | {n_v} | {res} | {tb:.2f} | {1e3 * tc:.2f} | {1e3 * ts:.1f} "
                f"| {1e3 * tf:.1f} |"
            )


main()
