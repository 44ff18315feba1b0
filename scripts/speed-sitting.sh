#!/usr/bin/env bash
# The speed figures against the peers, measured side by side in one sitting on one machine
# (BENCHMARKS.md, "Speed against the peers in one sitting"): every row of the table a user
# weighs biscale by, each from the command printed above it.
#
#  1. the transfer stage and biscale's BVH against Mitsuba 3's `ray_test` (Embree) on the same
#     rays: the bundled bunny at 6x64x64 and the 30k-vertex bunny at 6x32x32
#     (scripts/ray_peer.py); and the transfer stage both ways (`transfer.visibility`,
#     coverage and rays) on both bunnies at the reference 6x64x64, with the rays where their
#     T differ (the `visibility_paths` example);
#  2. the RGB gathers against SciPy CSR `T @ L` on the bunny, 1 and 2 threads
#     (scripts/peer_bench.py);
#  3. the gathers on the 30k bunny against the memory-copy floor (the `gather_floor` example,
#     CPU only);
#  4. `biscale run configs/compare_bunny.toml --no-cache`: the whole comparison, cold;
#  5. the 30k bunny's transfer and lossless biclustering in `biscale run`, at the default
#     1024-vertex blocks and, in the same run, at 256-vertex blocks (faster to build, for
#     about 6% more bytes and flops).
#
# Needs .venv with Mitsuba and SciPy: bash scripts/setup-python.sh --mitsuba. Run on a quiet
# machine: every figure is wall-clock, and the load average is recorded before and after.
# About 12 minutes on 2 cores.
#
#   scripts/speed-sitting.sh [OUT]      (default out/speed-sitting; prints Markdown)
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in -h|--help) sed -n '2,22p' "$0"; exit 0 ;; esac
out=${1:-out/speed-sitting}
py=.venv/bin/python
if ! [ -x "$py" ] || ! "$py" -c "import mitsuba, scipy" 2>/dev/null; then
    echo "speed-sitting: needs Mitsuba 3 and SciPy in .venv: bash scripts/setup-python.sh --mitsuba" >&2
    exit 2
fi
mkdir -p "$out"
cargo build --release --locked -p biscale-cli --bin biscale -p biscale --example ray_peer --example peer_gather --example visibility_paths
cargo build --release --locked -p biscale-gpu --example gather_floor
B=target/release/biscale
l2=$(realpath "$out")/bunny-l2.obj
[ -f "$l2" ] || "$B" -q generate subdivide assets/meshes/bunny.obj --levels 2 --out "$l2"

load() { cut -d' ' -f1 /proc/loadavg; }
echo "# Speed against the peers in one sitting"
echo
echo "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) CPUs; commit $(git rev-parse --short HEAD); $(date -u +%Y-%m-%dT%H:%M:%SZ); load average $(load) at start"
step() { echo; echo "## $1"; echo; echo '```'; echo "$2"; echo '```'; echo; }

step "1. Rays: the bunny" "$py scripts/ray_peer.py assets/meshes/bunny.obj --rounds 3"
"$py" scripts/ray_peer.py assets/meshes/bunny.obj --rounds 3
step "1. Rays: the 30k bunny" "$py scripts/ray_peer.py $l2 --resolution 32 --rounds 1"
"$py" scripts/ray_peer.py "$l2" --resolution 32 --rounds 1
step "1. The transfer stage both ways, reference settings" "target/release/examples/visibility_paths assets/meshes/bunny.obj $l2 --rounds 1"
target/release/examples/visibility_paths assets/meshes/bunny.obj "$l2" --rounds 1

step "2. Gathers against SciPy" "$B export configs/bunny.toml --what t,l --out $out/bunny-export && $py scripts/peer_bench.py $out/bunny-export --no-sklearn"
rm -rf "$out/bunny-export"
"$B" -q export configs/bunny.toml --what t,l --out "$out/bunny-export"
"$py" scripts/peer_bench.py "$out/bunny-export" --no-sklearn

step "3. Gathers on the 30k bunny against the copy floor" "target/release/examples/gather_floor --mesh $l2 --no-gpu --runs 10"
target/release/examples/gather_floor --mesh "$l2" --no-gpu --runs 10

step "4. The whole comparison, cold" "$B -q run configs/compare_bunny.toml --no-cache --out $out/compare_bunny"
rm -rf "$out/compare_bunny"
"$B" -q run configs/compare_bunny.toml --no-cache --out "$out/compare_bunny" 2>"$out/compare_bunny.log"
python3 - "$out/compare_bunny/metrics.json" <<'PY'
import json, sys
c = json.load(open(sys.argv[1]))
stages = sorted(((s["stage"], s["wall_seconds"]) for s in c["run"]["stages"]), key=lambda kv: -kv[1])[:4]
print(f"compare_bunny, cold: {c['run']['wall_seconds']:.1f} s wall, {c['run']['cpu_seconds']:.1f} CPU-s, "
      f"load {c['load']['load_before']:.2f} to {c['load']['load_after']:.2f}; largest stages: "
      + ", ".join(f"{k} {v:.1f} s" for k, v in stages))
PY

l2_set=(--set "scene.mesh=\"$l2\"" --set 'scene.material={kind="lambertian", albedo=[0.8, 0.8, 0.8]}'
    --set 'compressors=[{kind="bicluster", block_vertices=1024}, {kind="bicluster", block_vertices=256}]'
    --set report.reference=false --set runtime.width=160 --set runtime.height=120)
step "5. The 30k bunny: transfer and lossless biclustering" "$B -q run configs/bunny.toml --no-cache $(printf '%q ' "${l2_set[@]}")--out $out/l2-bicluster"
rm -rf "$out/l2-bicluster"
"$B" -q run configs/bunny.toml --no-cache "${l2_set[@]}" --out "$out/l2-bicluster" 2>"$out/l2-bicluster.log"
python3 - "$out/l2-bicluster/metrics.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
t = m["transfer"]
print(f"30k bunny ({t['rows'] // t['local_dirs']} vertices): transfer {t['build_seconds']:.1f} s "
      f"({t['rays_per_second'] / 1e6:.1f} M rays/s); load {m['load']['load_before']:.2f} to {m['load']['load_after']:.2f}")
for b in m["compressors"]:
    print(f"  {b['name']}: lossless biclustering {b['build_seconds']:.1f} s, transfer + it "
          f"{t['build_seconds'] + b['build_seconds']:.1f} s; {b['bytes'] / 2**20:.2f} MiB, "
          f"{b['flops_per_gather'] / 1e6:.2f} Mflop, CPU gather {b['gather_ms']:.1f} ms")
PY

echo
echo "load average $(load) at end"
