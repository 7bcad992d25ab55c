#!/usr/bin/env bash
# Regenerates every table of BENCHMARKS.md (release build, real-mesh fixtures + the demo), one
# script after another, each into its own folder under OUT_DIR:
#   bash scripts/bench_all.sh [OUT_DIR]   (default out/bench; about 215 min on 2-core lavapipe)
# Run it on an otherwise idle machine: the timings are only as steady as the host.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/bench}
mkdir -p "$OUT"
step() {
  echo "== $1 → $2"
}
step "quality and speed at 512² (scripts/bench.sh)" "$OUT/quality/tables.md: 'Quality', 'Speed at 512×512'"
bash scripts/bench.sh "$OUT/quality"
step "trade-off sweep (scripts/bench_tradeoff.sh)" "$OUT/tradeoff/tables.md and SCENE/pareto.png: 'Speed against accuracy'"
bash scripts/bench_tradeoff.sh "$OUT/tradeoff"
step "coarse-to-fine guide (scripts/bench_guide.sh, 8 runs)" "$OUT/guide/tables.md: 'Coarse-to-fine guide'"
RUNS=${RUNS:-8} bash scripts/bench_guide.sh "$OUT/guide"
step "automatic LOD (scripts/bench_lod.sh)" "$OUT/lod/tables.md: 'Automatic LOD'"
bash scripts/bench_lod.sh "$OUT/lod"
step "scenes (scripts/bench_scene.sh)" "$OUT/scene/times.txt: 'Scenes'"
mkdir -p "$OUT/scene"
bash scripts/bench_scene.sh "$OUT/scene" 2>&1 | tee "$OUT/scene/times.txt"
step "volume light fields (scripts/bench_volume.sh)" "$OUT/volume/table.md: 'Volume light fields'"
bash scripts/bench_volume.sh "$OUT/volume"
step "volume multi light fields (scripts/bench_volume_layers.sh)" "$OUT/volume-layers/table.md: 'Volume light fields', 3-layer rows"
bash scripts/bench_volume_layers.sh "$OUT/volume-layers"
step "volume block compression (scripts/bench_volume_codecs.sh)" "$OUT/volume-codecs/table.md: 'Volume light fields', compressed rows"
bash scripts/bench_volume_codecs.sh "$OUT/volume-codecs"
step "shadows (scripts/bench_shadows.sh)" "$OUT/shadows/table.md: 'Shadows'"
bash scripts/bench_shadows.sh "$OUT/shadows"
step "light states (scripts/bench_lights.sh)" "$OUT/lights/table.md: 'Light states'"
bash scripts/bench_lights.sh "$OUT/lights"
step "deformation states (scripts/bench_states.sh)" "$OUT/states/table.md: 'Deformation states'"
bash scripts/bench_states.sh "$OUT/states"
step "import of external renders (scripts/bench_import.sh)" "$OUT/import/table.md: 'Import of external renders'"
bash scripts/bench_import.sh "$OUT/import"
step "two-plane light fields (scripts/bench_two_plane.sh)" "$OUT/two_plane/table.md: 'Two-plane light fields'"
bash scripts/bench_two_plane.sh "$OUT/two_plane"
step "lenslet import (scripts/bench_lenslet.sh)" "$OUT/lenslet/table.md: 'Two-plane light fields' / 'Lenslet import'"
bash scripts/bench_lenslet.sh "$OUT/lenslet"
step "animation (scripts/bench_animation.sh)" "$OUT/animation/table.md: 'Animation'"
bash scripts/bench_animation.sh "$OUT/animation"
step "still refinement (scripts/bench_refine.sh)" "$OUT/refine/tables.md: 'Still-frame refinement'"
bash scripts/bench_refine.sh "$OUT/refine"
step "render service (scripts/bench_service.py)" "$OUT/service.md: 'Render service streaming'"
source scripts/common.sh
make_venv .venv-bench 10
pip_install_once .venv-bench "httpx websockets pillow" httpx websockets pillow
.venv-bench/bin/python scripts/bench_service.py --out "$OUT/service.md"
step "batch baking (scripts/bench_distributed.sh)" "$OUT/distributed/table.md: 'Batch baking'"
bash scripts/bench_distributed.sh "$OUT/distributed"
step "replicas behind the router (scripts/bench_replicas.sh)" "$OUT/replicas.md: 'Replicas behind the router'"
bash scripts/bench_replicas.sh "$OUT/replicas.md"
step "block compression (scripts/bench_compression.sh)" "$OUT/compression/table.md: 'Block compression'"
bash scripts/bench_compression.sh "$OUT/compression"
step "paged two-plane rendering (scripts/bench_paging.sh)" "$OUT/paging/table.md: 'Paged two-plane rendering'"
bash scripts/bench_paging.sh "$OUT/paging"
step "z-stacks (scripts/bench_zstack.sh, twice)" "$OUT/zstack/table.md and $OUT/zstack8k/table.md: 'z-stacks'"
bash scripts/bench_zstack.sh "$OUT/zstack"
SIZE=8192x8192x13 GRID=3x3 bash scripts/bench_zstack.sh "$OUT/zstack8k"
echo "== done: tables in $OUT"
