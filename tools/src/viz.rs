//! Matrix-structure pictures (issue 3): what `T` and its biclusters look like.
//!
//! * [`write_sparsity`]: the sparsity pattern of `T` for a patch of consecutive vertices (as in
//!   Sun et al., Figure 3b), one small square per entry, grey by value (1/4 light .. 1 black),
//!   white for zero.
//! * [`write_bicluster_patch`]: the same patch with every entry covered by a bicluster in that
//!   bicluster's colour (hue fixed by its id), overlaps through residuals marked.
//! * [`write_bicluster_size_histograms`], [`write_value_histograms`]: bar charts (log counts)
//!   of the bicluster sizes r and l, of the values of `T` and of the biclusters' column
//!   constants (residual codes included).
//! * [`write_vertex_heatmap`]: a per-vertex scalar on the rendered mesh, interpolated
//!   barycentrically per pixel exactly as the shader interpolates `L*`
//!   ([`biscale_shading::cpu::primary_hit`]), viridis with a colour bar; scalars:
//!   [`gather_cost_per_vertex`], [`nnz_per_vertex`], or any `&[f32]`.
//!
//! # Patch layouts
//!
//! A patch of 4-16 vertices has `count * M` rows (256-1024 at M = 64) against N = 6144
//! columns, and one vertex's visible hemisphere touches about half of them, so compacting the
//! touched columns hardly shrinks the matrix: a literal matrix picture is a strip several
//! thousand pixels wide in which each row is a few short runs of dots. Two layouts:
//!
//! * [`PatchLayout::CubemapPanels`] (the default, the most legible): each transfer entry
//!   `T_p[j, k]` is non-zero only for the one bin `j` that contains `d_k` (DESIGN.md section 3),
//!   so a vertex's M rows never share a column and fold without loss onto the cubemap: one
//!   strip per vertex of six R x R face panels (+X, -X, +Y, -Y, +Z, -Z, texel row 0 at the top,
//!   column 0 at the left), cell `(p, k)` showing entry `(p M + j(k), k)`. The visible
//!   hemisphere appears as a lit region, occluders as holes, the M local bins as thin blue
//!   boundaries (sparsity picture), and a bicluster, whose rows are the same bin `j` of
//!   neighbouring vertices, as the same coloured patch of texels repeated down the strips.
//!   (A synthetic `T` whose rows do share columns shows the largest value of a cell.)
//! * [`PatchLayout::Matrix`]: the literal matrix, rows `p M + j` top to bottom (vertex groups
//!   separated by grey lines), columns in texel order left to right, optionally compacted to
//!   the columns the patch touches; cubemap face boundaries are blue vertical lines. Each row
//!   is a few short runs (one per texel row its bin crosses), so on a real `T` this is a strip
//!   thousands of pixels wide (bunny, 4 vertices compacted at 2 px: 8888 x 610) to be zoomed
//!   into; it reads directly for small synthetic matrices.
//!
//! Pixel geometry (both layouts; the tests rely on it): the image is
//! `max(MIN_WIDTH, LEFT + content + RIGHT)` x `HEADER + content + FOOTER` pixels, each entry a
//! `cell x cell` square.
//! Panels: entry `(p, k)` with `k = (face, row, col)` has its top-left pixel at
//! `x = LEFT + face (R cell + GAP) + col cell`, `y = HEADER + p (R cell + GAP) + row cell`.
//! Matrix: row `i = p M + j` (local to the patch) at `y = HEADER + i cell + p LINE`; the
//! `c`-th shown column at `x = LEFT + c cell + f LINE`, `f` the number of face boundaries to
//! its left.
//!
//! Every file is written atomically ([`biscale_shading::image::write_rgb8_png`]); text uses the
//! bundled DejaVu Sans ([`crate::plots`]).

use crate::plots::register_font;
use biscale_compressors::bicluster::{BiclusterView, Distribution};
use biscale_core::basis::LocalBasis;
use biscale_core::compress::{CompressError, CompressedForm};
use biscale_core::geometry::{vertex_frames, Mesh};
use biscale_core::scene::image::write_rgb8_png;
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_core::transfer::TransferMatrix;
use biscale_shading::cpu::primary_hit;
use biscale_shading::image::{viridis, NON_FINITE_COLOUR};
use biscale_shading::ShadingError;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use rayon::prelude::*;
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// Errors of the pictures (bad input, a form that does not match `T`, drawing or writing).
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    #[error("viz: {0}")]
    Invalid(String),
    #[error("viz: {0}")]
    Form(#[from] CompressError),
    #[error("viz: {0}")]
    Image(#[from] ShadingError),
    #[error("viz: {0}")]
    Core(#[from] biscale_core::CoreError),
    #[error("viz: drawing failed: {0}")]
    Draw(String),
}

type Result<T> = std::result::Result<T, VizError>;

fn invalid<T>(m: impl Into<String>) -> Result<T> {
    Err(VizError::Invalid(m.into()))
}

fn draw_err<E: std::fmt::Display>(e: E) -> VizError {
    VizError::Draw(e.to_string())
}

// ---------------------------------------------------------------------------------------------
// Patch pictures
// ---------------------------------------------------------------------------------------------

/// Left margin (vertex labels), pixels.
pub const LEFT: u32 = 72;
/// Right margin, pixels.
pub const RIGHT: u32 = 8;
/// Header (title line and face labels), pixels.
pub const HEADER: u32 = 44;
/// Footer (legend), pixels.
pub const FOOTER: u32 = 48;
/// Smallest image width, so the title and legend fit.
pub const MIN_WIDTH: u32 = 640;
/// Gap between face panels and between vertex strips ([`PatchLayout::CubemapPanels`]).
pub const GAP: u32 = 6;
/// Width of a face boundary or vertex separator line ([`PatchLayout::Matrix`]).
pub const LINE: u32 = 2;
/// Largest picture side in pixels: beyond it, ask for fewer vertices or smaller cells.
pub const MAX_SIDE: u32 = 16384;

/// How a patch of `T` is laid out (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatchLayout {
    /// One strip of six R x R face panels per vertex, its M rows folded onto the cubemap.
    CubemapPanels,
    /// Rows against columns in texel order; `compact` keeps only the columns the patch's
    /// rows touch (non-zeros of `T`, and in the bicluster picture the biclusters' columns).
    Matrix { compact: bool },
}

/// Which rows of `T` a patch picture shows, and how.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PatchView {
    /// First vertex p of the patch (rows `p M ..`).
    pub first_vertex: usize,
    /// Number of consecutive vertices (4-16 read well).
    pub vertices: usize,
    pub layout: PatchLayout,
    /// Side of one entry's square in pixels, 1..=64. Overlap marks and bin boundaries need
    /// at least 3.
    pub cell: u32,
}

impl PatchView {
    /// `vertices` vertices from `first_vertex`, cubemap panels, 4-pixel cells.
    pub fn new(first_vertex: usize, vertices: usize) -> Self {
        Self { first_vertex, vertices, layout: PatchLayout::CubemapPanels, cell: 4 }
    }
}

const WHITE_PX: [u8; 3] = [255, 255, 255];
const BLACK_PX: [u8; 3] = [0, 0, 0];
/// Face boundaries (matrix layout) and local-bin boundaries (panels).
const ACCENT: [u8; 3] = [70, 130, 220];
/// Panel frames and vertex separators.
const FRAME: [u8; 3] = [190, 190, 190];
const FACE_NAMES: [&str; 6] = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"];

/// Grey of a transfer value: `255 (1 - v)` for v in [0, 1] (1/4 -> 191, 1/2 -> 128,
/// 3/4 -> 64, 1 -> 0), white for 0; out-of-range values clamp.
pub fn value_grey(v: f32) -> [u8; 3] {
    let g = (255.0 * (1.0 - v.abs().clamp(0.0, 1.0)) + 0.5) as u8;
    [g; 3]
}

/// The colour of bicluster `id`: hues spread by the golden ratio (neighbouring ids get very
/// different hues), saturation and value varied a little so that ids whose hues come close
/// still differ; never white, grey or black, and the same id always gets the same colour.
pub fn bicluster_colour(id: usize) -> [u8; 3] {
    let h = (id as f64 * 0.618_033_988_749_895 + 0.05).fract();
    let s = 0.55 + 0.4 * ((id * 7 % 5) as f64 / 4.0);
    let v = 0.72 + 0.24 * ((id * 3 % 4) as f64 / 3.0);
    hsv(h, s, v)
}

