#!/usr/bin/env bash
# Builds the lumigraph container images on this machine and checks them, without a registry or
# a container daemon:
#   bash docker/build.sh            (about 5 min on 2 cores with a warm cargo cache)
# 1. compiles `lumigraph` (release) and the Python wheel on this host (Debian 12) into the build
#    context out/docker/context (bin/lumigraph, wheels/);
# 2. makes the base image: $LUMIGRAPH_BASE_IMAGE when set (e.g. docker.io/library/debian:bookworm-slim
#    where a registry is reachable), else a Debian 12 root file system from
#    `debootstrap --variant=minbase bookworm` imported into podman as localhost/lumigraph-base:bookworm
#    (made once; LUMIGRAPH_REBUILD_BASE=1 remakes it);
# 3. lints docker/Dockerfile with hadolint;
# 4. `podman build --isolation=chroot --format docker` of the targets runtime (localhost/lumigraph)
#    and batch (localhost/lumigraph-batch), then `podman save` of both into out/docker/*.tar;
# 5. container-structure-test --driver tar on the runtime image (docker/structure-test.yaml).
# Needs root, podman, buildah's chroot isolation, debootstrap (apt-get installs them when
# missing) and network access to Debian's mirror. docker/smoke.sh runs the built image.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/setup.sh
OUT=$ROOT/out/docker
CONTEXT=$OUT/context
BASE_TAG=localhost/lumigraph-base:bookworm
mkdir -p "$OUT"

need=()
command -v podman >/dev/null || need+=(podman)
command -v buildah >/dev/null || need+=(buildah)
command -v debootstrap >/dev/null || need+=(debootstrap)
command -v bwrap >/dev/null || need+=(bubblewrap)
command -v jq >/dev/null || need+=(jq)
if [ ${#need[@]} -gt 0 ]; then
  apt_install "${need[@]}"
fi

TOOLS=$OUT/tools
make_venv "$TOOLS" 11
pip_install_once "$TOOLS" "$(sha256sum docker/requirements-tools.txt | cut -d' ' -f1)" -r docker/requirements-tools.txt

echo "== cargo build --release -p lumigraph_server; maturin build --release"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
cargo build --release --locked -q -p lumigraph_server
rm -rf "$CONTEXT"
mkdir -p "$CONTEXT/bin" "$CONTEXT/wheels"
# Debug line tables out (124 MB → 22 MB); symbols stay, so backtraces still name functions.
strip --strip-debug -o "$CONTEXT/bin/lumigraph" "$CARGO_TARGET_DIR/release/lumigraph"
(cd pylib && PATH="$TOOLS/bin:$PATH" maturin build --release --locked -q -o "$CONTEXT/wheels")
ls "$CONTEXT/wheels"/lumigraph-*.whl >/dev/null

if [ -n "${LUMIGRAPH_BASE_IMAGE:-}" ]; then
  BASE=$LUMIGRAPH_BASE_IMAGE
elif [ "${LUMIGRAPH_REBUILD_BASE:-0}" = 1 ] || ! podman image exists "$BASE_TAG"; then
  echo "== debootstrap --variant=minbase bookworm → $BASE_TAG"
  rootfs=$(mktemp -d "$OUT/rootfs.XXXXXX")
  trap 'rm -rf "$rootfs"' EXIT
  debootstrap --variant=minbase bookworm "$rootfs" "${DEBIAN_MIRROR:-http://deb.debian.org/debian}" >"$OUT/debootstrap.log" 2>&1 \
    || { tail -20 "$OUT/debootstrap.log"; exit 1; }
  # What a registry's debian:bookworm-slim also leaves out: caches and package lists.
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
  tar -C "$rootfs" -c . | podman import --quiet - "$BASE_TAG" >/dev/null
  rm -rf "$rootfs"
  trap - EXIT
  BASE=$BASE_TAG
else
  BASE=$BASE_TAG
fi

echo "== hadolint docker/Dockerfile"
"$TOOLS/bin/hadolint" --config docker/hadolint.yaml docker/Dockerfile

for target in runtime batch; do
  tag=localhost/lumigraph:latest
  [ "$target" = batch ] && tag=localhost/lumigraph-batch:latest
  echo "== podman build --target $target → $tag (base $BASE)"
  podman build --quiet --isolation=chroot --format docker --target "$target" \
    --build-arg "BASE=$BASE" -f docker/Dockerfile -t "$tag" "$CONTEXT" >/dev/null
  archive=$OUT/$([ "$target" = batch ] && echo lumigraph-batch || echo lumigraph).tar
  rm -f "$archive"
  podman save --quiet --format docker-archive -o "$archive" "$tag"
done

echo "== container-structure-test --driver tar"
"$TOOLS/bin/container-structure-test" test --driver tar --image "$OUT/lumigraph.tar" \
  --config docker/structure-test.yaml
size=$(podman image inspect localhost/lumigraph:latest --format '{{.Size}}')
batch_size=$(podman image inspect localhost/lumigraph-batch:latest --format '{{.Size}}')
printf '{"image": "localhost/lumigraph:latest", "size_bytes": %s, "batch_size_bytes": %s, "base": "%s"}\n' \
  "$size" "$batch_size" "$BASE" > "$OUT/build.json"
echo "== built: localhost/lumigraph:latest ($((size / 1048576)) MiB), localhost/lumigraph-batch:latest ($((batch_size / 1048576)) MiB); archives in $OUT"
