//! Tileable height fields (the meso-scale geometry of a synthesized BTF) and albedo maps.
//!
//! A [`HeightField`] is an `N x N` grid of heights in **patch units** (the patch is the unit
//! square, so a height of `0.1` is a tenth of the patch's side). Sample `(i, j)` sits at patch
//! coordinates `(i / N, j / N)`; the surface is the periodic piecewise-linear interpolation of
//! the samples, two triangles per cell split along the diagonal from `(i, j)` to
//! `(i + 1, j + 1)`, with index `N` wrapping to `0`. Every procedural recipe is a function of
//! `(x, y)` that is periodic with period 1 by construction (integer lattice frequencies,
//! wrapped cell indices), so patches tile without seams.
//!
//! The recipes are the kinds of materials Sloan et al. 2003 ("Bi-scale radiance transfer",
//! SIGGRAPH 2003) and Sun et al. synthesize their BTFs from: bumps, weave, stucco, holes (deep
//! pits), bricks and scales. Each takes an amplitude (patch units), an integer frequency
//! (features per patch side) and a seed.

use crate::error::{Result, ShadingError};
use biscale_core::Rgb;
use std::f64::consts::PI;
use std::path::Path;

/// Largest accepted height-field side (4096^2 samples = 64 MiB of f32).
pub const MAX_HEIGHT_FIELD_SIZE: u32 = 4096;
/// Smallest accepted height-field side.
pub const MIN_HEIGHT_FIELD_SIZE: u32 = 2;

/// A periodic height field on the unit patch (see the module docs). `h[j * width + i]` is the
/// height of sample `(i, j)` at patch coordinates `(i / width, j / height)`, in patch units.
/// Width and height must be equal ([`Self::validate`]).
#[derive(Clone, Debug, PartialEq)]
pub struct HeightField {
    pub width: u32,
    pub height: u32,
    pub h: Vec<f32>,
}

/// The procedural patterns of [`Recipe`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Pattern {
    /// Smooth Gaussian bumps, one per cell of a `frequency x frequency` lattice, centre jittered
    /// by up to 0.3 cell, standard deviation 0.15..0.25 cell, peak `amplitude * (0.6..1.0)`.
    /// Where bumps overlap the higher one wins. Range `[0, amplitude]`.
    Bumps,
    /// A plain (over-under) weave of `frequency` threads per side in each direction: rounded
    /// thread cross-sections (90% of the pitch wide), undulating over and under the crossing
    /// threads; thread heights vary by +-5% with the seed. `frequency` must be even (the over-under
    /// pattern repeats every two threads). Range `[0, amplitude]`.
    Weave,
    /// Plaster: 4 octaves of periodic value noise on a `frequency x frequency` base lattice,
    /// normalized to `[0, 1]` and cubed (flat valleys, sharp ridges). Range `[0, amplitude]`.
    Stucco,
    /// Deep round pits in a flat top at height 0, one per cell of a `frequency x frequency`
    /// lattice: radius 0.25..0.35 cell, centre jittered by up to 0.15 cell, depth
    /// `amplitude * (0.8..1.0)`, walls steepened over 0.05 cell. Range `[-amplitude, 0]`.
    Holes,
    /// Running-bond bricks: `frequency` rows per side (must be even), bricks two rows long,
    /// every other row offset by half a brick; mortar joints 8% of a row wide at height 0,
    /// bevelled over another 8%; brick tops at `amplitude * (0.85..1.0)`. Range `[0, amplitude]`.
    Bricks,
    /// Overlapping scales: `frequency` rows of `frequency` domes (must be even), odd rows offset
    /// by half a scale, radius 0.75 pitch; a scale of a higher row lies on top of the lower rows
    /// (its edge is a small cliff); dome heights are `amplitude * (0.85..1.0)` with the seed. Range
    /// `[0, amplitude]`.
    Scales,
}

impl Pattern {
    /// Every pattern, in declaration order.
    pub const ALL: [Pattern; 6] =
        [Pattern::Bumps, Pattern::Weave, Pattern::Stucco, Pattern::Holes, Pattern::Bricks, Pattern::Scales];