fn hsv(h: f64, s: f64, v: f64) -> [u8; 3] {
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

fn mix(a: [u8; 3], b: [u8; 3], t: f32) -> [u8; 3] {
    std::array::from_fn(|c| (a[c] as f32 * (1.0 - t) + b[c] as f32 * t + 0.5) as u8)
}

/// Call `f(k, value)` for every stored entry of row `i` of a CSR matrix.
fn for_row(csr: &sprs::CsMat<f32>, i: usize, mut f: impl FnMut(usize, f32)) {
    if let Some(row) = csr.outer_view(i) {
        for (k, &v) in row.iter() {
            f(k, v);
        }
    }
}

/// CSR view of `T` (borrowed when it is already CSR).
fn csr_of(t: &TransferMatrix) -> Cow<'_, sprs::CsMat<f32>> {
    if t.csr().is_csr() {
        Cow::Borrowed(t.csr())
    } else {
        Cow::Owned(t.csr().to_csr())
    }
}

/// Check that `t` has the shape of a transfer matrix and that `view` lies inside it.
fn check_patch(t: &TransferMatrix, view: &PatchView) -> Result<()> {
    let (n, m) = (t.cols(), t.local_dirs());
    let r = t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution as usize;
    if m == 0 || t.rows() != t.vertices() * m || n != 6 * r * r {
        return invalid(format!(
            "T is {}x{} for {} vertices x {m} local directions and a {r}x{r} cubemap",
            t.rows(),
            n,
            t.vertices()
        ));
    }
    if view.vertices == 0 || view.first_vertex.checked_add(view.vertices).is_none_or(|e| e > t.vertices()) {
        return invalid(format!(
            "patch of {} vertices from {} is outside the {} vertices of T",
            view.vertices,
            view.first_vertex,
            t.vertices()
        ));
    }
    if !(1..=64).contains(&view.cell) {
        return invalid(format!("cell size must be 1..=64 pixels, got {}", view.cell));
    }
    Ok(())
}

/// The pixel geometry of one patch picture.
struct Grid {
    panels: bool,
    cell: u32,
    /// Cubemap resolution R, texels per face R^2, columns N, local directions M.
    r: usize,
    n: usize,
    m: usize,
    vertices: usize,
    /// Matrix layout: column k -> position among the shown columns (u32::MAX: not shown),
    /// and each shown column's x and face.
    col_pos: Vec<u32>,
    col_x: Vec<u32>,
    shown: Vec<u16>,
    width: u32,
    height: u32,
}

impl Grid {
    /// `touched[k]`: whether column k is touched by the patch (used by compact matrices).
    fn new(t: &TransferMatrix, view: &PatchView, touched: &[bool]) -> Result<Self> {
        check_patch(t, view)?;
        let (n, m, r) = (
            t.cols(),
            t.local_dirs(),
            t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution as usize,
        );
        let cell = view.cell as u64;
        let (content_w, content_h, col_pos, col_x, shown) = match view.layout {
            PatchLayout::CubemapPanels => {
                let side = r as u64 * cell;
                let w = 6 * side + 5 * GAP as u64;
                let h = view.vertices as u64 * side + (view.vertices as u64 - 1) * GAP as u64;
                (w, h, vec![], vec![], vec![])
            }
            PatchLayout::Matrix { compact } => {
                let shown: Vec<u16> = (0..n).filter(|&k| !compact || touched[k]).map(|k| k as u16).collect();
                let mut col_pos = vec![u32::MAX; n];
                let mut col_x = Vec::with_capacity(shown.len());
                let (mut x, mut prev_face) = (LEFT as u64, None);
                for (c, &k) in shown.iter().enumerate() {
                    let face = k as usize / (r * r);
                    if prev_face.is_some_and(|f| f != face) {
                        x += LINE as u64;
                    }
                    prev_face = Some(face);
                    col_pos[k as usize] = c as u32;
                    col_x.push(x.min(u32::MAX as u64) as u32);
                    x += cell;
                }
                let w = x - LEFT as u64;
                let rows = (view.vertices * m) as u64;
                let h = rows * cell + (view.vertices as u64 - 1) * LINE as u64;
                (w, h, col_pos, col_x, shown)
            }
        };
        let width = (LEFT as u64 + content_w + RIGHT as u64).max(MIN_WIDTH as u64);
        let height = HEADER as u64 + content_h + FOOTER as u64;
        if width > MAX_SIDE as u64 || height > MAX_SIDE as u64 {
            return invalid(format!(
                "picture would be {width}x{height} pixels (limit {MAX_SIDE}): show fewer vertices, smaller cells or compact columns"
            ));
        }
        Ok(Self {
            panels: view.layout == PatchLayout::CubemapPanels,
            cell: view.cell,
            r,
            n,
            m,
            vertices: view.vertices,
            col_pos,
            col_x,
            shown,
            width: width as u32,
            height: height as u32,
        })
    }

    /// Number of cells.
    fn cells(&self) -> usize {
        if self.panels {
            self.vertices * self.n
        } else {
            self.vertices * self.m * self.shown.len()
        }
    }

    /// Cell of entry (patch-local row `i`, column `k`), if shown.
    fn cell_of(&self, i: usize, k: usize) -> Option<usize> {
        if self.panels {
            Some((i / self.m) * self.n + k)
        } else {
            let c = self.col_pos[k];
            (c != u32::MAX).then(|| i * self.shown.len() + c as usize)
        }
    }

    /// Top-left pixel of a cell.
    fn origin(&self, cell: usize) -> (u32, u32) {
        if self.panels {
            let (p, k) = (cell / self.n, cell % self.n);
            let (face, row, col) = (k / (self.r * self.r), (k / self.r) % self.r, k % self.r);
            let side = self.r as u32 * self.cell;
            (
                LEFT + face as u32 * (side + GAP) + col as u32 * self.cell,
                HEADER + p as u32 * (side + GAP) + row as u32 * self.cell,
            )
        } else {
            let (i, c) = (cell / self.shown.len(), cell % self.shown.len());
            (self.col_x[c], HEADER + i as u32 * self.cell + (i / self.m) as u32 * LINE)
        }
    }

    /// Cell to the right / below within the same panel (panels only), for bin boundaries.
    fn neighbours(&self, cell: usize) -> [Option<usize>; 2] {
        let k = cell % self.n;
        let (row, col) = ((k / self.r) % self.r, k % self.r);
        [(col + 1 < self.r).then_some(cell + 1), (row + 1 < self.r).then_some(cell + self.r)]
    }

    /// Height in pixels of one vertex's strip or row group, and its top.
    fn vertex_band(&self, p: usize) -> (u32, u32) {
        if self.panels {
            let side = self.r as u32 * self.cell;
            (HEADER + p as u32 * (side + GAP), side)
        } else {
            let h = self.m as u32 * self.cell;
            (HEADER + p as u32 * (h + LINE), h)
        }
    }
}

/// An RGB8 canvas (row-major, 3 bytes per pixel, white).
struct Canvas {
    width: u32,
    height: u32,
    buf: Vec<u8>,
}

impl Canvas {
    fn new(width: u32, height: u32) -> Self {
        Self { width, height, buf: vec![255; width as usize * height as usize * 3] }
    }

    fn rect(&mut self, x: u32, y: u32, w: u32, h: u32, c: [u8; 3]) {
        for yy in y..(y + h).min(self.height) {
            for xx in x..(x + w).min(self.width) {
                let i = (yy as usize * self.width as usize + xx as usize) * 3;
                self.buf[i..i + 3].copy_from_slice(&c);
            }
        }
    }

