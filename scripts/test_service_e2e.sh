#!/usr/bin/env bash
# End-to-end tests of the render service (python_tests/service/): creates ./.venv-e2e with
# pytest, pytest-timeout, httpx, websockets, pillow, playwright, schemathesis (the schema fuzzing
# test), matplotlib (the soak plot), moto[server] and boto3 (the S3-protocol server of the asset
# store tests), installs Debian's `chromium` when missing (playwright drives it through
# executable_path; no browser download) and `haproxy` (the replica tests), builds the release
# `lumigraph` binary
# and runs pytest (strict: python_tests/service/pytest.ini). The test fixtures start and stop
# their own servers on free loopback ports in temporary folders. Then scripts/soak.py runs for
# LUMIGRAPH_SOAK_SECONDS (default 60; 0 skips it), its report and plot in $CARGO_TARGET_DIR/soak.
# Idempotent: a second run reuses the venv and rebuilds only what cargo finds changed.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
CHROMIUM=${LUMIGRAPH_CHROMIUM:-/usr/bin/chromium}
if [ ! -x "$CHROMIUM" ]; then
  apt_install chromium
fi
# HAProxy: the router of test_replicas.py (docker/k8s/router.yaml's balancing).
if ! command -v haproxy >/dev/null && [ ! -x /usr/sbin/haproxy ]; then
  apt_install haproxy
fi
VENV=$ROOT/.venv-e2e
make_venv "$VENV" 10
PACKAGES="pytest pytest-timeout httpx websockets playwright pillow schemathesis==4.32.5 matplotlib moto[server]==5.2.5 boto3==1.44.8"
pip_install_once "$VENV" "$PACKAGES" $PACKAGES

# LUMIGRAPH_PROFILE=dev (scripts/test.sh) reuses the binary `cargo test` just built.
if [ "${LUMIGRAPH_PROFILE:-release}" = dev ]; then PROFILE_DIR=debug; PROFILE_FLAG=""; else PROFILE_DIR=release; PROFILE_FLAG=--release; fi
stage "cargo build ${PROFILE_FLAG} -p lumigraph_server"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
if [ "$PROFILE_DIR" = debug ]; then
  # The binary exactly as `cargo test --workspace` builds it (same feature unification, so
  # nothing is rebuilt after the Rust tests).
  cargo test --workspace --locked -q --no-run
else
  cargo build $PROFILE_FLAG --locked -q -p lumigraph_server
fi
export LUMIGRAPH_BIN=$CARGO_TARGET_DIR/$PROFILE_DIR/lumigraph

export LUMIGRAPH_CHROMIUM=$CHROMIUM

stage "pytest python_tests/service"
"$VENV/bin/python" -m pytest -c python_tests/service/pytest.ini python_tests/service \
  -p no:cacheprovider -q --durations=10 ${LUMIGRAPH_PYTEST_ARGS:-}
SOAK_SECONDS=${LUMIGRAPH_SOAK_SECONDS:-60}
if [ "$SOAK_SECONDS" != 0 ]; then
  stage "soak ${SOAK_SECONDS} s (scripts/soak.py)"
  "$VENV/bin/python" scripts/soak.py --seconds "$SOAK_SECONDS" --out "$CARGO_TARGET_DIR/soak"
fi
stage "service e2e tests passed"
