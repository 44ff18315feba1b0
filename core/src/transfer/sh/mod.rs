//! The SH transfer of the low-frequency method (Sloan et al. 2003): per vertex `p` an
//! `n^2 x n^2` matrix `M_p` that maps the world-SH light `L_sh` to the local-SH incident light
//! `l_p = M_p L_sh` in the vertex's frame, macro-scale visibility included:
//!
//! `M_p[i][j] = int_{H_p} y_i(F_p^T w) y_j(w) V_p(w) dw`,
//!
//! `H_p` the upper hemisphere of the vertex's frame (directions below the tangent plane count
//! as occluded, as in `T`), `V_p` the visibility of the distant light, `y` the real SH of
//! [`crate::sh`]. Stacked like `T` (row `v n^2 + i`, column `j`), it is a [`TransferMatrix`] in
//! the bases `LocalBasis::Sh` x `LightBasis::Sh`, so every compressor and both gathers take it.
//!
//! * **Ray tracing** ([`build_sh`]): stratified (jittered) sampling of `H_p` through the
//!   equal-area concentric map on a `g x g` grid (`g^2 >= rays`), each stratum of solid angle
//!   `2 pi / g^2`, one ray per stratum with the jitter of a per-(seed, vertex, stratum) hash,
//!   traced with the same frames, normalised BVH and origin offset as `T`
//!   ([`TransferScene`]), accumulated in f64. Deterministic for a seed, for any thread count.
//! * **Interreflection** ([`add_bounces`]): bounces off Lambertian triangles of given albedos,
//!   on the same strata (see there).
//! * **From `T`** ([`sh_from_transfer`]): `M_p[i][j] ~= sum_k v_pk omega_k y_i(F_p^T d_k) y_j(d_k)`
//!   with `v_pk = sum_b T_p[b, k]` the texel's visible fraction (2 x 2 box-filtered): the
//!   midpoint rule over the cubemap texels. The bridge that makes the two methods comparable:
//!   both are quadratures of the same integral over the same visibility.

mod bounce;
pub use bounce::add_bounces;

use super::{TransferMatrix, TransferScene};
use crate::basis::{LightBasis, LocalBasis};
use crate::error::{CoreError, Result};
use crate::geometry::VertexFrame;
use crate::sampling::hemisphere::square_to_hemisphere;
use crate::sh::{eval, eval_into, ShOrder};
use glam::DVec3;
use rayon::prelude::*;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// Settings that determine `M`: the SH order, the rays per vertex and the jitter seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ShTransferSettings {
    order: ShOrder,
    grid: u32,
    seed: u64,
}

/// Most strata per side: 256^2 = 65,536 rays per vertex.
pub const MAX_SH_GRID: u32 = 256;

impl ShTransferSettings {
    /// Order `n`, at least `rays` rays per vertex (rounded up to the square `g^2` of the
    /// stratified grid), jitter seed `seed`.
    pub fn new(order: u32, rays: u32, seed: u64) -> Result<Self> {
        let order = ShOrder::new(order)?;
        let grid = (rays as f64).sqrt().ceil() as u32;
        if grid == 0 || grid > MAX_SH_GRID {
            return Err(CoreError::Invalid(format!(
                "SH transfer rays per vertex must be 1..={}, got {rays}",
                MAX_SH_GRID * MAX_SH_GRID
            )));
        }
        Ok(Self { order, grid, seed })
    }

    pub fn order(&self) -> ShOrder {
        self.order
    }

