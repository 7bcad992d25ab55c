#!/usr/bin/env bash
# Runs the image docker/build.sh built, without a container runtime, and checks it end to end:
#   bash docker/build.sh && bash docker/smoke.sh
# 1. exports localhost/lumigraph:latest's file system (podman create + export) into a folder;
# 2. starts the image's entrypoint and command in it (bubblewrap: the image's root, /proc, /dev,
#    a private /tmp; setpriv to the image's user, no capabilities; the image's environment plus
#    LUMIGRAPH_TOKEN), listening on a free loopback port instead of 0.0.0.0:8080;
# 3. waits for readiness with the image's own HEALTHCHECK command (the empty assets volume means
#    the demo scene is baked first: start-to-ready includes that bake);
# 4. renders one frame over HTTP and one over the WebSocket stream (docker/smoke_client.py);
# 5. checks that the image's user cannot write outside its own folders;
# 6. sends SIGTERM and expects a clean exit (0) within the drain time;
# 7. runs the batch image's default command (the wheel imports and finds the adapter).
# Writes out/docker/smoke.json (start-to-ready, exit times, frame sizes, image size).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
OUT=$ROOT/out/docker
IMAGE=${LUMIGRAPH_IMAGE:-localhost/lumigraph:latest}
BATCH_IMAGE=${LUMIGRAPH_BATCH_IMAGE:-localhost/lumigraph-batch:latest}
TOOLS=$OUT/tools
if ! podman image exists "$IMAGE" || [ ! -x "$TOOLS/bin/python" ]; then
  echo "smoke: $IMAGE or $TOOLS is missing: run bash docker/build.sh first" >&2
  exit 1
fi

