#!/usr/bin/env bash
# The light-moments study (BENCHMARKS.md, "Light moments"): the bundled bunny, white
# Lambertian (albedo 1), under every bundled sky and one with its brightest texel boosted into
# a sun, rendered with `[runtime] light_moments = true`. Each run also keeps the paper's
# bin-mean-cosine image, so the summary gives, side by side, both uncompressed images against
# the per-pixel exact-cosine reference (same T visibility, each texel's own cosine at the
# pixel normal), the paper's image against the moments' one, and the lossless and lossy
# biclusterings' errors. Then `moments_bench` times the plain gather against the moments
# gather for every built-in compressor.
#
# The glossy case: configs/glossy_ggx_bunny.toml, the bunny as a flat GGX rough conductor
# (aluminium-like, alpha 0.15) under the forest sky (the brightest compact sun), raw sparse and
# lossless bicluster compressors; its row in the first table has no lossy bicluster. It runs
# twice: as configured (the BTF's tables, 8x8 bins) and with `moments_resolve = "pixel_analytic"`
# on 16x16 bins (the GGX BRDF itself at each bin's mean direction, shaded per pixel).
#
# With Mitsuba 3 in .venv (scripts/setup-python.sh --mitsuba) every run without a boosted sun is
# also checked against Mitsuba's direct-light render (scripts/mitsuba_check.py, 1024 spp, two
# seeds); the glossy case in a table of its own, with Mitsuba's image noise (its per-vertex
# irradiance check is for Lambertian materials only).
#
# Usage: scripts/moments-study.sh            (about 10 minutes on 2 cores with the Mitsuba check)
#   SKIP_BENCH=1 leaves out the gather timing; SKIP_MITSUBA=1 the Mitsuba check;
#   REUSE=1 keeps runs already in out/moments; TEXEL_DIRECTIONS=mean takes every texel's light
#   from the mean direction of its pixels (`[lighting] texel_directions`), default centre (the
#   rule BENCHMARKS' light-moments figures were measured with).
# Writes out/moments/<sky>/ (one run each), out/moments/glossy-ggx/ and glossy-ggx-analytic/,
# and prints Markdown tables.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
out=$root/out/moments
mkdir -p "$out"
cargo build --release --locked -p biscale-cli --bin biscale
B=$root/target/release/biscale

run_sky() { # NAME ENVMAP [SUN_BOOST]
    local name=$1 env=$2 boost=${3:-} cfg=$out/$1.toml
    {
        echo "# Written by scripts/moments-study.sh: white Lambertian bunny under $env${boost:+, brightest texel x$boost}."
        echo "name = \"moments-$name\""
        echo "seed = 1"
        echo "[scene]"
        echo "mesh = \"$root/assets/meshes/bunny.obj\""
        echo "[scene.material]"
        echo "kind = \"lambertian\""
        echo "albedo = [1.0, 1.0, 1.0]"
        echo "[lighting]"
        echo "env_map = \"$root/assets/envmaps/$env\""
        echo "texel_directions = \"${TEXEL_DIRECTIONS:-centre}\""
        [ -n "$boost" ] && echo "sun_boost = $boost"
        echo "[transfer]"
        echo "cubemap_resolution = 32"
        echo "visibility_resolution = 64"
        echo "local_grid = 8"
        echo "[[compressors]]"
        echo "kind = \"bicluster\""
        echo "block_vertices = 1024"
        echo "[[compressors]]"
        echo "kind = \"bicluster\""
        echo "error_budget = 0.1"
        echo "[runtime]"
        echo "width = 320"
        echo "height = 240"
        echo "repeats = 3"
        echo "light_moments = true"
        echo "[runtime.camera]"
        echo "azimuth_degrees = 25.0"
        echo "elevation_degrees = 15.0"
        echo "fov_y_degrees = 30.0"
        echo "[report]"
        echo "reference = true"
        echo "reference_downscale = 2"
    } >"$cfg"
    echo "== $name" >&2
    if [ -n "${REUSE:-}" ] && [ -f "$out/$name/metrics.json" ]; then return; fi
    "$B" run "$cfg" --out "$out/$name" 2>"$out/$name.log" || { cat "$out/$name.log" >&2; exit 1; }
}

run_sky courtyard blender_courtyard.exr
run_sky forest blender_forest.exr
run_sky studio blender_studio.exr
run_sky sunset blender_sunset.exr
run_sky apartment pmndrs_apartment.exr
run_sky sunset-sun1e3 blender_sunset.exr 1000

glossy_cfg=$root/configs/glossy_ggx_bunny.toml
echo "== glossy-ggx" >&2
if [ -z "${REUSE:-}" ] || [ ! -f "$out/glossy-ggx/metrics.json" ]; then
    "$B" run "$glossy_cfg" --set "lighting.texel_directions=\"${TEXEL_DIRECTIONS:-centre}\"" --out "$out/glossy-ggx" \
        2>"$out/glossy-ggx.log" || { cat "$out/glossy-ggx.log" >&2; exit 1; }
fi
# The same scene resolved per pixel with the GGX BRDF itself (no BTF tables) on 16x16 bins:
# the setting of BENCHMARKS' "analytic resolve" rows.
analytic_sets=(--set 'runtime.moments_resolve="pixel_analytic"' --set transfer.local_grid=16 --set scene.material.view_grid=32
    --set "lighting.texel_directions=\"${TEXEL_DIRECTIONS:-centre}\"")