    /// Draw text and lines with plotters on top of the pixels, then write the PNG.
    fn finish(
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

fn text(area: &DrawingArea<BitMapBackend<'_>, Shift>, s: &str, x: i32, y: i32, size: u32, pos: Pos) -> Result<()> {
    let style = ("sans-serif", size).into_font().color(&BLACK).pos(pos);
    area.draw_text(s, &style, (x, y)).map_err(draw_err)
}

const TOP_LEFT: Pos = Pos { h_pos: HPos::Left, v_pos: VPos::Top };

/// Panel frames (panels) or face boundaries and vertex separators (matrix), drawn pixel-exactly
/// into the gaps between cells, never over a cell.
fn draw_lines(canvas: &mut Canvas, g: &Grid) {
    if g.panels {
        let side = g.r as u32 * g.cell;
        for f in 0..6u32 {
            let x = LEFT + f * (side + GAP);
            for p in 0..g.vertices {
                let (y, h) = g.vertex_band(p);
                // A 1-pixel frame just outside the panel's cells.
                canvas.rect(x - 1, y - 1, side + 2, 1, FRAME);
                canvas.rect(x - 1, y + h, side + 2, 1, FRAME);
                canvas.rect(x - 1, y - 1, 1, h + 2, FRAME);
                canvas.rect(x + side, y - 1, 1, h + 2, FRAME);
            }
        }
    } else if !g.shown.is_empty() {
        let bottom = g.height - FOOTER;
        for c in 1..g.shown.len() {
            let face = |c: usize| g.shown[c] as usize / (g.r * g.r);
            if face(c) != face(c - 1) {
                canvas.rect(g.col_x[c - 1] + g.cell, HEADER, LINE, bottom - HEADER, ACCENT);
            }
        }
        let right = g.col_x[g.shown.len() - 1] + g.cell;
        for p in 1..g.vertices {
            let (y, _) = g.vertex_band(p);
            canvas.rect(LEFT, y - LINE, right - LEFT, LINE, FRAME);
        }
    }
}

/// Title, face labels and vertex labels shared by both patch pictures.
fn draw_labels(area: &DrawingArea<BitMapBackend<'_>, Shift>, g: &Grid, view: &PatchView, title: &str) -> Result<()> {
    text(area, title, 8, 6, 15, TOP_LEFT)?;
    let centred = Pos::new(HPos::Center, VPos::Top);
    if g.panels {
        let side = g.r as u32 * g.cell;
        for (f, name) in FACE_NAMES.iter().enumerate() {
            let x = LEFT + f as u32 * (side + GAP);
            text(area, name, (x + side / 2) as i32, 26, 13, centred)?;
        }
    } else if !g.shown.is_empty() {
        // Face names over each face's span of shown columns, where there is room.
        let face = |c: usize| g.shown[c] as usize / (g.r * g.r);
        let mut start = 0;
        for c in 1..=g.shown.len() {
            if c == g.shown.len() || face(c) != face(start) {
                let (x0, x1) = (g.col_x[start], g.col_x[c - 1] + g.cell);
                if x1 - x0 >= 16 {
                    text(area, FACE_NAMES[face(start)], ((x0 + x1) / 2) as i32, 26, 13, centred)?;
                }
                start = c;
            }
        }
    }
    for p in 0..g.vertices {
        let (y, h) = g.vertex_band(p);
        let label = format!("v {}", view.first_vertex + p);
        text(area, &label, (LEFT - 6) as i32, (y + h / 2) as i32, 12, Pos::new(HPos::Right, VPos::Center))?;
    }
    Ok(())
}

/// A legend line in the footer: swatches `(colour, centre dot, label)` drawn on `canvas`; returns
/// where each label goes, for [`legend_labels`].
fn legend_swatches(canvas: &mut Canvas, items: &[([u8; 3], bool, String)]) -> Vec<(i32, i32)> {
    let y = canvas.height - FOOTER + 8;
    let mut x = 8u32;
    let mut at = vec![];
    for (c, dot, label) in items {
        canvas.rect(x, y, 12, 12, [120; 3]);
        canvas.rect(x + 1, y + 1, 10, 10, *c);
        if *dot {
            canvas.rect(x + 4, y + 4, 4, 4, BLACK_PX);
        }
        at.push(((x + 17) as i32, y as i32));
        x += 17 + 7 * label.chars().count() as u32 + 16;
    }
    at
}

fn legend_labels(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    items: &[([u8; 3], bool, String)],
    at: &[(i32, i32)],
    note: &str,
) -> Result<()> {
    for ((_, _, label), &(x, y)) in items.iter().zip(at) {
        text(area, label, x, y, 12, TOP_LEFT)?;
    }
    let y = area.dim_in_pixel().1 as i32 - FOOTER as i32 + 26;
    text(area, note, 8, y, 12, TOP_LEFT)
}

/// Write the sparsity pattern of the rows of `view.vertices` vertices from
/// `view.first_vertex` (all their M local-direction rows) as a PNG at `path`: each entry a
/// `cell`-pixel square, grey by value ([`value_grey`]: 1/4 light grey .. 1 black), white for
/// zero; in the panel layout thin blue edges separate entries of different local bins j
/// (cells of 3 pixels and up). Returns `path`.
pub fn write_sparsity(t: &TransferMatrix, view: &PatchView, path: &Path) -> Result<PathBuf> {
    check_patch(t, view)?;
    let csr = csr_of(t);
    let m = t.local_dirs();
    let (row0, patch_rows) = (view.first_vertex * m, view.vertices * m);
    let mut touched = vec![false; t.cols()];
    for i in row0..row0 + patch_rows {
        for_row(&csr, i, |k, v| touched[k] |= v != 0.0);
    }
    let g = Grid::new(t, view, &touched)?;
    // Per cell: the largest |value| and the bin j that holds it (u32::MAX: empty).
    let mut value = vec![0.0f32; g.cells()];
    let mut bin = vec![u32::MAX; g.cells()];
    let (mut nnz, mut bad) = (0usize, None);
    for il in 0..patch_rows {
        for_row(&csr, row0 + il, |k, v| {
            if let (Some(c), true) = (g.cell_of(il, k), v != 0.0) {
                if !v.is_finite() {
                    bad = Some((row0 + il, k, v));
                }
                nnz += 1;
                if v.abs() > value[c].abs() {
                    value[c] = v;
                    bin[c] = (il % m) as u32;
                }
            }
        });
    }
    if let Some((i, k, v)) = bad {
        return invalid(format!("T[{i}, {k}] is {v}"));
    }
    let mut canvas = Canvas::new(g.width, g.height);
    for c in 0..g.cells() {
        if bin[c] != u32::MAX {
            let (x, y) = g.origin(c);
            canvas.rect(x, y, g.cell, g.cell, value_grey(value[c]));
        }
    }
    if g.panels && g.cell >= 3 {
        // Bin boundaries: the last pixel column (row) of a cell whose right (lower) neighbour
        // is non-zero in another bin.
        for c in 0..g.cells() {
            if bin[c] == u32::MAX {
                continue;
            }
            let (x, y) = g.origin(c);
            let [right, below] = g.neighbours(c);
            if right.is_some_and(|o| bin[o] != u32::MAX && bin[o] != bin[c]) {
                canvas.rect(x + g.cell - 1, y, 1, g.cell, ACCENT);
            }
            if below.is_some_and(|o| bin[o] != u32::MAX && bin[o] != bin[c]) {
                canvas.rect(x, y + g.cell - 1, g.cell, 1, ACCENT);
            }
        }
    }
    let title = format!(
        "T: vertices {}..{} ({} rows of M = {m} each) x N = {} columns; {nnz} non-zeros{}",
        view.first_vertex,
        view.first_vertex + view.vertices - 1,
        patch_rows,
        t.cols(),
        match view.layout {
            PatchLayout::CubemapPanels => ", rows folded onto the cubemap".to_string(),
            PatchLayout::Matrix { compact: true } => format!(", {} touched columns", g.shown.len()),
            PatchLayout::Matrix { compact: false } => String::new(),
        }
    );
    draw_lines(&mut canvas, &g);
    let items: Vec<([u8; 3], bool, String)> = [0.25f32, 0.5, 0.75, 1.0]
        .iter()
        .map(|&v| (value_grey(v), false, format!("{v}")))
        .chain([(WHITE_PX, false, "0".into())])
        .collect();
    let at = legend_swatches(&mut canvas, &items);
    let note = if g.panels {
        "grey = visibility fraction T[pM + j, k] at texel k; blue edges separate local bins j (the M rows)"
    } else {
        "grey = visibility fraction; blue lines = cubemap face boundaries; grey lines separate vertices"
    };
    canvas.finish(path, |area| {
        draw_labels(area, &g, view, &title)?;
        legend_labels(area, &items, &at, note)
    })
}

/// What the biclusters put on one entry of the patch.
#[derive(Clone, Copy, Default)]
struct Cover {
    /// Smallest covering bicluster id + 1 (0: none).
    first: u32,
    count: u32,
    code_sum: i32,
}

/// Write the patch of [`write_sparsity`] with the biclusters of `form` (a bicluster form of
/// `t`) coloured: an entry covered by a bicluster takes [`bicluster_colour`] of the smallest
/// covering id (the first emitted by the greedy build); entries covered by two or more
/// biclusters (residual overlaps) get a black centre dot; entries where `T` is 0 but
/// biclusters cover it (their residuals cancel) are drawn pale with the dot; white is 0 and
/// uncovered. Returns `path`.
///
/// Errors when the form is not a bicluster form of `t`: shape, or any entry of the patch whose
/// covering codes do not sum to `T`'s value.
pub fn write_bicluster_patch(
    t: &TransferMatrix,
    form: &CompressedForm,
    view: &PatchView,
    path: &Path,
) -> Result<PathBuf> {
    let bv = BiclusterView::new(form)?;
    if (bv.rows, bv.cols, form.local_dirs()) != (t.rows(), t.cols(), t.local_dirs()) {
        return invalid(format!(
            "the form is {}x{} with M = {}, T is {}x{} with M = {}",
            bv.rows,
            bv.cols,
            form.local_dirs(),
            t.rows(),
            t.cols(),
            t.local_dirs()
        ));
    }
    check_patch(t, view)?;
    let csr = csr_of(t);
    let m = t.local_dirs();
    let (row0, patch_rows) = (view.first_vertex * m, view.vertices * m);
    let q = bv.value_scale as f32;
    // Entries of every patch row: T's value and the biclusters' cover.
    let mut rows: Vec<Vec<(usize, f32, Cover)>> = Vec::with_capacity(patch_rows);
    let mut touched = vec![false; t.cols()];
    let mut acc = vec![(0.0f32, Cover::default()); t.cols()];
    let mut seen: Vec<usize> = vec![];
    let mut ids = std::collections::BTreeSet::new();
    for il in 0..patch_rows {
        let i = row0 + il;
        for_row(&csr, i, |k, v| {
            if v != 0.0 {
                if acc[k].0 == 0.0 && acc[k].1.count == 0 {
                    seen.push(k);
                }
                acc[k].0 = v;
            }
        });
        for b in bv.row_biclusters(i) {
            ids.insert(b);
            let (ks, codes) = bv.bicluster(b);
            for (&k, &code) in ks.iter().zip(codes) {
                let (k, e) = (k as usize, &mut acc[k as usize]);
                if e.0 == 0.0 && e.1.count == 0 {
                    seen.push(k);
                }
                let c = &mut e.1;
                c.first = if c.first == 0 { b as u32 + 1 } else { c.first.min(b as u32 + 1) };
                c.count += 1;
                c.code_sum += code as i32;
            }
        }
        let mut row = Vec::with_capacity(seen.len());
        for &k in &seen {
            let (v, c) = std::mem::take(&mut acc[k]);
            // Codes are exact integers and values code / q to f32 rounding (codes.rs).
            let sum = c.code_sum as f32 / q;
            // Written so that a NaN in T fails too.
            let agrees = (sum - v).abs() <= 1e-5 * v.abs().max(1.0);
            if !agrees {
                return invalid(format!("the biclusters sum to {sum} at T[{i}, {k}] = {v}: the form is not of this T"));
            }
            touched[k] = true;
            row.push((k, v, c));
        }
        seen.clear();
        rows.push(row);
    }
    let g = Grid::new(t, view, &touched)?;
    // Per cell: value (T), first cover of the visible entry, overlap flag.
    #[derive(Clone, Copy, Default)]
    struct CellState {
        value: f32,
        /// Smallest covering id + 1 of the entry where T is non-zero (the one the cell shows),
        /// and over all covered entries of the cell (0: none).
        first_nonzero: u32,
        first_any: u32,
        overlap: bool,
    }
    let mut cells = vec![CellState::default(); g.cells()];
    let (mut covered, mut overlaps, mut cancelled) = (0usize, 0usize, 0usize);
    for (il, row) in rows.iter().enumerate() {
        for &(k, v, c) in row {
            let Some(ci) = g.cell_of(il, k) else { continue };
            let cell = &mut cells[ci];
            covered += (c.count > 0) as usize;
            overlaps += (c.count > 1) as usize;
            cancelled += (v == 0.0 && c.count > 0) as usize;
            let min_id = |a: u32, b: u32| {
                if a == 0 {
                    b
                } else if b == 0 {
                    a
                } else {
                    a.min(b)
                }
            };
            if v != 0.0 {
                cell.first_nonzero = min_id(cell.first_nonzero, c.first);
            }
            cell.first_any = min_id(cell.first_any, c.first);
            cell.overlap |= c.count > 1;
            if v.abs() > cell.value.abs() {
                cell.value = v;
            }
        }
    }
    let mut canvas = Canvas::new(g.width, g.height);
    let dot = (g.cell / 3).max(1);
    for (ci, cell) in cells.iter().enumerate() {
        let first = if cell.first_nonzero != 0 { cell.first_nonzero } else { cell.first_any };
        if first == 0 {
            continue;
        }
        let (x, y) = g.origin(ci);
        let mut colour = bicluster_colour(first as usize - 1);
        if cell.value == 0.0 {
            colour = mix(colour, WHITE_PX, 0.65);
        }
        canvas.rect(x, y, g.cell, g.cell, colour);
        if cell.overlap && g.cell >= 3 {
            let off = (g.cell - dot) / 2;
            canvas.rect(x + off, y + off, dot, dot, BLACK_PX);
        }
    }
    let title = format!(
        "Biclusters on T: vertices {}..{} ({} rows), {} of the {} biclusters touch these rows",
        view.first_vertex,
        view.first_vertex + view.vertices - 1,
        patch_rows,
        ids.len(),
        bv.biclusters()
    );
    let note = format!(
        "{covered} covered entries; {overlaps} covered by 2+ biclusters (residuals), {cancelled} of them zero in T; colour = smallest covering id"
    );
    draw_lines(&mut canvas, &g);
    let sample = ids.iter().next().copied().unwrap_or(0);
    let items = vec![
        (bicluster_colour(sample), false, "bicluster (hue by id)".to_string()),
        (bicluster_colour(sample), true, "overlap: 2+ biclusters".to_string()),
        (mix(bicluster_colour(sample), WHITE_PX, 0.65), true, "T = 0, residuals cancel".to_string()),
        (WHITE_PX, false, "0, uncovered".to_string()),
    ];
    let at = legend_swatches(&mut canvas, &items);
    canvas.finish(path, |area| {
        draw_labels(area, &g, view, &title)?;
        legend_labels(area, &items, &at, &note)
    })
}

// ---------------------------------------------------------------------------------------------
// Histograms
// ---------------------------------------------------------------------------------------------

/// Size of the histogram pictures: two charts side by side.
pub const HISTOGRAM_SIZE: (u32, u32) = (1100, 460);

/// One bar: label under it, count, colour.
struct Bar {
    label: String,
    count: u64,
    colour: RGBColor,
}

/// A bar chart with a log count axis on `area`.
fn bar_chart(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    bars: &[Bar],
) -> Result<()> {
    if bars.is_empty() {
        let (w, h) = area.dim_in_pixel();
        return text(
            area,
            &format!("{title}: nothing to show"),
            w as i32 / 2,
            h as i32 / 2,
            16,
            Pos::new(HPos::Center, VPos::Center),
        );
    }
    let max = bars.iter().map(|b| b.count).max().unwrap_or(1).max(1) as f64;
    let nb = bars.len() as u32;
    // Bars start at 0.5 so that a count of 1 still shows on the log axis.
    let base = 0.5f64;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(58)
        .y_label_area_size(70)
        .build_cartesian_2d((0u32..nb - 1).into_segmented(), (base..max * 2.0).log_scale())
        .map_err(draw_err)?;
    // At most ~14 labels: every `step`-th bar.
    let step = (bars.len()).div_ceil(14);
    let labels: Vec<String> =
        bars.iter().enumerate().map(|(i, b)| if i % step == 0 { b.label.clone() } else { String::new() }).collect();
    let label_size = if nb > 8 { 11 } else { 13 };
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_labels(nb as usize)
        .x_label_style(("sans-serif", label_size))
        .y_label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .x_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => labels.get(*i as usize).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .y_label_formatter(&|v| if *v >= 1.0 { format!("{v:.0}") } else { String::new() })
        .draw()
        .map_err(draw_err)?;
    chart
        .draw_series(bars.iter().enumerate().filter(|(_, b)| b.count > 0).map(|(i, b)| {
            let (x0, x1) = (SegmentValue::Exact(i as u32), SegmentValue::Exact(i as u32 + 1));
            let mut r = Rectangle::new([(x0, base), (x1, b.count as f64)], b.colour.filled());
            r.set_margin(0, 0, 3, 3);
            r
        }))
        .map_err(draw_err)?;
    Ok(())
}

fn two_charts(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>, &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<PathBuf> {
    let (w, h) = HISTOGRAM_SIZE;
    Canvas::new(w, h).finish(path, |root| {
        let (left, right) = root.split_horizontally((w / 2) as i32);
        draw(&left, &right)
    })
}

fn log2_bars(values: &[u64], colour: RGBColor) -> Vec<Bar> {
    Distribution::of(values)
        .histogram
        .iter()
        .map(|&(lo, hi, count)| Bar {
            label: if lo == hi { format!("{lo}") } else { format!("{lo}-{hi}") },
            count,
            colour,
        })
        .collect()
}

/// Histograms of the bicluster sizes of `form`: rows r (left) and columns l (right) per
/// bicluster, power-of-two bins (1, 2-3, 4-7, ...), log-scaled counts; written as a PNG of
/// [`HISTOGRAM_SIZE`] at `path`. Returns `path`.
pub fn write_bicluster_size_histograms(form: &CompressedForm, path: &Path) -> Result<PathBuf> {
    let bv = BiclusterView::new(form)?;
    let r: Vec<u64> = bv.bicluster_rows().into_iter().map(u64::from).collect();
    let l: Vec<u64> = bv.bc_col_ptr.windows(2).map(|w| (w[1] - w[0]) as u64).collect();
    let (dr, dl) = (Distribution::of(&r), Distribution::of(&l));
    two_charts(path, |left, right| {
        bar_chart(
            left,
            &format!("rows r per bicluster ({} biclusters, mean {:.1}, max {})", r.len(), dr.mean, dr.max),
            "r (rows = vertices x local bins)",
            "biclusters",
            &log2_bars(&r, RGBColor(70, 130, 220)),
        )?;
        bar_chart(
            right,
            &format!("columns l per bicluster (mean {:.1}, max {})", dl.mean, dl.max),
            "l (cubemap texels)",
            "biclusters",
            &log2_bars(&l, RGBColor(230, 140, 40)),
        )
    })
}

/// Bars for the values `xs`: one per distinct value when there are at most 24 of them (the
/// reference `T` has four: 1/4, 1/2, 3/4, 1), else 24 equal-width bins.
fn value_bars(xs: &[f32], colour: RGBColor) -> Vec<Bar> {
    let mut s: Vec<f32> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f32::total_cmp);
    let mut distinct: Vec<(f32, u64)> = vec![];
    for &x in &s {
        match distinct.last_mut() {
            Some(d) if d.0 == x => d.1 += 1,
            _ => distinct.push((x, 1)),
        }
    }
    let fmt = |x: f32| {
        let t = format!("{x:.3}");
        let t = t.trim_end_matches('0').trim_end_matches('.');
        if t == "-0" {
            "0".to_string()
        } else {
            t.to_string()
        }
    };
    if distinct.len() <= 24 {
        return distinct.into_iter().map(|(x, count)| Bar { label: fmt(x), count, colour }).collect();
    }
    let (lo, hi) = (s[0], s[s.len() - 1]);
    let nb = 24usize;
    let width = (hi - lo) / nb as f32;
    let mut counts = vec![0u64; nb];
    for &x in &s {
        counts[(((x - lo) / width) as usize).min(nb - 1)] += 1;
    }
    counts
        .into_iter()
        .enumerate()
        .map(|(i, count)| {
            let centre = lo + (i as f32 + 0.5) * width;
            Bar { label: fmt(centre), count, colour }
        })
        .collect()
}

/// One bar per integer code from the smallest to the largest of `codes`, labelled `code / q`.
fn code_bars(codes: &[i8], q: u32) -> Vec<Bar> {
    let (lo, hi) = codes.iter().fold((i32::MAX, i32::MIN), |(a, b), &c| (a.min(c as i32), b.max(c as i32)));
    if lo > hi {
        return vec![];
    }
    let mut counts = vec![0u64; (hi - lo + 1) as usize];
    for &c in codes {
        counts[(c as i32 - lo) as usize] += 1;
    }
    counts
        .into_iter()
        .enumerate()
        .map(|(i, count)| {
            let code = lo + i as i32;
            let colour = if code < 0 { RGBColor(230, 120, 30) } else { RGBColor(70, 130, 220) };
            Bar { label: fmt_value(code as f64 / q as f64), count, colour }
        })
        .collect()
}

/// Histograms of the values of `T`'s non-zeros (left) and, with a bicluster `form`, of its
/// column constants `code / q` over all biclusters (right: one count per stored constant;
/// negative ones, in orange, are residual corrections of earlier biclusters); log-scaled
/// counts; a PNG of [`HISTOGRAM_SIZE`] at `path`. Returns `path`.
pub fn write_value_histograms(t: &TransferMatrix, form: Option<&CompressedForm>, path: &Path) -> Result<PathBuf> {
    let values: Vec<f32> = t.csr().data().iter().copied().filter(|&v| v != 0.0).collect();
    let consts = match form {
        Some(f) => {
            let bv = BiclusterView::new(f)?;
            Some((bv.bc_vals.to_vec(), bv.value_scale))
        }
        None => None,
    };
    two_charts(path, |left, right| {
        bar_chart(
            left,
            &format!("values of T ({} non-zeros)", values.len()),
            "visibility fraction",
            "entries",
            &value_bars(&values, RGBColor(110, 110, 110)),
        )?;
        match &consts {
            Some((c, q)) => bar_chart(
                right,
                &format!("bicluster column constants ({} stored, q = {q})", c.len()),
                "constant = code / q (negative: residual corrections)",
                "constants",
                &code_bars(c, *q),
            ),
            None => {
                let (w, h) = right.dim_in_pixel();
                text(
                    right,
                    "no bicluster form given",
                    w as i32 / 2,
                    h as i32 / 2,
                    16,
                    Pos::new(HPos::Center, VPos::Center),
                )
            }
        }
    })
}

// ---------------------------------------------------------------------------------------------
// Per-vertex scalars and heat maps
// ---------------------------------------------------------------------------------------------

/// Non-zeros of `T` per vertex (over its M rows): how much of the cubemap the vertex sees.
pub fn nnz_per_vertex(t: &TransferMatrix) -> Vec<f32> {
    let csr = csr_of(t);
    let m = t.local_dirs().max(1);
    let mut out = vec![0.0f32; t.vertices()];
    for (i, row) in csr.outer_iterator().enumerate() {
        if let Some(o) = out.get_mut(i / m) {
            *o += row.data().iter().filter(|&&v| v != 0.0).count() as f32;
        }
    }
    out
}

/// Gather flops per vertex under biclustering (Sun et al. section 4, `W(B) = r + 2l - 1`
/// split over vertices): for each of the vertex's M rows, its row-list length (one add per
/// bicluster), plus, for each bicluster, `(2 l - 1) x` (the fraction of its r rows that belong
/// to the vertex). Summed over all vertices this is `sum_b (r_b + 2 l_b - 1)`, the
/// `mflops_biclustered` of [`biscale_compressors::bicluster::table_stats`] (without the N
/// prescale flops). Accumulated in f64.
pub fn gather_cost_per_vertex(form: &CompressedForm) -> Result<Vec<f32>> {
    let bv = BiclusterView::new(form)?;
    // The form's rows are whole vertices of M rows (its shape is an invariant).
    let m = form.local_dirs();
    let r = bv.bicluster_rows();
    let share: Vec<f64> = bv
        .bc_col_ptr
        .windows(2)
        .zip(&r)
        .map(|(w, &r)| if r == 0 { 0.0 } else { (2.0 * (w[1] - w[0]) as f64 - 1.0) / r as f64 })
        .collect();
    let out = (0..bv.rows / m)
        .into_par_iter()
        .map(|v| {
            let mut acc = 0.0f64;
            for i in v * m..(v + 1) * m {
                for b in bv.row_biclusters(i) {
                    acc += 1.0 + share[b];
                }
            }
            acc as f32
        })
        .collect();
    Ok(out)
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
fn fmt_in_span(x: f64, span: f64) -> String {
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

fn fmt_value(x: f64) -> String {
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

/// The first vertex of the window of `count` consecutive vertices whose biclusters share the
/// most columns (the patch where biclustering's structure shows best).
pub fn most_shared_window(form: &CompressedForm, count: usize) -> Result<usize> {
    let bv = biscale_compressors::bicluster::BiclusterView::new(form)?;
    let m = form.local_dirs();
    let vertices = bv.rows / m;
    if count == 0 || count > vertices {
        return Err(VizError::Invalid(format!("{count} vertices asked, T has {vertices}")));
    }
    let per_vertex: Vec<Vec<usize>> = (0..vertices)
        .map(|v| {
            let mut ids: Vec<usize> = (v * m..(v + 1) * m).flat_map(|i| bv.row_biclusters(i)).collect();
            ids.sort_unstable();
            ids.dedup();
            ids
        })
        .collect();
    let l = |b: usize| (bv.bc_col_ptr[b + 1] - bv.bc_col_ptr[b]) as u64;
    let mut best = (0u64, 0usize);
    let mut seen = std::collections::HashMap::new();
    for s in 0..=vertices - count {
        seen.clear();
        for ids in &per_vertex[s..s + count] {
            for &b in ids {
                *seen.entry(b).or_insert(0u64) += 1;
            }
        }
        let score: u64 = seen.iter().map(|(&b, &n)| l(b) * (n - 1)).sum();
        if score > best.0 {
            best = (score, s);
        }
    }
    Ok(best.1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use biscale_compressors::bicluster::{table_stats, Bicluster};
    use biscale_compressors::testing::{self, random_transfer};
    use biscale_core::basis::TransferShape;
    use biscale_core::compress::{ArrayData, CompressContext, Compressor};
    use biscale_core::geometry::shapes;
    use glam::Vec3;
    use std::collections::BTreeMap;

    fn tmp() -> tempfile::TempDir {
        tempfile::tempdir().unwrap()
    }

    fn open(p: &Path) -> image::RgbImage {
        image::open(p).unwrap().into_rgb8()
    }

    /// `T` from explicit `(row, col, value)` entries: `vertices` of `m = g^2` rows each over
    /// the R x R cubemap.
    fn matrix(vertices: usize, m: usize, r: u32, entries: &[(usize, usize, f32)]) -> TransferMatrix {
        let light = testing::cubemap(r);
        let g = (1..=64).find(|g| g * g == m as u32).expect("m must be a square");
        let mut tri = sprs::TriMat::new((vertices * m, light.len()));
        for &(i, k, v) in entries {
            tri.add_triplet(i, k, v);
        }
        TransferMatrix::new(testing::bins(g), light, tri.to_csr()).unwrap()
    }

    fn value(t: &TransferMatrix, i: usize, k: usize) -> f32 {
        t.csr().get(i, k).copied().unwrap_or(0.0)
    }

    /// Expected top-left pixel of entry (patch row il, column k) in the uncompacted matrix
    /// layout, from the module docs' formula (written out independently of `Grid`).
    fn matrix_origin(t: &TransferMatrix, cell: u32, il: usize, k: usize) -> (u32, u32) {
        let r2 = (t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution
            * t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution) as usize;
        let faces_left = (k / r2) as u32;
        (LEFT + k as u32 * cell + faces_left * LINE, HEADER + il as u32 * cell + (il / t.local_dirs()) as u32 * LINE)
    }

    fn panel_origin(t: &TransferMatrix, cell: u32, p: usize, k: usize) -> (u32, u32) {
        let r = t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution as usize;
        let (face, row, col) = (k / (r * r), (k / r) % r, k % r);
        let side = r as u32 * cell;
        (LEFT + face as u32 * (side + GAP) + col as u32 * cell, HEADER + p as u32 * (side + GAP) + row as u32 * cell)
    }

    #[test]
    fn sparsity_matrix_shows_every_entry_of_a_random_t_where_it_belongs() {
        let t = random_transfer(5, 2, 4, 0.15, 7);
        let dir = tmp();
        let view = PatchView { first_vertex: 1, vertices: 3, layout: PatchLayout::Matrix { compact: false }, cell: 3 };
        let path = write_sparsity(&t, &view, &dir.path().join("s.png")).unwrap();
        let img = open(&path);
        // 96 columns, 6 faces: 5 boundary lines; 12 rows, 2 vertex separators.
        let w = (LEFT + 96 * 3 + 5 * LINE + RIGHT).max(MIN_WIDTH);
        assert_eq!(img.dimensions(), (w, HEADER + 12 * 3 + 2 * LINE + FOOTER));
        let mut nonzeros = 0;
        for il in 0..12 {
            for k in 0..96 {
                let v = value(&t, 4 + il, k);
                let (x, y) = matrix_origin(&t, 3, il, k);
                // Every pixel of the cell, not only its centre.
                for (dx, dy) in [(0, 0), (1, 1), (2, 2), (2, 0)] {
                    let got = img.get_pixel(x + dx, y + dy).0;
                    if v == 0.0 {
                        assert_eq!(got, WHITE_PX, "zero T[{}, {k}] is white", 4 + il);
                    } else {
                        // 255 (1 - v): 1/4 -> 191, 1/2 -> 128, 3/4 -> 64, 1 -> 0.
                        assert_eq!(
                            got,
                            [[191u8; 3], [128; 3], [64; 3], [0; 3]][(v * 4.0) as usize - 1],
                            "T[{}, {k}] = {v}",
                            4 + il
                        );
                    }
                }
                nonzeros += (v != 0.0) as usize;
            }
        }
        assert!(nonzeros > 100, "the random T has entries to check ({nonzeros})");
        // Face boundaries are accent lines between the faces, spanning the content.
        let (x, y) = matrix_origin(&t, 3, 0, 16);
        assert_eq!(img.get_pixel(x - 1, y).0, ACCENT);
    }

    #[test]
    fn compact_matrix_keeps_only_touched_columns_in_order() {
        // Vertex 0 (outside the patch) touches column 3, the patch columns 5 and 30 (faces 1, 7).
        // Vertex 1's rows are 4..8 (M = 4); its first two rows hold the entries.
        let t = matrix(2, 4, 2, &[(0, 3, 1.0), (4, 5, 0.5), (5, 20, 0.25)]);
        let dir = tmp();
        let view = PatchView { first_vertex: 1, vertices: 1, layout: PatchLayout::Matrix { compact: true }, cell: 5 };
        let img = open(&write_sparsity(&t, &view, &dir.path().join("c.png")).unwrap());
        assert_eq!(img.dimensions(), (MIN_WIDTH, HEADER + 4 * 5 + FOOTER));
        // Column 5 (face 1) first, column 20 (face 5) second after one boundary line.
        assert_eq!(img.get_pixel(LEFT + 2, HEADER + 2).0, [128; 3]);
        assert_eq!(img.get_pixel(LEFT + 5 + LINE + 2, HEADER + 5 + 2).0, [191; 3]);
        assert_eq!(img.get_pixel(LEFT + 5 + LINE + 2, HEADER + 2).0, WHITE_PX, "T[4, 20] = 0");
        assert_eq!(img.get_pixel(LEFT + 5 + LINE + 5 + 2, HEADER + 2).0, WHITE_PX, "nothing right of the last column");
    }

    #[test]
    fn sparsity_panels_fold_a_vertex_onto_the_cubemap() {
        // Like a real T: at each vertex every texel belongs to one bin j (here k mod M).
        let (r, m) = (4u32, 4usize);
        let mut entries = vec![];
        for p in 0..3 {
            for k in 0..96usize {
                if (k * 7 + p) % 3 != 0 {
                    entries.push((p * m + k % m, k, ((k + p) % 4 + 1) as f32 / 4.0));
                }
            }
        }
        let t = matrix(3, m, r, &entries);
        let dir = tmp();
        let view = PatchView { first_vertex: 1, vertices: 2, layout: PatchLayout::CubemapPanels, cell: 4 };
        let img = open(&write_sparsity(&t, &view, &dir.path().join("p.png")).unwrap());
        let side = 4 * 4;
        let w = (LEFT + 6 * side + 5 * GAP + RIGHT).max(MIN_WIDTH);
        assert_eq!(img.dimensions(), (w, HEADER + 2 * side + GAP + FOOTER));
        for p in 0..2 {
            for k in 0..96 {
                let v = value(&t, (1 + p) * m + k % m, k);
                let (x, y) = panel_origin(&t, 4, p, k);
                let want = if v == 0.0 { WHITE_PX } else { value_grey(v) };
                assert_eq!(img.get_pixel(x + 1, y + 1).0, want, "vertex {} texel {k}", 1 + p);
                // Right neighbour non-zero in another bin (k + 1 mod M differs): blue edge.
                let r = r as usize;
                if v != 0.0 && k % r + 1 < r && value(&t, (1 + p) * m + (k + 1) % m, k + 1) != 0.0 {
                    assert_eq!(img.get_pixel(x + 3, y + 1).0, ACCENT, "bin boundary right of texel {k}");
                }
            }
        }
    }

    /// A bicluster form written out by hand (global row ids, one block).
    fn hand_form(rows: usize, cols: usize, m: usize, q: u32, bcs: &[(Vec<u32>, Vec<u16>, Vec<i8>)]) -> CompressedForm {
        let mut bc_col_ptr = vec![0u32];
        let (mut bc_cols, mut bc_vals) = (vec![], vec![]);
        let mut per_row: Vec<Vec<u32>> = vec![vec![]; rows];
        for (b, (rs, ks, vs)) in bcs.iter().enumerate() {
            bc_cols.extend_from_slice(ks);
            bc_vals.extend_from_slice(vs);
            bc_col_ptr.push(bc_cols.len() as u32);
            for &i in rs {
                per_row[i as usize].push(b as u32);
            }
        }
        let mut row_ptr = vec![0u32];
        let mut row_bc = vec![];
        for l in &per_row {
            row_bc.extend_from_slice(l);
            row_ptr.push(row_bc.len() as u32);
        }
        let g = (1..=64).find(|g| (g * g) as usize == m).expect("m must be a square");
        let r = (1..=104).find(|r| (6 * r * r) as usize == cols).expect("cols must be 6 R^2");
        let shape = TransferShape::from_rows(rows, testing::bins(g), testing::cubemap(r)).unwrap();
        let mut form = CompressedForm::new("bicluster", shape)
            .with_array("bc_col_ptr", ArrayData::U32(bc_col_ptr))
            .with_array("bc_cols", ArrayData::U16(bc_cols))
            .with_array("bc_vals", ArrayData::I8(bc_vals))
            .with_array("row_ptr", ArrayData::U32(row_ptr))
            .with_array("row_bc", ArrayData::U32(row_bc))
            .with_array("block_bc_base", ArrayData::U32(vec![0, bcs.len() as u32]));
        form.meta = BTreeMap::from([
            ("value_scale".into(), q as u64),
            ("block_rows".into(), rows as u64),
            ("blocks".into(), 1),
            ("biclusters".into(), bcs.len() as u64),
            ("row_bc_local".into(), 0),
        ]);
        form.lossless = true;
        form
    }

    #[test]
    fn bicluster_patch_of_a_random_t_colours_every_entry_by_a_covering_bicluster() {
        let t = random_transfer(6, 2, 4, 0.2, 3);
        let form = Bicluster { block_vertices: 3, value_scale: 0 }.compress(&t, &CompressContext::default()).unwrap();
        let bv = BiclusterView::new(&form).unwrap();
        let dir = tmp();
        let cell = 5;
        let view = PatchView { first_vertex: 2, vertices: 3, layout: PatchLayout::Matrix { compact: false }, cell };
        let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("b.png")).unwrap());
        let w = (LEFT + 96 * cell + 5 * LINE + RIGHT).max(MIN_WIDTH);
        assert_eq!(img.dimensions(), (w, HEADER + 12 * cell + 2 * LINE + FOOTER));
        let (mut checked, mut overlaps) = (0, 0);
        for il in 0..12 {
            let i = 8 + il;
            let ids: Vec<usize> = bv.row_biclusters(i).collect();
            for k in 0..96 {
                // Brute force: every bicluster of the row whose columns contain k.
                let cover: Vec<usize> =
                    ids.iter().copied().filter(|&b| bv.bicluster(b).0.contains(&(k as u16))).collect();
                let (x, y) = matrix_origin(&t, cell, il, k);
                let corner = img.get_pixel(x, y).0;
                let centre = img.get_pixel(x + cell / 2, y + cell / 2).0;
                let v = value(&t, i, k);
                if cover.is_empty() {
                    assert_eq!(v, 0.0, "lossless form: a non-zero is covered");
                    assert_eq!((corner, centre), (WHITE_PX, WHITE_PX));
                    continue;
                }
                let first = *cover.iter().min().unwrap();
                let want =
                    if v == 0.0 { mix(bicluster_colour(first), WHITE_PX, 0.65) } else { bicluster_colour(first) };
                assert_eq!(corner, want, "T[{i}, {k}] covered by {cover:?}");
                assert_eq!(centre, if cover.len() > 1 { BLACK_PX } else { want }, "overlap mark at T[{i}, {k}]");
                checked += 1;
                overlaps += (cover.len() > 1) as usize;
            }
        }
        assert!(checked > 50, "{checked} covered entries checked");
        eprintln!("{checked} covered entries, {overlaps} overlaps");
    }

    #[test]
    fn a_single_bicluster_is_one_colour() {
        // Rows 0..8 (vertices 0 and 1, M = 4), columns 3, 10, 40 with constants 1/4, 1, 3/4:
        // one constant-column bicluster covers all of T.
        let mut entries = vec![];
        for i in 0..8 {
            for (k, v) in [(3, 0.25), (10, 1.0), (40, 0.75)] {
                entries.push((i, k, v));
            }
        }
        let t = matrix(2, 4, 4, &entries);
        let form = Bicluster::global().compress(&t, &CompressContext::default()).unwrap();
        assert_eq!(BiclusterView::new(&form).unwrap().biclusters(), 1, "greedy finds the one bicluster");
        let dir = tmp();
        for layout in [PatchLayout::Matrix { compact: false }, PatchLayout::CubemapPanels] {
            let view = PatchView { first_vertex: 0, vertices: 2, layout, cell: 4 };
            let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("one.png")).unwrap());
            for p in 0..2 {
                for j in 0..4 {
                    for k in 0..96 {
                        let (x, y) = match layout {
                            PatchLayout::CubemapPanels => panel_origin(&t, 4, p, k),
                            _ => matrix_origin(&t, 4, p * 4 + j, k),
                        };
                        let want = if [3, 10, 40].contains(&k) { bicluster_colour(0) } else { WHITE_PX };
                        assert_eq!(img.get_pixel(x + 1, y + 2).0, want, "{layout:?} row {} col {k}", p * 4 + j);
                    }
                }
            }
        }
    }

    #[test]
    fn overlaps_and_cancellations_are_marked_and_a_foreign_form_is_refused() {
        // q = 4. One vertex of M = 4 rows. T row 0: (k0 1/2, k1 1/4); row 1: (k0 1/2, k1 0);
        // rows 2 and 3 empty. B0 = rows {0, 1} x cols {0, 1} with codes (2, 1); B1 = row {1}
        // x col {1}, code -1.
        let t = matrix(1, 4, 4, &[(0, 0, 0.5), (0, 1, 0.25), (1, 0, 0.5)]);
        let form = hand_form(4, 96, 4, 4, &[(vec![0, 1], vec![0, 1], vec![2, 1]), (vec![1], vec![1], vec![-1])]);
        let dir = tmp();
        let cell = 6;
        let view = PatchView { first_vertex: 0, vertices: 1, layout: PatchLayout::Matrix { compact: true }, cell };
        let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("o.png")).unwrap());
        let px = |i: u32, c: u32, dx: u32, dy: u32| img.get_pixel(LEFT + c * cell + dx, HEADER + i * cell + dy).0;
        let (c0, pale) = (bicluster_colour(0), mix(bicluster_colour(0), WHITE_PX, 0.65));
        assert_eq!((px(0, 0, 0, 0), px(0, 0, 3, 3)), (c0, c0), "B0 alone");
        assert_eq!((px(0, 1, 0, 0), px(0, 1, 3, 3)), (c0, c0));
        assert_eq!((px(1, 0, 0, 0), px(1, 0, 3, 3)), (c0, c0));
        // dot = cell / 3 = 2 pixels at offset (cell - 2) / 2 = 2.
        assert_eq!((px(1, 1, 0, 0), px(1, 1, 2, 2), px(1, 1, 3, 3)), (pale, BLACK_PX, BLACK_PX), "cancelled overlap");
        // The same form against a T that it does not sum to.
        let other = matrix(1, 4, 4, &[(0, 0, 0.5), (0, 1, 0.25), (1, 0, 0.75)]);
        let e = write_bicluster_patch(&other, &form, &view, &dir.path().join("x.png")).unwrap_err().to_string();
        assert!(e.contains("T[1, 0]"), "{e}");
        assert!(!dir.path().join("x.png").exists());
        // Shape mismatch and patch outside T.
        let wide = matrix(2, 4, 4, &[]);
        assert!(write_bicluster_patch(&wide, &form, &view, &dir.path().join("y.png")).is_err());
        let far = PatchView { first_vertex: 1, ..view };
        assert!(write_bicluster_patch(&t, &form, &far, &dir.path().join("y.png")).is_err());
        assert!(write_sparsity(&t, &far, &dir.path().join("y.png")).is_err());
        assert!(write_sparsity(&t, &PatchView { cell: 0, ..view }, &dir.path().join("y.png")).is_err());
        assert!(!dir.path().join("y.png").exists());
    }

