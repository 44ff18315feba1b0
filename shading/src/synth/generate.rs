//! The BTF generator: ray traces a tileable height field under every light bin and view
//! sample (see the [module docs](super) for the definition it implements).

use super::brdf::{Brdf, Frame};
use super::heightfield::{AlbedoMap, HeightField};
use super::trace::PeriodicTracer;
use crate::error::{Result, ShadingError};
use biscale_core::basis::LocalBasis;
use biscale_core::sampling::hemisphere::{square_to_disk, square_to_hemisphere};
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::Btf;
use biscale_core::Rgb;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Everything that determines a synthesized BTF.
#[derive(Clone, Debug, PartialEq)]
pub struct BtfSpec {
    /// The meso-scale geometry (patch = unit square, heights in patch units).
    pub height_field: HeightField,
    /// Texels per patch side (the reference settings use 32 or 64; `1..=1024`).
    pub resolution: u32,
    /// The light directions: the local basis of the `L*` the BTF will be dotted with (take
    /// it from `T`; default 8 x 8 bins).
    pub local_basis: LocalBasis,
    /// View grid side (default 12), or `None` for a view-independent BTF (no view axis),
    /// which is seen from straight above (`e = +Z`) and needs a Lambertian BRDF.
    pub view_grid: Option<u32>,
    /// The BRDF of the meso-surface.
    pub brdf: Brdf,
    /// `s`: each texel averages `s x s` view rays through its footprint (default 2; `1..=16`).
    pub supersample: u32,
    /// Add one bounce of interreflected light between meso-scale facets (default off).
    pub interreflection: bool,
    /// Cosine-weighted gather rays per visible point for the bounce (default 16; `1..=4096`).
    pub bounce_rays: u32,
    /// Optional texture scaling the BRDF's diffuse term at the visible meso point.
    pub albedo_map: Option<AlbedoMap>,
    /// Name stored in the BTF (reports, the file header).
    pub name: String,
}

impl BtfSpec {
    /// A spec with the reference defaults: 64 texels, 8x8 lights, 12x12 views, 2x2
    /// supersampling, no interreflection, no albedo map.
    pub fn new(height_field: HeightField, brdf: Brdf) -> Self {
        Self {
            height_field,
            resolution: 64,
            local_basis: LocalBasis::bins(8).expect("8 is a valid grid"),
            view_grid: Some(12),
            brdf,
            supersample: 2,
            interreflection: false,
            bounce_rays: 16,
            albedo_map: None,
            name: "synthesized".into(),
        }
    }

    /// Check every field (ranges above; height field, BRDF and albedo map validated).
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(ShadingError::Invalid(format!("BTF spec '{}': {m}", self.name)));
        self.height_field.validate()?;
        self.brdf.validate()?;
        if let Some(map) = &self.albedo_map {
            map.validate()?;
        }
        if !(1..=1024).contains(&self.resolution) {
            return bad(format!("resolution must be 1..=1024 texels, got {}", self.resolution));
        }
        if self.local_basis.grid().is_none() {
            return bad(format!("a synthesized BTF needs a bin basis, not {}", self.local_basis));
        }
        match self.view_grid {
            Some(v) if !(1..=64).contains(&v) => return bad(format!("view grid must be 1..=64 per side, got {v}")),
            None if !matches!(self.brdf, Brdf::Lambertian { .. }) => {
                return bad(format!(
                    "a view-independent BTF (no view grid) needs a Lambertian BRDF, got {}",
                    self.brdf.kind()
                ))
            }
            _ => {}
        }
        if !(1..=16).contains(&self.supersample) {
            return bad(format!("supersample must be 1..=16, got {}", self.supersample));
        }
        if self.interreflection && !(1..=4096).contains(&self.bounce_rays) {
            return bad(format!("bounce_rays must be 1..=4096, got {}", self.bounce_rays));
        }
        Ok(())
    }
}

/// Synthesize the BTF of `spec` (see the [module docs](super)). `progress`, if given, is called
/// from worker threads with the number of texels finished so far (out of `resolution^2`, or
/// 1 for a flat patch without an albedo map, which is tabulated analytically as a one-texel
/// table: [`Btf::lambertian`] / [`Btf::phong`] exactly).
pub fn synthesize(spec: &BtfSpec, progress: Option<&(dyn Fn(usize) + Sync)>) -> Result<Btf> {
    spec.validate()?;
    if spec.height_field.is_flat() {
        return flat(spec, progress);
    }
    run(spec, progress, Mode::Traced)
}

