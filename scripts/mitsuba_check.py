#!/usr/bin/env python3
"""An external check of biscale's images against Mitsuba 3 (never needed by the tests).

Renders what a biscale run rendered -- the same mesh in biscale's vertex order with the normals
T was traced with, the same camera, environment map and rotation, the run's material -- with
Mitsuba 3's `direct` integrator (box film filter), and prints the relative L2 error of
biscale's images against it over the covered pixels ("full frame") and over the interior
(covered pixels whose 5x5 neighbourhood is all covered, so silhouettes are out), beside
Mitsuba's own noise; and, for a Lambertian material, each vertex's direct irradiance,
estimated by Mitsuba with emitter sampling and its own visibility rays, against biscale's
`T L` with the paper's bin-mean cosine and with each texel's own cosine (`irradiance.csv` from
`biscale export-matrix`).

    scripts/setup-python.sh --mitsuba          # .venv with Mitsuba 3 (and libllvm19 if apt can)
    biscale run CONFIG --out RUN               # e.g. a white Lambertian run, or a flat GGX one
    biscale export-matrix CONFIG --out SCENE   # mesh.obj and view.json (and T.mtx, L.mtx)
    .venv/bin/python scripts/mitsuba_check.py SCENE RUN [--spp 1024] [--save mitsuba.exr]

The material is the run's own: the config text as it ran (with its --set overrides) is
`RUN/metrics.json` `run.config_text`, read here as TOML. Mapped to Mitsuba:
* `lambertian` (albedo) -> `diffuse` (reflectance = albedo); no material at all is the config's
  default, Lambertian albedo 0.8;
* `synthesized` with `amplitude = 0` (a flat patch) and no `albedo_map`, by its brdf:
  `lambertian` -> `diffuse`; `rough_conductor` -> `roughconductor` (distribution "ggx", alpha,
  eta, k, specular_reflectance); `rough_plastic` -> `roughplastic` (distribution "ggx", alpha,
  int_ior, ext_ior, diffuse_reflectance, specular_reflectance, nonlinear), the parameters
  defaulted as Mitsuba's (biscale names and defaults them the same way).
Anything else is refused with one line saying why: Phong and Ashikhmin-Shirley (Mitsuba has
neither), a bumpy synthesized patch (its meso-scale shadowing and masking are in no Mitsuba
BSDF), an albedo map, a measured BTF, or several materials.

With `[report] background = false` the run's images have no sky behind the mesh, so Mitsuba's
emitter is hidden too (`hide_emitters`): the box filter mixes what lies behind a silhouette
pixel into it.

Mitsuba's noise: the scene is rendered twice at `--spp` with seeds 0 and 1; the rel. L2
between the two over sqrt(2) is one render's noise, and biscale is compared against their mean,
whose noise (one render's over sqrt(2)) is printed beside the errors ("Mitsuba noise").

Conventions matched, each from biscale's code:
* lat-long maps: biscale uses Mitsuba 3's mapping, so the emitter's to_world is only the
  rotation about +Y by `rotation_degrees` (biscale's `rotate_y`, right-handed);
* the camera: a pinhole through pixel centres, vertical field of view, row 0 at the top;
* the mesh: `mesh.obj` has one `vn` per `v` and faces `a//a`, read here into arrays so no
  loader re-indexes the vertices; Mitsuba interpolates the given normals.
* shading: biscale's Lambertian (albedo a) is Mitsuba's `diffuse` with reflectance a; its GGX
  BRDFs follow Mitsuba's `roughconductor` / `roughplastic` (scripts/mitsuba_bsdf_check.py).
The run's images are the files `images/<name>.exr` at the run's full resolution; biscale's
`uncompressed` image (and with light moments `uncompressed_paper`) and every compressor's.
"""

import argparse
import json
import os
import sys

import numpy as np

try:
    import tomllib
except ImportError:  # Python < 3.11
    import tomli as tomllib


