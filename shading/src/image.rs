//! Error metrics of images against a reference (HDR here, the tone-mapped LDR ones in
//! [`crate::ldr`]), resampling for a comparison across sizes, and false-colour error images
//! (the report's comparisons). The image type itself is core's [`HdrImage`].

use crate::error::{Result, ShadingError};
use biscale_core::scene::image::{luminance, write_rgb8_png, HdrImage};
use std::path::Path;

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
    /// LDR PSNR in dB after the report's tone map: `10 log10(1 / mse)` with peak 1 over the
    /// masked pixels' three channels of [`crate::ldr::tone_map`] (`x 2^exposure`, clamped to
    /// [0, 1], sRGB-encoded, not rounded to 8 bits). `+inf` when equal (JSON: null).
    pub ldr_psnr: f64,
    /// SSIM (Wang et al. 2004: 11 x 11 Gaussian window, sigma 1.5, K1 = 0.01, K2 = 0.03, L = 1)
    /// of the tone-mapped values, per channel, averaged over R, G, B and the masked pixels
    /// ([`crate::ldr::ssim_map`]). 1 when equal.
    pub ssim: f64,
    /// Mean LDR FLIP error over the masked pixels, of the report's 8-bit PNG pixels
    /// ([`crate::ldr::flip_map`]): 0 when equal, at most 1.
    pub flip: f64,
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

/// [`compare_exposed`] at exposure 0 (the tone map of the LDR figures leaves values as they are).
pub fn compare(a: &HdrImage, b_reference: &HdrImage, mask: Option<&[bool]>) -> Result<ImageMetrics> {
    compare_exposed(a, b_reference, mask, 0.0)
}

/// Error metrics of `a` against `b_reference` over the pixels where `mask` is true (all pixels
/// without a mask), accumulated in f64; the LDR ones after the tone map at `exposure` (stops,
/// the run's `[report] exposure`). Sizes must match, the mask must not be empty, and
/// masked pixels must be finite in both images ([`ShadingError::NonFinite`] names the first).
pub fn compare_exposed(
    a: &HdrImage,
    b_reference: &HdrImage,
    mask: Option<&[bool]>,
    exposure: f32,
) -> Result<ImageMetrics> {
    check_pair(a, b_reference, mask)?;
    if !exposure.is_finite() {
        return Err(ShadingError::Invalid(format!("compare: exposure {exposure} is not finite")));
    }
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
    let rel_l2 = biscale_core::stats::relative_l2(d2, r2);
    let ldr = crate::ldr::ldr_metrics(a, b_reference, mask, exposure);
    Ok(ImageMetrics { rmse, psnr, rel_l2, pixels, ldr_psnr: ldr.ldr_psnr, ssim: ldr.ssim, flip: ldr.flip })
}

/// How [`resample`] changed an image's size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Resampling {
    /// Already the size asked for: unchanged.
    None,
    /// Each output pixel is the mean of an `fx x fy` block (the size divides exactly).
    Box { fx: u32, fy: u32 },
    /// Bilinear interpolation at the output pixels' centres, edges clamped.
    Bilinear,
}

impl std::fmt::Display for Resampling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Resampling::None => write!(f, "not resampled"),
            Resampling::Box { fx, fy } => write!(f, "box-filtered over {fx}x{fy} pixel blocks"),
            Resampling::Bilinear => write!(f, "resampled bilinearly (no prefilter: a large downsample aliases)"),
        }
    }
}

