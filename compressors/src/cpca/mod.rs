//! Clustered principal component analysis of the transfer rows (Sloan, Hall, Hart, Snyder
//! 2003, "Clustered principal components for precomputed radiance transfer").
//!
//! # What is clustered
//!
//! The **rows** of `T` (one per vertex and local bin, N = 6 R^2 texels each). Sloan et al.
//! cluster per-vertex transfer matrices; here a per-vertex block is M x N, so each cluster
//! mean and component would be an M x N matrix: K (C + 1) M N floats, 450 MB at the
//! reference 32 x 8 (M = 64, N = 6144), more than the raw sparse `T` of the bunny (80 MB).
//! Row clustering stores K (C + 1) N floats (7 MB) plus C coefficients per row, and its
//! runtime is the one the biclustering paper compares against. Rows that are entirely zero
//! (fully occluded bins) get no cluster: they are stored as a sentinel id and gather to 0.
//!
//! # Build (Sloan et al. 2003, section 3: iterative CPCA)
//!
//! 1. **Seeding**: k-means++ (Arthur & Vassilvitskii 2007) on the non-zero rows with
//!    `CompressContext::seed`: each seed is drawn with probability proportional to the squared
//!    distance to the nearest seed so far. Seeding stops early when every row coincides with a
//!    seed (so K may shrink: more clusters than distinct rows is fine). Each seed starts as a
//!    cluster with that row as mean and no components.
//! 2. **Assignment**: every row goes to the cluster whose affine model reconstructs it best:
//!    `err_k(x) = ||x - mu_k||^2 - sum_c ((x - mu_k) . u_kc)^2`, expanded so that only the
//!    row's non-zeros are touched: `||x||^2 - 2 x.mu + ||mu||^2 - sum_c (x.u_c - mu.u_c)^2`.
//!    All K (C + 1) sparse dot products of a row are one pass over its non-zeros through an
//!    N x K(C + 1) f32 table (texel-major, contiguous per non-zero). The dot products use f32
//!    (at most ~100 non-zeros of size <= 1 against unit-norm vectors: relative error ~1e-6,
//!    which only matters for rows two clusters fit equally well); the error itself is
//!    combined in f64.
//! 3. **Refit**: each cluster's mean and its top C principal directions of the centred rows
//!    `A = X - 1 mu^T`, never formed: `A Q = X Q - 1 (mu^T Q)` and
//!    `A^T Z = X^T Z - mu (1^T Z)` on the sparse rows. Randomised subspace iteration (Halko,
//!    Martinsson, Tropp 2011, Algorithm 4.4) with `l = C + oversampling` columns, warm-started
//!    from the cluster's previous components, `power_iterations` rounds of `Q <- orth(A^T A Q)`,
//!    then Rayleigh-Ritz: the eigen-decomposition of the l x l matrix `(A Q)^T (A Q)`
//!    (Jacobi, [`linalg::sym_eigen`]). A cluster whose centred rows span at most `l`
//!    dimensions (fewer rows than `l + 1`, or N <= l) uses those rows (or the identity) as `Q`,
//!    which makes its PCA exact. Directions with a Ritz value below 1e-13 of the largest
//!    (rank-deficient clusters) are stored as zero components.
//! 4. Empty clusters are re-seeded with the worst-fit rows (largest `err`) taken from clusters
//!    that keep at least one row; a cluster that cannot be re-seeded (every row is fit exactly)
//!    is dropped. Rounds stop after `iterations` or when no row changes cluster.
//! 5. A final assignment with the final models, coefficients `c = U (x - mu)` accumulated in
//!    f64 against the stored (f32) basis, and clusters left empty are removed.
//!
//! Every reduction runs in a fixed order (per cluster, or per row), so the same seed gives the
//! same bytes on any number of threads.
//!
//! # Compressed form (`kind = "cpca"`)
//!
//! | array     | type | length           | meaning |
//! |-----------|------|------------------|---------|
//! | `basis`   | f32  | K (C + 1) N      | cluster k's mean at `basis[(k (C+1)) N ..][..N]`, its component c (1..=C) at `basis[(k (C+1) + c) N ..][..N]`; zero vectors for absent components |
//! | `cluster` | u16  | rows             | cluster id of each row; `K` (one past the last) marks an all-zero row |
//! | `coeffs`  | f32  | rows C           | row r's coefficient of component c at `coeffs[r C + c - 1]` (zeros for all-zero rows) |
//!
//! meta: `clusters` (K, after dropping empty clusters), `components` (C, capped at N).
//!
//! Gather: `P[k][c] = basis[k][c] . L` for all K (C + 1) vectors (RGB), then
//! `L*_r = P[k][0] + sum_c coeffs[r][c] P[k][c]` with `k = cluster[r]` (0 when `k = K`).
//! The CPU gather accumulates both in f64; the GPU gather (`gather.wgsl`) projects with one
//! workgroup per basis vector, then combines per row. Flops per monochrome gather:
//! `2 N K (C + 1) + 2 C (non-zero rows)`.

