#!/usr/bin/env bash
# The GPU check (issue 34, item 4): times every wgpu figure the paper reports and writes them
# as Markdown rows for BENCHMARKS.md, each labelled with the adapter wgpu reports, the commit
# and the date.
#
# What it times, on the bunny and on the temple (configs/paper/table1_{bunny,temple}.toml,
# Table I's scenes and settings, with CPCA 32x8, Haar 12 and Sloan et al.'s SH order 5, plain
# and CPCA-compressed, appended), by driving `biscale run --set runtime.backend="gpu"`:
#   * the GPU gather of every form: sparse (raw T), lossless bicluster, CPCA, Haar; SH order 5
#   * the light-moments gather + resolve (runtime.light_moments = true), per form
#   * BTF shading and SH RTT shading, at 640x480 and 1920x1080
#   * frame time for a view change (shade) and a light change (gather + shade) of the lossless
#     biclustering, at 640x480 and 1920x1080 (Table I's fps definitions, reproduce/facts.rs)
#   * both per-pixel resolves of light moments: the bunny with runtime.moments_resolve = "pixel"
#     at the first size, and configs/glossy_ggx_bunny.toml (a flat GGX conductor) with
#     "pixel_analytic" at both sizes, each row beside the frame-time model's projected floor
#   * and gpu/examples/gpu_bench.rs --real --all-kinds as a cross-check of the per-form gathers.
# The pipeline's CPU figures of the same runs stand beside them.
#
# Usage:
#   scripts/gpu-check.sh [--out DIR] [--budget SECONDS] [--repeats N] [--cache-dir DIR]
#                        [--allow-cpu-adapter] [--no-bench] [--build-only]
#   scripts/gpu-check.sh --small      # CI: tiny sizes on lavapipe, checks the script end to end
#
# On a GPU machine: `bash scripts/gpu-check.sh` (it builds the release `biscale` and the
# gpu_bench example first: a few minutes on 16 cores, about 8 on 2; `--build-only` does just
# that, so a machine with a per-command limit can build in one call and check in the next).
# The runs then take an estimated 2-4 minutes on 16 cores (not yet measured on a GPU machine:
# the CPU side dominates, tracing T, building the CPCA forms and shading the CPU images beside
# the GPU's) and are cut at --budget (default 480 s = 8 minutes; the build is not counted); a
# run cut short leaves its figures missing and the check failing.
# wgpu uses Vulkan only: the machine needs libvulkan1 and the GPU's Vulkan driver (for NVIDIA
# its ICD, nvidia_icd.json). The check refuses when wgpu finds no adapter, and when the only
# one is a CPU driver (lavapipe) unless --allow-cpu-adapter (implied by --small).
#
# --small: QUICK's sizes of `biscale reproduce --quick` (6x8x8 light, 6x16x16 visibility, 4x4
# local directions, 8x8-texel BTFs), SH order 3, images of 96x72 and 192x108, one repeat, a
# temporary stage cache (removed at the end), debug binaries. About a minute on a 2-core machine.
#
# Environment: BISCALE_BIN and GPU_BENCH_BIN use already-built binaries instead of building
# (CI: BISCALE_BIN=target/debug/biscale GPU_BENCH_BIN=target/debug/examples/gpu_bench).
#
# Writes only under DIR (default out/gpu-check, or out/gpu-check-small): rows.md (the rows,
# then any missing figure), figures.json, metrics/<run>.json, logs/<run>.log, configs/ (the
# derived configs) and runs/<run>/ (each biscale run, images included: about 0.5 GB at full
# size). It refuses a DIR that holds other files; on a rerun it replaces its own earlier
# output. Exit status: 0 every expected figure was produced, finite and positive; 1 some were
# not (rows.md lists them); 2 no usable adapter or bad arguments.
set -euo pipefail
caller=$PWD
cd "$(dirname "$0")/.."
root=$PWD
absolute() { case "$1" in /*) echo "$1" ;; *) echo "$caller/$1" ;; esac; } # paths given are the caller's
helper="$root/scripts/gpu_check_rows.py"

small=0 out="" budget="" repeats="" cache_dir="" allow_cpu=0 bench=1 build_only=0
while [ $# -gt 0 ]; do
    case "$1" in
        --small) small=1 ;;
        --out) out=$(absolute "${2:?--out needs a folder}"); shift ;;
        --budget) budget=${2:?--budget needs a number}; shift ;;
        --repeats) repeats=${2:?--repeats needs a number}; shift ;;
        --cache-dir) cache_dir=$(absolute "${2:?--cache-dir needs a folder}"); shift ;;
        --allow-cpu-adapter) allow_cpu=1 ;;
        --no-bench) bench=0 ;;
        --build-only) build_only=1 ;;
        -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "gpu-check: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
    shift
done

say() { echo "gpu-check: $*" >&2; }
started=$(date +%s)

if [ $small = 1 ]; then
    mode=small profile=debug cargo_profile=() allow_cpu=1
    out=${out:-out/gpu-check-small} budget=${budget:-300} repeats=${repeats:-1}
    sizes=(96x72 192x108) sh_order=3
else
    mode=full profile=release cargo_profile=(--release)
    out=${out:-out/gpu-check} budget=${budget:-480} repeats=${repeats:-10}
    sizes=(640x480 1920x1080) sh_order=5
fi
case "$budget$repeats" in *[!0-9]*) echo "gpu-check: --budget and --repeats take whole numbers" >&2; exit 2 ;; esac

# --- the output folder: ours alone ----------------------------------------------------------
if [ $build_only = 0 ]; then
    if [ -d "$out" ] && [ -n "$(ls -A "$out")" ] && [ ! -f "$out/.gpu-check" ]; then
        say "refusing to write into $out: it holds files this script did not write (pass --out to another folder)"
        exit 2
    fi
    mkdir -p "$out"
    out=$(cd "$out" && pwd)
    echo "scripts/gpu-check.sh writes this folder; a rerun replaces what it holds" >"$out/.gpu-check"
    rm -rf "$out/logs" "$out/metrics" "$out/configs" "$out/rows.md" "$out/figures.json"
    mkdir -p "$out/logs" "$out/metrics" "$out/configs" "$out/runs"
fi

# --- build (unless given binaries) --------------------------------------------------------
target=${CARGO_TARGET_DIR:-$root/target}
BISCALE_BIN=${BISCALE_BIN:+$(absolute "$BISCALE_BIN")}
GPU_BENCH_BIN=${GPU_BENCH_BIN:+$(absolute "$GPU_BENCH_BIN")}
if [ -z "$BISCALE_BIN" ]; then
    say "building biscale ($profile): cargo build ${cargo_profile[*]:+${cargo_profile[*]} }--locked -p biscale-cli --bin biscale"
    cargo build "${cargo_profile[@]}" --locked -p biscale-cli --bin biscale
    BISCALE_BIN=$target/$profile/biscale
fi
if [ $bench = 1 ] && [ -z "$GPU_BENCH_BIN" ]; then
    say "building gpu_bench ($profile): cargo build ${cargo_profile[*]:+${cargo_profile[*]} }--locked -p biscale-gpu --example gpu_bench"
    cargo build "${cargo_profile[@]}" --locked -p biscale-gpu --example gpu_bench
    GPU_BENCH_BIN=$target/$profile/examples/gpu_bench
fi
built=$(date +%s)
say "binaries ready in $((built - started)) s: $BISCALE_BIN${GPU_BENCH_BIN:+, $GPU_BENCH_BIN}"
[ $build_only = 1 ] && exit 0
[ $bench = 1 ] || GPU_BENCH_BIN=""
for b in "$BISCALE_BIN" ${GPU_BENCH_BIN:+"$GPU_BENCH_BIN"}; do
    [ -x "$b" ] || { say "not an executable: $b"; exit 2; }
done

if [ -z "$cache_dir" ] && [ $small = 1 ]; then
    cache_dir=$(mktemp -d "${TMPDIR:-/tmp}/gpu-check-cache.XXXXXX")
    trap 'rm -rf "$cache_dir"' EXIT
fi
cache_args=()
[ -n "$cache_dir" ] && cache_args=(--cache-dir "$cache_dir")

# --- the configs: Table I's scenes with every form and the SH method appended ----------------
forms='[[compressors]]
kind = "cpca"
clusters = 32
components = 8

[[compressors]]
kind = "haar"
terms = 12
'
sh_methods="
[[methods]]
kind = \"sh\"
order = $sh_order

[[methods]]
kind = \"sh\"
order = $sh_order
compressor = { kind = \"cpca\", clusters = 32, components = 8, unit = \"vertex\" }
"
sh_labels=sh-n$sh_order,sh-n$sh_order-cpca-k32-c8-vertex # the labels biscale gives them
scenes=(bunny temple)
for s in "${scenes[@]}"; do
    python3 "$helper" derive "configs/paper/table1_$s.toml" "$out/configs/$s.toml" <<<"$forms$sh_methods"
    python3 "$helper" derive "configs/paper/table1_$s.toml" "$out/configs/$s-forms.toml" <<<"$forms"
done

# Every run's overrides; --small adds `biscale reproduce --quick`'s (reproduce/items.rs).
common=(--set 'runtime.backend="gpu"' --set "runtime.repeats=$repeats" --set report.reference=false)
declare -A quick
if [ $small = 1 ]; then
    common+=(--set transfer.cubemap_resolution=8 --set transfer.visibility_resolution=16
        --set transfer.local_grid=4)
    quick[bunny]="scene.material.resolution=8 scene.material.view_grid=4"
    quick[temple]="scene.materials.0.resolution=8 scene.materials.1.resolution=8 scene.materials.1.view_grid=4
        scene.materials.2.resolution=8 scene.materials.2.view_grid=4 scene.materials.3.view_grid=4
        scene.materials.4.resolution=8 scene.materials.4.view_grid=4"
fi
scene_args() { # SCENE -> its --set pairs, one per line
    local kv
    for kv in ${quick[$1]:-}; do printf -- '--set\n%s\n' "$kv"; done
}

# --- run steps within the budget --------------------------------------------------------------
deadline=$((built + budget))
step=0
steps=$((1 + 3 * ${#scenes[@]} + 3 + bench)) # the probe; per scene two sizes and the moments; the per-pixel resolves; gpu_bench
run_step() { # NAME COMMAND... : run with what is left of the budget, log to logs/NAME.log
    local name=$1 t0 rc=0 left
    shift
    step=$((step + 1))
    left=$((deadline - $(date +%s)))
    if [ $left -lt 5 ]; then
        say "[$step/$steps] $name: skipped, the budget of $budget s is spent"
        echo "skipped: budget spent" >"$out/logs/$name.log"
        return 1
    fi
    say "[$step/$steps] $name ... (budget left $left s)"
    t0=$(date +%s)
    timeout -k 10 "$left" "$@" >"$out/logs/$name.log" 2>&1 || rc=$?
    if [ $rc = 0 ]; then
        say "[$step/$steps] $name: done in $(($(date +%s) - t0)) s"
    else
        [ $rc = 124 ] && say "[$step/$steps] $name: cut at the budget ($budget s)" ||
            say "[$step/$steps] $name: FAILED (exit $rc) after $(($(date +%s) - t0)) s; from logs/$name.log:"
        { grep -E '^(error|Error|thread .* panicked)' "$out/logs/$name.log" || tail -n 8 "$out/logs/$name.log"; } |
            tail -n 8 | cut -c 1-400 | sed 's/^/    /' >&2
    fi
    return $rc
}

biscale_run() { # NAME SCENE CONFIG SIZE [--set ...]: one `biscale run` into runs/NAME
    local name=$1 scene=$2 config=$3 size=$4
    shift 4
    rm -rf "$out/runs/$name"
    local extra=()
    mapfile -t extra < <(scene_args "$scene")
    if ! run_step "$name" "$BISCALE_BIN" run "$config" --out "$out/runs/$name" "${cache_args[@]}" "${common[@]}" \
        "${extra[@]}" --set "runtime.width=${size%x*}" --set "runtime.height=${size#*x}" "$@"; then
        rm -rf "$out/runs/.$name.staging-"* # what a run cut at the budget leaves
    fi
    [ -f "$out/runs/$name/metrics.json" ] && cp "$out/runs/$name/metrics.json" "$out/metrics/$name.json"
    return 0
}

# --- the adapter: a tiny run first, so a machine without a GPU is refused in seconds ----------
if ! run_step probe "$BISCALE_BIN" run configs/paper/table1_bunny.toml --out "$out/runs/probe" "${cache_args[@]}" \
    --set 'runtime.backend="gpu"' --set runtime.repeats=1 --set report.reference=false \
    --set transfer.cubemap_resolution=8 --set transfer.visibility_resolution=16 --set transfer.local_grid=4 \
    --set runtime.width=32 --set runtime.height=24 --set scene.material.resolution=8 --set scene.material.view_grid=4; then
    if grep -q "no GPU adapter found" "$out/logs/probe.log"; then
        say "REFUSED: wgpu found no adapter (it uses Vulkan only). Vulkan drivers (ICDs) present:"
        ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | sed 's/^/    /' >&2 || true
        say "install the GPU's Vulkan driver (NVIDIA: its ICD, nvidia_icd.json) and libvulkan1, or scripts/setup-vulkan.sh for lavapipe"
    else
        say "REFUSED: the probe run failed or did not run (logs/probe.log); no figures were timed"
    fi
    exit 2
fi
adapter=$(python3 "$helper" adapter "$out/runs/probe")
say "wgpu adapter: $adapter"
if echo "$adapter" | grep -Eqi 'llvmpipe|lavapipe|softpipe|swiftshader'; then
    if [ $allow_cpu = 0 ]; then
        say "REFUSED: the only adapter wgpu found is a CPU driver ($adapter), not a GPU."
        say "  A GPU's Vulkan driver is missing? ICDs present: $(ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | tr '\n' ' ')"
        command -v nvidia-smi >/dev/null && say "  nvidia-smi -L: $(nvidia-smi -L 2>&1 | head -n 2 | tr '\n' ' ')"
        say "  pass --allow-cpu-adapter to time it anyway (or --small for CI sizes)"
        exit 2
    fi
    say "note: a CPU adapter: these are lavapipe figures, not GPU figures"
fi

# --- the runs, most wanted first ----------------------------------------------------------------
rows_args=()
for s in "${scenes[@]}"; do
    biscale_run "$s-${sizes[0]}" "$s" "$out/configs/$s.toml" "${sizes[0]}"
    rows_args+=(--run "$s" main "${sizes[0]}" "$out/runs/$s-${sizes[0]}")
done
for s in "${scenes[@]}"; do
    biscale_run "$s-moments" "$s" "$out/configs/$s-forms.toml" "${sizes[0]}" --set runtime.light_moments=true
    rows_args+=(--run "$s" moments "${sizes[0]}" "$out/runs/$s-moments")
done
for s in "${scenes[@]}"; do
    biscale_run "$s-${sizes[1]}" "$s" "$out/configs/$s.toml" "${sizes[1]}"
    rows_args+=(--run "$s" main "${sizes[1]}" "$out/runs/$s-${sizes[1]}")
done
# The per-pixel resolves: the bunny's tables ("pixel"), the glossy bunny's GGX ("pixel_analytic").
biscale_run "bunny-pixel" bunny "$out/configs/bunny-forms.toml" "${sizes[0]}" --set runtime.light_moments=true \
    --set 'runtime.moments_resolve="pixel"'
rows_args+=(--run bunny pixel "${sizes[0]}" "$out/runs/bunny-pixel")
[ $small = 1 ] && quick[glossy]="scene.material.resolution=8 scene.material.view_grid=4"
for size in "${sizes[@]}"; do
    biscale_run "glossy-pixel_analytic-$size" glossy configs/glossy_ggx_bunny.toml "$size" \
        --set 'runtime.moments_resolve="pixel_analytic"'
    rows_args+=(--run glossy pixel "$size" "$out/runs/glossy-pixel_analytic-$size")
done
if [ $bench = 1 ]; then
    if [ $small = 1 ]; then # a random T of the bunny's vertices at 2x2 local directions
        bench_args=(--local 2 --texels 8 --width 96 --height 72 --reps 1 --all-kinds)
    else
        bench_args=(--real --all-kinds --reps "$repeats")
    fi
    run_step gpu_bench "$GPU_BENCH_BIN" "${bench_args[@]}" || true
    rows_args+=(--bench "$out/logs/gpu_bench.log")
fi

# --- the rows -------------------------------------------------------------------------------------
rc=0
python3 "$helper" rows --out "$out" --mode "$mode" --sh "$sh_labels" "${rows_args[@]}" \
    --commit "$(git rev-parse HEAD 2>/dev/null || echo unknown)" >/dev/null || rc=$?
cat "$out/rows.md"
say "wrote $out/rows.md and $out/figures.json in $(($(date +%s) - started)) s ($(($(date +%s) - built)) s after the build)"
if [ $rc != 0 ]; then
    say "FAILED: some expected figures are missing or not positive (listed at the end of rows.md)"
    exit 1
fi
say "every expected figure was produced"
