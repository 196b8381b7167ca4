#!/usr/bin/env bash
# Build the matdeform wheel for a CPython that need not be installed here (the add-on carries a
# core for each Python that Blender ships: 3.11 for Blender 4.1-5.0, 3.13 for 5.1 and later):
# the same sources and libraries as the project's own wheel, compiled against that Python's
# headers (scripts/lib.sh python_headers: Debian's libpythonX.Y-dev) and packed by make_wheel.py.
#   scripts/build_core_wheel.sh VERSION OUTDIR      e.g. 3.13 build/addon/wheels
# Writes OUTDIR/matdeform-<ver>-cpXY-cpXY-linux_<arch>.whl (unbundled: build_addon.sh repairs
# it like the main wheel). Env: PYTHON (the Python running the build tools, default .venv),
# MD_PREBUILT_CORE (libmatdeform_core.a of a Release build of the same sources: only the bindings
# are compiled then).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
. scripts/lib.sh
ver=$1 out=$2
PY="${PYTHON:-$ROOT/.venv/bin/python}"
# absolute, not resolved (a venv's python is a symlink): CMake runs the tools from other folders
if [[ "$PY" == */* ]]; then PY="$(realpath -s "$PY")"; else PY="$(command -v "$PY")"; fi
core="${MD_PREBUILT_CORE:+$(realpath "$MD_PREBUILT_CORE")}"
CMAKE="$(dirname "$PY")/cmake"
[[ -x "$CMAKE" ]] || CMAKE=cmake
includes="$(python_headers "$ver")"
cp="cp${ver/./}"
arch="$(gcc -print-multiarch)"  # x86_64-linux-gnu
suffix=".cpython-${ver/./}-$arch.so"
dir="build/core-$cp"
mkdir -p "$dir"
gen=()
ninja="$(dirname "$PY")/ninja"
[[ -x "$ninja" ]] || ninja="$(command -v ninja || true)"
# a tree keeps the generator it was configured with
[[ -n "$ninja" && ! -f "$dir/CMakeCache.txt" ]] && gen=(-G Ninja -DCMAKE_MAKE_PROGRAM="$ninja")
"$CMAKE" -S . -B "$dir" "${gen[@]}" -DCMAKE_BUILD_TYPE=Release -DMATDEFORM_BUILD_TESTS=OFF \
  -DMATDEFORM_BUILD_PYTHON=ON -DMATDEFORM_PYTHON_INCLUDE_DIRS="$includes" \
  -DMATDEFORM_PYTHON_EXT_SUFFIX="$suffix" -DMATDEFORM_PREBUILT_CORE="$core" \
  -Dpybind11_DIR="$("$PY" -m pybind11 --cmakedir)" \
  >"$dir/configure.log" 2>&1 || { cat "$dir/configure.log"; exit 2; }
"$CMAKE" --build "$dir" --target _core -j "${JOBS:-2}" >"$dir/build.log" 2>&1 \
  || { tail -40 "$dir/build.log"; exit 2; }
so="$dir/native/python/_core$suffix"
[[ -f "$so" ]] || { echo "no $so after the build" >&2; exit 2; }
"$PY" scripts/make_wheel.py "$so" "$cp-$cp-linux_${arch%%-*}" "$out"
