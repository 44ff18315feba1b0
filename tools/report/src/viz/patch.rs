//! The patch pictures: the sparsity of `T` for a patch of consecutive vertices, and the same
//! patch with the biclusters that cover it (the layouts and pixel geometry are in the
//! [module docs](super)).

use super::raster::{hsv, mix, text, Canvas, BLACK_PX, TOP_LEFT, WHITE_PX};
use super::{invalid, Result};
use biscale_compressors::bicluster::analysis::row_cover;
use biscale_compressors::bicluster::BiclusterView;
use biscale_core::compress::CompressedForm;
use biscale_core::transfer::TransferMatrix;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

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
    /// `vertices a..b`, for titles.
    fn span(&self) -> String {
        format!("vertices {}..{}", self.first_vertex, self.first_vertex + self.vertices - 1)
    }

    /// `vertices` vertices from `first_vertex`, cubemap panels, 4-pixel cells.
    pub fn new(first_vertex: usize, vertices: usize) -> Self {
        Self { first_vertex, vertices, layout: PatchLayout::CubemapPanels, cell: 4 }
    }
}

/// Face boundaries (matrix layout) and local-bin boundaries (panels).
pub(super) const ACCENT: [u8; 3] = [70, 130, 220];
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

/// Call `f(k, value)` for every stored entry of row `i` of a CSR matrix.
fn for_row(csr: &sprs::CsMat<f32>, i: usize, mut f: impl FnMut(usize, f32)) {
    if let Some(row) = csr.outer_view(i) {
        for (k, &v) in row.iter() {
            f(k, v);
        }
    }
}

/// Check that `view` lies inside `t` and has a drawable cell size (`T`'s own shape is an
/// invariant of the type).
pub(super) fn check_patch(t: &TransferMatrix, view: &PatchView) -> Result<()> {
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
pub(super) struct Grid {
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
    let csr = t.csr();
    let m = t.local_dirs();
    let (row0, patch_rows) = (view.first_vertex * m, view.vertices * m);
    let mut touched = vec![false; t.cols()];
    for i in row0..row0 + patch_rows {
        for_row(csr, i, |k, v| touched[k] |= v != 0.0);
    }
    let g = Grid::new(t, view, &touched)?;
    // Per cell: the largest |value| and the bin j that holds it (u32::MAX: empty).
    let mut value = vec![0.0f32; g.cells()];
    let mut bin = vec![u32::MAX; g.cells()];
    let mut nnz = 0usize;
    for il in 0..patch_rows {
        for_row(csr, row0 + il, |k, v| {
            if let (Some(c), true) = (g.cell_of(il, k), v != 0.0) {
                nnz += 1;
                if v.abs() > value[c].abs() {
                    value[c] = v;
                    bin[c] = (il % m) as u32;
                }
            }
        });
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
        "T: {} ({patch_rows} rows of M = {m} each) x N = {} columns; {nnz} non-zeros{}",
        view.span(),
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
    check_patch(t, view)?;
    let biclusters = BiclusterView::new(form)?.biclusters();
    let m = t.local_dirs();
    let (row0, patch_rows) = (view.first_vertex * m, view.vertices * m);
    // Entries of every patch row: T's value and the biclusters' cover (checked against T).
    let (rows, ids) = row_cover(form, t, row0..row0 + patch_rows)?;
    let mut touched = vec![false; t.cols()];
    for e in rows.iter().flatten() {
        touched[e.col] = true;
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
        for e in row {
            let (v, first) = (e.value, e.first.map_or(0, |b| b as u32 + 1));
            let Some(ci) = g.cell_of(il, e.col) else { continue };
            let cell = &mut cells[ci];
            covered += (e.count > 0) as usize;
            overlaps += (e.count > 1) as usize;
            cancelled += (v == 0.0 && e.count > 0) as usize;
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
                cell.first_nonzero = min_id(cell.first_nonzero, first);
            }
            cell.first_any = min_id(cell.first_any, first);
            cell.overlap |= e.count > 1;
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
        "Biclusters on T: {} ({patch_rows} rows), {} of the {} biclusters touch these rows",
        view.span(),
        ids.len(),
        biclusters
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
