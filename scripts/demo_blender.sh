#!/usr/bin/env bash
# Build the demo scene in background Blender: out/demo.blend and out/demo.png.
# Installs Debian's blender + numpy if missing and builds the add-on (core included) if needed.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
if ! command -v blender >/dev/null \
   || ! blender -b --factory-startup --python-expr "import numpy" >/dev/null 2>&1; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq blender python3-numpy
fi
VENDOR="$ROOT/build/addon/legacy/material_deform/_vendor"
[[ -d "$VENDOR/matdeform" ]] || scripts/build_addon.sh
MD_SYS_PATH="$VENDOR" blender -b --factory-startup --python-exit-code 1 \
  --python scripts/demo_blender.py
