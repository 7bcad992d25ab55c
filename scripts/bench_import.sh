#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Import of external renders" table: each real-mesh fixture's
# reference (--shadows) rendered from the first 12 and 42 directions of the camera set
# (perspective, 2.5 r away, 40°, 256² colour + z-depth), imported with `import-views`'s defaults
# into 162 cameras × 256 px, and scored beside a direct bake of the mesh with the same settings
# on 6 random 512² views (seed 0) against the reference (`lumigraph bench import`).
#   bash scripts/bench_import.sh [OUT_DIR]   (default out/import; about 5 min on 2 cores)
# Writes OUT_DIR/table.md and the JSON reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/import}
mkdir -p "$OUT"
source scripts/bench_common.sh
for scene in bunny cow spot; do
  $LG bench import "${MESH[$scene]}" --shadows --input-views 12,42 --input-size 256 \
    --views 6 --size 512 --seed 0 --json "$OUT/$scene.json"
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
rows = ["| scene | source | triangles | relief build ms | bake ms | asset MiB | masked PSNR | PSNR ∩ masks | wrong-surface px | SSIM |",
        "|---|---|---|---|---|---|---|---|---|---|"]
for scene in ("bunny", "cow", "spot"):
    r = json.load(open(f"{out}/{scene}.json"))
    for row in r["rows"]:
        s = row["score"]
        name = "direct bake" if row["input_views"] == 0 else f"{row['input_views']} views imported"
        rows.append(f"| {scene} | {name} | {row['relief_triangles']} | {row['build_ms']:.0f} | {row['bake_ms']:.0f} | "
                    f"{row['asset_bytes'] / 2**20:.1f} | {s['masked_psnr']:.2f} | {s['intersection_psnr']:.2f} | "
                    f"{s['wrong_surface_px']:.0f} | {s['ssim']:.4f} |")
text = "\n".join(rows) + "\n"
open(f"{out}/table.md", "w").write(text)
print(text)
PY
