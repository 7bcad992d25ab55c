#!/usr/bin/env bash
# Reproduces the scene figures of BENCHMARKS.md: two instances of the bunny (162 cameras × 256
# px; one rotated 60°, scaled 0.7 and moved 1 unit aside) and a rasterized floor quad,
# composited by depth, rendered from 4 views of 512² (eye 3.2 units from the pair, 40°) by
# `lumigraph render scene.json --views`, three times (one process each).
#   bash scripts/bench_scene.sh [OUT_DIR]   (default out/scene; about 1 min on 2-core lavapipe)
# Prints each run's per-frame times and wall time.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/scene}
mkdir -p "$OUT"
source scripts/bench_common.sh
scene_asset bunny
cat >"$OUT/floor.obj" <<'OBJ'
v -3 -0.75 -3
v 3 -0.75 -3
v 3 -0.75 3
v -3 -0.75 3
f 1 3 2
f 1 4 3
OBJ
cat >"$OUT/scene.json" <<'JSON'
{"objects": [
  {"type": "lightfield", "asset": "bunny.lfa"},
  {"type": "lightfield", "asset": "bunny.lfa",
   "transform": {"translation": [1, 0, 0], "rotation": {"axis": [0, 1, 0], "degrees": 60}, "scale": 0.7}},
  {"type": "mesh", "mesh": "floor.obj"}
]}
JSON
python3 - "$OUT/views4.json" <<'PY'
import json, math, sys
views = []
for k in range(4):
    a = math.radians(20 + 90 * k)
    eye = [0.5 + 3.2 * math.sin(a), 0.8, 3.2 * math.cos(a)]
    views.append({"eye": eye, "target": [0.5, 0, 0], "up": [0, 1, 0], "yfov_deg": 40,
                  "width": 512, "height": 512})
json.dump(views, open(sys.argv[1], "w"))
PY
for run in 1 2 3; do
  echo "== run $run"
  TIMEFORMAT='wall %R s'
  time $LG render "$OUT/scene.json" --views "$OUT/views4.json" -o "$OUT/frames"
done
