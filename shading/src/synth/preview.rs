//! Contact sheets: a BTF patch under several light and view directions, for looking at.

use crate::error::{Result, ShadingError};
use biscale_core::scene::image::{linear_to_srgb, write_rgb8_png};
use biscale_core::scene::Btf;
use std::path::Path;

/// Tiles narrower than this are enlarged (nearest neighbour) by an integer factor.
const MIN_TILE: u32 = 32;

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
    let [w, h] = btf.spatial();
    let k = MIN_TILE.div_ceil(w.min(h)).max(1);
    let (tw, th) = (w * k, h * k);
    let (cols, rows) = (lights.len() as u32, views.len() as u32);
    let at = |texel: usize, view: usize, light: usize| btf.data()[(texel * v + view) * m + light];
    let mut peak = 0.0f32;
    for t in 0..btf.texel_count() {
        for &e in views {
            for &j in lights {
                peak = at(t, e, j).iter().copied().fold(peak, f32::max);
            }
        }
    }
    let scale = if peak > 0.0 { 1.0 / peak } else { 0.0 };
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
    Ok(img)
}

/// [`contact_sheet`] written as a PNG, atomically.
pub fn save_contact_sheet(btf: &Btf, lights: &[usize], views: &[usize], path: &Path) -> Result<()> {
    Ok(write_rgb8_png(&contact_sheet(btf, lights, views)?, path)?)
}
