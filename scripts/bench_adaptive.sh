#!/usr/bin/env bash
# Adaptive streaming over throttled loopback links (scripts/bench_adaptive.py): builds the release
# binary and runs the benchmark with a Python that has httpx and websockets (./.venv-e2e when
# present, else $PYTHON or python3). Arguments go to the script; the report is out/bench_adaptive.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked -q -p lumigraph_server
PY=${PYTHON:-python3}
[ -x .venv-e2e/bin/python ] && PY=.venv-e2e/bin/python
exec "$PY" scripts/bench_adaptive.py "$@"