work=$(mktemp -d "$OUT/smoke.XXXXXX")
server_pid=""
bwrap_pid=""
cleanup() {
  for pid in $server_pid $bwrap_pid; do kill -KILL "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

# export_fs IMAGE DIR: the image's flattened file system.
export_fs() {
  local id
  id=$(podman create "$1" 2>/dev/null)
  mkdir -p "$2"
  podman export "$id" | tar -C "$2" -x
  # (podman without systemd logs an error about healthcheck timers it never made: not ours)
  podman rm "$id" >/dev/null 2>&1
}

echo "== exporting $IMAGE"
export_fs "$IMAGE" "$work/root"
config=$(podman image inspect "$IMAGE" --format '{{json .Config}}')
user=$(jq -r '.User' <<<"$config")
uid=$(awk -F: -v u="${user%%:*}" '$1 == u {print $3}' "$work/root/etc/passwd")
gid=$(awk -F: -v g="${user##*:}" '$1 == g {print $3}' "$work/root/etc/group")
[ -n "$uid" ] && [ -n "$gid" ] && [ "$uid" != 0 ] || { echo "smoke: the image's user $user is missing or root" >&2; exit 1; }
# Owners (what the structure test's tar driver cannot check): root's binary, the user's folders.
for spec in "usr/local/bin/lumigraph 0:0 755" "run/lumigraph $uid:$gid 700" "var/lib/lumigraph/assets $uid:$gid 755"; do
  read -r file owner mode <<<"$spec"
  [ "$(stat -c '%u:%g %a' "$work/root/$file")" = "$owner $mode" ] \
    || { echo "smoke: /$file is $(stat -c '%u:%g %a' "$work/root/$file"), expected $owner $mode" >&2; exit 1; }
done
workdir=$(jq -r '.WorkingDir' <<<"$config")
mapfile -t env_args < <(jq -r '.Env[] | capture("^(?<k>[^=]+)=(?<v>.*)$") | "--setenv\n\(.k)\n\(.v)"' <<<"$config")
mapfile -t command < <(jq -r '(.Entrypoint // []) + (.Cmd // []) | .[]' <<<"$config")
mapfile -t healthcheck < <(podman image inspect "$IMAGE" --format '{{json .HealthCheck}}' | jq -r '.Test[0] as $k | if $k == "CMD" then .Test[1:][] else error("HEALTHCHECK is \($k), not CMD") end')
[ ${#healthcheck[@]} -gt 0 ] || { echo "smoke: the image has no HEALTHCHECK" >&2; exit 1; }
port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
# The image's command with its listen address moved to a free loopback port.
for i in "${!command[@]}"; do [ "${command[$i]}" = 0.0.0.0:8080 ] && command[$i]=127.0.0.1:$port; done
for i in "${!healthcheck[@]}"; do [ "${healthcheck[$i]}" = 127.0.0.1:8080 ] && healthcheck[$i]=127.0.0.1:$port; done

# in_image CMD...: runs CMD in the exported image as its user, replacing the calling shell
# (call it in a subshell or in the background: then $! is bwrap itself).
in_image() {
  exec bwrap --bind "$work/root" / --proc /proc --dev /dev --ro-bind /sys /sys --tmpfs /tmp \
    --die-with-parent --chdir "$workdir" --clearenv "${env_args[@]}" --setenv LUMIGRAPH_TOKEN smoke-token \
    -- /usr/bin/setpriv --reuid="$uid" --regid="$gid" --clear-groups --inh-caps=-all --bounding-set=-all "$@"
}

echo "== starting: ${command[*]} (uid $uid)"
start=$(date +%s.%N)
in_image "${command[@]}" >"$work/serve.log" 2>&1 &
bwrap_pid=$!
for _ in $(seq 50); do
  server_pid=$(pgrep -P "$bwrap_pid" | head -1 || true)
  [ -n "$server_pid" ] && break
  sleep 0.1
done
ready=""
for _ in $(seq 600); do
  if (in_image "${healthcheck[@]}") >/dev/null 2>&1; then ready=$(date +%s.%N); break; fi
  kill -0 "$bwrap_pid" 2>/dev/null || { echo "smoke: serve exited:"; tail -30 "$work/serve.log"; exit 1; }
  sleep 0.5
done
[ -n "$ready" ] || { echo "smoke: not ready after 300 s"; tail -30 "$work/serve.log"; exit 1; }
start_to_ready=$(python3 -c "print(round($ready - $start, 2))")
echo "== ready after ${start_to_ready} s (healthcheck: ${healthcheck[*]})"

frames=$("$TOOLS/bin/python" docker/smoke_client.py "http://127.0.0.1:$port" demo)
echo "== frames: $frames"

# The service user owns its data folders and nothing else.
if (in_image /bin/sh -c 'touch /usr/local/bin/x || touch /etc/x') 2>/dev/null; then
  echo "smoke: the image's user can write to system folders" >&2; exit 1
fi
[ "$(stat -c %u "$work/root/var/lib/lumigraph/assets/demo.lfa")" = "$uid" ] || { echo "smoke: demo.lfa not owned by the image's user" >&2; exit 1; }

echo "== SIGTERM"
stop=$(date +%s.%N)
kill -TERM "$server_pid"
code=0
wait "$bwrap_pid" || code=$?
stopped=$(date +%s.%N)
[ "$code" = 0 ] || { echo "smoke: serve exited with $code after SIGTERM"; tail -30 "$work/serve.log"; exit 1; }
server_pid=""
exit_s=$(python3 -c "print(round($stopped - $stop, 2))")
echo "== exited 0 after ${exit_s} s"

echo "== LUMIGRAPH_ADAPTER=gpu: alive, never ready, the reason in /readyz"
(env_args+=(--setenv LUMIGRAPH_ADAPTER gpu); in_image "${command[@]}") >"$work/serve-gpu.log" 2>&1 &
bwrap_pid=$!
answer=""
for _ in $(seq 100); do
  answer=$(curl -s "http://127.0.0.1:$port/readyz" || true)
  [ -n "$answer" ] && break
  sleep 0.2
done
server_pid=$(pgrep -P "$bwrap_pid" | head -1 || true)
if grep -q '"ready":true' <<<"$answer"; then
  echo "== (this machine has a hardware GPU: the gpu adapter was found)"
else
  grep -q 'LUMIGRAPH_ADAPTER=gpu: no such adapter' <<<"$answer" || { echo "smoke: /readyz said: $answer" >&2; exit 1; }
  check=0; (in_image "${healthcheck[@]}") >/dev/null 2>&1 || check=$?
  [ "$check" = 1 ] || { echo "smoke: healthcheck exited $check on the unready service" >&2; exit 1; }
  echo "== /readyz 503: $(jq -r .error.message <<<"$answer" | cut -c1-120)..."
fi
kill -TERM "$server_pid"
code=0; wait "$bwrap_pid" || code=$?
server_pid=""
[ "$code" = 0 ] || { echo "smoke: the unready serve exited with $code after SIGTERM" >&2; exit 1; }

echo "== batch image: $(podman image inspect "$BATCH_IMAGE" --format '{{json .Config.Cmd}}')"
export_fs "$BATCH_IMAGE" "$work/batch"
batch_out=$(bwrap --bind "$work/batch" / --proc /proc --dev /dev --ro-bind /sys /sys --tmpfs /tmp \
  --die-with-parent --clearenv --setenv PATH /usr/local/bin:/usr/bin:/bin --setenv XDG_RUNTIME_DIR /run/lumigraph \
  -- /usr/bin/setpriv --reuid="$uid" --regid="$gid" --clear-groups --inh-caps=-all --bounding-set=-all \
  python3 -c "import lumigraph as lg; lf = lg.bake_mesh(lg.Mesh.demo(), cameras=12, resolution=32, progress=False); print(lg.__version__, lf.cameras, lg.device_info())")
echo "== batch: $batch_out"

size=$(podman image inspect "$IMAGE" --format '{{.Size}}')
printf '{"start_to_ready_s": %s, "sigterm_exit_s": %s, "frames": %s, "image_size_bytes": %s, "batch": "%s"}\n' \
  "$start_to_ready" "$exit_s" "$frames" "$size" "$batch_out" > "$OUT/smoke.json"
cat "$OUT/smoke.json"
echo "== smoke test passed"
