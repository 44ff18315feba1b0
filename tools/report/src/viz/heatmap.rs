//! Per-vertex scalars on the rendered mesh: a heat map interpolated per pixel exactly as the
//! shader interpolates `L*`, with a colour bar; and the scalars of `T` itself.

use super::patch::MAX_SIDE;
use super::raster::{text, Canvas, BLACK_PX, TOP_LEFT, WHITE_PX};
use super::{invalid, Result};
use biscale_core::basis::LocalBasis;
use biscale_core::geometry::{vertex_frames, Mesh};
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_core::transfer::TransferMatrix;
use biscale_shading::cpu::primary_hit;
use biscale_shading::image::{viridis, NON_FINITE_COLOUR};
use plotters::style::text_anchor::{HPos, Pos, VPos};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Non-zeros of `T` per vertex (over its M rows): how much of the cubemap the vertex sees.
pub fn nnz_per_vertex(t: &TransferMatrix) -> Vec<f32> {
    let csr = t.csr();
    let m = t.local_dirs().max(1);
    let mut out = vec![0.0f32; t.vertices()];
    for (i, row) in csr.outer_iterator().enumerate() {
        if let Some(o) = out.get_mut(i / m) {
            *o += row.data().iter().filter(|&&v| v != 0.0).count() as f32;
        }
    }
    out
}

/// How a heat map is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatmapOptions {
    /// Colour scale `(lo, hi)`; `None`: the finite range of the values. Values outside clamp.
    pub range: Option<(f32, f32)>,
    /// Shape cue: colours are scaled by `1 - relief + relief |cos(view, normal)|`; 0 gives
    /// flat colours that match the colour bar exactly.
    pub relief: f32,
}

impl Default for HeatmapOptions {
    fn default() -> Self {
        Self { range: None, relief: 0.3 }
    }
}

/// Width of the colour-bar margin right of the render, and height of the title above it.
pub const COLOUR_BAR_WIDTH: u32 = 130;
pub const TITLE_HEIGHT: u32 = 32;

/// Size of [`write_vertex_heatmap`]'s picture for `camera`.
pub fn heatmap_size(camera: &Camera) -> (u32, u32) {
    (camera.width + COLOUR_BAR_WIDTH, camera.height + TITLE_HEIGHT)
}

/// `x` with enough decimals to tell apart values `span` apart (at most 3).
pub(super) fn fmt_in_span(x: f64, span: f64) -> String {
    let a = x.abs().max(span.abs());
    if !(1e-2..1e5).contains(&a) && x != 0.0 {
        return format!("{x:.3e}");
    }
    let decimals = if span > 0.0 { (2.0 - span.log10().floor()).clamp(0.0, 3.0) as usize } else { 3 };
    let t = format!("{x:.decimals$}");
    if t.contains('.') {
        t.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        t
    }
}

