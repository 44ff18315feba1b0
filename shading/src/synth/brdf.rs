//! The meso-scale BRDFs a synthesized BTF can be built from, evaluated in a local frame
//! (+Z = the meso-surface normal, +X = the tangent: the patch's +X projected onto the facet).
//!
//! * Lambertian: `f = albedo / pi`.
//! * Phong: the normalized modified Phong BRDF of [`phong_brdf`].
//! * Ashikhmin-Shirley: the anisotropic Phong BRDF of Ashikhmin and Shirley 2000 ("An
//!   anisotropic Phong BRDF model", J. Graphics Tools 5(2)), equations 4 (specular, with
//!   Schlick's Fresnel term) and 5 (the coupled diffuse term). `nu` is the exponent for
//!   half-vectors tilted towards the tangent (+X), `nv` towards the bitangent (+Y).
//! * Rough conductor and rough plastic: the GGX microfacet BRDFs of Mitsuba 3's
//!   `roughconductor` and `roughplastic` plugins (`distribution = "ggx"`), with Mitsuba's
//!   parameter names and defaults; see [`crate::microfacet`].
//!
//! Evaluation returns the diffuse and specular parts separately, because an
//! [`AlbedoMap`](super::AlbedoMap) scales the diffuse part only.

use crate::error::{Result, ShadingError};
use crate::microfacet;
use biscale_core::scene::btf::phong_brdf;
use biscale_core::Rgb;
use glam::DVec3;
use std::f64::consts::PI;

/// A meso-scale BRDF (see the module docs); a config's `brdf = { kind = "phong", ... }` table
/// deserializes into it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Brdf {
    /// `f = albedo / pi`.
    Lambertian { albedo: Rgb },
    /// `f = kd / pi + ks (n + 2) / (2 pi) cos^n(alpha)` ([`phong_brdf`]).
    Phong { kd: Rgb, ks: Rgb, exponent: f32 },
    /// Ashikhmin-Shirley: diffuse reflectance `rd`, specular reflectance at normal incidence
    /// `rs`, Phong-like exponents `nu` (along the tangent) and `nv` (along the bitangent).
    AshikhminShirley { rd: Rgb, rs: Rgb, nu: f32, nv: f32 },
    /// Mitsuba 3's `roughconductor` with GGX ([`microfacet::RoughConductor`]): roughness
    /// `alpha` (default 0.1), complex IOR `eta + i k` per channel (default `eta = 0`, `k = 1`:
    /// Mitsuba's default, `F = 1`, a perfect rough mirror) and `specular_reflectance` (default
    /// 1). All specular: an albedo map does not change it.
    RoughConductor {
        #[serde(default = "default_alpha")]
        alpha: f32,
        #[serde(default = "default_conductor_eta")]
        eta: Rgb,
        #[serde(default = "default_conductor_k")]
        k: Rgb,
        #[serde(default = "default_one")]
        specular_reflectance: Rgb,
    },
    /// Mitsuba 3's `roughplastic` with GGX ([`microfacet::RoughPlastic`]): roughness `alpha`
    /// (default 0.1), `int_ior` (default 1.49, polypropylene), `ext_ior` (default 1.000277,
    /// air), `diffuse_reflectance` (default 0.5), `specular_reflectance` (default 1) and
    /// `nonlinear` (default false). An albedo map scales the diffuse term as evaluated (with
    /// `nonlinear = true` that is not the same as scaling `diffuse_reflectance`).
    RoughPlastic {
        #[serde(default = "default_alpha")]
        alpha: f32,
        #[serde(default = "default_int_ior")]
        int_ior: f32,
        #[serde(default = "default_ext_ior")]
        ext_ior: f32,
        #[serde(default = "default_diffuse_reflectance")]
        diffuse_reflectance: Rgb,
        #[serde(default = "default_one")]
        specular_reflectance: Rgb,
        #[serde(default)]
        nonlinear: bool,
    },
}

