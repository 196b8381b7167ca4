"""Install the built zips (scripts/build_addon.sh -> dist/) into a throw-away user directory in
a fresh Blender process, enable them and deform a cylinder with the vendored/wheel core; then
run the background bake recipe of docs/addon.md on a saved scene, once per install kind."""

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import output, tube, two_end_anchors

HERE = Path(__file__).resolve().parent
DIST = Path(os.environ.get("MD_DIST", HERE.parents[1] / "dist"))
DOCS = HERE.parents[1] / "docs" / "addon.md"
VERSION = "0.1.0"

# The documented one-liner that enables the add-on for one run, whichever way it is installed:
# the legacy add-on is the module 'material_deform', the 4.2+ extension
# 'bl_ext.<repository>.material_deform'.
ENABLE = (
    "import addon_utils as a; a.enable(next(m.__name__ for m in a.modules() "
    "if m.__name__.rsplit('.', 1)[-1] == 'material_deform'))"
)
BAKE = (
    "import bpy; bpy.context.view_layer.objects.active = bpy.data.objects['Bar']; "
    "bpy.ops.object.material_deform_bake_point_cache(frame_start=1, frame_end=5); "
    "bpy.ops.wm.save_mainfile()"
)


def _env(tmp_path):
    env = dict(os.environ)
    env.pop("MD_TEST_SYS_PATH", None)
    env.pop("PYTHONPATH", None)
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "res")  # 4.2+
    env["BLENDER_USER_SCRIPTS"] = str(tmp_path / "scripts")  # 3.x
    env["BLENDER_USER_CONFIG"] = str(tmp_path / "config")
    return env


def _run(zip_path, tmp_path, *args):
    smoke = str(HERE / "install_smoke.py")
    if bpy.app.binary_path:  # running inside a Blender executable
        cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1"]
        cmd += ["--python", smoke, "--", str(zip_path), *args]
    else:  # PyPI bpy module
        cmd = [sys.executable, smoke, str(zip_path), *args]
    out = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "INSTALL SMOKE OK" in out.stdout, out.stdout + out.stderr
    return out


def _zip(kind):
    if kind == "extension" and bpy.app.version < (4, 2, 0):
        pytest.skip("extensions need Blender 4.2+")
    name = (
        f"material_deform-{VERSION}-legacy.zip"
        if kind == "legacy"
        else f"material_deform-{VERSION}.zip"
    )
    z = DIST / name
    if not z.exists():
        pytest.skip(f"{z} not built (run scripts/build_addon.sh)")
    return z


@pytest.mark.parametrize("kind", ["legacy", "extension"])
def test_install_zip(tmp_path, kind):
    _run(_zip(kind), tmp_path)


def test_the_zips_carry_a_core_for_each_python_blender_ships():
    """Blender 4.1-5.0 run CPython 3.11, 5.1-5.3 CPython 3.13: both zips carry both cores (a
    distribution's MD_SYSTEM_LIBS build carries its own Python's alone)."""
    with zipfile.ZipFile(DIST / f"material_deform-{VERSION}.zip") as z:
        manifest = z.read("blender_manifest.toml").decode()
        listed = re.findall(r'"\./(wheels/matdeform-[^"]+\.whl)"', manifest)
        assert set(listed) <= set(z.namelist()), listed
    if not all("manylinux" in w for w in listed):
        pytest.skip("a build against the system's libraries (MD_SYSTEM_LIBS=1)")
    assert sorted(w.split("-")[2] for w in listed) == ["cp311", "cp313"], listed
    with zipfile.ZipFile(DIST / f"material_deform-{VERSION}-legacy.zip") as z:
        names = z.namelist()
        wheel_info = z.read(_one(names, r".*\.dist-info/WHEEL")).decode()
    tags = re.findall(r"^Tag: (.*)$", wheel_info, re.M)
    for cp in ("311", "313"):
        _one(names, rf"material_deform/_vendor/matdeform/_core\.cpython-{cp}-x86_64-linux-gnu\.so")
        assert any(t.startswith(f"cp{cp}-cp{cp}-manylinux_") for t in tags), tags


def _one(names, pattern):
    (name,) = [n for n in names if re.fullmatch(pattern, n)]
    return name


