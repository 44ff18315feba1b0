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
//! # Build
//!
//! Sloan et al.'s iterative CPCA, shared with local-PCA BTFs:
//! [`biscale_core::linalg::cpca`] (k-means++ seeding, assignment by reconstruction error,
//! randomised-subspace refits, re-seeding of empty clusters; deterministic for a seed on any
//! number of threads), run on the CSR rows of `T` (or on each vertex's block as one row).
//!
//! # Compressed form (`kind = "cpca"`)
//!
//! | array     | type | length           | meaning |
//! |-----------|------|------------------|---------|
//! | `basis`   | f32  | K (C + 1) N      | cluster k's mean at `basis[(k (C+1)) N ..][..N]`, its component c (1..=C) at `basis[(k (C+1) + c) N ..][..N]`; zero vectors for absent components |
//! | `cluster` | u16  | rows             | cluster id of each row; `K` (one past the last) marks an all-zero row |
//! | `coeffs`  | f32  | rows C           | row r's coefficient of component c at `coeffs[r C + c - 1]` (zeros for all-zero rows) |
//!
//! meta: `clusters` (K, after dropping empty clusters), `components` (C, at most N).
//!
//! Gather: `P[k][c] = basis[k][c] . L` for all K (C + 1) vectors (RGB), then
//! `L*_r = P[k][0] + sum_c coeffs[r][c] P[k][c]` with `k = cluster[r]` (0 when `k = K`).
//! The CPU gather accumulates both in f64; the GPU gather (`gather.wgsl`) projects with one
//! workgroup per basis vector, then combines per row. Flops per monochrome gather:
//! `2 N K (C + 1) + 2 C (non-zero rows)`.

mod params;
pub use params::{Cpca, CpcaUnit};

use crate::registry::{self, Kind};
use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::linalg::{clustered_pca, CpcaSettings, SparseRows};
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use rayon::prelude::*;
use std::time::Instant;

/// Largest model a build may hold (2 GiB, the shared clustered PCA's limit); beyond, the
/// request is refused with the estimate.
pub const MAX_CPCA_BYTES: u64 = biscale_core::linalg::cpca::MAX_BUILD_BYTES;

impl registry::MakeCompressor for Cpca {
    fn make(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
        Ok(Box::new(registry::parse::<Cpca>(p)?.validated()?))
    }
}

/// The registry entry.
pub const KIND: Kind = Kind {
    fits,
    memory,
    flops: form_flops,
    ..Kind::built_in::<Cpca>(
        "cpca",
        "clustered PCA: `clusters` clusters of `components` principal components (lossy)",
        |p| {
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
    )
};

/// The flops of one gather of `form`, counted from its own arrays (`eval --form` reports this,
/// not what a file claims).
/// Projection of the light on every basis vector, `2 N U K (C + 1)`, then `2 C` per
/// row of each unit that is not all zero (cluster id below K; K is the zero sentinel).
fn form_flops(form: &CompressedForm) -> Option<u64> {
    let meta = |key: &str| form.meta.get(key).copied();
    let cols = form.cols() as u64;
    let (k, c, unit_rows) = (meta("clusters")?, meta("components")?, meta("unit_rows")?);
    let nonzero = form.u16s("cluster").ok()?.iter().filter(|&&id| u64::from(id) < k).count() as u64;
    let project = cols.saturating_mul(unit_rows).saturating_mul(k).saturating_mul(c.saturating_add(1));
    let rows = c.saturating_mul(nonzero).saturating_mul(unit_rows);
    Some(project.saturating_add(rows).saturating_mul(2))
}

/// [`Kind::fits`]: no more components than a clustered unit has values (`N` light
/// directions times the unit's rows).
fn fits(p: &serde_json::Value, t: &biscale_core::transfer::TransferSettings) -> Result<(), String> {
    let p: Cpca = registry::parse(p)?;
    let n = t.light_basis().len();
    let unit_rows = match p.unit {
        CpcaUnit::Row => 1,
        CpcaUnit::Vertex => t.local_basis().len(),
    };
    if p.components > n * unit_rows {
        return Err(format!(
            "components = {} is more than the {} values of a clustered unit ({n} light directions x {unit_rows} \
             rows at {}): at most {} components exist",
            p.components,
            n * unit_rows,
            t.light_basis(),
            n * unit_rows
        ));
    }
    Ok(())
}

/// [`Kind::memory`]: the models' basis values (as `linalg::cpca::build_bytes` counts them, 16
/// bytes each at the build's peak), held twice (assignment tables and refits), f64
/// coefficients per unit, a vertex unit's gathered rows, and the form; saturating, since a
/// setting too large to build is refused by the compressor with its own message.
fn memory(p: &serde_json::Value, t: &registry::MemoryFacts) -> registry::FormMemory {
    let p: Cpca = registry::parse(p).unwrap_or_default();
    let (unit_rows, extra) = match p.unit {
        CpcaUnit::Row => (1, 0),
        CpcaUnit::Vertex => (t.local_dirs, t.nnz * 8 + (t.vertices + 1) * 8),
    };
    let (dim, units) = (t.light_dirs * unit_rows, t.rows() / unit_rows.max(1));
    let c = (p.components as u64).min(dim);
    let values = (p.clusters as u64).saturating_mul(c + 1).saturating_mul(dim);
    let model = values.saturating_mul(biscale_core::linalg::cpca::BUILD_BYTES_PER_BASIS_VALUE);
    let form = values.saturating_mul(4).saturating_add(units * (4 * c + 4));
    let working = model.saturating_mul(2).saturating_add(units * (8 * c + 8) + extra).saturating_add(form);
    registry::FormMemory { working, form }
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
        if self.components > n {
            // Clamping silently left metrics naming a count the form does not have.
            return Err(CompressError::Params(format!(
                "cpca: components = {} is more than the {n} values of a unit (N = {} x {unit_rows} rows): at most {n} \
                 components exist",
                self.components,
                t.cols()
            )));
        }
        let c = self.components;
        let bytes = biscale_core::linalg::cpca::build_bytes(self.clusters, c, n);
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
            1 => SparseRows { dim: n, indptr: &indptr, indices: csr.indices(), data: csr.data() },
            _ => SparseRows { dim: n, indptr: &unit_indptr, indices: &unit_indices, data: csr.data() },
        };
        if n_rows > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("cpca: {n_rows} rows")));
        }
        let settings = CpcaSettings {
            clusters: self.clusters,
            components: self.components,
            iterations: self.iterations,
            power_iterations: self.power_iterations,
            oversampling: self.oversampling,
        };
        let fit = clustered_pca(&rows, &settings, ctx.seed, &|f| ctx.report(f));
        let k_out = fit.clusters;
        let nz_rows = fit.nonzero_rows;
        // Ids fit u16: clusters <= 65534 (validated), K itself is the all-zero sentinel.
        let cluster: Vec<u16> = fit.cluster.iter().map(|&k| k as u16).collect();
        let (basis, coeffs) = (fit.basis, fit.coeffs);
        ctx.report(1.0);
        let exact = nz_rows == 0;
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
        form.flops_per_gather = 2 * (n * k_out * (c + 1)) as u64 + 2 * (c * nz_rows * unit_rows) as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    /// The clusters' k-means and their bases see every unit of `T` at once.
    fn separability(&self, _shape: biscale_core::basis::TransferShape) -> biscale_core::compress::Separability {
        biscale_core::compress::Separability::Whole {
            why: "k-means clusters the units of every vertex together, and each cluster's basis is fit to all its members"
                .into(),
        }
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        let channels: [Vec<f64>; 3] = std::array::from_fn(|ch| light.power.iter().map(|l| l[ch] as f64).collect());
        let rows = gather_lanes(form, &channels)?;
        form.lstar(rows.iter().map(|r| r.map(|x| x as f32)).collect())
    }

    /// The three lights in one pass: every basis segment is read once and projected on nine
    /// channels instead of three, three times. Each channel's sums run in the order of
    /// [`Compressor::gather`], so the result is its three gathers bit for bit.
    fn gather_three(
        &self,
        form: &CompressedForm,
        lights: [&LightVector; 3],
    ) -> Result<[LocalRadiance; 3], CompressError> {
        for l in lights {
            form.check_light(l)?;
        }
        let channels: [Vec<f64>; 9] =
            std::array::from_fn(|ch| lights[ch / 3].power.iter().map(|l| l[ch % 3] as f64).collect());
        let rows = gather_lanes(form, &channels)?;
        let wide: Vec<[f32; 9]> = rows.iter().map(|r| r.map(|x| x as f32)).collect();
        form.lstar_three(&wide, 3)
    }
}

