//! Environment maps and the light vector `L`: lat-long (equirectangular) maps here, cube
//! maps (a cross image or six face files) in [`super::cube_env`], one [`EnvMap`] type for both.
//!
//! The mapping between pixels and directions lives in [`latlong_direction`] and
//! [`direction_to_latlong`] alone (Mitsuba 3's convention, so a physically based renderer
//! given the same file sees the sky in the same directions; pixels are integrated as boxes
//! here, so one that interpolates bilinearly sees slightly different values): +Y is up, row
//! 0 is the zenith,
//! `u = atan2(d.x, -d.z) / 2 pi` (u = 0 looks down -Z, u = 1/4 down +X),
//! `v = acos(d.y) / pi`.
//!
//! `L_k` is the power through cubemap texel `k`: the integral of radiance over the texel's
//! solid angle (docs/DESIGN.md section 3). It is built by *splatting* every source pixel, split
//! into sub-pixels each carrying its exact solid angle, into the texel its centre falls in,
//! so the total power equals the integral of the piecewise-constant source map exactly and a
//! sun a few pixels wide keeps its energy.
//!
//! Beside `L_k`, the splat keeps each texel's first moment per RGB channel: the power-weighted
//! mean direction of the sub-pixels it averages (`LightVector::mean_direction`). A sun sits
//! wherever it is inside its texel, up to about 1.35 degrees from the centre of a 6x32x32
//! texel; with `[lighting] texel_directions = "mean"` light moments and the analytic resolve
//! take its light from the mean, not the centre (the transfer `T` still bins texels by their
//! centres). Per channel, not by luminance: the
//! moment is linear in each channel's radiance, so per channel it is exact for every colour
//! mix inside a texel (a blue sky beside a yellow sun), at 9 floats per texel.

use crate::basis::LightBasis;
use crate::error::{CoreError, Result};
use crate::sampling::Cubemap;
use crate::Rgb;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::path::Path;

/// An HDR environment of linear radiance: a lat-long image (row-major, row 0 = zenith), or
/// a cube map (see [`EnvLayout`]).
#[derive(Clone, Debug)]
pub struct EnvMap {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<Rgb>,
    pub layout: EnvLayout,
}

/// How an [`EnvMap`]'s pixels map to directions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EnvLayout {
    /// `width = 2 height`, [`latlong_direction`].
    #[default]
    LatLong,
    /// Six square faces of `width` texels, stacked (`height = 6 width`) in biscale's own
    /// cubemap layout: the texels of `Cubemap::new(width)`, in its order (docs/DESIGN.md
    /// section 3). [`super::cube_env`] reads cross images and face files into it.
    Cube,
}

/// Direction (unit, +Y up) through lat-long coordinates `(u, v)` in `[0,1]^2`.
pub fn latlong_direction(u: f64, v: f64) -> DVec3 {
    let phi = 2.0 * PI * u;
    let theta = PI * v;
    DVec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
}

/// Inverse of [`latlong_direction`]: `(u, v)` of a (not necessarily unit) direction.
pub fn direction_to_latlong(d: DVec3) -> (f64, f64) {
    let d = d.normalize();
    let mut u = d.x.atan2(-d.z) / (2.0 * PI);
    if u < 0.0 {
        u += 1.0;
    }
    (u.min(1.0), d.y.clamp(-1.0, 1.0).acos() / PI)
}

/// Rotation of the environment about +Y by `angle` radians (applied to directions of the map).
pub fn rotate_y(d: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    DVec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
}

impl EnvMap {
    /// A map of constant radiance.
    pub fn constant(width: usize, height: usize, rgb: Rgb) -> Self {
        Self { width, height, pixels: vec![rgb; width * height], layout: EnvLayout::LatLong }
    }

    /// Load an OpenEXR (`.exr`) or Radiance (`.hdr`) environment: a lat-long map (2:1), a
    /// cube-map cross (4:3 horizontal, 3:4 vertical), or, when the file name holds `{face}`,
    /// six square face files (`px nx py ny pz nz`; [`super::cube_env`]). Pixels with NaN or
    /// infinite values are an error naming the pixel; negative values are clamped to 0 and
    /// reported in the returned warnings.
    pub fn load(path: &Path) -> Result<(Self, Vec<String>)> {
        if let Some(faces) = super::cube_env::face_paths(path) {
            return super::cube_env::load_faces(path, &faces);
        }
        let mut map = Self::read_image(path)?;
        if map.width > 0 && super::cube_env::is_cross(map.width, map.height) {
            return super::cube_env::from_cross(&map, path);
        }
        let warnings = map.validate(path)?;
        Ok((map, warnings))
    }

