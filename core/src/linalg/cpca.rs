//! Clustered principal component analysis (Sloan, Hall, Hart, Snyder 2003, "Clustered principal
//! components for precomputed radiance transfer", section 3: iterative CPCA) of a set of rows,
//! sparse or dense ([`RowSet`]). The transfer compressor `cpca` clusters the rows (or per-vertex
//! blocks) of `T`; local-PCA BTFs (Müller, Meseth, Klein 2004) cluster the apparent BRDFs of a
//! BTF's texels. Rows that are entirely zero get no cluster.
//!
//! 1. **Seeding**: k-means++ (Arthur & Vassilvitskii 2007) on the non-zero rows: each seed is
//!    drawn with probability proportional to the squared distance to the nearest seed so far.
//!    Seeding stops early when every row coincides with a seed (so K may shrink: more clusters
//!    than distinct rows is fine). Each seed starts as a cluster with that row as mean and no
//!    components.
//! 2. **Assignment**: every row goes to the cluster whose affine model reconstructs it best:
//!    `err_k(x) = ||x - mu_k||^2 - sum_c ((x - mu_k) . u_kc)^2`, expanded so that only the
//!    row's stored entries are touched: `||x||^2 - 2 x.mu + ||mu||^2 - sum_c (x.u_c - mu.u_c)^2`.
//!    All K (C + 1) dot products of a row are one pass over its entries through an
//!    N x K(C + 1) f32 table (contiguous per entry). The dot products use f32 (rows against
//!    unit-norm vectors: relative error ~1e-6 per term, which only matters for rows two clusters
//!    fit equally well); the error itself is combined in f64.
//! 3. **Refit**: each cluster's mean and its top C principal directions of the centred rows
//!    `A = X - 1 mu^T`, never formed: `A Q = X Q - 1 (mu^T Q)` and `A^T Z = X^T Z - mu (1^T Z)`
//!    on the stored rows, in the cluster's support (the columns its rows store: `A` is zero in
//!    the others, and so are the mean and every direction). Randomised subspace iteration (Halko, Martinsson, Tropp 2011,
//!    Algorithm 4.4) with `l = C + oversampling` columns, warm-started from the cluster's
//!    previous components, `power_iterations` rounds of `Q <- orth(A^T A Q)`, then Rayleigh-Ritz:
//!    the eigen-decomposition of the l x l matrix `(A Q)^T (A Q)` (Jacobi, [`super::eigen`]).
//!    A cluster whose centred rows span at most `l` dimensions (fewer rows than `l + 1`, or a
//!    support of at most `l` columns) uses those rows (or the identity) as `Q`, which makes its
//!    PCA exact. Directions with a Ritz value below 1e-13 of the largest (rank-deficient
//!    clusters) are stored as zero components.
//! 4. Empty clusters are re-seeded with the worst-fit rows (largest `err`) taken from clusters
//!    that keep at least one row; a cluster that cannot be re-seeded (every row is fit exactly)
//!    is dropped. Rounds stop after `iterations` or when no row changes cluster.
//! 5. A final assignment with the final models, coefficients `c = U (x - mu)` accumulated in
//!    f64 against the stored (f32) basis, and clusters left empty are removed.
//!
//! Every reduction runs in a fixed order (per cluster, or per row), so the same seed gives the
//! same result on any number of threads.

use super::eigen;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Rows to cluster: `count` rows of `dim` values, each visited through its stored entries.
pub trait RowSet: Sync {
    fn count(&self) -> usize;
    fn dim(&self) -> usize;
    /// `f(column, value)` for every stored entry of row `r`, in increasing column order.
    fn for_each(&self, r: usize, f: impl FnMut(usize, f32));
    /// Row `r` as a dense slice of `dim` values, when the set stores it so (the assignment
    /// then streams its table once per block of rows instead of once per row).
    fn dense(&self, _r: usize) -> Option<&[f32]> {
        None
    }
}

/// CSR rows: row `r` is `indices/data[indptr[r]..indptr[r + 1]]`, columns sorted.
pub struct SparseRows<'a> {
    pub dim: usize,
    pub indptr: &'a [usize],
    pub indices: &'a [usize],
    pub data: &'a [f32],
}

impl RowSet for SparseRows<'_> {
    fn count(&self) -> usize {
        self.indptr.len().saturating_sub(1)
    }
    fn dim(&self) -> usize {
        self.dim
    }
    #[inline]
    fn for_each(&self, r: usize, mut f: impl FnMut(usize, f32)) {
        let span = self.indptr[r]..self.indptr[r + 1];
        for (&c, &v) in self.indices[span.clone()].iter().zip(&self.data[span]) {
            f(c, v);
        }
    }
}

