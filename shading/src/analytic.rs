//! The CPU analytic resolve at speed (`runtime.moments_resolve = "pixel_analytic"`,
//! [`crate::cpu::shade_moments_analytic`]): what [`crate::cpu::analytic_resolve`] computes per
//! vertex and bin, with the work that does not depend on the shading point done once per frame
//! and the BRDF evaluated over a vertex's bins in f32 lanes the compiler vectorises.
//!
//! * **Once per frame** ([`LitBins::new`]): each vertex's lit bins only (a bin whose three
//!   moments are all zero, in shadow or dark, sends nothing and is dropped), each with its unit
//!   luminance direction `w_j` (world space; the frame does not change a direction's length)
//!   and its three channels' direction sums `D_j`.
//! * **Per shading point and vertex** ([`Resolver::resolve`]): each lit bin's direction in the
//!   point's frame and its exact-cosine power `n . D_j`; the bins whose direction lies at or
//!   below the point's horizon are dropped (the BRDF is 0 there), the others packed into lanes
//!   and the BRDF evaluated over them at once ([`brdf_lanes`]), then `sum_j f(w_j, v) (n . D_j)`
//!   accumulated in f64.
//!
//! The lanes are f32, so the image differs from the f64 [`crate::cpu::analytic_resolve`] by f32
//! rounding of the BRDF (relative `1e-6` to `1e-5` through a GGX lobe, the test
//! `lanes_match_the_f64_resolve` bounds it), far below any error biscale reports. The rough
//! conductor, the rough plastic and the Lambertian are evaluated branch-free over the lanes;
//! Phong and Ashikhmin-Shirley (whose powers the compiler does not vectorise) lane by lane by
//! [`Brdf::eval`].

use crate::synth::Brdf;
use biscale_core::gather::moments::LUMINANCE;
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::VertexFrame;
use glam::DVec3;

/// Each vertex's lit bins, structure of arrays.
pub struct LitBins {
    /// Bins of vertex `v`: `start[v]..start[v + 1]`.
    start: Vec<u32>,
    /// Unit luminance direction of each lit bin (world).
    w: [Vec<f32>; 3],
    /// `D` of each lit bin: `d[c][a]` is channel `c`'s component along world axis `a`.
    d: [[Vec<f32>; 3]; 3],
}

impl LitBins {
    /// The lit bins of the three gathered moments `along[a]` (`D`'s world component `a`).
    pub fn new(along: [&LocalRadiance; 3]) -> Self {
        let (vertices, m) = (along[0].vertices(), along[0].local_dirs());
        let mut lit = LitBins { start: Vec::with_capacity(vertices + 1), w: Default::default(), d: Default::default() };
        lit.start.push(0);
        for v in 0..vertices {
            let rows = along.map(|a| a.vertex(v));
            for j in 0..m {
                let d: [DVec3; 3] = std::array::from_fn(|c| {
                    DVec3::new(rows[0][j][c] as f64, rows[1][j][c] as f64, rows[2][j][c] as f64)
                });
                if d.iter().all(|d| *d == DVec3::ZERO) {
                    continue;
                }
                let g = d[0] * LUMINANCE[0] + d[1] * LUMINANCE[1] + d[2] * LUMINANCE[2];
                // A bin with light but no mean direction (the luminance cancels): the f64
                // resolve skips it too (no direction to evaluate the BRDF at).
                let Some(w) = g.try_normalize() else { continue };
                for a in 0..3 {
                    lit.w[a].push(w[a] as f32);
                    for (c, dc) in d.iter().enumerate() {
                        lit.d[c][a].push(dc[a] as f32);
                    }
                }
            }
            lit.start.push(lit.w[0].len() as u32);
        }
        lit
    }