pub mod linalg;
mod params;
pub use params::{Cpca, CpcaUnit};

use crate::registry::{self, Kind};
use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::time::Instant;

/// Bytes per basis value at the peak of a build: the f32 assignment table, the f64 model
/// (mean or component) and the f32 stored basis.
const BYTES_PER_BASIS_VALUE: u64 = 4 + 8 + 4;

/// Largest model a build may hold (2 GiB); beyond, the request is refused with the estimate.
pub const MAX_CPCA_BYTES: u64 = 2 << 30;

fn build(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
    Ok(Box::new(registry::parse::<Cpca>(p)?.validated()?))
}

/// The registry entry.
pub const KIND: Kind = Kind {
    name: "cpca",
    about: "clustered PCA: `clusters` clusters of `components` principal components (lossy)",
    label: |p| {
        let c: Cpca = registry::parse(p)?;
        let label = registry::tagged_label(
            "cpca",
            &serde_json::to_value(c).unwrap(),
            &[("clusters", "k"), ("components", "c")],
        );
        Ok(match c.unit {
            CpcaUnit::Row => label,
            CpcaUnit::Vertex => label + "-vertex",
        })
    },
    check: |p| build(p).map(drop),
    build: |p| Ok(build(p)?),
};

/// `T` as plain CSR slices (row `r` is `indices/data[indptr[r]..indptr[r+1]]`).
struct Rows<'a> {
    indptr: &'a [usize],
    indices: &'a [usize],
    data: &'a [f32],
}

impl Rows<'_> {
    fn row(&self, r: usize) -> (&[usize], &[f32]) {
        let span = self.indptr[r]..self.indptr[r + 1];
        (&self.indices[span.clone()], &self.data[span])
    }
}

/// One cluster's affine model during the build (f64).
#[derive(Clone)]
struct Model {
    mean: Vec<f64>,
    /// `C` unit vectors of length N, row-major; all-zero rows are absent components.
    comps: Vec<f64>,
}

/// The f32 table all assignments read: `table[n * w + k (C+1) + c]` (c = 0 the mean), plus
/// the per-cluster constants of the error formula, computed from the f32 values.
struct Table {
    w: usize,
    table: Vec<f32>,
    mean_sq: Vec<f64>,
    /// `mean_dot[k * C + c] = mu_k . u_kc`.
    mean_dot: Vec<f64>,
}

impl Table {
    fn new(models: &[Model], n: usize, c: usize) -> Self {
        let w = models.len() * (c + 1);
        let mut table = vec![0.0f32; n * w];
        let (mut mean_sq, mut mean_dot) = (vec![0.0; models.len()], vec![0.0; models.len() * c]);
        for (k, m) in models.iter().enumerate() {
            let base = k * (c + 1);
            for i in 0..n {
                table[i * w + base] = m.mean[i] as f32;
                for j in 0..c {
                    table[i * w + base + 1 + j] = m.comps[j * n + i] as f32;
                }
            }
            for i in 0..n {
                let mu = table[i * w + base] as f64;
                mean_sq[k] += mu * mu;
                for j in 0..c {
                    mean_dot[k * c + j] += mu * table[i * w + base + 1 + j] as f64;
                }
            }
        }
        Self { w, table, mean_sq, mean_dot }
    }

