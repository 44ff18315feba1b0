//! The report's zoomed insets: one region of the render, chosen once per run (`[report]
//! inset`, else the window where the worst lossy setting differs most from the uncompressed
//! render), shown magnified beside every setting's image, and marked by a rectangle on each
//! image's thumbnail.

use biscale_core::scene::image::HdrImage;
use image::{Rgb, RgbImage};

/// A rectangle of pixels: `x`, `y` its top-left corner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Region {
    /// The same region on an image `factor` times smaller (a reference traced at
    /// `reference_downscale`): the size divided and rounded up, the corner rounded to the
    /// nearest pixel, moved in to fit `size`.
    pub fn shrunk(&self, factor: u32, size: (u32, u32)) -> Region {
        let f = factor.max(1);
        let (width, height) = (self.width.div_ceil(f).clamp(1, size.0), self.height.div_ceil(f).clamp(1, size.1));
        let x = ((self.x + f / 2) / f).min(size.0 - width);
        let y = ((self.y + f / 2) / f).min(size.1 - height);
        Region { x, y, width, height }
    }
}

/// The side of the default inset window: an eighth of the image's shorter side, at least 8
/// and at most 64 pixels (never more than the image).
pub fn default_side(width: u32, height: u32) -> u32 {
    (width.min(height) / 8).clamp(8, 64).min(width.min(height)).max(1)
}

/// The magnification of an inset of `region`: the integer factor that brings its longer
/// side nearest to 256 pixels without passing it (at least 1).
pub fn magnification(region: &Region) -> u32 {
    (256 / region.width.max(region.height).max(1)).max(1)
}

/// The integer factor that magnifies an image `width` pixels wide to at least 300 (the colour
/// bar's width), so every figure of a row shows its picture at one size: 1 for wider images.
pub fn thumbnail_factor(width: u32) -> u32 {
    300u32.div_ceil(width.max(1)).max(1)
}

/// One row's pictures from the PNG `png` of `out_dir` (relative path): its thumbnail with
/// `region` marked, magnified by [`thumbnail_factor`], and its inset magnified by
/// [`magnification`], written as `images/<name>_thumb.png` and `images/<name>_inset.png`
/// (their relative paths are returned). `region` is in pixels of the render, `render_width`
/// wide; an image a whole factor narrower (a reference traced at a downscale) gets the region
/// scaled down and its inset magnified that much more, so every inset has one size.
pub fn write_row(
    out_dir: &std::path::Path,
    png: &str,
    name: &str,
    region: &Region,
    render_width: u32,
) -> Result<(String, String), String> {
    let img = image::open(out_dir.join(png)).map_err(|e| format!("{png}: {e}"))?.to_rgb8();
    let down = (render_width / img.width().max(1)).max(1);
    let r = region.shrunk(down, img.dimensions());
    let stem = name.replace(':', "-");
    let (thumb, zoom) = (format!("images/{stem}_thumb.png"), format!("images/{stem}_inset.png"));
    let write = |picture: &RgbImage, rel: &str| {
        biscale_core::scene::image::write_rgb8_png(picture, &out_dir.join(rel)).map_err(|e| format!("{rel}: {e}"))
    };
    write(&marked(&img, &r, thumbnail_factor(img.width())), &thumb)?;
    write(&inset(&img, &r, magnification(region) * down), &zoom)?;
    Ok((thumb, zoom))
}

/// The per-pixel difference of `a` and `b` as their PNGs show it, row-major: the sum over R,
/// G and B of `|a - b|` after the PNGs' tone map at `exposure` (`HdrImage::to_srgb8`), so a
/// highlight clipped to white in both counts for nothing however far apart its radiances are.
pub fn error_map(a: &HdrImage, b: &HdrImage, exposure: f32) -> Vec<f32> {
    let (a, b) = (a.to_srgb8(exposure), b.to_srgb8(exposure));
    (a.pixels().zip(b.pixels())).map(|(p, q)| (0..3).map(|c| p.0[c].abs_diff(q.0[c]) as f32).sum()).collect()
}

