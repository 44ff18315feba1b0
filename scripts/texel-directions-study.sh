#!/usr/bin/env bash
# The texel-mean-direction study (BENCHMARKS.md, "Texel mean directions"): the glossy GGX bunny
# (configs/glossy_ggx_bunny.toml) with the analytic resolve on 16x16 bins and 32x32 views, under
# each bundled sky with a sun, turned about +Y so that the sun's azimuth sits on a vertical edge
# of its 6x32x32 texel and at a texel's centre (turns computed from the map's brightest pixel;
# its elevation stays where the sky has it), rendered with each texel's light at its centre and
# at its mean direction (`[lighting] texel_directions`), and both checked against one Mitsuba 3
# render (scripts/mitsuba_check.py, direct integrator, SPP samples per pixel x 2 seeds). Also
# prints how far the two rules' per-vertex irradiance (`biscale export-matrix`'s irradiance.csv,
# exact-cosine columns) are apart. The rule has no parameter: nothing here is tuned.
#
# Usage: scripts/texel-directions-study.sh [SKY...]  (default: the four bundled skies with a sun)
#   SPP=1024 Mitsuba's samples per pixel. Needs Mitsuba 3 in .venv (scripts/setup-python.sh
#   --mitsuba). About 20 s per sky and turn on 2 cores. Writes out/texel-directions/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/lib/sky-study.sh
study_setup texel-directions "$@"
cfg=configs/glossy_ggx_bunny.toml
echo "| sky | sun | turn (deg) | centre: full frame / interior | mean: full frame / interior | Mitsuba noise | irradiance, centre vs mean |"
echo "|---|---|---|---|---|---|---|"
for sky in "${skies[@]}"; do
    # The turns that put the brightest pixel's azimuth on a texel edge and on a texel centre of
    # its side face (a side face's coordinate is tan of the azimuth from the face's centre,
    # whatever the elevation; a turn of +t degrees about +Y lowers the azimuth by t).
    read -r edge centre <<<"$("$PY" - "$root/assets/envmaps/$sky.exr" <<'PY'
import sys, numpy as np, mitsuba as mi
mi.set_variant("scalar_rgb")
img = np.array(mi.Bitmap(sys.argv[1]).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False))
h, w, _ = img.shape
y, x = np.unravel_index(np.argmax(img @ np.array([0.2126, 0.7152, 0.0722])), (h, w))
rel = (360 * (x + 0.5) / w + 45) % 90 - 45
i = (np.tan(np.radians(rel)) + 1) * 16
to = lambda s: rel - np.degrees(np.arctan(s))
print(f"{to(np.round(i) / 16 - 1):.3f} {to((np.floor(i) + 0.5) / 16 - 1):.3f}")
PY
)"
    for which in edge centre; do
        rot=${!which}
        o=$out/$sky-$which
        sets=(--set 'runtime.moments_resolve="pixel_analytic"' --set transfer.local_grid=16 --set scene.material.view_grid=32
              --set "lighting.env_map=\"../assets/envmaps/$sky.exr\"" --set "lighting.rotation_degrees=$rot"
              --set runtime.repeats=1 --set 'compressors=[{kind="sparse"}]' --set report.reference=false)
        for td in centre mean; do
            "$B" -q export-matrix "$cfg" "${sets[@]}" --set "lighting.texel_directions=\"$td\"" --out "$o/scene-$td" >/dev/null
            "$B" -q run "$cfg" "${sets[@]}" --set "lighting.texel_directions=\"$td\"" --out "$o/$td" 2>/dev/null
        done
        "$PY" scripts/mitsuba_check.py "$o/scene-centre" "$o/centre" --spp "${SPP:-1024}" --json --save "$o/mitsuba.exr" \
            > "$o/mitsuba.json"
        "$PY" - "$o" "$sky" "$which" "$rot" <<'PY'
import json, os, sys
import numpy as np
import mitsuba as mi
mi.set_variant("scalar_rgb")
sys.path.insert(0, "scripts")
from mitsuba_check import interior_of, read_exr, read_mask, rel_l2
o, sky, which, rot = sys.argv[1:]
noise = json.load(open(f"{o}/mitsuba.json"))["mitsuba_noise"]["full_frame"]
ref = read_exr(mi, f"{o}/mitsuba.exr")
mask = read_mask(mi, f"{o}/centre/images/mask.png")
inner = interior_of(mask)
def err(td):
    img = read_exr(mi, f"{o}/{td}/images/uncompressed.exr")
    return f"{rel_l2(img, ref, mask):.4f} / {rel_l2(img, ref, inner):.4f}"
irr = [np.loadtxt(f"{o}/scene-{td}/irradiance.csv", delimiter=",", skiprows=1)[:, 4:7] for td in ("centre", "mean")]
apart = np.sqrt(((irr[0] - irr[1]) ** 2).sum() / (irr[1] ** 2).sum())
print(f"| {sky} | at a texel {which} | {float(rot):g} | {err('centre')} | {err('mean')} | {noise:.4f} | {apart:.5f} |")
PY
    done
done
