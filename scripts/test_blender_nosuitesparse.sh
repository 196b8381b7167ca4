#!/usr/bin/env bash
# The shipped extension zip on a Linux without SuiteSparse, BLAS or OpenMP: a debootstrapped
# Debian 12 (bookworm, Python 3.11) in .cache/bookworm-bare (about 1.5 GB) that holds only
# Python and the X11/GL libraries PyPI's bpy links, with bpy 4.5.4 from PyPI in /opt/bpy.
#   1. proves the libraries are absent: no such package (dpkg), none known to the loader
#      (ldconfig -p), and the Debian-linked core (build/addon/system, what the zips used to
#      carry) fails to import there;
#   2. installs dist/material_deform-<ver>.zip as an extension, binds and poses a 7.7k-vertex bar
#      (tests/blender/deform_compare.py; ldd shows every library coming from the extension);
#   3. compares the positions with the host's: the same scene on the host, with the add-on from
#      the source tree and the Debian-linked core.
# Needs root (debootstrap, chroot) and a built dist/ (scripts/build_addon.sh); without root it
# exits 77 (skipped). Debian's mirror and PyPI only.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
CH="${MD_BARE_DIR:-$ROOT/.cache/bookworm-bare}"
MIRROR="${MD_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
BPY_VERSION="${MD_BPY_VERSION:-4.5.4}"
# What bpy's __init__.so links outside its own lib/ (ldd), and Python with venv.
PKGS=(python3 python3-venv libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libxext6 libsm6
  libice6 libgl1)
# Nothing of this may be on the system (dpkg -l names, ldconfig -p sonames).
ABSENT_PKGS='suitesparse|cholmod|libamd|libcamd|libccolamd|libcolamd|metis|blas|lapack|gomp|libomp|gfortran'
ABSENT_LIBS='libcholmod|libsuitesparse|libamd|libcolamd|libcamd|libccolamd|libmetis|libblas|liblapack|libopenblas|libgomp|libomp|libiomp|libgfortran'

if [[ "$(id -u)" -ne 0 ]]; then
  echo "SKIPPED: the bare Debian 12 chroot needs root" >&2
  exit 77
fi
VERSION="$(sed -n 's/^version = "\(.*\)"/\1/p' addon/material_deform/blender_manifest.toml)"
ZIP="dist/material_deform-$VERSION.zip"
SYSTEM_WHEEL="$(ls build/addon/system/matdeform-*.whl 2>/dev/null | head -n1)"
[[ -f "$ZIP" && -n "$SYSTEM_WHEEL" ]] || {
  echo "no $ZIP or build/addon/system/*.whl: run scripts/build_addon.sh (not MD_SYSTEM_LIBS=1)" >&2
  exit 2
}
BPY_HOST="${BPY_PYTHON:-.venv-bpy/bin/python}"
[[ -x "$BPY_HOST" ]] || { echo "no $BPY_HOST (the host's PyPI bpy, scripts/lib.sh)" >&2; exit 2; }

# A clean environment inside: the host's PIP_*/PYTHON* settings mean nothing there, except the
# CA bundle (the host's, in case its connection to PyPI needs it).
in_chroot() {
  env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 \
    PIP_CERT=/etc/md-host-ca.crt PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_DEFAULT_TIMEOUT=180 \
    chroot "$CH" "$@"
}

if [[ "$(cat "$CH/.md-packages" 2>/dev/null)" != "${PKGS[*]}" ]]; then
  # .md-debootstrapped is written only after debootstrap succeeded: a half-made one starts over.
  if [[ ! -f "$CH/.md-debootstrapped" ]]; then
    if [[ -e "$CH" && -n "${MD_BARE_DIR:-}" && ! -d "$CH/debootstrap" ]]; then
      echo "$CH exists and is not a chroot this script started: remove it or pick another" >&2
      exit 2
    fi
    command -v debootstrap >/dev/null || {
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap
    } >/dev/null
    echo "[bare] debootstrap bookworm into $CH"
    rm -rf "$CH" && mkdir -p "$CH"
    debootstrap --variant=minbase bookworm "$CH" "$MIRROR" >"$CH.debootstrap.log" 2>&1 \
      || { tail -20 "$CH.debootstrap.log"; exit 2; }
    touch "$CH/.md-debootstrapped"
  fi
  echo "[bare] apt-get install ${PKGS[*]}"
  in_chroot apt-get update -qq >"$CH.apt.log" 2>&1 || { tail -20 "$CH.apt.log"; exit 2; }
  in_chroot env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${PKGS[@]}" >"$CH.apt.log" 2>&1 || { tail -20 "$CH.apt.log"; exit 2; }
  in_chroot apt-get clean
  echo "${PKGS[*]}" >"$CH/.md-packages"
