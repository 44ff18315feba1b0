#!/usr/bin/env bash
# Install what the interactive viewer (`biscale view`, cargo feature `viewer` of biscale-gpu)
# needs at run time on Debian/Ubuntu: the Vulkan loader and lavapipe (scripts/setup-vulkan.sh),
# and the X11 client libraries winit loads with dlopen:
#   libX11 (libx11-6), libX11-xcb (libx11-xcb1), libXcursor (libxcursor1), libXi (libxi6),
#   libxkbcommon + libxkbcommon-x11 (libxkbcommon0, libxkbcommon-x11-0).
# (libXrandr is not needed: winit speaks RandR through x11rb. On a Wayland desktop winit uses
# libwayland-client0 when present, which every such desktop has, and falls back to X11.)
#
# With --xvfb it also installs a virtual X server for headless use (xvfb, xauth for xvfb-run):
#   xvfb-run -s "-screen 0 1024x768x24" cargo run --release -p biscale-gpu --features viewer \
#       --example view_demo -- --screenshot shot.png --frames 5
#
# Idempotent: does nothing (and prints nothing) when everything is already installed. Works as
# root on a fresh Debian/Ubuntu without sudo, and uses sudo when run as another user.
# `apt-get update` runs only when the install fails for lack of package lists.
#
# Usage: scripts/setup-viewer.sh [--xvfb]
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
"$here/setup-vulkan.sh"

PACKAGES=(libx11-6 libx11-xcb1 libxcursor1 libxi6 libxkbcommon0 libxkbcommon-x11-0)
for a in "$@"; do
    case "$a" in
        --xvfb) PACKAGES+=(xvfb xauth) ;;
        *) echo "setup-viewer: unknown option $a (usage: $0 [--xvfb])" >&2; exit 2 ;;
    esac
done

missing=()
for p in "${PACKAGES[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup-viewer: apt-get not found; install ${missing[*]} (X11 client libraries) by hand" >&2
    exit 1
fi

SUDO=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO=(sudo)
    else
        echo "setup-viewer: not root and no sudo; cannot install ${missing[*]}" >&2
        exit 1
    fi
fi

export DEBIAN_FRONTEND=noninteractive
install() {
    "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

echo "setup-viewer: installing ${missing[*]}"
if ! install 2>/dev/null; then
    echo "setup-viewer: package lists stale or missing; running apt-get update"
    "${SUDO[@]}" apt-get update -qq
    install
fi
echo "setup-viewer: done"
