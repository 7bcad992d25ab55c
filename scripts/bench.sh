#!/usr/bin/env bash
# Reproduces the tables of BENCHMARKS.md (release build, real-mesh fixtures + the demo).
#   bash scripts/bench.sh [OUT_DIR]     (default: out/bench; about 5 min on 2-core lavapipe)
# Writes OUT_DIR/*.json (raw `lumigraph eval --json` reports) and OUT_DIR/tables.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/bench}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in bunny cow spot demo; do
  for cams in 42 162; do
    asset="$OUT/$scene-$cams.lfa"
    if [ "$scene" = demo ]; then src=(--demo); else src=("${MESH[$scene]}"); fi
    /usr/bin/time -f "%e s wall, %M KiB max RSS" -o "$OUT/$scene-$cams.bake-time" \
      $LG bake "${src[@]}" -o "$asset" --cameras "$cams" --resolution 256 --no-calibrate > "$OUT/$scene-$cams.bake.txt"
    if [ "$scene" = demo ]; then ref=(--demo); else ref=(--mesh "${MESH[$scene]}"); fi
    for method in default fixed; do
      $LG eval "$asset" "${ref[@]}" --method "$method" --json > "$OUT/$scene-$cams-$method.json"
    done
  done
done
# Speed at 512x512: cameras x step (bunny asset, 12 random views each).
for cams in 12 42 162; do
  for method in default fixed; do
    for step in 0.0625 0.03125 0.015625; do
      $LG eval "$OUT/bunny-162.lfa" --mesh "${MESH[bunny]}" --lod "$cams" --method "$method" --step "$step" \
        --size 512 --views 6 --json > "$OUT/speed-$cams-$method-$step.json"
    done
  done
done
# Cold start: process start to first frame written (asset load, device, pipeline compile, frame).
echo '{"eye":[0.3,0.4,0.6],"target":[-0.0168,0.11,-0.0015],"yfov_deg":40,"width":512,"height":512}' > "$OUT/view.json"
/usr/bin/time -f "%e" -o "$OUT/cold-start" $LG render "$OUT/bunny-162.lfa" --view "$OUT/view.json" -o "$OUT/cold.png" > /dev/null
python3 scripts/bench_tables.py "$OUT" > "$OUT/tables.md"
cat "$OUT/tables.md"
