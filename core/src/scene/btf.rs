//! BTF tables `b(u, e, d_j)` for analytic materials, and their lookup (paper section 3,
//! `B(x, e) = sum_j b(u, e, d_j) L*(x, d_j)`).
//!
//! Convention (docs/DESIGN.md section 3): `b(u, e, d_j)` is the outgoing radiance at patch texel `u`
//! towards view `e` under a directional light of unit perpendicular irradiance from `d_j`,
//! *including* `cos(theta_d)`. For an analytic BRDF `f` this is `f(d_j, e) cos(theta_j)`.
//!
//! Two choices fix the discrete sum `sum_j b_j L*_j` (where `L*_j` is the light *power* that
//! arrives through bin `j`, i.e. radiance integrated over the bin's `2 pi / M` steradians):
//!
//! * the cosine factor is the bin's **mean** cosine ([`HemisphereGrid::bin_mean_cosine`]), not
//!   the cosine at its centre. Then `sum_j cosbar_j * 2 pi / M = pi` exactly, so a constant sky
//!   of radiance `1` on a white Lambertian patch gives `B = (albedo / pi) * pi = albedo`, as it
//!   must. The centre cosine would overestimate by a few percent in the outer ring of bins, where
//!   `cos` is convex in the concentric coordinate.
//! * the BRDF lobe itself (the part that depends on the light direction other than the cosine)
//!   is evaluated at the bin-centre direction ([`HemisphereGrid::bin_direction`]).
//!
//! The sum is exact only for fully visible, evenly lit bins (a constant sky). Light that varies
//! within a bin is weighted by the bin's mean cosine instead of its own: a sun low in an
//! outer-ring bin, whose cosines span 0 to 0.44, is over-weighted up to an order of magnitude,
//! one high in the same ring under-weighted, and an occluder that hides a bin's low part
//! darkens it. `[runtime] light_moments` replaces the mean cosine by each texel's own
//! (`biscale_core::gather::moments`); the paper's rule stays the default.
//!
//! Table layout: `data[(texel * V + view) * M + light]`, texel `= ty * spatial[0] + tx`, `V` the
//! number of view samples (1 when the BTF is view-independent and has no view axis, docs/DESIGN.md
//! section 5), `M` the number of light bins. View samples sit at the bin centres of
//! `view_grid` and are interpolated bilinearly in the concentric-square parameterization.

use crate::basis::LocalBasis;
use crate::error::{CoreError, Result};
use crate::sampling::HemisphereGrid;
use crate::Rgb;
use glam::{Vec2, Vec3};
use std::f64::consts::PI;

/// A tabulated BTF: `spatial[0] x spatial[1]` texels, `M` light directions (the local basis
/// of `L*` it is dotted with), optionally `V` view samples. Built through [`Btf::new`] (or
/// the analytic constructors), which checks that the parts fit together and the table is
/// finite, so a `Btf` in hand is valid and no consumer checks it again.
#[derive(Clone, Debug, PartialEq)]
pub struct Btf {
    spatial: [u32; 2],
    local_basis: LocalBasis,
    view_grid: Option<HemisphereGrid>,
    data: Vec<Rgb>,
    name: String,
}

/// The normalized modified Phong BRDF (Lafortune and Willems 1994, "Using the modified Phong
/// reflectance model for physically based rendering"):
/// `f = kd / pi + ks (n + 2) / (2 pi) cos^n(alpha)`, where `alpha` is the angle between the view
/// direction and the light direction mirrored about the normal, `cos(alpha)` clamped at 0.
/// The `(n + 2) / (2 pi)` factor makes the specular lobe's directional albedo 1 at normal
/// incidence, so `kd + ks <= 1` conserves energy. Directions are local (+Z = normal), unit.
pub fn phong_brdf(kd: Rgb, ks: Rgb, exponent: f64, light_local: Vec3, view_local: Vec3) -> [f64; 3] {
    let l = light_local.as_dvec3();
    let mirrored = glam::DVec3::new(-l.x, -l.y, l.z);
    let cos_alpha = mirrored.dot(view_local.as_dvec3()).max(0.0);
    let lobe = (exponent + 2.0) / (2.0 * PI) * cos_alpha.powf(exponent);
    std::array::from_fn(|c| kd[c] as f64 / PI + ks[c] as f64 * lobe)
}

