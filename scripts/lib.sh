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

# Slow downloads and builds that outlive a clone (fresh_check, CI) live here, keyed by version.
MD_CACHE="${MD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/matdeform}"

# python_headers VERSION : prints the include directories (';'-separated, for CMake) of CPython
# VERSION's headers, from Debian's libpythonX.Y-dev of the release that ships that Python
# (no interpreter needed: the add-on's core for another Blender's Python is built from these).
# Downloaded once into $MD_CACHE with a private apt state, so the host's apt is not touched.
python_headers() {
  local ver=$1 suite
  case "$ver" in
    3.11) suite=bookworm ;;
    3.13) suite=trixie ;;
    *) echo "no Debian release ships CPython $ver headers" >&2; return 2 ;;
  esac
  local arch dir="$MD_CACHE/python-headers/$ver"
  arch="$(gcc -print-multiarch)"
  if [[ ! -f "$dir/usr/include/$arch/python$ver/pyconfig.h" ]]; then
    local apt="$MD_CACHE/apt-$suite" mirror="${MD_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
    mkdir -p "$apt/lists/partial" "$apt/cache/archives/partial" "$apt/deb"
    echo "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] $mirror $suite main" \
      >"$apt/sources.list"
    : >"$apt/status"
    local opts=(-o "Dir::Etc::SourceList=$apt/sources.list" -o Dir::Etc::SourceParts=/nonexistent
      -o "Dir::State::Lists=$apt/lists" -o "Dir::Cache=$apt/cache" -o "Dir::State::status=$apt/status"
      -o Debug::NoLocking=1)
    [[ "$(id -u)" -eq 0 ]] && opts+=(-o APT::Sandbox::User=root)
    echo "[headers] libpython$ver-dev from Debian $suite" >&2
    apt-get "${opts[@]}" -qq update >&2 \
      && (cd "$apt/deb" && rm -f ./*.deb && apt-get "${opts[@]}" -qq download "libpython$ver-dev") >&2 \
      || { echo "cannot download libpython$ver-dev from Debian $suite" >&2; return 2; }
    rm -rf "$dir" && mkdir -p "$dir"
    dpkg-deb -x "$apt"/deb/libpython"$ver"-dev_*.deb "$dir" || return 2
    [[ -f "$dir/usr/include/$arch/python$ver/pyconfig.h" ]] \
      || { echo "libpython$ver-dev has no pyconfig.h for $arch" >&2; return 2; }
  fi
  echo "$dir/usr/include/python$ver;$dir/usr/include"
}
