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
# cargo unpacks the packaged crates into $CARGO_HOME/registry/src/<hash of this checkout's path>/
# and never unpacks a name-version pair again once that folder exists, so a second checkout at the
# same path (CI's) would build against the sources of an earlier commit. No biscale crate comes
# from crates.io: every such folder is one of these stale copies. The verifying build gets a target
# folder of its own, emptied first: cargo takes a compiled registry crate of the same version to be
# unchanged, so the workspace's target folder could hold one built from an earlier commit.
registry_src="${CARGO_HOME:-$HOME/.cargo}/registry/src"
for stale in "$registry_src"/*/biscale-*; do
    [[ -d "$stale" ]] && rm -rf "$stale"
done
rm -rf target/package-verify
echo "package: biscale-kernels biscale-core biscale-plugin-api (built from the packaged sources)"
package --target-dir target/package-verify -p biscale-kernels -p biscale-core -p biscale-plugin-api
