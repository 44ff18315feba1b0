#!/usr/bin/env bash
# The `biscale` Python module's tests (python/tests, pytest) against the CLI built by cargo:
# every API call beside the same command's output on configs/smoke.toml, a Python compressor
# in a run, bad input from Python, the GIL released during a run. scripts/test.sh runs it
# after `cargo test`; it builds the module first (scripts/setup-python.sh --module).
#
#   scripts/test-python.sh [PYTEST ARGS]     e.g. -k gil, -x
#
# Without a Python environment (no network, say) it is skipped with a message, unless
# BISCALE_REQUIRE_PYTHON=1 (CI), which makes that a failure.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! bash scripts/setup-python.sh --module; then
    if [ "${BISCALE_REQUIRE_PYTHON:-0}" = 1 ]; then
        echo "test-python: scripts/setup-python.sh --module failed and BISCALE_REQUIRE_PYTHON=1" >&2
        exit 1
    fi
    echo "test-python: warning: the biscale module could not be built; its tests are skipped" >&2
    exit 0
fi
# The CLI the tests compare with: the one `cargo test` built.
cargo build --locked --quiet -p biscale-cli -p biscale-plugin-quantized
export BISCALE_BIN="${BISCALE_BIN:-$PWD/target/debug/biscale}"
exec .venv/bin/python -m pytest python/tests -q -p no:cacheprovider "$@"
