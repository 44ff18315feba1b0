//! What a bicluster form says about `T`'s structure: the paper's Table I statistics
//! ([`table_stats`]), the gather cost each vertex carries ([`gather_cost_per_vertex`]), the
//! window of vertices whose biclusters share the most ([`most_shared_window`]), and the cover
//! of rows of `T` by biclusters ([`row_cover`]). The report and the matrix-structure pictures
//! are drawn from these; they read the form through [`BiclusterView`], which checks it.

use super::BiclusterView;
use biscale_core::compress::{CompressError, CompressedForm};
use biscale_core::transfer::{TransferMatrix, TransferView};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::ops::Range;

/// Quantiles and a power-of-two histogram of a size distribution.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Distribution {
    pub mean: f64,
    pub min: u64,
    pub p50: u64,
    pub p90: u64,
    pub p99: u64,
    pub max: u64,
    /// `(lo, hi, count)`: how many values lie in `[lo, hi]`, bins 1, 2-3, 4-7, ...
    pub histogram: Vec<(u64, u64, u64)>,
}

impl Distribution {
    pub fn of(values: &[u64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut s = values.to_vec();
        s.sort_unstable();
        let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
        let mut histogram: Vec<(u64, u64, u64)> = Vec::new();
        for &x in &s {
            let bin = 64 - x.max(1).leading_zeros() as u64 - 1;
            let (lo, hi) = (1u64 << bin, (1u64 << bin) * 2 - 1);
            match histogram.last_mut() {
                Some(h) if h.0 == lo => h.2 += 1,
                _ => histogram.push((lo, hi, 1)),
            }
        }
        Self {
            mean: s.iter().sum::<u64>() as f64 / s.len() as f64,
            min: s[0],
            p50: q(0.5),
            p90: q(0.9),
            p99: q(0.99),
            max: s[s.len() - 1],
            histogram,
        }
    }
}

/// The paper's Table I for one biclustered matrix, computed from the form's arrays.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BiclusterStats {
    pub rows: usize,
    pub cols: usize,
    /// Non-zeros of `T`.
    pub nnz: u64,
    /// Raw product `T L`: 2 nnz flops (monochrome), in millions.
    pub mflops_raw: f64,
    /// `sum_b W(B_b) = sum_b (r_b + 2 l_b - 1)`, in millions (the paper's count).
    pub mflops_biclustered: f64,
    /// `mflops_biclustered / mflops_raw` (paper: 27.4% on average).
    pub flops_ratio: f64,
    /// The gather's extra `L / q` prescale: N flops.
    pub prescale_flops: u64,
    /// Dense `T` at one byte per entry (the paper's 'data size').
    pub dense_bytes: u64,
    /// Raw CSR: 8 bytes per non-zero (u32 column, f32 value) + 4 per row.
    pub csr_bytes: u64,
    /// Every array of the form at its stored width.
    pub compressed_bytes: u64,
    pub bytes_by_array: BTreeMap<String, u64>,
    pub ratio_to_dense: f64,
    pub ratio_to_csr: f64,
    pub bytes_per_nnz: f64,
    pub biclusters: usize,
    /// Rows r and columns l per bicluster.
    pub r: Distribution,
    pub l: Distribution,
    /// Biclusters per row (the row list length).
    pub row_list_mean: f64,
    pub row_list_max: u64,
    pub build_seconds: f64,
    /// The error the form achieves against `t` (0 for the lossless build).
    pub error: AchievedError,
}

/// How far a bicluster form is from the `T` it was built from, recomputed from the arrays
/// (independently of the pruning's own bookkeeping).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AchievedError {
    /// `||T - T'||_F / ||T||_F`: what `error_budget` bounds.
    pub frobenius: f64,
    /// Relative L2 error of `L*` over all rows under the uniform white sky (each texel's
    /// power its solid angle); `None` outside the cubemap basis.
    pub sky: Option<f64>,
}