/// How texels are shaded: by ray tracing, or (flat patches) analytically on the plane.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) enum Mode {
    Traced,
    Plane,
}

fn flat(spec: &BtfSpec, progress: Option<&(dyn Fn(usize) + Sync)>) -> Result<Btf> {
    let lambertian = matches!(spec.brdf, Brdf::Lambertian { .. });
    let btf = match (spec.brdf, &spec.albedo_map) {
        (Brdf::Lambertian { albedo }, None) => Btf::lambertian(albedo, spec.local_basis)?,
        (Brdf::Phong { kd, ks, exponent }, None) => {
            // validate() guarantees a view grid for non-Lambertian BRDFs.
            Btf::phong(kd, ks, exponent, spec.local_basis, spec.view_grid.unwrap_or(1))?
        }
        (_, None) => {
            // Uniform: one texel at one sample.
            let one = BtfSpec { resolution: 1, supersample: 1, ..spec.clone() };
            run(&one, None, Mode::Plane)?
        }
        (_, Some(_)) => {
            // A flat Lambertian patch has no view dependence even with a texture.
            let s = if lambertian { BtfSpec { view_grid: None, ..spec.clone() } } else { spec.clone() };
            run(&s, None, Mode::Plane)?
        }
    };
    let btf = btf.renamed(spec.name.clone());
    if let Some(p) = progress {
        p(btf.texel_count());
    }
    Ok(btf)
}

/// Mean direction over each bin of `grid` (not unit length): its `z` is
/// [`HemisphereGrid::bin_mean_cosine`] exactly; `x` and `y` are midpoint sums over 64x64
/// sub-cells of the bin's square (the map is area preserving, so that is the mean over the
/// bin's solid angle; error ~1e-6). The clamped cosine of a facet with normal `n` is taken as
/// `max(0, n . mean)`, which is the bin-mean cosine for a flat patch (so it reproduces
/// [`Btf::lambertian`]) and exact for every bin wholly above the facet's horizon.
pub(crate) fn bin_mean_directions(grid: HemisphereGrid) -> Vec<DVec3> {
    const S: u32 = 64;
    (0..grid.len() as u32)
        .map(|j| {
            let (col, row) = ((j % grid.m) as f64, (j / grid.m) as f64);
            let m = grid.m as f64;
            let (mut x, mut y) = (0.0, 0.0);
            for a in 0..S {
                for b in 0..S {
                    let u = (col + (a as f64 + 0.5) / S as f64) / m;
                    let v = (row + (b as f64 + 0.5) / S as f64) / m;
                    let d = square_to_hemisphere(u, v);
                    x += d.x;
                    y += d.y;
                }
            }
            let k = (S * S) as f64;
            DVec3::new(x / k, y / k, grid.bin_mean_cosine(j))
        })
        .collect()
}

/// Shared, read-only state of one synthesis.
struct Context<'a> {
    spec: &'a BtfSpec,
    tracer: Option<PeriodicTracer>,
    /// Bin-centre light directions, as `Btf::lambertian`/`phong` evaluate the lobe.
    lights: Vec<DVec3>,
    /// Unit-length versions of `lights` for shadow rays.
    light_rays: Vec<DVec3>,
    light_means: Vec<DVec3>,
    views: Vec<DVec3>,
    /// Macro plane (mean height) and the start height of view rays.
    zref: f64,
    top: f64,
    /// Direct irradiance `E[triangle * M + j]` for the bounce.
    bounce_irradiance: Option<Vec<f32>>,
}

/// Tolerance on ray distances (patch units) that keeps a ray from hitting the facet it starts
/// on. Sample points are rounded to ~1e-16; the facet's own plane is met at |t| ~ 1e-13 or less.
const TMIN: f64 = 1e-9;

