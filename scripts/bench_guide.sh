#!/usr/bin/env bash
# Reproduces the coarse-to-fine (`--guide`) figures of BENCHMARKS.md: bakes bunny, cow, spot
# (real-mesh fixtures) and the demo at 162 cameras × 256 px, then evaluates 6 random 512² views
# per scene with the fixed baseline (1/64), the default method unguided (--guide 0) and with
# guides 2, 4 (its default) and 8, against the rasterized mesh. Each configuration runs
# RUNS times (default 4, one process each), the configurations taking turns within each run
# so that all of them see the same phases of a busy host; ms/frame is the mean over views of
# each view's fastest run (single runs vary by up to ±20 % here, and this host's speed drifts
# by up to 30 % over minutes).
#   bash scripts/bench_guide.sh [OUT_DIR]   (default out/guide; about 5 min on 2-core lavapipe)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/guide}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in ${SCENES:-bunny cow spot demo}; do
  scene_asset "$scene" --no-calibrate
  for run in $(seq 1 "${RUNS:-4}"); do
    for config in fixed unguided guide2 default guide8; do
      case $config in
        fixed) flags=(--method fixed) ;;
        unguided) flags=(--guide 0) ;;
        default) flags=() ;;
        guide*) flags=(--guide "${config#guide}") ;;
      esac
      $LG eval "$ASSET" "${REF[@]}" --views 6 --size 512 "${flags[@]}" --json > "$OUT/$scene-$config-$run.json"
    done
  done
done
python3 - "$OUT" "${RUNS:-4}" ${SCENES:-bunny cow spot demo} <<'PY' | tee "$OUT/tables.md"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
runs = int(sys.argv[2])


def load(scene, config):
    """The last run's report, its mean_ms replaced by the mean of per-view minima over runs."""
    reports = [json.loads((out / f"{scene}-{config}-{k}.json").read_text()) for k in range(1, runs + 1)]
    r = reports[-1]
    views = len(r["views"])
    r["mean_ms"] = sum(min(x["views"][v]["ms"] for x in reports) for v in range(views)) / views
    return r


print("| scene | setting | ms/frame 512² | × fixed time | fetches/pixel | masked PSNR | vs fixed | mismatched px |")
print("|---|---|---|---|---|---|---|---|")
for scene in sys.argv[3:]:
    fixed = load(scene, "fixed")
    for config in ["fixed", "unguided", "guide2", "default", "guide8"]:
        r = load(scene, config)
        name = {
            "fixed": "fixed 1/64 (baseline)",
            "unguided": "default 1/32, unguided",
            "default": "**default: 1/32, guide 4**",
        }.get(config, f"default 1/32, guide {config[5:]}")
        print(f"| {scene} | {name} | {r['mean_ms']:.0f} | {r['mean_ms'] / fixed['mean_ms']:.2f} | "
              f"{r['mean_fetches_per_pixel']:.1f} | {r['mean']['masked_psnr']:.2f} | "
              f"{r['mean']['masked_psnr'] - fixed['mean']['masked_psnr']:+.2f} dB | {r['mean']['mask_mismatch_px']:.0f} |")
PY
