#!/usr/bin/env bash
# Reproduces the still-refinement figures of BENCHMARKS.md: bakes bunny, cow, spot (real-mesh
# fixtures) and the demo at 162 cameras × 256 px, then renders VIEWS (default 6) random 512²
# views per scene single-sample and refined with SAMPLES (default 8,16) jittered samples, and
# measures them against the 5×5 supersampled reference (single-sample frames also against the
# plain one): wrong-surface pixels per view (z off by more than 1 % of the true z), SSIM and
# PSNR, and the cost (ms per still, frames = samples). Quality numbers are deterministic; the
# milliseconds are one run each and only as good as the host is quiet.
#   bash scripts/bench_refine.sh [OUT_DIR]   (default out/refine)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/refine}
mkdir -p "$OUT"
source scripts/bench_common.sh
cargo build --release --locked -q -p lumigraph_core --example refine_eval
for scene in ${SCENES:-bunny cow spot demo}; do
  scene_asset "$scene" --no-calibrate
  target/release/examples/refine_eval "$ASSET" "${REF[@]}" --views "${VIEWS:-6}" --size 512 \
    --samples "${SAMPLES:-8,16}" > "$OUT/$scene.json"
done
python3 - "$OUT" ${SCENES:-bunny cow spot demo} <<'PY' | tee "$OUT/tables.md"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
print("| scene | frame | samples (frames) | wrong-surface px/view | SSIM vs supersampled | PSNR vs supersampled | ms/still |")
print("|---|---|---|---|---|---|---|")
for scene in sys.argv[2:]:
    r = json.loads((out / f"{scene}.json").read_text())
    plain = r["single_vs_reference"]["mean"]
    print(f"| {scene} | single, vs plain reference | 1 | {plain['wrong_surface_px']:.1f} | {plain['ssim']:.4f} | "
          f"{plain['psnr']:.2f} | |")
    for label, s in [("single", r["single"])] + [("refined", s) for s in r["refined"]]:
        m = s["mean"]
        print(f"| {scene} | {label} | {s['samples']} | {m['wrong_surface_px']:.1f} | {m['ssim']:.4f} | "
              f"{m['psnr']:.2f} | {s['total_ms']:.0f} |")
PY