def read_obj(path):
    v, vn, f = [], [], []
    with open(path) as fh:
        for line in fh:
            p = line.split()
            if not p:
                continue
            if p[0] == "v":
                v.append([float(x) for x in p[1:4]])
            elif p[0] == "vn":
                vn.append([float(x) for x in p[1:4]])
            elif p[0] == "f":
                idx = [int(x.split("/")[0]) - 1 for x in p[1:4]]
                if any(int(x.split("/")[-1]) - 1 != i for x, i in zip(p[1:4], idx)):
                    sys.exit(f"{path}: face {len(f)} has a normal index other than its vertex's; export it with biscale")
                f.append(idx)
    v, vn, f = np.array(v, np.float32), np.array(vn, np.float32), np.array(f, np.uint32)
    if len(v) != len(vn):
        sys.exit(f"{path}: {len(v)} vertices but {len(vn)} normals; export it with `biscale export-matrix`")
    return v, vn, f


def read_exr(mi, path):
    bmp = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False)
    return np.array(bmp, dtype=np.float64)


def read_mask(mi, path):
    bmp = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.Y, mi.Struct.Type.UInt8, srgb_gamma=False)
    a = np.array(bmp)
    return (a[..., 0] if a.ndim == 3 else a) > 127


def interior_of(mask, radius=2):
    inner = mask.copy()
    h, w = mask.shape
    padded = np.zeros((h + 2 * radius, w + 2 * radius), bool)
    padded[radius : radius + h, radius : radius + w] = mask
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            inner &= padded[radius + dy : radius + dy + h, radius + dx : radius + dx + w]
    return inner


def refuse(why):
    sys.exit(f"mitsuba_check: {why}")


def run_config(run, metrics):
    """The config the run ran with (its --set overrides applied), parsed: `metrics.json`'s
    `run.config_text`; a run without that record falls back to the config file it names."""
    text = (metrics.get("run") or {}).get("config_text")
    if text is None:
        path = metrics.get("config")
        if not path or not os.path.exists(path):
            refuse(f"{run}/metrics.json records no run.config_text and its config {path!r} is not there; rerun it")
        print(f"mitsuba_check: {run}/metrics.json has no run.config_text; reading the material from {path}", file=sys.stderr)
        text = open(path).read()
    return tomllib.loads(text)


def rgb(value):
    return {"type": "rgb", "value": [float(x) for x in value]}


