"""Install the built zips (scripts/build_addon.sh -> dist/) into a throw-away user directory in
a fresh Blender process, enable them and deform a cylinder with the vendored/wheel core."""

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import bpy
import pytest

HERE = Path(__file__).resolve().parent
DIST = Path(os.environ.get("MD_DIST", HERE.parents[1] / "dist"))
VERSION = "0.1.0"


def _run(zip_path, tmp_path, *args):
    env = dict(os.environ)
    env.pop("MD_TEST_SYS_PATH", None)
    env.pop("PYTHONPATH", None)
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "res")  # 4.2+
    env["BLENDER_USER_SCRIPTS"] = str(tmp_path / "scripts")  # 3.x
    env["BLENDER_USER_CONFIG"] = str(tmp_path / "config")
    smoke = str(HERE / "install_smoke.py")
    if bpy.app.binary_path:  # running inside a Blender executable
        cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1"]
        cmd += ["--python", smoke, "--", str(zip_path), *args]
    else:  # PyPI bpy module
        cmd = [sys.executable, smoke, str(zip_path), *args]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "INSTALL SMOKE OK" in out.stdout, out.stdout + out.stderr
    return out


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
    z = DIST / f"material_deform-{VERSION}-legacy.zip"
    if not z.exists():
        pytest.skip(f"{z} not built (run scripts/build_addon.sh)")
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
    if bpy.app.version < (4, 2, 0):
        pytest.skip("extensions need Blender 4.2+")
    z = DIST / f"material_deform-{VERSION}.zip"
    if not z.exists():
        pytest.skip(f"{z} not built (run scripts/build_addon.sh)")
    windows = 'platforms = ["windows-x64"]'
    other = _rewritten(z, tmp_path / z.name, "blender_manifest.toml", r"^platforms = .*$", windows)
    out = _run(other, tmp_path, "refused")
    assert "isn't one of (windows-x64)" in out.stdout + out.stderr, out.stdout + out.stderr
