//! The one RGB image type of biscale ([`HdrImage`]: linear radiance, row-major, row 0 at the
//! top), its files (OpenEXR for numbers, PNG for looking, both written atomically through
//! [`crate::io::write_atomic`]), and a rendered image with its coverage ([`Render`]), which
//! every shader returns (the CPU shader, the reference renderer and the wgpu shader).
//!
//! The OpenEXR reader here is the only one: environment maps are read through it too.

use crate::error::{CoreError, Result};
use crate::io::write_atomic;
use crate::sampling::EnvMap;
use crate::scene::Camera;
use crate::Rgb;
use glam::Vec3;
use std::path::Path;

/// A linear-RGB image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct HdrImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Rgb>,
}

/// Rec. 709 / sRGB luminance of linear RGB.
pub fn luminance(c: Rgb) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The sRGB transfer function (IEC 61966-2-1) of a linear value in [0, 1].
pub fn linear_to_srgb(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Most pixels an image file may hold (2^28, 3.2 GB as f32 RGB): far beyond any env map or
/// render, and small enough that a header claiming more is refused before allocating.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 28;

impl HdrImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![[0.0; 3]; width as usize * height as usize] }
    }

    /// Pixel `(x, y)`.
    pub fn get(&self, x: u32, y: u32) -> Rgb {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// An error unless the pixel count is `width * height`.
    pub fn check_size(&self, what: &str) -> Result<()> {
        if self.pixels.len() != self.width as usize * self.height as usize {
            return Err(CoreError::Invalid(format!(
                "{what}: {} pixels for a {}x{} image",
                self.pixels.len(),
                self.width,
                self.height
            )));
        }
        Ok(())
    }

    /// Number of pixels with a NaN or infinite channel, and the first one `(x, y)`.
    pub fn non_finite(&self) -> Option<(usize, (u32, u32))> {
        let w = self.width.max(1) as usize;
        let mut bad = self.pixels.iter().enumerate().filter(|(_, p)| !p.iter().all(|c| c.is_finite()));
        let (first, _) = bad.next()?;
        Some((1 + bad.count(), ((first % w) as u32, (first / w) as u32)))
    }

    /// Write a 32-bit float RGB OpenEXR file (lossless, RLE in 64x64 tiles), atomically and
    /// byte-reproducibly.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
        self.check_size(&path.display().to_string())?;
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
            let p = self.pixels[y * w + x];
            (p[0], p[1], p[2])
        });
        // Chunks in increasing order (the default lets parallel compression write them as they
        // finish), so the same image always gives the same bytes.
        let encoding = Encoding { line_order: LineOrder::Increasing, ..Encoding::FAST_LOSSLESS };
        let image = Image::from_encoded_channels((w, self.height as usize), encoding, channels);
        write_atomic(path, |out| image.write().to_buffered(out).map_err(|e| format!("cannot write OpenEXR: {e}")))
    }

    /// Read the first RGB(A) layer of an OpenEXR file (alpha is ignored). NaN and infinite
    /// pixels are kept as they are and reported in the returned warnings (with their count and
    /// the first position), so a caller decides; [`compare`] rejects them.
    pub fn read_exr(path: &Path) -> Result<(Self, Vec<String>)> {
        use exr::prelude::*;
        let exr_err = |e: exr::error::Error| match e {
            exr::error::Error::Io(source) => CoreError::Io { path: path.into(), source },
            e => CoreError::Input { path: path.into(), message: format!("cannot read OpenEXR: {e}") },
        };
        // The header first: its data window sizes the pixel buffer, and a crafted one (a 2 KB
        // file claiming 10^6 x 10^6 pixels) would otherwise abort the process on allocation.
        crate::io::check_regular(path).map_err(|source| CoreError::Io { path: path.into(), source })?;
        let meta = exr::meta::MetaData::read_from_file(path, false).map_err(exr_err)?;
        for header in &meta.headers {
            let (w, h) = (header.layer_size.width() as u64, header.layer_size.height() as u64);
            if w.saturating_mul(h) > MAX_IMAGE_PIXELS {
                return Err(CoreError::Input {
                    path: path.into(),
                    message: format!(
                        "the header says {w} x {h} pixels ({:.1} GB as f32 RGB), over the limit of {MAX_IMAGE_PIXELS} \
                         pixels: a damaged or crafted file?",
                        w as f64 * h as f64 * 12.0 / 1e9
                    ),
                });
            }
        }
        let image = read_first_rgba_layer_from_file(
            path,
            |resolution, _| {
                let (w, h) = (resolution.width(), resolution.height());
                (w, vec![[0.0f32; 3]; w * h])
            },
            |(w, px): &mut (usize, Vec<Rgb>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = [r, g, b];
            },
        )
        .map_err(exr_err)?;
        let size = image.layer_data.size;
        let (_, pixels) = image.layer_data.channel_data.pixels;
        let (width, height) = (size.width(), size.height());
        if width > u32::MAX as usize || height > u32::MAX as usize {
            return Err(CoreError::Input { path: path.into(), message: format!("image too large: {width}x{height}") });
        }
        let img = Self { width: width as u32, height: height as u32, pixels };
        let mut warnings = vec![];
        if let Some((count, (x, y))) = img.non_finite() {
            warnings.push(format!("{}: {count} pixel(s) with NaN or Inf, first at ({x}, {y})", path.display()));
        }
        Ok((img, warnings))
    }

    /// Tone map for display: `value * 2^exposure` (exposure in stops, 0 = unchanged), clamped
    /// to [0, 1], sRGB-encoded, rounded to 8 bits. NaN becomes 0.
    pub fn to_srgb8(&self, exposure: f32) -> image::RgbImage {
        let scale = exposure.exp2();
        let enc = |x: f32| {
            let v = (x * scale).clamp(0.0, 1.0);
            if v.is_nan() {
                0
            } else {
                (linear_to_srgb(v) * 255.0 + 0.5) as u8
            }
        };
        let mut out = image::RgbImage::new(self.width, self.height);
        for (o, p) in out.pixels_mut().zip(&self.pixels) {
            o.0 = p.map(enc);
        }
        out
    }

    /// The share of the pixels `mask` marks (all of them for `None`) that the tone map of
    /// [`Self::to_srgb8`] at `exposure` clips: a channel above 1 after `x 2^exposure`.
    pub fn clipped_fraction(&self, mask: Option<&[bool]>, exposure: f32) -> f64 {
        let scale = exposure.exp2();
        let (mut seen, mut clipped) = (0usize, 0usize);
        for (i, p) in self.pixels.iter().enumerate() {
            if mask.is_some_and(|m| !m.get(i).copied().unwrap_or(false)) {
                continue;
            }
            seen += 1;
            clipped += p.iter().any(|&x| x * scale > 1.0) as usize;
        }
        clipped as f64 / seen.max(1) as f64
    }

    /// The exposure (stops) at which at most `1 - quantile` of the pixels `mask` marks clip:
    /// the `quantile` of their largest channel (nearest rank, finite values only) is taken to
    /// white, rounded down to a tenth of a stop so that the count holds after rounding. `0`
    /// when there is no such pixel or the quantile is not positive (a black image).
    pub fn auto_exposure(&self, mask: Option<&[bool]>, quantile: f64) -> f32 {
        let mut peaks: Vec<f32> = (self.pixels.iter().enumerate())
            .filter(|(i, _)| mask.is_none_or(|m| m.get(*i).copied().unwrap_or(false)))
            .map(|(_, p)| p.iter().copied().fold(f32::NEG_INFINITY, f32::max))
            .filter(|v| v.is_finite())
            .collect();
        if peaks.is_empty() {
            return 0.0;
        }
        let rank = ((quantile.clamp(0.0, 1.0) * peaks.len() as f64).ceil() as usize).clamp(1, peaks.len()) - 1;
        let white = *peaks.select_nth_unstable_by(rank, f32::total_cmp).1;
        if white <= 0.0 {
            return 0.0;
        }
        ((-(white as f64).log2() * 10.0).floor() / 10.0) as f32
    }

    /// Write an 8-bit sRGB PNG ([`Self::to_srgb8`]), atomically.
    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<()> {
        self.check_size(&path.display().to_string())?;
        write_rgb8_png(&self.to_srgb8(exposure), path)
    }
}