def mitsuba_material(cfg):
    """The run's material as a Mitsuba BSDF dict, with a label and whether it is Lambertian
    (and white, albedo 1: the case this check was first written for). Refuses what Mitsuba
    cannot render the same way."""
    scene = cfg.get("scene", {})
    entries = [scene["material"]] if "material" in scene else list(scene.get("materials", []))
    if not entries:
        entries = [{"kind": "lambertian", "albedo": [0.8, 0.8, 0.8]}]  # the config's default material
    if len(entries) > 1:
        refuse(f"the run has {len(entries)} materials ([[scene.materials]]); this check renders one material over the whole mesh")
    m = entries[0]
    kind = m.get("kind")

    def diffuse(albedo):
        albedo = [float(x) for x in albedo]
        label = "white Lambertian" if albedo == [1.0, 1.0, 1.0] else f"Lambertian, albedo {albedo}"
        return {"type": "diffuse", "reflectance": rgb(albedo)}, label, True, albedo == [1.0, 1.0, 1.0]

    if kind == "lambertian":
        return diffuse(m["albedo"])
    if kind == "phong":
        refuse("the run's material is Phong, and Mitsuba 3 has no Phong BSDF")
    if kind == "bonn":
        refuse("the run's material is a measured BTF (bonn), which Mitsuba 3 cannot render")
    if kind != "synthesized":
        refuse(f"the run's material kind {kind!r} is not one this check knows")
    if float(m.get("amplitude", 0.0)) != 0.0:
        refuse(f"the run's material is a bumpy synthesized patch (amplitude {m['amplitude']}): its meso-scale "
               "shadowing and masking are in no Mitsuba BSDF; check a flat one (amplitude = 0)")
    if m.get("albedo_map"):
        refuse("the run's synthesized material has an albedo_map (a texture over the patch), which this check does not map")
    b = m.get("brdf", {})
    bk = b.get("kind")
    if bk == "lambertian":
        return diffuse(b["albedo"])
    if bk == "rough_conductor":
        alpha = float(b.get("alpha", 0.1))
        eta, k = b.get("eta", [0.0] * 3), b.get("k", [1.0] * 3)
        spec = b.get("specular_reflectance", [1.0] * 3)
        bsdf = {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                "eta": rgb(eta), "k": rgb(k), "specular_reflectance": rgb(spec)}
        return bsdf, f"roughconductor (ggx, alpha {alpha:g}, eta {eta}, k {k}, specular_reflectance {spec})", False, False
    if bk == "rough_plastic":
        alpha = float(b.get("alpha", 0.1))
        int_ior, ext_ior = float(b.get("int_ior", 1.49)), float(b.get("ext_ior", 1.000277))
        kd, ks = b.get("diffuse_reflectance", [0.5] * 3), b.get("specular_reflectance", [1.0] * 3)
        nonlinear = bool(b.get("nonlinear", False))
        bsdf = {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": int_ior,
                "ext_ior": ext_ior, "diffuse_reflectance": rgb(kd), "specular_reflectance": rgb(ks),
                "nonlinear": nonlinear}
        return bsdf, (f"roughplastic (ggx, alpha {alpha:g}, int_ior {int_ior}, ext_ior {ext_ior}, "
                      f"diffuse_reflectance {kd}, specular_reflectance {ks}, nonlinear {str(nonlinear).lower()})"), False, False
    if bk in ("phong", "ashikhmin_shirley"):
        refuse(f"the run's synthesized BRDF is {bk}, and Mitsuba 3 has no such BSDF")
    refuse(f"the run's synthesized BRDF kind {bk!r} is not one this check knows")


