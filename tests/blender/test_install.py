"""Install the built zips (scripts/build_addon.sh -> dist/) into a throw-away user directory in
a fresh Blender process, enable them and deform a cylinder with the vendored/wheel core."""

import os
import subprocess
import sys
from pathlib import Path

import bpy
import pytest

HERE = Path(__file__).resolve().parent
DIST = Path(os.environ.get("MD_DIST", HERE.parents[1] / "dist"))
VERSION = "0.1.0"


def _run(zip_path, tmp_path):
    env = dict(os.environ)
    env.pop("MD_TEST_SYS_PATH", None)
    env.pop("PYTHONPATH", None)
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "res")  # 4.2+
    env["BLENDER_USER_SCRIPTS"] = str(tmp_path / "scripts")  # 3.x
    env["BLENDER_USER_CONFIG"] = str(tmp_path / "config")
    smoke = str(HERE / "install_smoke.py")
    if bpy.app.binary_path:  # running inside a Blender executable
        cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1"]
        cmd += ["--python", smoke, "--", str(zip_path)]
    else:  # PyPI bpy module
        cmd = [sys.executable, smoke, str(zip_path)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "INSTALL SMOKE OK" in out.stdout, out.stdout + out.stderr


def test_install_legacy_zip(tmp_path):
    z = DIST / f"material_deform-{VERSION}-legacy.zip"
    if not z.exists():
        pytest.skip(f"{z} not built (run scripts/build_addon.sh)")
    _run(z, tmp_path)


def test_install_extension_zip(tmp_path):
    if bpy.app.version < (4, 2, 0):
        pytest.skip("extensions need Blender 4.2+")
    z = DIST / f"material_deform-{VERSION}.zip"
    if not z.exists():
        pytest.skip(f"{z} not built (run scripts/build_addon.sh)")
    _run(z, tmp_path)
