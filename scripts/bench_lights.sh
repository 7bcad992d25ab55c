#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Light states" tables: every scene (the demo and the real-mesh
# fixtures) baked at 162 cameras × 256 px with --shadows and 12, 42 and 162 light directions
# (--lights, no calibration), then `lumigraph bench lights` on 3 random 512² views (seed 0):
# 4 lights of each kind per view (proxy directions, proxy-triangle centres, random), each scored
# against the reference with that light and the bake's shadows, the error split into the light
# field's (against the same blend of references) and the light interpolation's, planar weights
# and blended shadows (no shadow rays) beside, and the relit frames at the three proxy
# directions around each light in between (corners); and static against relit frames (with
# shadow rays and with blended shadows), 7 interleaved triples per view.
#   bash scripts/bench_lights.sh [OUT_DIR]   (default out/lights; about 35 min on 2 cores)
# Writes OUT_DIR/table.md and the JSON reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/lights}
mkdir -p "$OUT"
source scripts/bench_common.sh
: > "$OUT/bakes.txt"
for scene in demo bunny cow spot; do
  if [ "$scene" = demo ]; then src=(--demo); ref=(--demo); else src=("${MESH[$scene]}"); ref=(--mesh "${MESH[$scene]}"); fi
  for lights in 12 42 162; do
    asset="$OUT/$scene-$lights.lfa"
    $LG bake "${src[@]}" --cameras 162 --resolution 256 --shadows --lights "$lights" --no-calibrate -o "$asset" \
      | sed -n "s/.* in \([0-9]*\) ms: .* (\([0-9.]*\) MiB)/$scene $lights \1 \2/p" >> "$OUT/bakes.txt"
    $LG bench lights "$asset" "${ref[@]}" --views 3 --size 512 --lights 4 --repeats 7 --seed 0 \
      --json "$OUT/$scene-$lights.json"
    rm -f "$asset"
  done
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
bakes = {}
for line in open(f"{out}/bakes.txt"):
    scene, lights, ms, mib = line.split()
    bakes[(scene, lights)] = (float(ms) / 1e3, float(mib))
speed = ["| scene | lights | bake s | asset MiB | GPU MiB | static ms | relit ms | relit / static | blended-shadow relit / static |",
         "|---|---|---|---|---|---|---|---|---|"]
quality = ["| scene | lights | kind | masked PSNR | PSNR ∩ masks | wrong-surface px | corners masked PSNR | blended-shadow masked PSNR | light-field masked PSNR | interpolation masked PSNR | planar masked PSNR |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
for scene in ("demo", "bunny", "cow", "spot"):
    for lights in ("12", "42", "162"):
        r = json.load(open(f"{out}/{scene}-{lights}.json"))
        s, mib = bakes[(scene, lights)]
        speed.append(f"| {scene} | {lights} | {s:.1f} | {mib:.1f} | {r['gpu_bytes'] / 2**20:.0f} | "
                     f"{r['static_ms']:.2f} | {r['relit_ms']:.2f} | {r['relit_over_static']:.3f} | {r['blended_over_static']:.3f} |")
        for k in r["kinds"]:
            t, lf, it, pl = k["total"], k["light_field"], k["interpolation"], k["planar"]
            bl = k["blended_shadows"]
            co = f"{k['corners']['masked_psnr']:.2f}" if k.get("corners") else "–"
            quality.append(f"| {scene} | {lights} | {k['kind']} | {t['masked_psnr']:.2f} | {t['intersection_psnr']:.2f} | "
                           f"{t['wrong_surface_px']:.0f} | {co} | {bl['masked_psnr']:.2f} | {lf['masked_psnr']:.2f} | "
                           f"{it['masked_psnr']:.2f} | {pl['masked_psnr']:.2f} |")
text = "\n".join(speed) + "\n\n" + "\n".join(quality) + "\n"
open(f"{out}/table.md", "w").write(text)
print(text)
PY