    /// Lit bins over all vertices.
    pub fn len(&self) -> usize {
        self.w[0].len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Per-thread working lanes of [`Resolver::resolve`].
#[derive(Default)]
pub struct Lanes {
    local: [Vec<f32>; 3],
    power: [Vec<f32>; 3],
    f: [Vec<f32>; 3],
}

/// A material's BRDF ready for lanes: the constants of its kind.
pub struct Resolver {
    brdf: Brdf,
    /// Rough plastic: its coating's external transmittance at the nodes, `R_int`, `eta`.
    coating: Option<([f32; crate::microfacet::TRANSMITTANCE_RES], f32, f32)>,
}

impl Resolver {
    pub fn new(brdf: Brdf) -> Self {
        let coating = brdf
            .coating()
            .map(|t| (t.external_transmittance.map(|x| x as f32), t.internal_reflectance as f32, t.eta as f32));
        Resolver { brdf, coating }
    }

    /// `sum_j f(w_j, view) (n . D_j)` over vertex `v`'s lit bins at the point of `frame`
    /// (`view` in that frame, above its horizon).
    pub fn resolve(&self, lit: &LitBins, v: usize, frame: &VertexFrame, view: DVec3, lanes: &mut Lanes) -> [f64; 3] {
        let range = lit.start[v] as usize..lit.start[v + 1] as usize;
        let (t, b, n) = (frame.tangent, frame.bitangent, frame.normal);
        for x in lanes.local.iter_mut().chain(lanes.power.iter_mut()) {
            x.clear();
        }
        let [wx, wy, wz] = &lit.w;
        for i in range {
            let w = [wx[i], wy[i], wz[i]];
            let z = n.x * w[0] + n.y * w[1] + n.z * w[2];
            if z <= 0.0 {
                continue;
            }
            lanes.local[0].push(t.x * w[0] + t.y * w[1] + t.z * w[2]);
            lanes.local[1].push(b.x * w[0] + b.y * w[1] + b.z * w[2]);
            lanes.local[2].push(z);
            for (c, p) in lanes.power.iter_mut().enumerate() {
                let [dx, dy, dz] = &lit.d[c];
                // The exact-cosine power in f64, as the f64 resolve: near the horizon `n . D`
                // is much smaller than `|D|`.
                let nd = n.x as f64 * dx[i] as f64 + n.y as f64 * dy[i] as f64 + n.z as f64 * dz[i] as f64;
                p.push(nd as f32);
            }
        }
        let count = lanes.local[0].len();
        for f in &mut lanes.f {
            f.clear();
            f.resize(count, 0.0);
        }
        brdf_lanes(self, [&lanes.local[0], &lanes.local[1], &lanes.local[2]], view.as_vec3().into(), &mut lanes.f);
        std::array::from_fn(|c| lanes.f[c].iter().zip(&lanes.power[c]).map(|(&f, &p)| f as f64 * p as f64).sum())
    }
}

/// `f(l_i, view)` per channel for unit local light directions `l` above the horizon into `out`.
///
/// Where the CPU has AVX2 the loops run eight lanes wide instead of SSE2's four, with no fused
/// multiply-add enabled: the same IEEE operations per lane, so the same bits (tested below).
pub fn brdf_lanes(r: &Resolver, l: [&[f32]; 3], view: [f32; 3], out: &mut [Vec<f32>; 3]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the one feature the function enables was detected just above.
        return unsafe { brdf_lanes_avx2(r, l, view, out) };
    }
    brdf_lanes_in(r, l, view, out)
}

/// [`brdf_lanes`] compiled for AVX2 (no FMA: the same roundings).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn brdf_lanes_avx2(r: &Resolver, l: [&[f32]; 3], view: [f32; 3], out: &mut [Vec<f32>; 3]) {
    brdf_lanes_in(r, l, view, out)
}

