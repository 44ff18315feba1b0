#!/usr/bin/env bash
# `cargo package` for the library crates, as CI runs it: every library crate must package (its
# manifest complete, path dependencies versioned, no file included from outside the crate),
# and the crates at the bottom of the graph are also built from their packaged sources.
# (The others are packaged without that build: it would compile wgpu once more, minutes on
# two cores, for what their own tests already build.)
set -euo pipefail
cd "$(dirname "$0")/.."
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
package() {
    # cargo's advice on missing documentation/homepage metadata is left out of the log.
    if ! cargo package --allow-dirty "$@" >"$log" 2>&1; then
        cat "$log"
        echo "package: failed: cargo package $*" >&2
        exit 1
    fi
    grep -v "manifest has no\|^  |\|^  = note" "$log" | grep -E "Packag|Verif|error" || true
}
libs=(biscale-kernels biscale-core biscale-plugin-api biscale-compressors biscale-shading biscale-gpu)
args=()
for l in "${libs[@]}"; do args+=(-p "$l"); done
echo "package: ${libs[*]} (without building)"
package --no-verify "${args[@]}"
echo "package: biscale-kernels biscale-core biscale-plugin-api (built from the packaged sources)"
package -p biscale-kernels -p biscale-core -p biscale-plugin-api