/// The CPCA gather for `W` channels of light (3: one RGB light; 9: three), each laid out per
/// channel in f64: every row's `W` sums, in f64.
fn gather_lanes<const W: usize>(
    form: &CompressedForm,
    channels: &[Vec<f64>; W],
) -> Result<Vec<[f64; W]>, CompressError> {
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
    // Projections of the light on every mean and component segment (f64: a sun may sit beside
    // a dim sky in L, and the components have both signs). Each dot product keeps four partial
    // sums per channel: one running sum would chain every f64 add on the one before (4 cycles
    // each), and the compiler may not reorder float sums itself. Segment `(v (C + 1) + c) U + j`
    // is row j of cluster v's vector c.
    let proj: Vec<[f64; W]> =
        basis.par_chunks(n.max(1)).take(k * (c + 1) * u).map(|b| split_dot(b, channels)).collect();
    Ok((0..form.rows())
        .into_par_iter()
        .map(|r| {
            let (unit, j) = (r / u, r % u);
            let id = cluster[unit] as usize;
            if id == k {
                return [0.0; W];
            }
            let segment = |v: usize| &proj[(id * (c + 1) + v) * u + j];
            let mut acc = *segment(0);
            for (v, &w) in coeffs[unit * c..(unit + 1) * c].iter().enumerate() {
                let pj = segment(v + 1);
                for ch in 0..W {
                    acc[ch] += w as f64 * pj[ch];
                }
            }
            acc
        })
        .collect())
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

/// `sum_i b_i l_i` in f64 for the `W` channels of `l` at once (`b` is read and widened
/// once), with four partial sums per channel: element `i` goes to sum `i % 4`, the four added
/// `(0 + 1) + (2 + 3)`, so consecutive adds do not wait on each other.
fn split_dot<const W: usize>(b: &[f32], l: &[Vec<f64>; W]) -> [f64; W] {
    let mut acc = [[0.0f64; 4]; W];
    let n = l.iter().fold(b.len(), |n, l| n.min(l.len()));
    let b = &b[..n];
    let whole = n / 4 * 4;
    for i in (0..whole).step_by(4) {
        let x: [f64; 4] = std::array::from_fn(|e| b[i + e] as f64);
        for ch in 0..W {
            let y = &l[ch][i..i + 4];
            for e in 0..4 {
                acc[ch][e] += x[e] * y[e];
            }
        }
    }
    for i in whole..n {
        for ch in 0..W {
            acc[ch][i - whole] += b[i] as f64 * l[ch][i];
        }
    }
    acc.map(|a| (a[0] + a[1]) + (a[2] + a[3]))
}

#[cfg(test)]
mod tests;
