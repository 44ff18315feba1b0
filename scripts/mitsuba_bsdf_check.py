#!/usr/bin/env python3
"""Compare biscale's GGX rough conductor / rough plastic BRDFs with Mitsuba 3's.

    .venv/bin/python scripts/mitsuba_bsdf_check.py [table.csv] [--pairs N] [--tolerance T]

Without a CSV path it runs `cargo run -p biscale-shading --example microfacet_table N` (see
shading/examples/microfacet_table.rs for the columns). Each row is evaluated with Mitsuba 3's
`roughconductor` / `roughplastic` plugin (variant scalar_rgb, distribution "ggx"): Mitsuba's
`bsdf.eval(ctx, si, wo)` with `si.wi` = the view and `wo` = the light returns f * cos(theta_wo),
so it is divided by light_z. Reports the largest relative difference per plugin (over values
above a floor: see below) and the largest absolute one, and exits 1 when a relative
difference exceeds the tolerance.

Tolerance (default 5e-3 relative). What is left between the two once the formulas agree:
  * Mitsuba computes in f32: ~1e-6 relative for smooth terms, amplified by sharp lobes (the
    GGX lobe's slope at alpha = 0.05 turns the ~6e-8 rounding of the half-vector into ~5e-6).
  * The rough plastic's coating tables (external transmittance t(mu) and internal reflectance
    R_int): Mitsuba integrates them with one 32 x 32 (eta > 1) or 128 x 128 (eta < 1)
    Gauss-Legendre rule over its visible-normal square, biscale in f64 with a converged rule
    (shading/src/microfacet.rs, CoatingTable). The integrands jump (horizon, critical angle),
    so Mitsuba's values carry quadrature errors of ~1e-4..1e-3, which the diffuse term
    (t_i t_o / (1 - R_int)) carries over; 5e-3 leaves room for those and flags any formula
    error (a wrong Fresnel, G or normalisation is off by percents or more).
Values below 1e-4 times the largest value of the same material are left out of the relative
figure (Mitsuba's D cuts off in f32 and far tails differ by rounding) but kept in the absolute one.
"""

import argparse
import csv
import io
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def parse_params(s):
    out = {}
    for item in s.split(";"):
        name, value = item.split("=")
        if value in ("true", "false"):
            out[name] = value == "true"
        elif ":" in value:
            out[name] = [float(x) for x in value.split(":")]
        else:
            out[name] = float(value)
    return out


def load_bsdf(mi, cache, alpha, kind, params):
    key = (alpha, kind, params)
    if key not in cache:
        d = {"type": kind, "distribution": "ggx", "alpha": float(alpha)}
        for name, value in parse_params(params).items():
            d[name] = {"type": "rgb", "value": value} if isinstance(value, list) else value
        cache[key] = mi.load_dict(d)
    return cache[key]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", nargs="?", help="the example's output (default: run it)")
    ap.add_argument("--pairs", type=int, default=40, help="direction pairs per material (default 40)")
    ap.add_argument("--tolerance", type=float, default=5e-3, help="largest relative difference (default 5e-3)")
    args = ap.parse_args()

    try:
        import mitsuba as mi
    except ImportError:
        print("mitsuba_bsdf_check: Mitsuba 3 is not installed (scripts/setup-python.sh --mitsuba)", file=sys.stderr)
        return 2
    mi.set_variant("scalar_rgb")

    if args.csv:
        text = Path(args.csv).read_text()
    else:
        cmd = ["cargo", "run", "-q", "-p", "biscale-shading", "--example", "microfacet_table", str(args.pairs)]
        text = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True).stdout

    rows = list(csv.DictReader(io.StringIO(text)))
    cache = {}
    ctx = mi.BSDFContext()
    results = []  # (kind, alpha, material key, channel, biscale, mitsuba)
    for row in rows:
        alpha, kind, params = row["alpha"], row["kind"], row["params"]
        bsdf = load_bsdf(mi, cache, alpha, kind, params)
        light = [float(row[f"light_{c}"]) for c in "xyz"]
        view = [float(row[f"view_{c}"]) for c in "xyz"]
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*view)
        value = bsdf.eval(ctx, si, mi.Vector3f(*light))
        for ch, name in enumerate("rgb"):
            ours = float(row[name])
            theirs = float(value[ch]) / light[2]
            results.append((kind, alpha, (alpha, kind, params), ch, ours, theirs))

    peak = defaultdict(float)
    for kind, alpha, key, ch, ours, theirs in results:
        peak[key] = max(peak[key], abs(ours), abs(theirs))
    worst = {}
    max_abs = 0.0
    for kind, alpha, key, ch, ours, theirs in results:
        max_abs = max(max_abs, abs(ours - theirs))
        if max(abs(ours), abs(theirs)) < 1e-4 * peak[key]:
            continue
        rel = abs(ours - theirs) / max(abs(ours), abs(theirs))
        k = (kind, alpha)
        if k not in worst or rel > worst[k][0]:
            worst[k] = (rel, ours, theirs, key[2])
    print(f"mitsuba {mi.__version__} (scalar_rgb), {len(rows)} direction pairs x 3 channels")
    overall = 0.0
    for (kind, alpha), (rel, ours, theirs, params) in sorted(worst.items()):
        overall = max(overall, rel)
        print(f"  {kind:15s} alpha {alpha:5s}: max rel diff {rel:.2e} (biscale {ours:.6g}, mitsuba {theirs:.6g}; {params})")
    print(f"max relative difference {overall:.3e} (tolerance {args.tolerance:.1e}); max absolute difference {max_abs:.3e}")
    if overall > args.tolerance:
        print("mitsuba_bsdf_check: FAILED", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
