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
