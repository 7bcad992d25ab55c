#!/usr/bin/env bash
# Reproduces the multi-light-field rows of BENCHMARKS.md's volume section (seed 002 Table 1's
# 3-layer row, §7's 162 cameras × 3 layers × 512²): the MNI152 T1 head (dev fixture
# volume/mni_t1.nii.gz) with gradient shading, baked at 162 cameras × 512-px maps three ways:
# whole through `mri-brain`; as three depth layers of `mri-brain` (every ray split where its
# accumulated opacity reaches 0.3 and 0.7); as three TF layers that cut `mri-brain`'s value range
# into grey (70–150), white (150–205) and bright (205–255) matter (layers per structure, §6).
# Each is scored by `lumigraph eval --volume` on 30 random 512² views (seed 0) against the direct
# CPU ray cast (layered assets against their layers' composited ray casts; depth layers at full
# opacity are the whole ray cast), then timed interleaved: `lumigraph render --views` of the
# same 12 views (eye at 2.5 radii, 40°), one asset after the other, three rounds, the first view
# of each process (pipeline compilation) left out; the layered assets once more composited on
# the GPU (LUMIGRAPH_COMPOSITE=gpu) beside the default choice. Bakes and evals already in
# OUT_DIR are kept.
#   bash scripts/bench_volume_layers.sh [OUT_DIR]   (default out/volume-layers; about 35 min)
# LUMIGRAPH_PROFILE=dev times the debug build (its core crate is optimized too).
# Writes OUT_DIR/table.md and the JSON and logs beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/volume-layers}
mkdir -p "$OUT"
source scripts/bench_common.sh
# A copy of the binary: a rebuild during the run does not change what is measured.
cp "$LG" "$OUT/lumigraph.bin"
LG=$OUT/lumigraph.bin
VOL="$FIX/volume/mni_t1.nii.gz"
VIEWS=${VIEWS:-30}
cat >"$OUT/depth3.json" <<'JSON'
{"tf": "mri-brain", "split": {"opacity": [0.3, 0.7]},
 "layers": [{"name": "outer"}, {"name": "middle"}, {"name": "inner"}]}
JSON
cat >"$OUT/tf3.json" <<'JSON'
{"layers": [
 {"name": "grey", "tf": {"points": [[0, 0, 0, 0, 0], [70, 0, 0, 0, 0], [100, 0.85, 0.62, 0.55, 0.03],
   [150, 0.85, 0.62, 0.55, 0.03], [151, 0, 0, 0, 0]]}},
 {"name": "white", "tf": {"points": [[0, 0, 0, 0, 0], [150, 0, 0, 0, 0], [180, 0.96, 0.92, 0.86, 0.6],
   [205, 0.97, 0.94, 0.88, 0.7], [206, 0, 0, 0, 0]]}},
 {"name": "bright", "tf": {"points": [[0, 0, 0, 0, 0], [205, 0, 0, 0, 0], [206, 0.97, 0.94, 0.88, 0.7],
   [255, 1, 1, 1, 0.9]]}}
]}
JSON
one="$OUT/mni-162.lfa"
three="$OUT/mni-162-depth3.lfa"
tf3="$OUT/mni-162-tf3.lfa"
[ -f "$one" ] || $LG bake "$VOL" --tf mri-brain --shade --cameras 162 --resolution 512 -o "$one" \
  | tee "$OUT/bake-1.txt"
[ -f "$three" ] || $LG bake "$VOL" --layers "$OUT/depth3.json" --shade --cameras 162 \
  --resolution 512 -o "$three" | tee "$OUT/bake-3.txt"
[ -f "$tf3" ] || $LG bake "$VOL" --layers "$OUT/tf3.json" --shade --cameras 162 \
  --resolution 512 -o "$tf3" | tee "$OUT/bake-tf3.txt"
for a in "$one" "$three" "$tf3"; do
  zstd -q -3 -T1 -f -o "$a.zst" "$a"
  $LG info "$a" > "$a.info.txt"
