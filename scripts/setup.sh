#!/usr/bin/env bash
# Install the system packages biscale needs on a fresh Debian machine with a Rust toolchain:
# the software Vulkan driver (lavapipe) so the wgpu runtime runs without a GPU, and g++ for
# the FLIP metric's C++. Idempotent and quiet when everything is already there.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -f scripts/setup-vulkan.sh ]; then
    bash scripts/setup-vulkan.sh
fi
# A C++ compiler: the nv-flip crate builds NVIDIA's FLIP (C++) for the image metrics' FLIP
# figure (biscale_shading::ldr). Debian's Rust toolchain brings gcc, not always g++.
source scripts/lib/apt.sh
apt_ensure setup g++