    /// The pixels of an `.exr` or `.hdr` image as they are stored (a lat-long layout, unchecked).
    pub(crate) fn read_image(path: &Path) -> Result<Self> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        match crate::io::check_regular(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(CoreError::Input { path: path.into(), message: "file not found".into() })
            }
            Err(e) => return Err(CoreError::Input { path: path.into(), message: e.to_string() }),
            Ok(_) => {}
        }
        Ok(match ext.as_str() {
            "exr" => load_exr(path)?,
            "hdr" => load_hdr(path)?,
            _ => {
                return Err(CoreError::Input {
                    path: path.into(),
                    message: format!("unsupported env map extension '.{ext}' (expected .exr or .hdr)"),
                })
            }
        })
    }

    /// Reject NaN/Inf (naming the first offending pixel), clamp negatives with a warning.
    fn validate(&mut self, path: &Path) -> Result<Vec<String>> {
        if self.width == 0 || self.height == 0 {
            return Err(CoreError::Input { path: path.into(), message: "image is empty".into() });
        }
        let w = self.width;
        match self.layout {
            EnvLayout::LatLong if self.width != 2 * self.height => Err(CoreError::Input {
                path: path.into(),
                message: format!(
                    "an env map must be a lat-long map twice as wide as tall, or a cube-map cross 4:3 \
                     (horizontal) or 3:4 (vertical); got {}x{}",
                    self.width, self.height
                ),
            }),
            EnvLayout::LatLong => self.check_radiance(path, &|i| format!("pixel (x={}, y={})", i % w, i / w)),
            EnvLayout::Cube if self.height != 6 * self.width => Err(CoreError::Input {
                path: path.into(),
                message: format!("a cube map of {w}x{w} faces needs {} rows, has {}", 6 * w, self.height),
            }),
            EnvLayout::Cube => self.check_radiance(path, &|i| super::cube_env::texel_place(w, i)),
        }
    }

    /// [`EnvMap::validate`]'s pixel checks, naming pixel `i` as `place(i)` says.
    pub(crate) fn check_radiance(&mut self, path: &Path, place: &dyn Fn(usize) -> String) -> Result<Vec<String>> {
        if self.pixels.len() != self.width * self.height {
            return Err(CoreError::Input {
                path: path.into(),
                message: format!("{} pixels for a {}x{} image", self.pixels.len(), self.width, self.height),
            });
        }
        let mut negatives = 0usize;
        for (i, p) in self.pixels.iter_mut().enumerate() {
            for (c, v) in p.iter_mut().enumerate() {
                if !v.is_finite() {
                    return Err(CoreError::Input {
                        path: path.into(),
                        message: format!(
                            "{} channel {} is {} (NaN/Inf radiance is not allowed)",
                            place(i),
                            ["R", "G", "B"][c],
                            v
                        ),
                    });
                }
                if *v < 0.0 {
                    *v = 0.0;
                    negatives += 1;
                }
            }
        }
        Ok(if negatives > 0 {
            vec![format!("{}: clamped {negatives} negative channel values to 0", path.display())]
        } else {
            vec![]
        })
    }

    /// Radiance seen in direction `d` (world, +Y up), after rotating the map by `rotation`
    /// radians about +Y: bilinear between pixel centres, wrapping in u and clamped at the
    /// poles (for drawing backgrounds; `L` itself is built by exact integration).
    pub fn radiance(&self, d: Vec3, rotation: f64) -> Rgb {
        if self.width == 0 || self.height == 0 {
            return [0.0; 3];
        }
        if self.layout == EnvLayout::Cube {
            return super::cube_env::radiance(self, d, rotation);
        }
        let (u, v) = direction_to_latlong(rotate_y(d.as_dvec3(), -rotation));
        let x = u * self.width as f64 - 0.5;
        let y = (v * self.height as f64 - 0.5).clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let w = self.width as i64;
        let col = |i: i64| (i.rem_euclid(w)) as usize;
        let (c0, c1) = (col(x0 as i64), col(x0 as i64 + 1));
        let (r0, r1) = (y0 as usize, (y0 as usize + 1).min(self.height - 1));
        let p = |r: usize, c: usize| self.pixels[r * self.width + c];
        let (a, b, c, e) = (p(r0, c0), p(r0, c1), p(r1, c0), p(r1, c1));
        // `x + (y - x) t` is exact when x == y, so a constant map stays exactly constant.
        let lerp = |x: f32, y: f32, t: f32| x + (y - x) * t;
        std::array::from_fn(|i| lerp(lerp(a[i], b[i], fx), lerp(c[i], e[i], fx), fy))
    }

    /// Integral of radiance over the sphere, per channel (exact for the piecewise-constant map).
    pub fn total_power(&self) -> [f64; 3] {
        if self.layout == EnvLayout::Cube {
            return super::cube_env::total_power(self);
        }
        let mut s = [0.0f64; 3];
        for y in 0..self.height {
            let w = pixel_solid_angle(self.width, self.height, y);
            for x in 0..self.width {
                for c in 0..3 {
                    s[c] += self.pixels[y * self.width + x][c] as f64 * w;
                }
            }
        }
        s
    }

    /// This map as a lat-long image, for what draws only lat-long textures (the GPU
    /// background): itself, or a cube map looked up ([`EnvMap::radiance`]) at the centres of a
    /// `4F x 2F` lat-long image. Never for `L`, which integrates the map itself.
    pub fn latlong_view(&self) -> std::borrow::Cow<'_, EnvMap> {
        if self.layout == EnvLayout::LatLong {
            return std::borrow::Cow::Borrowed(self);
        }
        let (w, h) = (4 * self.width, 2 * self.width);
        let pixels = (0..w * h)
            .map(|i| {
                let (u, v) = (((i % w) as f64 + 0.5) / w as f64, ((i / w) as f64 + 0.5) / h as f64);
                self.radiance(latlong_direction(u, v).as_vec3(), 0.0)
            })
            .collect();
        std::borrow::Cow::Owned(EnvMap { width: w, height: h, pixels, layout: EnvLayout::LatLong })
    }
}