pub(crate) fn run(spec: &BtfSpec, progress: Option<&(dyn Fn(usize) + Sync)>, mode: Mode) -> Result<Btf> {
    spec.validate()?;
    let lg = spec.local_basis.grid().expect("validate() checked it is a bin basis");
    let vg = spec.view_grid.map(HemisphereGrid::new);
    let lights: Vec<DVec3> = (0..lg.len() as u32).map(|j| lg.bin_direction(j).as_dvec3()).collect();
    let views: Vec<DVec3> = match vg {
        Some(g) => (0..g.len() as u32).map(|v| g.bin_direction(v).as_dvec3()).collect(),
        None => vec![DVec3::Z],
    };
    let hf = &spec.height_field;
    let tracer = (mode == Mode::Traced).then(|| PeriodicTracer::new(hf));
    let zref = hf.mean();
    let top = tracer.as_ref().map_or(zref, |t| t.hmax() + 1e-4);
    let mut ctx = Context {
        spec,
        light_rays: lights.iter().map(|l| l.normalize()).collect(),
        lights,
        light_means: bin_mean_directions(lg),
        views,
        zref,
        top,
        tracer,
        bounce_irradiance: None,
    };
    if spec.interreflection && mode == Mode::Traced {
        ctx.bounce_irradiance = Some(direct_irradiance_per_triangle(&ctx));
    }
    let (r, m, v) = (spec.resolution as usize, ctx.lights.len(), ctx.views.len());
    let mut data = vec![[0.0f32; 3]; r * r * v * m];
    let done = AtomicUsize::new(0);
    data.par_chunks_mut(v * m).enumerate().for_each(|(texel, out)| {
        shade_texel(&ctx, texel % r, texel / r, out);
        let k = done.fetch_add(1, Ordering::Relaxed) + 1;
        if let Some(p) = progress {
            p(k);
        }
    });
    Ok(Btf::new([r as u32; 2], spec.local_basis, vg, data, spec.name.clone())?)
}

fn shade_texel(ctx: &Context<'_>, tx: usize, ty: usize, out: &mut [Rgb]) {
    let spec = ctx.spec;
    let (s, r, m) = (spec.supersample as usize, spec.resolution as f64, ctx.lights.len());
    let mut acc = vec![[0.0f64; 3]; m];
    for (vi, &e) in ctx.views.iter().enumerate() {
        acc.fill([0.0; 3]);
        for sy in 0..s {
            for sx in 0..s {
                let px = (tx as f64 + (sx as f64 + 0.5) / s as f64) / r;
                let py = (ty as f64 + (sy as f64 + 0.5) / s as f64) / r;
                let seed = ((((ty * spec.resolution as usize + tx) * ctx.views.len() + vi) * s + sy) * s + sx) as u64;
                shade_sample(ctx, px, py, e, seed, &mut acc);
            }
        }
        let norm = 1.0 / (s * s) as f64;
        for (o, a) in out[vi * m..(vi + 1) * m].iter_mut().zip(&acc) {
            *o = a.map(|x| (x * norm) as f32);
        }
    }
}

/// Add `b` of the meso point seen along `-e` through macro-plane point `(px, py)` to `acc`.
fn shade_sample(ctx: &Context<'_>, px: f64, py: f64, e: DVec3, seed: u64, acc: &mut [[f64; 3]]) {
    let spec = ctx.spec;
    let (point, normal, triangle) = match &ctx.tracer {
        None => (DVec3::new(px, py, ctx.zref), DVec3::Z, None),
        Some(tracer) => {
            // Cast from above along -e through the texel's footprint on the macro plane; the
            // first hit on the tiled surface is what the viewer sees (masking).
            let origin = DVec3::new(px, py, ctx.zref) + e * ((ctx.top - ctx.zref) / e.z);
            match tracer.closest_hit(origin, -e, 0.0) {
                Some(h) => (h.point, tracer.normal(h.triangle), Some(h.triangle)),
                // Impossible for a view direction above the horizon (the surface is a
                // continuous height field); contributes black rather than panicking.
                None => return,
            }
        }
    };
    let frame = Frame::from_normal(normal);
    let mut e_local = frame.to_local(e);
    if e_local.z <= 0.0 {
        // Only reachable through rounding at a facet seen exactly edge-on.
        e_local.z = 1e-9;
        e_local = e_local.normalize();
    }
    let albedo = spec.albedo_map.as_ref().map_or([1.0; 3], |map| map.sample(point.x, point.y));
    for (j, a) in acc.iter_mut().enumerate() {
        let cos = normal.dot(ctx.light_means[j]);
        if cos <= 0.0 || normal.dot(ctx.lights[j]) <= 0.0 {
            continue;
        }
        if let Some(tracer) = &ctx.tracer {
            if tracer.occluded(point, ctx.light_rays[j], TMIN) {
                continue;
            }
        }
        let f = spec.brdf.eval_scaled(frame.to_local(ctx.lights[j]), e_local, albedo);
        for c in 0..3 {
            a[c] += f[c] * cos;
        }
    }
    if let (Some(tracer), Some(table), Some(_)) = (&ctx.tracer, &ctx.bounce_irradiance, triangle) {
        bounce(ctx, tracer, table, point, &frame, e_local, albedo, seed, acc);
    }
}