echo "== glossy-ggx-analytic" >&2
if [ -z "${REUSE:-}" ] || [ ! -f "$out/glossy-ggx-analytic/metrics.json" ]; then
    "$B" run "$glossy_cfg" "${analytic_sets[@]}" --out "$out/glossy-ggx-analytic" 2>"$out/glossy-ggx-analytic.log" ||
        { cat "$out/glossy-ggx-analytic.log" >&2; exit 1; }
fi

python3 - "$out" <<'PY'
import json, sys, os
out = sys.argv[1]
print("| sky | paper vs moments (image) | uncompressed vs reference: paper | with moments | lossless bicluster vs reference | lossy bicluster (10%) vs reference | moments gather / ms (lossless) |")
print("|---|---|---|---|---|---|---|")
for name in ["courtyard", "forest", "studio", "sunset", "apartment", "sunset-sun1e3"]:
    m = json.load(open(os.path.join(out, name, "metrics.json")))
    u, r = m["uncompressed"], m["reference"]
    cs = m["compressors"]
    vs = lambda c: c["image"]["vs_reference"]["rel_l2"]
    print(f"| {name} | {u['paper_vs_moments']['rel_l2']:.4f} | {r['uncompressed_paper_vs_reference']['rel_l2']:.4f} "
          f"| {r['uncompressed_vs_reference']['rel_l2']:.4f} | {vs(cs[0]):.4f} | {vs(cs[1]):.4f} | {cs[0]['gather_ms']:.2f} |")
# The glossy case (configs/glossy_ggx_bunny.toml), with the tables and with the analytic
# resolve: its compressors are sparse and the lossless bicluster, found by name; no lossy one.
for name, label in [("glossy-ggx", "glossy-ggx (GGX Al, forest)"),
                    ("glossy-ggx-analytic", "glossy-ggx, analytic resolve, 16x16 bins")]:
    m = json.load(open(os.path.join(out, name, "metrics.json")))
    u, r = m["uncompressed"], m["reference"]
    c = {x["name"]: x for x in m["compressors"]}["bicluster-b1024"]
    print(f"| {label} | {u['paper_vs_moments']['rel_l2']:.4f} | {r['uncompressed_paper_vs_reference']['rel_l2']:.4f} "
          f"| {r['uncompressed_vs_reference']['rel_l2']:.4f} | {c['image']['vs_reference']['rel_l2']:.4f} | - | {c['gather_ms']:.2f} |")
PY
if [ -z "${SKIP_MITSUBA:-}" ] && [ -x .venv/bin/python ] && .venv/bin/python -c "import mitsuba" 2>/dev/null; then
    echo
    echo "| sky | Mitsuba 3 vs paper: full frame | interior | vs moments: full frame | interior | lossy bicluster (moments): interior | per-vertex irradiance: paper | moments | (Mitsuba noise) |"
    echo "|---|---|---|---|---|---|---|---|---|"
    for name in courtyard forest studio sunset apartment; do
        "$B" export-matrix "$out/$name.toml" --out "$out/$name-scene" >/dev/null 2>&1
        .venv/bin/python scripts/mitsuba_check.py "$out/$name-scene" "$out/$name" --spp 1024 --vertex-samples 65536 --json \
            >"$out/$name-mitsuba.json"
    done
    python3 - "$out" <<'PY'
import json, os, sys
for name in ["courtyard", "forest", "studio", "sunset", "apartment"]:
    o = json.load(open(os.path.join(sys.argv[1], name + "-mitsuba.json")))
    r = {x["image"]: x for x in o["rows"]}
    p, m, l = r["uncompressed_paper"], r["uncompressed"], r["bicluster-e0.1"]
    i = o["irradiance"] or {"paper": float("nan"), "exact_cosine": float("nan"), "mitsuba_noise": float("nan")}
    print(f"| {name} | {p['full_frame']:.4f} | {p['interior']:.4f} | {m['full_frame']:.4f} | {m['interior']:.4f} | {l['interior']:.4f} "
          f"| {i['paper']:.4f} | {i['exact_cosine']:.4f} | {i['mitsuba_noise']:.4f} |")
PY
    "$B" export-matrix "$glossy_cfg" --out "$out/glossy-ggx-scene" >/dev/null 2>&1
    for name in glossy-ggx glossy-ggx-analytic; do
        .venv/bin/python scripts/mitsuba_check.py "$out/glossy-ggx-scene" "$out/$name" --spp 1024 --json >"$out/$name-mitsuba.json"
    done
    echo
    echo "| glossy case | Mitsuba 3 vs paper: full frame | interior | vs moments: full frame | interior | lossless bicluster (moments): interior | Mitsuba noise (mean of 2 seeds): full frame | interior |"
    echo "|---|---|---|---|---|---|---|---|"
    python3 - "$out" <<'PY'
import json, os, sys
for name, label in [("glossy-ggx", "glossy-ggx (GGX Al, forest)"),
                    ("glossy-ggx-analytic", "glossy-ggx, analytic resolve, 16x16 bins")]:
    o = json.load(open(os.path.join(sys.argv[1], name + "-mitsuba.json")))
    r = {x["image"]: x for x in o["rows"]}
    p, m, l, n = r["uncompressed_paper"], r["uncompressed"], r["bicluster-b1024"], o["mitsuba_noise"]
    print(f"| {label} | {p['full_frame']:.4f} | {p['interior']:.4f} | {m['full_frame']:.4f} | {m['interior']:.4f} "
          f"| {l['interior']:.4f} | {n['full_frame']:.4f} | {n['interior']:.4f} |")
PY
fi
if [ -z "${SKIP_BENCH:-}" ]; then
    cargo run --release --locked -p biscale-compressors --example moments_bench -- --rounds 21
fi