    /// Best cluster of every listed row and its reconstruction error (ties: lower id).
    fn assign(&self, rows: &Rows<'_>, nz_rows: &[u32], sq_norm: &[f64], c: usize) -> (Vec<u32>, Vec<f64>) {
        let k_count = self.mean_sq.len();
        nz_rows
            .par_iter()
            .zip(sq_norm)
            .map_init(
                || vec![0.0f32; self.w],
                |acc, (&r, &sq)| {
                    acc.fill(0.0);
                    let (cols, vals) = rows.row(r as usize);
                    for (&col, &v) in cols.iter().zip(vals) {
                        let t = &self.table[col * self.w..(col + 1) * self.w];
                        for (a, &b) in acc.iter_mut().zip(t) {
                            *a += v * b;
                        }
                    }
                    let mut best = (0u32, f64::INFINITY);
                    for k in 0..k_count {
                        let base = k * (c + 1);
                        let mut e = sq - 2.0 * acc[base] as f64 + self.mean_sq[k];
                        for j in 0..c {
                            let p = acc[base + 1 + j] as f64 - self.mean_dot[k * c + j];
                            e -= p * p;
                        }
                        let e = e.max(0.0);
                        if e < best.1 {
                            best = (k as u32, e);
                        }
                    }
                    best
                },
            )
            .unzip()
    }
}

/// Deterministic random stream for (round, cluster).
fn stream(seed: u64, round: usize, cluster: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(((round as u64) << 32) | cluster as u64);
    rng
}

/// k-means++ seeding over the non-zero rows: the seed rows (at most `k`).
fn seed_rows(rows: &Rows<'_>, nz_rows: &[u32], sq_norm: &[f64], n: usize, k: usize, seed: u64) -> Vec<u32> {
    let mut rng = stream(seed, usize::MAX >> 32, usize::MAX >> 32);
    let mut seeds = vec![nz_rows[rng.gen_range(0..nz_rows.len())]];
    let mut d2 = vec![f64::INFINITY; nz_rows.len()];
    let mut dense = vec![0.0f64; n];
    while seeds.len() < k {
        let s = *seeds.last().unwrap() as usize;
        let (cols, vals) = rows.row(s);
        let mut s_sq = 0.0;
        for (&col, &v) in cols.iter().zip(vals) {
            dense[col] = v as f64;
            s_sq += v as f64 * v as f64;
        }
        d2.par_iter_mut().zip(nz_rows).zip(sq_norm).for_each(|((d, &r), &sq)| {
            let (cols, vals) = rows.row(r as usize);
            let dot: f64 = cols.iter().zip(vals).map(|(&col, &v)| v as f64 * dense[col]).sum();
            *d = d.min((sq + s_sq - 2.0 * dot).max(0.0));
        });
        for &col in cols {
            dense[col] = 0.0;
        }
        let total: f64 = d2.iter().sum();
        if total <= 0.0 {
            break; // every row coincides with a seed
        }
        let target = rng.gen::<f64>() * total;
        let mut acc = 0.0;
        let mut pick = None;
        for (i, &d) in d2.iter().enumerate() {
            if d > 0.0 {
                acc += d;
                pick = Some(i);
                if acc > target {
                    break;
                }
            }
        }
        seeds.push(nz_rows[pick.expect("total > 0 means some row has d2 > 0")]);
    }
    seeds
}