/// The body of [`brdf_lanes`], inlined into each build of it.
#[inline(always)]
fn brdf_lanes_in(r: &Resolver, l: [&[f32]; 3], view: [f32; 3], out: &mut [Vec<f32>; 3]) {
    let n = l[0].len();
    let (lx, ly, lz) = (&l[0][..n], &l[1][..n], &l[2][..n]);
    let [o0, o1, o2] = out;
    let (o0, o1, o2) = (&mut o0[..n], &mut o1[..n], &mut o2[..n]);
    let [vx, vy, vz] = view;
    match r.brdf {
        Brdf::Lambertian { albedo } => {
            let f = albedo.map(|a| a / std::f32::consts::PI);
            o0.fill(f[0]);
            o1.fill(f[1]);
            o2.fill(f[2]);
        }
        Brdf::RoughConductor { alpha, eta, k, specular_reflectance } => {
            let a = alpha.max(crate::microfacet::MIN_ALPHA as f32);
            let a2 = a * a;
            let g1v = smith_g1_unoriented(a2, view);
            for i in 0..n {
                let (h, d, g1l) = microfacet_terms(a2, [lx[i], ly[i], lz[i]], view);
                let base = d * g1v * g1l / (4.0 * vz * lz[i]);
                let c = vx * h[0] + vy * h[1] + vz * h[2];
                o0[i] = specular_reflectance[0] * fresnel_conductor(c, eta[0], k[0]) * base;
                o1[i] = specular_reflectance[1] * fresnel_conductor(c, eta[1], k[1]) * base;
                o2[i] = specular_reflectance[2] * fresnel_conductor(c, eta[2], k[2]) * base;
            }
        }
        Brdf::RoughPlastic { alpha, diffuse_reflectance, specular_reflectance, nonlinear, .. } => {
            let (table, r_int, eta) = r.coating.expect("built with the plastic");
            let a = alpha.max(crate::microfacet::MIN_ALPHA as f32);
            let a2 = a * a;
            let g1v = smith_g1_unoriented(a2, view);
            let tv = transmittance(&table, vz);
            let diffuse: [f32; 3] = std::array::from_fn(|c| {
                let rho = diffuse_reflectance[c];
                rho / (1.0 - if nonlinear { rho * r_int } else { r_int }) * tv / (std::f32::consts::PI * eta * eta)
            });
            for i in 0..n {
                let (h, d, g1l) = microfacet_terms(a2, [lx[i], ly[i], lz[i]], view);
                let c = vx * h[0] + vy * h[1] + vz * h[2];
                let spec = fresnel_dielectric(c, eta) * d * g1v * g1l / (4.0 * vz * lz[i]);
                let tl = transmittance(&table, lz[i]);
                o0[i] = diffuse[0] * tl + specular_reflectance[0] * spec;
                o1[i] = diffuse[1] * tl + specular_reflectance[1] * spec;
                o2[i] = diffuse[2] * tl + specular_reflectance[2] * spec;
            }
        }
        Brdf::Phong { .. } | Brdf::AshikhminShirley { .. } => {
            let v = DVec3::new(vx as f64, vy as f64, vz as f64);
            for i in 0..n {
                let f = r.brdf.eval(DVec3::new(lx[i] as f64, ly[i] as f64, lz[i] as f64), v);
                (o0[i], o1[i], o2[i]) = (f[0] as f32, f[1] as f32, f[2] as f32);
            }
        }
    }
}

/// Smith's `G1` of a direction above the horizon for a microfacet it sees from the front (the
/// half-vector of two directions above the horizon always is): it depends on the direction
/// alone, so the view's is computed once per point.
#[inline(always)]
fn smith_g1_unoriented(a2: f32, v: [f32; 3]) -> f32 {
    let xy = a2 * (v[0] * v[0] + v[1] * v[1]);
    if xy == 0.0 {
        return 1.0;
    }
    2.0 / (1.0 + (1.0 + xy / (v[2] * v[2])).sqrt())
}