// Mitsuba 3's defaults (roughconductor.cpp, roughplastic.cpp, microfacet.h).
fn default_alpha() -> f32 {
    0.1
}
fn default_conductor_eta() -> Rgb {
    [0.0; 3]
}
fn default_conductor_k() -> Rgb {
    [1.0; 3]
}
fn default_one() -> Rgb {
    [1.0; 3]
}
fn default_int_ior() -> f32 {
    1.49
}
fn default_ext_ior() -> f32 {
    1.000277
}
fn default_diffuse_reflectance() -> Rgb {
    [0.5; 3]
}

/// The smallest and largest microfacet roughness accepted. Below, Mitsuba clamps to `1e-4`
/// (so smaller values would not mean the same there); above 1 the surface is rougher than any
/// finish Mitsuba's docs describe (0.3-0.7 is "extremely rough"), and single-scattering GGX
/// already returns only `1 - ln 2` (31%) of the light at alpha = 1 and normal incidence.
pub const ALPHA_RANGE: std::ops::RangeInclusive<f32> = 1e-4..=1.0;

fn check_alpha(what: &str, alpha: f32) -> Result<()> {
    if alpha.is_finite() && ALPHA_RANGE.contains(&alpha) {
        Ok(())
    } else {
        Err(ShadingError::Invalid(format!(
            "{what} alpha must be finite and in [{}, {}], got {alpha}",
            ALPHA_RANGE.start(),
            ALPHA_RANGE.end()
        )))
    }
}

fn check_ior(what: &str, ior: f32) -> Result<()> {
    if ior.is_finite() && ior > 0.0 {
        Ok(())
    } else {
        Err(ShadingError::Invalid(format!("{what} must be finite and > 0, got {ior}")))
    }
}

fn check_rgb(what: &str, v: Rgb, max: f32) -> Result<()> {
    if v.iter().all(|x| x.is_finite() && (0.0..=max).contains(x)) {
        Ok(())
    } else {
        Err(ShadingError::Invalid(format!("{what} must be finite and in [0, {max}], got {v:?}")))
    }
}