    #[test]
    fn histograms_have_the_documented_size_and_their_bars() {
        let t = random_transfer(8, 2, 4, 0.2, 5);
        let form = Bicluster::default().compress(&t, &CompressContext::default()).unwrap();
        let dir = tmp();
        let count = |img: &image::RgbImage, c: [u8; 3], left: bool| {
            img.enumerate_pixels().filter(|(x, _, p)| (*x < img.width() / 2) == left && p.0 == c).count()
        };
        let img = open(&write_bicluster_size_histograms(&form, &dir.path().join("h.png")).unwrap());
        assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
        assert!(count(&img, [70, 130, 220], true) > 200, "r bars on the left");
        assert!(count(&img, [230, 140, 40], false) > 200, "l bars on the right");
        let img = open(&write_value_histograms(&t, Some(&form), &dir.path().join("v.png")).unwrap());
        assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
        assert!(count(&img, [110, 110, 110], true) > 200, "T value bars");
        let bv = BiclusterView::new(&form).unwrap();
        let negative = bv.bc_vals.iter().any(|&c| c < 0);
        assert_eq!(count(&img, [230, 120, 30], false) > 0, negative, "orange bars iff residual codes < 0");
        let img = open(&write_value_histograms(&t, None, &dir.path().join("v.png")).unwrap());
        assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
        // One distinct value: a single bar; no values at all: a note instead of a chart.
        let one = matrix(1, 1, 1, &[(0, 0, 1.0), (0, 4, 1.0)]);
        let img = open(&write_value_histograms(&one, None, &dir.path().join("1.png")).unwrap());
        assert!(count(&img, [110, 110, 110], true) > 200);
        let none = matrix(1, 1, 1, &[]);
        let img = open(&write_value_histograms(&none, None, &dir.path().join("0.png")).unwrap());
        assert_eq!(count(&img, [110, 110, 110], true), 0);
    }