    /// Rays per vertex actually traced, `g^2`.
    pub fn rays(&self) -> u32 {
        self.grid * self.grid
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The bases of `M`: local SH rows, world SH columns.
    pub fn bases(&self) -> (LocalBasis, LightBasis) {
        (LocalBasis::Sh(self.order), LightBasis::Sh(self.order))
    }
}

/// A built SH transfer and how it went.
#[derive(Clone, Debug)]
pub struct ShTransferBuild {
    pub matrix: TransferMatrix,
    /// Rays traced (every stratum of every vertex).
    pub rays_traced: u64,
    pub seconds: f64,
}

/// 64-bit mix (splitmix64's finaliser): the jitter's hash.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Uniform `[0, 1)` for (seed, vertex, stratum, axis).
fn jitter(seed: u64, v: usize, s: u32, axis: u64) -> f64 {
    let h = mix(seed ^ mix(v as u64 ^ mix((s as u64) << 1 | axis)));
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// World direction of local direction `l` in `frame`, in f64.
pub(crate) fn to_world(frame: &VertexFrame, l: DVec3) -> DVec3 {
    frame.tangent.as_dvec3() * l.x + frame.bitangent.as_dvec3() * l.y + frame.normal.as_dvec3() * l.z
}

/// The local direction of stratum `s` of vertex `v` (jittered within its cell).
pub(crate) fn stratum_direction(settings: &ShTransferSettings, v: usize, s: u32) -> DVec3 {
    let g = settings.grid;
    let (row, col) = (s / g, s % g);
    let u = (col as f64 + jitter(settings.seed, v, s, 0)) / g as f64;
    let w = (row as f64 + jitter(settings.seed, v, s, 1)) / g as f64;
    square_to_hemisphere(u, w)
}

/// `M_p` of vertex `v` as a dense row-major `n^2 x n^2` f64 matrix.
fn vertex_matrix(scene: &TransferScene, settings: &ShTransferSettings, v: usize) -> Vec<f64> {
    let n = settings.order.len();
    let frame = scene.frames()[v];
    let origin = scene.vertex_origin(v);
    let strata = settings.rays();
    let weight = 2.0 * std::f64::consts::PI / strata as f64;
    let (mut m, mut yl, mut yw) = (vec![0.0f64; n * n], vec![0.0f64; n], vec![0.0f64; n]);
    for s in 0..strata {
        let local = stratum_direction(settings, v, s);
        let world = to_world(&frame, local);
        if scene.occluded_from(origin, world.as_vec3()) {
            continue;
        }
        eval_into(settings.order, local, &mut yl);
        eval_into(settings.order, world, &mut yw);
        for (i, &a) in yl.iter().enumerate() {
            let a = a * weight;
            for (mij, &b) in m[i * n..(i + 1) * n].iter_mut().zip(&yw) {
                *mij += a * b;
            }
        }
    }
    m
}

/// Dense per-vertex `n x n` blocks (f64, row-major) stacked into a CSR [`TransferMatrix`] in
/// the SH bases (exact zeros dropped: a fully occluded vertex has empty rows).
pub(crate) fn assemble(order: ShOrder, blocks: &[Vec<f64>]) -> Result<TransferMatrix> {
    let n = order.len();
    let mut indptr = Vec::with_capacity(blocks.len() * n + 1);
    let (mut indices, mut data) = (Vec::new(), Vec::new());
    indptr.push(0);
    for b in blocks {
        for i in 0..n {
            for (j, &x) in b[i * n..(i + 1) * n].iter().enumerate() {
                let x = x as f32;
                if x != 0.0 {
                    indices.push(j);
                    data.push(x);
                }
            }
            indptr.push(indices.len());
        }
    }
    let csr = sprs::CsMat::new((blocks.len() * n, n), indptr, indices, data);
    TransferMatrix::new(LocalBasis::Sh(order), LightBasis::Sh(order), csr)
}

/// `M` for the vertices in `range` of `scene` by ray tracing (see the module docs).
/// `progress` counts vertices finished so far.
pub fn build_sh(
    scene: &TransferScene,
    settings: &ShTransferSettings,
    range: Range<usize>,
    progress: Option<&(dyn Fn(usize) + Sync)>,
) -> Result<ShTransferBuild> {
    let start = Instant::now();
    if range.start > range.end || range.end > scene.vertex_count() {
        return Err(CoreError::Invalid(format!(
            "vertex range {range:?} is not within the scene's {} vertices",
            scene.vertex_count()
        )));
    }
    let done = AtomicUsize::new(0);
    let blocks: Vec<Vec<f64>> = range
        .clone()
        .into_par_iter()
        .map(|v| {
            let m = vertex_matrix(scene, settings, v);
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            if let Some(p) = progress {
                p(d);
            }
            m
        })
        .collect();
    let matrix = assemble(settings.order, &blocks)?;
    Ok(ShTransferBuild {
        matrix,
        rays_traced: range.len() as u64 * settings.rays() as u64,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// `M` projected from the bins transfer matrix `t` (see the module docs) with the vertex
/// frames `frames` (`t`'s): an error unless `t` is in a cubemap light basis with one frame per
/// vertex.
pub fn sh_from_transfer(t: &TransferMatrix, frames: &[VertexFrame], order: ShOrder) -> Result<TransferMatrix> {
    let all: Vec<usize> = (0..t.vertices()).collect();
    assemble(order, &sh_from_transfer_vertices(t, frames, order, &all)?)
}

/// [`sh_from_transfer`] for some vertices only: their dense `n^2 x n^2` blocks (f64,
/// row-major), in the order given.
pub fn sh_from_transfer_vertices(
    t: &TransferMatrix,
    frames: &[VertexFrame],
    order: ShOrder,
    vertices: &[usize],
) -> Result<Vec<Vec<f64>>> {
    let cubemap = t.light_basis().cubemap_layout().ok_or_else(|| {
        CoreError::Invalid(format!("projecting T onto SH needs a cubemap light basis, T has {}", t.light_basis()))
    })?;
    if frames.len() != t.vertices() {
        return Err(CoreError::Invalid(format!("{} frames for the {} vertices of T", frames.len(), t.vertices())));
    }
    if let Some(v) = vertices.iter().find(|&&v| v >= t.vertices()) {
        return Err(CoreError::Invalid(format!("vertex {v} of a T of {} vertices", t.vertices())));
    }
    let (m, n) = (t.local_dirs(), order.len());
    // World SH at every texel centre, weighted by the texel's solid angle.
    let yw: Vec<f64> = (0..cubemap.texel_count())
        .into_par_iter()
        .flat_map_iter(|k| {
            let w = cubemap.texel_solid_angle(k);
            eval(order, cubemap.texel_direction_f64(k)).into_iter().map(move |y| y * w)
        })
        .collect();
    let csr = t.csr();
    Ok(vertices
        .par_iter()
        .map(|&v| {
            let frame = frames[v];
            // Visible fraction of every texel the vertex's rows touch.
            let mut vis: std::collections::BTreeMap<usize, f64> = std::collections::BTreeMap::new();
            for r in v * m..(v + 1) * m {
                if let Some(row) = csr.outer_view(r) {
                    for (k, &x) in row.iter() {
                        *vis.entry(k).or_default() += x as f64;
                    }
                }
            }
            let (mut out, mut yl) = (vec![0.0f64; n * n], vec![0.0f64; n]);
            for (&k, &f) in &vis {
                eval_into(order, to_local(&frame, cubemap.texel_direction_f64(k)), &mut yl);
                for i in 0..n {
                    let a = yl[i] * f;
                    for j in 0..n {
                        out[i * n + j] += a * yw[k * n + j];
                    }
                }
            }
            out
        })
        .collect())
}

/// The shadowed diffuse PRT transfer of an SH transfer `m` (Sloan et al. 2002): per vertex
/// the one row `t_p = c^T M_p` (`c` the clamped cosine's coefficients, [`crate::sh::clamped_cosine`]),
/// so that `t_p . L_sh` is the vertex's irradiance at the order. Rows in
/// `LocalBasis::Irradiance`, the same columns.
pub fn irradiance_transfer(m: &TransferMatrix) -> Result<TransferMatrix> {
    let order = m.local_basis().sh_order().ok_or_else(|| {
        CoreError::Invalid(format!("the irradiance transfer reduces an SH transfer, not one on {}", m.local_basis()))
    })?;
    let (n, cols) = (order.len(), m.cols());
    let c = crate::sh::clamped_cosine(order);
    let mut indptr = vec![0usize];
    let (mut indices, mut data) = (vec![], vec![]);
    for v in 0..m.vertices() {
        let mut row = vec![0.0f64; cols];
        for (i, ci) in c.iter().enumerate().filter(|(_, c)| **c != 0.0) {
            if let Some(r) = m.csr().outer_view(v * n + i) {
                for (j, &x) in r.iter() {
                    row[j] += ci * x as f64;
                }
            }
        }
        for (j, x) in row.into_iter().enumerate() {
            if x as f32 != 0.0 {
                indices.push(j);
                data.push(x as f32);
            }
        }
        indptr.push(indices.len());
    }
    let csr = sprs::CsMat::new((m.vertices(), cols), indptr, indices, data);
    TransferMatrix::new(LocalBasis::Irradiance(order), m.light_basis(), csr)
}

/// World direction `d` in `frame`'s coordinates, in f64.
fn to_local(frame: &VertexFrame, d: DVec3) -> DVec3 {
    let (t, b, n) = (frame.tangent.as_dvec3(), frame.bitangent.as_dvec3(), frame.normal.as_dvec3());
    DVec3::new(d.dot(t), d.dot(b), d.dot(n))
}

#[cfg(test)]
mod tests;
