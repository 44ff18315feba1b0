//! Matrix-structure pictures: what `T` and its biclusters look like.
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
//!   `biscale_compressors::bicluster::analysis::gather_cost_per_vertex`, [`nnz_per_vertex`],
//!   or any `&[f32]`.
//!
//! # Patch layouts
//!
//! A patch of 4-16 vertices has `count * M` rows (256-1024 at M = 64) against N = 6144
//! columns, and one vertex's visible hemisphere touches about half of them, so compacting the
//! touched columns hardly shrinks the matrix: a literal matrix picture is a strip several
//! thousand pixels wide in which each row is a few short runs of dots. Two layouts:
//!
//! * [`PatchLayout::CubemapPanels`] (the default, the most legible): each transfer entry
//!   `T_p[j, k]` is non-zero only for the one bin `j` that contains `d_k` (docs/DESIGN.md section 3),
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
//!
//! Files: `patch` (the two patch pictures and their geometry), `histograms`, `heatmap`, and
//! `raster` (the canvas, text and colours they share). What the pictures say about biclusters is computed beside the
//! compressor (`biscale_compressors::bicluster::analysis`); this module only draws.

mod heatmap;
mod histograms;
mod patch;
mod raster;
#[cfg(test)]
mod tests;

pub use heatmap::{heatmap_size, nnz_per_vertex, write_vertex_heatmap, HeatmapOptions, COLOUR_BAR_WIDTH, TITLE_HEIGHT};
pub use histograms::{write_bicluster_size_histograms, write_value_histograms, HISTOGRAM_SIZE};
pub use patch::{
    bicluster_colour, value_grey, write_bicluster_patch, write_sparsity, PatchLayout, PatchView, FOOTER, GAP, HEADER,
    LEFT, LINE, MAX_SIDE, MIN_WIDTH, RIGHT,
};

use biscale_core::compress::CompressError;
use biscale_shading::ShadingError;

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
