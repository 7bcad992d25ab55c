#!/usr/bin/env bash
# Reproduces the trade-off figures of BENCHMARKS.md: bakes bunny, cow, spot (real-mesh
# fixtures) and the demo at 162 cameras × 256 px, runs `lumigraph bench tradeoff` on each
# (default grid: cameras × step × tolerance × method × depth bits × size, 4 views per setting),
# and formats the tables.
#   bash scripts/bench_tradeoff.sh [OUT_DIR]   (default out/tradeoff; about 7 min on 2-core lavapipe)
# Writes OUT_DIR/SCENE/{tradeoff.csv,tradeoff.json,pareto.png} and OUT_DIR/tables.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/tradeoff}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in ${SCENES:-bunny cow spot demo}; do
  scene_asset "$scene" --no-calibrate
  $LG bench tradeoff "$ASSET" "${REF[@]}" --out "$OUT/$scene" ${TRADEOFF_FLAGS:-} | tee "$OUT/$scene.txt"
done
python3 scripts/tradeoff_tables.py "$OUT" > "$OUT/tables.md"
cat "$OUT/tables.md"