/// Mean and top `c` principal directions of the rows `members` (see the module doc, step 3).
fn fit(
    rows: &Rows<'_>,
    members: &[u32],
    prev: Option<&Model>,
    n: usize,
    c: usize,
    params: &Cpca,
    mut rng: ChaCha8Rng,
) -> Model {
    let count = members.len();
    let mut mean = vec![0.0f64; n];
    for &r in members {
        let (cols, vals) = rows.row(r as usize);
        for (&col, &v) in cols.iter().zip(vals) {
            mean[col] += v as f64;
        }
    }
    for m in &mut mean {
        *m /= count.max(1) as f64;
    }
    let mut comps = vec![0.0f64; c * n];
    if c == 0 || count <= 1 {
        return Model { mean, comps };
    }
    let l_rand = (c + params.oversampling).min(n);
    // Q: orthonormal columns (row-major n x l) spanning (an approximation of) the top
    // principal subspace.
    let (q, l) = if n <= l_rand {
        let mut q = vec![0.0; n * n];
        for i in 0..n {
            q[i * n + i] = 1.0;
        }
        (q, n)
    } else if count <= l_rand + 1 {
        // The centred rows span at most count - 1 <= l dimensions: use them.
        let l = count;
        let mut q = vec![0.0; n * l];
        for (j, &r) in members.iter().enumerate() {
            for i in 0..n {
                q[i * l + j] = -mean[i];
            }
            let (cols, vals) = rows.row(r as usize);
            for (&col, &v) in cols.iter().zip(vals) {
                q[col * l + j] += v as f64;
            }
        }
        linalg::orthonormalize_columns(&mut q, n, l, |_, col| col.fill(0.0));
        (q, l)
    } else {
        let l = l_rand;
        let mut q = vec![0.0; n * l];
        let mut warm = 0;
        if let Some(p) = prev {
            for j in 0..c {
                let u = &p.comps[j * n..(j + 1) * n];
                if u.iter().any(|&x| x != 0.0) {
                    for i in 0..n {
                        q[i * l + warm] = u[i];
                    }
                    warm += 1;
                }
            }
        }
        for i in 0..n {
            for j in warm..l {
                q[i * l + j] = rng.gen_range(-1.0..1.0);
            }
        }
        let mut fill = |_: usize, col: &mut [f64]| col.iter_mut().for_each(|x| *x = rng.gen_range(-1.0..1.0));
        linalg::orthonormalize_columns(&mut q, n, l, &mut fill);
        for _ in 0..params.power_iterations {
            let z = apply_a(rows, members, &mean, &q, n, l);
            q = apply_at(rows, members, &mean, &z, n, l);
            linalg::orthonormalize_columns(&mut q, n, l, &mut fill);
        }
        (q, l)
    };
    // Rayleigh-Ritz: eigenvectors of (A Q)^T (A Q) rotate Q onto the principal directions.
    let z = apply_a(rows, members, &mean, &q, n, l);
    let mut g = vec![0.0f64; l * l];
    for zr in z.chunks(l) {
        for a in 0..l {
            for b in a..l {
                g[a * l + b] += zr[a] * zr[b];
            }
        }
    }
    for a in 0..l {
        for b in 0..a {
            g[a * l + b] = g[b * l + a];
        }
    }
    let (values, vectors) = linalg::sym_eigen(&g, l);
    let top = values.first().copied().unwrap_or(0.0);
    for j in 0..c.min(l) {
        if values[j].is_nan() || values[j] <= 1e-13 * top {
            continue; // rank-deficient: no direction left
        }
        let u = &mut comps[j * n..(j + 1) * n];
        for i in 0..n {
            u[i] = (0..l).map(|a| q[i * l + a] * vectors[a * l + j]).sum();
        }
        let norm = u.iter().map(|x| x * x).sum::<f64>().sqrt();
        u.iter_mut().for_each(|x| *x /= norm);
    }
    Model { mean, comps }
}

/// `Z = A Q` (row-major members x l) with `A = X - 1 mu^T`, from the sparse rows.
fn apply_a(rows: &Rows<'_>, members: &[u32], mean: &[f64], q: &[f64], n: usize, l: usize) -> Vec<f64> {
    let mut mu_q = vec![0.0; l];
    for i in 0..n {
        for j in 0..l {
            mu_q[j] += mean[i] * q[i * l + j];
        }
    }
    let mut z = vec![0.0; members.len() * l];
    for (zr, &r) in z.chunks_mut(l).zip(members) {
        let (cols, vals) = rows.row(r as usize);
        for (&col, &v) in cols.iter().zip(vals) {
            for (a, &b) in zr.iter_mut().zip(&q[col * l..(col + 1) * l]) {
                *a += v as f64 * b;
            }
        }
        for (a, b) in zr.iter_mut().zip(&mu_q) {
            *a -= b;
        }
    }
    z
}

/// `Y = A^T Z` (row-major n x l) with `A = X - 1 mu^T`, from the sparse rows.
fn apply_at(rows: &Rows<'_>, members: &[u32], mean: &[f64], z: &[f64], n: usize, l: usize) -> Vec<f64> {
    let mut y = vec![0.0; n * l];
    let mut z_sum = vec![0.0; l];
    for (zr, &r) in z.chunks(l).zip(members) {
        let (cols, vals) = rows.row(r as usize);
        for (&col, &v) in cols.iter().zip(vals) {
            for (a, &b) in y[col * l..(col + 1) * l].iter_mut().zip(zr) {
                *a += v as f64 * b;
            }
        }
        for (a, b) in z_sum.iter_mut().zip(zr) {
            *a += b;
        }
    }
    for i in 0..n {
        for j in 0..l {
            y[i * l + j] -= mean[i] * z_sum[j];
        }
    }
    y
}

/// Row ids of every cluster, in increasing row order.
fn members_of(assign: &[u32], nz_rows: &[u32], k: usize) -> Vec<Vec<u32>> {
    let mut members = vec![vec![]; k];
    for (&a, &r) in assign.iter().zip(nz_rows) {
        members[a as usize].push(r);
    }
    members
}