/// `img` at `width x height`: a box filter (block means, f64) when its size is an integer
/// multiple of that in both axes, else bilinear interpolation at pixel centres (source
/// position `(x + 0.5) * w_in / w_out - 0.5`, clamped to the edge). For comparing images of
/// different resolutions (`biscale diff`); the returned [`Resampling`] says which was done.
pub fn resample(img: &HdrImage, width: u32, height: u32) -> Result<(HdrImage, Resampling)> {
    img.check_size("image to resample")?;
    let (sw, sh) = (img.width, img.height);
    if (sw, sh) == (width, height) {
        return Ok((img.clone(), Resampling::None));
    }
    if sw == 0 || sh == 0 || width == 0 || height == 0 {
        return Err(ShadingError::Invalid(format!("cannot resample a {sw}x{sh} image to {width}x{height}")));
    }
    let at = |x: u32, y: u32| img.pixels[y as usize * sw as usize + x as usize];
    if sw % width == 0 && sh % height == 0 {
        let (fx, fy) = (sw / width, sh / height);
        let n = (fx * fy) as f64;
        let pixels = (0..width * height)
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let mut s = [0.0f64; 3];
                for v in y * fy..(y + 1) * fy {
                    for u in x * fx..(x + 1) * fx {
                        let p = at(u, v);
                        for c in 0..3 {
                            s[c] += p[c] as f64;
                        }
                    }
                }
                s.map(|v| (v / n) as f32)
            })
            .collect();
        return Ok((HdrImage { width, height, pixels }, Resampling::Box { fx, fy }));
    }
    // Source coordinate of an output pixel centre along an axis, split into the lower sample
    // and the weight of the upper one.
    let axis = |o: u32, n_out: u32, n_in: u32| -> (u32, u32, f64) {
        let s = ((o as f64 + 0.5) * n_in as f64 / n_out as f64 - 0.5).clamp(0.0, (n_in - 1) as f64);
        let i = (s.floor() as u32).min(n_in - 1);
        (i, (i + 1).min(n_in - 1), s - i as f64)
    };
    let pixels = (0..width * height)
        .map(|i| {
            let ((x0, x1, tx), (y0, y1, ty)) = (axis(i % width, width, sw), axis(i / width, height, sh));
            let (p00, p10, p01, p11) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
            std::array::from_fn(|c| {
                let top = p00[c] as f64 * (1.0 - tx) + p10[c] as f64 * tx;
                let bottom = p01[c] as f64 * (1.0 - tx) + p11[c] as f64 * tx;
                (top * (1.0 - ty) + bottom * ty) as f32
            })
        })
        .collect();
    Ok((HdrImage { width, height, pixels }, Resampling::Bilinear))
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
    use biscale_core::testing::random_hdr_image;

    #[test]
    fn metrics_on_known_inputs() {
        let r = random_hdr_image(16, 8, 3);
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
        assert!(compare(&random_hdr_image(16, 9, 1), &reference, None).is_err());
        assert!(compare(&b, &reference, Some(&mask[..10])).is_err());
        assert!(compare(&b, &reference, Some(&[false; 128])).is_err());
        b.pixels[2][1] = f32::NAN;
        let e = compare(&b, &reference, Some(&mask)).unwrap_err().to_string();
        assert!(e.contains("(2, 0)"), "{e}");
        mask[2] = false;
        assert!(compare(&b, &reference, Some(&mask)).is_ok(), "NaN outside the mask is ignored");
    }

    #[test]
    fn resampling_box_filters_exact_multiples_and_interpolates_otherwise() {
        let img = random_hdr_image(6, 4, 5);
        // A 2x nearest upsample box-filters back to the original exactly (4 equal values).
        let up = HdrImage {
            width: 12,
            height: 8,
            pixels: (0..96).map(|i| img.pixels[(i / 12 / 2) * 6 + (i % 12) / 2]).collect(),
        };
        let (down, how) = resample(&up, 6, 4).unwrap();
        assert_eq!((down.pixels == img.pixels, how), (true, Resampling::Box { fx: 2, fy: 2 }));
        // 3x1 blocks: each output pixel is the block's mean.
        let (d, how) = resample(&img, 2, 4).unwrap();
        assert_eq!(how, Resampling::Box { fx: 3, fy: 1 });
        let mean = (0..3).map(|u| img.pixels[6 + u][1] as f64).sum::<f64>() / 3.0;
        assert!((d.pixels[2][1] as f64 - mean).abs() <= 1e-6 * mean, "{} vs {mean}", d.pixels[2][1]);
        // Not a multiple: bilinear, which keeps a linear ramp linear (and a constant constant).
        let ramp = HdrImage { width: 4, height: 3, pixels: (0..12).map(|i| [(i % 4) as f32, 1.0, 2.0]).collect() };
        let (r, how) = resample(&ramp, 6, 2).unwrap();
        assert_eq!(how, Resampling::Bilinear);
        for (i, p) in r.pixels.iter().enumerate() {
            // Output centre x + 0.5 maps to (x + 0.5) * 4 / 6 - 0.5, clamped to [0, 3].
            let want = (((i % 6) as f32 + 0.5) * 4.0 / 6.0 - 0.5).clamp(0.0, 3.0);
            assert!((p[0] - want).abs() < 1e-6 && p[1] == 1.0 && p[2] == 2.0, "{i}: {p:?} vs {want}");
        }
        assert_eq!(resample(&img, 6, 4).unwrap(), (img.clone(), Resampling::None));
        assert!(resample(&img, 0, 4).is_err());
    }

    #[test]
    fn compare_reports_the_ldr_figures_at_the_exposure() {
        let b = random_hdr_image(20, 10, 8);
        let a = HdrImage { pixels: b.pixels.iter().map(|p| p.map(|x| x * 1.1)).collect(), ..b.clone() };
        let at = |e: f32| compare_exposed(&a, &b, None, e).unwrap();
        let m = at(0.0);
        assert_eq!(m, compare(&a, &b, None).unwrap());
        assert!(m.ldr_psnr.is_finite() && m.ssim < 1.0 && m.flip > 0.0, "{m:?}");
        // Another exposure changes only the LDR figures.
        let n = at(5.0);
        assert_eq!((n.rmse, n.psnr, n.rel_l2, n.pixels), (m.rmse, m.psnr, m.rel_l2, m.pixels));
        assert!(n.ldr_psnr != m.ldr_psnr && n.ssim != m.ssim, "{n:?} vs {m:?}");
        let e = compare_exposed(&a, &b, None, f32::NAN).unwrap_err().to_string();
        assert!(e.contains("exposure NaN"), "{e}");
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
