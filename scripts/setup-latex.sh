#!/usr/bin/env bash
# Install pdflatex with booktabs and graphicx (Debian's texlive-latex-recommended, about 16
# packages) so that the tables and figures `biscale reproduce` writes can be typeset
# (scripts/paper-tex-check.sh). Idempotent and quiet when installed (scripts/lib/apt.sh).
#
# Usage: scripts/setup-latex.sh
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/lib/apt.sh"

apt_ensure setup-latex texlive-latex-recommended
command -v pdflatex >/dev/null || { echo "setup-latex: pdflatex not found after the install" >&2; exit 1; }