/// Write an 8-bit RGB image (e.g. from [`error_image`]) as PNG, atomically.
pub fn write_rgb8_png(img: &image::RgbImage, path: &Path) -> Result<()> {
    write_atomic(path, |out| img.write_to(out, image::ImageFormat::Png).map_err(|e| format!("cannot write PNG: {e}")))
}

/// Write an 8-bit RGB image as PNG to a path a user names ([`crate::io::write_single_file`]):
/// never over anything but a PNG biscale wrote (unless `force`, a user's regular file); `-` is
/// standard output. The PNG carries biscale's mark ([`crate::io::mark_png`]).
pub fn write_rgb8_png_single(img: &image::RgbImage, path: &Path, force: bool) -> Result<()> {
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| CoreError::Input { path: path.into(), message: format!("cannot write PNG: {e}") })?;
    let png = crate::io::mark_png(png.get_ref()).ok_or_else(|| CoreError::Input {
        path: path.into(),
        message: "the PNG encoder wrote no IHDR chunk first".into(),
    })?;
    crate::io::write_single_file(path, crate::io::FileMark::Png, force, |out| {
        std::io::Write::write_all(out, &png).map_err(|e| e.to_string())
    })
}

/// A rendered image and its coverage: what every shader returns.
#[derive(Clone, Debug, PartialEq)]
pub struct Render {
    pub image: HdrImage,
    /// Row-major like the image: true where a ray of the pixel hits the mesh (the pixel
    /// centre's, with one sample per pixel).
    pub mask: Vec<bool>,
    /// With several samples per pixel: the fraction of each pixel's rays that hit the mesh
    /// (the image holds the hits' sum over all samples, so a silhouette pixel is partly
    /// black until [`Render::with_background`]). `None`: every covered pixel is covered whole.
    pub coverage: Option<Vec<f32>>,
}

