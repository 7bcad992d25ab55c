#!/usr/bin/env bash
# Runs every test on a fresh machine: installs the software Vulkan driver, fetches the real-mesh
# fixtures (cached in ./fixtures), checks formatting and lints, then runs the Rust test suite
# (GPU tests on lavapipe where there is no GPU), then the Python bindings' suite.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
# The fixtures script pulls pinned packages with apt-get download and pip download.
if [ -z "${LUMIGRAPH_FETCH_FIXTURES:-}" ]; then
  for candidate in ../shared/data/fetch-dev-fixtures.sh /work/shared/data/fetch-dev-fixtures.sh; do
    if [ -f "$candidate" ]; then export LUMIGRAPH_FETCH_FIXTURES="$(realpath "$candidate")"; break; fi
  done
fi
if [ ! -f "${LUMIGRAPH_FIXTURES:-fixtures}/.fetch-complete" ] && [ "$(id -u)" = 0 ]; then
  apt-get update -qq || true
fi
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -q -- -D warnings
echo "== cargo test"
cargo test --workspace --locked -- --test-threads=2
# The Python and service suites reuse this debug build instead of a second, release one.
export LUMIGRAPH_PROFILE=dev
echo "== Python bindings (maturin build, stubtest, pytest, examples)"
bash scripts/test_python.sh
echo "== service end to end (HTTP, WebSocket, headless Chromium)"
bash scripts/test_service_e2e.sh
echo "== all tests passed"
