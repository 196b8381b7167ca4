# Shared helpers for the scripts (source it: `. scripts/lib.sh`). Each check really fails when the
# thing it checks is missing: Blender exits 0 after a --python-expr that raises unless it is told
# otherwise with --python-exit-code, so every Blender check passes that flag.

# blender_can_import MODULE... : true if Debian's `blender` runs and its Python imports them all.
blender_can_import() {
  command -v blender >/dev/null || return 1
  local mods
  mods=$(IFS=,; echo "$*")
  blender -b --factory-startup --python-exit-code 1 --python-expr "import ${mods}" \
    >/dev/null 2>&1
}

# apt_install PACKAGE... : installs Debian packages (as root, or with sudo).
apt_install() {
  local sudo=""
  [[ "$(id -u)" -ne 0 ]] && sudo="sudo"
  echo "[apt] installing $*"
  $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@" \
    >/dev/null || { echo "apt-get install $* failed" >&2; return 2; }
}

# ensure_debian_blender : Debian's Blender with numpy and pytest importable inside it.
ensure_debian_blender() {
  blender_can_import numpy pytest && return 0
  apt_install blender python3-numpy python3-pytest || return 2
  blender_can_import numpy pytest || {
    echo "Debian's blender still cannot import numpy and pytest" >&2
    return 2
  }
}

# ensure_bpy_venv DIR VERSION : a Python 3.11 venv with PyPI's bpy==VERSION, pytest and numpy
# (separate from the project's .venv: bpy pins its own numpy). PYTHON311 picks the interpreter.
ensure_bpy_venv() {
  local dir=$1 ver=$2 py="${PYTHON311:-python3}"
  if [[ ! -x "$dir/bin/python" ]]; then
    "$py" -c 'import sys; assert sys.version_info[:2] == (3, 11)' 2>/dev/null \
      || { echo "need a Python 3.11 for the bpy wheel (set PYTHON311)" >&2; return 2; }
    "$py" -m venv "$dir" || return 2
  fi
  "$dir/bin/python" -c "import bpy, pytest, numpy
assert bpy.app.version_string.startswith('${ver%.*}'), bpy.app.version_string" >/dev/null 2>&1 \
    && return 0
  echo "[bpy] pip install bpy==$ver pytest into $dir"
  "$dir/bin/pip" install -q "bpy==$ver" pytest || return 2
  "$dir/bin/python" -c "import bpy, pytest, numpy" >/dev/null 2>&1 \
    || { echo "$dir: bpy $ver does not import" >&2; return 2; }
}
