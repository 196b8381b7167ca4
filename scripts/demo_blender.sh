#!/usr/bin/env bash
# Build the demo scenes in background Blender: out/demo.blend + out/demo.png (material-aware),
# out/demo_pose_space.blend + out/demo_pose_space_addon.png (Pose space through the add-on).
# Installs Debian's blender + numpy if missing and builds the add-on (core included) if needed.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
. scripts/lib.sh
if ! blender_can_import numpy; then
  apt_install blender python3-numpy || exit 2
  blender_can_import numpy || { echo "Debian's blender cannot import numpy" >&2; exit 2; }
fi
VENDOR="$ROOT/build/addon/legacy/material_deform/_vendor"
# Rebuild when missing or older than any source it is built from (a stale core would show the
# last build's behaviour in the pictures).
if [[ ! -f "$VENDOR/matdeform/__init__.py" ]] \
  || [[ -n "$(find native src addon CMakeLists.txt pyproject.toml -newer "$VENDOR/matdeform/__init__.py" -type f 2>/dev/null | head -1)" ]]; then
  scripts/build_addon.sh
fi
MD_SYS_PATH="$VENDOR" blender -b --factory-startup --python-exit-code 1 \
  --python scripts/demo_blender.py