/// Exact solid angle of a pixel in row `y` of a `w x h` lat-long map.
pub fn pixel_solid_angle(w: usize, h: usize, y: usize) -> f64 {
    let t0 = PI * y as f64 / h as f64;
    let t1 = PI * (y + 1) as f64 / h as f64;
    2.0 * PI / w as f64 * (t0.cos() - t1.cos())
}

fn load_exr(path: &Path) -> Result<EnvMap> {
    // Non-finite pixels come back as warnings; `validate` rejects them, naming the first.
    let (img, _) = crate::scene::HdrImage::read_exr(path)?;
    Ok(EnvMap {
        width: img.width as usize,
        height: img.height as usize,
        pixels: img.pixels,
        layout: EnvLayout::LatLong,
    })
}

fn load_hdr(path: &Path) -> Result<EnvMap> {
    let img = image::open(path)
        .map_err(|e| CoreError::Input { path: path.into(), message: format!("cannot read Radiance HDR: {e}") })?
        .into_rgb32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let pixels = img.pixels().map(|p| [p.0[0], p.0[1], p.0[2]]).collect();
    Ok(EnvMap { width: w, height: h, pixels, layout: EnvLayout::LatLong })
}

/// The light vector `L` in its basis, RGB: in a cubemap, the power per texel (radiance
/// integrated over the texel's solid angle) in the order of [`Cubemap`] texels; in SH, the
/// radiance's coefficients (`crate::sh::light` projects and rotates). Its basis is fixed at
/// construction; the values are open (the stiff cases of the tests and `sun_boost` edit them).
#[derive(Clone, Debug, PartialEq)]
pub struct LightVector {
    basis: LightBasis,
    pub power: Vec<Rgb>,
    /// Per cubemap texel and RGB channel, the power-weighted mean direction of the light the
    /// texel holds (length at most 1: shorter where the light inside it spreads); `None` where
    /// the light was not splatted from an image (a constant light, a cube-map input, SH): then
    /// every texel's light comes from its centre. See [`Self::mean_direction`].
    means: Option<std::sync::Arc<Vec<[[f32; 3]; 3]>>>,
}

