#!/usr/bin/env bash
# The main job: builds what is needed, deforms procedural meshes (uniform vs material-aware)
# and writes OBJ files, PNG pictures and (with Blender) a .blend into out/.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
OUT="${1:-$ROOT/out}"
mkdir -p "$OUT"
.venv/bin/python scripts/demo.py --out "$OUT"
if [ -f scripts/demo_blender.sh ]; then
  bash scripts/demo_blender.sh "$OUT"
fi
echo "demo output in $OUT:"
ls -1 "$OUT"
