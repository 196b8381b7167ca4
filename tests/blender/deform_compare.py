"""Bind and pose one fixed scene with the add-on and save the deformed positions, for comparing
two installs (scripts/test_blender_nosuitesparse.sh). Run with the PyPI bpy module:

    python deform_compare.py zip ZIP OUT.npy          # install ZIP as an extension first
    python deform_compare.py source CORE_DIR OUT.npy  # the add-on from this source tree, the
                                                      # matdeform package from CORE_DIR
The mesh has 7.7k vertices: above about 5k CHOLMOD takes its supernodal path, so the solve goes
through BLAS and LAPACK (checked by interposing dsyrk_). In zip mode it also checks, with ldd,
that every library the core loads outside the C/C++ runtime comes from the extension itself.
"""

import atexit
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

mode, where, out_path = sys.argv[1:4]
assert mode in ("zip", "source"), mode
user = tempfile.mkdtemp(prefix="md-deform-")
atexit.register(shutil.rmtree, user, ignore_errors=True)
os.environ["BLENDER_USER_RESOURCES"] = os.path.join(user, "res")  # before bpy reads them
os.environ["BLENDER_USER_CONFIG"] = os.path.join(user, "config")
os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(user, "scripts")

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Matrix  # noqa: E402

if mode == "zip":
    bpy.ops.extensions.package_install_files(
        filepath=where, repo="user_default", enable_on_install=True
    )
    module = "bl_ext.user_default.material_deform"
else:
    sys.path[:0] = [where, str(Path(__file__).resolve().parents[2] / "addon")]
    import addon_utils

    addon_utils.enable("material_deform", default_set=True)
    module = "material_deform"
assert module in bpy.context.preferences.addons, f"{module} not enabled"

import importlib  # noqa: E402

md = importlib.import_module(module + ".core").load()
bridge = importlib.import_module(module + ".bridge")
core_file = md._core.__file__
print("matdeform core:", core_file)
if mode == "source":
    assert core_file.startswith(os.path.abspath(where)), core_file
else:
    assert core_file.startswith(os.environ["BLENDER_USER_RESOURCES"]), core_file
    # Every dependency outside the C/C++ runtime must resolve inside the installed extension.
    runtime = ("linux-vdso", "libc.so", "libm.so", "libstdc++", "libgcc_s", "ld-linux", "libdl.so")
    runtime += ("libpthread.so", "librt.so")
    ldd = subprocess.run(["ldd", core_file], capture_output=True, text=True, check=True).stdout
    print(ldd)
    site = os.path.dirname(os.path.dirname(core_file))
    for line in ldd.splitlines():
        name, _, target = line.strip().partition(" => ")
        assert "not found" not in target, line
        if not os.path.basename(name).startswith(runtime):
            assert target.startswith(site), f"{name} comes from outside the extension: {target}"
    assert "libcholmod" in ldd and "libopenblas" in ldd, ldd

# A bar along z, 161 rings of 48 quads and two n-gon caps; stiff ends, soft middle.
rings, sides, length = 161, 48, 4.0
verts = [
    (0.5 * math.cos(2 * math.pi * s / sides), 0.5 * math.sin(2 * math.pi * s / sides), z)
    for z in np.linspace(-length / 2, length / 2, rings)
    for s in range(sides)
]
faces = [tuple(reversed(range(sides))), tuple(range((rings - 1) * sides, rings * sides))]
for r in range(rings - 1):
    for s in range(sides):
        a, b = r * sides + s, r * sides + (s + 1) % sides
        faces.append((a, b, b + sides, a + sides))
bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
me = bpy.data.meshes.new("Bar")
me.from_pydata(verts, [], faces)
obj = bpy.data.objects.new("Bar", me)
bpy.context.scene.collection.objects.link(obj)
bpy.context.view_layer.objects.active = obj
obj.select_set(True)
vg = obj.vertex_groups.new(name="Stiffness")
vg.add([i for i, v in enumerate(verts) if abs(v[2]) > 1.0], 1.0, "REPLACE")
assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}

anchors = [  # (faces, mode): both caps follow their Empty, a middle band only turns
    (lambda p: p.center.z > length / 2 - 1e-4, "POSITION"),
    (lambda p: p.center.z < -length / 2 + 1e-4, "POSITION"),
    (lambda p: abs(p.center.z) < 0.1, "ROTATION"),
]
for pick, anchor_mode in anchors:
    mask = [bool(pick(p)) for p in obj.data.polygons]
    bpy.ops.object.mode_set(mode="EDIT")
    bridge.select_polygons_edit(obj, mask)
    assert bpy.ops.mesh.material_deform_add_anchor(mode=anchor_mode) == {"FINISHED"}
    bpy.ops.object.mode_set(mode="OBJECT")
assert bpy.ops.object.material_deform_bind() == {"FINISHED"}

top, bottom, middle = (a.empty for a in obj.material_deform.anchors)
move = (
    Matrix.Translation((0.8, 0.3, -0.5))
    @ Matrix.Rotation(math.radians(70), 4, "X")
    @ Matrix.Diagonal((1.15, 1.15, 1.15, 1.0))
)
top_bind = top.matrix_world.copy()
top.matrix_world = move @ top_bind
middle.matrix_world = Matrix.Rotation(math.radians(30), 4, "Z") @ middle.matrix_world
bpy.context.view_layer.update()

kb = obj.data.shape_keys.key_blocks["Material Deform"]
X = np.empty(len(kb.data) * 3, np.float32)
kb.data.foreach_get("co", X)
X = X.reshape(-1, 3).astype(np.float64)
V = np.asarray(verts)
assert np.isfinite(X).all()
# The caps follow their Empties exactly; the soft middle really bends.
cap_top, cap_bottom = V[:, 2] > length / 2 - 1e-6, V[:, 2] < -length / 2 + 1e-6
T = np.array(move)
np.testing.assert_allclose(X[cap_top], V[cap_top] @ T[:3, :3].T + T[:3, 3], atol=2e-5)
np.testing.assert_allclose(X[cap_bottom], V[cap_bottom], atol=2e-5)
assert np.abs(X - V).max(axis=1)[np.abs(V[:, 2]) < 1.0].max() > 0.1
np.save(out_path, X)
print(f"DEFORM OK {bpy.app.version_string}: {len(X)} vertices -> {out_path}")
