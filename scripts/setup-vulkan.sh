#!/usr/bin/env bash
# Install the Vulkan loader and Mesa's software Vulkan driver (lavapipe) so that the wgpu
# runtime (crate biscale-gpu) can run on a machine without a GPU.
#
# Idempotent and quiet when both packages are already installed (see scripts/lib/apt.sh).
#
# Usage: scripts/setup-vulkan.sh        (then `cargo test -p biscale-gpu` shows the adapter
#        wgpu picks)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/lib/apt.sh"

apt_ensure setup-vulkan libvulkan1 mesa-vulkan-drivers

# Check that the ICD for lavapipe is where the loader looks.
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    echo "setup-vulkan: warning: no lavapipe ICD (lvp_icd*.json) in /usr/share/vulkan/icd.d" >&2
fi