    /// The lowercase name used in configs and reports.
    pub fn name(self) -> &'static str {
        match self {
            Pattern::Bumps => "bumps",
            Pattern::Weave => "weave",
            Pattern::Stucco => "stucco",
            Pattern::Holes => "holes",
            Pattern::Bricks => "bricks",
            Pattern::Scales => "scales",
        }
    }

    /// Inverse of [`Self::name`].
    pub fn from_name(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| {
            let names: Vec<_> = Self::ALL.iter().map(|p| p.name()).collect();
            ShadingError::Invalid(format!(
                "unknown height-field pattern '{name}' (expected one of {})",
                names.join(", ")
            ))
        })
    }

    fn needs_even_frequency(self) -> bool {
        matches!(self, Pattern::Weave | Pattern::Bricks | Pattern::Scales)
    }
}

/// A procedural height field: a pattern and its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Recipe {
    pub pattern: Pattern,
    /// Height scale in patch units (`>= 0`; 0 gives a flat patch). Typical: 0.02 .. 0.2.
    pub amplitude: f32,
    /// Features per patch side (`1..=256`; even for weave, bricks and scales).
    pub frequency: u32,
    /// Seed of the per-feature random variation (jitter, sizes, heights).
    pub seed: u64,
}

impl Recipe {
    pub fn new(pattern: Pattern, amplitude: f32, frequency: u32, seed: u64) -> Self {
        Self { pattern, amplitude, frequency, seed }
    }
}

impl HeightField {
    /// A flat field of `size x size` zeros.
    pub fn flat(size: u32) -> Result<Self> {
        check_size(size, size, "flat height field")?;
        Ok(Self { width: size, height: size, h: vec![0.0; (size * size) as usize] })
    }

