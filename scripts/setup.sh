#!/usr/bin/env bash
# Install the system packages biscale needs on a fresh Debian machine with a Rust toolchain:
# the software Vulkan driver (lavapipe) so the wgpu runtime runs without a GPU. Idempotent
# and quiet when everything is already there.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -f scripts/setup-vulkan.sh ]; then
    bash scripts/setup-vulkan.sh
fi
