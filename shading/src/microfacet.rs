//! GGX (Trowbridge-Reitz) microfacet BRDFs parameterised as Mitsuba 3's `roughconductor` and
//! `roughplastic` plugins (with `distribution = "ggx"`), so a synthesized BTF can be checked
//! against a Mitsuba render of the same material. Everything is evaluated in a local frame
//! (+Z = the normal) for unit `light` and `view` directions; either one at or below the horizon
//! gives 0, as in Mitsuba. Values are `f(light, view)` (no cosine): Mitsuba's `eval(ctx, si, wo)`
//! returns `f * cos_theta(wo)` with `si.wi` the view direction and `wo` the light.
//!
//! # The pieces (each written from the formulas; the Mitsuba 3 file it follows in brackets)
//!
//! * [`Ggx`] (`include/mitsuba/render/microfacet.h`, `MicrofacetDistribution`, isotropic GGX):
//!   `D(m) = 1 / (pi a^2 ((m_x^2 + m_y^2) / a^2 + m_z^2)^2)`, set to 0 where `D cos(theta_m) <=
//!   1e-20` as Mitsuba does; Smith's `G1(v, m) = 2 / (1 + sqrt(1 + a^2 tan^2(theta_v)))`, 0 when
//!   `(v.m) v_z <= 0`; and Smith's **separable** (uncorrelated) `G = G1(wi, m) G1(wo, m)`, which
//!   is what `MicrofacetDistribution::G` returns. `alpha` is clamped below at `1e-4` as in
//!   Mitsuba's `configure()`.
//! * [`fresnel_conductor`] and [`fresnel_dielectric`] (`include/mitsuba/render/fresnel.h`): the
//!   unpolarized Fresnel reflectance of a conductor with complex IOR `eta + i k` and of a
//!   dielectric interface with relative IOR `eta` (total internal reflection gives 1).
//! * [`RoughConductor`] (`src/bsdfs/roughconductor.cpp`): `f = s F_c(view.h) D(h) G(view,
//!   light, h) / (4 cos_light cos_view)`, `h = normalize(light + view)`, per RGB channel with
//!   `eta`, `k` and `specular_reflectance` `s`. Mitsuba's default (no `material`, no `eta`) is
//!   `eta = 0`, `k = 1`: `F = 1` at every angle, a 100% reflecting rough mirror.
//! * [`RoughPlastic`] (`src/bsdfs/roughplastic.cpp`): a rough dielectric coating (relative IOR
//!   `eta = int_ior / ext_ior`) over a Lambertian base:
//!
//!   ```text
//!   f = s F(view.h, eta) D G / (4 cos_l cos_v)
//!     + rho / (1 - R_int) * t(cos_v) t(cos_l) / (pi eta^2)     (rho R_int for nonlinear)
//!   ```
//!
//!   with `t(mu)` the coating's external transmittance and `R_int` its internal diffuse
//!   reflectance, both from [`CoatingTable`] (see there for how they are computed and how they
//!   differ from Mitsuba's numbers). The diffuse part is what an albedo map scales.
//!
//! Both BRDFs are reciprocal: the specular terms are symmetric in (light, view) (`h`, `G` and
//! `|view.h| = |light.h|`) and the rough plastic's diffuse term has the product `t_i t_o`.
//! Neither conserves energy exactly: single-scattering microfacet models lose the light that
//! scatters more than once between microfacets (more with higher `alpha`).

use biscale_core::sh::quadrature::gauss_legendre;
use glam::DVec3;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex, OnceLock};

/// Mitsuba's lower clamp on `alpha` (`MicrofacetDistribution::configure`).
pub const MIN_ALPHA: f64 = 1e-4;

/// Nodes of the external transmittance table over `cos(theta)` in `[0, 1]`
/// (`MI_ROUGH_TRANSMITTANCE_RES` in Mitsuba's `roughplastic.cpp`).
pub const TRANSMITTANCE_RES: usize = 64;

/// The isotropic GGX (Trowbridge-Reitz) distribution of roughness `alpha` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    alpha: f64,
}

