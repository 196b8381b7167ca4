#!/usr/bin/env bash
# The add-on in a real Blender >= 4.2 executable: Debian 13's Blender 4.3, in a debootstrap chroot
# (Debian packages only, cached in .cache/debian13, about 2.3 GB). Inside it:
#   1. build the core for its Python 3.13 and both zips, the extension built and validated by
#      `blender --command extension build` / `extension validate` (scripts/build_addon.sh), linked
#      to Debian 13's own SuiteSparse (MD_SYSTEM_LIBS=1): a build for a distribution's Blender is
#      what that flag is for, and this keeps it tested (the shipped, bundled zip is step 2);
#   2. `extension validate` the zip that ships (dist/, Python 3.11 wheel) as well;
#   3. run the Blender test suite (tests/blender), including installing both zips.
# With --bpy VERSION instead: the suite in PyPI's bpy VERSION (5.1 and later need Python 3.13,
# which Debian 12 lacks and Debian 13 has), against the zips that ship (dist/): the core is
# imported from the legacy zip's _vendor and the install tests install both zips.
# Needs root (debootstrap, chroot); without it, exits 77 (skipped). Usage:
#   scripts/test_blender_debian13.sh [--bpy VERSION] [pytest args]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
CH="${MD_DEBIAN13_DIR:-$ROOT/.cache/debian13}"
MIRROR="${MD_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
BPY=""
if [[ "${1:-}" == --bpy ]]; then BPY=$2; shift 2; fi
PKGS=(blender python3-numpy python3-pytest python3-venv libegl1 libegl-mesa0 libgl1-mesa-dri
  gcc g++ libc6-dev cmake ninja-build python3-dev python3-pip python3-pybind11 pybind11-dev
  python3-scikit-build-core libeigen3-dev libsuitesparse-dev libmeshoptimizer-dev
  libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libxext6 libsm6 libice6 libgl1)
# (the last line: what PyPI's bpy links beyond its own lib/ and Blender's package)

if [[ "$(id -u)" -ne 0 ]]; then
  echo "SKIPPED: the Debian 13 chroot needs root" >&2
  exit 77
fi
# A clean environment inside: the host's PIP_*/PYTHON* settings mean nothing there.
in_chroot() { env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 chroot "$CH" "$@"; }

if [[ "$(cat "$CH/.md-packages" 2>/dev/null)" != "${PKGS[*]}" ]]; then
  # .md-debootstrapped is written only after debootstrap succeeded: a run that failed half-way
  # (which can leave apt-get behind) starts over.
  if [[ ! -f "$CH/.md-debootstrapped" ]]; then
    if [[ -e "$CH" && -n "${MD_DEBIAN13_DIR:-}" && ! -d "$CH/debootstrap" ]]; then
      echo "$CH exists and is not a chroot this script started: remove it or pick another" >&2
      exit 2
    fi
    command -v debootstrap >/dev/null || {
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap
    } >/dev/null
    echo "[debian13] debootstrap trixie into $CH"
    rm -rf "$CH" && mkdir -p "$CH"
    debootstrap --variant=minbase trixie "$CH" "$MIRROR" >"$CH.debootstrap.log" 2>&1 \
      || { tail -20 "$CH.debootstrap.log"; exit 2; }
    touch "$CH/.md-debootstrapped"
  fi
  echo "[debian13] apt-get install ${PKGS[*]}"
  in_chroot apt-get update -qq >"$CH.apt.log" 2>&1 || { tail -20 "$CH.apt.log"; exit 2; }
  in_chroot env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${PKGS[@]}" >"$CH.apt.log" 2>&1 || { tail -20 "$CH.apt.log"; exit 2; }
  echo "${PKGS[*]}" >"$CH/.md-packages"
fi

# The working tree (tracked and new files, as they are now, minus deleted ones) into a fresh
# /proj; only /proj/build is kept, so that the native build is incremental.
mkdir -p "$CH/proj"
find "$CH/proj" -mindepth 1 -maxdepth 1 ! -name build -exec rm -rf {} +
git ls-files -co --exclude-standard -z | while IFS= read -r -d '' f; do
  [[ -e "$f" ]] || continue
  printf '%s\0' "$f"
