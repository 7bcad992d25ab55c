#!/usr/bin/env bash
# Sourced by the other scripts: installs what lumigraph needs at run time on a fresh
# Debian/Ubuntu machine, Mesa's software Vulkan driver (lavapipe), so rendering works without a
# GPU, and libjpeg-turbo's development files (the service's JPEG encoder), and gives the shell a private runtime directory when it has none (lumigraph makes one
# itself, but test binaries run many threads, where setting the environment is not safe).
# Idempotent; quiet when done already.
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 && ! ls /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then
  echo "setup: installing mesa-vulkan-drivers libvulkan1 (software Vulkan for CPU-only machines)" >&2
  apt_install mesa-vulkan-drivers libvulkan1
fi
# libjpeg-turbo: the service's JPEG encoder links it (`lumigraph_core` feature `turbojpeg`).
if ! dpkg -s libturbojpeg0-dev pkg-config >/dev/null 2>&1; then
  echo "setup: installing libturbojpeg0-dev pkg-config (the stream's JPEG encoder)" >&2
  apt_install libturbojpeg0-dev pkg-config
fi
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/lumigraph-xdg-$(id -u)"
  mkdir -p -m 700 "$XDG_RUNTIME_DIR"
fi