impl Ggx {
    /// `alpha` clamped below at [`MIN_ALPHA`], as Mitsuba does.
    pub fn new(alpha: f64) -> Self {
        Self { alpha: alpha.max(MIN_ALPHA) }
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// `D(m)`, normalised so that `integral D(m) cos(theta_m) dm = 1` over the hemisphere.
    pub fn d(&self, m: DVec3) -> f64 {
        let a2 = self.alpha * self.alpha;
        let s = (m.x * m.x + m.y * m.y) / a2 + m.z * m.z;
        let d = 1.0 / (PI * a2 * s * s);
        // Mitsuba's guard against tiny values (it also removes m below the horizon).
        if d * m.z > 1e-20 {
            d
        } else {
            0.0
        }
    }

    /// Smith's masking `G1(v, m)` for direction `v` and microfacet normal `m`.
    pub fn smith_g1(&self, v: DVec3, m: DVec3) -> f64 {
        // A microfacet is never seen from its back side, nor from the other side of the macro
        // surface.
        if v.dot(m) * v.z <= 0.0 {
            return 0.0;
        }
        let xy = self.alpha * self.alpha * (v.x * v.x + v.y * v.y);
        if xy == 0.0 {
            return 1.0;
        }
        let tan2 = xy / (v.z * v.z);
        2.0 / (1.0 + (1.0 + tan2).sqrt())
    }

    /// Smith's separable shadowing-masking `G1(wi, m) G1(wo, m)`.
    pub fn g(&self, wi: DVec3, wo: DVec3, m: DVec3) -> f64 {
        self.smith_g1(wi, m) * self.smith_g1(wo, m)
    }

    /// The microfacet normal of visible-normal sample `(u1, u2)` in `[0, 1]^2` for direction
    /// `v` (`v.z > 0`): the map of Heitz 2018 ("Sampling the GGX distribution of visible
    /// normals", JCGT 7(4)), which carries the uniform measure on the square to the
    /// distribution of visible normals `G1(v, m) max(0, v.m) D(m) / v_z`.
    pub fn visible_normal(&self, v: DVec3, u1: f64, u2: f64) -> DVec3 {
        self.visible_normal_polar(v, u1.max(0.0).sqrt(), 2.0 * PI * u2)
    }

    /// [`visible_normal`](Self::visible_normal) with the disk point in polar coordinates
    /// (`r = sqrt(u1)`, `phi = 2 pi u2`): quadratures in `r` avoid the square root's
    /// singular derivative.
    fn visible_normal_polar(&self, v: DVec3, r: f64, phi: f64) -> DVec3 {
        let a = self.alpha;
        // The direction in the hemisphere configuration (alpha = 1).
        let vh = DVec3::new(a * v.x, a * v.y, v.z).normalize();
        let len2 = vh.x * vh.x + vh.y * vh.y;
        let t1 = if len2 > 0.0 { DVec3::new(-vh.y, vh.x, 0.0) / len2.sqrt() } else { DVec3::X };
        let t2 = vh.cross(t1);
        // A point of the disk, warped onto the projected visible half of the hemisphere.
        let (p1, p2) = (r * phi.cos(), r * phi.sin());
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
        let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
        // Back to the ellipsoid configuration.
        DVec3::new(a * nh.x, a * nh.y, nh.z.max(0.0)).normalize()
    }
}

/// Unpolarized Fresnel reflectance of a conductor with complex relative IOR `eta + i k` at
/// incidence cosine `cos_i` in `[0, 1]` (light arriving from outside). At normal incidence it is
/// `((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2)`.
pub fn fresnel_conductor(cos_i: f64, eta: f64, k: f64) -> f64 {
    let c2 = cos_i * cos_i;
    let s2 = 1.0 - c2;
    // a^2 + b^2 = |n^2 - sin^2|, with n^2 - sin^2 = (a + i b)^2.
    let re = eta * eta - k * k - s2;
    let ab2 = (re * re + 4.0 * eta * eta * k * k).max(0.0).sqrt();
    let a = (0.5 * (ab2 + re)).max(0.0).sqrt();
    let rs = (ab2 + c2 - 2.0 * a * cos_i) / (ab2 + c2 + 2.0 * a * cos_i);
    let (p, q) = (ab2 * c2 + s2 * s2, 2.0 * a * cos_i * s2);
    let rp = rs * (p - q) / (p + q);
    0.5 * (rs + rp)
}

/// The result of [`fresnel_dielectric`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DielectricFresnel {
    /// Unpolarized reflectance (1 under total internal reflection).
    pub reflectance: f64,
    /// Signed cosine of the transmitted direction (opposite sign to `cos_i`; 0 under total
    /// internal reflection).
    pub cos_t: f64,
    /// Relative IOR in the direction of travel (`eta` from outside, `1 / eta` from inside).
    pub eta_it: f64,
    /// Its reciprocal: the scale of the tangential part of the refracted direction.
    pub eta_ti: f64,
}

/// Fresnel reflectance of a dielectric interface of relative IOR `eta` (inside / outside;
/// the normal points outside) at signed incidence cosine `cos_i` (negative: from inside).
pub fn fresnel_dielectric(cos_i: f64, eta: f64) -> DielectricFresnel {
    let outside = cos_i >= 0.0;
    let (eta_it, eta_ti) = if outside { (eta, 1.0 / eta) } else { (1.0 / eta, eta) };
    let cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti;
    let ci = cos_i.abs();
    let ct = cos_t2.max(0.0).sqrt();
    let reflectance = if eta == 1.0 {
        0.0
    } else if ci == 0.0 {
        1.0
    } else {
        let a_s = (ci - eta_it * ct) / (ci + eta_it * ct);
        let a_p = (ct - eta_it * ci) / (ct + eta_it * ci);
        0.5 * (a_s * a_s + a_p * a_p)
    };
    DielectricFresnel { reflectance, cos_t: if outside { -ct } else { ct }, eta_it, eta_ti }
}

/// `v` reflected about `m`.
#[inline]
fn reflect(v: DVec3, m: DVec3) -> DVec3 {
    2.0 * v.dot(m) * m - v
}

/// `v` (on `m`'s side, `v.m > 0`) refracted through `m`, given `fresnel_dielectric(v.m, ..)`.
#[inline]
fn refract(v: DVec3, m: DVec3, fr: &DielectricFresnel) -> DVec3 {
    m * (v.dot(m) * fr.eta_ti + fr.cos_t) - v * fr.eta_ti
}

/// Mitsuba 3's `roughconductor` with `distribution = "ggx"` and an isotropic `alpha`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoughConductor {
    pub alpha: f64,
    /// Real part of the complex IOR per RGB channel.
    pub eta: [f64; 3],
    /// Imaginary part (extinction coefficient) per RGB channel.
    pub k: [f64; 3],
    pub specular_reflectance: [f64; 3],
}

impl RoughConductor {
    /// `f(light, view)` per RGB channel (all specular).
    pub fn eval(&self, light: DVec3, view: DVec3) -> [f64; 3] {
        if !(light.z > 0.0 && view.z > 0.0) {
            return [0.0; 3];
        }
        let h = (light + view).normalize();
        let distr = Ggx::new(self.alpha);
        let d = distr.d(h);
        if d == 0.0 {
            return [0.0; 3];
        }
        let base = d * distr.g(view, light, h) / (4.0 * view.z * light.z);
        let c = view.dot(h);
        std::array::from_fn(|i| self.specular_reflectance[i] * fresnel_conductor(c, self.eta[i], self.k[i]) * base)
    }
}

