#!/usr/bin/env bash
# Python for comparisons and for the NumPy interop test: a virtual environment in .venv with
# NumPy, SciPy and scikit-learn (peer tools, never needed by the tests), or NumPy alone
# (--numpy-only: what tools/cli/tests/cli/interop.rs needs for python/test_biscale_io.py; scripts/test.sh
# runs it). Installs python3 and python3-venv first when they are missing (Debian). Idempotent.
#
#   scripts/setup-python.sh             NumPy, SciPy, scikit-learn
#   scripts/setup-python.sh --numpy-only
#                                       NumPy alone (quick; the tests' interpreter)
#   scripts/setup-python.sh --mitsuba   and Mitsuba 3 (scripts/mitsuba_check.py), with Debian's
#                                       libllvm19 for its llvm_ad_rgb variant (LLVM 15 and 16
#                                       abort on `fmaximum`; without it the check falls back to
#                                       the much slower scalar_rgb variant)
set -euo pipefail
cd "$(dirname "$0")/.."
mitsuba=0
numpy_only=0
for a in "$@"; do
    case "$a" in
        --mitsuba) mitsuba=1 ;;
        --numpy-only) numpy_only=1 ;;
        -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
        *) echo "setup-python: unknown option $a (expected --numpy-only or --mitsuba)" >&2; exit 2 ;;
    esac
done
if [ "$numpy_only" = 1 ] && [ "$mitsuba" = 1 ]; then
    echo "setup-python: --numpy-only and --mitsuba exclude each other" >&2
    exit 2
fi
if [ ! -x .venv/bin/python ]; then
    # Debian's python3 has no ensurepip (so no venv) without python3-venv.
    if ! command -v python3 >/dev/null 2>&1 || ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then
        # shellcheck source=lib/apt.sh
        source scripts/lib/apt.sh
        apt_ensure setup-python python3 python3-venv
    fi
    python3 -m venv .venv
fi
if [ "$numpy_only" = 1 ]; then
    # Quiet and quick when NumPy is there already (every scripts/test.sh run).
    if ! .venv/bin/python -c "import numpy" >/dev/null 2>&1; then
        .venv/bin/python -m pip install --quiet "numpy>=1.26"
    fi
    exit 0
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet "numpy>=1.26" "scipy>=1.11" "scikit-learn>=1.4"
.venv/bin/python -c "import sklearn, scipy; print('scikit-learn', sklearn.__version__, 'scipy', scipy.__version__)"
if [ "$mitsuba" = 1 ]; then
    # shellcheck source=lib/apt.sh
    source scripts/lib/apt.sh
    apt_ensure setup-python libllvm19 || echo "setup-python: no libllvm19; Mitsuba will use scalar_rgb" >&2
    .venv/bin/python -m pip install --quiet "mitsuba>=3.5"
    .venv/bin/python -c "import mitsuba as mi; print('mitsuba', mi.__version__)"
fi
