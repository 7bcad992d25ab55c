#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Deformation states" tables: each real-mesh fixture dented by 2, 5
# and 10 % of its bounding radius (a smooth dent 0.2 r across, on the surface farthest towards
# 0,0.5,1) and baked at 162 cameras × 256 px with --shadows, the dents as deformation states
# beside two bake-noise controls (the mesh unchanged, and with its triangles reversed), at page
# sides 32 and 128 (`lumigraph bench states`); each dent rendered on 6 random 512² views (seed 0)
# against the dented mesh's reference, beside a plain bake of the dented mesh.
#   bash scripts/bench_states.sh [OUT_DIR]   (default out/states; about 5 min on 2 cores)
# Writes OUT_DIR/table.md and the JSON reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/states}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in bunny cow spot; do
  $LG bench states "${MESH[$scene]}" --shadows --views 6 --size 512 --seed 0 --json "$OUT/$scene.json"
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
storage = ["| scene | state | page px | stored % | cameras touched | colour-only cameras | stored KiB | base KiB |",
           "|---|---|---|---|---|---|---|---|"]
quality = ["| scene | state | state masked PSNR | plain-bake masked PSNR | Δ dB | state wrong px | plain wrong px |",
           "|---|---|---|---|---|---|---|"]
cost = ["| scene | base ms | state ms | GPU MiB (base) | GPU MiB (5 states) |", "|---|---|---|---|---|"]
for scene in ("bunny", "cow", "spot"):
    r = json.load(open(f"{out}/{scene}.json"))
    for s in r["storage"]:
        storage.append(f"| {scene} | {s['state']} | {s['page_size']} | {100 * s['fraction']:.2f} | {s['cameras']} | "
                       f"{s['colour_only_cameras']} | {s['stored_bytes'] / 1024:.0f} | {r['base_bytes'] / 1024:.0f} |")
    for q in r["quality"]:
        a, b = q["state_render"], q["plain_bake"]
        quality.append(f"| {scene} | {q['state']} | {a['masked_psnr']:.2f} | {b['masked_psnr']:.2f} | "
                       f"{a['masked_psnr'] - b['masked_psnr']:+.2f} | {a['wrong_surface_px']:.0f} | {b['wrong_surface_px']:.0f} |")
    cost.append(f"| {scene} | {r['base_ms']:.2f} | {r['state_ms']:.2f} | {r['base_gpu_bytes'] / 2**20:.0f} | {r['gpu_bytes'] / 2**20:.0f} |")
text = "\n".join(storage) + "\n\n" + "\n".join(quality) + "\n\n" + "\n".join(cost) + "\n"
open(f"{out}/table.md", "w").write(text)
print(text)
PY