fn check_rgb(what: &str, v: Rgb) -> Result<()> {
    if v.iter().all(|x| x.is_finite() && *x >= 0.0) {
        Ok(())
    } else {
        Err(CoreError::Invalid(format!("{what} must be finite and non-negative, got {v:?}")))
    }
}

/// The view grid of side `m` (1..=64, as the local grid).
pub fn view_grid(m: u32) -> Result<HemisphereGrid> {
    if m == 0 || m > crate::basis::MAX_LOCAL_GRID {
        return Err(CoreError::Invalid(format!(
            "view grid must be 1..={} per side, got {m}",
            crate::basis::MAX_LOCAL_GRID
        )));
    }
    Ok(HemisphereGrid::new(m))
}

/// The bin grid of a local basis the BTF tables can be tabulated on.
fn light_bins(basis: LocalBasis) -> Result<HemisphereGrid> {
    basis.grid().ok_or_else(|| CoreError::Invalid(format!("a tabulated BTF needs a bin basis, not {basis}")))
}

/// Nearest texel of patch coordinates `uv` on a `spatial` patch, wrapping around (the patch
/// tiles the surface). Every BTF representation looks texels up through this.
/// Non-finite coordinates give texel 0.
pub fn texel_of(spatial: [u32; 2], uv: Vec2) -> usize {
    let wrap = |x: f32, n: u32| -> usize {
        if !x.is_finite() {
            return 0;
        }
        ((x as f64 * n as f64).floor() as i64).rem_euclid(n as i64) as usize
    };
    wrap(uv.y, spatial[1]) * spatial[0] as usize + wrap(uv.x, spatial[0])
}

/// The (up to) four view samples of `view_grid` and bilinear weights for local view direction
/// `view_local` (+Z = normal): bilinear in the concentric-square coordinates of
/// [`HemisphereGrid::continuous_coords`], whose integer values are bin centres; directions
/// outside the centres' hull clamp to the border samples, directions below the horizon are
/// clamped onto it, and a non-finite or zero direction is treated as the normal.
/// Weights sum to 1. A view-independent BTF returns sample 0 with weight 1.
pub fn view_weights(view_grid: Option<HemisphereGrid>, view_local: Vec3) -> [(usize, f32); 4] {
    match view_grid {
        Some(g) => grid_weights(g, view_local),
        None => [(0, 1.0), (0, 0.0), (0, 0.0), (0, 0.0)],
    }
}

/// The (up to) four light bins of `grid` and bilinear weights for local light direction
/// `light_local`: the same interpolation as [`view_weights`], over the BTF's light axis. A BTF
/// value divided by its bin's mean cosine is the BRDF at the bin centre, so
/// `sum_i w_i b_i / cosbar_i` is the BRDF interpolated at `light_local` (light moments and the
/// ground-truth reference evaluate the lobe this way instead of at the bin centre).
#[inline]
pub fn light_weights(grid: HemisphereGrid, light_local: Vec3) -> [(usize, f32); 4] {
    grid_weights(grid, light_local)
}

