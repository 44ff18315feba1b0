#!/usr/bin/env bash
# Per-vertex irradiance against Mitsuba 3 where a sun is hardest for the cube map (BENCHMARKS.md,
# "Per-vertex irradiance with the sun on a texel boundary"): the bundled bunny, white Lambertian,
# under each bundled sky with a sun, as bundled and turned about +Y so that the sun (the map's
# brightest pixel) sits on a vertical edge of its 6x32x32 texel and, where a turn can do it, on a
# horizontal edge (a side face's row coordinate is tan(elevation) / cos(azimuth), so the turn
# moves it too; a corner needs both at once, which one turn about +Y cannot give, so the two
# edges are taken one at a time). biscale's per-vertex `T L` (exact cosine, `biscale
# export-matrix`'s irradiance.csv) against Mitsuba's own irradiance at the vertices
# (scripts/mitsuba_check.py --vertex-samples, emitter sampling with its visibility rays; its
# noise from two independent halves). Nothing here is tuned; the turns are computed.
#
# Usage: scripts/sun-irradiance-study.sh [SKY...]  (default: the four bundled skies with a sun)
#   VERTEX_SAMPLES=65536 Mitsuba's samples per vertex. Needs Mitsuba 3 in .venv
#   (scripts/setup-python.sh --mitsuba). About a minute per sky and turn on 2 cores.
#   Writes out/sun-irradiance/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/lib/sky-study.sh
study_setup sun-irradiance "$@"
echo "| sky | sun | turn (deg) | per-vertex irradiance vs Mitsuba: exact cosine | paper's bin-mean cosine | Mitsuba's noise |"
echo "|---|---|---|---|---|---|"
for sky in "${skies[@]}"; do
    cfg=$out/$sky.toml
    {
        echo "# Written by scripts/sun-irradiance-study.sh: white Lambertian bunny under $sky."
        echo "name = \"sun-irradiance-$sky\""
        echo "seed = 1"
        echo "[scene]"
        echo "mesh = \"$root/assets/meshes/bunny.obj\""
        echo "[scene.material]"
        echo "kind = \"lambertian\""
        echo "albedo = [1.0, 1.0, 1.0]"
        echo "[lighting]"
        echo "env_map = \"$root/assets/envmaps/$sky.exr\""
        echo "[transfer]"
        echo "cubemap_resolution = 32"
        echo "visibility_resolution = 64"
        echo "local_grid = 8"
        echo "[[compressors]]"
        echo "kind = \"sparse\""
        echo "[runtime]"
        echo "light_moments = true"
        echo "repeats = 1"
        echo "[report]"
        echo "reference = false"
    } >"$cfg"
    # The turns (degrees; +t about +Y lowers the azimuth by t) that put the brightest pixel on a
    # vertical texel edge of its side face and on a horizontal one ("-" where no turn keeps it
    # on a side face), from the map's brightest pixel.
    read -r vertical horizontal <<<"$("$PY" - "$root/assets/envmaps/$sky.exr" <<'PY'
import sys, numpy as np, mitsuba as mi
mi.set_variant("scalar_rgb")
img = np.array(mi.Bitmap(sys.argv[1]).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False))
h, w, _ = img.shape
y, x = np.unravel_index(np.argmax(img @ np.array([0.2126, 0.7152, 0.0722])), (h, w))
rel = (360 * (x + 0.5) / w + 45) % 90 - 45  # azimuth from the side face's centre
el = 90 - 180 * (y + 0.5) / h
# Vertical edge: the face's column coordinate tan(rel) on a multiple of 1/16.
i = (np.tan(np.radians(rel)) + 1) * 16
vertical = rel - np.degrees(np.arctan(np.round(i) / 16 - 1))
# Horizontal edge: the row coordinate tan(el) / cos(rel') on a multiple of 1/16, for the
# nearest turn that keeps |rel'| <= 45 degrees.
best = None
for k in range(-16, 17):
    v = k / 16
    if v == 0 or np.sign(v) != np.sign(np.tan(np.radians(el))):
        continue
    c = np.tan(np.radians(el)) / v
    if not 0 < c <= 1:
        continue
    for r in (np.degrees(np.arccos(c)), -np.degrees(np.arccos(c))):
        if abs(r) <= 45 and (best is None or abs(rel - r) < abs(best)):
            best = rel - r
print(f"{vertical:.3f} {'-' if best is None else f'{best:.3f}'}")
PY
)"
    for which in bundled vertical horizontal; do
        case $which in
            bundled) rot=0 ;;
            vertical) rot=$vertical ;;
            horizontal) rot=$horizontal ;;
        esac
        [ "$rot" = "-" ] && { echo "| $sky | on a $which edge | - | no turn about +Y puts it there | | |"; continue; }
        o=$out/$sky-$which
        sets=(--set "lighting.rotation_degrees=$rot")
        "$B" -q export-matrix "$cfg" "${sets[@]}" --out "$o/scene" >/dev/null
        "$B" -q run "$cfg" "${sets[@]}" --out "$o/run" 2>/dev/null
        "$PY" scripts/mitsuba_check.py "$o/scene" "$o/run" --spp 16 --vertex-samples "${VERTEX_SAMPLES:-65536}" --json \
            2>/dev/null | sed -n '/^{/,$p' >"$o/mitsuba.json"
        "$PY" - "$o/mitsuba.json" "$sky" "$which" "$rot" <<'PY'
import json, sys
path, sky, which, rot = sys.argv[1:]
i = json.load(open(path))["irradiance"]
sun = "as bundled" if which == "bundled" else f"on a {which} texel edge"
print(f"| {sky} | {sun} | {float(rot):g} | {i['exact_cosine']:.4f} | {i['paper']:.4f} | {i['mitsuba_noise']:.4f} |")
PY
    done
done
