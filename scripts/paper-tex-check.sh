#!/usr/bin/env bash
# Typeset what `biscale reproduce` writes as a journal would: every tables/*.tex and
# figures/*.tex of a paper folder, each \input into a portrait A4 article at a 17 cm text width
# (a two-column journal's full-width floats: TVCG's `table*`), then the folder's own paper.tex
# (all of them, in the page's order), each through pdflatex in batch mode. It fails when LaTeX
# rejects a table or caption, and when any line is wider than the text (an overfull box: a
# table falling off the page, a caption word that cannot break). CI runs it on a
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

# pdflatex SOURCE NAME: typeset SOURCE (run from the paper folder, whose paths the figures
# use) into $tmp; exit 1 with LaTeX's message when it fails or sets a line wider than the text.
typeset() {
    local src=$1 name=$2 log
    if ! (cd "$paper" && pdflatex -interaction=nonstopmode -halt-on-error -output-directory "$tmp" -jobname "$name" "$src" > "$tmp/$name.out" 2>&1); then
        echo "paper-tex-check: $3 does not typeset:" >&2
        grep -A4 '^!' "$tmp/$name.out" >&2 || tail -20 "$tmp/$name.out" >&2
        exit 1
    fi
    log="$tmp/$name.log"
    if grep -q '^Overfull \\hbox' "$log"; then
        echo "paper-tex-check: $3 sets $(grep -c '^Overfull \\hbox' "$log") line(s) wider than the ${width} text:" >&2
        grep -A2 '^Overfull \\hbox' "$log" >&2
        exit 1
    fi
    echo "paper-tex-check: $3: $(grep -o 'Output written on .*' "$tmp/$name.out" || echo 'no output')"
}

width=17cm
n=0
for tex in "$paper"/tables/*.tex "$paper"/figures/*.tex; do
    [ -e "$tex" ] || continue
    name="$(basename "$(dirname "$tex")")-$(basename "$tex" .tex)"
    cat > "$tmp/$name-doc.tex" <<TEX
\documentclass{article}
\usepackage[a4paper,textwidth=$width]{geometry}
\usepackage{booktabs}
\usepackage{graphicx}
\begin{document}
\input{$tex}
\end{document}
TEX
    typeset "$tmp/$name-doc.tex" "$name" "$tex"
    n=$((n + 1))
done
[ "$n" -gt 0 ] || { echo "paper-tex-check: nothing to typeset in $paper" >&2; exit 1; }
[ -e "$paper/paper.tex" ] || { echo "paper-tex-check: $paper has no paper.tex" >&2; exit 1; }
typeset "$paper/paper.tex" paper "$paper/paper.tex"
echo "paper-tex-check: $n files typeset alone and together in paper.tex, none wider than $width"
