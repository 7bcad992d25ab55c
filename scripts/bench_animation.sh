#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Animation" table: the Debian glTF samples (a morph-target cube, a
# simple skin) baked with --animation at 8 fps into 162 cameras × 128 px, then
# `lumigraph bench animation` on 3 random 512² views (seed 0): frames rendered in turn as a
# player advances them against the static frame, 24 interleaved pairs per view, the medians.
#   bash scripts/bench_animation.sh [OUT_DIR]   (default out/animation; about 3 min on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/animation}
mkdir -p "$OUT"
source scripts/bench_common.sh
: > "$OUT/bakes.txt"
for scene in AnimatedMorphCube simple_skin; do
  $LG bake "$FIX/anim/$scene.gltf" --animation --fps 8 --cameras 162 --resolution 128 --no-calibrate \
    -o "$OUT/$scene.lfa" | sed -n "s/.* in \([0-9]*\) ms: .*/$scene \1/p" >> "$OUT/bakes.txt"
  $LG bench animation "$OUT/$scene.lfa" --views 3 --size 512 --repeats 24 --seed 0 --json "$OUT/$scene.json"
  rm -f "$OUT/$scene.lfa"
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
bakes = dict(line.split() for line in open(f"{out}/bakes.txt"))
rows = ["| scene | frames | bake s | mean stored % | asset MiB | GPU MiB | static ms | playing ms | playing / static |",
        "|---|---|---|---|---|---|---|---|---|"]
for scene in ("AnimatedMorphCube", "simple_skin"):
    r = json.load(open(f"{out}/{scene}.json"))
    rows.append(f"| {scene} | {r['frames']} | {float(bakes[scene]) / 1e3:.1f} | {100 * r['mean_stored_fraction']:.1f} | "
                f"{r['asset_bytes'] / 2**20:.1f} | {r['gpu_bytes'] / 2**20:.0f} | {r['static_ms']:.2f} | "
                f"{r['playing_ms']:.2f} | {r['playing_over_static']:.3f} |")
text = "\n".join(rows) + "\n"
open(f"{out}/table.md", "w").write(text)
print(text)
PY
