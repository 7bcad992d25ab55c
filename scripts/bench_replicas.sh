#!/usr/bin/env bash
# Stream throughput of three replicas behind HAProxy against one replica: BENCHMARKS.md,
# "Replicas behind the router".
#   bash scripts/bench_replicas.sh [OUT_FILE]   (default out/bench_replicas.md; about 2 min)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/bench_replicas.md}
command -v haproxy >/dev/null || [ -x /usr/sbin/haproxy ] || apt_install haproxy
cargo build --release --locked -q -p lumigraph_server
make_venv .venv-bench 10
pip_install_once .venv-bench "httpx websockets pillow" httpx websockets pillow
.venv-bench/bin/python scripts/bench_replicas.py --out "$OUT"
