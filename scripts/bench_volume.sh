#!/usr/bin/env bash
# Reproduces the volume light-field figures of BENCHMARKS.md (seed 002's Table 1): the MNI152
# T1 head (dev fixture volume/mni_t1.nii.gz, 197×233×189, 8-bit) through the `mri-brain` transfer
# function with gradient shading, baked at 12/42/162 cameras × 512-px maps and scored by
# `lumigraph eval --volume` on 30 random 512² views (seed 0) against the direct CPU ray cast;
# the floor (the GPU's own direct ray cast against the CPU's) and its time come from `--floor`.
# The opaque-mesh figures for the speed ratio are the bunny at the same cameras, maps and views.
#   bash scripts/bench_volume.sh [OUT_DIR]   (default out/volume; about 25 min on 2-core lavapipe)
# Writes OUT_DIR/table.md and the per-run JSON beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/volume}
mkdir -p "$OUT"
source scripts/bench_common.sh
VOL="$FIX/volume/mni_t1.nii.gz"
VIEWS=${VIEWS:-30}
for cams in 12 42 162; do
  asset="$OUT/mni-$cams.lfa"
  $LG bake "$VOL" --tf mri-brain --shade --cameras "$cams" --resolution 512 -o "$asset" \
    | tee "$OUT/bake-$cams.txt"
  zstd -q -3 -T1 -f -o "$asset.zst" "$asset"
  floor=()
  [ "$cams" = 12 ] && floor=(--floor)
  $LG eval "$asset" --volume "$VOL" --views "$VIEWS" --size 512 --seed 0 "${floor[@]}" --json \
    > "$OUT/eval-$cams.json"
done
for cams in 12 42 162; do
  mesh="$OUT/bunny-$cams-512.lfa"
  [ -f "$mesh" ] || $LG bake "${MESH[bunny]}" --cameras "$cams" --resolution 512 --no-calibrate -o "$mesh" >/dev/null
  $LG eval "$mesh" --mesh "${MESH[bunny]}" --views "$VIEWS" --size 512 --seed 0 --json > "$OUT/eval-mesh-$cams.json"
done
python3 - "$OUT" <<'PY'
import json, os, re, sys
out = sys.argv[1]
seed = {12: 10.41, 42: 7.84, 162: 6.34}
mesh = {c: json.load(open(f"{out}/eval-mesh-{c}.json")) for c in (12, 42, 162)}
rows = ["| cameras | size MiB | zstd MiB | bake s | MAE (seed) | MAE | masked PSNR | PSNR over black | SSIM | footprint | ms/frame | fps | mesh ms/frame | × mesh |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
floor = None
for cams in (12, 42, 162):
    e = json.load(open(f"{out}/eval-{cams}.json"))
    size = os.path.getsize(f"{out}/mni-{cams}.lfa") / 2**20
    zsize = os.path.getsize(f"{out}/mni-{cams}.lfa.zst") / 2**20
    bake_ms = float(re.search(r"in (\d+) ms", open(f"{out}/bake-{cams}.txt").read()).group(1))
    m = e["mean"]
    foot = sum(v["footprint"] for v in e["views"]) / len(e["views"])
    rows.append(f"| {cams} | {size:.1f} | {zsize:.1f} | {bake_ms / 1e3:.1f} | {seed[cams]} | {m['mae']:.2f} | "
                f"{m['masked_psnr']:.2f} | {m['psnr']:.2f} | {m['ssim']:.4f} | {100 * foot:.1f} % | {e['mean_ms']:.1f} | "
                f"{1e3 / e['mean_ms']:.0f} | {mesh[cams]['mean_ms']:.1f} | {e['mean_ms'] / mesh[cams]['mean_ms']:.2f} |")
    if e.get("mean_floor"):
        floor = (e["mean_floor"], e["mean_direct_ms"], e["mean_reference_ms"])
rows.append("")
rows.append("Mesh: the opaque bunny light field at the same cameras × 512 px on the same kind of views; masked PSNR "
            + ", ".join(f"{c}: {mesh[c]['mean']['masked_psnr']:.2f} dB" for c in (12, 42, 162)) + ".")
if floor:
    f, direct_ms, ref_ms = floor
    rows.append(f"Floor (GPU direct ray cast against the CPU reference, 30 views): MAE {f['mae']:.3f}, "
                f"masked PSNR {f['masked_psnr']:.2f} dB, PSNR {f['psnr']:.2f} dB; direct GPU ray cast "
                f"{direct_ms:.0f} ms/frame, CPU reference {ref_ms:.0f} ms/frame.")
open(f"{out}/table.md", "w").write("\n".join(rows) + "\n")
print("\n".join(rows))
PY
