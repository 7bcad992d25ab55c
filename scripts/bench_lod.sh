#!/usr/bin/env bash
# Reproduces the automatic-LOD figures of BENCHMARKS.md: bakes bunny, cow, spot (real-mesh
# fixtures) and the demo at 162 cameras × 256 px with their calibration, then for each scene
# evaluates 8 views whose bounding sphere projects to 60…800 px in a 512² frame, once with
# `--auto-lod` (1 px bound, default cross-fade) and once with the default settings, against the
# rasterized mesh. Prints per size the level chosen, predicted vs measured silhouette error, and
# time and masked PSNR of both.
#   bash scripts/bench_lod.sh [OUT_DIR]   (default out/lod; about 6 min on 2-core lavapipe)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/lod}
mkdir -p "$OUT"
source scripts/bench_common.sh
SIZES=${LOD_SIZES:-60,120,200,300,400,500,600,800}
for scene in ${SCENES:-bunny cow spot demo}; do
  scene_asset "$scene"
  python3 scripts/lod_views.py "$LG" "$ASSET" 512 "$SIZES" > "$OUT/$scene.views.json"
  # Warm-up pass (shader compilation, first allocations), then the two measured passes.
  $LG eval "$ASSET" "${REF[@]}" --views "$OUT/$scene.views.json" --json > /dev/null
  $LG eval "$ASSET" "${REF[@]}" --views "$OUT/$scene.views.json" --auto-lod ${LOD_FLAGS:-} --json > "$OUT/$scene.auto.json"
  $LG eval "$ASSET" "${REF[@]}" --views "$OUT/$scene.views.json" --json > "$OUT/$scene.default.json"
done
python3 scripts/lod_tables.py "$OUT" ${SCENES:-bunny cow spot demo} | tee "$OUT/tables.md"