    /// Sample a procedural [`Recipe`] at `size x size` points.
    pub fn procedural(recipe: &Recipe, size: u32) -> Result<Self> {
        let Recipe { pattern, amplitude, frequency: f, seed } = *recipe;
        let what = format!("{} height field", pattern.name());
        check_size(size, size, &what)?;
        if !(amplitude.is_finite() && amplitude >= 0.0) {
            return Err(ShadingError::Invalid(format!("{what}: amplitude must be finite and >= 0, got {amplitude}")));
        }
        if f == 0 || f > 256 {
            return Err(ShadingError::Invalid(format!("{what}: frequency must be 1..=256, got {f}")));
        }
        if pattern.needs_even_frequency() && f % 2 != 0 {
            return Err(ShadingError::Invalid(format!("{what}: frequency must be even to tile, got {f}")));
        }
        let n = size as usize;
        let a = amplitude as f64;
        let mut h = Vec::with_capacity(n * n);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
                let v = match pattern {
                    Pattern::Bumps => bumps(x, y, f, seed),
                    Pattern::Weave => weave(x, y, f, seed),
                    Pattern::Stucco => stucco(x, y, f, seed),
                    Pattern::Holes => holes(x, y, f, seed),
                    Pattern::Bricks => bricks(x, y, f, seed),
                    Pattern::Scales => scales(x, y, f, seed),
                };
                h.push((a * v) as f32);
            }
        }
        Ok(Self { width: size, height: size, h })
    }

    /// Load a grayscale height image: `h = amplitude * value`, where `value` is the grey level
    /// in `[0, 1]` for integer images (8- or 16-bit PNG; colour images are converted to luma)
    /// and the raw value for float images (OpenEXR `.exr`: mean of R, G, B; Radiance `.hdr`:
    /// luma). Image row 0 is patch `y = 0`. The image must be square, `2..=4096` pixels per
    /// side, and finite; every error names the file.
    pub fn from_image(path: &Path, amplitude: f32) -> Result<Self> {
        let file_err = |message: String| ShadingError::File { path: path.into(), message };
        if !(amplitude.is_finite() && amplitude >= 0.0) {
            return Err(file_err(format!("height amplitude must be finite and >= 0, got {amplitude}")));
        }
        let (w, hgt, values) = read_gray(path)?;
        if w != hgt {
            return Err(file_err(format!("height image must be square (the patch is the unit square), got {w}x{hgt}")));
        }
        if !(MIN_HEIGHT_FIELD_SIZE..=MAX_HEIGHT_FIELD_SIZE).contains(&w) {
            return Err(file_err(format!(
                "height image is {w}x{hgt}; sizes {MIN_HEIGHT_FIELD_SIZE}..={MAX_HEIGHT_FIELD_SIZE} per side are supported"
            )));
        }
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            let count = values.iter().filter(|v| !v.is_finite()).count();
            return Err(file_err(format!(
                "height image has {count} NaN or infinite pixel(s), first at ({}, {})",
                k % w as usize,
                k / w as usize
            )));
        }
        let h = values.iter().map(|v| v * amplitude).collect::<Vec<_>>();
        if let Some(k) = h.iter().position(|v| !v.is_finite()) {
            return Err(file_err(format!("height {} x amplitude {amplitude} overflows at pixel {k}", values[k])));
        }
        Ok(Self { width: w, height: hgt, h })
    }

    /// Check the size (square, `2..=4096`), the sample count, and that every height is finite.
    pub fn validate(&self) -> Result<()> {
        check_size(self.width, self.height, "height field")?;
        let expect = self.width as usize * self.height as usize;
        if self.h.len() != expect {
            return Err(ShadingError::Invalid(format!(
                "height field {}x{} holds {} samples, expected {expect}",
                self.width,
                self.height,
                self.h.len()
            )));
        }
        if let Some(k) = self.h.iter().position(|v| !v.is_finite()) {
            return Err(ShadingError::Invalid(format!(
                "height field: non-finite height at sample ({}, {})",
                k % self.width as usize,
                k / self.width as usize
            )));
        }
        Ok(())
    }

    /// `(min, max)` height.
    pub fn range(&self) -> (f32, f32) {
        self.h.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)))
    }

    /// True when every sample has the same height (zero amplitude): such a patch is tabulated
    /// analytically, without ray tracing.
    pub fn is_flat(&self) -> bool {
        let (lo, hi) = self.range();
        lo == hi
    }

    /// Mean height: the level of the macro-scale plane the BTF's texels lie in.
    pub fn mean(&self) -> f64 {
        self.h.iter().map(|&v| v as f64).sum::<f64>() / self.h.len().max(1) as f64
    }
}

fn check_size(w: u32, h: u32, what: &str) -> Result<()> {
    if w != h {
        return Err(ShadingError::Invalid(format!("{what}: must be square, got {w}x{h}")));
    }
    if !(MIN_HEIGHT_FIELD_SIZE..=MAX_HEIGHT_FIELD_SIZE).contains(&w) {
        return Err(ShadingError::Invalid(format!(
            "{what}: size {w} outside {MIN_HEIGHT_FIELD_SIZE}..={MAX_HEIGHT_FIELD_SIZE}"
        )));
    }
    Ok(())
}

/// Read an image as one float channel: `(width, height, values)` (see
/// [`HeightField::from_image`] for the conversion).
fn read_gray(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let is_exr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if is_exr {
        // NaN pixels come back as warnings; the caller turns them into an error.
        let (img, _warnings) = biscale_core::scene::HdrImage::read_exr(path)?;
        let v = img.pixels.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
        return Ok((img.width, img.height, v));
    }
    biscale_core::io::check_regular(path).map_err(|source| ShadingError::Io { path: path.into(), source })?;
    let img = image::open(path).map_err(|e| match e {
        image::ImageError::IoError(source) => ShadingError::Io { path: path.into(), source },
        e => ShadingError::File { path: path.into(), message: format!("cannot read image: {e}") },
    })?;
    let luma = img.to_luma32f();
    Ok((luma.width(), luma.height(), luma.into_raw()))
}