impl Brdf {
    /// Short name for reports: `lambertian`, `phong`, `ashikhmin-shirley`, `rough-conductor`,
    /// `rough-plastic`.
    pub fn kind(&self) -> &'static str {
        match self {
            Brdf::Lambertian { .. } => "lambertian",
            Brdf::Phong { .. } => "phong",
            Brdf::AshikhminShirley { .. } => "ashikhmin-shirley",
            Brdf::RoughConductor { .. } => "rough-conductor",
            Brdf::RoughPlastic { .. } => "rough-plastic",
        }
    }

    /// Check the parameters: reflectances finite and non-negative (`rs <= 1`: it is a Fresnel
    /// reflectance), exponents finite, `>= 0` for Phong and `> 0` for Ashikhmin-Shirley. For
    /// the microfacet BRDFs: `alpha` in [`ALPHA_RANGE`]; Mitsuba's reflectances in `[0, 1]`;
    /// a conductor's `eta` and `k` finite and `>= 0` (`eta = 0` is Mitsuba's default) but not
    /// both 0 (the Fresnel term is 0/0 there); a plastic's IORs finite, `> 0` and different
    /// (Mitsuba refuses equal ones: the coating would vanish).
    pub fn validate(&self) -> Result<()> {
        match *self {
            Brdf::Lambertian { albedo } => check_rgb("lambertian albedo", albedo, f32::MAX),
            Brdf::Phong { kd, ks, exponent } => {
                check_rgb("phong kd", kd, f32::MAX)?;
                check_rgb("phong ks", ks, f32::MAX)?;
                if !(exponent.is_finite() && exponent >= 0.0) {
                    return Err(ShadingError::Invalid(format!(
                        "phong exponent must be finite and >= 0, got {exponent}"
                    )));
                }
                Ok(())
            }
            Brdf::AshikhminShirley { rd, rs, nu, nv } => {
                check_rgb("ashikhmin-shirley rd", rd, f32::MAX)?;
                check_rgb("ashikhmin-shirley rs", rs, 1.0)?;
                for (name, e) in [("nu", nu), ("nv", nv)] {
                    if !(e.is_finite() && e > 0.0) {
                        return Err(ShadingError::Invalid(format!(
                            "ashikhmin-shirley {name} must be finite and > 0, got {e}"
                        )));
                    }
                }
                Ok(())
            }
            Brdf::RoughConductor { alpha, eta, k, specular_reflectance } => {
                check_alpha("rough-conductor", alpha)?;
                check_rgb("rough-conductor eta", eta, f32::MAX)?;
                check_rgb("rough-conductor k", k, f32::MAX)?;
                check_rgb("rough-conductor specular_reflectance", specular_reflectance, 1.0)?;
                if (0..3).any(|c| eta[c] == 0.0 && k[c] == 0.0) {
                    return Err(ShadingError::Invalid(format!(
                        "rough-conductor eta and k must not both be 0 in a channel, got eta {eta:?}, k {k:?}"
                    )));
                }
                Ok(())
            }
            Brdf::RoughPlastic { alpha, int_ior, ext_ior, diffuse_reflectance, specular_reflectance, .. } => {
                check_alpha("rough-plastic", alpha)?;
                check_ior("rough-plastic int_ior", int_ior)?;
                check_ior("rough-plastic ext_ior", ext_ior)?;
                if int_ior == ext_ior {
                    return Err(ShadingError::Invalid(format!(
                        "rough-plastic int_ior and ext_ior must differ, both are {int_ior}"
                    )));
                }
                check_rgb("rough-plastic diffuse_reflectance", diffuse_reflectance, 1.0)?;
                check_rgb("rough-plastic specular_reflectance", specular_reflectance, 1.0)
            }
        }
    }

    /// `(diffuse, specular)` parts of `f(light, view)`, both local unit directions with
    /// `z > 0` (callers make sure of it). Their sum is the BRDF.
    pub fn eval_parts(&self, light: DVec3, view: DVec3) -> ([f64; 3], [f64; 3]) {
        match *self {
            Brdf::Lambertian { albedo } => (albedo.map(|a| a as f64 / PI), [0.0; 3]),
            Brdf::Phong { kd, ks, exponent } => {
                // phong_brdf computes kd/pi + ks * lobe per channel; kd = 0 leaves the lobe.
                let spec = phong_brdf([0.0; 3], ks, exponent as f64, light.as_vec3(), view.as_vec3());
                (kd.map(|a| a as f64 / PI), spec)
            }
            Brdf::AshikhminShirley { rd, rs, nu, nv } => ashikhmin_shirley(rd, rs, nu as f64, nv as f64, light, view),
            Brdf::RoughConductor { alpha, eta, k, specular_reflectance } => {
                let c = microfacet::RoughConductor {
                    alpha: alpha as f64,
                    eta: eta.map(f64::from),
                    k: k.map(f64::from),
                    specular_reflectance: specular_reflectance.map(f64::from),
                };
                ([0.0; 3], c.eval(light, view))
            }
            Brdf::RoughPlastic { alpha, int_ior, ext_ior, diffuse_reflectance, specular_reflectance, nonlinear } => {
                microfacet::RoughPlastic {
                    alpha: alpha as f64,
                    int_ior: int_ior as f64,
                    ext_ior: ext_ior as f64,
                    diffuse_reflectance: diffuse_reflectance.map(f64::from),
                    specular_reflectance: specular_reflectance.map(f64::from),
                    nonlinear,
                }
                .eval_parts(light, view)
            }
        }
    }

    /// `f(light, view)` per RGB channel, both local unit directions (+Z the shading normal);
    /// 0 when either is at or below the horizon (as Mitsuba's BSDFs). What the ground-truth
    /// reference evaluates at each texel's exact direction for a flat analytic material.
    pub fn eval(&self, light: DVec3, view: DVec3) -> [f64; 3] {
        if !(light.z > 0.0 && view.z > 0.0) {
            return [0.0; 3];
        }
        let (d, s) = self.eval_parts(light, view);
        std::array::from_fn(|c| d[c] + s[c])
    }

    /// A rough plastic's coating tables (`None` for another kind), for the relative IOR
    /// `int_ior / ext_ior` its evaluation uses (`CoatingTable::eta`): what the f32 lanes and the
    /// GPU upload, so that every evaluation reads the same table.
    pub fn coating(&self) -> Option<std::sync::Arc<microfacet::CoatingTable>> {
        match *self {
            Brdf::RoughPlastic { alpha, int_ior, ext_ior, .. } => {
                Some(microfacet::coating_table(alpha as f64, int_ior as f64 / ext_ior as f64))
            }
            _ => None,
        }
    }

    /// One BRDF of every kind, with parameters away from the defaults (a coloured conductor
    /// and Mitsuba's default perfect one, a linear and a nonlinear plastic): the cases each
    /// implementation of the kinds is held to the others on (this `eval` in f64, the CPU's f32
    /// lanes in `crate::analytic`, the WGSL of `biscale-gpu`).
    pub fn one_of_each() -> Vec<Brdf> {
        vec![
            Brdf::Lambertian { albedo: [0.7, 0.5, 0.3] },
            Brdf::Phong { kd: [0.3, 0.25, 0.2], ks: [0.4, 0.5, 0.6], exponent: 24.0 },
            Brdf::AshikhminShirley { rd: [0.4, 0.3, 0.2], rs: [0.05, 0.1, 0.2], nu: 40.0, nv: 8.0 },
            Brdf::RoughConductor {
                alpha: 0.15,
                eta: [0.143, 0.374, 1.442],
                k: [3.983, 2.385, 1.603],
                specular_reflectance: [1.0, 0.9, 0.8],
            },
            Brdf::RoughConductor { alpha: 0.3, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] },
            Brdf::RoughPlastic {
                alpha: 0.2,
                int_ior: 1.49,
                ext_ior: 1.000277,
                diffuse_reflectance: [0.6, 0.3, 0.2],
                specular_reflectance: [1.0; 3],
                nonlinear: false,
            },
            Brdf::RoughPlastic {
                alpha: 0.5,
                int_ior: 1.33,
                ext_ior: 1.0,
                diffuse_reflectance: [0.2, 0.5, 0.8],
                specular_reflectance: [0.9; 3],
                nonlinear: true,
            },
        ]
    }

    /// `f(light, view)` with the diffuse part scaled by `diffuse_scale` (an albedo map texel).
    #[inline]
    pub fn eval_scaled(&self, light: DVec3, view: DVec3, diffuse_scale: Rgb) -> [f64; 3] {
        let (d, s) = self.eval_parts(light, view);
        std::array::from_fn(|c| d[c] * diffuse_scale[c] as f64 + s[c])
    }
}

