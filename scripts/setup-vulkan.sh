#!/usr/bin/env bash
# Install the Vulkan loader and Mesa's software Vulkan driver (lavapipe) so that the wgpu
# runtime (crate biscale-gpu) can run on a machine without a GPU.
#
# Idempotent: does nothing (and prints nothing) when both packages are already installed.
# Works as root on a fresh Debian/Ubuntu without sudo, and uses sudo when run as another
# user. `apt-get update` runs only when the install fails for lack of package lists.
#
# Usage: scripts/setup-vulkan.sh        (then: vulkaninfo is not needed; run
#        `cargo test -p biscale-gpu` to see the adapter wgpu picks)
set -euo pipefail

PACKAGES=(libvulkan1 mesa-vulkan-drivers)

missing=()
for p in "${PACKAGES[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup-vulkan: apt-get not found; install ${missing[*]} (Vulkan loader + Mesa lavapipe) by hand" >&2
    exit 1
fi

SUDO=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO=(sudo)
    else
        echo "setup-vulkan: not root and no sudo; cannot install ${missing[*]}" >&2
        exit 1
    fi
fi

export DEBIAN_FRONTEND=noninteractive
install() {
    "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

echo "setup-vulkan: installing ${missing[*]}"
if ! install 2>/dev/null; then
    echo "setup-vulkan: package lists stale or missing; running apt-get update"
    "${SUDO[@]}" apt-get update -qq
    install
fi

# Check that the ICD for lavapipe is where the loader looks.
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    echo "setup-vulkan: warning: no lavapipe ICD (lvp_icd*.json) in /usr/share/vulkan/icd.d" >&2
fi
echo "setup-vulkan: done"
