#!/usr/bin/env bash
# Reproduces BENCHMARKS.md's "Paged two-plane rendering" table: the bunny captured as a two-plane
# light field of 17×17 cameras × 1024² (2.3 GiB resident as RGBA8 + f32 depth) replayed at 512²
# through a cache of CACHE_MIB (default 200: a tenth and less) on four camera traces (slow pan,
# fast pan, widening field of view and aperture, fast pan that reverses), with each prefetch
# policy (none, lru, predict) at PAGES pages per frame (default 64), lru and predict again with
# frames that do not wait for their pages (--async-loads), and the fully resident paged
# renderer as the reference.
#   bash scripts/bench_paging.sh [OUT_DIR]   (default out/paging; about 15 min on 2 cores)
# Writes OUT_DIR/table.md, the traces and the reports beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
OUT=${1:-out/paging}
CACHE_MIB=${CACHE_MIB:-200}
PAGES=${PAGES:-64}
mkdir -p "$OUT"
source scripts/bench_common.sh
ASSET="$OUT/bunny-17x17-1024.lfa"
[ -f "$ASSET" ] || $LG bake "${MESH[bunny]}" -o "$ASSET" --two-plane auto --axis 0,0,1 \
  --grid 17x17 --st-res 1024x1024 > /dev/null
# `info` prints a summary, then the header as JSON.
$LG info "$ASSET" | sed -n '/^{/,$p' > "$OUT/info.json"
python3 - "$OUT" <<'PY'
import json, math, sys
out = sys.argv[1]
p = json.load(open(f"{out}/info.json"))["geometry"]["planes"]
uc, us, sc = p["uv"]["center"], p["uv"]["size"][0], p["st"]["center"]
sep = uc[2] - sc[2]
z = uc[2] + 0.5 * sep
def frame(x, yfov=20.0, aperture=None, focus=None):
    f = {"eye": [uc[0] + x * us, uc[1] + 0.1 * us, z], "target": [sc[0] + 0.6 * x * us, sc[1], sc[2]],
         "up": [0, 1, 0], "yfov_deg": yfov, "width": 512, "height": 512}
    if aperture is not None:
        f["aperture"] = aperture
    if focus is not None:
        f["focus"] = focus
    return f
n = 50
traces = {
    "slow": [frame(-0.1 + 0.004 * k) for k in range(n)],
    "fast": [frame(-0.5 + 0.02 * k) for k in range(n)],
    "widen": [frame(0.0, yfov=10 + 30 * k / (n - 1), aperture=3.0 * k / (n - 1), focus=0.35 * sep) for k in range(n)],
    "reverse": [frame(-0.25 + 0.02 * (k if k < n // 2 else n - k)) for k in range(n)],
}
for name, t in traces.items():
    json.dump(t, open(f"{out}/trace-{name}.json", "w"))
PY
for trace in slow fast widen reverse; do
  $LG render "$ASSET" --trace "$OUT/trace-$trace.json" -o "$OUT/frames-$trace-whole" \
    --report "$OUT/report-$trace-whole.json" > /dev/null
  for policy in none lru predict; do
    $LG render "$ASSET" --trace "$OUT/trace-$trace.json" -o "$OUT/frames-$trace-$policy" \
      --cache-mib "$CACHE_MIB" --prefetch "$policy" --pages-per-frame "$PAGES" \
      --report "$OUT/report-$trace-$policy.json" > /dev/null
  done
  for policy in lru predict; do
    $LG render "$ASSET" --trace "$OUT/trace-$trace.json" -o "$OUT/frames-$trace-$policy-async" \
      --cache-mib "$CACHE_MIB" --prefetch "$policy" --pages-per-frame "$PAGES" --async-loads \
      --report "$OUT/report-$trace-$policy-async.json" > /dev/null
  done
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
import statistics
rows = ["| trace | policy | faults | faults / frame (max) | degraded px / frame | pages loaded | ms / frame (mean, median, max) | fps (mean) |",
        "|---|---|---|---|---|---|---|---|"]
desc = None
for trace in ["slow", "fast", "widen", "reverse"]:
    for policy in ["whole", "none", "lru", "predict", "lru-async", "predict-async"]:
        r = json.load(open(f"{out}/report-{trace}-{policy}.json"))
        s, f = r["summary"], r["frames"]
        if policy != "whole":
            desc = r["cache"]
        n = s["frames"]
        name = {"whole": "all resident"}.get(policy, policy.replace("-async", ", async loads"))
        median = statistics.median(x["ms"] for x in f)
        rows.append(f"| {trace} | {name} | {s['faults']} | "
                    f"{s['faults'] / n:.1f} ({max(x['faults'] for x in f)}) | {s['degraded_px'] / n:.0f} | "
                    f"{s['pages_loaded']} | {s['mean_ms']:.1f}, {median:.1f}, {s['max_ms']:.1f} | {1000 / s['mean_ms']:.1f} |")
head = (f"Cache: {desc['budget_mib']} MiB budget, {desc['device_mib']:.1f} MiB on the device, {desc['slots']} slots of "
        f"{desc['page_size']}² for {desc['pages']} pages ({desc['resident_asset_mib']:.0f} MiB resident), coarse level "
        f"{desc['coarse_factor']}×, {desc['pages_per_frame']} pages per frame.\n\n")
open(f"{out}/table.md", "w").write(head + "\n".join(rows) + "\n")
print(open(f"{out}/table.md").read())
PY