def rel_l2(a, b, m):
    d = (a - b)[m]
    return float(np.sqrt((d * d).sum() / max((b[m] ** 2).sum(), 1e-300)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="a `biscale export-matrix --out` folder (mesh.obj, view.json)")
    ap.add_argument("run", help="a `biscale run --out` folder of the same config (images/, metrics.json)")
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel (default 1024)")
    ap.add_argument("--variant", default=None, help="Mitsuba variant (default: llvm_ad_rgb, else scalar_rgb)")
    ap.add_argument("--save", default=None, help="write Mitsuba's image to this EXR")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    ap.add_argument("--vertex-samples", type=int, default=4096,
                    help="emitter samples per vertex for the irradiance check (0: skip; needs the LLVM variant)")
    args = ap.parse_args()

    import mitsuba as mi

    variants = [args.variant] if args.variant else ["llvm_ad_rgb", "scalar_rgb"]
    for var in variants:
        try:
            mi.set_variant(var)
            break
        except Exception as e:  # the LLVM variant needs libllvm (scripts/setup-python.sh)
            print(f"mitsuba_check: variant {var} unavailable ({e})", file=sys.stderr)
    else:
        sys.exit("mitsuba_check: no Mitsuba variant could be set")

    view = json.load(open(os.path.join(args.scene, "view.json")))
    metrics = json.load(open(os.path.join(args.run, "metrics.json")))
    cfg = run_config(args.run, metrics)
    bsdf, material, lambertian, white = mitsuba_material(cfg)
    hide_emitters = not cfg.get("report", {}).get("background", True)
    if view.get("sun_boost"):
        sys.exit("mitsuba_check: sun_boost edits biscale's light vector, not the map Mitsuba reads; check without it")
    if not view.get("env_map"):
        sys.exit("mitsuba_check: this check needs an environment map (a constant sky is a trivial case)")
    # Mitsuba's envmap emitter reads lat-long maps only; biscale also takes cube maps.
    if "{face}" in os.path.basename(view["env_map"]):
        sys.exit("mitsuba_check: the run's sky is six cube-map faces; Mitsuba needs a lat-long map")
    env_size = mi.Bitmap(view["env_map"]).size()
    if env_size[0] != 2 * env_size[1]:
        sys.exit(f"mitsuba_check: the run's sky is {env_size[0]}x{env_size[1]} (a cube-map cross); Mitsuba needs a lat-long map")
    cam = view["camera"]
    v, vn, f = read_obj(os.path.join(args.scene, "mesh.obj"))

    mesh = mi.Mesh("biscale", vertex_count=len(v), face_count=len(f), has_vertex_normals=True, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.ravel())
    params["vertex_normals"] = mi.Float(vn.ravel())
    params["faces"] = mi.UInt(f.ravel())
    params.update()
    mesh.set_bsdf(mi.load_dict(bsdf))

    T = mi.ScalarTransform4f
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "direct", "hide_emitters": hide_emitters},
            "sensor": {
                "type": "perspective",
                "fov_axis": "y",
                "fov": cam["fov_y_degrees"],
                "to_world": T().look_at(origin=cam["position"], target=cam["target"], up=cam["up"]),
                "sampler": {"type": "multijitter", "sample_count": args.spp},
                "film": {
                    "type": "hdrfilm",
                    "width": cam["width"],
                    "height": cam["height"],
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
            },
            "emitter": {
                "type": "envmap",
                "filename": view["env_map"],
                "to_world": T().rotate([0, 1, 0], view["rotation_degrees"]),
            },
            "mesh": mesh,
        }
    )
    # Two renders with different seeds: their mean is the reference, their difference its noise.
    renders = [np.array(mi.render(scene, seed=seed), dtype=np.float64)[..., :3] for seed in (0, 1)]
    image = 0.5 * (renders[0] + renders[1])
    if args.save:
        mi.Bitmap(image.astype(np.float32)).write(args.save)

    images = os.path.join(args.run, "images")
    mask = read_mask(mi, os.path.join(images, "mask.png"))
    if mask.shape != image.shape[:2]:
        sys.exit(f"mitsuba_check: the run's mask is {mask.shape[1]}x{mask.shape[0]}, the camera {cam['width']}x{cam['height']}")
    inner = interior_of(mask)
    # One render's noise: rel. L2 between the two renders / sqrt(2); the mean's: that / sqrt(2).
    # (Relative to the mean's norm, as every error here is.)
    half_diff = 0.5 * (renders[0] - renders[1])
    noise_one = {k: rel_l2(image + half_diff, image, m) * np.sqrt(2.0) for k, m in (("full_frame", mask), ("interior", inner))}
    noise = {k: x * np.sqrt(0.5) for k, x in noise_one.items()}
    names = ["uncompressed"]
    if os.path.exists(os.path.join(images, "uncompressed_paper.exr")):
        names.append("uncompressed_paper")
    names += [c["name"] for c in metrics.get("compressors", []) if os.path.exists(os.path.join(images, c["name"] + ".exr"))]
    # biscale's own ray-traced reference, when the run traced it at full resolution
    # (`--set report.reference_downscale=1`): how far the ground truth itself is from Mitsuba.
    ref = os.path.join(images, "reference.exr")
    if os.path.exists(ref) and read_exr(mi, ref).shape == image.shape:
        names.append("reference")
    rows = []
    for name in names:
        b = read_exr(mi, os.path.join(images, name + ".exr"))
        rows.append({"image": name, "full_frame": rel_l2(b, image, mask), "interior": rel_l2(b, image, inner)})
    irradiance = None
    csv = os.path.join(args.scene, "irradiance.csv")
    irradiance_skipped = None
    if not lambertian:
        irradiance_skipped = f"the material is {bsdf['type']}, not Lambertian"
    elif args.vertex_samples > 0 and os.path.exists(csv) and mi.variant().startswith("llvm"):
        irradiance = vertex_irradiance_check(mi, scene, v, vn, csv, args.vertex_samples)
    out = {
        "irradiance": irradiance,
        "irradiance_skipped": irradiance_skipped,
        "material": material,
        "mitsuba_bsdf": bsdf,
        "hide_emitters": hide_emitters,
        "seeds": [0, 1],
        # Mitsuba's noise: of one render, and of the mean of the two (what biscale is compared with).
        "mitsuba_noise_one_render": noise_one,
        "mitsuba_noise": noise,
        "variant": mi.variant(),
        "spp": args.spp,
        "pixels": int(mask.sum()),
        "interior_pixels": int(inner.sum()),
        "light_moments": metrics["uncompressed"].get("light_moments", False),
        "rows": rows,
    }
    if args.json:
        print(json.dumps(out))
        return
    print(f"Mitsuba {mi.__version__} {out['variant']}, {args.spp} spp x 2 seeds; {out['pixels']} covered pixels, {out['interior_pixels']} interior")
    if not white or hide_emitters:
        print(f"material: {material}" + ("; emitter hidden ([report] background = false)" if hide_emitters else ""))
    print("| biscale image | rel. L2, full frame | rel. L2, interior | Mitsuba noise (mean of 2 seeds): full frame | interior |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['image']} | {r['full_frame']:.4f} | {r['interior']:.4f} | {noise['full_frame']:.4f} | {noise['interior']:.4f} |")
    if irradiance_skipped:
        print(f"\nPer-vertex irradiance: skipped ({irradiance_skipped}: the image is not irradiance times albedo / pi)")
    if irradiance:
        i = irradiance
        print(f"\nPer-vertex irradiance, {i['samples']} emitter samples per vertex (Mitsuba's own noise: "
              f"rel. L2 {i['mitsuba_noise']:.4f} between two halves' estimates / 2):")
        print(f"| biscale T L | rel. L2 over vertices |\n|---|---|\n| paper's bin-mean cosine | {i['paper']:.4f} |"
              f"\n| each texel's own cosine (light moments) | {i['exact_cosine']:.4f} |")


