#!/usr/bin/env bash
# Soak test of `lumigraph serve` (scripts/soak.py: good and abusive clients, uploads, bakes; fails
# when the server's RSS is not flat, on any 5xx or crash, or when good clients get no frames).
# Uses the e2e venv (scripts/test_service_e2e.sh makes it) and the release binary, building it
# when cargo finds it out of date. Arguments go to soak.py, e.g. `bash scripts/soak.sh --seconds
# 300 --out /tmp/soak`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
if [ ! -x .venv-e2e/bin/python ]; then
  echo "no .venv-e2e: run bash scripts/test_service_e2e.sh once first" >&2
  exit 2
fi
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}
if [ -z "${LUMIGRAPH_BIN:-}" ]; then
  cargo build --release --locked -q -p lumigraph_server
fi
exec .venv-e2e/bin/python scripts/soak.py "$@"
