//! Building the stacked transfer matrix `T` ((n M) x N, CSR) of a whole mesh: one
//! [`VisibilitySampler::point_counts`] query per vertex, in parallel over vertices (rayon),
//! assembled into rows `v * M + j` with sorted column indices.
//!
//! * **Geometry.** Frames, the normalised BVH and the ray origins come from a
//!   [`TransferScene`] (see there for the origin offset and the normalisation).
//! * **Determinism.** Each vertex's entries depend only on that vertex (the per-thread
//!   scratch is reset per query and the ray order within a vertex is fixed), and rayon's
//!   indexed `collect` keeps vertex order, so `T` does not depend on the thread count.
//! * **Memory.** A point's texel centres above its tangent plane are at most `N / 2`
//!   (the cubemap's texel centres are antipodally symmetric and `d . n > 0` excludes `-d`),
//!   so a vertex has at most `N / 2` non-zeros. Requests whose worst case exceeds
//!   [`MAX_TRANSFER_BYTES`] are refused before anything is allocated.

use super::{TransferMatrix, TransferScene, TransferSettings, VisibilitySampler, VisibilityScratch};
use crate::error::{CoreError, Result};
use crate::geometry::Mesh;
use rayon::prelude::*;
use std::ops::Range;
use std::sync::Mutex;
use std::time::Instant;

/// Largest worst-case memory a transfer build may need (8 GiB): see [`worst_case_bytes`].
pub const MAX_TRANSFER_BYTES: u64 = 8 << 30;

/// Bytes per stored non-zero at the peak of a build: the final CSR's f32 value and usize
/// column index (sprs), plus the staged u16 column and u16 count of the per-vertex results.
pub const BYTES_PER_NONZERO: u64 = (std::mem::size_of::<f32>() + std::mem::size_of::<usize>() + 4) as u64;

/// A built transfer matrix and how it went.
#[derive(Clone, Debug)]
pub struct TransferBuild {
    pub matrix: TransferMatrix,
    pub stats: TransferStats,
}

/// One line for logs: `T`'s shape and non-zeros, and the build's time and ray rate.
impl std::fmt::Display for TransferBuild {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = &self.matrix;
        write!(
            f,
            "{} x {} ({}), {} non-zeros ({:.1} per row), built in {:.2} s ({:.1} M rays/s, {} threads)",
            t.rows(),
            t.cols(),
            t.shape(),
            t.nnz(),
            t.nnz() as f64 / t.rows().max(1) as f64,
            self.stats.seconds,
            self.stats.rays_per_second / 1e6,
            rayon::current_num_threads()
        )
    }
}

/// Statistics of a transfer build.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferStats {
    /// Visibility queries answered (fine-texel rays above the tangent planes).
    pub rays_traced: u64,
    /// Wall-clock seconds of the whole build (frames, BVH, tracing, assembly).
    pub seconds: f64,
    /// `rays_traced / seconds`.
    pub rays_per_second: f64,
    /// `(value, number of non-zeros with that value)` for every possible value
    /// `i / s^2`, `i = 1..=s^2`, ascending.
    pub value_histogram: Vec<(f32, u64)>,
    /// Vertices whose normal fell back to +Y (see [`vertex_frames`]).
    pub frame_fallbacks: usize,
}

/// Worst-case peak bytes of a build of `vertices` vertices: `vertices * N/2` non-zeros at
/// [`BYTES_PER_NONZERO`] plus the row pointers.
pub fn worst_case_bytes(vertices: usize, settings: &TransferSettings) -> u64 {
    let n = settings.light_basis().len() as u64;
    let m = settings.local_basis().len() as u64;
    let nnz = vertices as u64 * (n / 2);
    nnz.saturating_mul(BYTES_PER_NONZERO)
        .saturating_add((vertices as u64 * m + 1).saturating_mul(std::mem::size_of::<usize>() as u64))
}

/// One vertex's entries, sorted by (row j, column k): `row_len[j]` entries per local bin.
struct VertexRows {
    row_len: Vec<u32>,
    cols: Vec<u16>,
    counts: Vec<u16>,
}

/// Build `T` for every vertex of `mesh`. `progress`, if given, is called (from any thread,
/// with increasing values) with the number of vertices finished so far.
pub fn build(
    mesh: &Mesh,
    settings: &TransferSettings,
    progress: Option<&(dyn Fn(usize) + Sync)>,
) -> Result<TransferBuild> {
    let start = Instant::now();
    check_size(mesh.vertex_count(), settings)?;
    let scene = TransferScene::new(mesh)?;
    let mut b = build_range(&scene, settings, 0..mesh.vertex_count(), progress)?;
    b.stats.seconds = start.elapsed().as_secs_f64();
    b.stats.rays_per_second = b.stats.rays_traced as f64 / b.stats.seconds.max(1e-12);
    Ok(b)
}

