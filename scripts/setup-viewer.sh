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
# Idempotent and quiet when everything is already installed (see scripts/lib/apt.sh).
#
# Usage: scripts/setup-viewer.sh [--xvfb]
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/lib/apt.sh"
"$here/setup-vulkan.sh"

PACKAGES=(libx11-6 libx11-xcb1 libxcursor1 libxi6 libxkbcommon0 libxkbcommon-x11-0)
for a in "$@"; do
    case "$a" in
        --xvfb) PACKAGES+=(xvfb xauth) ;;
        *) echo "setup-viewer: unknown option $a (usage: $0 [--xvfb])" >&2; exit 2 ;;
    esac
done

apt_ensure setup-viewer "${PACKAGES[@]}"