/// The top-left corner of the `w x h` window of `values` (row-major, `width x height`) with
/// the largest sum, by a summed-area table; the first (top-most, then left-most) of equal
/// ones. A window larger than the image is clamped to it.
pub fn largest_sum_window(values: &[f32], width: u32, height: u32, w: u32, h: u32) -> (u32, u32) {
    let (width, height) = (width as usize, height as usize);
    assert_eq!(values.len(), width * height, "values must be width x height");
    let (w, h) = ((w as usize).clamp(1, width.max(1)), (h as usize).clamp(1, height.max(1)));
    // sat[(y) * (width + 1) + x]: the sum over rows < y, columns < x (f64: long sums).
    let stride = width + 1;
    let mut sat = vec![0.0f64; stride * (height + 1)];
    for y in 0..height {
        let mut row = 0.0;
        for x in 0..width {
            row += values[y * width + x] as f64;
            sat[(y + 1) * stride + x + 1] = sat[y * stride + x + 1] + row;
        }
    }
    let mut best = (f64::NEG_INFINITY, 0, 0);
    for y in 0..=height.saturating_sub(h) {
        for x in 0..=width.saturating_sub(w) {
            let s = sat[(y + h) * stride + x + w] - sat[y * stride + x + w] - sat[(y + h) * stride + x]
                + sat[y * stride + x];
            if s > best.0 {
                best = (s, x, y);
            }
        }
    }
    (best.1 as u32, best.2 as u32)
}

/// `region` of `img`, magnified `factor` times by nearest neighbour (every pixel a
/// `factor x factor` block).
pub fn inset(img: &RgbImage, region: &Region, factor: u32) -> RgbImage {
    let crop = image::imageops::crop_imm(img, region.x, region.y, region.width, region.height).to_image();
    magnify(&crop, factor)
}

/// `img` magnified `factor` times by nearest neighbour.
pub fn magnify(img: &RgbImage, factor: u32) -> RgbImage {
    let f = factor.max(1);
    RgbImage::from_fn(img.width() * f, img.height() * f, |x, y| *img.get_pixel(x / f, y / f))
}

/// The colour of the rectangle that marks the inset region on a thumbnail.
pub const MARK: Rgb<u8> = Rgb([255, 40, 40]);