done | tar --null -T - -cf - | tar -xf - -C "$CH/proj"
mkdir -p "$CH/proj/shipped"
shopt -s nullglob
shipped=(dist/material_deform-*[0-9].zip)
legacy=(dist/material_deform-*-legacy.zip)
if [[ ${#shipped[@]} -eq 0 || ${#legacy[@]} -eq 0 ]]; then
  echo "no add-on zips in dist/ to test (run scripts/build_addon.sh first)" >&2
  exit 2
fi
cp "${shipped[@]}" "${legacy[@]}" "$CH/proj/shipped/"

if [[ -n "$BPY" ]]; then
  # bpy 5.x reads /proc/self/maps (its SYCL runtime aborts without it); the 4.3 executable not
  mountpoint -q "$CH/proc" || { mount -t proc proc "$CH/proc" && trap 'umount "$CH/proc"' EXIT; }
  if ! in_chroot /opt/bpy/bin/python -c "import bpy, pytest, numpy
assert bpy.app.version_string.startswith('${BPY%.*}'), bpy.app.version_string" 2>/dev/null; then
    echo "[debian13] pip install bpy==$BPY pytest into /opt/bpy ($(in_chroot python3 -V))"
    rm -rf "$CH/opt/bpy"
    in_chroot python3 -m venv /opt/bpy
    cp /etc/ssl/certs/ca-certificates.crt "$CH/etc/md-host-ca.crt"
    in_chroot env PIP_CERT=/etc/md-host-ca.crt PIP_DEFAULT_TIMEOUT=180 \
      /opt/bpy/bin/pip install -q "bpy==$BPY" pytest >"$CH.pip.log" 2>&1 \
      || { tail -20 "$CH.pip.log"; exit 2; }
  fi
  # the shipped legacy zip where the tests look for a built add-on (the 4.3 run rebuilds it)
  rm -rf "$CH/proj/build/addon/legacy" && mkdir -p "$CH/proj/build/addon/legacy"
  python3 -m zipfile -e "$CH/proj/shipped/${legacy[0]##*/}" "$CH/proj/build/addon/legacy"
  echo "[debian13] bpy $BPY, Python $(in_chroot /opt/bpy/bin/python -c 'import sys; print(sys.version.split()[0])'): tests/blender with the shipped zips"
  in_chroot env MD_TEST_SYS_PATH=/proj/build/addon/legacy/material_deform/_vendor MD_DIST=/proj/shipped \
    sh -c 'cd /proj && exec /opt/bpy/bin/python -m pytest -p no:cacheprovider tests/blender "$@"' \
    sh -q "$@"
  exit
fi

echo "[debian13] $(in_chroot blender --version 2>/dev/null | head -n1): build_addon.sh"
in_chroot sh -c 'cd /proj && PYTHON=python3 MD_BLENDER_PYTHON=3.13 MD_EXTRA_PYTHONS= MD_SYSTEM_LIBS=1 \
  BLENDER42=/usr/bin/blender bash scripts/build_addon.sh' >"$CH/proj/build_addon.log" 2>&1 \
  || { cat "$CH/proj/build_addon.log"; exit 2; }
grep -E "^(created|building|extension|legacy)|Success|ERROR|FATAL" "$CH/proj/build_addon.log" || true

for z in "${shipped[@]##*/}"; do  # the extension zips
  echo "[debian13] extension validate shipped/$z"
  rc=0
  out="$(in_chroot blender --factory-startup --command extension validate "/proj/shipped/$z" \
    2>&1)" || rc=$?
  grep -v "could not get a list of mounted" <<<"$out" || true
  [[ $rc -eq 0 ]] || { echo "extension validate failed on $z" >&2; exit 1; }
done

# The suite, with the core built in step 1 (the install tests take the zips in /proj/dist).
in_chroot env MD_TEST_SYS_PATH=/proj/build/addon/legacy/material_deform/_vendor sh -c \
  'cd /proj && exec blender -b --factory-startup --python-exit-code 1 --python tests/blender/run.py -- "$@"' \
  sh -q "$@"