/// Where light moments take a cubemap texel's light from (`lighting.texel_directions`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TexelDirections {
    /// The power-weighted mean direction of the source pixels the texel averages, per channel
    /// (kept by [`LightVector::from_env`]): where a sun really is.
    Mean,
    /// The texel's centre, as `T` bins it. The default: against Mitsuba 3 the mean rule helped
    /// only the low sun of the bundled skies (BENCHMARKS.md, "Texel mean directions").
    #[default]
    Centre,
}

impl TexelDirections {
    /// The config's spelling.
    pub fn name(self) -> &'static str {
        match self {
            TexelDirections::Mean => "mean",
            TexelDirections::Centre => "centre",
        }
    }
}

impl LightVector {
    /// `L` from power values in `basis`; an error unless there are `basis.len()` of them.
    pub fn new(basis: LightBasis, power: Vec<Rgb>) -> Result<Self> {
        if power.len() != basis.len() {
            return Err(CoreError::Invalid(format!(
                "a light vector in the {basis} needs {} values, got {}",
                basis.len(),
                power.len()
            )));
        }
        Ok(Self { basis, power, means: None })
    }

    /// The basis of the values (the columns of the `T` it may be gathered with).
    pub fn basis(&self) -> LightBasis {
        self.basis
    }

    /// The cubemap layout of the values, `None` for a light in SH.
    pub fn cubemap(&self) -> Option<Cubemap> {
        self.basis.cubemap_layout()
    }