/// The half-vector of `l` and `v`, GGX's `D` there (0 where Mitsuba cuts it) and `G1(l)`.
#[inline(always)]
fn microfacet_terms(a2: f32, l: [f32; 3], v: [f32; 3]) -> ([f32; 3], f32, f32) {
    let h = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
    let inv = 1.0 / (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
    let h = h.map(|x| x * inv);
    let s = (h[0] * h[0] + h[1] * h[1]) / a2 + h[2] * h[2];
    let d = 1.0 / (std::f32::consts::PI * a2 * s * s);
    let d = if d * h[2] > 1e-20 { d } else { 0.0 };
    (h, d, smith_g1_unoriented(a2, l))
}

/// [`crate::microfacet::fresnel_conductor`] in f32, with `a^2` taken without cancellation when
/// `re < 0` (as `gpu/src/shade/brdf.wgsl`).
#[inline(always)]
fn fresnel_conductor(cos_i: f32, eta: f32, k: f32) -> f32 {
    let c2 = cos_i * cos_i;
    let s2 = 1.0 - c2;
    let re = eta * eta - k * k - s2;
    let ek = eta * eta * k * k;
    let ab2 = (re * re + 4.0 * ek).max(0.0).sqrt();
    let a2 = if re < 0.0 { 2.0 * ek / (ab2 - re) } else { 0.5 * (ab2 + re) };
    let a = a2.max(0.0).sqrt();
    let rs = (ab2 + c2 - 2.0 * a * cos_i) / (ab2 + c2 + 2.0 * a * cos_i);
    let (p, q) = (ab2 * c2 + s2 * s2, 2.0 * a * cos_i * s2);
    let rp = rs * (p - q) / (p + q);
    0.5 * (rs + rp)
}

/// [`crate::microfacet::fresnel_dielectric`]'s reflectance from outside (`cos_i >= 0`), f32.
#[inline(always)]
fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    if eta == 1.0 {
        return 0.0;
    }
    if cos_i == 0.0 {
        return 1.0;
    }
    let eta_ti = 1.0 / eta;
    let ct = (1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti).max(0.0).sqrt();
    let a_s = (cos_i - eta * ct) / (cos_i + eta * ct);
    let a_p = (ct - eta * cos_i) / (ct + eta * cos_i);
    0.5 * (a_s * a_s + a_p * a_p)
}

