#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Two-plane light fields" tables: every scene (the demo and the
# real-mesh fixtures) captured with planes fitted along +z (`bake --two-plane auto`) at uv grids
# 8×8 and 17×17 and st resolutions 256² and 512², then every uv filter scored against the
# reference rasterizer over the valid region from 4 random 512² views beyond the uv plane
# (seed 0), with the median render time of 5 repeats; and the 5×5 aperture and the full
# aperture (16 stratified draws accumulated).
#   bash scripts/bench_two_plane.sh [OUT_DIR]   (default out/two_plane; about 10 min on 2 cores)
# Writes OUT_DIR/table.md and the JSON reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/two_plane}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in demo bunny cow spot; do
  if [ "$scene" = demo ]; then src=(--demo); else src=("${MESH[$scene]}"); fi
  $LG bench two-plane "${src[@]}" --grids 8x8,17x17 --st-res 256x256,512x512 --views 4 --size 512 \
    --repeats 5 --seed 0 --json "$OUT/$scene.json"
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
quality = ["| scene | uv grid | st | nearest | bilinear | dither | depth-corrected | depth − bilinear |",
           "|---|---|---|---|---|---|---|---|"]
detail = ["| scene | uv grid | st | filter | masked PSNR | SSIM | wrong-surface px | ms / frame (512²) | JPEG q50 KiB | JPEG q90 KiB | WebP lossless KiB |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
aperture = ["| scene | uv grid | st | aperture R | cameras per pixel | ms / frame | accumulated frames | accumulated ms |",
            "|---|---|---|---|---|---|---|---|"]
for scene in ("demo", "bunny", "cow", "spot"):
    r = json.load(open(f"{out}/{scene}.json"))
    rows = {}
    for row in r["rows"]:
        key = (tuple(row["grid"]), tuple(row["st_resolution"]))
        rows.setdefault(key, {})[row["filter"]] = row
        g, s = row["grid"], row["st_resolution"]
        detail.append(f"| {scene} | {g[0]}×{g[1]} | {s[0]}² | {row['filter']} | {row['masked_psnr']:.2f} | "
                      f"{row['ssim']:.4f} | {row['wrong_surface_px']:.0f} | {row['ms']:.2f} | "
                      f"{row['jpeg50_bytes'] / 1024:.1f} | {row['jpeg90_bytes'] / 1024:.1f} | {row['webp_bytes'] / 1024:.1f} |")
    for (g, s), f in rows.items():
        d = f["depth"]["masked_psnr"] - f["bilinear"]["masked_psnr"]
        quality.append(f"| {scene} | {g[0]}×{g[1]} | {s[0]}² | " + " | ".join(
            f"{f[k]['masked_psnr']:.2f}" for k in ("nearest", "bilinear", "dither", "depth")) + f" | {d:+.2f} |")
    for a in r["apertures"]:
        g, s = a["grid"], a["st_resolution"]
        aperture.append(f"| {scene} | {g[0]}×{g[1]} | {s[0]}² | {a['aperture']:g} | {a['cameras_per_pixel']} | "
                        f"{a['ms']:.2f} | {a['accumulated_frames']} | {a['accumulated_ms']:.0f} |")
adapter = json.load(open(f"{out}/demo.json"))["adapter"]
with open(f"{out}/table.md", "w") as f:
    f.write(f"Adapter: {adapter}\n\nMasked PSNR (dB) over the valid region:\n\n")
    f.write("\n".join(quality) + "\n\n" + "\n".join(detail) + "\n\n" + "\n".join(aperture) + "\n")
print(open(f"{out}/table.md").read())
PY