def _rewritten(z, out, member, line, new):
    """A copy of zip z at out in which the lines matching regex `line` of the members whose
    names match regex `member` become `new`."""
    with zipfile.ZipFile(z) as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if re.fullmatch(member, item.filename):
                text = re.sub(line, new, data.decode(), flags=re.M)
                assert text != data.decode(), f"nothing to rewrite in {item.filename}"
                data = text.encode()
            dst.writestr(item, data)
    return out


def test_legacy_zip_on_another_platform_says_why(tmp_path):
    """The legacy zip's core tagged for Windows: enabling it prints one clear reason, shows it in
    the add-on's preferences and sidebar tab, and registers nothing else; no traceback."""
    z = _zip("legacy")
    wheel_info = r"material_deform/_vendor/[^/]+\.dist-info/WHEEL"
    other = _rewritten(z, tmp_path / z.name, wheel_info, r"^Tag: .*$", "Tag: cp311-cp311-win_amd64")
    out = _run(other, tmp_path, "unsupported")
    assert (
        "Material Deform cannot run in this Blender: its native core is built for CPython "
        "3.11 on Windows x86-64" in out.stdout
    ), out.stdout
    assert "Traceback" not in out.stdout + out.stderr, out.stdout + out.stderr


def test_extension_zip_for_another_platform_is_refused(tmp_path):
    """What `platforms` in the manifest buys: Blender refuses the extension with a message
    instead of installing a core that cannot load."""
    z = _zip("extension")
    windows = 'platforms = ["windows-x64"]'
    other = _rewritten(z, tmp_path / z.name, "blender_manifest.toml", r"^platforms = .*$", windows)
    out = _run(other, tmp_path, "refused")
    assert "isn't one of (windows-x64)" in out.stdout + out.stderr, out.stdout + out.stderr


def _saved_scene(path):
    """A bound bar whose top Empty moves over frames 1..5; returns the live result per frame."""
    obj = tube()
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    e = top.empty
    e.keyframe_insert("location", frame=1)
    e.location.x += 1.5
    e.rotation_euler.y = 0.8
    e.keyframe_insert("location", frame=5)
    e.keyframe_insert("rotation_euler", frame=5)
    scene = bpy.context.scene
    live = []
    for f in range(1, 6):
        scene.frame_set(f)
        live.append(output(obj).copy())
    scene.frame_set(1)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return np.stack(live)


def test_docs_give_the_recipe_for_both_installs():
    text = DOCS.read_text()
    runs = [line for line in text.splitlines() if line.startswith("blender ") and "-expr" in line]
    assert len(runs) >= 3  # Learn, render, bake
    assert all(ENABLE in line for line in runs)  # not addon_utils.enable('material_deform')


@pytest.mark.parametrize("kind", ["legacy", "extension"])
def test_background_bake_recipe_on_a_saved_scene(tmp_path, kind):
    """`blender -b scene.blend --python-expr "<enable>; <bake>"` with the add-on installed but
    not enabled (a render-farm node), as docs/addon.md gives it."""
    from material_deform.pointcache import read_pc2

    z = _zip(kind)
    _run(z, tmp_path)  # installs it into the throw-away user directory (not saved as enabled)
    blend = tmp_path / "scene.blend"
    live = _saved_scene(blend)
    expr = f"{ENABLE}; {BAKE}"
    if bpy.app.binary_path:
        cmd = [bpy.app.binary_path, "-b", str(blend), "--python-exit-code", "1"]
        cmd += ["--python-expr", expr]
    else:  # the bpy module has no command line: open the file, then run the same expression
        cmd = [
            sys.executable,
            "-c",
            f"import bpy; bpy.ops.wm.open_mainfile(filepath={str(blend)!r}); {expr}",
        ]
    out = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    start, _rate, frames = read_pc2(str(tmp_path / "scene_Bar.pc2"))
    assert start == 1.0
    np.testing.assert_allclose(frames, live, atol=1e-5)
    bpy.ops.wm.open_mainfile(filepath=str(blend))  # saved with the modifier that reads it
    mod = bpy.data.objects["Bar"].modifiers[0]
    assert mod.type == "MESH_CACHE" and mod.filepath == "//scene_Bar.pc2"