/// `CoatingTable::transmittance` in f32.
#[inline(always)]
fn transmittance(t: &[f32; crate::microfacet::TRANSMITTANCE_RES], mu: f32) -> f32 {
    let last = crate::microfacet::TRANSMITTANCE_RES - 1;
    let x = mu * last as f32;
    let j = (x.max(0.0) as usize).min(last - 1);
    let w = x - j as f32;
    (1.0 - w) * t[j] + w * t[j + 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::analytic_resolve;
    use biscale_core::basis::LocalBasis;
    use glam::Vec3;
    use rand::{Rng, SeedableRng};

    /// The lanes against the f64 resolve on random moments (directions everywhere, bins left
    /// dark, below the point's horizon and with a cancelling luminance) at random frames and
    /// views: within `2e-4` of the sum of the terms' magnitudes `sum_j |f_j (n . D_j)|`. That
    /// bound: the f32 BRDF's rounding (the GPU's test of the same formulas measures at most
    /// `5e-5` relative, Ashikhmin-Shirley's power) and the f32 direction (a few `u`, `2 / alpha`
    /// relative per radian through a GGX lobe: `4e-6` at alpha 0.15).
    #[test]
    fn lanes_match_the_f64_resolve() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (vertices, m) = (40usize, 4u32);
        let basis = LocalBasis::bins(m).unwrap();
        let bins = basis.len();
        let mut unit = || loop {
            let d = Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            if d.length() > 0.1 {
                return d.normalize();
            }
        };
        let frames: Vec<VertexFrame> = (0..vertices).map(|_| VertexFrame::from_normal(unit())).collect();
        let views: Vec<Vec3> = (0..vertices).map(|_| unit()).collect();
        let mut along =
            [vec![[0.0f32; 3]; vertices * bins], vec![[0.0; 3]; vertices * bins], vec![[0.0; 3]; vertices * bins]];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        for row in 0..vertices * bins {
            if row % 5 == 0 {
                continue; // dark
            }
            for c in 0..3 {
                let d = Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
                (0..3).for_each(|a| along[a][row][c] = d[a]);
            }
        }
        let along = along.map(|values| LocalRadiance::new(basis, vertices, values).unwrap());
        let lit = LitBins::new([&along[0], &along[1], &along[2]]);
        assert!(lit.len() < vertices * bins, "the dark bins are dropped");
        let mut lanes = Lanes::default();
        for brdf in Brdf::one_of_each() {
            let r = Resolver::new(brdf);
            let mut worst = 0.0f64;
            for v in 0..vertices {
                let view = crate::cpu::above_horizon(views[v].as_dvec3());
                let rows = [along[0].vertex(v), along[1].vertex(v), along[2].vertex(v)];
                let want = analytic_resolve(&brdf, &frames[v], rows, view);
                let got = r.resolve(&lit, v, &frames[v], view, &mut lanes);
                // The sum of the magnitudes the f64 resolve adds.
                let f = &frames[v];
                let (t, b, n) = (f.tangent.as_dvec3(), f.bitangent.as_dvec3(), f.normal.as_dvec3());
                let mut scale = [1e-30f64; 3];
                for j in 0..bins {
                    let d: [DVec3; 3] = std::array::from_fn(|c| {
                        DVec3::new(rows[0][j][c] as f64, rows[1][j][c] as f64, rows[2][j][c] as f64)
                    });
                    let g = d[0] * LUMINANCE[0] + d[1] * LUMINANCE[1] + d[2] * LUMINANCE[2];
                    if let Some(l) = DVec3::new(g.dot(t), g.dot(b), g.dot(n)).try_normalize().filter(|l| l.z > 0.0) {
                        let fv = brdf.eval(l, view);
                        (0..3).for_each(|c| scale[c] += (fv[c] * n.dot(d[c])).abs());
                    }
                }
                for c in 0..3 {
                    let err = (got[c] - want[c]).abs() / scale[c];
                    worst = worst.max(err);
                    assert!(
                        err <= 2e-4,
                        "{brdf:?} vertex {v} channel {c}: lanes {} vs f64 {} ({err:e} of the terms)",
                        got[c],
                        want[c]
                    );
                }
            }
            eprintln!("{}: largest error {worst:.2e} of the terms' magnitudes", brdf.kind());
        }
    }

    /// The BRDF lanes built for AVX2 (eight wide, no FMA) give the very bits of the SSE2
    /// build's four, for every kind, on random directions, grazing ones and counts that are
    /// not a multiple of eight.
    #[test]
    fn the_wide_brdf_lanes_give_the_same_bits_as_the_narrow_ones() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for count in [1usize, 7, 8, 13, 64] {
            let mut l: [Vec<f32>; 3] = Default::default();
            for i in 0..count {
                let z = if i % 4 == 0 { 1e-6 } else { rng.gen_range(0.001f32..1.0) };
                let phi = rng.gen_range(0.0..std::f32::consts::TAU);
                let s = (1.0 - z * z).sqrt();
                for (a, x) in [s * phi.cos(), s * phi.sin(), z].into_iter().enumerate() {
                    l[a].push(x);
                }
            }
            let view = [0.3f32, -0.2, (1.0f32 - 0.13).sqrt()];
            for brdf in Brdf::one_of_each() {
                let r = Resolver::new(brdf);
                let (mut wide, mut narrow): ([Vec<f32>; 3], [Vec<f32>; 3]) = Default::default();
                for o in wide.iter_mut().chain(narrow.iter_mut()) {
                    o.resize(count, 0.0);
                }
                brdf_lanes(&r, [&l[0], &l[1], &l[2]], view, &mut wide);
                brdf_lanes_in(&r, [&l[0], &l[1], &l[2]], view, &mut narrow);
                let bits = |o: &[Vec<f32>; 3]| o.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&wide), bits(&narrow), "{} with {count} lanes", brdf.kind());
            }
        }
    }
}
