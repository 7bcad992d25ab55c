#!/usr/bin/env bash
# Python bindings: creates ./.venv (git-ignored), installs the pinned test requirements, builds
# the extension (pylib, release) into it, checks the type stubs (mypy.stubtest, mypy), runs
# python_tests/ (pytest, strict) and the examples. Idempotent: a second run reuses the venv, skips
# pip when the requirements did not change, and rebuilds only what cargo finds changed.
# Needs Python >= 3.11 as $PYTHON (Debian 12: python3 3.11 + python3-venv, installed here when
# missing). The real-mesh fixtures are fetched by python_tests/ on first use (scripts/fixtures.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
VENV=$ROOT/.venv
make_venv "$VENV" 11
PY=$VENV/bin/python
pip_install_once "$VENV" "$(sha256sum pylib/requirements-test.txt | cut -d' ' -f1)" \
  -r pylib/requirements-test.txt

# LUMIGRAPH_PROFILE=dev (what scripts/test.sh uses) reuses the dependencies `cargo test` just
# built (they are optimized at opt-level 2 even in dev); the GPU work runs in the driver anyway.
PROFILE_FLAG=--release
if [ "${LUMIGRAPH_PROFILE:-release}" = dev ]; then PROFILE_FLAG=""; fi
stage "maturin develop ${PROFILE_FLAG} (lumigraph._lumigraph)"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
(cd pylib && VIRTUAL_ENV=$VENV PATH="$VENV/bin:$PATH" maturin develop $PROFILE_FLAG --locked -q)

stage "mypy.stubtest + mypy"
(cd pylib/python && "$PY" -m mypy.stubtest lumigraph._lumigraph --mypy-config-file ../pyproject.toml)
"$PY" -m mypy --config-file pylib/pyproject.toml pylib/python/lumigraph pylib/examples

stage "pytest python_tests"
"$PY" -m pytest python_tests -q --durations=10 ${LUMIGRAPH_PYTEST_ARGS:-}

stage "examples"
EXAMPLES_OUT=$(mktemp -d)
trap 'rm -rf "$EXAMPLES_OUT"' EXIT
(cd "$EXAMPLES_OUT" && "$PY" "$ROOT/pylib/examples/quickstart.py")
"$PY" pylib/examples/batch_bake_report.py --out "$EXAMPLES_OUT/report"
"$PY" pylib/examples/exr_roundtrip.py --out "$EXAMPLES_OUT/exr"
"$PY" pylib/examples/quality_vs_speed.py --out "$EXAMPLES_OUT/plot.png"
stage "python tests passed"