/// One bounce of interreflection at a visible point (the module docs give the estimator).
#[allow(clippy::too_many_arguments)]
fn bounce(
    ctx: &Context<'_>,
    tracer: &PeriodicTracer,
    table: &[f32],
    point: DVec3,
    frame: &Frame,
    e_local: DVec3,
    albedo: Rgb,
    seed: u64,
    acc: &mut [[f64; 3]],
) {
    let spec = ctx.spec;
    let (k_rays, m) = (spec.bounce_rays as usize, ctx.lights.len());
    let lambert = match spec.brdf {
        Brdf::Lambertian { albedo } => Some(albedo),
        _ => None,
    };
    // Cranley-Patterson rotation of the R2 sequence (Roberts 2018), per visible point.
    let (g1, g2) = (0.754_877_666_246_692_7, 0.569_840_290_998_053_2);
    let shift = (unit(seed, 1), unit(seed, 2));
    let weight = PI / k_rays as f64;
    for k in 0..k_rays {
        let u1 = (shift.0 + g1 * (k + 1) as f64).fract();
        let u2 = (shift.1 + g2 * (k + 1) as f64).fract();
        // Cosine-weighted direction: concentric disk lifted to the hemisphere (Malley).
        let d = square_to_disk(u1, u2);
        let local = DVec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt());
        let w = frame.to_world(local);
        let Some(hit) = tracer.closest_hit(point, w, TMIN) else {
            continue;
        };
        let nq = tracer.normal(hit.triangle);
        let fq_frame = Frame::from_normal(nq);
        let out_q = fq_frame.to_local(-w);
        if out_q.z <= 0.0 {
            continue;
        }
        let albedo_q = spec.albedo_map.as_ref().map_or([1.0; 3], |map| map.sample(hit.point.x, hit.point.y));
        let fp = spec.brdf.eval_scaled(local, e_local, albedo);
        let row = &table[hit.triangle as usize * m..(hit.triangle as usize + 1) * m];
        let lambert_q = lambert.map(|a| std::array::from_fn::<f64, 3, _>(|c| a[c] as f64 / PI * albedo_q[c] as f64));
        for j in 0..m {
            let irr = row[j] as f64;
            if irr == 0.0 {
                continue;
            }
            let fq = match lambert_q {
                Some(f) => f,
                None => spec.brdf.eval_scaled(fq_frame.to_local(ctx.lights[j]), out_q, albedo_q),
            };
            for c in 0..3 {
                acc[j][c] += weight * fp[c] * fq[c] * irr;
            }
        }
    }
}

/// Uniform `[0, 1)` from a seed and a stream.
fn unit(seed: u64, stream: u64) -> f64 {
    let mut z = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ stream.wrapping_mul(0xd1b5_4a32_d192_ed03);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Direct irradiance of every triangle under every light bin, for the bounce: the clamped
/// mean cosine times the unshadowed fraction of 4 points (centroid and the three points at
/// barycentrics (2/3, 1/6, 1/6) and permutations).
fn direct_irradiance_per_triangle(ctx: &Context<'_>) -> Vec<f32> {
    let tracer = ctx.tracer.as_ref().expect("traced mode");
    let hf = &ctx.spec.height_field;
    let n = hf.width as usize;
    let m = ctx.lights.len();
    let mut table = vec![0.0f32; tracer.triangle_count() * m];
    let bary = [
        [1.0 / 3.0; 3],
        [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
        [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
        [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
    ];
    table.par_chunks_mut(m).enumerate().for_each(|(tri, row)| {
        let cell = tri / 2;
        let (i, j) = (cell % n, cell / n);
        let hz = |di: usize, dj: usize| hf.h[((j + dj) % n) * n + (i + di) % n] as f64;
        let corner =
            |di: usize, dj: usize| DVec3::new((i + di) as f64 / n as f64, (j + dj) as f64 / n as f64, hz(di, dj));
        let v = if tri % 2 == 0 {
            [corner(0, 0), corner(1, 0), corner(1, 1)]
        } else {
            [corner(0, 0), corner(1, 1), corner(0, 1)]
        };
        let normal = tracer.normal(tri as u32);
        for (jl, out) in row.iter_mut().enumerate() {
            let cos = normal.dot(ctx.light_means[jl]);
            if cos <= 0.0 || normal.dot(ctx.lights[jl]) <= 0.0 {
                continue;
            }
            let lit = bary
                .iter()
                .filter(|b| !tracer.occluded(v[0] * b[0] + v[1] * b[1] + v[2] * b[2], ctx.light_rays[jl], TMIN))
                .count();
            *out = (cos * lit as f64 / bary.len() as f64) as f32;
        }
    });
    table
}
