#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Block compression" tables: the bunny baked as a spherical light
# field (162 cameras × 256 px) with every colour × depth codec and scored by `lumigraph eval` on
# 12 random 512² views (seed 0); and captured as a two-plane light field (8×8 cameras × 512²)
# with raw, BC1 and BC7 colour (and BC7 forced onto the device), scored by `lumigraph bench
# two-plane` (4 views, seed 0).
#   bash scripts/bench_compression.sh [OUT_DIR]   (default out/compression; about 20 min on 2 cores)
# Writes OUT_DIR/table.md and the JSON reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/compression}
mkdir -p "$OUT"
source scripts/bench_common.sh
MESH_FILE=${MESH[bunny]}
for pair in raw:r16 raw:r8 bc1:r16 bc7:r16 raw:bc4 bc1:bc4 bc7:bc4; do
  color=${pair%%:*}; depth=${pair##*:}
  asset="$OUT/bunny-$color-$depth.lfa"
  start=$(date +%s.%N)
  $LG bake "$MESH_FILE" -o "$asset" --cameras 162 --resolution 256 --color-codec "$color" \
    --depth-codec "$depth" > /dev/null
  end=$(date +%s.%N)
  echo "{\"bake_s\": $(python3 -c "print($end - $start)"), \"zstd_bytes\": $(zstd -3 -q -c "$asset" | wc -c)}" \
    > "$OUT/bunny-$color-$depth.bake.json"
  $LG eval "$asset" --mesh "$MESH_FILE" --views 12 --size 512 --seed 0 --json > "$OUT/bunny-$color-$depth.json"
done
for color in raw bc1 bc7; do
  $LG bench two-plane "$MESH_FILE" --grids 8x8 --st-res 512x512 --views 4 --size 512 --repeats 5 \
    --seed 0 --color-codec "$color" --json "$OUT/two-plane-$color.json" > /dev/null
done
# BC7 sampled by the device itself (on a CPU adapter lumigraph decodes it on the host instead).
LUMIGRAPH_BC_ON_DEVICE=all $LG bench two-plane "$MESH_FILE" --grids 8x8 --st-res 512x512 --views 4 \
  --size 512 --repeats 5 --seed 0 --color-codec bc7 --json "$OUT/two-plane-bc7-device.json" > /dev/null
python3 - "$OUT" <<'PY'
import json, os, sys
out = sys.argv[1]
rows = ["| colour | depth | size MiB | zstd MiB | bake s | masked PSNR | PSNR | interior PSNR | SSIM | coverage mismatch px | wrong-surface px | depth error median | ms/frame 512² |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
for pair in ["raw:r16", "raw:r8", "bc1:r16", "bc7:r16", "raw:bc4", "bc1:bc4", "bc7:bc4"]:
    color, depth = pair.split(":")
    e = json.load(open(f"{out}/bunny-{color}-{depth}.json"))
    b = json.load(open(f"{out}/bunny-{color}-{depth}.bake.json"))
    m = e["mean"]
    size = os.path.getsize(f"{out}/bunny-{color}-{depth}.lfa")
    rows.append(f"| {color} | {depth} | {size / 2**20:.2f} | {b['zstd_bytes'] / 2**20:.2f} | {b['bake_s']:.1f} | "
                f"{m['masked_psnr']:.2f} | {m['psnr']:.2f} | {m['intersection_psnr']:.2f} | {m['ssim']:.4f} | "
                f"{m['mask_mismatch_px']:.0f} | {m['wrong_surface_px']:.0f} | {m['depth']['median']:.2e} | {e['mean_ms']:.1f} |")
tp = ["| colour | filter | asset MiB | GPU MiB | masked PSNR | SSIM | wrong-surface px | ms/frame 512² |",
      "|---|---|---|---|---|---|---|---|"]
for color, name in [("raw", "raw"), ("bc1", "bc1"), ("bc7", "bc7"), ("bc7-device", "bc7 sampled on the device")]:
    r = json.load(open(f"{out}/two-plane-{color}.json"))
    for row in r["rows"]:
        tp.append(f"| {name} | {row['filter']} | {row['asset_bytes'] / 2**20:.1f} | {row['gpu_bytes'] / 2**20:.1f} | "
                  f"{row['masked_psnr']:.2f} | {row['ssim']:.4f} | {row['wrong_surface_px']:.0f} | {row['ms']:.2f} |")
adapter = json.load(open(f"{out}/two-plane-raw.json"))["adapter"]
with open(f"{out}/table.md", "w") as f:
    f.write(f"Adapter: {adapter}\n\nSpherical (bunny, 162 cameras × 256 px):\n\n" + "\n".join(rows)
            + "\n\nTwo-plane (bunny, 8×8 cameras × 512²):\n\n" + "\n".join(tp) + "\n")
print(open(f"{out}/table.md").read())
PY