def vertex_irradiance_check(mi, scene, v, vn, csv, samples):
    """Mitsuba's direct irradiance at every vertex (emitter sampling, visibility rays from the
    vertex along its normal's side) against biscale's two per-vertex values."""
    import drjit as dr

    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    paper, exact = data[:, 1:4], data[:, 4:7]
    n_v = len(v)
    halves = []
    for seed in (1, 2):
        est = np.zeros((n_v, 3))
        chunk = max(1, 2_000_000 // samples)
        for start in range(0, n_v, chunk):
            idx = np.arange(start, min(n_v, start + chunk))
            rep = np.repeat(idx, samples // 2)
            si = dr.zeros(mi.SurfaceInteraction3f, len(rep))
            si.p = mi.Point3f(*[mi.Float(v[rep, a]) for a in range(3)])
            si.n = mi.Normal3f(*[mi.Float(vn[rep, a]) for a in range(3)])
            si.sh_frame = mi.Frame3f(si.n)
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(seed * 1_000_003 + start, len(rep))
            ds, weight = scene.sample_emitter_direction(si, sampler.next_2d(), True)
            cos = dr.maximum(dr.dot(si.n, ds.d), 0.0)
            contrib = np.stack([np.array(weight[a] * cos) for a in range(3)], axis=1)
            est[idx] = contrib.reshape(len(idx), samples // 2, 3).mean(axis=1)
        halves.append(est)
    mts = 0.5 * (halves[0] + halves[1])

    def rel(a, b):
        return float(np.sqrt(((a - b) ** 2).sum() / max((b ** 2).sum(), 1e-300)))

    return {
        "samples": samples,
        "mitsuba_noise": rel(halves[0], halves[1]) / 2.0,
        "paper": rel(paper, mts),
        "exact_cosine": rel(exact, mts),
    }


if __name__ == "__main__":
    main()
