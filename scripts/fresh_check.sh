#!/usr/bin/env bash
# Proves that the README's two commands work from scratch, as on a new machine:
#   1. clones HEAD (committed work only) into a new temporary folder with nothing beside it (no
#      ../shared: everything the tests, demo and benchmarks read is in the repository);
#   2. as root, first removes the Debian Python packages the scripts install for Debian's Blender
#      (python3-pytest, python3-numpy), so that their install steps must really run;
#   3. runs ./scripts/demo.sh, checks that it wrote out/demo.blend and PNGs, then runs
#      ./scripts/test.sh (the command CI runs).
# Exit status is non-zero if either command fails. Env: MD_FRESH_KEEP=1 keeps the folder,
# MD_FRESH_REMOVE=0 skips step 2. Run it before every stop.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WORK="$(mktemp -d "${TMPDIR:-/tmp}/md-fresh.XXXXXX")"
REMOVED=0
cleanup() {
  [[ "${MD_FRESH_KEEP:-0}" == 1 ]] || rm -rf "$WORK"
  # Stopped before the test command put Debian's packages back (interrupted, or the demo
  # failed): put them back here, so that the machine's Blender keeps its numpy and pytest.
  if [[ $REMOVED == 1 ]] && ! dpkg-query -W -f='${Status}' python3-numpy 2>/dev/null \
    | grep -q "install ok installed"; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-pytest python3-numpy >/dev/null || true
  fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM
git clone -q "$ROOT" "$WORK/main"
cd "$WORK/main"
echo "[fresh] $(git log -1 --format='%h %s') in $WORK/main"

if [[ "${MD_FRESH_REMOVE:-1}" == 1 ]]; then
  if [[ "$(id -u)" -eq 0 ]]; then
    echo "[fresh] apt-get remove python3-pytest python3-numpy"
    REMOVED=1
    DEBIAN_FRONTEND=noninteractive apt-get remove -y -qq python3-pytest python3-numpy >/dev/null
    if command -v blender >/dev/null \
      && blender -b --factory-startup --python-exit-code 1 --python-expr "import pytest" \
        >/dev/null 2>&1; then
      echo "[fresh] pytest is still importable in Debian's Blender after removing it" >&2
      exit 1
    fi
  else
    echo "[fresh] not root: Debian's python3-pytest/python3-numpy are left installed"
  fi
fi

t0=$SECONDS
echo "[fresh] ./scripts/demo.sh"
./scripts/demo.sh >"$WORK/demo.log" 2>&1 || { tail -40 "$WORK/demo.log"; echo "[fresh] demo FAILED" >&2; exit 1; }
ls out/demo.blend >/dev/null && compgen -G "out/*.png" >/dev/null \
  || { echo "[fresh] demo wrote no out/demo.blend or no PNG" >&2; exit 1; }
echo "[fresh] demo ok in $((SECONDS - t0)) s: $(ls out | tr '\n' ' ')"

t0=$SECONDS
echo "[fresh] ./scripts/test.sh"
rc=0
./scripts/test.sh >"$WORK/test.log" 2>&1 || rc=$?
grep -E "^(==|===)|passed|failed|rc=|SKIPPED|Error" "$WORK/test.log" | tail -40
echo "[fresh] test.sh rc=$rc in $((SECONDS - t0)) s (log: $WORK/test.log)"
[[ $rc -eq 0 ]] || { MD_FRESH_KEEP=1; exit 1; }
