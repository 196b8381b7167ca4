"""Blender's Laplacian Deform on the cat with pinned anchor vertices (runs inside Blender).

    blender -b --factory-startup --python bench/blender_laplacian.py -- IN.npz OUT.npz

IN.npz: rest (n,3), faces (m,3), anchors (a,) vertex indices, targets (l,a,3) anchor positions
per pose, iterations (scalar). OUT.npz: deformed (l,n,3).

The modifier is bound on the rest mesh; each pose is a shape key that moves only the anchor
vertices (all other vertices stay at rest). Laplacian Deform reads the anchor positions from its
input (the shape-keyed mesh) and solves for the rest, so the evaluated mesh is its answer.
"""

import sys

import bpy
import numpy as np


def main() -> None:
    argv = sys.argv[sys.argv.index("--") + 1 :]
    data = np.load(argv[0])
    rest, faces, anchors, targets = data["rest"], data["faces"], data["anchors"], data["targets"]

    mesh = bpy.data.meshes.new("cat")
    mesh.from_pydata(rest.tolist(), [], faces.tolist())
    mesh.update()
    obj = bpy.data.objects.new("cat", mesh)
    bpy.context.scene.collection.objects.link(obj)
    group = obj.vertex_groups.new(name="anchors")
    group.add(anchors.tolist(), 1.0, "REPLACE")

    obj.shape_key_add(name="Basis")
    keys = []
    for s in range(len(targets)):
        key = obj.shape_key_add(name=f"pose{s}", from_mix=False)
        co = rest.copy()
        co[anchors] = targets[s]
        key.data.foreach_set("co", co.ravel())
        key.value = 0.0
        keys.append(key)

    mod = obj.modifiers.new("Laplacian", "LAPLACIANDEFORM")
    mod.vertex_group = "anchors"
    mod.iterations = int(data["iterations"])
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.context.view_layer.update()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.laplaciandeform_bind(modifier=mod.name)
    if not mod.is_bind:
        raise RuntimeError("Laplacian Deform did not bind")

    out = np.empty((len(targets), len(rest), 3))
    for s, key in enumerate(keys):
        for k in keys:
            k.value = 0.0
        key.value = 1.0
        depsgraph = bpy.context.evaluated_depsgraph_get()
        depsgraph.update()
        ev = obj.evaluated_get(depsgraph).to_mesh()
        co = np.empty(len(ev.vertices) * 3)
        ev.vertices.foreach_get("co", co)
        out[s] = co.reshape(-1, 3)
        obj.evaluated_get(depsgraph).to_mesh_clear()
    np.savez(argv[1], deformed=out)
    print(f"laplacian: deformed {len(targets)} poses, {len(rest)} vertices")


main()
