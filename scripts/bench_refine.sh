#!/usr/bin/env bash
# Reproduces the still-refinement figures of BENCHMARKS.md: bakes bunny, cow, spot (real-mesh
# fixtures) and the demo at 162 cameras × 256 px (and again × 512 px), then renders VIEWS (default 6) random 512²
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
  # The same scene from maps at the view's resolution: what bounds the marcher's depth at limbs.
  if [ "$scene" = demo ]; then src=(--demo); else src=("${MESH[$scene]}"); fi
  [ -f "$OUT/$scene-512.lfa" ] || $LG bake "${src[@]}" -o "$OUT/$scene-512.lfa" \
    --cameras 162 --resolution 512 --no-calibrate > /dev/null
  target/release/examples/refine_eval "$OUT/$scene-512.lfa" "${REF[@]}" --views "${VIEWS:-6}" \
    --size 512 --samples 16 > "$OUT/$scene-512.json"
done
python3 - "$OUT" ${SCENES:-bunny cow spot demo} <<'PY' | tee "$OUT/tables.md"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
print("| scene | frame | samples (frames) | wrong-surface px/view (centre) | off every surface in the pixel | SSIM vs supersampled | PSNR vs supersampled | ms/still |")
print("|---|---|---|---|---|---|---|---|")
for name in [n for scene in sys.argv[2:] for n in (scene, f"{scene}-512")]:
    r = json.loads((out / f"{name}.json").read_text())
    scene = name.replace("-512", ", 512-px maps")
    plain = r["single_vs_reference"]["mean"]
    print(f"| {scene} | single, vs plain reference | 1 | {plain['wrong_surface_px']:.1f} | | {plain['ssim']:.4f} | "
          f"{plain['psnr']:.2f} | |")
    for label, s in [("single", r["single"])] + [("refined", s) for s in r["refined"]]:
        m = s["mean"]
        print(f"| {scene} | {label} | {s['samples']} | {m['wrong_surface_px']:.1f} | "
              f"{s['mean_wrong_surface_footprint_px']:.1f} | {m['ssim']:.4f} | "
              f"{m['psnr']:.2f} | {s['total_ms']:.0f} |")
PY