/// Ashikhmin-Shirley 2000, equations 4 and 5, with `k1` = light and `k2` = view.
fn ashikhmin_shirley(rd: Rgb, rs: Rgb, nu: f64, nv: f64, k1: DVec3, k2: DVec3) -> ([f64; 3], [f64; 3]) {
    let (n1, n2) = (k1.z.max(0.0), k2.z.max(0.0));
    let sum = k1 + k2;
    let h = if sum.length_squared() > 0.0 { sum.normalize() } else { DVec3::Z };
    let kh = k1.dot(h).max(1e-12);
    let nh = h.z.max(0.0);
    let sin2 = h.x * h.x + h.y * h.y;
    // (nu (h.u)^2 + nv (h.v)^2) / (1 - (h.n)^2); at h = n the power is of 1 whatever the exponent.
    let e = if sin2 > 0.0 { (nu * h.x * h.x + nv * h.y * h.y) / sin2 } else { 0.0 };
    let lobe = ((nu + 1.0) * (nv + 1.0)).sqrt() / (8.0 * PI) * nh.powf(e) / (kh * n1.max(n2).max(1e-12));
    let schlick = (1.0 - kh).powi(5);
    let g = |c: f64| 1.0 - (1.0 - c / 2.0).powi(5);
    let coupling = 28.0 / (23.0 * PI) * g(n1) * g(n2);
    let spec = rs.map(|r| lobe * (r as f64 + (1.0 - r as f64) * schlick));
    let diff = std::array::from_fn(|c| rd[c] as f64 * (1.0 - rs[c] as f64) * coupling);
    (diff, spec)
}