impl Compressor for Cpca {
    registry::kind_and_params!();

    fn kernels(&self, form: &CompressedForm) -> Result<KernelDesc, CompressError> {
        let (k, c) = (|| Factor::Meta("clusters".into()), || Factor::MetaPlus("components".into(), 1));
        let u = || Factor::Meta("unit_rows".into());
        // One cluster id per unit: a row, or a vertex.
        let units = match form.meta("unit_rows")? {
            1 => Factor::Rows,
            x if x as usize == form.local_dirs() => Factor::Vertices,
            x => return Err(CompressError::malformed("cpca", "unit_rows", format!("is {x}, neither 1 nor M"))),
        };
        Ok(KernelDesc {
            kind: KIND.name.into(),
            wgsl: biscale_kernels::with_row_pass(include_str!("gather.wgsl")),
            passes: vec![
                // A workgroup of 64 per N-long basis segment (K (C + 1) U of them), then a row each.
                PassDesc { entry_point: "cpca_project".into(), threads: Count::of([k(), c(), u(), Factor::Const(64)]) },
                PassDesc { entry_point: biscale_kernels::ROW_ENTRY.into(), threads: Count::of([Factor::Rows]) },
            ],
            scratch: vec![ScratchDesc { name: "proj".into(), words: Count::of([k(), c(), u(), Factor::Const(3)]) }],
            meta_keys: vec!["clusters".into(), "components".into(), "unit_rows".into()],
            checks: vec![
                FormCheck::Len { array: "basis".into(), count: Count::of([k(), c(), u(), Factor::Cols]) },
                FormCheck::Len { array: "cluster".into(), count: Count::of([units.clone()]) },
                FormCheck::Len { array: "coeffs".into(), count: Count::of([units, Factor::Meta("components".into())]) },
                // Id K is the all-zero unit's sentinel.
                FormCheck::Below {
                    array: "cluster".into(),
                    bound: Count::of([Factor::MetaPlus("clusters".into(), 1)]),
                },
                FormCheck::Finite { array: "basis".into() },
                FormCheck::Finite { array: "coeffs".into() },
            ],
        })
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        self.check()?;
        // T is CSR with finite values by construction (TransferMatrix::new).
        let csr = t.csr();
        let indptr_view = csr.indptr();
        let indptr = indptr_view.to_proper();
        // The unit clustered: a row, or a vertex's M rows as one vector (row j's column k at
        // j N + k, still sorted).
        let unit_rows = match self.unit {
            CpcaUnit::Row => 1,
            CpcaUnit::Vertex => t.local_dirs(),
        };
        let (n, n_rows) = (t.cols() * unit_rows, t.rows() / unit_rows);
        let c = self.components.min(n);
        let bytes = (self.clusters * (c + 1)) as u64 * n as u64 * BYTES_PER_BASIS_VALUE;
        if bytes > MAX_CPCA_BYTES {
            return Err(CompressError::TooLarge(format!(
                "cpca: {} clusters x {} vectors of {n} values ({unit_rows} rows of {} per unit) need about {:.1} GiB to fit, over the {} GiB limit",
                self.clusters,
                c + 1,
                t.cols(),
                bytes as f64 / (1u64 << 30) as f64,
                MAX_CPCA_BYTES >> 30
            )));
        }
        let (unit_indices, unit_indptr): (Vec<usize>, Vec<usize>) = if unit_rows == 1 {
            (vec![], vec![])
        } else {
            let mut idx = Vec::with_capacity(csr.nnz());
            let mut ptr = Vec::with_capacity(n_rows + 1);
            ptr.push(0);
            for u in 0..n_rows {
                for j in 0..unit_rows {
                    let r = u * unit_rows + j;
                    idx.extend(csr.indices()[indptr[r]..indptr[r + 1]].iter().map(|&k| j * t.cols() + k));
                }
                ptr.push(idx.len());
            }
            (idx, ptr)
        };
        let rows = match unit_rows {
            1 => Rows { indptr: &indptr, indices: csr.indices(), data: csr.data() },
            _ => Rows { indptr: &unit_indptr, indices: &unit_indices, data: csr.data() },
        };
        let nz_rows: Vec<u32> =
            (0..n_rows).filter(|&r| rows.row(r).1.iter().any(|&v| v != 0.0)).map(|r| r as u32).collect();
        if n_rows > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("cpca: {n_rows} rows")));
        }
        let sq_norm: Vec<f64> =
            nz_rows.iter().map(|&r| rows.row(r as usize).1.iter().map(|&v| v as f64 * v as f64).sum()).collect();

        let mut models: Vec<Model> = vec![];
        let mut assign: Vec<u32> = vec![];
        let mut table = Table::new(&models, n, c);
        if !nz_rows.is_empty() {
            for s in seed_rows(&rows, &nz_rows, &sq_norm, n, self.clusters, ctx.seed) {
                let mut mean = vec![0.0; n];
                let (cols, vals) = rows.row(s as usize);
                for (&col, &v) in cols.iter().zip(vals) {
                    mean[col] = v as f64;
                }
                models.push(Model { mean, comps: vec![0.0; c * n] });
            }
            table = Table::new(&models, n, c);
            let mut converged = false;
            for round in 0..self.iterations {
                let (new_assign, err) = table.assign(&rows, &nz_rows, &sq_norm, c);
                let changed = if assign.is_empty() {
                    nz_rows.len()
                } else {
                    new_assign.iter().zip(&assign).filter(|(a, b)| a != b).count()
                };
                assign = new_assign;
                if round > 0 && changed == 0 {
                    converged = true; // the models were fit to exactly this assignment
                    break;
                }
                // Re-seed empty clusters with the worst-fit rows of clusters that keep a row.
                let mut counts = vec![0usize; models.len()];
                assign.iter().for_each(|&a| counts[a as usize] += 1);
                let empty: Vec<usize> = (0..models.len()).filter(|&k| counts[k] == 0).collect();
                if !empty.is_empty() {
                    let mut worst: Vec<usize> = (0..nz_rows.len()).filter(|&i| err[i] > 0.0).collect();
                    worst.sort_by(|&a, &b| err[b].total_cmp(&err[a]).then(a.cmp(&b)));
                    let mut worst = worst.into_iter();
                    for &k in &empty {
                        for i in worst.by_ref() {
                            if counts[assign[i] as usize] > 1 {
                                counts[assign[i] as usize] -= 1;
                                assign[i] = k as u32;
                                counts[k] += 1;
                                break;
                            }
                        }
                    }
                    // Drop clusters that stayed empty and renumber.
                    let keep: Vec<usize> = (0..models.len()).filter(|&k| counts[k] > 0).collect();
                    let mut new_id = vec![u32::MAX; models.len()];
                    keep.iter().enumerate().for_each(|(i, &k)| new_id[k] = i as u32);
                    assign.iter_mut().for_each(|a| *a = new_id[*a as usize]);
                    models = keep.iter().map(|&k| models[k].clone()).collect();
                }
                let members = members_of(&assign, &nz_rows, models.len());
                models = (0..models.len())
                    .into_par_iter()
                    .map(|k| fit(&rows, &members[k], Some(&models[k]), n, c, self, stream(ctx.seed, round, k)))
                    .collect();
                table = Table::new(&models, n, c);
                ctx.report((round + 1) as f64 / (self.iterations + 1) as f64);
            }
            if !converged {
                assign = table.assign(&rows, &nz_rows, &sq_norm, c).0;
            }
        }

        // Compact away empty clusters; coefficients against the stored f32 basis.
        let mut counts = vec![0usize; models.len()];
        assign.iter().for_each(|&a| counts[a as usize] += 1);
        let keep: Vec<usize> = (0..models.len()).filter(|&k| counts[k] > 0).collect();
        let k_out = keep.len();
        let mut new_id = vec![u16::MAX; models.len()];
        keep.iter().enumerate().for_each(|(i, &k)| new_id[k] = i as u16);
        let mut basis = vec![0.0f32; k_out * (c + 1) * n];
        for (i, &k) in keep.iter().enumerate() {
            for j in 0..=c {
                let dst = &mut basis[(i * (c + 1) + j) * n..(i * (c + 1) + j + 1) * n];
                for (x, d) in dst.iter_mut().enumerate() {
                    *d = table.table[x * table.w + k * (c + 1) + j];
                }
            }
        }
        let mut cluster = vec![k_out as u16; n_rows];
        let mut coeffs = vec![0.0f32; n_rows * c];
        let nz_coeffs: Vec<Vec<f32>> = nz_rows
            .par_iter()
            .zip(&assign)
            .map(|(&r, &k)| {
                let k = k as usize;
                let mut acc = vec![0.0f64; c];
                let (cols, vals) = rows.row(r as usize);
                for (&col, &v) in cols.iter().zip(vals) {
                    let t = &table.table[col * table.w + k * (c + 1) + 1..col * table.w + (k + 1) * (c + 1)];
                    for (a, &b) in acc.iter_mut().zip(t) {
                        *a += v as f64 * b as f64;
                    }
                }
                acc.iter().enumerate().map(|(j, a)| (a - table.mean_dot[k * c + j]) as f32).collect()
            })
            .collect();
        for ((&r, &k), co) in nz_rows.iter().zip(&assign).zip(nz_coeffs) {
            cluster[r as usize] = new_id[k as usize];
            coeffs[r as usize * c..(r as usize + 1) * c].copy_from_slice(&co);
        }
        ctx.report(1.0);
        let exact = nz_rows.is_empty();
        let mut form = CompressedForm::new(KIND.name, t.shape());
        form.arrays = vec![
            NamedArray { name: "basis".into(), data: ArrayData::F32(basis) },
            NamedArray { name: "cluster".into(), data: ArrayData::U16(cluster) },
            NamedArray { name: "coeffs".into(), data: ArrayData::F32(coeffs) },
        ];
        form.meta = [
            ("clusters".to_string(), k_out as u64),
            ("components".into(), c as u64),
            ("unit_rows".into(), unit_rows as u64),
        ]
        .into_iter()
        .collect();
        form.lossless = exact;
        form.flops_per_gather = 2 * (n * k_out * (c + 1)) as u64 + 2 * (c * nz_rows.len() * unit_rows) as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        let (k, c, n) = (form.meta("clusters")? as usize, form.meta("components")? as usize, form.cols());
        let u = unit_rows(form)?;
        let basis = form.f32s("basis")?;
        let cluster = form.u16s("cluster")?;
        let coeffs = form.f32s("coeffs")?;
        let units = form.rows() / u;
        if basis.len() != k * (c + 1) * u * n
            || cluster.len() != units
            || coeffs.len() != units * c
            || cluster.iter().any(|&id| id as usize > k)
        {
            return Err(CompressError::malformed("cpca", "cluster", "lengths or ids do not match the shape"));
        }
        // Projections of the light on every mean and component segment (f64: a sun may sit
        // beside a dim sky in L, and the components have both signs). The light is laid out
        // per channel, and each dot product keeps four partial sums per channel: one running
        // sum would chain every f64 add on the one before (4 cycles each), and the compiler may
        // not reorder float sums itself. Each projection is stored as RGB padded to four f64
        // lanes, so the per-row combination below is two packed multiply-adds per term.
        // Segment `(v (C + 1) + c) U + j` is row j of cluster v's vector c.
        let channels: [Vec<f64>; 3] = std::array::from_fn(|ch| light.power.iter().map(|l| l[ch] as f64).collect());
        let proj: Vec<[f64; 4]> = basis
            .par_chunks(n.max(1))
            .take(k * (c + 1) * u)
            .map(|b| {
                let [x, y, z] = split_dot(b, &channels);
                [x, y, z, 0.0]
            })
            .collect();
        let values: Vec<[f32; 3]> = (0..form.rows())
            .into_par_iter()
            .map(|r| {
                let (unit, j) = (r / u, r % u);
                let id = cluster[unit] as usize;
                if id == k {
                    return [0.0; 3];
                }
                let segment = |v: usize| &proj[(id * (c + 1) + v) * u + j];
                let mut acc = *segment(0);
                for (v, &w) in coeffs[unit * c..(unit + 1) * c].iter().enumerate() {
                    let pj = segment(v + 1);
                    for ch in 0..4 {
                        acc[ch] += w as f64 * pj[ch];
                    }
                }
                [acc[0] as f32, acc[1] as f32, acc[2] as f32]
            })
            .collect();
        form.lstar(values)
    }
}

