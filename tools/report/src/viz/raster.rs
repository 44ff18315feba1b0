//! The raster toolkit of the pictures: an RGB8 canvas drawn pixel-exactly, with text (and
//! plotters charts) on top through the bundled font, written atomically as a PNG; colour
//! helpers and number formatting for labels.

use super::{draw_err, Result, VizError};
use crate::plots::register_font;
use biscale_core::scene::image::write_rgb8_png;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

pub(super) const WHITE_PX: [u8; 3] = [255, 255, 255];
pub(super) const BLACK_PX: [u8; 3] = [0, 0, 0];

pub(super) fn hsv(h: f64, s: f64, v: f64) -> [u8; 3] {
    let h6 = h * 6.0;
    let i = h6.floor() as i32 % 6;
    let f = h6 - h6.floor();
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    let (r, g, b) = match i {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r, g, b].map(|x| (x * 255.0 + 0.5) as u8)
}

pub(super) fn mix(a: [u8; 3], b: [u8; 3], t: f32) -> [u8; 3] {
    std::array::from_fn(|c| (a[c] as f32 * (1.0 - t) + b[c] as f32 * t + 0.5) as u8)
}

/// An RGB8 canvas (row-major, 3 bytes per pixel, white).
pub(super) struct Canvas {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) buf: Vec<u8>,
}

impl Canvas {
    pub(super) fn new(width: u32, height: u32) -> Self {
        Self { width, height, buf: vec![255; width as usize * height as usize * 3] }
    }

    pub(super) fn rect(&mut self, x: u32, y: u32, w: u32, h: u32, c: [u8; 3]) {
        for yy in y..(y + h).min(self.height) {
            for xx in x..(x + w).min(self.width) {
                let i = (yy as usize * self.width as usize + xx as usize) * 3;
                self.buf[i..i + 3].copy_from_slice(&c);
            }
        }
    }

    /// Draw text and lines with plotters on top of the pixels, then write the PNG.
    pub(super) fn finish(
        mut self,
        path: &Path,
        draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
    ) -> Result<PathBuf> {
        register_font();
        {
            let root = BitMapBackend::with_buffer(&mut self.buf, (self.width, self.height)).into_drawing_area();
            draw(&root)?;
            root.present().map_err(draw_err)?;
        }
        let img = image::RgbImage::from_raw(self.width, self.height, self.buf)
            .ok_or_else(|| VizError::Draw("canvas size mismatch".into()))?;
        write_rgb8_png(&img, path)?;
        Ok(path.to_path_buf())
    }
}

pub(super) fn text(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    s: &str,
    x: i32,
    y: i32,
    size: u32,
    pos: Pos,
) -> Result<()> {
    let style = ("sans-serif", size).into_font().color(&BLACK).pos(pos);
    area.draw_text(s, &style, (x, y)).map_err(draw_err)
}

pub(super) const TOP_LEFT: Pos = Pos { h_pos: HPos::Left, v_pos: VPos::Top };

pub(super) fn fmt_value(x: f64) -> String {
    let a = x.abs();
    if x == 0.0 {
        "0".into()
    } else if !(1e-2..1e5).contains(&a) {
        format!("{x:.2e}")
    } else if (x - x.round()).abs() < 1e-9 {
        format!("{x:.0}")
    } else {
        let t = format!("{x:.3}");
        t.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}
