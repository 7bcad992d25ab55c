#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Lenslet import" table: the dev set's light-field microscope image
# (napari-LF's GUV example) imported with `import --layout lenslet` (the median of 5 timed
# runs), then refocused with the full aperture (R = 7, 16 stratified draws averaged) at
# 208 × 208 px from −12 to +12 µm: the render time and a focus measure per focal depth (mean
# squared central-difference gradient of the grey image over its covered interior, over the
# squared mean grey). Needs a Python with numpy and pillow (./.venv-e2e or ./.venv, else
# $PYTHON or python3).
#   bash scripts/bench_lenslet.sh [OUT_DIR]   (default out/lenslet; about 30 s)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/lenslet}
mkdir -p "$OUT"
source scripts/bench_common.sh
PY=${PYTHON:-python3}
for venv in .venv .venv-e2e; do [ -x "$venv/bin/python" ] && PY=$venv/bin/python; done
SRC="$FIX/lightfield/GUVExperim1"
times=()
for _ in 1 2 3 4 5; do
  start=$(date +%s%N)
  $LG import "$SRC" -o "$OUT/guv.lfa" --layout lenslet > "$OUT/import.txt"
  times+=($(( ($(date +%s%N) - start) / 1000000 )))
done
IMPORT_MS=$(printf '%s\n' "${times[@]}" | sort -n | sed -n 3p)
$LG info "$OUT/guv.lfa" > "$OUT/info.txt"
"$PY" - "$OUT" "$LG" "$IMPORT_MS" <<'PY'
import json, math, re, subprocess, sys
import numpy as np
from PIL import Image
out, lg, import_ms = sys.argv[1], sys.argv[2], sys.argv[3]
text = open(f"{out}/info.txt").read()
header = json.loads(text[text.index("{"):])
planes = header["geometry"]["planes"]
distance, st = planes["uv"]["center"][2], planes["st"]["size"][0]
view = {"eye": [0, 0, 1.5 * distance], "target": [0, 0, 0], "up": [0, 1, 0],
        "yfov_deg": math.degrees(2 * math.atan(0.45 * st / (1.5 * distance))), "width": 208, "height": 208}
json.dump(view, open(f"{out}/view.json", "w"))
rows = []
for focus in range(-12, 13, 2):
    png = f"{out}/focus_{focus:+d}.png"
    done = subprocess.run([lg, "render", f"{out}/guv.lfa", "--view", f"{out}/view.json", "-o", png,
                           "--aperture", "7", f"--focus={focus}", "--accumulate", "16"],
                          capture_output=True, text=True, check=True)
    ms = float(re.search(r"([0-9.]+) ms", done.stdout).group(1))
    a = np.asarray(Image.open(png).convert("RGBA")).astype(float)
    grey, covered = a[..., :3].mean(axis=2), a[..., 3] > 0
    inner = covered[1:-1, 1:-1] & covered[:-2, 1:-1] & covered[2:, 1:-1] & covered[1:-1, :-2] & covered[1:-1, 2:]
    gx = grey[1:-1, 2:] - grey[1:-1, :-2]
    gy = grey[2:, 1:-1] - grey[:-2, 1:-1]
    energy = float((gx ** 2 + gy ** 2)[inner].mean() / grey[1:-1, 1:-1][inner].mean() ** 2)
    rows.append((focus, ms, energy))
report = open(f"{out}/import.txt").read().strip().splitlines()
best = max(rows, key=lambda r: r[2])
lines = [f"Import: {import_ms} ms (median of 5). " + " ".join(report[:1]), "",
         "| focus (µm above the native plane) | ms (16 draws, 208²) | focus measure |", "|---:|---:|---:|"]
lines += [f"| {f:+d} | {ms:.0f} | {e:.4f} |" for f, ms, e in rows]
lines += ["", f"Maximum at focus {best[0]:+d} µm; ends {rows[0][2] / best[2]:.2f} and {rows[-1][2] / best[2]:.2f} of it."]
open(f"{out}/table.md", "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