/// Mitsuba 3's `roughplastic` with `distribution = "ggx"`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoughPlastic {
    pub alpha: f64,
    pub int_ior: f64,
    pub ext_ior: f64,
    pub diffuse_reflectance: [f64; 3],
    pub specular_reflectance: [f64; 3],
    /// Divide by `1 - rho R_int` (colour shifts from internal scattering) rather than by
    /// `1 - R_int`.
    pub nonlinear: bool,
}

impl RoughPlastic {
    /// Relative IOR of the coating, `int_ior / ext_ior`.
    pub fn eta(&self) -> f64 {
        self.int_ior / self.ext_ior
    }

    /// The coating's tables (computed once per `(alpha, eta)` and process, then shared).
    pub fn coating(&self) -> Arc<CoatingTable> {
        coating_table(self.alpha, self.eta())
    }

    /// `(diffuse, specular)` parts of `f(light, view)`; their sum is the BRDF.
    pub fn eval_parts(&self, light: DVec3, view: DVec3) -> ([f64; 3], [f64; 3]) {
        if !(light.z > 0.0 && view.z > 0.0) {
            return ([0.0; 3], [0.0; 3]);
        }
        let eta = self.eta();
        let distr = Ggx::new(self.alpha);
        let h = (light + view).normalize();
        let fr = fresnel_dielectric(view.dot(h), eta).reflectance;
        let spec = fr * distr.d(h) * distr.g(view, light, h) / (4.0 * view.z * light.z);
        let table = self.coating();
        let (t_i, t_o) = (table.transmittance(view.z), table.transmittance(light.z));
        let scale = t_i * t_o / (PI * eta * eta);
        let r_int = table.internal_reflectance;
        let diffuse = std::array::from_fn(|c| {
            let rho = self.diffuse_reflectance[c];
            rho / (1.0 - if self.nonlinear { rho * r_int } else { r_int }) * scale
        });
        (diffuse, self.specular_reflectance.map(|s| s * spec))
    }
}

/// The rough coating's diffuse-transfer quantities for one `(alpha, eta)`, on Mitsuba's
/// discretisation: `external_transmittance[j] = T(mu_j)` at `mu_j = max(1e-6, j / 63)`, read
/// by linear interpolation in `mu` ([`transmittance`](Self::transmittance), as Mitsuba's
/// `lerp_gather`), and `internal_reflectance = 2 mean_j(R_int(mu_j) mu_j)` (Mitsuba's
/// estimate of `2 integral R_int(mu) mu dmu`, the mean over the 64 nodes rather than a
/// quadrature rule: it runs about 1.5% below the integral).
///
/// * `T(mu)`: the fraction of light arriving from outside at `cos(theta) = mu` that the rough
///   interface refracts inside, single scattering: the integral over visible normals `m` of
///   `(1 - F(wi.m, eta)) G1(wt, m)` with `wt` the refracted direction, counted when it points
///   inside (Mitsuba's `eval_transmittance`).
/// * `R_int(mu)`: the fraction of light arriving from inside that the interface reflects back
///   inside, the integral over visible normals of `F(wi.m, 1 / eta) G1(wr, m)`, with `wr` the
///   reflected direction, counted when it stays inside (`eval_reflectance` with `1 / eta`).
///
/// **How the numbers differ from Mitsuba's.** Mitsuba evaluates both integrals in `f32` with
/// one Gauss-Legendre rule over its visible-normal sample square (32 x 32 nodes for `eta > 1`,
/// 128 x 128 for `eta < 1`), whose integrands jump where the refracted or reflected direction
/// crosses the horizon and at the critical angle. Here the same integrals are taken in `f64`
/// over half-vectors, weighted by the density of visible normals, in coordinates that resolve
/// the GGX lobe (`tan(theta_h) = alpha tan(pi u / 2)`) with a composite Gauss-Legendre rule:
/// converged to ~1e-6 (the tests check it against a finer rule and against the visible-normal
/// disk, which converges much more slowly at the critical angle for small `alpha`). The
/// cross-check against Mitsuba (scripts/mitsuba_bsdf_check.py) measures what is left:
/// Mitsuba's quadrature and `f32` error.
#[derive(Clone, Debug, PartialEq)]
pub struct CoatingTable {
    pub alpha: f64,
    pub eta: f64,
    pub external_transmittance: [f64; TRANSMITTANCE_RES],
    pub internal_reflectance: f64,
}

impl CoatingTable {
    /// The cosines the table is tabulated at (`max(1e-6, j / 63)`).
    pub fn nodes() -> [f64; TRANSMITTANCE_RES] {
        std::array::from_fn(|j| (j as f64 / (TRANSMITTANCE_RES - 1) as f64).max(1e-6))
    }

    /// Compute the tables (about 4 10^6 BRDF-sized evaluations, a fraction of a second;
    /// [`coating_table`] caches them).
    pub fn compute(alpha: f64, eta: f64) -> Self {
        let distr = Ggx::new(alpha);
        let nodes = Self::nodes();
        let direction = |mu: f64| DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
        let external_transmittance = nodes.map(|mu| interface_transmittance(distr, direction(mu), eta));
        let sum: f64 = nodes.iter().map(|&mu| interface_reflectance(distr, direction(mu), 1.0 / eta) * mu).sum();
        let internal_reflectance = 2.0 * sum / TRANSMITTANCE_RES as f64;
        Self { alpha: distr.alpha(), eta, external_transmittance, internal_reflectance }
    }