/// Rows per clustered unit of a form (1, or M for vertex units).
fn unit_rows(form: &CompressedForm) -> Result<usize, CompressError> {
    match form.meta("unit_rows")? as usize {
        1 => Ok(1),
        m if m == form.local_dirs() => Ok(m),
        m => Err(CompressError::malformed("cpca", "unit_rows", format!("is {m}, neither 1 nor M"))),
    }
}

/// `||T - T~||_F / ||T||_F`: the relative Frobenius error of the rows `form` stands for (the
/// quantity CPCA minimises), without decoding dense rows: per row
/// `||x - r||^2 = ||x||^2 - 2 x.r + ||r||^2` with `r = B_kj w` (`w = (1, coeffs)` of the row's
/// unit, `B_kj` the unit's cluster's segment for the row) and `||r||^2 = w^T (B_kj B_kj^T) w`
/// from each segment's (C+1) x (C+1) Gram matrix. f64 throughout; the expansion loses about
/// `eps ||x||^2` absolute per row (fine for a diagnostic; 0 when `T` is 0).
pub fn relative_frobenius_error(form: &CompressedForm, t: &TransferMatrix) -> Result<f64, CompressError> {
    let (k, c, n) = (form.meta("clusters")? as usize, form.meta("components")? as usize, form.cols());
    let u = unit_rows(form)?;
    let (basis, cluster, coeffs) = (form.f32s("basis")?, form.u16s("cluster")?, form.f32s("coeffs")?);
    let units = form.rows() / u;
    if form.rows() != t.rows()
        || n != t.cols()
        || basis.len() != k * (c + 1) * u * n
        || cluster.len() != units
        || coeffs.len() != units * c
    {
        return Err(CompressError::malformed("cpca", "basis", "does not match T"));
    }
    let w = c + 1;
    // Segment of cluster `id`'s vector `v` for row `j` of a unit.
    let seg = |id: usize, v: usize, j: usize| &basis[((id * w + v) * u + j) * n..((id * w + v) * u + j + 1) * n];
    let gram: Vec<f64> = (0..k * u)
        .into_par_iter()
        .flat_map_iter(|kj| {
            let (id, j) = (kj / u, kj % u);
            (0..w * w).map(move |ab| {
                seg(id, ab / w, j).iter().zip(seg(id, ab % w, j)).map(|(&x, &y)| x as f64 * y as f64).sum::<f64>()
            })
        })
        .collect();
    let csr = t.csr();
    let (num, den) = (0..form.rows())
        .into_par_iter()
        .map(|r| {
            let row = csr.outer_view(r).expect("row in range");
            let x_sq: f64 = row.data().iter().map(|&v| v as f64 * v as f64).sum();
            let (unit, j) = (r / u, r % u);
            let id = cluster[unit] as usize;
            if id >= k {
                return (x_sq, x_sq);
            }
            let mut wv = vec![1.0f64; w];
            for v in 0..c {
                wv[v + 1] = coeffs[unit * c + v] as f64;
            }
            let mut x_r = 0.0;
            for (col, &x) in row.iter() {
                let rec: f64 = (0..w).map(|v| wv[v] * seg(id, v, j)[col] as f64).sum();
                x_r += x as f64 * rec;
            }
            let g = &gram[(id * u + j) * w * w..(id * u + j + 1) * w * w];
            let r_sq: f64 = (0..w).map(|a| (0..w).map(|b| wv[a] * g[a * w + b] * wv[b]).sum::<f64>()).sum();
            ((x_sq - 2.0 * x_r + r_sq).max(0.0), x_sq)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok(if den > 0.0 { (num / den).sqrt() } else { 0.0 })
}

/// `sum_i b_i l_i` in f64 for the three channels of `l` at once (`b` is read and widened
/// once), with four partial sums per channel: element `i` goes to sum `i % 4`, the four added
/// `(0 + 1) + (2 + 3)`, so consecutive adds do not wait on each other.
fn split_dot(b: &[f32], l: &[Vec<f64>; 3]) -> [f64; 3] {
    let mut acc = [[0.0f64; 4]; 3];
    let n = b.len().min(l[0].len()).min(l[1].len()).min(l[2].len());
    let (b, l) = (&b[..n], [&l[0][..n], &l[1][..n], &l[2][..n]]);
    let whole = n / 4 * 4;
    for i in (0..whole).step_by(4) {
        let x: [f64; 4] = std::array::from_fn(|e| b[i + e] as f64);
        for ch in 0..3 {
            let y = &l[ch][i..i + 4];
            for e in 0..4 {
                acc[ch][e] += x[e] * y[e];
            }
        }
    }
    for i in whole..n {
        for ch in 0..3 {
            acc[ch][i - whole] += b[i] as f64 * l[ch][i];
        }
    }
    acc.map(|a| (a[0] + a[1]) + (a[2] + a[3]))
}

#[cfg(test)]
mod tests;