/// Refuse a build whose worst case exceeds [`MAX_TRANSFER_BYTES`], before allocating.
fn check_size(vertices: usize, settings: &TransferSettings) -> Result<()> {
    let bytes = worst_case_bytes(vertices, settings);
    if bytes > MAX_TRANSFER_BYTES {
        return Err(CoreError::TooLarge(format!(
            "transfer matrix for {vertices} vertices at {light} and {local}: up to {nnz} non-zeros, \
             {gib:.1} GiB worst case, over the {lim} GiB limit (MAX_TRANSFER_BYTES)",
            light = settings.light_basis(),
            local = settings.local_basis(),
            nnz = vertices as u64 * (settings.light_basis().len() as u64 / 2),
            gib = bytes as f64 / (1u64 << 30) as f64,
            lim = MAX_TRANSFER_BYTES >> 30,
        )));
    }
    Ok(())
}

/// Build the rows of `T` for the vertices in `range` of `scene` (a shard of the whole
/// matrix: its row `i * M + j` is row `(range.start + i) * M + j` of the full `T`, bit for
/// bit). `progress` counts the range's vertices finished so far.
pub fn build_range(
    scene: &TransferScene,
    settings: &TransferSettings,
    range: Range<usize>,
    progress: Option<&(dyn Fn(usize) + Sync)>,
) -> Result<TransferBuild> {
    let start = Instant::now();
    if range.start > range.end || range.end > scene.vertex_count() {
        return Err(CoreError::Invalid(format!(
            "vertex range {range:?} is not within the scene's {} vertices",
            scene.vertex_count()
        )));
    }
    let vertices = range.len();
    check_size(vertices, settings)?;
    let s = settings.supersampling() as u64;
    let sampler = VisibilitySampler::new(settings);
    let m = sampler.grid.len();
    let done = Mutex::new(0usize);
    let per_vertex: Vec<(VertexRows, u64)> = range
        .into_par_iter()
        .map_init(
            || (VisibilityScratch::default(), Vec::<(u32, u16, u16)>::new()),
            |(scratch, entries), v| {
                entries.clear();
                let rays = scene.vertex_counts(&sampler, v, scratch, |j, k, c| entries.push((j, k as u16, c as u16)));
                // Counting sort by row j; entries arrive in increasing k, so each row's
                // columns stay sorted.
                let mut row_len = vec![0u32; m];
                for e in entries.iter() {
                    row_len[e.0 as usize] += 1;
                }
                let mut at: Vec<u32> = row_len
                    .iter()
                    .scan(0u32, |acc, &l| {
                        let s = *acc;
                        *acc += l;
                        Some(s)
                    })
                    .collect();
                let mut cols = vec![0u16; entries.len()];
                let mut counts = vec![0u16; entries.len()];
                for &(j, k, c) in entries.iter() {
                    let p = &mut at[j as usize];
                    cols[*p as usize] = k;
                    counts[*p as usize] = c;
                    *p += 1;
                }
                if let Some(report) = progress {
                    let mut d = done.lock().unwrap_or_else(|e| e.into_inner());
                    *d += 1;
                    report(*d);
                }
                (VertexRows { row_len, cols, counts }, rays)
            },
        )
        .collect();

    // Assemble the CSR in vertex order.
    let nnz: usize = per_vertex.iter().map(|(r, _)| r.cols.len()).sum();
    let s2 = (s * s) as usize;
    let value_of: Vec<f32> = (0..=s2).map(|c| c as f32 / s2 as f32).collect();
    let mut histogram = vec![0u64; s2 + 1];
    let mut indptr = Vec::with_capacity(vertices * m + 1);
    let mut indices = Vec::with_capacity(nnz);
    let mut data = Vec::with_capacity(nnz);
    let mut rays_traced = 0u64;
    indptr.push(0usize);
    for (rows, rays) in per_vertex {
        rays_traced += rays;
        for len in rows.row_len {
            indptr.push(indptr.last().unwrap() + len as usize);
        }
        indices.extend(rows.cols.iter().map(|&k| k as usize));
        for c in rows.counts {
            histogram[c as usize] += 1;
            data.push(value_of[c as usize]);
        }
    }
    let n = settings.light_basis().len();
    let csr = sprs::CsMat::try_new((vertices * m, n), indptr, indices, data)
        .map_err(|e| CoreError::Invalid(format!("internal error assembling T: {}", e.3)))?;
    let seconds = start.elapsed().as_secs_f64();
    Ok(TransferBuild {
        matrix: TransferMatrix::new(settings.local_basis(), settings.light_basis(), csr)?,
        stats: TransferStats {
            rays_traced,
            seconds,
            rays_per_second: rays_traced as f64 / seconds.max(1e-12),
            value_histogram: (1..=s2).map(|c| (value_of[c], histogram[c])).collect(),
            frame_fallbacks: scene.frame_fallbacks(),
        },
    })
}
