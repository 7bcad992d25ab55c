#!/usr/bin/env bash
# Reproduces the automatic-bake figures of BENCHMARKS.md ("Automatic bake: modelling only what
# the scene requires"): per scene (bunny, cow, spot, demo), the default bake (162 cameras ×
# 256 px, 16-bit depth) measured on the automatic bake's held-out views, then
# `lumigraph bake --auto` for target PSNRs 24, 27 and 30 dB, for the default's measured quality
# (bytes saved at equal quality) and for the default's size (quality gained at equal bytes).
#   bash scripts/bench_auto.sh [OUT_DIR]   (default out/auto-bench; about 30 min on 2-core lavapipe)
# Writes OUT_DIR/SCENE/*.json and OUT_DIR/tables.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/auto-bench}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in ${SCENES:-bunny cow spot demo}; do
  dir="$OUT/$scene"
  mkdir -p "$dir"
  if [ "$scene" = demo ]; then src=(--demo); ref=(--demo); else src=("${MESH[$scene]}"); ref=(--mesh "${MESH[$scene]}"); fi
  # The default bake, measured on the same held-out views as the automatic bakes.
  /usr/bin/time -f %e -o "$dir/default.time" $LG bake "${src[@]}" -o "$dir/default.lfa" --no-calibrate > /dev/null
  python3 scripts/bench_auto_tables.py views "$dir/default.lfa" > "$dir/held_out_views.json"
  $LG eval "$dir/default.lfa" "${ref[@]}" --views "$dir/held_out_views.json" --json > "$dir/default-eval.json"
  default_psnr=$(python3 -c "import json,sys; print(round(json.load(open(sys.argv[1]))['mean']['masked_psnr'], 2))" "$dir/default-eval.json")
  default_bytes=$(stat -c %s "$dir/default.lfa")
  for run in equal-quality equal-bytes psnr-27 psnr-24 psnr-30; do
    case $run in
      psnr-*) flags=(--target-psnr "${run#psnr-}") ;;
      equal-quality) flags=(--target-psnr "$default_psnr") ;;
      equal-bytes) flags=(--max-bytes "$default_bytes") ;;
    esac
    echo "$scene $run: ${flags[*]}" >&2
    /usr/bin/time -f %e -o "$dir/$run.time" $LG bake "${src[@]}" -o "$dir/$run.lfa" --auto "${flags[@]}" --no-calibrate --json > "$dir/$run.json"
    # Cross-check: `eval` on the held-out views measures what the report says.
    $LG eval "$dir/$run.lfa" "${ref[@]}" --views "$dir/held_out_views.json" --json > "$dir/$run-eval.json"
  done
done
python3 scripts/bench_auto_tables.py tables "$OUT" > "$OUT/tables.md"
cat "$OUT/tables.md"