done
evaluate() {
  [ -s "$2" ] || $LG eval "$1" --volume "$VOL" --views "$VIEWS" --size 512 --seed 0 --json > "$2.tmp"
  [ -s "$2" ] || mv "$2.tmp" "$2"
}
evaluate "$three" "$OUT/eval-3.json"
evaluate "$one" "$OUT/eval-1.json"
evaluate "$tf3" "$OUT/eval-tf3.json"
timing_views "$one.info.txt" "$OUT/views.json"
: > "$OUT/timing.txt"
# The layered assets twice: composited where the adapter suits (auto) and, as `three_gpu` and
# `tf3_gpu`, on the GPU whatever the adapter (LUMIGRAPH_COMPOSITE=gpu).
for round in 1 2 3; do
  for a in one three tf3 three_gpu tf3_gpu; do
    name=${a%_gpu}
    asset=${!name}
    mode=auto
    [ "$name" = "$a" ] || mode=gpu
    LUMIGRAPH_COMPOSITE=$mode $LG render "$asset" --views "$OUT/views.json" -o "$OUT/frames-$a" \
      | sed -n 's/^view \([0-9]*\): \([0-9.]*\) ms.*/\1 \2/p' \
      | awk -v a="$a" -v r="$round" '$1 != "000" {print a, r, $2}' >> "$OUT/timing.txt"
  done
done
python3 - "$OUT" <<'PY'
import json, os, re, statistics, sys
out = sys.argv[1]
rows = ["| asset | layers | size MiB | zstd MiB | bake s | MAE | masked PSNR | PSNR over black | SSIM | wrong-surface px | footprint | eval ms/frame | interleaved ms/frame | fps | × one layer | GPU MiB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
times = {"one": [], "three": [], "tf3": [], "three_gpu": [], "tf3_gpu": []}
for line in open(f"{out}/timing.txt"):
    a, _, ms = line.split()
    times[a].append(float(ms))
med = {a: statistics.median(v) for a, v in times.items()}
for key, name, layers, tag in (("one", "mni-162", 1, "1"), ("three", "mni-162-depth3", 3, "3"),
                               ("tf3", "mni-162-tf3", 3, "tf3")):
    e = json.load(open(f"{out}/eval-{tag}.json"))
    path = f"{out}/{name}.lfa"
    size = os.path.getsize(path) / 2**20
    zsize = os.path.getsize(path + ".zst") / 2**20
    bake_ms = float(re.search(r"in (\d+) ms", open(f"{out}/bake-{tag}.txt").read()).group(1))
    info = open(path + ".info.txt").read()
    gpu = int(re.search(r"GPU memory when served: (\d+) bytes", info).group(1)) / 2**20
    m = e["mean"]
    foot = sum(v["footprint"] for v in e["views"]) / len(e["views"])
    rows.append(f"| {name} | {layers} | {size:.1f} | {zsize:.1f} | {bake_ms / 1e3:.0f} | {m['mae']:.2f} | "
                f"{m['masked_psnr']:.2f} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['wrong_surface_px']:.0f} | "
                f"{100 * foot:.1f} % | {e['mean_ms']:.1f} | {med[key]:.1f} | {1e3 / med[key]:.0f} | "
                f"{med[key] / med['one']:.2f} | {gpu:.0f} |")
rows.append("")
rows.append("Composited on the GPU (LUMIGRAPH_COMPOSITE=gpu): " + ", ".join(
    f"{a[:-4]} {med[a]:.1f} ms ({med[a] / med['one']:.2f}× one layer, {med[a] - med[a[:-4]]:+.1f} ms)"
    for a in ("three_gpu", "tf3_gpu")) + ".")
rows.append("Interleaved frames per asset: " + ", ".join(f"{a} {len(v)} (median {med[a]:.1f} ms)" for a, v in times.items()) + ".")
open(f"{out}/table.md", "w").write("\n".join(rows) + "\n")
print("\n".join(rows))
PY