/// The error of `form` against `t`, from the form's decompressed integer codes and `t`'s
/// codes at the form's `value_scale`, accumulated in f64 (exact for the Frobenius sums). The
/// sums run over rows in order, part after part, so `T`'s parts give what `T` whole gives.
pub fn achieved_error<'a>(
    form: &CompressedForm,
    t: impl Into<TransferView<'a>>,
) -> Result<AchievedError, CompressError> {
    let t = t.into();
    let kept = super::decompress_codes(form)?;
    if (kept.rows, kept.cols) != (t.rows(), t.cols()) {
        return Err(CompressError::malformed("bicluster", "shape", "does not match T"));
    }
    let omega = match t.light_basis() {
        biscale_core::basis::LightBasis::Cubemap(c) => Some(c.solid_angles()),
        _ => None,
    };
    let m = t.local_dirs();
    let (mut e2, mut t2, mut se2, mut st2) = (0f64, 0f64, 0f64, 0f64);
    // Ordered by column, so the f64 sums run in one order on every run (a hash map's order
    // differs per process, and with it the last bit of `sky`).
    let mut diff: BTreeMap<u16, i32> = BTreeMap::new();
    t.for_each_part(|first: usize, part: &TransferMatrix| -> Result<(), CompressError> {
        let full = super::codes::quantize(part, kept.scale)?;
        for i in 0..full.rows {
            diff.clear();
            let mut sky_t = 0.0;
            for (k, c) in full.row(i) {
                *diff.entry(k).or_insert(0) += c as i32;
                t2 += (c as f64).powi(2);
                if let Some(w) = &omega {
                    sky_t += c as f64 * w[k as usize];
                }
            }
            for (k, c) in kept.row(first * m + i) {
                *diff.entry(k).or_insert(0) -= c as i32;
            }
            let mut sky_e = 0.0;
            for (&k, &d) in &diff {
                e2 += (d as f64).powi(2);
                if let Some(w) = &omega {
                    sky_e += d as f64 * w[k as usize];
                }
            }
            se2 += sky_e * sky_e;
            st2 += sky_t * sky_t;
        }
        Ok(())
    })?;
    let rel = |a: f64, b: f64| if b == 0.0 { 0.0 } else { (a / b).sqrt() };
    Ok(AchievedError { frobenius: rel(e2, t2), sky: omega.map(|_| rel(se2, st2)) })
}

/// Table I stats of `form` (a bicluster form of `t`).
pub fn table_stats<'a>(form: &CompressedForm, t: impl Into<TransferView<'a>>) -> Result<BiclusterStats, CompressError> {
    let t = t.into();
    let v = BiclusterView::new(form)?;
    if (v.rows, v.cols) != (t.rows(), t.cols()) {
        return Err(CompressError::malformed(
            "bicluster",
            "shape",
            format!("is {}x{}, T is {}x{}", v.rows, v.cols, t.rows(), t.cols()),
        ));
    }
    let nnz = t.nonzero()? as u64;
    let r: Vec<u64> = v.bicluster_rows().into_iter().map(u64::from).collect();
    let l: Vec<u64> = v.bicluster_cols().into_iter().map(u64::from).collect();
    let w: u64 = r.iter().zip(&l).map(|(&r, &l)| r + 2 * l - 1).sum();
    let list: Vec<u64> = v.row_ptr.windows(2).map(|w| (w[1] - w[0]) as u64).collect();
    let dense = (v.rows * v.cols) as u64;
    let csr = 8 * nnz + 4 * v.rows as u64;
    let bytes = form.bytes();
    let div = |a: f64, b: f64| if b == 0.0 { 0.0 } else { a / b };
    Ok(BiclusterStats {
        rows: v.rows,
        cols: v.cols,
        nnz,
        mflops_raw: 2.0 * nnz as f64 / 1e6,
        mflops_biclustered: w as f64 / 1e6,
        flops_ratio: div(w as f64, 2.0 * nnz as f64),
        prescale_flops: v.cols as u64,
        dense_bytes: dense,
        csr_bytes: csr,
        compressed_bytes: bytes,
        bytes_by_array: form.bytes_by_array(),
        ratio_to_dense: div(bytes as f64, dense as f64),
        ratio_to_csr: div(bytes as f64, csr as f64),
        bytes_per_nnz: div(bytes as f64, nnz as f64),
        biclusters: v.biclusters(),
        r: Distribution::of(&r),
        l: Distribution::of(&l),
        row_list_mean: div(list.iter().sum::<u64>() as f64, list.len() as f64),
        row_list_max: list.iter().copied().max().unwrap_or(0),
        build_seconds: form.build_seconds,
        error: if form.lossless {
            let cubemap = matches!(t.light_basis(), biscale_core::basis::LightBasis::Cubemap(_));
            AchievedError { frobenius: 0.0, sky: cubemap.then_some(0.0) }
        } else {
            achieved_error(form, t)?
        },
    })
}