    /// Integrate `env` (rotated by `rotation` radians about +Y) over every texel of `cubemap`
    /// (a cube map input: [`super::cube_env`]).
    pub fn from_env(env: &EnvMap, cubemap: Cubemap, rotation: f64) -> Self {
        let basis = LightBasis::Cubemap(cubemap);
        if env.layout == EnvLayout::Cube {
            return Self { basis, power: super::cube_env::light_power(env, cubemap, rotation), means: None };
        }
        let resolution = cubemap.resolution;
        let n = cubemap.texel_count();
        // Sub-pixels small against a cubemap texel (about a quarter of its angular size).
        let s = 4usize.max((16.0 * resolution as f64 / env.height as f64).ceil() as usize);
        let (w, h) = (env.width, env.height);
        // Per texel: the power per channel, and per channel the power-weighted direction sum.
        type Acc = Vec<([f64; 3], [DVec3; 3])>;
        let acc: Acc = (0..h)
            .into_par_iter()
            .fold(
                || vec![([0.0f64; 3], [DVec3::ZERO; 3]); n],
                |mut acc: Acc, y| {
                    for sy in 0..s {
                        let v0 = (y as f64 + sy as f64 / s as f64) / h as f64;
                        let v1 = (y as f64 + (sy + 1) as f64 / s as f64) / h as f64;
                        let omega = 2.0 * PI / (w * s) as f64 * ((PI * v0).cos() - (PI * v1).cos());
                        let v = 0.5 * (v0 + v1);
                        for x in 0..w {
                            let p = env.pixels[y * w + x];
                            if p == [0.0; 3] {
                                continue;
                            }
                            for sx in 0..s {
                                let u = (x as f64 + (sx as f64 + 0.5) / s as f64) / w as f64;
                                let d = rotate_y(latlong_direction(u, v), rotation);
                                let k = cubemap.texel_of(d.as_vec3());
                                for c in 0..3 {
                                    let w = p[c] as f64 * omega;
                                    acc[k].0[c] += w;
                                    acc[k].1[c] += w * d;
                                }
                            }
                        }
                    }
                    acc
                },
            )
            .reduce(
                || vec![([0.0f64; 3], [DVec3::ZERO; 3]); n],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(&b) {
                        for c in 0..3 {
                            x.0[c] += y.0[c];
                            x.1[c] += y.1[c];
                        }
                    }
                    a
                },
            );
        let power = acc.iter().map(|(p, _)| [p[0] as f32, p[1] as f32, p[2] as f32]).collect();
        let means = acc
            .iter()
            .enumerate()
            .map(|(k, (p, sum))| {
                std::array::from_fn(|c| {
                    let m = if p[c] > 0.0 { sum[c] / p[c] } else { cubemap.texel_direction_f64(k) };
                    m.as_vec3().to_array()
                })
            })
            .collect();
        Self { basis, power, means: Some(std::sync::Arc::new(means)) }
    }

    /// The mean direction of texel `k`'s light in channel `c` (0, 1, 2): the power-weighted
    /// mean of the directions of the source pixels it holds, where the light was splatted from
    /// an image ([`Self::from_env`]), else (or for a dark channel) the texel's centre. Its
    /// length is at most 1; times `power[k][c]` it is the texel's exact first moment, whose dot
    /// with a normal is the texel's irradiance there (for the part above the horizon).
    /// `None` for a light in SH.
    pub fn mean_direction(&self, k: usize, c: usize) -> Option<DVec3> {
        let cube = self.cubemap()?;
        Some(match &self.means {
            Some(m) => DVec3::from(m[k][c].map(f64::from)),
            None => cube.texel_direction_f64(k),
        })
    }

    /// Whether texels keep their mean directions ([`Self::mean_direction`]).
    pub fn has_mean_directions(&self) -> bool {
        self.means.is_some()
    }

    /// The same light with every texel's light taken from its centre (`TexelDirections::Centre`).
    pub fn with_centre_directions(self) -> Self {
        Self { means: None, ..self }
    }

    /// A light vector of constant radiance `rgb` in every direction: `L_k = rgb * omega_k` in a
    /// cubemap; in SH only the constant coefficient, `rgb * sqrt(4 pi)`.
    pub fn constant(basis: LightBasis, rgb: Rgb) -> Self {
        let scale = |w: f64| rgb.map(|c| (c as f64 * w) as f32);
        let power = match basis {
            LightBasis::Cubemap(cubemap) => cubemap.solid_angles().iter().map(|&w| scale(w)).collect(),
            LightBasis::Sh(order) => {
                let mut p = vec![[0.0; 3]; order.len()];
                p[0] = scale((4.0 * PI).sqrt());
                p
            }
        };
        Self { basis, power, means: None }
    }

    /// Number of coefficients N (texels of a cubemap).
    pub fn len(&self) -> usize {
        self.power.len()
    }

    pub fn is_empty(&self) -> bool {
        self.power.is_empty()
    }

    /// Mean radiance of cubemap texel `k` (power / solid angle); `None` for a light in SH.
    pub fn radiance(&self, k: usize) -> Option<Rgb> {
        let w = self.cubemap()?.texel_solid_angle(k) as f32;
        let p = self.power[k];
        Some([p[0] / w, p[1] / w, p[2] / w])
    }

    /// Multiply the brightest texel (by Rec. 709 luminance) by `factor`: the stiff "sun" case
    /// of the experiments (`lighting.sun_boost`). Returns the texel, `None` for an empty `L`.
    pub fn boost_brightest(&mut self, factor: f32) -> Option<usize> {
        let lum = |p: &Rgb| crate::scene::image::luminance(*p);
        let k = (0..self.len()).max_by(|&a, &b| lum(&self.power[a]).total_cmp(&lum(&self.power[b])))?;
        self.power[k] = self.power[k].map(|v| v * factor);
        Some(k)
    }

    /// Total power per channel (f64 sum).
    pub fn total(&self) -> [f64; 3] {
        let mut s = [0.0; 3];
        for p in &self.power {
            for c in 0..3 {
                s[c] += p[c] as f64;
            }
        }
        s
    }
}

