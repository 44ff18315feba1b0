#!/usr/bin/env bash
# The project's test command (the README's second command; CI runs it too).
# Installs what the tests need (the software Vulkan driver, so wgpu runs without a GPU, and
# NumPy in .venv for the Python round trip of tools/cli/tests/cli/interop.rs), then runs the whole
# workspace's tests, then the Python module's (scripts/test-python.sh: pytest on python/tests).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# NumPy for python/test_biscale_io.py. Without it (no network, say) that part of the interop
# test is skipped with a message, unless BISCALE_REQUIRE_PYTHON=1 (CI), which makes it fail.
if bash scripts/setup-python.sh --numpy-only; then
    export BISCALE_PYTHON="${BISCALE_PYTHON:-$PWD/.venv/bin/python}"
elif [ "${BISCALE_REQUIRE_PYTHON:-0}" = 1 ]; then
    echo "test.sh: scripts/setup-python.sh --numpy-only failed and BISCALE_REQUIRE_PYTHON=1" >&2
    exit 1
else
    echo "test.sh: warning: no NumPy (scripts/setup-python.sh --numpy-only failed); the Python round trip will be skipped" >&2
fi
cargo test --workspace --locked "$@"
# The Python module's tests (pytest; builds the module into .venv first).
bash scripts/test-python.sh
