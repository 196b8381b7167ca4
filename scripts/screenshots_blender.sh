#!/usr/bin/env bash
# Screenshots of the add-on panel from a real Blender GUI (Debian's Blender 3.4) under Xvfb, for
# docs/addon.md: the sidebar at its default width with the mesh selected and with an anchor Empty
# selected. Installs xvfb if missing and builds the add-on core if needed.
#   scripts/screenshots_blender.sh [OUT_DIR]     (default docs/images)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
. scripts/lib.sh
OUT="$(realpath -m "${1:-docs/images}")"
ensure_debian_blender || exit 2
command -v xvfb-run >/dev/null || apt_install xvfb || exit 2
VENDOR="$ROOT/build/addon/legacy/material_deform/_vendor"
[[ -d "$VENDOR/matdeform" ]] || scripts/build_addon.sh
TMP="$(mktemp -d)"
trap "rm -rf \"$TMP\"" EXIT
ENABLE="import sys; sys.path[:0] = ['$ROOT/addon', '$VENDOR']; import addon_utils; \
assert addon_utils.enable('material_deform')"
blender -b --factory-startup --python-exit-code 1 --python-expr "$ENABLE" \
  --python scripts/screenshots_blender.py -- build "$TMP/scene.blend" >"$TMP/build.log" 2>&1 \
  || { cat "$TMP/build.log"; exit 1; }
# The user configuration goes to the temporary folder: nothing of the user's is read or written.
BLENDER_USER_CONFIG="$TMP/config" BLENDER_USER_SCRIPTS="$TMP/scripts" \
  timeout 300 xvfb-run -a -s "-screen 0 1280x1400x24" \
  blender --factory-startup --enable-event-simulate -p 0 0 1280 1400 \
  --python-expr "$ENABLE" "$TMP/scene.blend" --python scripts/screenshots_blender.py -- shoot "$OUT" \
  >"$TMP/shoot.log" 2>&1 || true
grep -E "^saved|tab active|Error|Traceback" "$TMP/shoot.log" || true
for f in addon_panel_mesh addon_panel_empty; do
  [[ -s "$OUT/$f.png" && "$OUT/$f.png" -nt "$TMP/scene.blend" ]] \
    || { cat "$TMP/shoot.log"; echo "screenshot $f.png was not made" >&2; exit 1; }
done
echo "screenshots in $OUT"
