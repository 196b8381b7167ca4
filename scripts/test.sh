#!/usr/bin/env bash
# Runs every test: C++ (GoogleTest via ctest, then again under ASan+UBSan), Python (pytest),
# lint (ruff, clang-format), and the Blender suites when scripts/test_blender.sh exists.
# Installs what is missing first. Exit code is non-zero if anything fails.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
VPY="$ROOT/.venv/bin/python"
CMAKE="$ROOT/.venv/bin/cmake"
JOBS="${JOBS:-2}"

echo "== C++ tests (Release)"
"$CMAKE" -S . -B build/cpp -G Ninja -DCMAKE_MAKE_PROGRAM="$ROOT/.venv/bin/ninja" \
  -DMATDEFORM_BUILD_TESTS=ON -DCMAKE_BUILD_TYPE=Release >/dev/null
"$CMAKE" --build build/cpp -j "$JOBS"
ctest --test-dir build/cpp --output-on-failure

echo "== C++ tests (AddressSanitizer + UBSan)"
"$CMAKE" -S . -B build/asan -G Ninja -DCMAKE_MAKE_PROGRAM="$ROOT/.venv/bin/ninja" \
  -DMATDEFORM_BUILD_TESTS=ON -DMATDEFORM_SANITIZE=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
"$CMAKE" --build build/asan -j "$JOBS"
ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build/asan --output-on-failure

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
