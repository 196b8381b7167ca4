#!/usr/bin/env bash
# Run the add-on test suite inside Debian's Blender (3.4), with the PyPI bpy module (4.5 LTS; 4.2.0,
# the oldest Blender the extension supports, MD_BPY42=0 skips it; plus 5.0 if MD_BPY5=1) and
# inside Debian 13's Blender 4.3 in a chroot, then PyPI's bpy 5.3 (Python 3.13) in the same chroot
# with the shipped zips (as root; MD_DEBIAN13=0 skips both, MD_BPY53=0 the second), installing
# whatever is missing; then, as root, the shipped extension zip in a Debian 12 chroot without
# SuiteSparse, BLAS or OpenMP (MD_NOSUITESPARSE=0 skips it). Exit status: non-zero if any run
# fails.
#   scripts/test_blender.sh [extra pytest args]
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
BPY_VERSION="${MD_BPY_VERSION:-4.5.4}"

. scripts/lib.sh
ensure_debian_blender || exit 2
# separate venvs: bpy pins its own numpy, the project's .venv must not be disturbed
ensure_bpy_venv .venv-bpy "$BPY_VERSION" || exit 2

# build the wheel and both zips; the tests import the core from the vendored copy
build_log=$(mktemp)  # not a fixed name: other checkouts may run this at the same time
scripts/build_addon.sh >"$build_log" 2>&1 \
  || { cat "$build_log"; echo "build_addon.sh failed" >&2; exit 2; }
rm -f "$build_log"
export MD_TEST_SYS_PATH="$ROOT/build/addon/legacy/material_deform/_vendor"

status=0
summary=()
run() {  # run LABEL CMD...
  local label=$1; shift
  echo "=== $label"
  local log; log=$(mktemp)
  # Exit status of the test process itself: a filtered pipeline with '|| true' would hide it.
  local rc=0
  "$@" >"$log" 2>&1 || rc=$?
  grep -vE "^(Read blend|Info:|Warning:|Error:|Blender quit)" "$log" || true
  if [[ $rc -eq 77 ]]; then  # the run could not start here (e.g. the chroot without root)
    summary+=("$label: $(tail -n1 "$log")")  # "SKIPPED: why"
  else
    summary+=("$label: rc=$rc $(grep -E '[0-9]+ (passed|failed)|^OK: ' "$log" | tail -n1)")
    [[ $rc -eq 0 ]] || status=1
  fi
  rm -f "$log"
}
run "Blender $(blender --version 2>/dev/null | head -n1 | cut -d' ' -f2) (Debian)" \
  blender -b --factory-startup --python-exit-code 1 --python tests/blender/run.py -- -q "$@"
run "bpy $BPY_VERSION (PyPI)" .venv-bpy/bin/python -m pytest -q -p no:cacheprovider tests/blender "$@"
# blender_version_min of the extension: Blender versions differ in what they tag on a bulk write
# (4.2 tags nothing, 4.3+ the Key), and only a run there shows that the live updates still land
if [[ "${MD_BPY42:-1}" == 1 ]]; then
  ensure_bpy_venv .venv-bpy42 4.2.0 || exit 2
  run "bpy 4.2.0 (PyPI)" .venv-bpy42/bin/python -m pytest -q -p no:cacheprovider tests/blender "$@"
fi
# A real Blender >= 4.2 executable: Debian 13's 4.3 in a chroot (also runs the extension tool)
if [[ "${MD_DEBIAN13:-1}" == 1 ]]; then
  run "Blender 4.3 (Debian 13 chroot)" bash scripts/test_blender_debian13.sh "$@"
  # today's Blender: 5.1-5.3 run Python 3.13, and only the shipped zips show that they load there
  if [[ "${MD_BPY53:-1}" == 1 ]]; then
    run "bpy 5.3.0 (PyPI, Python 3.13, Debian 13 chroot), shipped zips" \
      bash scripts/test_blender_debian13.sh --bpy 5.3.0 "$@"
  fi
fi
# The shipped zip where SuiteSparse, BLAS and OpenMP are not installed, against the host's numbers
if [[ "${MD_NOSUITESPARSE:-1}" == 1 ]]; then
  run "bpy $BPY_VERSION, shipped zip (Debian 12 chroot without SuiteSparse/BLAS/OpenMP)" \
    bash scripts/test_blender_nosuitesparse.sh
fi
if [[ "${MD_BPY5:-0}" == 1 ]]; then
  ensure_bpy_venv .venv-bpy5 5.0.1 || exit 2
  run "bpy 5.0.1 (PyPI)" .venv-bpy5/bin/python -m pytest -q -p no:cacheprovider tests/blender "$@"
fi
printf '%s\n' "${summary[@]}"
exit $status
