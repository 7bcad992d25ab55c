#!/usr/bin/env bash
# Runs every test on a fresh machine: installs the software Vulkan driver, fetches the real-mesh
# fixtures (into $LUMIGRAPH_FIXTURES, default ./fixtures), checks formatting, lints and API docs,
# then runs the Rust test suite (GPU tests on lavapipe where there is no GPU), the Python
# bindings' suite and the service's end-to-end suite, and validates the Kubernetes manifests.
# LUMIGRAPH_FUZZ=1 adds the fuzz smoke run, LUMIGRAPH_DOCKER=1 the container image build and its
# smoke test.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
stage "fixtures (scripts/fixtures.sh)"
bash scripts/fixtures.sh "${LUMIGRAPH_FIXTURES:-fixtures}"
stage "cargo fmt --check"
cargo fmt --all -- --check
stage "cargo clippy"
cargo clippy --workspace --all-targets --locked -q -- -D warnings
stage "cargo doc (no warnings: broken or private intra-doc links fail)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked -q
stage "cargo test"
cargo test --workspace --locked -- --test-threads=2
# The Python and service suites reuse this debug build instead of a second, release one.
export LUMIGRAPH_PROFILE=dev
# The fuzz smoke builds every target a second time with libFuzzer's instrumentation (minutes):
# asked for with LUMIGRAPH_FUZZ=1 (alone: `bash scripts/fuzz.sh --smoke`). The parsers' own tests
# and property tests run in `cargo test` above either way.
if [ "${LUMIGRAPH_FUZZ:-0}" = 1 ]; then
  stage "fuzz smoke (scripts/fuzz.sh --smoke: every target for a few seconds)"
  LUMIGRAPH_BIN=${CARGO_TARGET_DIR:-$PWD/target}/debug/lumigraph bash scripts/fuzz.sh --smoke
fi
stage "Python bindings (maturin build, stubtest, pytest, examples)"
bash scripts/test_python.sh
stage "service end to end (HTTP, WebSocket, headless Chromium)"
bash scripts/test_service_e2e.sh
stage "deployment manifests (docker/k8s/validate.sh)"
bash docker/k8s/validate.sh
# The container image build and its smoke run take minutes and a Debian mirror: asked for with
# LUMIGRAPH_DOCKER=1 (run them alone with `bash docker/build.sh && bash docker/smoke.sh`).
if [ "${LUMIGRAPH_DOCKER:-0}" = 1 ]; then
  stage "container image (docker/build.sh, docker/smoke.sh)"
  bash docker/build.sh
  bash docker/smoke.sh
fi
stage "all tests passed"