/// A diffuse-reflectance texture over the patch (linear RGB, `[0, 1]`), sampled at the visible
/// meso-scale point (nearest pixel, wrapping). It multiplies the diffuse term of the BRDF
/// (Lambertian albedo, Phong `kd`, Ashikhmin-Shirley `rd`), not the specular one.
/// `rgb[y * width + x]`, row 0 at patch `y = 0`.
#[derive(Clone, Debug, PartialEq)]
pub struct AlbedoMap {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<Rgb>,
}

impl AlbedoMap {
    /// Load a colour image: PNG (sRGB-encoded, decoded to linear) or OpenEXR (linear). Values
    /// must be finite and in `[0, 1]`; every error names the file.
    pub fn from_image(path: &Path) -> Result<Self> {
        let is_exr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
        let map = if is_exr {
            let (img, _) = biscale_core::scene::HdrImage::read_exr(path)?;
            Self { width: img.width, height: img.height, rgb: img.pixels }
        } else {
            biscale_core::io::check_regular(path).map_err(|source| ShadingError::Io { path: path.into(), source })?;
            let img = image::open(path)
                .map_err(|e| match e {
                    image::ImageError::IoError(source) => ShadingError::Io { path: path.into(), source },
                    e => ShadingError::File { path: path.into(), message: format!("cannot read image: {e}") },
                })?
                .to_rgb32f();
            let (width, height) = img.dimensions();
            let rgb = img.pixels().map(|p| p.0.map(srgb_to_linear)).collect();
            Self { width, height, rgb }
        };
        map.validate().map_err(|e| ShadingError::File { path: path.into(), message: e.to_string() })?;
        Ok(map)
    }

    /// Check the size (`1..=4096` per side), the pixel count and the value range `[0, 1]`.
    pub fn validate(&self) -> Result<()> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 || w > MAX_HEIGHT_FIELD_SIZE || h > MAX_HEIGHT_FIELD_SIZE {
            return Err(ShadingError::Invalid(format!("albedo map size {w}x{h} outside 1..=4096")));
        }
        if self.rgb.len() != w as usize * h as usize {
            return Err(ShadingError::Invalid(format!("albedo map {w}x{h} holds {} pixels", self.rgb.len())));
        }
        if let Some(k) = self.rgb.iter().position(|p| !p.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c))) {
            return Err(ShadingError::Invalid(format!(
                "albedo map pixel ({}, {}) = {:?} is not in [0, 1]",
                k % w as usize,
                k / w as usize,
                self.rgb[k]
            )));
        }
        Ok(())
    }

    /// The pixel containing patch point `(x, y)` (wrapping).
    pub fn sample(&self, x: f64, y: f64) -> Rgb {
        let wrap = |c: f64, n: u32| ((c * n as f64).floor() as i64).rem_euclid(n as i64) as usize;
        self.rgb[wrap(y, self.height) * self.width as usize + wrap(x, self.width)]
    }
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

// ---- procedural patterns: each returns a value in units of the amplitude ----

