#!/usr/bin/env bash
# Typeset what `biscale reproduce` writes: every tables/*.tex and figures/*.tex of a paper
# folder, each \input into a small article (booktabs, graphicx) and run through pdflatex in
# batch mode, so a table or caption that LaTeX rejects fails here. CI runs it on a
# `reproduce --quick` folder (about 40 s with pdflatex installed).
#
#   bash scripts/paper-tex-check.sh [PAPER_DIR]
#
# PAPER_DIR: a folder `biscale reproduce` wrote. Without it, `biscale reproduce --quick` runs
# into a temporary folder first (BISCALE: the binary, default target/debug/biscale, built
# with cargo when missing). Installs pdflatex with scripts/setup-latex.sh. Writes only into a
# temporary folder, removed on exit; prints each PDF's page count.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup-latex.sh
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

paper="${1:-}"
if [ -z "$paper" ]; then
    bin="${BISCALE:-${CARGO_TARGET_DIR:-target}/debug/biscale}"
    [ -x "$bin" ] || cargo build --locked -q -p biscale-cli --bin biscale
    paper="$tmp/paper"
    echo "paper-tex-check: biscale reproduce --quick into $paper"
    "$bin" -q reproduce --quick --out "$paper" --cache-dir "$tmp/cache"
fi
[ -d "$paper/tables" ] || { echo "paper-tex-check: $paper has no tables/ (not a biscale reproduce folder)" >&2; exit 1; }

n=0
for tex in "$paper"/tables/*.tex "$paper"/figures/*.tex; do
    [ -e "$tex" ] || continue
    name="$(basename "$(dirname "$tex")")-$(basename "$tex" .tex)"
    # Figures name their panels relative to the paper folder: typeset from there.
    cat > "$tmp/$name.tex" <<TEX
\documentclass{article}
\usepackage[margin=1.5cm,landscape]{geometry}
\usepackage{booktabs}
\usepackage{graphicx}
\begin{document}
\input{$tex}
\end{document}
TEX
    if ! (cd "$paper" && pdflatex -interaction=nonstopmode -halt-on-error -output-directory "$tmp" "$tmp/$name.tex" > "$tmp/$name.out" 2>&1); then
        echo "paper-tex-check: $tex does not typeset:" >&2
        grep -A4 '^!' "$tmp/$name.out" >&2 || tail -20 "$tmp/$name.out" >&2
        exit 1
    fi
    pages="$(grep -o 'Output written on .*' "$tmp/$name.out" || true)"
    echo "paper-tex-check: $tex: ${pages:-no output}"
    n=$((n + 1))
done
[ "$n" -gt 0 ] || { echo "paper-tex-check: nothing to typeset in $paper" >&2; exit 1; }
echo "paper-tex-check: $n files typeset"
