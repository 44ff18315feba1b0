#!/usr/bin/env bash
# Where the vertex resolve's light goes (BENCHMARKS.md, "Why the vertex resolve is dark at
# 16x16 bins"): the glossy GGX bunny (configs/glossy_ggx_bunny.toml) at 16x16 bins and 32x32
# views under each bundled sky with a sun, rendered with each resolve of the light moments
# (`vertex`: L*' per vertex, blended; `pixel`: the moments resolved at every hit's frame, the
# BTF's tables; `pixel_analytic`: the same with the BRDF itself) and the paper's rule, and each
# image held to one Mitsuba 3 render (scripts/mitsuba_check.py, direct integrator, SPP samples
# per pixel x 2 seeds). Printed per image: the ratio of its light to Mitsuba's over the
# interior pixels, the same over the brightest 5% of Mitsuba's interior (the highlight) and
# over the rest, and the interior rel. L2. Going from `vertex` to `pixel` removes only the
# blend of rows resolved in different vertices' frames; from `pixel` to `pixel_analytic` only
# the tabulation of the lobe. Nothing here is tuned.
#
# Usage: scripts/resolve-energy-study.sh [SKY...]  (default: the four bundled skies with a sun)
#   SPP=1024 Mitsuba's samples per pixel (a square; Mitsuba rounds other counts up with a
#   warning). Needs Mitsuba 3 in .venv (scripts/setup-python.sh --mitsuba). About 90 s per sky
#   on 2 cores with T cached. Writes out/resolve-energy/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/lib/sky-study.sh
study_setup resolve-energy "$@"
cfg=configs/glossy_ggx_bunny.toml
echo "| sky | image | light / Mitsuba's, interior | in the highlight (brightest 5%) | elsewhere | rel. L2, interior |"
echo "|---|---|---|---|---|---|"
for sky in "${skies[@]}"; do
    o=$out/$sky
    sets=(--set transfer.local_grid=16 --set scene.material.view_grid=32
          --set "lighting.env_map=\"../assets/envmaps/$sky.exr\"" --set runtime.repeats=1
          --set 'compressors=[{kind="sparse"}]' --set report.reference=false)
    "$B" -q export-matrix "$cfg" "${sets[@]}" --out "$o/scene" >/dev/null
    for r in vertex pixel pixel_analytic; do
        "$B" -q run "$cfg" "${sets[@]}" --set "runtime.moments_resolve=\"$r\"" --out "$o/$r" 2>/dev/null
    done
    "$PY" scripts/mitsuba_check.py "$o/scene" "$o/pixel_analytic" --spp "${SPP:-1024}" --json --save "$o/mitsuba.exr" \
        > "$o/mitsuba.json"
    "$PY" - "$o" "$sky" <<'PY'
import sys
import numpy as np
import mitsuba as mi
mi.set_variant("scalar_rgb")
sys.path.insert(0, "scripts")
from mitsuba_check import interior_of, read_exr, read_mask, rel_l2
o, sky = sys.argv[1:]
ref = read_exr(mi, f"{o}/mitsuba.exr")
inner = interior_of(read_mask(mi, f"{o}/vertex/images/mask.png"))
lum = lambda img: img @ np.array([0.2126, 0.7152, 0.0722])
y = lum(ref)
high = inner & (y >= np.quantile(y[inner], 0.95))
rest = inner & ~high
for name, path in [("paper's rule", "vertex/images/uncompressed_paper.exr"), ("vertex", "vertex/images/uncompressed.exr"),
                   ("pixel", "pixel/images/uncompressed.exr"), ("pixel_analytic", "pixel_analytic/images/uncompressed.exr")]:
    img = read_exr(mi, f"{o}/{path}")
    ratio = lambda m: lum(img)[m].sum() / y[m].sum()
    print(f"| {sky} | {name} | {ratio(inner):.4f} | {ratio(high):.4f} | {ratio(rest):.4f} | {rel_l2(img, ref, inner):.4f} |")
PY
done
