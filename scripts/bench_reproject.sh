#!/usr/bin/env bash
# Reproduces the reprojection figures of BENCHMARKS.md: bakes the demo and spot (162 cameras ×
# 256 px) and runs scripts/bench_reproject.py on them in headless Chromium (software GL) through
# a loopback proxy delaying each direction by 50, 100 and 200 ms: motion-to-photon delay with and
# without reprojection, and the warp's error against the true frame for 1°, 5°, 15° rotations.
#   bash scripts/bench_reproject.sh [OUT_DIR]   (default out/reproject; about 10 min on 2 cores)
# Needs ./.venv-e2e (scripts/test_service_e2e.sh creates it). Writes OUT_DIR/table.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/reproject}
mkdir -p "$OUT"
source scripts/bench_common.sh
assets=()
for scene in ${SCENES:-demo spot}; do
  scene_asset "$scene"
  assets+=(--asset "$ASSET")
done
LUMIGRAPH_BIN=$PWD/$LG .venv-e2e/bin/python scripts/bench_reproject.py "${assets[@]}" \
  --out "$OUT/table.md" ${REPROJECT_FLAGS:-}