/// SplitMix64 finalizer: a well-mixed 64-bit hash.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Uniform `[0, 1)` for lattice point `(i, j)` (already wrapped), stream `salt`.
fn rand01(seed: u64, i: i64, j: i64, salt: u64) -> f64 {
    let h = mix(seed ^ mix((i as u64) ^ mix((j as u64) ^ mix(salt))));
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// `(unwrapped cell index, wrapped cell index)` pairs of the cells around coordinate `c`
/// (`c * f` in cells), `reach` cells each side.
fn cells_around(c: f64, f: u32, reach: i64) -> impl Iterator<Item = (i64, i64)> {
    let base = (c * f as f64).floor() as i64;
    (base - reach..=base + reach).map(move |k| (k, k.rem_euclid(f as i64)))
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A pattern of one feature per cell: the cell's centre jittered by up to `jitter / 2` cells
/// on each axis (random streams `salt`, `salt + 1`), looked for `reach` cells around a point.
struct CellFeatures {
    reach: i64,
    jitter: f64,
    salt: u64,
}

impl CellFeatures {
    /// Call `visit(d2, a, b)` for every feature near `(x, y)`: its squared distance to the
    /// point, and two more uniforms of its cell (streams `salt + 2`, `salt + 3`).
    fn visit(&self, x: f64, y: f64, f: u32, seed: u64, mut visit: impl FnMut(f64, f64, f64)) {
        let (fl, salt) = (f as f64, self.salt);
        for (cj, wj) in cells_around(y, f, self.reach) {
            for (ci, wi) in cells_around(x, f, self.reach) {
                let cx = (ci as f64 + 0.5 + self.jitter * (rand01(seed, wi, wj, salt) - 0.5)) / fl;
                let cy = (cj as f64 + 0.5 + self.jitter * (rand01(seed, wi, wj, salt + 1) - 0.5)) / fl;
                let d2 = (x - cx).powi(2) + (y - cy).powi(2);
                visit(d2, rand01(seed, wi, wj, salt + 2), rand01(seed, wi, wj, salt + 3));
            }
        }
    }
}

fn bumps(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let fl = f as f64;
    let mut best = 0.0f64;
    CellFeatures { reach: 2, jitter: 0.6, salt: 1 }.visit(x, y, f, seed, |d2, a, b| {
        let (sigma, peak) = ((0.15 + 0.1 * a) / fl, 0.6 + 0.4 * b);
        best = best.max(peak * (-d2 / (2.0 * sigma * sigma)).exp());
    });
    best
}

fn weave(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let fl = f as f64;
    // Warp thread i runs along y at x = (i + 0.5) / f; weft thread k along x at y = (k + 0.5) / f.
    let (i, k) = ((x * fl).floor(), (y * fl).floor());
    let (a, b) = (x * fl - i - 0.5, y * fl - k - 0.5);
    let profile = |c: f64| (1.0 - (2.0 * c / 0.9).powi(2)).max(0.0).sqrt();
    // Warp i is over weft k where i + k is even: cos(pi (f y - 0.5 + i)) = +1 there.
    let warp_up = 0.5 + 0.5 * (PI * (fl * y - 0.5 + i)).cos();
    let weft_up = 0.5 - 0.5 * (PI * (fl * x - 0.5 + k)).cos();
    let (wi, wk) = ((i as i64).rem_euclid(f as i64), (k as i64).rem_euclid(f as i64));
    let var_i = 0.95 + 0.1 * rand01(seed, wi, 0, 5);
    let var_k = 0.95 + 0.1 * rand01(seed, 0, wk, 6);
    let warp = profile(a) * (0.45 + 0.5 * warp_up) * var_i;
    let weft = profile(b) * (0.45 + 0.5 * weft_up) * var_k;
    warp.max(weft) / 1.05
}

/// Periodic value noise with lattice period `p` cells on the unit patch.
fn value_noise(x: f64, y: f64, p: u32, seed: u64, salt: u64) -> f64 {
    let (gx, gy) = (x * p as f64, y * p as f64);
    let (i0, j0) = (gx.floor(), gy.floor());
    let (fx, fy) = (gx - i0, gy - j0);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (fade(fx), fade(fy));
    let at = |di: i64, dj: i64| {
        let i = (i0 as i64 + di).rem_euclid(p as i64);
        let j = (j0 as i64 + dj).rem_euclid(p as i64);
        2.0 * rand01(seed, i, j, salt) - 1.0
    };
    let top = at(0, 0) + (at(1, 0) - at(0, 0)) * sx;
    let bottom = at(0, 1) + (at(1, 1) - at(0, 1)) * sx;
    top + (bottom - top) * sy
}

fn stucco(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let (mut n, mut amp, mut total) = (0.0, 1.0, 0.0);
    for o in 0..4u32 {
        n += amp * value_noise(x, y, f << o, seed, 10 + o as u64);
        total += amp;
        amp *= 0.5;
    }
    let t = (0.5 + 0.5 * n / total).clamp(0.0, 1.0);
    t * t * t
}

fn holes(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let fl = f as f64;
    let mut depth = 0.0f64;
    CellFeatures { reach: 1, jitter: 0.3, salt: 21 }.visit(x, y, f, seed, |d2, a, b| {
        let (r, deep) = ((0.25 + 0.1 * a) / fl, 0.8 + 0.2 * b);
        depth = depth.max(deep * (1.0 - smoothstep(r - 0.05 / fl, r, d2.sqrt())));
    });
    -depth
}

fn bricks(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let fl = f as f64;
    let row = (y * fl).floor();
    let v = y * fl - row;
    let shift = (row as i64).rem_euclid(2) as f64; // odd rows offset by half a brick (one row unit)
    let gx = (x * fl - shift) / 2.0; // in bricks
    let col = gx.floor();
    let u = gx - col;
    // Distance to the brick's edge in row-height units (a brick is 2 units long).
    let e = (2.0 * u.min(1.0 - u)).min(v.min(1.0 - v));
    let m = 0.08;
    let (wc, wr) = ((col as i64).rem_euclid((f / 2) as i64), (row as i64).rem_euclid(f as i64));
    let top = 0.85 + 0.15 * rand01(seed, wc, wr, 31);
    top * smoothstep(m, 2.0 * m, e)
}

fn scales(x: f64, y: f64, f: u32, seed: u64) -> f64 {
    let fl = f as f64;
    let r = 0.75 / fl;
    // The containing scale with the highest (unwrapped) row lies on top.
    let mut best: Option<(i64, f64, f64)> = None;
    for (rj, wj) in cells_around(y, f, 2) {
        let shift = 0.5 * (rj.rem_euclid(2)) as f64;
        for (ci, _) in cells_around(x, f, 2) {
            let cx = (ci as f64 + shift) / fl;
            let cy = rj as f64 / fl;
            let d = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
            if d < r && best.is_none_or(|(br, bx, _)| rj > br || (rj == br && cx > bx)) {
                let wi = ((ci as f64 + shift).floor() as i64).rem_euclid(f as i64);
                let var = 0.85 + 0.15 * rand01(seed, wi, wj, 41);
                best = Some((rj, cx, var * (1.0 - (d / r).powi(2)).sqrt()));
            }
        }
    }
    best.map_or(0.0, |b| b.2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recipes_tile_and_stay_in_range() {
        // Periodicity: evaluating each pattern at x and x + 1 (and y + 1) gives the same value,
        // up to the f64 rounding of the shifted coordinates (~1e-15 * features per side,
        // amplified by the steepest slopes: 1e-9 is far above that and far below any seam).
        for p in Pattern::ALL {
            let f = 4;
            for s in 0..50 {
                let (x, y) = (((s * 37) % 50) as f64 / 50.0 + 0.003, ((s * 11) % 50) as f64 / 50.0 + 0.007);
                let eval = |x: f64, y: f64| match p {
                    Pattern::Bumps => bumps(x, y, f, 9),
                    Pattern::Weave => weave(x, y, f, 9),
                    Pattern::Stucco => stucco(x, y, f, 9),
                    Pattern::Holes => holes(x, y, f, 9),
                    Pattern::Bricks => bricks(x, y, f, 9),
                    Pattern::Scales => scales(x, y, f, 9),
                };
                let v = eval(x, y);
                for (dx, dy) in [(1.0, 0.0), (0.0, 1.0), (-1.0, 2.0)] {
                    let w = eval(x + dx, y + dy);
                    assert!((v - w).abs() < 1e-9, "{p:?} at ({x},{y}) shifted ({dx},{dy}): {v} vs {w}");
                }
            }
            let hf = HeightField::procedural(&Recipe::new(p, 0.1, 4, 3), 64).unwrap();
            hf.validate().unwrap();
            let (lo, hi) = hf.range();
            let (elo, ehi) = if p == Pattern::Holes { (-0.1, 0.0) } else { (0.0, 0.1) };
            assert!(lo >= elo - 1e-6 && hi <= ehi + 1e-6, "{p:?}: range {lo}..{hi}");
            assert!(hi - lo > 0.03, "{p:?}: pattern is (nearly) flat: {lo}..{hi}");
            // The seed changes the pattern (stochastic variation is real).
            let other = HeightField::procedural(&Recipe::new(p, 0.1, 4, 4), 64).unwrap();
            assert_ne!(hf, other, "{p:?}: seed has no effect");
        }
    }

    #[test]
    fn zero_amplitude_is_flat() {
        for p in Pattern::ALL {
            assert!(HeightField::procedural(&Recipe::new(p, 0.0, 2, 1), 16).unwrap().is_flat());
        }
    }

    #[test]
    fn bad_recipes_are_errors() {
        assert!(HeightField::procedural(&Recipe::new(Pattern::Weave, 0.1, 3, 0), 32).is_err());
        assert!(HeightField::procedural(&Recipe::new(Pattern::Bumps, f32::NAN, 3, 0), 32).is_err());
        assert!(HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.1, 0, 0), 32).is_err());
        assert!(HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.1, 2, 0), 1).is_err());
        assert!(Pattern::from_name("velvet").is_err());
        assert_eq!(Pattern::from_name("scales").unwrap(), Pattern::Scales);
        let mut hf = HeightField::flat(4).unwrap();
        hf.h[5] = f32::NAN;
        assert!(hf.validate().unwrap_err().to_string().contains("(1, 1)"));
    }

    #[test]
    fn height_images_load_and_bad_ones_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        // 16-bit PNG: grey levels map to [0, 1] x amplitude.
        let png = dir.path().join("h.png");
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(8, 8, |x, _| image::Luma([(x * 9362) as u16]));
        img.save(&png).unwrap();
        let hf = HeightField::from_image(&png, 0.2).unwrap();
        assert_eq!((hf.width, hf.height), (8, 8));
        // 16-bit levels are exact to 1/65535 in [0, 1].
        assert!((hf.h[7] - 0.2 * (7.0 * 9362.0 / 65535.0)).abs() < 1e-6, "{}", hf.h[7]);
        assert_eq!(hf.h[0], 0.0);

        let wide = dir.path().join("wide.png");
        image::GrayImage::new(8, 4).save(&wide).unwrap();
        let e = HeightField::from_image(&wide, 0.1).unwrap_err().to_string();
        assert!(e.contains("wide.png") && e.contains("square"), "{e}");

        let tiny = dir.path().join("tiny.png");
        image::GrayImage::new(1, 1).save(&tiny).unwrap();
        let e = HeightField::from_image(&tiny, 0.1).unwrap_err().to_string();
        assert!(e.contains("tiny.png") && e.contains("1x1"), "{e}");

        let exr = dir.path().join("nan.exr");
        let mut hdr = biscale_core::scene::HdrImage::new(4, 4);
        hdr.pixels[6] = [f32::NAN; 3];
        hdr.write_exr(&exr).unwrap();
        let e = HeightField::from_image(&exr, 0.1).unwrap_err().to_string();
        assert!(e.contains("nan.exr") && e.contains("NaN") && e.contains("(2, 1)"), "{e}");

        let missing = dir.path().join("missing.png");
        assert!(HeightField::from_image(&missing, 0.1).unwrap_err().to_string().contains("missing.png"));
        let garbage = dir.path().join("garbage.png");
        std::fs::write(&garbage, b"not a png").unwrap();
        assert!(HeightField::from_image(&garbage, 0.1).unwrap_err().to_string().contains("garbage.png"));
    }

    #[test]
    fn albedo_maps_sample_with_wrapping() {
        let map = AlbedoMap { width: 2, height: 1, rgb: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] };
        map.validate().unwrap();
        assert_eq!(map.sample(0.25, 0.5), [1.0, 0.0, 0.0]);
        assert_eq!(map.sample(0.75, 3.5), [0.0, 1.0, 0.0]);
        assert_eq!(map.sample(-0.25, -0.5), [0.0, 1.0, 0.0]);
        let bad = AlbedoMap { width: 1, height: 1, rgb: vec![[1.5, 0.0, 0.0]] };
        assert!(bad.validate().is_err());
    }
}