impl Render {
    /// Write the coverage as an 8-bit grey PNG (255 where the mesh is hit, 0 elsewhere): the
    /// pixels a run's image errors are measured over, for `biscale diff --mask`.
    pub fn write_mask_png(&self, path: &Path) -> Result<()> {
        let (w, h) = (self.image.width, self.image.height);
        let grey = image::GrayImage::from_raw(w, h, self.mask.iter().map(|&m| if m { 255 } else { 0 }).collect())
            .ok_or_else(|| {
                CoreError::Invalid(format!("{}: mask of {} for {w}x{h}", path.display(), self.mask.len()))
            })?;
        write_atomic(path, |out| {
            grey.write_to(out, image::ImageFormat::Png).map_err(|e| format!("cannot write PNG: {e}"))
        })
    }
}

impl Render {
    /// Box-filter a one-sample-per-pixel render of [`Camera::supersampled`] down by `n` per
    /// axis: each pixel is the sum of its `n x n` samples' values over `n^2` (missed samples
    /// contribute 0), covered where any sample hits, with the hit fraction as its coverage.
    /// The same arithmetic as the CPU shaders' anti-aliasing, so a supersampled GPU render
    /// filtered here matches a CPU render of the original camera.
    pub fn box_filtered(&self, n: u32) -> Result<Render> {
        let (w, h) = (self.image.width, self.image.height);
        if n == 0 || w % n != 0 || h % n != 0 || self.coverage.is_some() {
            return Err(CoreError::Invalid(format!(
                "cannot box-filter a {w}x{h} render{} by {n}: it needs one sample per pixel and a size divisible by {n}",
                if self.coverage.is_some() { " with coverage" } else { "" }
            )));
        }
        if n == 1 {
            return Ok(self.clone());
        }
        let (cw, ch) = (w / n, h / n);
        let samples = (n * n) as f64;
        let mut image = HdrImage::new(cw, ch);
        let (mut mask, mut coverage) = (vec![false; (cw * ch) as usize], vec![0.0f32; (cw * ch) as usize]);
        for y in 0..ch {
            for x in 0..cw {
                let (mut sum, mut hits) = ([0.0f64; 3], 0u32);
                for j in 0..n {
                    for i in 0..n {
                        let s = ((y * n + j) * w + x * n + i) as usize;
                        if self.mask[s] {
                            let p = self.image.pixels[s];
                            (0..3).for_each(|c| sum[c] += p[c] as f64);
                            hits += 1;
                        }
                    }
                }
                let o = (y * cw + x) as usize;
                if hits > 0 {
                    image.pixels[o] = sum.map(|v| (v / samples) as f32);
                    mask[o] = true;
                    coverage[o] = hits as f32 / samples as f32;
                }
            }
        }
        Ok(Render { image, mask, coverage: Some(coverage) })
    }
}

