"""Does another way of writing the result avoid Blender's fixed re-evaluation cost? (issue 12)

On Blender 3.4 any geometry change of a 25k-vertex mesh costs ~1 ms of re-evaluation, whatever
changed. This times, on the bench_blender.py tube (50k triangles), each route by which the
add-on could hand Blender the deformed positions, from the write to the end of
``view_layer.update()``:

* the add-on's route: bulk copy into the output shape key, tag only the Key;
* the same shape key, tagged through the mesh;
* the mesh's own vertices (``foreach_set`` + ``Mesh.update``), no shape key;
* a tag alone, nothing written (the floor of the two above);
* a write into the *evaluated* mesh of the depsgraph, no tag at all.

It then checks whether the last route survives: after an unrelated update, after moving the
object, and after a geometry re-evaluation of the object.

Usage:
  MD_SYS_PATH=$PWD/build/addon/legacy/material_deform/_vendor blender -b --factory-startup \\
      --python bench/bench_blender_routes.py -- [--faces 50000] [--reps 300]
  MD_SYS_PATH=build/addon/legacy/material_deform/_vendor .venv-bpy/bin/python \\
      bench/bench_blender_routes.py
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_blender as bb  # noqa: E402  (also puts MD_SYS_PATH on sys.path)
import bpy  # noqa: E402
import numpy as np  # noqa: E402
from bench_blender_parts import median_ms  # noqa: E402


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", type=int, default=50000)
    ap.add_argument("--reps", type=int, default=300)
    args = ap.parse_args(argv)

    import addon_utils

    addon_utils.enable("material_deform", default_set=True)
    from material_deform import bridge

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    vl = bpy.context.view_layer
    rings, sides = bb.tube_dims(args.faces)
    a = bb.tube("Key", rings, sides)
    b = bb.tube("Verts", rings, sides)
    c = bb.tube("Evaluated", rings, sides)
    n = len(a.data.vertices)
    base = np.empty((n, 3), np.float32)
    a.data.vertices.foreach_get("co", base.ravel())
    a.shape_key_add(name="Basis")
    kb = a.shape_key_add(name="Out")
    kb.value = 1.0
    vl.update()

    def moved(i):
        return base + np.float32(0.001 * (i % 7 + 1))

    def key_tagged(i):
        bridge.write_key(a, kb, moved(i))
        vl.update()

    def key_mesh_tagged(i):
        bridge.write_key(a, kb, moved(i))
        a.data.update_tag()
        vl.update()

    def vertices(i):
        b.data.vertices.foreach_set("co", moved(i).ravel())
        b.data.update()
        vl.update()

    def tag_only(i):
        b.data.update_tag()
        vl.update()

    def evaluated(i):
        dg = bpy.context.evaluated_depsgraph_get()
        c.evaluated_get(dg).data.vertices.foreach_set("co", moved(i).ravel())

    rows = [
        ("shape key, bulk copy, Key tagged (the add-on's route)", key_tagged),
        ("shape key, bulk copy, Mesh tagged", key_mesh_tagged),
        ("mesh vertices, foreach_set + Mesh.update", vertices),
        ("Mesh tagged, nothing written", tag_only),
        ("evaluated mesh written, no tag, no re-evaluation", evaluated),
    ]
    print(f"Blender {bpy.app.version_string}, {2 * len(a.data.polygons)} triangles, {n} vertices")
    print(f"medians of {args.reps} updates, write + view_layer.update() (ms):")
    for label, fn in rows:
        fn(0)
        print(f"  {label:<55} {median_ms(fn, args.reps):.3f}")

    def kept():
        dg = bpy.context.evaluated_depsgraph_get()
        co = np.empty(3 * n, np.float32)
        c.evaluated_get(dg).data.vertices.foreach_get("co", co)
        return np.array_equal(co, moved(args.reps - 1).ravel())

    vl.update()
    print("evaluated-mesh route: the written positions are still there")
    print(f"  after an unrelated update:        {kept()}")
    c.location.x += 0.1
    vl.update()
    print(f"  after moving the object:          {kept()}")
    c.data.update_tag()
    vl.update()
    print(f"  after a geometry re-evaluation:   {kept()}")


if __name__ == "__main__":
    main()
