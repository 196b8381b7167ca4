#!/usr/bin/env bash
# Installs what the build needs when it is missing (Debian packages, a project venv with the
# Python tools) and builds/installs the matdeform package into .venv. Idempotent and quiet when
# everything is already there. Source of truth for dependencies; demo.sh and test.sh call it.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

# OpenBLAS (serial: no thread pool fighting the host's) speeds up the supernodal factorisations;
# it is also the BLAS that scripts/build_addon.sh bundles into the add-on.
# clang: the test command builds the core with it too. meshoptimizer: the pose-space coarse mesh.
APT_PACKAGES=(build-essential libeigen3-dev libsuitesparse-dev libopenblas0-serial libgtest-dev clang-format
  clang libmeshoptimizer-dev)
missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "[setup] apt-get install ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
VPY=.venv/bin/python
# openjd-cli: the farm tests check and run farm/material_deform_bake.yaml (docs/farm.md); pinned,
# as the template uses the TASK_CHUNKING extension, which this version runs
OPENJD=openjd-cli==0.8.0
if ! $VPY -c "import numpy, scipy, pytest, ruff, scikit_build_core, pybind11, ninja, cmake, matplotlib, openjd.cli" 2>/dev/null \
  || [[ "$($VPY -m openjd --version 2>/dev/null)" != *" ${OPENJD#*==}" ]]; then
  echo "[setup] pip install build and test tools into .venv"
  $VPY -m pip install -q --upgrade pip
  $VPY -m pip install -q numpy scipy pytest ruff "scikit-build-core>=0.10" "pybind11>=2.12" ninja cmake matplotlib "$OPENJD"
fi

# Rebuild the extension when any native or package source is newer than the installed one.
stamp=.venv/.matdeform-installed
if [ ! -f "$stamp" ] || [ -n "$(find native src CMakeLists.txt pyproject.toml cmake -newer "$stamp" -type f 2>/dev/null | head -1)" ]; then
  echo "[setup] building and installing matdeform into .venv"
  $VPY -m pip install -q --no-build-isolation --no-deps . 2>&1 | grep -v "^WARNING: Location" || true
  $VPY -c "import matdeform" && touch "$stamp"
fi
