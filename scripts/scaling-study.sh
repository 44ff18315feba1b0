#!/usr/bin/env bash
# The sharded precompute's scaling study (BENCHMARKS.md, "Sharded precompute"): subdivided
# bunnies (and the temple) at the paper's reference settings (cubemap 6x32x32, visibility
# 6x64x64, 8x8 local directions, lossless biclustering in 1024-vertex blocks), split into
# shards that run as local processes (`xargs -P`, one thread each, as a one-CPU Slurm array
# task would), merged, and summarized per stage.
#
# Usage: scripts/scaling-study.sh [MESH:SHARDS ...]
#   MESH is bunny-l1 | bunny-l2 | bunny-l3 | bunny-l4 | temple-l1 (the bundled mesh midpoint-
#   subdivided that many times); SHARDS a shard count. Default: bunny-l2:8 bunny-l2:32.
#   SINGLE=1 also runs the same config as one `biscale run` (for the CPU-time comparison).
#   SHARDS_ONLY=K runs only the first K shards and skips the merge (for meshes whose merge
#   does not fit this machine: the shards' figures still extrapolate).
#   JOBS=N local processes at once (default: the core count).
# Writes out/scaling/<mesh>-s<shards>/ (manifest, shards, merged run, logs) and appends one
# line per run to out/scaling/summary.tsv. Needs python3 for the summary.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
out=$root/out/scaling
mkdir -p "$out/meshes"
jobs=${JOBS:-$(nproc)}
cargo build --release --locked -p biscale-cli --bin biscale
B=$root/target/release/biscale

mesh_of() { # NAME -> path of the generated mesh
    local name=$1 base levels
    base=${name%-l*}
    levels=${name##*-l}
    local path=$out/meshes/$name.obj
    if [ ! -f "$path" ]; then
        "$B" generate subdivide "assets/meshes/$base.obj" --levels "$levels" --out "$path" >&2
    fi
    echo "$path"
}

config_of() { # NAME MESH -> path of the study config
    local name=$1 mesh=$2 cfg=$out/$1.toml
    cat >"$cfg" <<EOF
# Written by scripts/scaling-study.sh: the paper's reference settings on $name.
name = "scaling-$name"
seed = 1
[scene]
mesh = "$mesh"
[scene.material]
kind = "lambertian"
albedo = [0.8, 0.8, 0.8]
[lighting]
env_map = "$root/assets/envmaps/blender_forest.exr"
[transfer]
cubemap_resolution = 32
visibility_resolution = 64
local_grid = 8
[[compressors]]
kind = "bicluster"
block_vertices = 1024
[runtime]
width = 256
height = 192
repeats = 1
[report]
reference = false
EOF
    echo "$cfg"
}

now() { date +%s.%N; }

runs=("$@")
[ ${#runs[@]} -eq 0 ] && runs=(bunny-l2:8 bunny-l2:32)
for run in "${runs[@]}"; do
    name=${run%%:*}
    shards=${run##*:}
    mesh=$(mesh_of "$name")
    cfg=$(config_of "$name" "$mesh")
    dir=$out/$name-s$shards
    rm -rf "$dir"
    mkdir -p "$dir/logs"
    echo "== $name, $shards shards ($(grep -c '^v ' "$mesh") vertices), $jobs processes at once"
    "$B" shard plan "$cfg" --shards "$shards" --out "$dir/shards" | tee "$dir/logs/plan.txt"
    count=${SHARDS_ONLY:-$shards}
    t0=$(now)
    seq 0 $((count - 1)) | RAYON_NUM_THREADS=1 xargs -P "$jobs" -I{} \
        sh -c "'$B' shard run '$dir/shards/manifest.json' --index {} >'$dir/logs/shard-{}.log' 2>&1 || { echo 'shard {} failed:'; tail -5 '$dir/logs/shard-{}.log'; exit 255; }"
    t1=$(now)
    merge_wall=nan merge_rss=nan
    if [ -z "${SHARDS_ONLY:-}" ]; then
        /usr/bin/time -f '%e %M' -o "$dir/logs/merge.time" \
            "$B" shard merge "$dir/shards/manifest.json" --out "$dir/merged" --no-cache 2>"$dir/logs/merge.log"
        read -r merge_wall merge_rss <"$dir/logs/merge.time"
        merge_rss=$((merge_rss * 1024))
    fi
    single_wall=nan single_cpu=nan single_rss=nan
    if [ -n "${SINGLE:-}" ]; then
        /usr/bin/time -f '%e %U %S %M' -o "$dir/logs/single.time" \
            "$B" run "$cfg" --out "$dir/single" --no-cache 2>"$dir/logs/single.log"
        read -r single_wall u s single_rss <"$dir/logs/single.time"
        single_cpu=$(python3 -c "print($u + $s)")
        single_rss=$((single_rss * 1024))
    fi
    python3 - "$dir" "$name" "$shards" "$count" "$(python3 -c "print($t1 - $t0)")" "$merge_wall" "$merge_rss" \
        "$single_wall" "$single_cpu" "$single_rss" "$jobs" >>"$out/summary.tsv" <<'PY'
import json, sys, glob, os
d, name, shards, count, shard_wall, merge_wall, merge_rss, single_wall, single_cpu, single_rss, jobs = sys.argv[1:]
m = json.load(open(f"{d}/shards/manifest.json"))
done = [json.load(open(p)) for p in sorted(glob.glob(f"{d}/shards/shards/*/done.json"))]
verts = sum(x["end_vertex"] - x["first_vertex"] for x in done)
nnz = sum(x["nnz"] for x in done)
rays = sum(x["rays_traced"] for x in done)
t_tr = sum(x["transfer_seconds"] for x in done)
t_bc = sum(s for x in done for _, s in x["compressor_seconds"])
cpu = sum(x["cpu_seconds"] or 0 for x in done)
rss = [(x["end_vertex"] - x["first_vertex"], x["peak_rss_bytes"]) for x in done]
flops = bpn = merge_load = float("nan")
mp = f"{d}/merged/metrics.json"
if os.path.exists(mp):
    mm = json.load(open(mp))
    c = mm["compressors"][0]
    flops = c["flops_per_gather"] / (2 * mm["transfer"]["nnz"])
    bpn = c["bytes_per_nnz"]
    merge_load = mm["sharded"]["merge_load_seconds"]
row = [name, m["vertices"], shards, count, verts, nnz, rays, f"{rays / t_tr:.4g}", f"{t_tr:.1f}", f"{t_bc:.1f}",
       f"{cpu:.1f}", f"{float(shard_wall):.1f}", max(r for _, r in rss), min(r for _, r in rss),
       max(v for v, _ in rss), f"{flops:.4f}", f"{bpn:.3f}", f"{merge_load:.2f}", merge_wall, merge_rss,
       single_wall, single_cpu, single_rss, jobs]
print("\t".join(str(x) for x in row))
PY
    tail -1 "$out/summary.tsv"
done
echo "columns: mesh vertices shards shards_run vertices_run nnz rays rays_per_cpu_s transfer_s bicluster_s shard_cpu_s shard_wall_s shard_rss_max shard_rss_min shard_vertices_max flops_ratio bytes_per_nnz merge_load_s merge_wall_s merge_rss single_wall_s single_cpu_s single_rss jobs"