/// A mask written by [`Render::write_mask_png`] (any PNG: a pixel is in where its luma is at
/// least 128), with its size.
pub fn read_mask_png(path: &Path) -> Result<(Vec<bool>, u32, u32)> {
    crate::io::check_regular(path).map_err(|source| CoreError::Io { path: path.into(), source })?;
    let img = image::open(path)
        .map_err(|e| CoreError::Input { path: path.into(), message: format!("not a readable mask image: {e}") })?;
    let grey = img.to_luma8();
    Ok((grey.pixels().map(|p| p.0[0] >= 128).collect(), grey.width(), grey.height()))
}

/// What a primary ray that misses the mesh sees.
#[derive(Clone, Copy, Debug)]
pub enum Background<'a> {
    Black,
    /// The environment map, rotated by `rotation` radians about +Y (as
    /// [`crate::sampling::LightVector::from_env`] rotates it), looked up bilinearly.
    Env {
        env: &'a EnvMap,
        rotation: f64,
    },
}

impl Background<'_> {
    /// Radiance seen along world direction `dir`.
    pub fn radiance(&self, dir: Vec3) -> Rgb {
        match self {
            Background::Black => [0.0; 3],
            Background::Env { env, rotation } => env.radiance(dir, *rotation),
        }
    }
}

