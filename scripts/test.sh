#!/usr/bin/env bash
# The project's test command (the README's second command; CI runs it too).
# Installs what the tests need (the software Vulkan driver, so wgpu runs without a GPU),
# then runs the whole workspace's tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo test --workspace --locked "$@"