    /// `T(cos)` linearly interpolated between the nodes (Mitsuba's `lerp_gather`).
    pub fn transmittance(&self, cos: f64) -> f64 {
        let x = cos * (TRANSMITTANCE_RES - 1) as f64;
        // Truncation as Mitsuba's unsigned conversion (cos > 0 here), capped at the last cell.
        let j = (x.max(0.0) as usize).min(TRANSMITTANCE_RES - 2);
        let w = x - j as f64;
        let t = &self.external_transmittance;
        (1.0 - w) * t[j] + w * t[j + 1]
    }
}

/// The coating tables of `(alpha, eta)`, computed on first use and kept for the process (a
/// BTF synthesis evaluates the BRDF millions of times from many threads). `alpha` is clamped
/// as [`Ggx::new`] does.
pub fn coating_table(alpha: f64, eta: f64) -> Arc<CoatingTable> {
    type Key = (u64, u64);
    thread_local! {
        // The last tables this thread used: no lock on the hot path.
        static LAST: std::cell::RefCell<Option<(Key, Arc<CoatingTable>)>> = const { std::cell::RefCell::new(None) };
    }
    static ALL: OnceLock<Mutex<HashMap<Key, Arc<CoatingTable>>>> = OnceLock::new();
    let key = (alpha.max(MIN_ALPHA).to_bits(), eta.to_bits());
    if let Some(t) = LAST.with(|l| l.borrow().as_ref().filter(|(k, _)| *k == key).map(|(_, t)| t.clone())) {
        return t;
    }
    let table = {
        // Computed under the lock, so threads asking at once wait for one computation rather
        // than all doing it (no rayon inside: a stolen task taking the lock would deadlock).
        let mut all = ALL.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner());
        all.entry(key).or_insert_with(|| Arc::new(CoatingTable::compute(alpha, eta))).clone()
    };
    LAST.with(|l| *l.borrow_mut() = Some((key, table.clone())));
    table
}

/// Composite Gauss-Legendre rule on `[0, 1]`: `panels` equal panels of `order` nodes each.
/// (The order-`order` rule is `biscale_core::sh::quadrature::gauss_legendre` on each panel.)
pub(crate) fn composite_rule(panels: usize, order: usize) -> Vec<(f64, f64)> {
    let h = 1.0 / panels as f64;
    (0..panels)
        .flat_map(|p| {
            let (x, w) = gauss_legendre(order, p as f64 * h, (p + 1) as f64 * h);
            x.into_iter().zip(w)
        })
        .collect()
}

/// `integral over the upper hemisphere of g(h) dh` for `g` symmetric under `y -> -y` (the
/// incident direction lies in the xz plane): `phi` over `[0, pi]`, doubled. Coordinates
/// `tan(theta_h) = alpha tan(pi u / 2)`, which turn `D(h) cos(theta_h)` into `pi/2 sin(pi u)`,
/// so GGX lobes of every width get the same resolution; a composite Gauss-Legendre rule of 32
/// panels x 8 nodes in `u` and 32 x 4 in `phi` (converged to ~1e-6 where the integrands jump,
/// see the tests).
fn over_half_vectors_xz_symmetric(alpha: f64, g: impl Fn(DVec3) -> f64) -> f64 {
    type Rule = Vec<(f64, f64)>;
    thread_local! {
        static RULES: (Rule, Rule) = (composite_rule(32, 8), composite_rule(32, 4));
    }
    RULES.with(|(ru, rp)| {
        let mut total = 0.0;
        for &(u, wu) in ru {
            let (s, c) = (0.5 * PI * u).sin_cos();
            let (st, ct) = (alpha * s).atan2(c).sin_cos();
            let dtheta = 0.5 * PI * alpha / (c * c + alpha * alpha * s * s);
            let mut ring = 0.0;
            for &(p, wp) in rp {
                let (sp, cp) = (PI * p).sin_cos();
                ring += wp * g(DVec3::new(st * cp, st * sp, ct));
            }
            total += wu * 2.0 * PI * ring * st * dtheta;
        }
        total
    })
}

/// The density of visible normals `G1(wi, m) max(0, wi.m) D(m) / wi_z`.
#[inline]
fn vndf(distr: Ggx, wi: DVec3, m: DVec3) -> f64 {
    distr.smith_g1(wi, m) * wi.dot(m).max(0.0) * distr.d(m) / wi.z
}

/// Single-scattering transmittance of the rough interface of relative IOR `eta` for light
/// arriving from the side of direction `wi` (`wi.z > 0`; `eta` is the IOR across the
/// interface from there). See [`CoatingTable`].
pub fn interface_transmittance(distr: Ggx, wi: DVec3, eta: f64) -> f64 {
    over_half_vectors_xz_symmetric(distr.alpha(), |m| {
        let v = vndf(distr, wi, m);
        if v == 0.0 {
            return 0.0;
        }
        let fr = fresnel_dielectric(wi.dot(m), eta);
        let wt = refract(wi, m, &fr);
        if wt.z >= 0.0 {
            return 0.0;
        }
        v * (1.0 - fr.reflectance) * distr.smith_g1(wt, m)
    })
}

