"""Animated Empties drive command-line background renders (`blender -b file.blend -f N`)."""

import math
import os
import subprocess
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import tube, two_end_anchors

ADDON_DIR = Path(__file__).resolve().parents[2] / "addon"


def object_centroid_x(path):
    """Mean x (fraction of the width) of the pixels the object covers, from the alpha of a
    transparent-film render (the background colour differs between Blender versions)."""
    img = bpy.data.images.load(str(path))
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    ys, xs = np.nonzero(px.reshape(h, w, 4)[:, :, 3] > 0.5)
    assert 20 < len(xs) < 0.5 * w * h, f"{len(xs)} object pixels of {w * h}"
    return xs.mean() / w


@pytest.mark.skipif(not bpy.app.binary_path, reason="needs a Blender executable (not the module)")
def test_background_render_follows_animated_empty(tmp_path):
    obj = tube(rings=11)
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    e = top.empty
    e.keyframe_insert("location", frame=1)
    e.location.x += 2.0
    e.keyframe_insert("location", frame=10)
    scene = bpy.context.scene
    scene.frame_set(1)
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 8
    cam.location = (1, -10, 0)
    cam.rotation_euler = (math.pi / 2, 0, 0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 96
    scene.render.film_transparent = True
    blend = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))

    paths = [ADDON_DIR, *filter(None, os.environ.get("MD_TEST_SYS_PATH", "").split(os.pathsep))]
    expr = (
        f"import sys; sys.path[:0] = {[str(p) for p in paths]!r}; "
        "import addon_utils; addon_utils.enable('material_deform')"
    )
    cmd = [bpy.app.binary_path, "-b", str(blend), "--python-exit-code", "1", "--python-expr", expr]
    cmd += ["-o", str(tmp_path / "frame_####"), "-F", "PNG", "-f", "1", "-f", "10"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    x1 = object_centroid_x(tmp_path / "frame_0001.png")
    x10 = object_centroid_x(tmp_path / "frame_0010.png")
    # the top end moved 2 units right (of 8 in view): the mean of the bar shifts ~1/8 of width
    assert x10 - x1 > 0.06, (x1, x10)
