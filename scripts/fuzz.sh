#!/usr/bin/env bash
# Coverage-guided fuzzing of every parser input reaches (fuzz/fuzz_targets/): the .lfa reader,
# the OBJ/PLY/STL/OFF/glTF mesh loaders, the volume readers, view (and view-list) JSON, scene JSON, render request
# bodies and stream messages. Installs cargo-fuzz when missing, writes seed corpora from the
# fixtures and small generated inputs (scripts/fuzz_seeds.py), then runs each target and prints a
# table of executions. A crash, an out-of-memory (one allocation or RSS over 2 GiB), a leak or a
# single input slower than 10 s fails the run; libFuzzer keeps the input under
# fuzz/artifacts/TARGET/ and the script prints how to reproduce it.
#
#   bash scripts/fuzz.sh                    # every target, 60 s each
#   bash scripts/fuzz.sh --seconds 600 lfa_reader mesh_off
#   bash scripts/fuzz.sh --runs 10000000    # every target until 10 million executions
#   bash scripts/fuzz.sh --smoke            # CI: a debug build, 5 s each
#
# Fuzz builds run on stable Rust without a sanitizer (`-s none`): the code is safe Rust, so
# memory errors are not the risk; panics, overflow (debug assertions are on), hangs and
# unbounded allocation are, and libFuzzer catches those. Corpora grow in fuzz/corpus/ (kept
# between runs, never committed); `--fresh` starts from the seeds again.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
SECONDS_EACH=60
RUNS=""
PROFILE_FLAG=""
FRESH=0
TARGETS=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) SECONDS_EACH=$2; shift 2 ;;
    --runs) RUNS=$2; shift 2 ;;
    --smoke) SECONDS_EACH=5; PROFILE_FLAG=--dev; shift ;;  # own corpus and logs, removed after
    --fresh) FRESH=1; shift ;;
    -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) TARGETS+=("$1"); shift ;;
  esac
done
ALL=(lfa_reader mesh_obj mesh_ply mesh_stl mesh_off mesh_gltf volume view_json scene_json render_request stream_message)
if [ ${#TARGETS[@]} -eq 0 ]; then TARGETS=("${ALL[@]}"); fi
for t in "${TARGETS[@]}"; do
  [[ " ${ALL[*]} " == *" $t "* ]] || { echo "unknown target $t (targets: ${ALL[*]})" >&2; exit 2; }
done

CARGO_FUZZ_VERSION=0.13.2
if ! cargo fuzz --version 2>/dev/null | grep -q "$CARGO_FUZZ_VERSION"; then
  echo "== installing cargo-fuzz $CARGO_FUZZ_VERSION"
  cargo install --locked -q cargo-fuzz --version "$CARGO_FUZZ_VERSION"
fi

# The .lfa seeds are baked by the lumigraph binary (lavapipe where there is no GPU).
source scripts/setup.sh
BIN=${LUMIGRAPH_BIN:-}
if [ -z "$BIN" ]; then
  echo "== cargo build -p lumigraph_server (for the .lfa seeds)"
  cargo build --locked -q -p lumigraph_server
  BIN=${CARGO_TARGET_DIR:-$ROOT/target}/debug/lumigraph
fi
CORPUS=$ROOT/fuzz/corpus
LOGS=$ROOT/fuzz/logs
if [ -n "$PROFILE_FLAG" ]; then
  # A smoke run starts from the seeds in a folder of its own and leaves the corpus alone.
  SMOKE_DIR=$(mktemp -d)
  trap 'rm -rf "$SMOKE_DIR"' EXIT
  CORPUS=$SMOKE_DIR/corpus
  LOGS=$SMOKE_DIR/logs
fi
if [ "$FRESH" = 1 ]; then rm -rf "$CORPUS"; fi
python3 scripts/fuzz_seeds.py "$CORPUS" --bin "$BIN" --fixtures "${LUMIGRAPH_FIXTURES:-fixtures}"

cd fuzz
# Its own target folder: instrumented builds share nothing with the main one.
unset CARGO_TARGET_DIR
echo "== cargo fuzz build ${PROFILE_FLAG:-(release)}"
cargo fuzz build -s none $PROFILE_FLAG
HOST=$(rustc -vV | sed -n 's/^host: //p')
if [ -n "$PROFILE_FLAG" ]; then BIN_DIR=target/$HOST/debug; else BIN_DIR=target/$HOST/release; fi

LIMIT_ARGS=(-rss_limit_mb=2048 -malloc_limit_mb=2048 -timeout=10 -max_len=65536 -print_final_stats=1)
if [ -n "$RUNS" ]; then LIMIT_ARGS+=(-runs="$RUNS"); else LIMIT_ARGS+=(-max_total_time="$SECONDS_EACH"); fi
mkdir -p "$LOGS"
SUMMARY=$LOGS/summary.tsv
printf 'target\texecutions\tseconds\texec_per_s\tcorpus\tresult\n' > "$SUMMARY"
FAILED=0
for t in "${TARGETS[@]}"; do
  mkdir -p "artifacts/$t"
  log=$LOGS/$t.log
  start=$(date +%s)
  # The binaries `cargo fuzz build` made, run directly: `cargo fuzz run` would rebuild first.
  if "$BIN_DIR/$t" "${LIMIT_ARGS[@]}" -artifact_prefix="artifacts/$t/" "$CORPUS/$t" \
      > "$log" 2>&1; then
    result=ok
  else
    result=FAILED
    FAILED=1
  fi
  secs=$(( $(date +%s) - start ))
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  corpus=$(find "$CORPUS/$t" -type f | wc -l)
  printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$t" "${execs:-?}" "$secs" "${rate:-?}" "$corpus" "$result" >> "$SUMMARY"
  echo "$t: ${execs:-?} executions in ${secs} s (${rate:-?}/s), corpus $corpus, $result"
  if [ "$result" = FAILED ]; then
    tail -n 25 "$log"
    echo "  full log: $log; reproduce: (cd fuzz && $BIN_DIR/$t artifacts/$t/<file>)"
  fi
done
column -t -s $'\t' "$SUMMARY"
exit $FAILED
