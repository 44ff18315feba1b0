//! HDR images, their files (OpenEXR for numbers, PNG for looking), error metrics and false
//! colour error images.
//!
//! Every write is atomic: the bytes go to a temporary file in the target's directory, which is
//! flushed, synced and then renamed over the target, so a failed or interrupted write never
//! leaves a half-written output (and a missing directory leaves nothing at all).

use crate::error::{Result, ShadingError};
use biscale_core::Rgb;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

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

impl HdrImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![[0.0; 3]; width as usize * height as usize] }
    }

    /// Pixel `(x, y)`.
    pub fn get(&self, x: u32, y: u32) -> Rgb {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    fn check_size(&self, what: &str) -> Result<()> {
        if self.pixels.len() != self.width as usize * self.height as usize {
            return Err(ShadingError::Invalid(format!(
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

    /// Write a 32-bit float RGB OpenEXR file (lossless), atomically.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
        self.check_size(&path.display().to_string())?;
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
            let p = self.pixels[y * w + x];
            (p[0], p[1], p[2])
        });
        let image = Image::from_channels((w, self.height as usize), channels);
        write_atomic(path, |out| image.write().to_buffered(out).map_err(|e| format!("cannot write OpenEXR: {e}")))
    }

    /// Read the first RGB(A) layer of an OpenEXR file (alpha is ignored). NaN and infinite
    /// pixels are kept as they are and reported in the returned warnings (with their count and
    /// the first position), so a caller decides; [`compare`] rejects them.
    pub fn read_exr(path: &Path) -> Result<(Self, Vec<String>)> {
        use exr::prelude::*;
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
        .map_err(|e| match e {
            exr::error::Error::Io(source) => ShadingError::Io { path: path.into(), source },
            e => ShadingError::File { path: path.into(), message: format!("cannot read OpenEXR: {e}") },
        })?;
        let size = image.layer_data.size;
        let (_, pixels) = image.layer_data.channel_data.pixels;
        let (width, height) = (size.width(), size.height());
        if width > u32::MAX as usize || height > u32::MAX as usize {
            return Err(ShadingError::File {
                path: path.into(),
                message: format!("image too large: {width}x{height}"),
            });
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

/// Write `path` through a temporary sibling file and a rename (see the module docs).
/// `write` reports encoder failures as a message.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<(), String>,
) -> Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let io = |source: std::io::Error| ShadingError::Io { path: path.into(), source };
    let name = path.file_name().ok_or_else(|| ShadingError::Invalid(format!("{}: not a file path", path.display())))?;
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp: PathBuf = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let file = OpenOptions::new().write(true).create_new(true).open(&tmp).map_err(io)?;
    let mut out = BufWriter::new(file);
    let result = write(&mut out)
        .map_err(|message| ShadingError::File { path: path.into(), message })
        .and_then(|()| out.flush().map_err(io))
        .and_then(|()| out.get_ref().sync_all().map_err(io));
    // Close the file before renaming or removing it.
    drop(out);
    let result = result.and_then(|()| std::fs::rename(&tmp, path).map_err(io));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Error of an image against a reference over the pixels of a mask.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ImageMetrics {
    /// Root mean square error over all channels of the masked pixels.
    pub rmse: f64,
    /// `20 log10(peak / rmse)` in dB, where `peak` is the largest channel value of the
    /// reference over the mask (HDR images have no fixed peak, so the reference's own range
    /// stands in). `+inf` when the images are equal (JSON writes it as null), `-inf` for a
    /// black reference with a non-zero error.
    pub psnr: f64,
    /// `||a - ref|| / ||ref||` over all channels of the masked pixels (0 when both are 0).
    pub rel_l2: f64,
    /// Number of pixels compared.
    pub pixels: usize,
}

fn check_pair(a: &HdrImage, b: &HdrImage, mask: Option<&[bool]>) -> Result<()> {
    a.check_size("image")?;
    b.check_size("reference image")?;
    if (a.width, a.height) != (b.width, b.height) {
        return Err(ShadingError::Invalid(format!(
            "image size {}x{} differs from the reference's {}x{}",
            a.width, a.height, b.width, b.height
        )));
    }
    if let Some(m) = mask {
        if m.len() != a.pixels.len() {
            return Err(ShadingError::Invalid(format!("mask has {} entries for {} pixels", m.len(), a.pixels.len())));
        }
    }
    Ok(())
}

/// Error metrics of `a` against `b_reference` over the pixels where `mask` is true (all pixels
/// without a mask), accumulated in f64. Sizes must match, the mask must not be empty, and
/// masked pixels must be finite in both images ([`ShadingError::NonFinite`] names the first).
pub fn compare(a: &HdrImage, b_reference: &HdrImage, mask: Option<&[bool]>) -> Result<ImageMetrics> {
    check_pair(a, b_reference, mask)?;
    let w = a.width as usize;
    let inside = |i: usize| mask.is_none_or(|m| m[i]);
    for (img, what) in [(a, "image"), (b_reference, "reference image")] {
        let mut bad = (0..img.pixels.len()).filter(|&i| inside(i) && !img.pixels[i].iter().all(|c| c.is_finite()));
        if let Some(first) = bad.next() {
            return Err(ShadingError::NonFinite {
                what: what.into(),
                count: 1 + bad.count(),
                first: ((first % w) as u32, (first / w) as u32),
            });
        }
    }
    let (mut d2, mut r2, mut peak, mut pixels) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for (i, (p, q)) in a.pixels.iter().zip(&b_reference.pixels).enumerate() {
        if !inside(i) {
            continue;
        }
        pixels += 1;
        for c in 0..3 {
            let (x, r) = (p[c] as f64, q[c] as f64);
            d2 += (x - r) * (x - r);
            r2 += r * r;
            peak = peak.max(r);
        }
    }
    if pixels == 0 {
        return Err(ShadingError::Invalid("compare: the mask selects no pixels".into()));
    }
    let rmse = (d2 / (3 * pixels) as f64).sqrt();
    let psnr = if rmse == 0.0 { f64::INFINITY } else { 20.0 * (peak / rmse).log10() };
    let rel_l2 = if r2 == 0.0 {
        if d2 == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (d2 / r2).sqrt()
    };
    Ok(ImageMetrics { rmse, psnr, rel_l2, pixels })
}

/// Matplotlib's viridis at 10 evenly spaced points (perceptually uniform, colour-blind safe).
const VIRIDIS: [[u8; 3]; 10] = [
    [0x44, 0x01, 0x54],
    [0x48, 0x28, 0x78],
    [0x3e, 0x49, 0x89],
    [0x31, 0x68, 0x8e],
    [0x26, 0x82, 0x8e],
    [0x1f, 0x9e, 0x89],
    [0x35, 0xb7, 0x79],
    [0x6e, 0xce, 0x58],
    [0xb5, 0xde, 0x2b],
    [0xfd, 0xe7, 0x25],
];

/// Colour of non-finite errors in [`error_image`]: magenta, which viridis never produces.
pub const NON_FINITE_COLOUR: [u8; 3] = [255, 0, 255];

/// The viridis ramp at `t` in [0, 1] (clamped), piecewise linear between the stops.
pub fn viridis(t: f32) -> [u8; 3] {
    let x = t.clamp(0.0, 1.0) * (VIRIDIS.len() - 1) as f32;
    let i = (x as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f32;
    std::array::from_fn(|c| (VIRIDIS[i][c] as f32 * (1.0 - f) + VIRIDIS[i + 1][c] as f32 * f + 0.5) as u8)
}

/// False-colour picture of the per-pixel error `luminance(|a - b|)` (channel-wise absolute
/// difference, then luminance, so colour shifts are not cancelled), mapped through
/// [`viridis`] with `error / scale` clamped to 1. `scale` defaults to the 99th percentile
/// (nearest rank) of the finite per-pixel errors, so a few outliers do not wash out the
/// picture; a zero or unusable scale falls back to the largest error (or 1 when all are 0).
/// Non-finite errors are drawn in [`NON_FINITE_COLOUR`]. Returns the picture and the scale
/// used (for the legend). Save it with [`write_rgb8_png`].
pub fn error_image(a: &HdrImage, b: &HdrImage, scale: Option<f32>) -> Result<(image::RgbImage, f32)> {
    check_pair(a, b, None)?;
    let err: Vec<f32> =
        a.pixels.iter().zip(&b.pixels).map(|(p, q)| luminance(std::array::from_fn(|c| (p[c] - q[c]).abs()))).collect();
    let mut finite: Vec<f32> = err.iter().copied().filter(|e| e.is_finite()).collect();
    let max = finite.iter().copied().fold(0.0f32, f32::max);
    let scale = match scale {
        Some(s) => s,
        None if finite.is_empty() => 0.0,
        None => {
            let rank = ((0.99 * finite.len() as f64).ceil() as usize).clamp(1, finite.len()) - 1;
            *finite.select_nth_unstable_by(rank, f32::total_cmp).1
        }
    };
    let scale = if scale > 0.0 && scale.is_finite() {
        scale
    } else if max > 0.0 {
        max
    } else {
        1.0
    };
    let mut out = image::RgbImage::new(a.width, a.height);
    for (o, e) in out.pixels_mut().zip(&err) {
        o.0 = if e.is_finite() { viridis(e / scale) } else { NON_FINITE_COLOUR };
    }
    Ok((out, scale))
}

/// [`error_image`] written as a PNG at `path` (atomically); returns the scale used.
pub fn write_error_image(a: &HdrImage, b: &HdrImage, scale: Option<f32>, path: &Path) -> Result<f32> {
    let (img, scale) = error_image(a, b, scale)?;
    write_rgb8_png(&img, path)?;
    Ok(scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_image(w: u32, h: u32, seed: u64) -> HdrImage {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // Values spanning many magnitudes, as HDR renders do.
        let pixels =
            (0..w * h).map(|_| std::array::from_fn(|_| rng.gen::<f32>() * 10f32.powi(rng.gen_range(-6..6)))).collect();
        HdrImage { width: w, height: h, pixels }
    }

    #[test]
    fn exr_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        let mut img = random_image(37, 23, 1);
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
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let img = random_image(4, 4, 2);
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

    #[test]
    fn metrics_on_known_inputs() {
        let r = random_image(16, 8, 3);
        // A constant offset c on every channel: rmse = c exactly (up to f32 rounding of the
        // sums x + c, relative 2^-24 of the values, which reach 1e5 here: keep c large enough).
        let c = 0.5f32;
        let mut reference = r.clone();
        for p in reference.pixels.iter_mut() {
            *p = p.map(|x| x.min(100.0));
        }
        let a = HdrImage { pixels: reference.pixels.iter().map(|p| p.map(|x| x + c)).collect(), ..reference.clone() };
        let m = compare(&a, &reference, None).unwrap();
        assert_eq!(m.pixels, 128);
        assert!((m.rmse - 0.5).abs() < 1e-5, "{}", m.rmse);
        let peak = reference.pixels.iter().flatten().fold(0.0f32, |x, &y| x.max(y)) as f64;
        assert!((m.psnr - 20.0 * (peak / 0.5).log10()).abs() < 1e-4);
        let norm: f64 = reference.pixels.iter().flatten().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
        // Each difference is 0.5 up to the f32 rounding of x + c (<= 2^-24 * 100 = 6e-6).
        assert!((m.rel_l2 - 0.5 * (384f64).sqrt() / norm).abs() < 2e-5 * m.rel_l2);
        // Identical images: rmse 0, psnr +inf.
        let same = compare(&reference, &reference, None).unwrap();
        assert_eq!((same.rmse, same.psnr, same.rel_l2), (0.0, f64::INFINITY, 0.0));
        // Mask: only the masked pixels count. Pixel 0 differs by (3, 0, 0): rmse = sqrt(9/3).
        let mut b = reference.clone();
        b.pixels[0][0] += 3.0;
        b.pixels[1][1] += 100.0; // outside the mask
        let mut mask = vec![false; 128];
        mask[0] = true;
        mask[2] = true;
        let m = compare(&b, &reference, Some(&mask)).unwrap();
        assert_eq!(m.pixels, 2);
        assert!((m.rmse - (9.0f64 / 6.0).sqrt()).abs() < 1e-5, "{}", m.rmse);
        // Errors: size mismatch, bad mask, empty mask, NaN inside the mask.
        assert!(compare(&random_image(16, 9, 1), &reference, None).is_err());
        assert!(compare(&b, &reference, Some(&mask[..10])).is_err());
        assert!(compare(&b, &reference, Some(&[false; 128])).is_err());
        b.pixels[2][1] = f32::NAN;
        let e = compare(&b, &reference, Some(&mask)).unwrap_err().to_string();
        assert!(e.contains("(2, 0)"), "{e}");
        mask[2] = false;
        assert!(compare(&b, &reference, Some(&mask)).is_ok(), "NaN outside the mask is ignored");
    }

    #[test]
    fn error_image_ramps_and_saves() {
        let reference = HdrImage::new(100, 1);
        let mut a = reference.clone();
        for (i, p) in a.pixels.iter_mut().enumerate() {
            *p = [i as f32; 3]; // luminance error = i
        }
        a.pixels[99] = [f32::NAN; 3];
        let (img, scale) = error_image(&a, &reference, None).unwrap();
        // 99 finite errors 0..=98: the 99th percentile by nearest rank is rank ceil(0.99*99) = 99,
        // the value 98.
        // (Rec. 709 weights sum to 1 up to f32 rounding.)
        assert!((scale - 98.0).abs() < 1e-4, "{scale}");
        assert_eq!(img.get_pixel(0, 0).0, VIRIDIS[0]);
        assert_eq!(img.get_pixel(98, 0).0, VIRIDIS[9]);
        assert_eq!(img.get_pixel(99, 0).0, NON_FINITE_COLOUR);
        let (img, _) = error_image(&a, &reference, Some(49.0)).unwrap();
        assert_eq!(img.get_pixel(80, 0).0, VIRIDIS[9], "clamped above the scale");
        // Luminance of the ramp increases monotonically (perceptual ordering).
        let lum = |c: [u8; 3]| 0.2126 * c[0] as f32 + 0.7152 * c[1] as f32 + 0.0722 * c[2] as f32;
        for i in 0..98 {
            assert!(lum(img.get_pixel(i + 1, 0).0) >= lum(img.get_pixel(i, 0).0));
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("err.png");
        write_rgb8_png(&img, &path).unwrap();
        assert_eq!(image::open(&path).unwrap().into_rgb8(), img);
        assert_eq!(write_error_image(&a, &reference, Some(49.0), &path).unwrap(), 49.0);
        assert_eq!(image::open(&path).unwrap().into_rgb8(), img);
        assert!(error_image(&a, &HdrImage::new(10, 10), None).is_err());
    }
}