/// The sum of two threads' per-texel power sums (the reduction of the splatting folds that
/// turn a lat-long or cube-map image into a light vector).
pub(crate) fn add_power(mut a: Vec<[f64; 3]>, b: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    for (x, y) in a.iter_mut().zip(&b) {
        for c in 0..3 {
            x[c] += y[c];
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latlong_mapping_round_trips_and_is_documented() {
        assert!((latlong_direction(0.0, 0.5) - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12);
        assert!((latlong_direction(0.25, 0.5) - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-12);
        assert!((latlong_direction(0.3, 0.0) - DVec3::new(0.0, 1.0, 0.0)).length() < 1e-12);
        for (u, v) in [(0.1, 0.2), (0.6, 0.9), (0.99, 0.5), (0.5, 0.01)] {
            let (u2, v2) = direction_to_latlong(latlong_direction(u, v));
            assert!((u - u2).abs() < 1e-12 && (v - v2).abs() < 1e-12);
        }
    }

    #[test]
    fn constant_map_gives_four_pi() {
        let env = EnvMap::constant(256, 128, [1.0, 2.0, 0.5]);
        let l = LightVector::from_env(&env, Cubemap::new(8), 0.3);
        let t = l.total();
        let fp = 4.0 * PI;
        assert!((t[0] - fp).abs() < 1e-5 * fp && (t[1] - 2.0 * fp).abs() < 1e-5 * fp);
        // Each texel receives close to its own solid angle: splatting misassigns at most the
        // sub-pixels along its border (sub-pixel 0.18 deg against a 11 deg texel: < 3%).
        for k in 0..l.len() {
            let w = l.cubemap().unwrap().texel_solid_angle(k);
            assert!((l.power[k][0] as f64 - w).abs() < 0.03 * w, "texel {k}: {} vs {w}", l.power[k][0]);
        }
        assert!((LightVector::constant(LightBasis::cubemap(8).unwrap(), [1.0; 3]).total()[0] - fp).abs() < 1e-5);
    }

    #[test]
    fn single_bright_pixel_lands_in_its_texel() {
        let (w, h) = (512, 256);
        let mut env = EnvMap::constant(w, h, [0.0; 3]);
        // A pixel near u = 0.25 (+X), slightly above the horizon.
        let (x, y) = (128, 100);
        env.pixels[y * w + x] = [1000.0, 1.0, 0.0];
        let l = LightVector::from_env(&env, Cubemap::new(32), 0.0);
        let d = latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
        let k = l.cubemap().unwrap().texel_of(d.as_vec3());
        assert_eq!(l.cubemap().unwrap().texel_coords(k).0, 0, "must be on the +X face");
        let energy = 1000.0 * pixel_solid_angle(w, h, y);
        assert!((l.power[k][0] as f64 - energy).abs() < 1e-6 * energy);
        assert!((l.total()[0] - energy).abs() < 1e-6 * energy);
    }

    /// A sun of one pixel off its texel's centre: the texel's mean direction is where the
    /// pixel is (its exact solid-angle centroid, integrated here independently in f64 over a
    /// fine grid of the pixel), not the centre, and a second, dimmer pixel of another colour in
    /// the same texel pulls each channel's mean its own way. Rotation moves the means with the
    /// light; a constant map's means stay inside their texels, no longer than 1.
    #[test]
    fn texels_keep_the_mean_direction_of_their_light_per_channel() {
        let (w, h) = (512, 256);
        let mut env = EnvMap::constant(w, h, [0.0; 3]);
        let (x, y) = (140, 100);
        env.pixels[y * w + x] = [1000.0, 1000.0, 0.0];
        let cube = Cubemap::new(16);
        let centroid = |x: usize, y: usize, rotation: f64| {
            // The pixel's solid-angle-weighted mean direction, on a 64 x 64 grid of the pixel.
            let (mut sum, n) = (DVec3::ZERO, 64);
            for i in 0..n {
                let v = (y as f64 + (i as f64 + 0.5) / n as f64) / h as f64;
                for j in 0..n {
                    let u = (x as f64 + (j as f64 + 0.5) / n as f64) / w as f64;
                    sum += (PI * v).sin() * rotate_y(latlong_direction(u, v), rotation);
                }
            }
            sum.normalize()
        };
        let sun = centroid(x, y, 0.0);
        let l = LightVector::from_env(&env, cube, 0.0);
        assert!(l.has_mean_directions());
        let k = cube.texel_of(sun.as_vec3());
        let centre = cube.texel_direction_f64(k);
        let mean = l.mean_direction(k, 0).unwrap();
        let angle = |a: DVec3, b: DVec3| a.normalize().dot(b.normalize()).clamp(-1.0, 1.0).acos().to_degrees();
        // The sub-pixel splat's mean is the pixel's centroid to well under its 0.7-degree size;
        // the centre is degrees away.
        assert!(angle(mean, sun) < 0.05, "mean {:.4} deg from the sun", angle(mean, sun));
        assert!(angle(centre, sun) > 0.5, "the test's sun must sit off the centre");
        assert!((mean.length() - 1.0).abs() < 1e-4, "one pixel: the mean is a unit vector");
        // Blue is dark in that texel: its channel falls back to the centre.
        assert!(angle(l.mean_direction(k, 2).unwrap(), centre) < 1e-5);
        // A dimmer, blue-free second pixel in the same texel pulls green (equal power) halfway.
        let (x2, y2) = (x + 3, y + 2);
        let other = centroid(x2, y2, 0.0);
        assert_eq!(cube.texel_of(other.as_vec3()), k);
        env.pixels[y2 * w + x2] = [
            0.0,
            1000.0 * (PI * (y as f64 + 0.5) / h as f64).sin() as f32 / (PI * (y2 as f64 + 0.5) / h as f64).sin() as f32,
            0.0,
        ];
        let two = LightVector::from_env(&env, cube, 0.0);
        assert!(angle(two.mean_direction(k, 0).unwrap(), sun) < 0.05, "red has one pixel");
        let g = two.mean_direction(k, 1).unwrap();
        assert!(angle(g, sun + other) < 0.05, "green between the two: {:.4} deg", angle(g, sun + other));
        assert!(g.length() < 1.0);
        // Turned about +Y, the mean turns with the light.
        let turned = LightVector::from_env(&EnvMap { pixels: env.pixels.clone(), ..env.clone() }, cube, 0.7);
        let sun_turned = centroid(x, y, 0.7);
        let kt = cube.texel_of(sun_turned.as_vec3());
        assert!(angle(turned.mean_direction(kt, 0).unwrap(), sun_turned) < 0.05);
        // `centre` drops the means; a constant map's means stay in their texels.
        assert_eq!(two.clone().with_centre_directions().mean_direction(k, 1).unwrap(), centre);
        let flat = LightVector::from_env(&EnvMap::constant(256, 128, [1.0; 3]), cube, 0.0);
        for k in 0..flat.len() {
            let m = flat.mean_direction(k, 0).unwrap();
            assert!(m.length() <= 1.0 + 1e-6 && angle(m, cube.texel_direction_f64(k)) < 4.0, "texel {k}");
        }
    }

    #[test]
    fn rotation_moves_light_about_y() {
        let (w, h) = (256, 128);
        let mut env = EnvMap::constant(w, h, [0.0; 3]);
        env.pixels[64 * w] = [1.0; 3]; // u ~ 0: looks down -Z at the horizon
        let l = LightVector::from_env(&env, Cubemap::new(16), std::f64::consts::FRAC_PI_2);
        let k = (0..l.len()).max_by(|&a, &b| l.power[a][0].total_cmp(&l.power[b][0])).unwrap();
        // Rotating -Z by +90 degrees about +Y gives -X.
        assert_eq!(l.cubemap().unwrap().texel_coords(k).0, 1);
    }

    #[test]
    fn background_lookup_is_bilinear_and_exact_at_pixel_centres() {
        let (w, h) = (8, 4);
        let mut env = EnvMap::constant(w, h, [0.0; 3]);
        for (i, p) in env.pixels.iter_mut().enumerate() {
            *p = [i as f32, 1.0, 0.0];
        }
        let centre =
            |x: usize, y: usize| latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64).as_vec3();
        assert!((env.radiance(centre(3, 1), 0.0)[0] - 11.0).abs() < 1e-3);
        // Half way between pixels (3,1) and (4,1).
        let mid = latlong_direction(4.0 / w as f64, 1.5 / h as f64).as_vec3();
        assert!((env.radiance(mid, 0.0)[0] - 11.5).abs() < 1e-3);
        // Wrap-around between the last and first column.
        let seam = latlong_direction(0.0, 1.5 / h as f64).as_vec3();
        assert!((env.radiance(seam, 0.0)[0] - 11.5).abs() < 1e-3, "{:?}", env.radiance(seam, 0.0));
        assert_eq!(env.radiance(Vec3::Y, 0.0)[1], 1.0);
        // A constant map is reproduced exactly anywhere (backgrounds are compared exactly).
        let c = EnvMap::constant(w, h, [0.1, 0.2, 0.3]);
        assert_eq!(c.radiance(Vec3::new(0.3, -0.2, 0.7).normalize(), 0.7), [0.1, 0.2, 0.3]);
    }

    #[test]
    fn nan_pixel_is_rejected_with_location() {
        let mut env = EnvMap::constant(8, 4, [1.0; 3]);
        env.pixels[8 + 3][1] = f32::NAN;
        let err = env.validate(Path::new("sky.exr")).unwrap_err().to_string();
        assert!(err.contains("sky.exr") && err.contains("x=3, y=1") && err.contains("G"), "{err}");
    }
}
