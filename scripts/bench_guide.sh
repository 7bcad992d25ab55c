#!/usr/bin/env bash
# Reproduces the coarse-to-fine (`--guide`) figures of BENCHMARKS.md: bakes bunny, cow, spot
# (real-mesh fixtures) and the demo at 162 cameras × 256 px, then evaluates 6 random 512² views
# per scene with the fixed baseline (1/64), the default method unguided and with guides 2, 4
# and 8, against the rasterized mesh. Each configuration runs twice; the second run is kept
# (the first pays one-off costs).
#   bash scripts/bench_guide.sh [OUT_DIR]   (default out/guide; about 5 min on 2-core lavapipe)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/guide}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in ${SCENES:-bunny cow spot demo}; do
  scene_asset "$scene" --no-calibrate
  for config in fixed default guide2 guide4 guide8; do
    case $config in
      fixed) flags=(--method fixed) ;;
      default) flags=() ;;
      guide*) flags=(--guide "${config#guide}") ;;
    esac
    for run in 1 2; do
      $LG eval "$ASSET" "${REF[@]}" --views 6 --size 512 "${flags[@]}" --json > "$OUT/$scene-$config.json"
    done
  done
done
python3 - "$OUT" ${SCENES:-bunny cow spot demo} <<'PY' | tee "$OUT/tables.md"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
print("| scene | setting | ms/frame 512² | × fixed time | fetches/pixel | masked PSNR | vs fixed | mismatched px |")
print("|---|---|---|---|---|---|---|---|")
for scene in sys.argv[2:]:
    fixed = json.loads((out / f"{scene}-fixed.json").read_text())
    for config in ["fixed", "default", "guide2", "guide4", "guide8"]:
        r = json.loads((out / f"{scene}-{config}.json").read_text())
        name = {"fixed": "fixed 1/64 (baseline)", "default": "default 1/32"}.get(config, f"default 1/32, guide {config[5:]}")
        print(f"| {scene} | {name} | {r['mean_ms']:.0f} | {r['mean_ms'] / fixed['mean_ms']:.2f} | "
              f"{r['mean_fetches_per_pixel']:.1f} | {r['mean']['masked_psnr']:.2f} | "
              f"{r['mean']['masked_psnr'] - fixed['mean']['masked_psnr']:+.2f} dB | {r['mean']['mask_mismatch_px']:.0f} |")
PY