    #[test]
    fn per_vertex_scalars_add_up() {
        let t = random_transfer(10, 2, 4, 0.1, 9);
        let nnz = nnz_per_vertex(&t);
        for (v, &n) in nnz.iter().enumerate() {
            let direct = (0..4).map(|j| t.csr().outer_view(v * 4 + j).unwrap().nnz()).sum::<usize>();
            assert_eq!(n as usize, direct);
        }
        let form = Bicluster { block_vertices: 4, value_scale: 0 }.compress(&t, &CompressContext::default()).unwrap();
        let cost = gather_cost_per_vertex(&form).unwrap();
        assert_eq!(cost.len(), 10);
        // The split is exact in f64; per-vertex sums of < 1e4 are stored in f32 (2^-24
        // relative each), so the total agrees with W to ~1e-6 relative.
        let total: f64 = cost.iter().map(|&c| c as f64).sum();
        let w = table_stats(&form, &t).unwrap().mflops_biclustered * 1e6;
        assert!((total - w).abs() <= 1e-6 * w, "{total} vs {w}");
        // Brute force for vertex 3: its rows' list lengths + (2l - 1) r_v / r per bicluster.
        let bv = BiclusterView::new(&form).unwrap();
        let r = bv.bicluster_rows();
        let mut want = 0.0f64;
        for (b, &rb) in r.iter().enumerate() {
            let rv = (12..16).filter(|&i| bv.row_biclusters(i).any(|x| x == b)).count() as f64;
            let l = bv.bicluster(b).0.len() as f64;
            want += rv + (2.0 * l - 1.0) * rv / rb as f64;
        }
        assert!((cost[3] as f64 - want).abs() <= 1e-6 * want, "{} vs {want}", cost[3]);
    }

