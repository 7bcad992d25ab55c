#!/usr/bin/env bash
# Installs what lumigraph needs at run time on a fresh Debian/Ubuntu machine: Mesa's software
# Vulkan driver (lavapipe), so rendering works without a GPU. Idempotent; quiet when done already.
set -euo pipefail
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 && ! ls /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  echo "setup: installing mesa-vulkan-drivers libvulkan1 (software Vulkan for CPU-only machines)" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
# Silence Mesa's "XDG_RUNTIME_DIR is invalid or not set" on every start.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/lumigraph-xdg-$(id -u)"
  mkdir -p -m 700 "$XDG_RUNTIME_DIR"
fi