/// A local frame at a meso-surface point: normal `n`, tangent `t` (the patch's +X made
/// orthogonal to `n`), bitangent `b = n x t`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frame {
    pub t: DVec3,
    pub b: DVec3,
    pub n: DVec3,
}

impl Frame {
    /// Frame of a height-field facet (`n.z > 0`, so `n` is never parallel to +X).
    pub fn from_normal(n: DVec3) -> Self {
        if n == DVec3::Z {
            // Exactly the patch frame, so a flat patch reproduces the analytic tables bit for bit.
            return Self { t: DVec3::X, b: DVec3::Y, n };
        }
        let t = (DVec3::X - n.x * n).normalize();
        Self { t, b: n.cross(t), n }
    }

    #[inline]
    pub fn to_local(self, d: DVec3) -> DVec3 {
        DVec3::new(d.dot(self.t), d.dot(self.b), d.dot(self.n))
    }

    #[inline]
    pub fn to_world(self, d: DVec3) -> DVec3 {
        self.t * d.x + self.b * d.y + self.n * d.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn ashikhmin_shirley_is_reciprocal_and_anisotropic() {
        // Equations 4 and 5 are symmetric in k1, k2 (max(n.k1, n.k2), h.k with k either one),
        // so f(l, v) = f(v, l) to rounding.
        let brdf = Brdf::AshikhminShirley { rd: [0.3; 3], rs: [0.05; 3], nu: 100.0, nv: 5.0 };
        brdf.validate().unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let dir = |rng: &mut rand_chacha::ChaCha8Rng| {
            let z: f64 = rng.gen_range(0.05..1.0);
            let phi: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let s = (1.0 - z * z).sqrt();
            DVec3::new(s * phi.cos(), s * phi.sin(), z)
        };
        for _ in 0..1000 {
            let (l, v) = (dir(&mut rng), dir(&mut rng));
            let (a, b) = (brdf.eval_scaled(l, v, [1.0; 3]), brdf.eval_scaled(v, l, [1.0; 3]));
            assert!((a[0] - b[0]).abs() <= 1e-12 * a[0].max(1.0), "{a:?} vs {b:?}");
        }
        // Light 30 degrees and view 50 degrees off the normal, both on the +X side: the
        // half-vector tilts towards +X (exponent nu = 100). The same pair rotated to the +Y
        // side tilts it towards +Y (exponent nv = 5): the lobe is much wider there.
        let rot = |a: f64, b: f64| {
            DVec3::new(
                a.to_radians().sin() * b.to_radians().cos(),
                a.to_radians().sin() * b.to_radians().sin(),
                a.to_radians().cos(),
            )
        };
        let along_x = brdf.eval_parts(rot(30.0, 0.0), rot(50.0, 0.0)).1[0];
        let along_y = brdf.eval_parts(rot(30.0, 90.0), rot(50.0, 90.0)).1[0];
        assert!(along_y > 2.0 * along_x, "along x {along_x}, along y {along_y}");
    }

    #[test]
    fn frames_are_orthonormal_and_keep_the_patch_frame_when_flat() {
        let f = Frame::from_normal(DVec3::Z);
        assert_eq!((f.t, f.b), (DVec3::X, DVec3::Y));
        let f = Frame::from_normal(DVec3::new(0.3, -0.4, 0.8).normalize());
        for (a, b) in [(f.t, f.b), (f.b, f.n), (f.n, f.t)] {
            assert!(a.dot(b).abs() < 1e-12);
        }
        assert!((f.t.cross(f.b) - f.n).length() < 1e-12, "right-handed");
        assert!(f.t.x > 0.9, "tangent follows the patch's +X");
        let d = DVec3::new(0.1, 0.2, 0.9).normalize();
        assert!((f.to_world(f.to_local(d)) - d).length() < 1e-12);
    }

    #[test]
    fn bad_parameters_are_errors() {
        assert!(Brdf::Lambertian { albedo: [-0.1, 0.0, 0.0] }.validate().is_err());
        assert!(Brdf::Phong { kd: [0.1; 3], ks: [0.1; 3], exponent: f32::NAN }.validate().is_err());
        assert!(Brdf::AshikhminShirley { rd: [0.1; 3], rs: [1.5; 3], nu: 10.0, nv: 10.0 }.validate().is_err());
        assert!(Brdf::AshikhminShirley { rd: [0.1; 3], rs: [0.1; 3], nu: 0.0, nv: 10.0 }.validate().is_err());
        let rc = Brdf::RoughConductor { alpha: 0.1, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] };
        rc.validate().unwrap();
        for bad in [
            Brdf::RoughConductor { alpha: 0.0, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] },
            Brdf::RoughConductor { alpha: 1.5, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] },
            Brdf::RoughConductor { alpha: f32::NAN, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] },
            Brdf::RoughConductor { alpha: 0.1, eta: [0.0; 3], k: [1.0, 0.0, 1.0], specular_reflectance: [1.0; 3] },
            Brdf::RoughConductor { alpha: 0.1, eta: [-1.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] },
            Brdf::RoughConductor { alpha: 0.1, eta: [1.0; 3], k: [1.0; 3], specular_reflectance: [1.1; 3] },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        let rp = |int_ior: f32, ext_ior: f32, d: f32| Brdf::RoughPlastic {
            alpha: 0.1,
            int_ior,
            ext_ior,
            diffuse_reflectance: [d; 3],
            specular_reflectance: [1.0; 3],
            nonlinear: false,
        };
        rp(1.49, 1.000277, 0.5).validate().unwrap();
        for bad in [rp(1.5, 1.5, 0.5), rp(0.0, 1.0, 0.5), rp(f32::INFINITY, 1.0, 0.5), rp(1.49, 1.0, 1.2)] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    /// A `brdf = { ... }` table as the pipeline's config deserializes it (JSON here).
    fn parse(v: serde_json::Value) -> std::result::Result<Brdf, serde_json::Error> {
        serde_json::from_value(v)
    }

    #[test]
    fn microfacet_brdfs_deserialize_with_mitsubas_names_and_defaults() {
        assert_eq!(
            parse(serde_json::json!({"kind": "rough_conductor"})).unwrap(),
            Brdf::RoughConductor { alpha: 0.1, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] }
        );
        assert_eq!(
            parse(serde_json::json!({"kind": "rough_plastic", "alpha": 0.3, "nonlinear": true})).unwrap(),
            Brdf::RoughPlastic {
                alpha: 0.3,
                int_ior: 1.49,
                ext_ior: 1.000277,
                diffuse_reflectance: [0.5; 3],
                specular_reflectance: [1.0; 3],
                nonlinear: true,
            }
        );
        let b = parse(serde_json::json!({
            "kind": "rough_conductor", "alpha": 0.2, "eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.2]
        }))
        .unwrap();
        assert_eq!(b.kind(), "rough-conductor");
        assert_eq!(parse(serde_json::json!({"kind": "rough_plastic"})).unwrap().kind(), "rough-plastic");
        b.validate().unwrap();
        let (d, s) = b.eval_parts(DVec3::Z, DVec3::Z);
        assert_eq!(d, [0.0; 3], "a conductor has no diffuse part");
        assert!(s.iter().all(|&x| x > 0.0));
        // Mitsuba's names only: unknown fields are errors.
        assert!(parse(serde_json::json!({"kind": "rough_plastic", "roughness": 0.3})).is_err());
        // The rough plastic's diffuse part is what an albedo map scales.
        let p = parse(serde_json::json!({"kind": "rough_plastic"})).unwrap();
        let (l, v) = (DVec3::new(0.3, 0.0, 0.9).normalize(), DVec3::new(-0.2, 0.1, 0.95).normalize());
        let (d, s) = p.eval_parts(l, v);
        let half = p.eval_scaled(l, v, [0.5; 3]);
        assert!(d[0] > 0.0 && s[0] > 0.0);
        assert!((half[0] - (0.5 * d[0] + s[0])).abs() < 1e-15);
    }
}
