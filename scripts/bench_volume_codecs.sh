#!/usr/bin/env bash
# Reproduces the block-compressed rows of seed 002's Table 1 in BENCHMARKS.md ("Volume light
# fields", compressed rows): the MNI152 T1 head through `mri-brain` with shading, as in
# scripts/bench_volume.sh, baked at 162 cameras × 512-px maps with every colour × depth storage
# that fits premultiplied colour (raw or bc7; bc1 keeps 1-bit alpha only) and scored by
# `lumigraph eval --volume` on the same 30 random 512² views (seed 0) against the direct CPU ray
# cast. The raw 16-bit row is baked again in the same run, and raw 8-bit depth is the control
# for bc4 (which compresses 8-bit codes). Then every asset is timed interleaved: `lumigraph
# render --views` of 12 views (eye at 2.5 radii, 40°), one asset after the other, three rounds,
# the first view of each process left out. Bakes and scores already in OUT_DIR are kept.
#   bash scripts/bench_volume_codecs.sh [OUT_DIR]   (default out/volume-codecs; about 45 min on
#   2-core lavapipe)
# Writes OUT_DIR/table.md and the per-run JSON beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/volume-codecs}
mkdir -p "$OUT"
source scripts/bench_common.sh
VOL="$FIX/volume/mni_t1.nii.gz"
VIEWS=${VIEWS:-30}
CONFIGS=${CONFIGS:-"raw:r16 raw:r8 bc7:r16 bc7:bc4 raw:bc4"}
for config in $CONFIGS; do
  color=${config%%:*}
  depth=${config##*:}
  asset="$OUT/mni-162-$color-$depth.lfa"
  if [ ! -s "$asset" ]; then
    $LG bake "$VOL" --tf mri-brain --shade --cameras 162 --resolution 512 \
      --color-codec "$color" --depth-codec "$depth" -o "$asset" | tee "$OUT/bake-$color-$depth.txt"
  fi
  [ -s "$asset.zst" ] || zstd -q -3 -T1 -f -o "$asset.zst" "$asset"
  $LG info "$asset" > "$asset.info.txt"
  json="$OUT/eval-$color-$depth.json"
  if [ ! -s "$json" ]; then
    $LG eval "$asset" --volume "$VOL" --views "$VIEWS" --size 512 --seed 0 --json > "$json.tmp"
    mv "$json.tmp" "$json"
  fi
done
first=${CONFIGS%% *}
timing_views "$OUT/mni-162-${first/:/-}.lfa.info.txt" "$OUT/views.json"
: > "$OUT/timing.txt"
for round in 1 2 3; do
  for config in $CONFIGS; do
    name=${config/:/-}
    $LG render "$OUT/mni-162-$name.lfa" --views "$OUT/views.json" -o "$OUT/frames-$name" \
      | sed -n 's/^view \([0-9]*\): \([0-9.]*\) ms.*/\1 \2/p' \
      | awk -v a="$config" -v r="$round" '$1 != "000" {print a, r, $2}' >> "$OUT/timing.txt"
  done
done
python3 - "$OUT" "$CONFIGS" <<'PY'
import json, os, re, statistics, sys
out, configs = sys.argv[1], sys.argv[2].split()
seed = {"raw:r16": ("uncompressed / uncompressed", 6.34, "166 MB", "ca. 18 MB", "35.00"),
        "bc7:r16": ("DXT1 / uncompressed", 6.47, "62 MB", "ca. 6 MB", "35.28"),
        "bc7:bc4": ("DXT1 / LATC1", 6.48, "41 MB", "ca. 5 MB", "35.46")}
times = {c: [] for c in configs}
for line in open(f"{out}/timing.txt"):
    c, _, ms = line.split()
    times[c].append(float(ms))
med = {c: statistics.median(v) for c, v in times.items()}
rows = ["| colour | depth | size MiB | zstd MiB | GPU MiB | seed 002 row (colour / depth) | seed size | seed zipped | MAE, seed | MAE | masked PSNR | PSNR over black | SSIM | wrong-surface px | interleaved ms/frame | fps | seed fps |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
for config in configs:
    color, depth = config.split(":")
    base = f"{out}/mni-162-{color}-{depth}.lfa"
    e = json.load(open(f"{out}/eval-{color}-{depth}.json"))
    size = os.path.getsize(base) / 2**20
    zsize = os.path.getsize(base + ".zst") / 2**20
    gpu = int(re.search(r"GPU memory when served: (\d+) bytes", open(base + ".info.txt").read()).group(1)) / 2**20
    m = e["mean"]
    row, seed_mae, seed_size, seed_zip, seed_fps = seed.get(config, ("", "", "", "", ""))
    rows.append(f"| {color} | {depth} | {size:.2f} | {zsize:.2f} | {gpu:.0f} | {row} | {seed_size} | {seed_zip} | "
                f"{seed_mae} | {m['mae']:.2f} | {m['masked_psnr']:.2f} | {m['psnr']:.2f} | {m['ssim']:.4f} | "
                f"{m['wrong_surface_px']:.0f} | {med[config]:.1f} | {1e3 / med[config]:.0f} | {seed_fps} |")
rows.append("")
rows.append("Interleaved frames per asset: " + ", ".join(f"{c} {len(v)}" for c, v in times.items()) + ".")
open(f"{out}/table.md", "w").write("\n".join(rows) + "\n")
print("\n".join(rows))
PY
