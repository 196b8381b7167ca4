#!/usr/bin/env bash
# Runs every test: C++ (GoogleTest via ctest: GCC, GCC with the portable SIMD path, Clang, all
# three warning-free (-Werror), then again under ASan+UBSan), Python (pytest), lint (ruff,
# clang-format), and the Blender suites when scripts/test_blender.sh exists.
# Installs what is missing first. Exit code is non-zero if anything fails.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
VPY="$ROOT/.venv/bin/python"
CMAKE="$ROOT/.venv/bin/cmake"
JOBS="${JOBS:-2}"

cpp_tests() {  # cpp_tests BUILD_DIR CMAKE_ARGS... : configure, build, run the GoogleTest suite
  local dir=$1; shift
  "$CMAKE" -S . -B "$dir" -G Ninja -DCMAKE_MAKE_PROGRAM="$ROOT/.venv/bin/ninja" \
    -DMATDEFORM_BUILD_TESTS=ON "$@" >/dev/null
  "$CMAKE" --build "$dir" -j "$JOBS"
  ctest --test-dir "$dir" --output-on-failure
}

echo "== C++ tests (Release)"
cpp_tests build/cpp -DCMAKE_BUILD_TYPE=Release -DMATDEFORM_WERROR=ON

# The plain-struct Vec4d that compilers without GCC/Clang vector extensions (MSVC) build.
echo "== C++ tests (portable SIMD path)"
cpp_tests build/portable -DCMAKE_BUILD_TYPE=Release -DMATDEFORM_WERROR=ON \
  -DMATDEFORM_PORTABLE_SIMD=ON

echo "== C++ tests (Clang)"
cpp_tests build/clang -DCMAKE_BUILD_TYPE=Release -DMATDEFORM_WERROR=ON \
  -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++

echo "== C++ tests (AddressSanitizer + UBSan)"
ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  cpp_tests build/asan -DMATDEFORM_SANITIZE=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo

echo "== Python tests"
"$VPY" -m pytest -q tests/python

echo "== Lint"
"$VPY" -m ruff check .
"$VPY" -m ruff format --check .
clang-format --dry-run --Werror native/include/matdeform/*.hpp native/src/*.[ch]pp \
  native/python/*.[ch]pp tests/cpp/*.[ch]pp

if [ -f scripts/test_blender.sh ]; then
  echo "== Blender tests"
  bash scripts/test_blender.sh
fi
echo "== all tests passed"
