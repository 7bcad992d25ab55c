#!/usr/bin/env bash
# End-to-end tests of the render service (python_tests/service/): creates ./.venv-e2e with
# pytest, pytest-timeout, httpx, websockets, pillow and playwright, installs Debian's `chromium`
# when missing (playwright drives it through executable_path; no browser download), builds the
# release `lumigraph` binary and runs pytest (strict: python_tests/service/pytest.ini). The test
# fixtures start and stop their own servers on free loopback ports in temporary folders.
# Idempotent: a second run reuses the venv and rebuilds only what cargo finds changed.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
PYTHON=${PYTHON:-python3}
if ! "$PYTHON" -c 'import sys; assert sys.version_info >= (3, 10)' 2>/dev/null; then
  echo "test_service_e2e: need Python >= 3.10 as \$PYTHON" >&2
  exit 1
fi
apt_install() {
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null
}
if ! "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null; then
  echo "== apt-get install python3-venv"
  apt_install python3-venv
fi
CHROMIUM=${LUMIGRAPH_CHROMIUM:-/usr/bin/chromium}
if [ ! -x "$CHROMIUM" ]; then
  echo "== apt-get install chromium"
  apt_install chromium
fi

VENV=$ROOT/.venv-e2e
PACKAGES="pytest pytest-timeout httpx websockets playwright pillow"
if [ ! -x "$VENV/bin/python" ]; then
  echo "== creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
if [ "$(cat "$VENV/.packages" 2>/dev/null || true)" != "$PACKAGES" ]; then
  echo "== pip install $PACKAGES"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check $PACKAGES
  echo "$PACKAGES" >"$VENV/.packages"
fi

# LUMIGRAPH_PROFILE=dev (scripts/test.sh) reuses the binary `cargo test` just built.
if [ "${LUMIGRAPH_PROFILE:-release}" = dev ]; then PROFILE_DIR=debug; PROFILE_FLAG=""; else PROFILE_DIR=release; PROFILE_FLAG=--release; fi
echo "== cargo build ${PROFILE_FLAG} -p lumigraph_server"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
if [ "$PROFILE_DIR" = debug ]; then
  # The binary exactly as `cargo test --workspace` builds it (same feature unification, so
  # nothing is rebuilt after the Rust tests).
  cargo test --workspace --locked -q --no-run
else
  cargo build $PROFILE_FLAG --locked -q -p lumigraph_server
fi
export LUMIGRAPH_BIN=$CARGO_TARGET_DIR/$PROFILE_DIR/lumigraph

# wgpu/Mesa want a private runtime dir.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  chmod 700 "$XDG_RUNTIME_DIR"
  export XDG_RUNTIME_DIR
  trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
fi
export LUMIGRAPH_CHROMIUM=$CHROMIUM

echo "== pytest python_tests/service"
"$VENV/bin/python" -m pytest -c python_tests/service/pytest.ini python_tests/service \
  -p no:cacheprovider -q ${LUMIGRAPH_PYTEST_ARGS:-}
echo "== service e2e tests passed"