/// Dense rows: row `r` is `data[r * dim..(r + 1) * dim]`.
pub struct DenseRows<'a> {
    pub dim: usize,
    pub data: &'a [f32],
}

impl RowSet for DenseRows<'_> {
    fn count(&self) -> usize {
        self.data.len().checked_div(self.dim).unwrap_or(0)
    }
    fn dim(&self) -> usize {
        self.dim
    }
    #[inline]
    fn for_each(&self, r: usize, mut f: impl FnMut(usize, f32)) {
        for (c, &v) in self.data[r * self.dim..(r + 1) * self.dim].iter().enumerate() {
            f(c, v);
        }
    }
    fn dense(&self, r: usize) -> Option<&[f32]> {
        Some(&self.data[r * self.dim..(r + 1) * self.dim])
    }
}

/// Rows per block of the dense assignment.
const DENSE_BLOCK: usize = 8;

/// Bytes per basis value at the peak of a build: the f32 assignment table, the f64 model (mean
/// or component) and the f32 stored basis.
pub const BUILD_BYTES_PER_BASIS_VALUE: u64 = 4 + 8 + 4;

/// Largest model a build may hold (2 GiB); callers refuse larger requests up front with the
/// estimate of [`build_bytes`].
pub const MAX_BUILD_BYTES: u64 = 2 << 30;

/// Peak bytes of the model of a build of `clusters` clusters with `components` components (capped
/// at `dim`, as the build does) over vectors of `dim` values.
pub fn build_bytes(clusters: usize, components: usize, dim: usize) -> u64 {
    (clusters * (components.min(dim) + 1)) as u64 * dim as u64 * BUILD_BYTES_PER_BASIS_VALUE
}

/// The build's settings (the CPCA compressor's keys; see there for their defaults).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CpcaSettings {
    /// Clusters K to seed (fewer come out when the rows have fewer distinct values).
    pub clusters: usize,
    /// Components C per cluster besides the mean (capped at the dimension).
    pub components: usize,
    /// Most assignment/refit rounds, at least 1.
    pub iterations: usize,
    /// Subspace iterations per refit.
    pub power_iterations: usize,
    /// Extra columns of the randomised subspace beyond C.
    pub oversampling: usize,
}

/// The result: K clusters of a mean and C components each, and per row its cluster and its C
/// coefficients.
#[derive(Clone, Debug, PartialEq)]
pub struct ClusteredPca {
    /// N, the length of every vector.
    pub dim: usize,
    /// K after dropping empty clusters.
    pub clusters: usize,
    /// C (the settings' components capped at N).
    pub components: usize,
    /// Cluster k's mean at `basis[(k (C+1)) N..][..N]`, its component c (1..=C) at
    /// `basis[(k (C+1) + c) N..][..N]`; zero vectors for absent components.
    pub basis: Vec<f32>,
    /// Cluster of every row; `K` (one past the last) marks an all-zero row.
    pub cluster: Vec<u32>,
    /// Row r's coefficient of component c at `coeffs[r C + c - 1]` (zeros for all-zero rows).
    pub coeffs: Vec<f32>,
    /// Rows that are not all zero.
    pub nonzero_rows: usize,
}