/// Gather flops per vertex under biclustering (Sun et al. section 4, `W(B) = r + 2l - 1`
/// split over vertices): for each of the vertex's M rows, its row-list length (one add per
/// bicluster), plus, for each bicluster, `(2 l - 1) x` (the fraction of its r rows that belong
/// to the vertex). Summed over all vertices this is `sum_b (r_b + 2 l_b - 1)`, the
/// `mflops_biclustered` of [`table_stats`] (without the N prescale flops). Accumulated in f64.
pub fn gather_cost_per_vertex(form: &CompressedForm) -> Result<Vec<f32>, CompressError> {
    let bv = BiclusterView::new(form)?;
    // The form's rows are whole vertices of M rows (its shape is an invariant).
    let m = form.local_dirs();
    let share: Vec<f64> = bv
        .bicluster_cols()
        .into_iter()
        .zip(bv.bicluster_rows())
        .map(|(l, r)| if r == 0 { 0.0 } else { (2.0 * l as f64 - 1.0) / r as f64 })
        .collect();
    let out = (0..form.vertices())
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

/// The first vertex of the window of `count` consecutive vertices whose biclusters share the
/// most columns (the patch where biclustering's structure shows best): the window maximising
/// `sum_b l_b (n_b - 1)`, `n_b` the number of its vertices whose rows use bicluster `b`.
pub fn most_shared_window(form: &CompressedForm, count: usize) -> Result<usize, CompressError> {
    let bv = BiclusterView::new(form)?;
    let (m, vertices) = (form.local_dirs(), form.vertices());
    if count == 0 || count > vertices {
        return Err(CompressError::Params(format!("a window of {count} vertices asked, the form has {vertices}")));
    }
    let per_vertex: Vec<Vec<usize>> = (0..vertices)
        .map(|v| {
            let mut ids: Vec<usize> = (v * m..(v + 1) * m).flat_map(|i| bv.row_biclusters(i)).collect();
            ids.sort_unstable();
            ids.dedup();
            ids
        })
        .collect();
    let l = bv.bicluster_cols();
    let mut best = (0u64, 0usize);
    let mut seen = HashMap::new();
    for s in 0..=vertices - count {
        seen.clear();
        for ids in &per_vertex[s..s + count] {
            for &b in ids {
                *seen.entry(b).or_insert(0u64) += 1;
            }
        }
        let score: u64 = seen.iter().map(|(&b, &n)| l[b] as u64 * (n - 1)).sum();
        if score > best.0 {
            best = (score, s);
        }
    }
    Ok(best.1)
}

/// One entry of a row of `T` as a form's biclusters cover it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoveredEntry {
    /// The column (cubemap texel).
    pub col: usize,
    /// `T`'s value there: 0 where biclusters cover an entry whose residuals cancel.
    pub value: f32,
    /// The smallest id of a bicluster covering it (the first the greedy build emitted).
    pub first: Option<usize>,
    /// How many biclusters cover it (two or more: residual overlaps).
    pub count: u32,
}

/// The entries of rows `rows` of `t` (its non-zeros and every entry a bicluster covers, in
/// first-seen order) with their cover by `form`'s biclusters, and the ids of the biclusters
/// those rows use. Errors when `form` is not a bicluster form of `t`: another shape, or an
/// entry whose covering codes do not sum to `T`'s value (codes are exact integers and values
/// `code / q` to f32 rounding, so agreement is checked to 1e-5 relative).
pub fn row_cover(
    form: &CompressedForm,
    t: &TransferMatrix,
    rows: Range<usize>,
) -> Result<(Vec<Vec<CoveredEntry>>, BTreeSet<usize>), CompressError> {
    let bv = BiclusterView::new(form)?;
    let bad = |what: String| CompressError::malformed("bicluster", "bc_vals", what);
    if form.shape() != t.shape() {
        return Err(bad(format!("is a form of {}, T is {}", form.shape(), t.shape())));
    }
    if rows.end > t.rows() {
        return Err(CompressError::Params(format!("rows {rows:?} outside the {} rows of T", t.rows())));
    }
    let q = bv.value_scale as f32;
    // Per column: T's value, smallest covering id + 1 (0: none), count, code sum.
    let mut acc = vec![(0.0f32, 0usize, 0u32, 0i32); t.cols()];
    let mut seen: Vec<usize> = vec![];
    let mut ids = BTreeSet::new();
    let mut out = Vec::with_capacity(rows.len());
    for i in rows {
        if let Some(row) = t.csr().outer_view(i) {
            for (k, &v) in row.iter().filter(|(_, v)| **v != 0.0) {
                if acc[k] == (0.0, 0, 0, 0) {
                    seen.push(k);
                }
                acc[k].0 = v;
            }
        }
        for b in bv.row_biclusters(i) {
            ids.insert(b);
            let (ks, codes) = bv.bicluster(b);
            for (&k, &code) in ks.iter().zip(codes) {
                let e = &mut acc[k as usize];
                if *e == (0.0, 0, 0, 0) {
                    seen.push(k as usize);
                }
                e.1 = if e.1 == 0 { b + 1 } else { e.1.min(b + 1) };
                e.2 += 1;
                e.3 += code as i32;
            }
        }
        let mut row = Vec::with_capacity(seen.len());
        for &k in &seen {
            let (value, first, count, code_sum) = std::mem::take(&mut acc[k]);
            let sum = code_sum as f32 / q;
            // Written so that a NaN in T fails too.
            let agrees = (sum - value).abs() <= 1e-5 * value.abs().max(1.0);
            if !agrees {
                return Err(bad(format!(
                    "the biclusters sum to {sum} at T[{i}, {k}] = {value}: the form is not of this T"
                )));
            }
            row.push(CoveredEntry { col: k, value, first: first.checked_sub(1), count });
        }
        seen.clear();
        out.push(row);
    }
    Ok((out, ids))
}
