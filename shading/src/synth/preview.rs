//! Contact sheets: a BTF patch under several light and view directions, for looking at; and a
//! dense BTF next to its compressed form and their difference.

use crate::error::{Result, ShadingError};
use biscale_core::scene::image::{linear_to_srgb, write_rgb8_png};
use biscale_core::scene::Btf;
use biscale_core::Rgb;
use std::path::Path;

/// Tiles narrower than this are enlarged (nearest neighbour) by an integer factor.
const MIN_TILE: u32 = 32;

/// The white gap in pixels between the three sheets of a [`comparison_sheet`].
pub const COMPARISON_GAP: u32 = 8;

/// A grid of tiles: row `r` shows view sample `views[r]`, column `c` light bin `lights[c]`;
/// each tile is the patch's texels (texel row 0 at the tile's top), enlarged by an integer
/// factor to at least 32 pixels, with 1-pixel black gaps between tiles. Values are scaled so
/// the largest value shown is white, then sRGB-encoded. A view-independent BTF has one view,
/// index 0. Errors: empty lists, indices out of range.
pub fn contact_sheet(btf: &Btf, lights: &[usize], views: &[usize]) -> Result<image::RgbImage> {
    let (m, v) = (btf.light_count(), btf.view_count());
    if lights.is_empty() || views.is_empty() {
        return Err(ShadingError::Invalid("contact sheet: no lights or no views given".into()));
    }
    if let Some(j) = lights.iter().find(|&&j| j >= m) {
        return Err(ShadingError::Invalid(format!(
            "contact sheet: light {j} out of range (BTF '{}' has {m})",
            btf.name()
        )));
    }
    if let Some(e) = views.iter().find(|&&e| e >= v) {
        return Err(ShadingError::Invalid(format!(
            "contact sheet: view {e} out of range (BTF '{}' has {v})",
            btf.name()
        )));
    }
    let at = |texel: usize, view: usize, light: usize| btf.data()[(texel * v + view) * m + light];
    Ok(sheet(btf.spatial(), lights, views, 1.0 / peak(btf, lights, views, &at).max(f32::MIN_POSITIVE), &at))
}

/// The largest value `at` gives over every texel of the shown lights and views.
fn peak(btf: &Btf, lights: &[usize], views: &[usize], at: &dyn Fn(usize, usize, usize) -> Rgb) -> f32 {
    let mut peak = 0.0f32;
    for t in 0..btf.texel_count() {
        for &e in views {
            for &j in lights {
                peak = at(t, e, j).iter().copied().fold(peak, f32::max);
            }
        }
    }
    peak
}

/// The tiles of [`contact_sheet`] for any value function `at(texel, view, light)`, scaled by
/// `scale` before sRGB encoding.
fn sheet(
    spatial: [u32; 2],
    lights: &[usize],
    views: &[usize],
    scale: f32,
    at: &dyn Fn(usize, usize, usize) -> Rgb,
) -> image::RgbImage {
    let [w, h] = spatial;
    let k = MIN_TILE.div_ceil(w.min(h)).max(1);
    let (tw, th) = (w * k, h * k);
    let (cols, rows) = (lights.len() as u32, views.len() as u32);
    let mut img = image::RgbImage::new(cols * tw + cols - 1, rows * th + rows - 1);
    for (r, &e) in views.iter().enumerate() {
        for (c, &j) in lights.iter().enumerate() {
            let (x0, y0) = (c as u32 * (tw + 1), r as u32 * (th + 1));
            for y in 0..th {
                for x in 0..tw {
                    let texel = ((y / k) * w + x / k) as usize;
                    let p = at(texel, e, j).map(|c| (linear_to_srgb((c * scale).clamp(0.0, 1.0)) * 255.0 + 0.5) as u8);
                    img.put_pixel(x0 + x, y0 + y, image::Rgb(p));
                }
            }
        }
    }
    img
}

/// A dense BTF next to its compressed form and their difference, as three contact sheets side
/// by side (8-pixel gaps): `dense` and `compressed` on the dense table's scale (its largest
/// shown value is white), then `|dense - compressed|` on its own scale. Returns the image and
/// the error panel's gain over the others (its white is `1 / gain` of the dense white).
/// Errors as [`contact_sheet`], and when the two tables have different shapes.
pub fn comparison_sheet(
    dense: &Btf,
    compressed: &Btf,
    lights: &[usize],
    views: &[usize],
) -> Result<(image::RgbImage, f32)> {
    let shape = |b: &Btf| (b.spatial(), b.local_basis(), b.view_grid());
    if shape(dense) != shape(compressed) {
        return Err(ShadingError::Invalid(format!(
            "comparison sheet: '{}' and '{}' have different shapes",
            dense.name(),
            compressed.name()
        )));
    }
    let left = contact_sheet(dense, lights, views)?;
    let (m, v) = (dense.light_count(), dense.view_count());
    let a = |b: &Btf, texel: usize, view: usize, light: usize| b.data()[(texel * v + view) * m + light];
    let d = |t, e, j| a(dense, t, e, j);
    let c = |t, e, j| a(compressed, t, e, j);
    let err = |t, e, j| {
        let (x, y): (Rgb, Rgb) = (d(t, e, j), c(t, e, j));
        [(x[0] - y[0]).abs(), (x[1] - y[1]).abs(), (x[2] - y[2]).abs()]
    };
    let dense_peak = peak(dense, lights, views, &d).max(f32::MIN_POSITIVE);
    let err_peak = peak(dense, lights, views, &err).max(f32::MIN_POSITIVE);
    let middle = sheet(dense.spatial(), lights, views, 1.0 / dense_peak, &c);
    let right = sheet(dense.spatial(), lights, views, 1.0 / err_peak, &err);
    let (w, h) = (left.width(), left.height());
    let mut img = image::RgbImage::from_pixel(3 * w + 2 * COMPARISON_GAP, h, image::Rgb([255, 255, 255]));
    for (i, panel) in [left, middle, right].iter().enumerate() {
        image::imageops::replace(&mut img, panel, (i as u32 * (w + COMPARISON_GAP)) as i64, 0);
    }
    Ok((img, dense_peak / err_peak))
}

/// [`contact_sheet`] written as a PNG, atomically.
pub fn save_contact_sheet(btf: &Btf, lights: &[usize], views: &[usize], path: &Path) -> Result<()> {
    Ok(write_rgb8_png(&contact_sheet(btf, lights, views)?, path)?)
}