impl ClusteredPca {
    /// Row `r` reconstructed, in f64 (for tests and error measures).
    pub fn decode_row(&self, r: usize) -> Vec<f64> {
        let (n, c) = (self.dim, self.components);
        let k = self.cluster[r] as usize;
        if k == self.clusters {
            return vec![0.0; n];
        }
        let vec_of = |j: usize| &self.basis[(k * (c + 1) + j) * n..(k * (c + 1) + j + 1) * n];
        let mut out: Vec<f64> = vec_of(0).iter().map(|&x| x as f64).collect();
        for j in 1..=c {
            let w = self.coeffs[r * c + j - 1] as f64;
            for (o, &u) in out.iter_mut().zip(vec_of(j)) {
                *o += w * u as f64;
            }
        }
        out
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

    /// The best cluster and its error for a row whose dot products with every table column
    /// are `acc` (ties: lower id).
    fn best(&self, acc: &[f32], sq: f64, c: usize) -> (u32, f64) {
        let mut best = (0u32, f64::INFINITY);
        for k in 0..self.mean_sq.len() {
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
    }

    /// Best cluster of every listed row and its reconstruction error (ties: lower id).
    fn assign<R: RowSet>(&self, rows: &R, nz_rows: &[u32], sq_norm: &[f64], c: usize) -> (Vec<u32>, Vec<f64>) {
        if nz_rows.first().is_some_and(|&r| rows.dense(r as usize).is_some()) {
            return self.assign_dense(rows, nz_rows, sq_norm, c);
        }
        nz_rows
            .par_iter()
            .zip(sq_norm)
            .map_init(
                || vec![0.0f32; self.w],
                |acc, (&r, &sq)| {
                    acc.fill(0.0);
                    rows.for_each(r as usize, |col, v| {
                        let t = &self.table[col * self.w..(col + 1) * self.w];
                        for (a, &b) in acc.iter_mut().zip(t) {
                            *a += v * b;
                        }
                    });
                    self.best(acc, sq, c)
                },
            )
            .unzip()
    }

    /// [`Self::assign`] for dense rows: blocks of [`DENSE_BLOCK`] rows share each pass over
    /// the table (N x K(C+1) f32, tens of MB for a BTF), and each row's sums run in the same
    /// column order as the one-row loop, so the result is the same.
    fn assign_dense<R: RowSet>(&self, rows: &R, nz_rows: &[u32], sq_norm: &[f64], c: usize) -> (Vec<u32>, Vec<f64>) {
        let w = self.w;
        let blocks: Vec<Vec<(u32, f64)>> = nz_rows
            .par_chunks(DENSE_BLOCK)
            .zip(sq_norm.par_chunks(DENSE_BLOCK))
            .map(|(block, sqs)| {
                let slices: Vec<&[f32]> =
                    block.iter().map(|&r| rows.dense(r as usize).expect("a dense row set")).collect();
                let mut acc = vec![0.0f32; block.len() * w];
                for (col, t) in self.table.chunks_exact(w.max(1)).enumerate().take(rows.dim()) {
                    for (b, row) in slices.iter().enumerate() {
                        let v = row[col];
                        if v != 0.0 {
                            for (a, &x) in acc[b * w..(b + 1) * w].iter_mut().zip(t) {
                                *a += v * x;
                            }
                        }
                    }
                }
                (0..block.len()).map(|b| self.best(&acc[b * w..(b + 1) * w], sqs[b], c)).collect()
            })
            .collect();
        blocks.into_iter().flatten().unzip()
    }
}

/// Deterministic random stream for (round, cluster).
fn stream(seed: u64, round: usize, cluster: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(((round as u64) << 32) | cluster as u64);
    rng
}

/// k-means++ seeding over the non-zero rows: the seed rows (at most `k`).
fn seed_rows<R: RowSet>(rows: &R, nz_rows: &[u32], sq_norm: &[f64], k: usize, seed: u64) -> Vec<u32> {
    let n = rows.dim();
    let mut rng = stream(seed, usize::MAX >> 32, usize::MAX >> 32);
    let mut seeds = vec![nz_rows[rng.gen_range(0..nz_rows.len())]];
    let mut d2 = vec![f64::INFINITY; nz_rows.len()];
    let mut dense = vec![0.0f64; n];
    let mut touched = vec![];
    while seeds.len() < k {
        let s = *seeds.last().unwrap() as usize;
        let mut s_sq = 0.0;
        touched.clear();
        rows.for_each(s, |col, v| {
            dense[col] = v as f64;
            s_sq += v as f64 * v as f64;
            touched.push(col);
        });
        d2.par_iter_mut().zip(nz_rows).zip(sq_norm).for_each(|((d, &r), &sq)| {
            let mut dot = 0.0f64;
            rows.for_each(r as usize, |col, v| dot += v as f64 * dense[col]);
            *d = d.min((sq + s_sq - 2.0 * dot).max(0.0));
        });
        for &col in &touched {
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

/// Mean and top `c` principal directions of the rows `members` (module doc, step 3).
/// The rows of a cluster seen through its support: column `col` of `rows` is column
/// `index[col]` here (increasing, so entries stay sorted), `dim` columns in all.
struct Supported<'a, R> {
    rows: &'a R,
    index: &'a [u32],
    dim: usize,
}

impl<R: RowSet> RowSet for Supported<'_, R> {
    fn count(&self) -> usize {
        self.rows.count()
    }
    fn dim(&self) -> usize {
        self.dim
    }
    fn for_each(&self, r: usize, mut f: impl FnMut(usize, f32)) {
        self.rows.for_each(r, |col, v| f(self.index[col] as usize, v))
    }
}

/// The model of one cluster ([`fit_in`]), computed on its support: the columns any member
/// stores. The centred rows `A = X - 1 mu^T` are zero in every other column, so the mean and
/// every principal direction are too, and the subspace iteration's `N x l` work shrinks to
/// the support's size (a cluster of a few vertices touches a small share of `T`'s columns).
fn fit<R: RowSet>(
    rows: &R,
    members: &[u32],
    prev: Option<&Model>,
    c: usize,
    settings: &CpcaSettings,
    rng: ChaCha8Rng,
) -> Model {
    let n = rows.dim();
    let mut index = vec![u32::MAX; n];
    let mut support: Vec<u32> = vec![];
    for &r in members {
        rows.for_each(r as usize, |col, _| {
            if index[col] == u32::MAX {
                index[col] = 0;
                support.push(col as u32);
            }
        });
    }
    support.sort_unstable();
    for (i, &col) in support.iter().enumerate() {
        index[col as usize] = i as u32;
    }
    let s = support.len();
    let gather = |full: &[f64]| -> Vec<f64> { support.iter().map(|&col| full[col as usize]).collect() };
    let prev = prev.map(|p| Model {
        mean: gather(&p.mean),
        comps: (0..c).flat_map(|j| gather(&p.comps[j * n..(j + 1) * n])).collect(),
    });
    let compact = Supported { rows, index: &index, dim: s };
    let m = fit_in(&compact, members, prev.as_ref(), c, settings, rng);
    let (mut mean, mut comps) = (vec![0.0f64; n], vec![0.0f64; c * n]);
    for (i, &col) in support.iter().enumerate() {
        mean[col as usize] = m.mean[i];
        for j in 0..c {
            comps[j * n + col as usize] = m.comps[j * s + i];
        }
    }
    Model { mean, comps }
}

/// The mean and top `c` principal directions of the `members` of `rows` (module docs, step 3).
fn fit_in<R: RowSet>(
    rows: &R,
    members: &[u32],
    prev: Option<&Model>,
    c: usize,
    settings: &CpcaSettings,
    mut rng: ChaCha8Rng,
) -> Model {
    let n = rows.dim();
    let count = members.len();
    let mut mean = vec![0.0f64; n];
    for &r in members {
        rows.for_each(r as usize, |col, v| mean[col] += v as f64);
    }
    for m in &mut mean {
        *m /= count.max(1) as f64;
    }
    let mut comps = vec![0.0f64; c * n];
    if c == 0 || count <= 1 {
        return Model { mean, comps };
    }
    let l_rand = (c + settings.oversampling).min(n);
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
            rows.for_each(r as usize, |col, v| q[col * l + j] += v as f64);
        }
        eigen::orthonormalize_columns(&mut q, n, l, |_, col| col.fill(0.0));
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
        eigen::orthonormalize_columns(&mut q, n, l, &mut fill);
        for _ in 0..settings.power_iterations {
            let z = apply_a(rows, members, &mean, &q, l);
            q = apply_at(rows, members, &mean, &z, l);
            eigen::orthonormalize_columns(&mut q, n, l, &mut fill);
        }
        (q, l)
    };
    // Rayleigh-Ritz: eigenvectors of (A Q)^T (A Q) rotate Q onto the principal directions.
    let z = apply_a(rows, members, &mean, &q, l);
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
    let (values, vectors) = eigen::sym_eigen(&g, l);
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

/// `Z = A Q` (row-major members x l) with `A = X - 1 mu^T`, from the stored rows.
fn apply_a<R: RowSet>(rows: &R, members: &[u32], mean: &[f64], q: &[f64], l: usize) -> Vec<f64> {
    let n = rows.dim();
    let mut mu_q = vec![0.0; l];
    for i in 0..n {
        for j in 0..l {
            mu_q[j] += mean[i] * q[i * l + j];
        }
    }
    let mut z = vec![0.0; members.len() * l];
    for (zr, &r) in z.chunks_mut(l).zip(members) {
        rows.for_each(r as usize, |col, v| {
            for (a, &b) in zr.iter_mut().zip(&q[col * l..(col + 1) * l]) {
                *a += v as f64 * b;
            }
        });
        for (a, b) in zr.iter_mut().zip(&mu_q) {
            *a -= b;
        }
    }
    z
}

/// `Y = A^T Z` (row-major n x l) with `A = X - 1 mu^T`, from the stored rows.
fn apply_at<R: RowSet>(rows: &R, members: &[u32], mean: &[f64], z: &[f64], l: usize) -> Vec<f64> {
    let n = rows.dim();
    let mut y = vec![0.0; n * l];
    let mut z_sum = vec![0.0; l];
    for (zr, &r) in z.chunks(l).zip(members) {
        rows.for_each(r as usize, |col, v| {
            for (a, &b) in y[col * l..(col + 1) * l].iter_mut().zip(zr) {
                *a += v as f64 * b;
            }
        });
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

/// Clustered PCA of `rows` (module docs). `progress` is called with the fraction done.
/// The caller checks the sizes first (the model holds about `16 K (C + 1) N` bytes at its peak);
/// `settings.clusters` and `settings.iterations` must be at least 1.
pub fn clustered_pca<R: RowSet>(rows: &R, settings: &CpcaSettings, seed: u64, progress: &dyn Fn(f64)) -> ClusteredPca {
    let (n, n_rows) = (rows.dim(), rows.count());
    let c = settings.components.min(n);
    let nz_rows: Vec<u32> = (0..n_rows)
        .filter(|&r| {
            let mut any = false;
            rows.for_each(r, |_, v| any |= v != 0.0);
            any
        })
        .map(|r| r as u32)
        .collect();
    let sq_norm: Vec<f64> = nz_rows
        .par_iter()
        .map(|&r| {
            let mut s = 0.0f64;
            rows.for_each(r as usize, |_, v| s += v as f64 * v as f64);
            s
        })
        .collect();

    let mut models: Vec<Model> = vec![];
    let mut assign: Vec<u32> = vec![];
    let mut table = Table::new(&models, n, c);
    if !nz_rows.is_empty() {
        for s in seed_rows(rows, &nz_rows, &sq_norm, settings.clusters.max(1), seed) {
            let mut mean = vec![0.0; n];
            rows.for_each(s as usize, |col, v| mean[col] = v as f64);
            models.push(Model { mean, comps: vec![0.0; c * n] });
        }
        table = Table::new(&models, n, c);
        let mut converged = false;
        let iterations = settings.iterations.max(1);
        for round in 0..iterations {
            let (new_assign, err) = table.assign(rows, &nz_rows, &sq_norm, c);
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
                .map(|k| fit(rows, &members[k], Some(&models[k]), c, settings, stream(seed, round, k)))
                .collect();
            table = Table::new(&models, n, c);
            progress((round + 1) as f64 / (iterations + 1) as f64);
        }
        if !converged {
            assign = table.assign(rows, &nz_rows, &sq_norm, c).0;
        }
    }

    // Compact away empty clusters; coefficients against the stored f32 basis.
    let mut counts = vec![0usize; models.len()];
    assign.iter().for_each(|&a| counts[a as usize] += 1);
    let keep: Vec<usize> = (0..models.len()).filter(|&k| counts[k] > 0).collect();
    let k_out = keep.len();
    let mut new_id = vec![u32::MAX; models.len()];
    keep.iter().enumerate().for_each(|(i, &k)| new_id[k] = i as u32);
    let mut basis = vec![0.0f32; k_out * (c + 1) * n];
    for (i, &k) in keep.iter().enumerate() {
        for j in 0..=c {
            let dst = &mut basis[(i * (c + 1) + j) * n..(i * (c + 1) + j + 1) * n];
            for (x, d) in dst.iter_mut().enumerate() {
                *d = table.table[x * table.w + k * (c + 1) + j];
            }
        }
    }
    let mut cluster = vec![k_out as u32; n_rows];
    let mut coeffs = vec![0.0f32; n_rows * c];
    let nz_coeffs: Vec<Vec<f32>> = nz_rows
        .par_iter()
        .zip(&assign)
        .map(|(&r, &k)| {
            let k = k as usize;
            let mut acc = vec![0.0f64; c];
            rows.for_each(r as usize, |col, v| {
                let t = &table.table[col * table.w + k * (c + 1) + 1..col * table.w + (k + 1) * (c + 1)];
                for (a, &b) in acc.iter_mut().zip(t) {
                    *a += v as f64 * b as f64;
                }
            });
            acc.iter().enumerate().map(|(j, a)| (a - table.mean_dot[k * c + j]) as f32).collect()
        })
        .collect();
    for ((&r, &k), co) in nz_rows.iter().zip(&assign).zip(nz_coeffs) {
        cluster[r as usize] = new_id[k as usize];
        coeffs[r as usize * c..(r as usize + 1) * c].copy_from_slice(&co);
    }
    progress(1.0);
    ClusteredPca { dim: n, clusters: k_out, components: c, basis, cluster, coeffs, nonzero_rows: nz_rows.len() }
}