    fn top_camera(mesh: &Mesh) -> Camera {
        let (lo, hi) = mesh.bounds();
        Camera::frame_bounds(lo, hi, 80, 60, 0.0, 90.0, 40.0)
    }

    #[test]
    fn heatmap_of_a_constant_is_one_colour() {
        let mesh = shapes::grid_plane(6, 2.0);
        let cam = top_camera(&mesh);
        let dir = tmp();
        let opts = HeatmapOptions { range: None, relief: 0.0 };
        let img = open(
            &write_vertex_heatmap(
                &mesh,
                &cam,
                &vec![3.5; mesh.vertex_count()],
                "const",
                &opts,
                &dir.path().join("c.png"),
            )
            .unwrap(),
        );
        assert_eq!(img.dimensions(), heatmap_size(&cam));
        let mut covered = 0;
        for y in 0..cam.height {
            for x in 0..cam.width {
                let p = img.get_pixel(x, y + TITLE_HEIGHT).0;
                if p != WHITE_PX {
                    assert_eq!(p, viridis(0.5), "pixel ({x}, {y})");
                    covered += 1;
                }
            }
        }
        // The plane seen from above fills a square of about 0.55 of the height: >= 1/4 of it.
        assert!(covered > (cam.width * cam.height / 4) as usize, "{covered}");
        // Bad inputs are errors.
        assert!(write_vertex_heatmap(&mesh, &cam, &[1.0], "x", &opts, &dir.path().join("e.png")).is_err());
        let bad = HeatmapOptions { range: Some((1.0, 0.0)), relief: 0.0 };
        assert!(write_vertex_heatmap(
            &mesh,
            &cam,
            &vec![0.0; mesh.vertex_count()],
            "x",
            &bad,
            &dir.path().join("e.png")
        )
        .is_err());
    }

