#!/usr/bin/env bash
# Batch-bake throughput of lumigraph.distributed.bake_many (local engine and a one-node Ray
# cluster on loopback) against one process baking in a loop: BENCHMARKS.md, "Batch baking".
#   bash scripts/bench_distributed.sh [OUT_DIR] [--resolution PX] [--cameras N]
#   (default out/distributed-bench, 162 cameras x 512 px; about 3 min on 2-core lavapipe)
# Builds the Python extension (release) into ./.venv with the pinned test requirements (Ray
# among them), then runs scripts/bench_distributed.py.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
OUT=${1:-out/distributed-bench}
shift || true
VENV=$ROOT/.venv
make_venv "$VENV" 11
pip_install_once "$VENV" "$(sha256sum pylib/requirements-test.txt | cut -d' ' -f1)" \
  -r pylib/requirements-test.txt
bash scripts/fixtures.sh "${LUMIGRAPH_FIXTURES:-fixtures}" >/dev/null
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
(cd pylib && VIRTUAL_ENV=$VENV PATH="$VENV/bin:$PATH" maturin develop --release --locked -q)
"$VENV/bin/python" scripts/bench_distributed.py --out "$OUT" --resolution 512 "$@"
