#!/usr/bin/env bash
# Peer tools for comparisons (never needed by the tests): a virtual environment in .venv
# with NumPy, SciPy and scikit-learn. Idempotent.
#
#   scripts/setup-python.sh             NumPy, SciPy, scikit-learn
#   scripts/setup-python.sh --mitsuba   and Mitsuba 3 (scripts/mitsuba_check.py), with Debian's
#                                       libllvm19 for its llvm_ad_rgb variant (LLVM 15 and 16
#                                       abort on `fmaximum`; without it the check falls back to
#                                       the much slower scalar_rgb variant)
set -euo pipefail
cd "$(dirname "$0")/.."
mitsuba=0
for a in "$@"; do
    case "$a" in
        --mitsuba) mitsuba=1 ;;
        -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
        *) echo "setup-python: unknown option $a (expected --mitsuba)" >&2; exit 2 ;;
    esac
done
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
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