    #[test]
    fn heatmap_of_a_ramp_matches_the_ramp_at_every_pixel() {
        let mesh = shapes::grid_plane(6, 2.0);
        let cam = top_camera(&mesh);
        // s = x, in [-1, 1]; linear, so barycentric interpolation reproduces it exactly.
        let values: Vec<f32> = mesh.positions.iter().map(|p| p.x).collect();
        let dir = tmp();
        let opts = HeatmapOptions { range: None, relief: 0.0 };
        let img = open(&write_vertex_heatmap(&mesh, &cam, &values, "x", &opts, &dir.path().join("r.png")).unwrap());
        let lum = |c: [u8; 3]| 0.2126 * c[0] as f32 + 0.7152 * c[1] as f32 + 0.0722 * c[2] as f32;
        let mut checked = 0;
        for y in 0..cam.height {
            let mut prev: Option<f32> = None;
            for x in 0..cam.width {
                let p = img.get_pixel(x, y + TITLE_HEIGHT).0;
                // Independent: intersect the pixel's ray with the plane y = 0.
                let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
                let hit = o + d * (-o.y / d.y);
                if hit.x.abs() > 0.999 || hit.z.abs() > 0.999 {
                    continue; // at the plane's edge a ray may just miss
                }
                let want = viridis((hit.x + 1.0) / 2.0);
                // f32 ray/barycentric rounding moves t by ~1e-6; viridis channels then move by
                // at most 1 unit after rounding to 8 bits.
                assert!(p.iter().zip(&want).all(|(a, b)| a.abs_diff(*b) <= 1), "({x}, {y}): {p:?} vs {want:?}");
                if let Some(l) = prev {
                    assert!(lum(p) >= l - 0.75, "luminance increases along +x at ({x}, {y})");
                }
                prev = Some(lum(p));
                checked += 1;
            }
        }
        assert!(checked > 1000, "{checked}");
        // Image x grows along world +X for this camera: left is dark, right is bright.
        let row = cam.height / 2 + TITLE_HEIGHT;
        let covered: Vec<u32> = (0..cam.width).filter(|&x| img.get_pixel(x, row).0 != WHITE_PX).collect();
        let (a, b) = (img.get_pixel(covered[0], row).0, img.get_pixel(*covered.last().unwrap(), row).0);
        assert!(lum(b) > lum(a) + 100.0, "{a:?} -> {b:?}");
        // Colour bar: top is viridis(1), bottom viridis(0).
        let bx = cam.width + 18 + 10;
        assert_eq!(img.get_pixel(bx, TITLE_HEIGHT + 14).0, viridis(1.0));
        assert_eq!(img.get_pixel(bx, img.height() - 15).0, viridis(0.0));
        // A NaN vertex shows as magenta where it weighs in.
        let mut nan = values.clone();
        nan[mesh.positions.iter().position(|p| *p == Vec3::ZERO).unwrap()] = f32::NAN;
        let img = open(&write_vertex_heatmap(&mesh, &cam, &nan, "x", &opts, &dir.path().join("n.png")).unwrap());
        assert_eq!(img.get_pixel(cam.width / 2, cam.height / 2 + TITLE_HEIGHT).0, NON_FINITE_COLOUR);
    }
}