/// Bilinear weights of local direction `d` between the bin centres of `g` (see [`view_weights`]).
#[inline]
fn grid_weights(g: HemisphereGrid, d: Vec3) -> [(usize, f32); 4] {
    let e = if d.is_finite() && d.length_squared() > 0.0 { d } else { Vec3::Z };
    let (x, y) = g.continuous_coords(e);
    let m = g.m as usize;
    if m == 1 {
        return [(0, 1.0), (0, 0.0), (0, 0.0), (0, 0.0)];
    }
    // `continuous_coords` is in [0, m - 1], where truncation is the floor (and a cast, not a
    // libm call on the x86-64 baseline).
    let split = |c: f32| {
        let i = (c as usize).min(m - 2);
        (i, (c - i as f32).clamp(0.0, 1.0))
    };
    let ((x0, fx), (y0, fy)) = (split(x), split(y));
    let at = |xi: usize, yi: usize| yi * m + xi;
    [
        (at(x0, y0), (1.0 - fx) * (1.0 - fy)),
        (at(x0 + 1, y0), fx * (1.0 - fy)),
        (at(x0, y0 + 1), (1.0 - fx) * fy),
        (at(x0 + 1, y0 + 1), fx * fy),
    ]
}

impl Btf {
    /// A table from its parts: `spatial` texels, light directions in `local_basis`, view
    /// samples on `view_grid` (`None`: no view axis), `data[(texel * V + view) * M + light]`.
    /// Errors name what does not fit: an empty patch, a table of the wrong length, a
    /// non-finite entry.
    pub fn new(
        spatial: [u32; 2],
        local_basis: LocalBasis,
        view_grid: Option<HemisphereGrid>,
        data: Vec<Rgb>,
        name: impl Into<String>,
    ) -> Result<Self> {
        let btf = Self { spatial, local_basis, view_grid, data, name: name.into() };
        btf.validate()?;
        Ok(btf)
    }

    /// A white-or-coloured Lambertian material: `b(d_j) = albedo / pi * cosbar_j`,
    /// view-independent (no view axis), spatially uniform (one texel).
    pub fn lambertian(albedo: Rgb, local_basis: LocalBasis) -> Result<Self> {
        check_rgb("lambertian albedo", albedo)?;
        let grid = light_bins(local_basis)?;
        let data = (0..grid.len() as u32)
            .map(|j| {
                let c = grid.bin_mean_cosine(j) / PI;
                albedo.map(|a| (a as f64 * c) as f32)
            })
            .collect();
        Self::new([1, 1], local_basis, None, data, format!("lambertian {albedo:?}"))
    }

    /// The normalized modified Phong material ([`phong_brdf`]) tabulated at the bin centres of
    /// `view_grid x view_grid` view directions and the light bins of `local_basis`:
    /// `b(e_v, d_j) = f(d_j, e_v) * cosbar_j`. Spatially uniform (one texel).
    pub fn phong(kd: Rgb, ks: Rgb, exponent: f32, local_basis: LocalBasis, view_grid_m: u32) -> Result<Self> {
        check_rgb("phong kd", kd)?;
        check_rgb("phong ks", ks)?;
        if !(exponent.is_finite() && exponent >= 0.0) {
            return Err(CoreError::Invalid(format!("phong exponent must be finite and >= 0, got {exponent}")));
        }
        let lg = light_bins(local_basis)?;
        let vg = view_grid(view_grid_m)?;
        let cosbar = lg.mean_cosines();
        let mut data = Vec::with_capacity(vg.len() * lg.len());
        for v in 0..vg.len() as u32 {
            let e = vg.bin_direction(v);
            for (j, cb) in cosbar.iter().enumerate() {
                let f = phong_brdf(kd, ks, exponent as f64, lg.bin_direction(j as u32), e);
                data.push(f.map(|x| (x * cb) as f32));
            }
        }
        Self::new([1, 1], local_basis, Some(vg), data, format!("phong kd={kd:?} ks={ks:?} n={exponent}"))
    }

    /// Patch size in texels, `[width, height]`.
    pub fn spatial(&self) -> [u32; 2] {
        self.spatial
    }

    /// The light directions `d_j`: the local basis of the `L*` the table is dotted with.
    pub fn local_basis(&self) -> LocalBasis {
        self.local_basis
    }

    /// View directions sampled at bin centres; `None` for a view-independent BTF.
    pub fn view_grid(&self) -> Option<HemisphereGrid> {
        self.view_grid
    }