impl Render {
    /// Fill every uncovered pixel with what `camera`'s ray through its centre sees of
    /// `background` (shaders leave uncovered pixels black), and add to a partly covered pixel
    /// its uncovered fraction of that same value (the background changes little across a
    /// pixel; each missed sample's own ray would differ by about its gradient over half a pixel).
    pub fn with_background(mut self, camera: &Camera, background: &Background<'_>) -> Self {
        if matches!(background, Background::Black) {
            return self;
        }
        let w = self.image.width as usize;
        for (i, (p, covered)) in self.image.pixels.iter_mut().zip(&self.mask).enumerate() {
            let missed = match (covered, &self.coverage) {
                (false, _) => 1.0,
                (true, Some(c)) if c[i] < 1.0 => 1.0 - c[i],
                (true, _) => continue,
            };
            let (_, dir) = camera.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let bg = background.radiance(dir);
            match covered {
                false => *p = bg,
                true => (0..3).for_each(|c| p[c] += missed * bg[c]),
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Box filtering a one-sample render by 2: sums over four samples divided by four, the
    /// hit fraction as coverage, any hit as the mask; sizes that do not divide, or a render
    /// that already has coverage, are refused.
    #[test]
    fn box_filtering_averages_samples_over_the_whole_cell() {
        let mut fine = Render { image: HdrImage::new(4, 2), mask: vec![false; 8], coverage: None };
        for (i, v) in [(0, 1.0), (1, 3.0), (4, 5.0), (2, 8.0)] {
            fine.image.pixels[i] = [v, 2.0 * v, 0.0];
            fine.mask[i] = true;
        }
        let coarse = fine.box_filtered(2).unwrap();
        assert_eq!((coarse.image.width, coarse.image.height), (2, 1));
        assert_eq!(coarse.image.pixels, vec![[9.0 / 4.0, 18.0 / 4.0, 0.0], [2.0, 4.0, 0.0]]);
        assert_eq!(coarse.mask, vec![true, true]);
        assert_eq!(coarse.coverage, Some(vec![0.75, 0.25]));
        assert_eq!(fine.box_filtered(1).unwrap(), fine);
        assert!(fine.box_filtered(3).unwrap_err().to_string().contains("divisible by 3"));
        assert!(coarse.box_filtered(1).unwrap_err().to_string().contains("with coverage"));
    }
    use crate::testing::random_hdr_image;
    use std::io::Write;

    #[test]
    fn exr_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        let mut img = random_hdr_image(37, 23, 1);
        img.pixels[5] = [f32::MAX, f32::MIN_POSITIVE, 0.0];
        img.pixels[6] = [f32::NAN, f32::INFINITY, -1.5];
        img.write_exr(&path).unwrap();
        let (back, warnings) = HdrImage::read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (37, 23));
        for (a, b) in img.pixels.iter().zip(&back.pixels) {
            for c in 0..3 {
                assert_eq!(a[c].to_bits(), b[c].to_bits(), "bit-exact f32 (NaN payload included)");
            }
        }
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("1 pixel(s)") && warnings[0].contains("(6, 0)"), "{warnings:?}");
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn png_is_written_with_srgb_encoding() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let img = HdrImage {
            width: 4,
            height: 1,
            pixels: vec![[0.0; 3], [0.5, 0.25, 0.125], [2.0, -1.0, f32::NAN], [0.214, 0.214, 0.214]],
        };
        img.write_png(&path, 1.0).unwrap();
        let back = image::open(&path).unwrap().into_rgb8();
        assert_eq!(back.dimensions(), (4, 1));
        // exposure +1 stop doubles: 0.5 -> 1.0 -> 255; 0.25 -> 0.5 -> sRGB 0.7354 -> 188;
        // 0.125 -> 0.25 -> 0.5371 -> 137; 0.214 * 2 = 0.428 -> 0.6860 -> 175.
        assert_eq!(back.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(back.get_pixel(1, 0).0, [255, 188, 137]);
        assert_eq!(back.get_pixel(2, 0).0, [255, 0, 0]);
        assert_eq!(back.get_pixel(3, 0).0, [175, 175, 175]);
    }

    #[test]
    fn auto_exposure_takes_the_quantile_to_white_and_clips_no_more() {
        // 1000 pixels with largest channels 0.001 .. 1.000, scaled by 8: the 99th percentile
        // (nearest rank 990) is 7.92, so the exposure is -log2(7.92) = -2.985 rounded down
        // to -3.0; at -3.0 the pixels above 8 (none) clip, at -2.9 the 67 above 2^2.9 = 7.464 would.
        let pixels: Vec<Rgb> = (1..=1000).map(|i| [0.0, 8.0 * i as f32 / 1000.0, 4.0 * i as f32 / 1000.0]).collect();
        let img = HdrImage { width: 1000, height: 1, pixels };
        let e = img.auto_exposure(None, 0.99);
        assert_eq!(e, -3.0);
        assert_eq!(img.clipped_fraction(None, e), 0.0);
        assert!((img.clipped_fraction(None, -2.9) - 0.067).abs() < 1e-9, "{}", img.clipped_fraction(None, -2.9));
        // The mask chooses the pixels: only the darkest ten, 0.008 i, peak 0.08 -> -log2 0.08 =
        // 3.64 -> 3.6; at 4 stops (x 16) i = 8, 9, 10 clip.
        let mask: Vec<bool> = (0..1000).map(|i| i < 10).collect();
        assert_eq!(img.auto_exposure(Some(&mask), 0.99), 3.6);
        assert_eq!(img.clipped_fraction(Some(&mask), 3.6), 0.0);
        assert_eq!(img.clipped_fraction(Some(&mask), 4.0), 0.3);
        // Non-finite pixels are left out; a black or empty selection is 0 stops.
        let mut odd = img.clone();
        odd.pixels[999] = [f32::INFINITY; 3];
        odd.pixels[998] = [f32::NAN; 3];
        // The largest finite peak is now pixel 997's 7.984: -log2 7.984 = -2.997 -> -3.0.
        assert_eq!(odd.auto_exposure(None, 1.0), -3.0);
        assert_eq!(img.auto_exposure(None, 1.0), -3.0, "8.0 itself maps to white exactly");
        assert_eq!(HdrImage::new(4, 4).auto_exposure(None, 0.99), 0.0);
        assert_eq!(img.auto_exposure(Some(&[false; 1000]), 0.99), 0.0);
    }

    #[test]
    fn bad_exr_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("garbage.exr");
        std::fs::write(&path, b"this is not an OpenEXR file").unwrap();
        let e = HdrImage::read_exr(&path).unwrap_err().to_string();
        assert!(e.contains("garbage.exr") && e.contains("OpenEXR"), "{e}");
        let e = HdrImage::read_exr(&dir.path().join("missing.exr")).unwrap_err().to_string();
        assert!(e.contains("missing.exr"), "{e}");
    }

