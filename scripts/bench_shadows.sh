#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Shadows" table: every scene (the demo and the real-mesh fixtures)
# baked at 162 cameras × 256 px without calibration, with and without `--shadows` (DESIGN §9:
# a shadow ray per texel through the mesh's BVH), twice each (bake time: the faster run), and
# each asset scored by `lumigraph eval` on 12 random 256² views (seed 0) against the reference
# shaded as it was baked (with shadows where the bake had them).
#   bash scripts/bench_shadows.sh [OUT_DIR]   (default out/shadows; about 3 min)
# Writes OUT_DIR/table.md and the eval JSON beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/shadows}
mkdir -p "$OUT"
source scripts/bench_common.sh
: > "$OUT/runs.txt"
for scene in demo bunny cow spot; do
  if [ "$scene" = demo ]; then src=(--demo); ref=(--demo); else src=("${MESH[$scene]}"); ref=(--mesh "${MESH[$scene]}"); fi
  for shadows in off on; do
    flags=()
    [ "$shadows" = on ] && flags=(--shadows)
    asset="$OUT/$scene-$shadows.lfa"
    for run in 1 2; do
      $LG bake "${src[@]}" --cameras 162 --resolution 256 --no-calibrate "${flags[@]}" -o "$asset" \
        | sed -n "s/.* from \([0-9]*\) triangles in \([0-9]*\) ms.*/$scene $shadows \1 \2/p" >> "$OUT/runs.txt"
    done
    $LG eval "$asset" "${ref[@]}" --views 12 --size 256 --seed 0 --json > "$OUT/eval-$scene-$shadows.json"
  done
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
bake = {}
for line in open(f"{out}/runs.txt"):
    scene, shadows, tris, ms = line.split()
    key = (scene, shadows)
    bake[key] = (int(tris), min(bake.get(key, (0, 1e18))[1], float(ms)))
rows = ["| scene | triangles | shadows | bake s | × without | masked PSNR | PSNR | SSIM | MAE | reference ms |",
        "|---|---|---|---|---|---|---|---|---|---|"]
for scene in ("demo", "bunny", "cow", "spot"):
    for shadows in ("off", "on"):
        tris, ms = bake[(scene, shadows)]
        e = json.load(open(f"{out}/eval-{scene}-{shadows}.json"))
        m = e["mean"]
        ratio = ms / bake[(scene, "off")][1]
        rows.append(f"| {scene} | {tris} | {shadows} | {ms / 1e3:.2f} | {ratio:.2f} | {m['masked_psnr']:.2f} | "
                    f"{m['psnr']:.2f} | {m['ssim']:.4f} | {m['mae']:.3f} | {e['mean_reference_ms']:.1f} |")
open(f"{out}/table.md", "w").write("\n".join(rows) + "\n")
print("\n".join(rows))
PY