    /// `[texel][view][light]`, linear RGB (see the module docs).
    pub fn data(&self) -> &[Rgb] {
        &self.data
    }

    /// Human-readable description (for reports).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The same table under another name.
    pub fn renamed(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    /// Number of light directions `M`.
    pub fn light_count(&self) -> usize {
        self.local_basis.len()
    }

    /// Number of view samples `V` (1 without a view axis).
    pub fn view_count(&self) -> usize {
        self.view_grid.map_or(1, |g| g.len())
    }

    /// Number of texels.
    pub fn texel_count(&self) -> usize {
        self.spatial[0] as usize * self.spatial[1] as usize
    }

    /// Check that the fields fit together and the table is finite ([`Self::new`]).
    fn validate(&self) -> Result<()> {
        let [w, h] = self.spatial;
        if w == 0 || h == 0 {
            return Err(CoreError::Invalid(format!("BTF '{}': empty patch {w}x{h}", self.name)));
        }
        if self.view_grid.is_some_and(|g| g.m == 0) {
            return Err(CoreError::Invalid(format!("BTF '{}': empty view grid", self.name)));
        }
        let expect = self.texel_count() * self.view_count() * self.light_count();
        if self.data.len() != expect {
            return Err(CoreError::Invalid(format!(
                "BTF '{}': table has {} entries, expected {w}x{h} texels x {} views x {} lights = {expect}",
                self.name,
                self.data.len(),
                self.view_count(),
                self.light_count()
            )));
        }
        if let Some(i) = self.data.iter().position(|v| !v.iter().all(|x| x.is_finite())) {
            return Err(CoreError::Invalid(format!("BTF '{}': non-finite entry at index {i}", self.name)));
        }
        Ok(())
    }

    /// Nearest texel of patch coordinates `uv`, wrapping around ([`texel_of`]).
    pub fn texel_of(&self, uv: Vec2) -> usize {
        texel_of(self.spatial, uv)
    }

    /// The (up to) four view samples and bilinear weights for `view_local` ([`view_weights`]).
    pub fn view_weights(&self, view_local: Vec3) -> [(usize, f32); 4] {
        view_weights(self.view_grid, view_local)
    }

    /// The `M` light values `b(u, e, d_j)` for one texel and view: nearest texel (wrapping),
    /// bilinear over view samples ([`Self::view_weights`]).
    ///
    /// # Panics
    /// If `out.len()` is not [`Self::light_count`] (a caller bug, not bad input), or if the
    /// table does not pass [`Self::validate`].
    pub fn eval_into(&self, texel_uv: Vec2, view_local: Vec3, out: &mut [Rgb]) {
        let m = self.light_count();
        assert_eq!(out.len(), m, "eval_into: output must hold one value per light bin");
        let base = self.texel_of(texel_uv) * self.view_count();
        let weights = self.view_weights(view_local);
        if self.view_grid.is_none() || weights[0].1 == 1.0 {
            let v = base + weights[0].0;
            out.copy_from_slice(&self.data[v * m..(v + 1) * m]);
            return;
        }
        out.fill([0.0; 3]);
        // Flat f32 runs (RGB interleaved on both sides), so the loop vectorizes.
        let flat: &mut [f32] = bytemuck::cast_slice_mut(out);
        for (v, w) in weights {
            if w == 0.0 {
                continue;
            }
            let row: &[f32] = bytemuck::cast_slice(&self.data[(base + v) * m..(base + v + 1) * m]);
            for (o, b) in flat.iter_mut().zip(row) {
                *o += w * b;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bins(m: u32) -> LocalBasis {
        LocalBasis::bins(m).unwrap()
    }
    use crate::sampling::hemisphere::square_to_hemisphere;
    use rand::{Rng, SeedableRng};

    #[test]
    fn lambertian_values_are_analytic() {
        let albedo = [0.8, 0.5, 0.25];
        let btf = Btf::lambertian(albedo, bins(8)).unwrap();
        assert_eq!((btf.light_count(), btf.view_count(), btf.texel_count()), (64, 1, 1));
        let mut out = vec![[0.0; 3]; 64];
        // Any view and any uv give the same values: view-independent, one texel.
        btf.eval_into(Vec2::new(-3.7, 12.2), Vec3::new(0.3, -0.2, 0.9).normalize(), &mut out);
        for (j, o) in out.iter().enumerate() {
            let c = btf.local_basis().grid().unwrap().bin_mean_cosine(j as u32);
            for k in 0..3 {
                let expect = albedo[k] as f64 / PI * c;
                assert!((o[k] as f64 - expect).abs() <= 1e-7 * expect.max(1e-3), "bin {j}: {} vs {expect}", o[k]);
            }
        }
    }

    #[test]
    fn white_lambertian_conserves_energy() {
        // sum_j b_j * (2 pi / M) = albedo / pi * sum_j cosbar_j (2 pi / M) = albedo: the
        // bin-mean cosines integrate the cosine exactly (core tests it to 1e-12); f32 storage of
        // M values adds at most M ulp.
        for m in [1, 2, 8, 12, 32] {
            let btf = Btf::lambertian([0.7; 3], bins(m)).unwrap();
            let w = btf.local_basis().grid().unwrap().bin_solid_angle();
            let s: f64 = btf.data().iter().map(|b| b[0] as f64 * w).sum();
            assert!((s - 0.7).abs() < 1e-6, "m={m}: {s}");
        }
    }

    #[test]
    fn phong_at_view_samples_equals_formula() {
        let (kd, ks, n) = ([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], 20.0f32);
        let btf = Btf::phong(kd, ks, n, bins(8), 12).unwrap();
        let (lg, vg) = (btf.local_basis().grid().unwrap(), btf.view_grid().unwrap());
        let mut out = vec![[0.0; 3]; lg.len()];
        for v in 0..vg.len() as u32 {
            let e = vg.bin_direction(v).as_dvec3();
            btf.eval_into(Vec2::ZERO, e.as_vec3(), &mut out);
            for j in 0..lg.len() as u32 {
                // The formula written out independently of `phong_brdf`.
                let d = lg.bin_direction(j).as_dvec3();
                let r = glam::DVec3::new(-d.x, -d.y, d.z);
                let spec = (n as f64 + 2.0) / (2.0 * PI) * r.dot(e).max(0.0).powf(n as f64);
                for c in 0..3 {
                    let expect = (kd[c] as f64 / PI + ks[c] as f64 * spec) * lg.bin_mean_cosine(j);
                    let got = out[j as usize][c] as f64;
                    // At a sample centre the bilinear weights are 1 and 0 up to the f32 rounding
                    // of the continuous coordinates (~1e-6 of a cell); the lobe is smooth on
                    // that scale, so the relative error stays near f32 epsilon.
                    assert!((got - expect).abs() <= 1e-5 * expect + 1e-7, "v={v} j={j} c={c}: {got} vs {expect}");
                }
            }
        }
    }

    #[test]
    fn bilinear_interpolates_between_view_samples() {
        // A table with random values, so any mix-up of indices shows.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (m_l, m_v) = (4u32, 6u32);
        let mut btf = Btf::phong([0.5; 3], [0.5; 3], 10.0, bins(m_l), m_v).unwrap();
        for v in btf.data.iter_mut() {
            *v = [rng.gen(), rng.gen(), rng.gen()];
        }
        let ml = btf.light_count();
        let mut out = vec![[0.0; 3]; ml];
        let at = |view: usize, j: usize, c: usize| btf.data()[view * ml + j][c];
        // Exact values at every sample centre.
        for v in 0..(m_v * m_v) as usize {
            btf.eval_into(Vec2::ZERO, btf.view_grid().unwrap().bin_direction(v as u32), &mut out);
            for j in 0..ml {
                for c in 0..3 {
                    assert!((out[j][c] - at(v, j, c)).abs() < 1e-5, "centre {v}");
                }
            }
        }
        // Between centres: the direction at continuous coordinates (x, y) is built through
        // the concentric map, so the expected value is the bilinear blend of the four samples.
        for _ in 0..200 {
            let (x, y): (f32, f32) = (rng.gen_range(0.0..(m_v - 1) as f32), rng.gen_range(0.0..(m_v - 1) as f32));
            let d = square_to_hemisphere((x as f64 + 0.5) / m_v as f64, (y as f64 + 0.5) / m_v as f64);
            btf.eval_into(Vec2::ZERO, d.as_vec3(), &mut out);
            let (x0, y0) = ((x.floor() as usize).min(m_v as usize - 2), (y.floor() as usize).min(m_v as usize - 2));
            let (fx, fy) = (x - x0 as f32, y - y0 as f32);
            let s = |xi: usize, yi: usize| yi * m_v as usize + xi;
            for j in 0..ml {
                for c in 0..3 {
                    let expect = (1.0 - fx) * (1.0 - fy) * at(s(x0, y0), j, c)
                        + fx * (1.0 - fy) * at(s(x0 + 1, y0), j, c)
                        + (1.0 - fx) * fy * at(s(x0, y0 + 1), j, c)
                        + fx * fy * at(s(x0 + 1, y0 + 1), j, c);
                    // Coordinates go through f64 -> f32 round trips: ~1e-6 of a cell.
                    assert!((out[j][c] - expect).abs() < 1e-4, "({x},{y}) j={j}: {} vs {expect}", out[j][c]);
                }
            }
        }
        // Degenerate views never produce NaN.
        for e in [Vec3::ZERO, Vec3::NAN, Vec3::new(0.0, 0.0, -1.0), Vec3::new(1.0, 0.0, 0.0)] {
            btf.eval_into(Vec2::NAN, e, &mut out);
            assert!(out.iter().flatten().all(|x| x.is_finite()), "{e:?}");
        }
    }

    #[test]
    fn texels_wrap_around() {
        let btf = Btf::new([4, 2], bins(1), None, (0..8).map(|i| [i as f32; 3]).collect(), "ramp").unwrap();
        let mut out = [[0.0; 3]];
        for (uv, texel) in [
            ((0.1, 0.1), 0),
            ((0.3, 0.1), 1),
            ((0.9, 0.9), 7),
            ((1.1, 0.1), 0),
            ((-0.1, 0.1), 3),
            ((0.1, -0.2), 4),
            ((2.6, 3.7), 6),
        ] {
            btf.eval_into(Vec2::new(uv.0, uv.1), Vec3::Z, &mut out);
            assert_eq!(out[0][0], texel as f32, "{uv:?}");
        }
    }

    #[test]
    fn bad_parameters_are_errors() {
        assert!(Btf::lambertian([f32::NAN, 0.0, 0.0], bins(8)).is_err());
        assert!(Btf::phong([0.5; 3], [-0.1, 0.0, 0.0], 10.0, bins(8), 8).is_err());
        assert!(Btf::phong([0.5; 3], [0.1; 3], f32::INFINITY, bins(8), 8).is_err());
        assert!(Btf::phong([0.5; 3], [0.1; 3], 10.0, bins(8), 0).is_err());
        let b = Btf::phong([0.5; 3], [0.1; 3], 10.0, bins(8), 8).unwrap();
        let mut short = b.data().to_vec();
        short.pop();
        assert!(Btf::new(b.spatial(), b.local_basis(), b.view_grid(), short, "short").is_err());
        let mut nan = b.data().to_vec();
        nan[3][1] = f32::NAN;
        assert!(Btf::new(b.spatial(), b.local_basis(), b.view_grid(), nan, "nan").is_err());
        assert!(Btf::new([0, 1], b.local_basis(), None, vec![], "empty").is_err());
    }
}
