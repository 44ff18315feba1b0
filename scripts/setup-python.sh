#!/usr/bin/env bash
# Peer tools for comparisons (never needed by the tests): a virtual environment in .venv
# with NumPy, SciPy and scikit-learn. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet "numpy>=1.26" "scipy>=1.11" "scikit-learn>=1.4"
.venv/bin/python -c "import sklearn, scipy; print('scikit-learn', sklearn.__version__, 'scipy', scipy.__version__)"
