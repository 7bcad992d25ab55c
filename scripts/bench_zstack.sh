#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "z-stacks" table: a synthetic fluorescence z-stack of SIZE voxels
# (default 4096x4096x61, the seed's stack size; `import-zstack --demo`) synthesised into a
# two-plane light field of GRID cameras (default 5x5), then replayed at 512² through a cache of
# CACHE_MIB (default 256) on five camera traces (slow pan, fast pan, widening field of view
# and aperture, fast pan that reverses, zoom out to the whole stack) with the lru and predict
# policies at PAGES pages per frame (default 64), and the zoom trace again without overview
# pixels (--no-overview: every pixel reads the pages).
#   bash scripts/bench_zstack.sh [OUT_DIR]   (default out/zstack; about 15 min on 2 cores)
# Writes OUT_DIR/table.md, the traces and the reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/zstack}
SIZE=${SIZE:-4096x4096x61}
GRID=${GRID:-5x5}
CACHE_MIB=${CACHE_MIB:-256}
PAGES=${PAGES:-64}
mkdir -p "$OUT"
source scripts/bench_common.sh
ASSET="$OUT/demo-$SIZE-$GRID.lfa"
if [ ! -f "$ASSET" ]; then
  /usr/bin/time -f '%e s %M KiB' -o "$OUT/import-time.txt" \
    $LG import-zstack --demo "$SIZE" --grid "$GRID" -o "$ASSET" > "$OUT/import.txt"
fi
$LG info "$ASSET" | sed -n '/^{/,$p' > "$OUT/info.json"
python3 - "$OUT" <<'PY'
import json, math, sys
out = sys.argv[1]
p = json.load(open(f"{out}/info.json"))["geometry"]["planes"]
uc, us, sw = p["uv"]["center"], p["uv"]["size"][0], p["st"]["size"][0]
h = uc[2]
def frame(x, y=0.0, yfov=6.0, z=1.3, aperture=None, focus=None):
    f = {"eye": [x * sw, y * sw, z * h], "target": [x * sw * 0.8, y * sw * 0.8, 0.0],
         "up": [0, 1, 0], "yfov_deg": yfov, "width": 512, "height": 512}
    if aperture is not None:
        f["aperture"] = aperture
    if focus is not None:
        f["focus"] = focus
    return f
n = 50
# The stack spans 2·atan(0.5 / 1.3) ≈ 42° from 1.3 H: 6° views one sixth of it across.
traces = {
    "slow": [frame(-0.2 + 0.002 * k) for k in range(n)],
    "fast": [frame(-0.35 + 0.014 * k) for k in range(n)],
    "widen": [frame(0.05, yfov=6 + 14 * k / (n - 1), aperture=1.5 * k / (n - 1), focus=0.0) for k in range(n)],
    "reverse": [frame(-0.2 + 0.014 * (k if k < n // 2 else n - k)) for k in range(n)],
    "zoom": [frame(0.02, 0.01, yfov=6 * (44 / 6) ** (k / (n - 1))) for k in range(n)],
}
for name, t in traces.items():
    json.dump(t, open(f"{out}/trace-{name}.json", "w"))
PY
run() {  # run NAME TRACE FLAGS...
  local name=$1 trace=$2
  shift 2
  $LG render "$ASSET" --trace "$OUT/trace-$trace.json" -o "$OUT/frames-$name" \
    --cache-mib "$CACHE_MIB" --pages-per-frame "$PAGES" --report "$OUT/report-$name.json" "$@" > /dev/null
}
for trace in slow fast widen reverse zoom; do
  for policy in lru predict; do
    run "$trace-$policy" "$trace" --prefetch "$policy"
  done
done
run zoom-predict-no-overview zoom --prefetch predict --no-overview
python3 - "$OUT" "$SIZE" "$GRID" <<'PY'
import json, statistics, sys
out, size, grid = sys.argv[1:4]
rows = ["| trace | policy | faults | faults / frame (max) | degraded px / frame | overview px / frame | pages loaded | ms / frame (mean, median) | fps (mean) |",
        "|---|---|---|---|---|---|---|---|---|"]
runs = [(t, p) for t in ["slow", "fast", "widen", "reverse", "zoom"] for p in ["lru", "predict"]]
runs.append(("zoom", "predict-no-overview"))
for trace, policy in runs:
    r = json.load(open(f"{out}/report-{trace}-{policy}.json"))
    s, f, desc = r["summary"], r["frames"], r["cache"]
    n = s["frames"]
    median = statistics.median(x["ms"] for x in f)
    rows.append(f"| {trace} | {policy.replace('-no-overview', ', no overview')} | {s['faults']} | "
                f"{s['faults'] / n:.1f} ({max(x['faults'] for x in f)}) | {s['degraded_px'] / n:.0f} | "
                f"{s.get('overview_px', 0) / n:.0f} | {s['pages_loaded']} | {s['mean_ms']:.1f}, {median:.1f} | "
                f"{1000 / s['mean_ms']:.1f} |")
imp = open(f"{out}/import.txt").read().strip()
tm = open(f"{out}/import-time.txt").read().strip() if __import__("os").path.exists(f"{out}/import-time.txt") else "?"
head = (f"Stack: demo {size} voxels (16-bit), {grid} cameras. Import: `{imp}` ({tm}, wall and peak memory).\n\n"
        f"Cache: {desc['budget_mib']} MiB budget, {desc['device_mib']:.1f} MiB on the device, {desc['slots']} slots of "
        f"{desc['page_size']}² for {desc['pages']} pages ({desc['resident_asset_mib']:.0f} MiB resident), coarse level "
        f"{desc['coarse_factor']}×, {desc['pages_per_frame']} pages per frame.\n\n")
open(f"{out}/table.md", "w").write(head + "\n".join(rows) + "\n")
print(open(f"{out}/table.md").read())
PY
