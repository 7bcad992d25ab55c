# Sourced by the bench scripts (from the repository root, after scripts/setup.sh): builds the
# release binary as $LG and provides the real-mesh fixtures as $FIX (fetched once) with their
# paths in MESH[scene] (the demo has none: it is built in). LUMIGRAPH_PROFILE=dev builds the
# debug binary instead (its core crate is optimized; the GPU work runs in the driver), where a
# release build would take longer than the measurement.
if [ "${LUMIGRAPH_PROFILE:-release}" = dev ]; then
  cargo build --locked -q -p lumigraph_server
  LG=${CARGO_TARGET_DIR:-target}/debug/lumigraph
else
  cargo build --release --locked -q -p lumigraph_server
  LG=${CARGO_TARGET_DIR:-target}/release/lumigraph
fi
FIX=${LUMIGRAPH_FIXTURES:-fixtures}
bash scripts/fixtures.sh "$FIX" >/dev/null
declare -A MESH=([bunny]="$FIX/mesh/bunny00.off" [cow]="$FIX/mesh/cow.off" [spot]="$FIX/mesh/spot.ply" [demo]="")
# scene_asset SCENE [BAKE_FLAGS...]: bakes SCENE (162 cameras × 256 px, plus BAKE_FLAGS) into
# $OUT/SCENE.lfa unless it is there, and sets ASSET to it and REF to `eval`'s source flags.
scene_asset() {
  local scene=$1 src
  shift
  ASSET="$OUT/$scene.lfa"
  if [ "$scene" = demo ]; then src=(--demo); REF=(--demo); else src=("${MESH[$scene]}"); REF=(--mesh "${MESH[$scene]}"); fi
  [ -f "$ASSET" ] || $LG bake "${src[@]}" -o "$ASSET" --cameras 162 --resolution 256 "$@" > /dev/null
}
# timing_views INFO_TXT OUT_JSON: 12 random 512² views (seed 7) of the asset whose `lumigraph
# info` is INFO_TXT, the eye at 2.5 radii from its frame's centre, 40°: the interleaved timing
# views of the volume benchmarks.
timing_views() {
  python3 - "$1" "$2" <<'PY'
import json, math, random, re, sys
info = open(sys.argv[1]).read()
m = re.search(r"centre \[([^\]]+)\], radius ([0-9.eE+-]+)", info)
c = [float(x) for x in m.group(1).split(",")]
r = float(m.group(2))
rng = random.Random(7)
views = []
for _ in range(12):
    z = rng.uniform(-1, 1); a = rng.uniform(0, 2 * math.pi); s = math.sqrt(1 - z * z)
    d = [s * math.cos(a), s * math.sin(a), z]
    up = [1, 0, 0] if abs(d[1]) > 0.9 else [0, 1, 0]
    views.append({"eye": [c[i] + 2.5 * r * d[i] for i in range(3)], "target": c, "up": up,
                  "yfov_deg": 40, "width": 512, "height": 512})
json.dump(views, open(sys.argv[2], "w"))
PY
}
