//! Display-referred (LDR) error metrics: the images as the report's PNGs show them, measured
//! the way the rendering literature reports them (PSNR with peak 1, SSIM, FLIP), so the
//! report's figures can be set beside published ones. HDR figures are in [`crate::image`].
//!
//! Every metric here takes the run's tone map ([`tone_map`]); the window statistics (SSIM,
//! FLIP) see every pixel, the mask only selects which pixels' values are averaged.

use biscale_core::scene::HdrImage;
use rayon::prelude::*;

/// Half width of the SSIM window: 11 x 11 pixels (Wang et al. 2004).
pub const SSIM_RADIUS: usize = 5;
/// Standard deviation of the SSIM window's Gaussian, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's stabilising constants `C1 = (K1 L)^2`, `C2 = (K2 L)^2` with dynamic range `L = 1`.
pub const SSIM_K1: f64 = 0.01;
pub const SSIM_K2: f64 = 0.03;
const C1: f64 = SSIM_K1 * SSIM_K1;
const C2: f64 = SSIM_K2 * SSIM_K2;

/// Pixels per degree of visual angle FLIP is evaluated at: NVIDIA's default, a 0.7 m wide
/// 3840-pixel monitor seen from 0.7 m.
pub const FLIP_PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

/// The tone map of the report's PNGs ([`HdrImage::to_srgb8`]) without its 8-bit rounding, in
/// f64: `v = clamp(x * 2^exposure, 0, 1)`, then the sRGB transfer function (IEC 61966-2-1).
/// Values lie in [0, 1] (the peak of the LDR metrics is 1, exactly 1 at the clamp); NaN maps
/// to 0 as in the PNG.
pub fn tone_map(x: f32, exposure: f32) -> f64 {
    let v = (x as f64 * (exposure as f64).exp2()).clamp(0.0, 1.0);
    if v.is_nan() {
        0.0
    } else if v == 1.0 {
        1.0 // the formula gives 1 - 1e-16
    } else if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The LDR figures of an image against a reference ([`ldr_metrics`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LdrMetrics {
    /// `10 log10(1 / mse)` in dB over the masked pixels' three tone-mapped channels
    /// ([`tone_map`], peak 1); `+inf` when they are equal.
    pub ldr_psnr: f64,
    /// Mean SSIM over the masked pixels and the R, G, B channels ([`ssim_map`]).
    pub ssim: f64,
    /// Mean FLIP error over the masked pixels ([`flip_map`]).
    pub flip: f64,
}

/// One channel of `img` tone-mapped ([`tone_map`]), row-major.
fn channel(img: &HdrImage, c: usize, exposure: f32) -> Vec<f64> {
    img.pixels.par_iter().map(|p| tone_map(p[c], exposure)).collect()
}

/// LDR PSNR, SSIM and FLIP of `a` against `b_reference` at `exposure` over the pixels where
/// `mask` is true (all without one). Sizes must match and the mask must select a pixel (the
/// caller checks, as [`crate::image::compare`] does). SSIM is the mean over R, G and B of each
/// channel's SSIM (as scikit-image's `channel_axis` does), on the tone-mapped values rather
/// than on luma, so a colour shift counts.
pub fn ldr_metrics(a: &HdrImage, b_reference: &HdrImage, mask: Option<&[bool]>, exposure: f32) -> LdrMetrics {
    let (w, h) = (a.width as usize, a.height as usize);
    let inside = |i: usize| mask.is_none_or(|m| m[i]);
    let pixels = (0..w * h).filter(|&i| inside(i)).count();
    let ((sse, ssim_sum), flip) = rayon::join(
        || {
            let (mut sse, mut ssim_sum) = (0.0f64, 0.0f64);
            for c in 0..3 {
                let (x, y) = (channel(a, c, exposure), channel(b_reference, c, exposure));
                let map = ssim_map(&x, &y, w, h);
                for i in (0..w * h).filter(|&i| inside(i)) {
                    sse += (x[i] - y[i]) * (x[i] - y[i]);
                    ssim_sum += map[i];
                }
            }
            (sse, ssim_sum)
        },
        || {
            let map = flip_map(a, b_reference, exposure);
            (0..w * h).filter(|&i| inside(i)).map(|i| map[i] as f64).sum::<f64>()
        },
    );
    let n = pixels.max(1) as f64;
    let ldr_psnr = if sse == 0.0 { f64::INFINITY } else { -10.0 * (sse / (3.0 * n)).log10() };
    LdrMetrics { ldr_psnr, ssim: ssim_sum / (3.0 * n), flip: flip / n }
}

/// The SSIM window's Gaussian weights `exp(-d^2 / (2 sigma^2))` for `d = -5..=5`, not
/// normalised (each position normalises over the part of the window inside the image).
fn ssim_weights() -> [f64; 2 * SSIM_RADIUS + 1] {
    std::array::from_fn(|k| {
        let d = k as f64 - SSIM_RADIUS as f64;
        (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
    })
}

/// SSIM of one pixel from the window means of `x`, `y`, `x^2`, `y^2`, `x y`.
fn ssim_of([mx, my, mxx, myy, mxy]: [f64; 5]) -> f64 {
    let (sxx, syy, sxy) = (mxx - mx * mx, myy - my * my, mxy - mx * my);
    ((2.0 * mx * my + C1) * (2.0 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
}

/// Per-pixel SSIM (Wang, Bovik, Sheikh, Simoncelli 2004) of one channel `x` against `y`
/// (`w x h`, row-major, values in [0, 1]): the 11 x 11 Gaussian window with sigma 1.5 (as a
/// separable filter), `K1 = 0.01`, `K2 = 0.03`, `L = 1`. At the image's border the window is
/// cut to the image and renormalised, so every pixel has a value (Wang et al. drop a 5-pixel
/// border instead; a mask may reach the edge). Accumulated in f64.
pub fn ssim_map(x: &[f64], y: &[f64], w: usize, h: usize) -> Vec<f64> {
    assert!(x.len() == w * h && y.len() == w * h, "ssim_map: {} and {} values for {w}x{h}", x.len(), y.len());
    let g = ssim_weights();
    // 1 / (sum of the weights inside [0, n)) at each position along an axis of n pixels.
    let norm = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let (lo, hi) = (i.saturating_sub(SSIM_RADIUS), (i + SSIM_RADIUS).min(n - 1));
                1.0 / (lo..=hi).map(|j| g[j + SSIM_RADIUS - i]).sum::<f64>()
            })
            .collect()
    };
    let (norm_x, norm_y) = (norm(w), norm(h));
    // Horizontal pass: the five window sums of each row.
    let mut rows = vec![[0.0f64; 5]; w * h];
    rows.par_chunks_mut(w.max(1)).enumerate().for_each(|(r, out)| {
        let (xr, yr) = (&x[r * w..(r + 1) * w], &y[r * w..(r + 1) * w]);
        for (i, o) in out.iter_mut().enumerate() {
            let (lo, hi) = (i.saturating_sub(SSIM_RADIUS), (i + SSIM_RADIUS).min(w - 1));
            let mut s = [0.0f64; 5];
            for j in lo..=hi {
                let (a, b, k) = (xr[j], yr[j], g[j + SSIM_RADIUS - i]);
                s[0] += k * a;
                s[1] += k * b;
                s[2] += k * a * a;
                s[3] += k * b * b;
                s[4] += k * a * b;
            }
            *o = s.map(|v| v * norm_x[i]);
        }
    });
    // Vertical pass, then SSIM of each pixel.
    let mut out = vec![0.0f64; w * h];
    out.par_chunks_mut(w.max(1)).enumerate().for_each(|(r, out)| {
        let (lo, hi) = (r.saturating_sub(SSIM_RADIUS), (r + SSIM_RADIUS).min(h - 1));
        let mut acc = vec![[0.0f64; 5]; w];
        for j in lo..=hi {
            let k = g[j + SSIM_RADIUS - r];
            for (a, s) in acc.iter_mut().zip(&rows[j * w..(j + 1) * w]) {
                for c in 0..5 {
                    a[c] += k * s[c];
                }
            }
        }
        for (o, a) in out.iter_mut().zip(&acc) {
            *o = ssim_of(a.map(|v| v * norm_y[r]));
        }
    });
    out
}

/// Per-pixel LDR FLIP error (Andersson et al. 2020, NVIDIA's C++ through the `nv-flip` crate)
/// of `a` against `b_reference`, in [0, 1], at [`FLIP_PIXELS_PER_DEGREE`]. Its input is the
/// report's 8-bit sRGB PNG pixels ([`HdrImage::to_srgb8`] at `exposure`): the crate takes
/// 8-bit images.
pub fn flip_map(a: &HdrImage, b_reference: &HdrImage, exposure: f32) -> Vec<f32> {
    let (w, h) = (a.width, a.height);
    let (ta, tb) = (a.to_srgb8(exposure), b_reference.to_srgb8(exposure));
    let reference = nv_flip::FlipImageRgb8::with_data(w, h, tb.as_raw());
    let test = nv_flip::FlipImageRgb8::with_data(w, h, ta.as_raw());
    nv_flip::flip(reference, test, FLIP_PIXELS_PER_DEGREE).to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;
    use biscale_core::testing::random_hdr_image;

    /// SSIM by its definition, the whole cut window summed at each pixel (f64).
    fn naive_ssim_map(x: &[f64], y: &[f64], w: usize, h: usize) -> Vec<f64> {
        let g = ssim_weights();
        let r = SSIM_RADIUS as i64;
        let mut out = vec![0.0; w * h];
        for py in 0..h as i64 {
            for px in 0..w as i64 {
                let (mut m, mut total) = ([0.0f64; 5], 0.0f64);
                for qy in (py - r).max(0)..=(py + r).min(h as i64 - 1) {
                    for qx in (px - r).max(0)..=(px + r).min(w as i64 - 1) {
                        let k = g[(qx - px + r) as usize] * g[(qy - py + r) as usize];
                        let i = qy as usize * w + qx as usize;
                        let (a, b) = (x[i], y[i]);
                        for (s, v) in m.iter_mut().zip([a, b, a * a, b * b, a * b]) {
                            *s += k * v;
                        }
                        total += k;
                    }
                }
                out[py as usize * w + px as usize] = ssim_of(m.map(|v| v / total));
            }
        }
        out
    }

    #[test]
    fn separable_ssim_matches_the_double_loop() {
        // Sizes below, at and above the window, odd and even. Both sum the same products in
        // f64 in another order (~1e-16 relative); the variances E[x^2] - mu^2 cancel at most a
        // factor ~10 on these images, so 1e-9 leaves orders of magnitude.
        for (w, h, seed) in [(1, 1, 1), (3, 7, 2), (11, 11, 3), (23, 17, 4), (40, 9, 5)] {
            let (a, b) = (random_hdr_image(w, h, seed), random_hdr_image(w, h, seed + 100));
            for c in 0..3 {
                let (x, y) = (channel(&a, c, 8.0), channel(&b, c, 8.0));
                let (fast, slow) =
                    (ssim_map(&x, &y, w as usize, h as usize), naive_ssim_map(&x, &y, w as usize, h as usize));
                for (i, (f, s)) in fast.iter().zip(&slow).enumerate() {
                    assert!((f - s).abs() <= 1e-9 * s.abs().max(1.0), "{w}x{h} pixel {i}: {f} vs {s}");
                }
                assert!(w * h == 1 || slow.iter().any(|s| s.abs() < 0.9), "{w}x{h}: the images should differ");
            }
        }
    }

    #[test]
    fn ssim_is_one_on_itself_and_the_closed_form_on_constants() {
        let a = random_hdr_image(19, 13, 7);
        let m = ldr_metrics(&a, &a, None, 6.0);
        // x = y: numerator and denominator are the same f64 expressions (2 (m m) = m m + m m).
        assert_eq!((m.ssim, m.ldr_psnr, m.flip), (1.0, f64::INFINITY, 0.0));
        // Constant images: the variances and covariance vanish, (2 sxy + C2) / (sxx + syy + C2)
        // is 1 up to rounding, and SSIM = (2 mx my + C1) / (mx^2 + my^2 + C1).
        let (w, h) = (17, 12);
        let (p, q) = ([0.2f32, 0.5, 0.9], [0.3f32, 0.1, 0.9]);
        let ia = HdrImage { width: w, height: h, pixels: vec![p; (w * h) as usize] };
        let ib = HdrImage { width: w, height: h, pixels: vec![q; (w * h) as usize] };
        let want: f64 = (0..3)
            .map(|c| {
                let (mx, my) = (tone_map(p[c], 0.0), tone_map(q[c], 0.0));
                (2.0 * mx * my + C1) / (mx * mx + my * my + C1)
            })
            .sum::<f64>()
            / 3.0;
        let got = ldr_metrics(&ia, &ib, None, 0.0).ssim;
        assert!((got - want).abs() <= 1e-12, "{got} vs {want}");
        // A mask averages only its pixels: equal there, different elsewhere far away.
        let mut mask = vec![false; (w * h) as usize];
        mask[0] = true;
        let mut ic = ia.clone();
        ic.pixels[(w * h - 1) as usize] = [5.0; 3];
        let m = ldr_metrics(&ic, &ia, Some(&mask), 0.0);
        assert_eq!((m.ssim, m.ldr_psnr), (1.0, f64::INFINITY), "the changed pixel is 16+ pixels away");
    }

    #[test]
    fn ldr_psnr_of_a_uniform_offset_is_the_closed_form() {
        // Values in sRGB's linear segment (v <= 0.0031308, tone map 12.92 v), dyadic so x and
        // x + c are exact in f32: every tone-mapped channel differs by 12.92 c 2^exposure.
        let (w, h, exposure) = (32u32, 16u32, 1.0f32);
        let c = 2f32.powi(-16);
        let pixels: Vec<[f32; 3]> =
            (0..w * h).map(|i| std::array::from_fn(|k| ((i * 3 + k as u32) % 1400) as f32 * 2f32.powi(-20))).collect();
        let b = HdrImage { width: w, height: h, pixels };
        let a = HdrImage { pixels: b.pixels.iter().map(|p| p.map(|x| x + c)).collect(), ..b.clone() };
        assert!(a.pixels.iter().flatten().all(|&x| 2.0 * x <= 0.003_130_8));
        let d = 12.92 * c as f64 * 2.0;
        let want = -20.0 * d.log10();
        let got = ldr_metrics(&a, &b, None, exposure).ldr_psnr;
        // Only the f64 rounding of 12.92 v (relative 1e-16 of values ~0.07 against a
        // difference of 4e-4): well under 1e-9 dB.
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        // Clamped values count as the PNG shows them: both above 1 after exposure, no error.
        let bright = HdrImage { width: 2, height: 1, pixels: vec![[3.0; 3]; 2] };
        let brighter = HdrImage { pixels: vec![[30.0; 3]; 2], ..bright.clone() };
        assert_eq!(ldr_metrics(&brighter, &bright, None, 0.0).ldr_psnr, f64::INFINITY);
    }

    #[test]
    fn tone_map_is_the_png_one_before_rounding() {
        let img = random_hdr_image(64, 8, 9);
        for exposure in [-0.5f32, 0.0, 3.0] {
            let png = img.to_srgb8(exposure);
            for (p, q) in img.pixels.iter().zip(png.pixels()) {
                for c in 0..3 {
                    let t = tone_map(p[c], exposure) * 255.0 + 0.5;
                    // f64 here, f32 in the PNG: a code value apart at most, at a rounding edge.
                    assert!((t.floor() - q.0[c] as f64).abs() <= 1.0, "{} -> {t} vs {}", p[c], q.0[c]);
                }
            }
        }
        assert_eq!((tone_map(f32::NAN, 0.0), tone_map(-1.0, 0.0), tone_map(f32::INFINITY, 0.0)), (0.0, 0.0, 1.0));
    }

    #[test]
    fn flip_grows_with_the_difference_and_takes_tiny_images() {
        let b = random_hdr_image(24, 16, 11);
        let scaled = |s: f32| HdrImage { pixels: b.pixels.iter().map(|p| p.map(|x| x * s)).collect(), ..b.clone() };
        let small = ldr_metrics(&scaled(1.05), &b, None, 4.0).flip;
        let large = ldr_metrics(&scaled(2.0), &b, None, 4.0).flip;
        assert!(0.0 < small && small < large && large <= 1.0, "{small} {large}");
        let one = HdrImage { width: 1, height: 1, pixels: vec![[0.5; 3]] };
        let other = HdrImage { pixels: vec![[0.0; 3]], ..one.clone() };
        let m = ldr_metrics(&other, &one, None, 0.0);
        assert!(m.flip > 0.0 && m.flip <= 1.0 && m.ssim < 1.0, "{m:?}");
    }
}