/// Render `mesh` with `camera` and colour each pixel whose centre ray hits it by the
/// per-vertex scalar `values` interpolated with the hit's barycentric weights
/// ([`primary_hit`]): `viridis((s - lo) / (hi - lo))` (`viridis(0.5)` when `hi = lo`),
/// non-finite in [`NON_FINITE_COLOUR`], background white. A title line names the scalar and its
/// range over the vertices; a colour bar with ticks sits on the right. The picture is
/// [`heatmap_size`]: the render at the top left below the title. Returns `path`.
pub fn write_vertex_heatmap(
    mesh: &Mesh,
    camera: &Camera,
    values: &[f32],
    name: &str,
    options: &HeatmapOptions,
    path: &Path,
) -> Result<PathBuf> {
    if values.len() != mesh.vertex_count() {
        return invalid(format!("{} values for {} vertices", values.len(), mesh.vertex_count()));
    }
    camera.validate()?;
    if camera.width > MAX_SIDE || camera.height > MAX_SIDE {
        return invalid(format!("camera image {}x{} exceeds {MAX_SIDE} pixels", camera.width, camera.height));
    }
    let (frames, _) = vertex_frames(mesh);
    // The shader's scene wants a BTF; only the geometry is used here.
    let btf = Btf::lambertian([1.0; 3], LocalBasis::bins(1)?)?;
    let scene = ShadeScene::new(mesh.clone(), frames, vec![Material::new(btf)], None)?;
    let finite = values.iter().copied().filter(|v| v.is_finite());
    let (vmin, vmax) = finite.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = match options.range {
        Some((lo, hi)) if lo.is_finite() && hi.is_finite() && lo <= hi => (lo, hi),
        Some(r) => return invalid(format!("colour range {r:?} is not finite and ordered")),
        None if vmin <= vmax => (vmin, vmax),
        None => (0.0, 1.0),
    };
    let relief = options.relief.clamp(0.0, 1.0);
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut pixels = vec![WHITE_PX; w * h];
    pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, px) in row.iter_mut().enumerate() {
            let (origin, dir) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
            let Some(hit) = primary_hit(&scene, origin, dir) else { continue };
            let s: f64 =
                hit.vertices.iter().zip(&hit.weights).map(|(&v, &wt)| wt as f64 * values[v as usize] as f64).sum();
            if !s.is_finite() {
                *px = NON_FINITE_COLOUR;
                continue;
            }
            let t = if hi > lo { ((s - lo as f64) / (hi - lo) as f64) as f32 } else { 0.5 };
            let c = viridis(t);
            let k = 1.0 - relief + relief * hit.view_local.z.abs().min(1.0);
            *px = c.map(|x| (x as f32 * k + 0.5) as u8);
        }
    });
    let (cw, ch) = heatmap_size(camera);
    let mut canvas = Canvas::new(cw, ch);
    for (i, p) in pixels.iter().enumerate() {
        let (x, y) = ((i % w) as u32, (i / w) as u32 + TITLE_HEIGHT);
        let o = (y as usize * cw as usize + x as usize) * 3;
        canvas.buf[o..o + 3].copy_from_slice(p);
    }
    // Colour bar: top = hi, bottom = lo.
    let (bx, by0, by1) = (camera.width + 18, TITLE_HEIGHT + 14, ch.saturating_sub(14).max(TITLE_HEIGHT + 16));
    for y in by0..by1 {
        let t = 1.0 - (y - by0) as f32 / (by1 - by0 - 1).max(1) as f32;
        canvas.rect(bx, y, 22, 1, viridis(t));
    }
    // Outline just outside the bar, and tick marks at `ticks` evenly spaced values.
    canvas.rect(bx - 1, by0 - 1, 24, 1, BLACK_PX);
    canvas.rect(bx - 1, by1, 24, 1, BLACK_PX);
    canvas.rect(bx - 1, by0 - 1, 1, by1 - by0 + 2, BLACK_PX);
    canvas.rect(bx + 22, by0 - 1, 1, by1 - by0 + 2, BLACK_PX);
    let ticks = 5;
    let tick_y = |i: u32| by1 - 1 - ((by1 - by0 - 1) as f64 * i as f64 / (ticks - 1) as f64).round() as u32;
    for i in 0..ticks {
        canvas.rect(bx + 23, tick_y(i), 5, 1, BLACK_PX);
    }
    let title = if vmin <= vmax {
        let span = (vmax - vmin) as f64;
        format!(
            "{name}: {} .. {} over {} vertices",
            fmt_in_span(vmin as f64, span),
            fmt_in_span(vmax as f64, span),
            values.len()
        )
    } else {
        format!("{name}: no finite values")
    };
    canvas.finish(path, |area| {
        text(area, &title, 8, 7, 16, TOP_LEFT)?;
        for i in 0..ticks {
            let v = lo as f64 + (hi - lo) as f64 * i as f64 / (ticks - 1) as f64;
            text(
                area,
                &fmt_in_span(v, (hi - lo) as f64),
                (bx + 31) as i32,
                tick_y(i) as i32,
                12,
                Pos::new(HPos::Left, VPos::Center),
            )?;
        }
        Ok(())
    })
}