/// Single-scattering specular albedo of the rough interface of relative IOR `eta` seen from
/// direction `wi` (`wi.z > 0`). See [`CoatingTable`].
pub fn interface_reflectance(distr: Ggx, wi: DVec3, eta: f64) -> f64 {
    over_half_vectors_xz_symmetric(distr.alpha(), |m| {
        let v = vndf(distr, wi, m);
        let wr = reflect(wi, m);
        if v == 0.0 || wr.z <= 0.0 {
            return 0.0;
        }
        v * fresnel_dielectric(wi.dot(m), eta).reflectance * distr.smith_g1(wr, m)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// `integral over the upper hemisphere of g(h) dh`, in `(u, phi)` with
    /// `tan(theta_h) = alpha tan(pi u / 2)`: the substitution that turns `D(h) cos(theta_h)`
    /// into `pi / 2 sin(pi u)` (so GGX lobes of any width are resolved by the same nodes).
    /// Composite Gauss-Legendre in both; `phi` panels are many because integrands depending on
    /// a direction `wo` jump where the reflected direction crosses the horizon.
    fn over_half_vectors(alpha: f64, panels: (usize, usize), g: impl Fn(DVec3) -> f64) -> f64 {
        let ru = composite_rule(panels.0, 8);
        let rp = composite_rule(panels.1, 4);
        let mut total = 0.0;
        for &(u, wu) in &ru {
            let (s, c) = (0.5 * PI * u).sin_cos();
            let theta = (alpha * s).atan2(c);
            let dtheta = 0.5 * PI * alpha / (c * c + alpha * alpha * s * s);
            let (st, ct) = theta.sin_cos();
            let mut ring = 0.0;
            for &(p, wp) in &rp {
                let (sp, cp) = (2.0 * PI * p).sin_cos();
                ring += wp * g(DVec3::new(st * cp, st * sp, ct));
            }
            total += wu * 2.0 * PI * ring * st * dtheta;
        }
        total
    }

    fn dir(theta_deg: f64, phi_deg: f64) -> DVec3 {
        let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    fn random_dir(rng: &mut rand_chacha::ChaCha8Rng) -> DVec3 {
        let z: f64 = rng.gen_range(0.02..1.0);
        let phi: f64 = rng.gen_range(0.0..2.0 * PI);
        let s = (1.0 - z * z).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z)
    }

    const ALPHAS: [f64; 5] = [0.05, 0.1, 0.3, 0.6, 1.0];

    /// Aluminium-like and gold-like complex IORs (RGB), and Mitsuba's default (eta 0, k 1).
    fn conductor(alpha: f64) -> RoughConductor {
        RoughConductor { alpha, eta: [1.66, 0.88, 0.52], k: [9.22, 6.27, 4.84], specular_reflectance: [1.0; 3] }
    }

    fn plastic(alpha: f64) -> RoughPlastic {
        RoughPlastic {
            alpha,
            int_ior: 1.49,
            ext_ior: 1.000277,
            diffuse_reflectance: [0.5, 0.25, 1.0],
            specular_reflectance: [1.0; 3],
            nonlinear: false,
        }
    }

    /// `integral over the visible normals m of wi of g(m)`: the Heitz 2018 disk in polar
    /// coordinates (`u1 = r^2`, so `r` is weighted by `2 r`), `panels` x 8 nodes per axis.
    fn over_visible_normals(distr: Ggx, wi: DVec3, panels: usize, g: impl Fn(DVec3) -> f64) -> f64 {
        let rule = composite_rule(panels, 8);
        let mut total = 0.0;
        for &(r, wr) in &rule {
            let mut ring = 0.0;
            for &(u, wu) in &rule {
                ring += wu * g(distr.visible_normal_polar(wi, r, 2.0 * PI * u));
            }
            total += 2.0 * r * wr * ring;
        }
        total
    }

    #[test]
    fn composite_rule_integrates_polynomials_exactly() {
        // Order n per panel is exact to degree 2n - 1: x^7 with 4 nodes, to rounding (1e-14).
        let w: f64 = composite_rule(3, 4).iter().map(|p| p.1).sum();
        assert!((w - 1.0).abs() < 1e-14);
        let c: f64 = composite_rule(3, 4).iter().map(|&(x, w)| w * x.powi(7)).sum();
        assert!((c - 1.0 / 8.0).abs() < 1e-14, "{c}");
    }

    #[test]
    fn ggx_d_is_normalised() {
        // integral D(h) cos(theta_h) dh = 1. After the substitution the integrand is smooth
        // ((pi/2) sin(pi u) if D is right), so 16 x 8 nodes in u give ~1e-15 and 8 x 4 in phi
        // are exact for the phi-independent D: 1e-10 leaves room only for rounding, and a
        // wrong constant or exponent in D would fail by orders of magnitude more.
        for alpha in ALPHAS {
            let d = Ggx::new(alpha);
            let i = over_half_vectors(alpha, (16, 8), |h| d.d(h) * h.z);
            assert!((i - 1.0).abs() < 1e-10, "alpha {alpha}: {i}");
        }
    }

    #[test]
    fn weak_white_furnace() {
        // Heitz 2014 eq. 80: integral over all wi (the whole sphere) of G1(wo, h) D(h) /
        // (4 cos_o) = 1, with h = normalize(wi + wo). In half-vectors (dwi = 4 |wo.h| dh, wi =
        // reflect(wo, h)) it is integral G1(wo, h) max(0, wo.h) D(h) / cos_o dh. The integrand
        // has only a kink where wo.h = 0, so composite quadrature converges to ~1e-6 at
        // grazing wo; 1e-5 is the bound.
        for alpha in ALPHAS {
            let d = Ggx::new(alpha);
            for theta in [0.0, 30.0, 60.0, 80.0, 88.0] {
                let wo = dir(theta, 20.0);
                let i = over_half_vectors(alpha, (32, 64), |h| d.smith_g1(wo, h) * wo.dot(h).max(0.0) * d.d(h) / wo.z);
                assert!((i - 1.0).abs() < 1e-5, "alpha {alpha}, theta_o {theta}: {i}");
            }
        }
    }

    #[test]
    fn brdfs_are_reciprocal() {
        // Both are symmetric in (light, view) term by term (module docs); the only asymmetry
        // is rounding (view.h against light.h in F, the order of products): 1e-12 relative.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(33);
        for alpha in ALPHAS {
            let (c, p) = (conductor(alpha), RoughPlastic { nonlinear: true, ..plastic(alpha) });
            for _ in 0..500 {
                let (l, v) = (random_dir(&mut rng), random_dir(&mut rng));
                let (a, b) = (c.eval(l, v), c.eval(v, l));
                let (pa, pb) = (p.eval_parts(l, v), p.eval_parts(v, l));
                for ch in 0..3 {
                    assert!((a[ch] - b[ch]).abs() <= 1e-12 * a[ch].abs().max(1e-300), "{a:?} vs {b:?}");
                    for (x, y) in [(pa.0[ch], pb.0[ch]), (pa.1[ch], pb.1[ch])] {
                        assert!((x - y).abs() <= 1e-12 * x.abs().max(1e-300), "{pa:?} vs {pb:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn below_the_horizon_is_zero() {
        let (c, p) = (conductor(0.3), plastic(0.3));
        for (l, v) in [(dir(100.0, 0.0), dir(30.0, 0.0)), (dir(30.0, 0.0), dir(90.5, 180.0))] {
            assert_eq!(c.eval(l, v), [0.0; 3]);
            assert_eq!(p.eval_parts(l, v), ([0.0; 3], [0.0; 3]));
        }
    }

    /// Directional albedo `integral f(wi, wo) cos_i dwi` of the specular part `spec` (a
    /// function of (light, view) with the GGX lobe of `alpha`) for view `wo`, in half-vectors.
    fn specular_albedo(alpha: f64, wo: DVec3, spec: impl Fn(DVec3, DVec3) -> f64) -> f64 {
        over_half_vectors(alpha, (32, 64), |h| {
            let c = wo.dot(h);
            if c <= 0.0 {
                return 0.0;
            }
            let wi = reflect(wo, h);
            if wi.z <= 0.0 {
                return 0.0;
            }
            spec(wi, wo) * wi.z * 4.0 * c
        })
    }

    /// `integral f cos_i dwi` of a diffuse part, in `(mu, phi)`: the rough plastic's diffuse
    /// term is piecewise linear in `mu` with nodes at `j / 63`, so 63 panels of 4 nodes are
    /// exact in `mu` (and it does not depend on `phi`).
    fn diffuse_albedo(wo: DVec3, diff: impl Fn(DVec3, DVec3) -> f64) -> f64 {
        let rule = composite_rule(TRANSMITTANCE_RES - 1, 4);
        rule.iter()
            .map(|&(mu, w)| {
                let wi = DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
                w * 2.0 * PI * diff(wi, wo) * mu
            })
            .sum()
    }

    #[test]
    fn energy_is_bounded_and_single_scattering_loses_more_with_alpha() {
        // The albedo quadrature is good to ~1e-5 (the furnace test's accuracy; the lobe is the
        // same); bounds below have at least that margin.
        let mirror = |alpha| RoughConductor { alpha, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] };
        let mut last_normal = 1.0;
        for alpha in ALPHAS {
            let (m, c) = (mirror(alpha), conductor(alpha));
            for theta in [0.0, 20.0, 40.0, 60.0, 75.0, 85.0, 89.0] {
                let wo = dir(theta, 45.0);
                let a_m = specular_albedo(alpha, wo, |l, v| m.eval(l, v)[0]);
                assert!(a_m <= 1.0 + 1e-5, "F = 1, alpha {alpha}, theta {theta}: albedo {a_m}");
                for ch in 0..3 {
                    let a_c = specular_albedo(alpha, wo, |l, v| c.eval(l, v)[ch]);
                    assert!(a_c <= a_m + 1e-5, "conductor above the F = 1 mirror: {a_c} > {a_m}");
                }
                if theta == 0.0 {
                    // F = 1 loses only multiple scattering: ~0 at alpha 0.05, growing with alpha.
                    assert!(a_m < last_normal, "alpha {alpha}: {a_m} not below {last_normal}");
                    last_normal = a_m;
                    if alpha == 0.05 {
                        assert!(a_m > 0.995, "{a_m}");
                    }
                }
            }
        }
        // At alpha = 1 and normal incidence D(h) h_z is the cosine distribution, theta_i =
        // 2 theta_h and G1(wi) = 2 cos_i / (1 + cos_i), so the albedo is integral_0^1 c / (1 + c)
        // dc = 1 - ln 2: single-scattering GGX returns only 31% there.
        assert!((last_normal - (1.0 - 2f64.ln())).abs() < 1e-5, "{last_normal}");

        // Rough plastic, white base (the largest diffuse term), both internal-scattering modes.
        for alpha in ALPHAS {
            for nonlinear in [false, true] {
                let p = RoughPlastic { diffuse_reflectance: [1.0; 3], nonlinear, ..plastic(alpha) };
                for theta in [0.0, 30.0, 60.0, 80.0, 89.0] {
                    let wo = dir(theta, 10.0);
                    let s = specular_albedo(alpha, wo, |l, v| p.eval_parts(l, v).1[0]);
                    let d = diffuse_albedo(wo, |l, v| p.eval_parts(l, v).0[0]);
                    assert!(s + d <= 1.0 + 1e-5, "alpha {alpha}, theta {theta}: {s} + {d}");
                }
            }
        }
    }

    #[test]
    fn conductor_fresnel() {
        // Normal incidence: ((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2) to rounding.
        for (eta, k) in [(1.66, 9.22), (0.18, 3.4), (0.0, 1.0), (1.5, 0.0), (2.9, 3.1)] {
            let f0 = ((eta - 1.0f64).powi(2) + k * k) / ((eta + 1.0f64).powi(2) + k * k);
            assert!((fresnel_conductor(1.0, eta, k) - f0).abs() < 1e-14, "{eta} {k}");
        }
        // Mitsuba's default conductor (eta 0, k 1) is a perfect mirror at every angle.
        for c in [1.0, 0.7, 0.3, 0.01] {
            assert!((fresnel_conductor(c, 0.0, 1.0) - 1.0).abs() < 1e-14);
        }
        // Every angle against the amplitude formulas in complex arithmetic:
        // r_s = (cos - w) / (cos + w), r_p = (n^2 cos - w) / (n^2 cos + w), w = sqrt(n^2 - sin^2).
        #[derive(Clone, Copy)]
        struct C(f64, f64);
        let mul = |a: C, b: C| C(a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
        let div = |a: C, b: C| {
            let n = b.0 * b.0 + b.1 * b.1;
            C((a.0 * b.0 + a.1 * b.1) / n, (a.1 * b.0 - a.0 * b.1) / n)
        };
        let sqrt = |a: C| {
            let r = (a.0 * a.0 + a.1 * a.1).sqrt();
            let re = ((r + a.0) / 2.0).sqrt();
            let im = ((r - a.0) / 2.0).max(0.0).sqrt().copysign(a.1);
            C(re, im)
        };
        let norm2 = |a: C| a.0 * a.0 + a.1 * a.1;
        for (eta, k) in [(1.66, 9.22), (0.18, 3.4), (2.9, 3.1), (1.5, 0.0)] {
            let n2 = mul(C(eta, k), C(eta, k));
            for deg in [0.0, 15.0, 45.0, 70.0, 85.0, 89.9] {
                let c = f64::to_radians(deg).cos();
                let w = sqrt(C(n2.0 - (1.0 - c * c), n2.1));
                let rs = norm2(div(C(c - w.0, -w.1), C(c + w.0, w.1)));
                let nc = C(n2.0 * c, n2.1 * c);
                let rp = norm2(div(C(nc.0 - w.0, nc.1 - w.1), C(nc.0 + w.0, nc.1 + w.1)));
                let got = fresnel_conductor(c, eta, k);
                assert!((got - 0.5 * (rs + rp)).abs() < 1e-12, "{eta} {k} {deg}: {got} vs {}", 0.5 * (rs + rp));
            }
        }
    }

    #[test]
    fn dielectric_fresnel() {
        // The exact formulas via Snell's law in angles: r_s = -sin(ti - tt) / sin(ti + tt),
        // r_p = tan(ti - tt) / tan(ti + tt) (Born and Wolf), to rounding.
        for eta in [1.49, 1.33, 2.4] {
            for deg in [10.0f64, 30.0, 50.0, 70.0, 85.0] {
                let ti = deg.to_radians();
                let tt = (ti.sin() / eta).asin();
                let rs = ((ti - tt).sin() / (ti + tt).sin()).powi(2);
                let rp = ((ti - tt).tan() / (ti + tt).tan()).powi(2);
                let f = fresnel_dielectric(ti.cos(), eta);
                assert!((f.reflectance - 0.5 * (rs + rp)).abs() < 1e-13, "{eta} {deg}");
                assert!((f.cos_t + tt.cos()).abs() < 1e-13, "transmitted cosine is negative");
                // From inside at the transmitted angle: the same reflectance (Stokes).
                let back = fresnel_dielectric(-tt.cos(), eta);
                assert!((back.reflectance - f.reflectance).abs() < 1e-13);
            }
            // Normal incidence ((eta - 1) / (eta + 1))^2; from inside past the critical angle, 1.
            let f0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
            assert!((fresnel_dielectric(1.0, eta).reflectance - f0).abs() < 1e-15);
            let critical = (1.0 / eta).asin();
            for extra in [1e-6, 0.1, 0.5] {
                let f = fresnel_dielectric(-(critical + extra).cos(), eta);
                assert_eq!((f.reflectance, f.cos_t), (1.0, 0.0), "{eta}: total internal reflection");
            }
            assert!(fresnel_dielectric(-(critical - 1e-3).cos(), eta).reflectance < 1.0);
        }
        assert_eq!(fresnel_dielectric(0.7, 1.0).reflectance, 0.0, "index matched");
    }

    #[test]
    fn interface_integrals_agree_with_independent_quadratures() {
        // The coating tables integrate over half-vectors (phi in [0, pi], doubled). References:
        // (1) the same integrals over the visible-normal disk of Heitz 2018 (other coordinates,
        // other nodes), 64 x 8 nodes per axis, which converges slowly where the integrand jumps
        // (the reflected / refracted direction crossing the horizon, the critical angle) and
        // squeezes GGX's long tail (where total internal reflection makes F = 1) into a thin
        // ring at the disk's rim: 6e-4 off at alpha 0.05, so 1e-3 absolute; (2) the full-phi
        // half-vector rule at twice the resolution: the tables' own convergence, measured at
        // ~1e-6 for most cases but up to 3e-5 at grazing incidence (mu = 1e-6), where the
        // visibility boundary wi.h = 0 runs through the lobe's centre: 2e-4 leaves margin.
        for alpha in [0.05, 0.3, 1.0] {
            let d = Ggx::new(alpha);
            for mu in [1e-6, 0.1, 0.4, 0.8, 1.0] {
                let wi = DVec3::new((1.0f64 - mu * mu).max(0.0).sqrt(), 0.0, mu);
                for eta in [1.49, 1.0 / 1.49] {
                    let t_of = |m: DVec3| {
                        let fr = fresnel_dielectric(wi.dot(m), eta);
                        let wt = refract(wi, m, &fr);
                        if wt.z >= 0.0 {
                            0.0
                        } else {
                            (1.0 - fr.reflectance) * d.smith_g1(wt, m)
                        }
                    };
                    let r_of = |m: DVec3| {
                        let wr = reflect(wi, m);
                        if wr.z <= 0.0 {
                            0.0
                        } else {
                            fresnel_dielectric(wi.dot(m), eta).reflectance * d.smith_g1(wr, m)
                        }
                    };
                    let (t, r) = (interface_transmittance(d, wi, eta), interface_reflectance(d, wi, eta));
                    let (t_disk, r_disk) =
                        (over_visible_normals(d, wi, 64, t_of), over_visible_normals(d, wi, 64, r_of));
                    let weighted = |g: &dyn Fn(DVec3) -> f64| {
                        over_half_vectors(alpha, (64, 128), |h| {
                            let v = vndf(d, wi, h);
                            if v == 0.0 {
                                0.0
                            } else {
                                v * g(h)
                            }
                        })
                    };
                    let (t_fine, r_fine) = (weighted(&t_of), weighted(&r_of));
                    let at = format!("alpha {alpha} mu {mu} eta {eta}");
                    assert!((r - r_disk).abs() < 1e-3, "R {at}: {r} vs disk {r_disk}");
                    // The tables use T from outside only (from inside, T ~ 0.002 slivers that
                    // escape total internal reflection are what neither rule resolves well).
                    if eta > 1.0 {
                        assert!((t - t_disk).abs() < 1e-3, "T {at}: {t} vs disk {t_disk}");
                        assert!((t - t_fine).abs() < 2e-4, "T {at}: {t} vs fine {t_fine}");
                    }
                    assert!((r - r_fine).abs() < 2e-4, "R {at}: {r} vs fine {r_fine}");
                    assert!(r + t <= 1.0 + 1e-6, "{r} + {t}");
                }
            }
        }
        // Nearly smooth: the Fresnel values (2e-3: what roughness 1e-3 and the jumps leave).
        let d = Ggx::new(1e-3);
        for mu in [0.3f64, 0.7, 1.0] {
            let wi = DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
            let f = fresnel_dielectric(mu, 1.49).reflectance;
            assert!((interface_transmittance(d, wi, 1.49) - (1.0 - f)).abs() < 2e-3);
            assert!((interface_reflectance(d, wi, 1.49) - f).abs() < 2e-3);
        }
    }

    #[test]
    fn coating_table_follows_mitsubas_discretisation() {
        let t = coating_table(0.3, 1.49);
        assert!(Arc::ptr_eq(&t, &coating_table(0.3, 1.49)), "cached");
        // The table is read by linear interpolation through its nodes.
        let nodes = CoatingTable::nodes();
        for j in [1, 17, 40, 63] {
            assert!((t.transmittance(nodes[j]) - t.external_transmittance[j]).abs() < 1e-12);
        }
        let mid = 0.5 * (nodes[10] + nodes[11]);
        let avg = 0.5 * (t.external_transmittance[10] + t.external_transmittance[11]);
        assert!((t.transmittance(mid) - avg).abs() < 1e-12);
        assert!(t.external_transmittance.iter().all(|&x| (0.0..=1.0).contains(&x)));
        // Nearly smooth coating: R_int is Mitsuba's mean over the nodes of 2 mu R(mu), which is
        // (63/64) (the trapezoid rule + its end terms / 63): about 1.5% below the smooth
        // interface's exact 2 integral F(mu, 1/eta) mu dmu (~0.596 for 1.49). 2% is the bound.
        let smooth = coating_table(1e-3, 1.49);
        let exact: f64 = composite_rule(200, 8)
            .iter()
            .map(|&(mu, w)| 2.0 * w * mu * fresnel_dielectric(mu, 1.0 / 1.49).reflectance)
            .sum();
        let rel = (smooth.internal_reflectance - exact) / exact;
        assert!((-0.02..0.0).contains(&rel), "{} vs {exact}", smooth.internal_reflectance);
    }

    #[test]
    fn a_flat_synthesized_patch_is_the_analytic_brdf() {
        // A flat patch is tabulated at the bin centres (light and view) times the light bin's
        // mean cosine (synth module docs), not bin-averaged: compare with that. The BTF is
        // f32 and bin directions are f32 (6e-8 relative), which the alpha = 0.2 lobe amplifies
        // to ~1e-6: 1e-5 relative.
        use crate::synth::{synthesize, Brdf, BtfSpec, HeightField};
        use biscale_core::basis::LocalBasis;
        let brdf = Brdf::RoughConductor {
            alpha: 0.2,
            eta: [0.2, 0.9, 1.1],
            k: [3.9, 2.4, 2.2],
            specular_reflectance: [1.0, 0.9, 0.8],
        };
        let spec = BtfSpec {
            resolution: 4,
            local_basis: LocalBasis::bins(6).unwrap(),
            view_grid: Some(6),
            ..BtfSpec::new(HeightField::flat(8).unwrap(), brdf)
        };
        let btf = synthesize(&spec, None).unwrap();
        let (lg, vg) = (btf.local_basis().grid().unwrap(), btf.view_grid().unwrap());
        let c = RoughConductor {
            alpha: 0.2,
            eta: [0.2, 0.9, 1.1],
            k: [3.9, 2.4, 2.2],
            specular_reflectance: [1.0, 0.9, 0.8],
        };
        for v in 0..vg.len() {
            for j in 0..lg.len() {
                let l = lg.bin_direction(j as u32).as_dvec3();
                let e = vg.bin_direction(v as u32).as_dvec3();
                let f = c.eval(l, e);
                let got = btf.data()[v * btf.light_count() + j];
                for ch in 0..3 {
                    let want = f[ch] * lg.bin_mean_cosine(j as u32);
                    assert!(
                        (got[ch] as f64 - want).abs() <= 1e-5 * want.abs() + 1e-9,
                        "v {v} j {j}: {got:?} vs {want}"
                    );
                }
            }
        }
    }
}
