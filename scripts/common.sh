# Helpers sourced by the other scripts: functions, and the start time that `stage` counts from.

# `stage TEXT` heads a stage with the seconds since the outermost script started, so a slow CI run
# shows where its time went.
: "${LUMIGRAPH_T0:=$(date +%s)}"
export LUMIGRAPH_T0
stage() { echo "== [$(($(date +%s) - LUMIGRAPH_T0)) s] $*"; }

# Runs a command as root: directly when we are root, else through sudo.
as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi
}

# apt_install PACKAGE...: installs Debian/Ubuntu packages quietly (after refreshing the lists).
apt_install() {
  echo "== apt-get install $*" >&2
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq "$@" >/dev/null
}

# require_python MIN_MINOR: checks that $PYTHON (default python3) is 3.MIN_MINOR or newer and can
# make virtual environments (installs python3-venv when it cannot); sets PYTHON.
require_python() {
  PYTHON=${PYTHON:-python3}
  if ! "$PYTHON" -c "import sys; assert sys.version_info >= (3, $1)" 2>/dev/null; then
    echo "need Python >= 3.$1 as \$PYTHON (found: $("$PYTHON" --version 2>&1 || true))" >&2
    return 1
  fi
  if ! "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null; then
    apt_install python3-venv
  fi
}

# make_venv DIR MIN_MINOR: creates the virtual environment DIR with $PYTHON unless a usable one
# (Python >= 3.MIN_MINOR) is there.
make_venv() {
  require_python "$2"
  if [ ! -x "$1/bin/python" ] || ! "$1/bin/python" -c "import sys; assert sys.version_info >= (3, $2)" 2>/dev/null; then
    echo "== creating $1" >&2
    rm -rf "$1"
    "$PYTHON" -m venv "$1"
  fi
}

# pip_install_once VENV STAMP_TEXT PIP_ARGS...: runs the venv's pip install PIP_ARGS unless the
# last successful install recorded the same STAMP_TEXT (e.g. a requirements file's hash).
pip_install_once() {
  local venv=$1 stamp=$2
  shift 2
  if [ "$(cat "$venv/.installed" 2>/dev/null || true)" != "$stamp" ]; then
    echo "== pip install $*" >&2
    "$venv/bin/python" -m pip install -q --disable-pip-version-check "$@"
    echo "$stamp" >"$venv/.installed"
  fi
}