fi
cp /etc/ssl/certs/ca-certificates.crt "$CH/etc/md-host-ca.crt"
if ! in_chroot /opt/bpy/bin/python -c "import bpy
assert bpy.app.version_string.startswith('$BPY_VERSION'), bpy.app.version_string" 2>/dev/null; then
  echo "[bare] pip install bpy==$BPY_VERSION into /opt/bpy"
  rm -rf "$CH/opt/bpy"
  in_chroot python3 -m venv /opt/bpy
  in_chroot /opt/bpy/bin/pip install -q "bpy==$BPY_VERSION" >"$CH.pip.log" 2>&1 \
    || { tail -20 "$CH.pip.log"; exit 2; }
fi

# 1. Nothing to lean on.
echo "[bare] $(in_chroot sh -c '. /etc/os-release; echo "$PRETTY_NAME"'), $(in_chroot python3 -V)"
found="$(in_chroot dpkg-query -W -f '${Package}\n' | grep -E "$ABSENT_PKGS" || true)"
[[ -z "$found" ]] || { echo "installed in the chroot, must not be: $found" >&2; exit 1; }
found="$(in_chroot ldconfig -p | grep -E "$ABSENT_LIBS" || true)"
[[ -z "$found" ]] || { echo "the chroot's loader knows: $found" >&2; exit 1; }
echo "[bare] no SuiteSparse/BLAS/LAPACK/OpenMP/gfortran package or library in the chroot"

rm -rf "$CH/md" && mkdir -p "$CH/md/system"
(cd "$CH/md/system" && python3 -m zipfile -e "$ROOT/$SYSTEM_WHEEL" .)
cp "$ZIP" tests/blender/deform_compare.py "$CH/md/"
rc=0
out="$(in_chroot /opt/bpy/bin/python -c "import sys; sys.path.insert(0, '/md/system')
import matdeform" 2>&1)" || rc=$?
if [[ $rc -eq 0 || "$out" != *"libcholmod.so"* ]]; then
  echo "the Debian-linked core did not fail on libcholmod in the chroot (rc=$rc): $out" >&2
  exit 1
fi
echo "[bare] the Debian-linked core fails there as it should: $(tail -n1 <<<"$out")"

# 2. The shipped zip, in the chroot.
echo "[bare] bpy $BPY_VERSION: install ${ZIP##*/}, bind, pose"
in_chroot /opt/bpy/bin/python /md/deform_compare.py zip "/md/${ZIP##*/}" /md/chroot.npy \
  >"$CH/md/chroot.log" 2>&1 || { cat "$CH/md/chroot.log"; exit 1; }
grep -E "libcholmod|DEFORM OK" "$CH/md/chroot.log"

# 3. The same scene on the host: source-tree add-on, Debian-linked core.
"$BPY_HOST" tests/blender/deform_compare.py source "$CH/md/system" "$CH/md/host.npy" \
  >"$CH/md/host.log" 2>&1 || { cat "$CH/md/host.log"; exit 1; }
"$BPY_HOST" - "$CH/md/chroot.npy" "$CH/md/host.npy" <<'EOF'
import sys

import numpy as np

chroot, host = np.load(sys.argv[1]), np.load(sys.argv[2])
assert chroot.shape == host.shape, (chroot.shape, host.shape)
err = float(np.abs(chroot - host).max())
assert err <= 1e-5, f"chroot and host differ by {err}"
print(f"OK: {len(host)} vertices, max |chroot - host| = {err:.1e} (tolerance 1e-5)")
EOF
