#!/usr/bin/env bash
# Python bindings: creates ./.venv (git-ignored), installs the pinned test requirements, builds
# the extension (pylib, release) into it, checks the type stubs (mypy.stubtest, mypy), runs
# python_tests/ (pytest, strict) and the examples. Idempotent: a second run reuses the venv, skips
# pip when the requirements did not change, and rebuilds only what cargo finds changed.
# Needs Python >= 3.11 (Debian 12: python3 3.11 + python3-venv, installed here when missing).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
# The real-mesh fixtures (fetched by python_tests/ on first use, like the Rust tests do).
if [ -z "${LUMIGRAPH_FETCH_FIXTURES:-}" ]; then
  for candidate in ../shared/data/fetch-dev-fixtures.sh /work/shared/data/fetch-dev-fixtures.sh; do
    if [ -f "$candidate" ]; then export LUMIGRAPH_FETCH_FIXTURES="$(realpath "$candidate")"; break; fi
  done
fi
if [ ! -f "${LUMIGRAPH_FIXTURES:-fixtures}/mesh/bunny00.off" ] && [ "$(id -u)" = 0 ]; then
  apt-get update -qq || true
fi
PYTHON=${PYTHON:-python3}
if ! "$PYTHON" -c 'import sys; assert sys.version_info >= (3, 11)' 2>/dev/null; then
  echo "test_python: need Python >= 3.11 as \$PYTHON (found: $("$PYTHON" --version 2>&1 || true))" >&2
  exit 1
fi
if ! "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null; then
  echo "test_python: installing python3-venv" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
fi

VENV=$ROOT/.venv
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c 'import sys; assert sys.version_info >= (3, 11)' 2>/dev/null; then
  echo "== creating $VENV"
  rm -rf "$VENV"
  "$PYTHON" -m venv "$VENV"
fi
PY=$VENV/bin/python
STAMP=$VENV/.requirements.sha256
WANT=$(sha256sum pylib/requirements-test.txt | cut -d' ' -f1)
if [ "$(cat "$STAMP" 2>/dev/null || true)" != "$WANT" ]; then
  echo "== pip install -r pylib/requirements-test.txt"
  "$PY" -m pip install -q --disable-pip-version-check -r pylib/requirements-test.txt
  echo "$WANT" >"$STAMP"
fi

# LUMIGRAPH_PROFILE=dev (what scripts/test.sh uses) reuses the dependencies `cargo test` just
# built (they are optimized at opt-level 2 even in dev); the GPU work runs in the driver anyway.
PROFILE_FLAG=--release
if [ "${LUMIGRAPH_PROFILE:-release}" = dev ]; then PROFILE_FLAG=""; fi
echo "== maturin develop ${PROFILE_FLAG} (lumigraph._lumigraph)"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
(cd pylib && VIRTUAL_ENV=$VENV PATH="$VENV/bin:$PATH" maturin develop $PROFILE_FLAG --locked -q)

echo "== mypy.stubtest + mypy"
(cd pylib/python && "$PY" -m mypy.stubtest lumigraph._lumigraph --mypy-config-file ../pyproject.toml)
"$PY" -m mypy --config-file pylib/pyproject.toml pylib/python/lumigraph pylib/examples

echo "== pytest python_tests"
"$PY" -m pytest python_tests -q ${LUMIGRAPH_PYTEST_ARGS:-}

echo "== examples"
EXAMPLES_OUT=$(mktemp -d)
trap 'rm -rf "$EXAMPLES_OUT"' EXIT
(cd "$EXAMPLES_OUT" && "$PY" "$ROOT/pylib/examples/quickstart.py")
"$PY" pylib/examples/batch_bake_report.py --out "$EXAMPLES_OUT/report"
"$PY" pylib/examples/exr_roundtrip.py --out "$EXAMPLES_OUT/exr"
"$PY" pylib/examples/quality_vs_speed.py --out "$EXAMPLES_OUT/plot.png"
echo "== python tests passed"