/// `img` magnified `factor` times (nearest) with `region` (in `img`'s pixels) outlined by a
/// two-pixel [`MARK`] rectangle just outside it (inside where it meets the image's edge).
pub fn marked(img: &RgbImage, region: &Region, factor: u32) -> RgbImage {
    let mut out = magnify(img, factor);
    let f = factor.max(1) as i64;
    let (w, h) = (out.width() as i64, out.height() as i64);
    let (x0, y0) = (region.x as i64 * f, region.y as i64 * f);
    let (x1, y1) = ((region.x + region.width) as i64 * f - 1, (region.y + region.height) as i64 * f - 1);
    // Two pixels outside the region, moved in where that leaves the image.
    let (l, t) = ((x0 - 2).max(0), (y0 - 2).max(0));
    let (r, b) = ((x1 + 2).min(w - 1), (y1 + 2).min(h - 1));
    let mut put = |x: i64, y: i64| {
        if (0..w).contains(&x) && (0..h).contains(&y) {
            out.put_pixel(x as u32, y as u32, MARK);
        }
    };
    for x in l..=r {
        for d in 0..2 {
            put(x, t + d);
            put(x, b - d);
        }
    }
    for y in t..=b {
        for d in 0..2 {
            put(l + d, y);
            put(r - d, y);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_error_window_is_found_around_a_known_hot_spot() {
        // A 200 x 120 error image: low noise everywhere, a 10 x 10 hot spot at (150, 30), and a
        // single brighter pixel elsewhere that a sum over a window must not prefer.
        let (w, h) = (200u32, 120u32);
        let mut e: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 13) as f32 * 1e-3).collect();
        for y in 30..40 {
            for x in 150..160 {
                e[(y * w + x) as usize] = 1.0;
            }
        }
        e[(100 * w + 20) as usize] = 20.0;
        let side = default_side(w, h);
        assert_eq!(side, 15);
        let (x, y) = largest_sum_window(&e, w, h, side, side);
        // The window holds the whole spot.
        assert!(x <= 150 && x + side >= 160 && y <= 30 && y + side >= 40, "({x}, {y})");
        // A window as large as the image sits at the origin; a zero image gives the first.
        assert_eq!(largest_sum_window(&e, w, h, 500, 500), (0, 0));
        assert_eq!(largest_sum_window(&[0.0; 12], 4, 3, 2, 2), (0, 0));
        // Exact on a small case: the 2 x 2 window with the largest sum.
        let v = [0.0, 1.0, 0.0, 0.0, 0.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(largest_sum_window(&v, 4, 3, 2, 2), (1, 0));
    }

    #[test]
    fn an_inset_is_the_region_magnified_and_the_thumbnail_marks_it() {
        let img = RgbImage::from_fn(40, 30, |x, y| Rgb([x as u8, y as u8, 7]));
        let region = Region { x: 10, y: 5, width: 8, height: 6 };
        assert_eq!(magnification(&region), 32);
        let zoom = inset(&img, &region, 4);
        assert_eq!(zoom.dimensions(), (32, 24));
        assert_eq!(zoom.get_pixel(0, 0).0, [10, 5, 7]);
        assert_eq!(zoom.get_pixel(3, 3).0, [10, 5, 7]);
        assert_eq!(zoom.get_pixel(4, 0).0, [11, 5, 7]);
        assert_eq!(zoom.get_pixel(31, 23).0, [17, 10, 7]);
        // The thumbnail, twice as large: the rectangle lies just outside the region.
        let thumb = marked(&img, &region, 2);
        assert_eq!(thumb.dimensions(), (80, 60));
        assert_eq!(*thumb.get_pixel(18, 8), MARK);
        assert_eq!(*thumb.get_pixel(19, 20), MARK);
        assert_eq!(*thumb.get_pixel(36, 22), MARK); // right edge: x = 18 * 2 - 1 + 2
        assert_eq!(thumb.get_pixel(20, 10).0, [10, 5, 7], "inside the region untouched");
        assert_eq!(thumb.get_pixel(0, 0).0, [0, 0, 7], "outside untouched");
        // A region at the image's corner is marked inside the image.
        let corner = marked(&img, &Region { x: 0, y: 0, width: 4, height: 4 }, 1);
        assert_eq!(*corner.get_pixel(0, 0), MARK);
        // On a reference half the size, the region rounds outwards.
        assert_eq!(region.shrunk(2, (20, 15)), Region { x: 5, y: 3, width: 4, height: 3 });
        assert_eq!(region.shrunk(1, (40, 30)), region);
        // At the edge it moves in; its size never changes.
        let edge = Region { x: 33, y: 25, width: 7, height: 5 };
        assert_eq!(edge.shrunk(2, (20, 15)), Region { x: 16, y: 12, width: 4, height: 3 });
    }

    #[test]
    fn the_error_map_is_the_difference_the_pngs_show() {
        let image = |pixels: Vec<[f32; 3]>| HdrImage { width: 3, height: 1, pixels };
        let a = image(vec![[0.5, 0.5, 0.5], [10.0, 10.0, 10.0], [f32::NAN, 0.0, 0.0]]);
        let b = image(vec![[0.25, 0.5, 0.5], [50.0, 50.0, 50.0], [0.0, 0.0, 0.0]]);
        let e = error_map(&a, &b, 0.0);
        // A visible difference in red; two highlights clipped to white alike; NaN shows black.
        assert!(e[0] > 40.0 && e[1] == 0.0 && e[2] == 0.0, "{e:?}");
    }

    #[test]
    fn the_default_window_is_an_eighth_of_the_shorter_side_within_8_and_64() {
        assert_eq!(default_side(640, 480), 60);
        assert_eq!(default_side(96, 72), 9);
        assert_eq!(default_side(4096, 2048), 64);
        assert_eq!(default_side(20, 10), 8);
        assert_eq!(default_side(5, 5), 5);
    }
}