    #[test]
    fn the_same_image_always_writes_the_same_exr_bytes() {
        // Regression (hostile input): identical runs gave EXRs whose pixels matched but whose
        // chunks (written as parallel compression finished) did not. Big enough for many
        // tiles, varied enough that RLE chunk sizes differ.
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (640u32, 480u32);
        let pixels = (0..w * h).map(|i| [(i % 7) as f32, (i % 13) as f32 * 0.5, ((i / w) % 3) as f32]).collect();
        let img = HdrImage { width: w, height: h, pixels };
        let bytes: Vec<Vec<u8>> = (0..4)
            .map(|i| {
                let p = dir.path().join(format!("{i}.exr"));
                img.write_exr(&p).unwrap();
                std::fs::read(&p).unwrap()
            })
            .collect();
        assert!(bytes.windows(2).all(|b| b[0] == b[1]), "EXR bytes differ between writes");
        assert_eq!(HdrImage::read_exr(&dir.path().join("0.exr")).unwrap().0, img);
    }

    #[test]
    fn an_exr_header_claiming_a_huge_image_is_refused_before_allocating() {
        // Regression (hostile input): a small EXR whose data window says 1,048,576 x 524,288
        // aborted the process (`memory allocation of 6597069766656 bytes failed`).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("crafted.exr");
        HdrImage { width: 2, height: 2, pixels: vec![[1.0; 3]; 4] }.write_exr(&path).unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
            let at = bytes.windows(name.len()).position(|w| w == name).expect("the attribute") + name.len();
            // size (4 bytes), then xMin, yMin, xMax, yMax as little-endian i32.
            bytes[at + 12..at + 16].copy_from_slice(&1_048_575i32.to_le_bytes());
            bytes[at + 16..at + 20].copy_from_slice(&524_287i32.to_le_bytes());
        }
        std::fs::write(&path, &bytes).unwrap();
        let e = HdrImage::read_exr(&path).unwrap_err().to_string();
        assert!(e.contains("crafted.exr") && e.contains("1048576 x 524288") && e.contains("limit"), "{e}");
    }

    #[test]
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let img = random_hdr_image(4, 4, 2);
        let missing = dir.path().join("no_such_dir").join("x.exr");
        let e = img.write_exr(&missing).unwrap_err().to_string();
        assert!(e.contains("x.exr"), "{e}");
        assert!(!missing.exists() && !dir.path().join("no_such_dir").exists());
        // An encoder failure mid-write leaves no output and no temporary file, and keeps an
        // existing output intact.
        let target = dir.path().join("keep.png");
        std::fs::write(&target, b"old").unwrap();
        let r = write_atomic(&target, |out| {
            out.write_all(b"partial").unwrap();
            Err("encoder exploded".into())
        });
        assert!(r.unwrap_err().to_string().contains("encoder exploded"));
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        // A wrong pixel count is an error, not a panic.
        let bad = HdrImage { width: 3, height: 3, pixels: vec![[0.0; 3]; 4] };
        assert!(bad.write_exr(&dir.path().join("bad.exr")).is_err());
        assert!(bad.write_png(&dir.path().join("bad.png"), 0.0).is_err());
    }
}
