#!/usr/bin/env bash
# Runs the lumigraph binary (release build), installing the software Vulkan driver if missing.
#   bash scripts/run.sh serve            # the main job: the viewer on the built-in demo scene
#   bash scripts/run.sh bake --demo -o demo.lfa
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked -q -p lumigraph_server
exec target/release/lumigraph "$@"
