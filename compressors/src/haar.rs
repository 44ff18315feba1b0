//! Non-linear Haar wavelet approximation of the transfer rows (Ng, Ramamoorthi, Hanrahan 2003,
//! "All-frequency shadows using non-linear wavelet lighting approximation"), applied to the
//! rows of `T` as in the biclustering paper's comparison (Sun et al.).
//!
//! # Transform
//!
//! Each row of `T` (N = 6 R^2 texels) is viewed as six R x R cubemap faces and every face is
//! transformed by the orthonormal 2D **non-standard** Haar basis (R a power of two): at each
//! level the current s x s averages are split into 2x2 blocks `(a b; c d)` (rows, then
//! columns) and replaced by
//!
//! ```text
//! average    (a + b + c + d) / 2      stored at (i,     j    )
//! horizontal (a - b + c - d) / 2      stored at (i,     j + h)
//! vertical   (a + b - c - d) / 2      stored at (i + h, j    )
//! diagonal   (a - b - c + d) / 2      stored at (i + h, j + h)      h = s / 2
//! ```
//!
//! down to one scaling coefficient per face at (0, 0) (the usual in-place "standard layout").
//! Coefficient `i = face*R*R + row*R + col` therefore lives in the same index space as the
//! texels. The 4x4 block matrix is orthonormal, so the whole transform `W` is orthogonal
//! (block-diagonal over faces) and `T L = (T W^T)(W L)`: the runtime transforms the light once
//! and every row is a short sparse dot product with the transformed light.
//!
//! # Selection (area-weighted, Ng et al. 2003 section 5)
//!
//! Each row keeps its `terms` coefficients of largest **area-weighted magnitude**
//! `|c_i| * A_i`, where `A_i` is the solid angle (steradians) of the support of basis
//! function `i`: the sum of the exact solid angles of the texels it covers (2x2 texels for the
//! finest details, the whole face for the scaling coefficient). Why: plain `|c_i|` ranking is
//! L2-optimal for the row itself, but what we need is `T L`, and the light vector carries the
//! solid angle (`L_k` = radiance x texel solid angle), so a broad basis function meets light
//! energy in proportion to the solid angle it covers; weighting by it keeps the low-frequency
//! terms that carry most of `T L` for typical environments (Ng et al. report area weighting as
//! their best heuristic). Using exact solid angles rather than texel counts also accounts for
//! the cube's distortion (corner texels subtend about 5x less than centre texels at R = 32).
//! `Haar { area_weighted: false, .. }` ranks by `|c_i|` alone. Ties break towards the lower
//! index, so the selection is deterministic. Rows whose transform has at most `terms` non-zero
//! coefficients are stored exactly (all of them); all-zero rows store nothing.
//!
//! # Compressed form (`kind = "haar"`)
//!
//! | array       | type            | length        | meaning |
//! |-------------|-----------------|---------------|---------|
//! | `row_ptr`   | u32             | rows + 1      | row r's terms are `row_ptr[r] .. row_ptr[r+1]` |
//! | `coeff_idx` | u16             | total terms   | coefficient index `face*R*R + row*R + col` in the layout above, increasing within a row |
//! | `coeff_val` | f32             | total terms   | coefficient value `(W t_r)_i` (present unless `f16_values`) |
//! | `coeff_f16` | u16 (f16 bits)  | total terms   | the same values as IEEE half floats (present when `f16_values`) |
//!
//! meta: `resolution` (R), `terms` (the per-row cap), `f16_values` (0 or 1).
//!
//! Gather: `l̂ = W L` per channel (the forward transform above on each face of the light), then
//! `L*_r = sum_{i in row r} coeff_val[i] * l̂[coeff_idx[i]]`. The CPU gather transforms and
//! accumulates in f64 (the light may hold a 10^6 sun next to a dim sky). Flops per monochrome
//! gather: `12` per 2x2 block of the light transform (8 adds, 4 halvings; `(R^2 - 1) / 3`
//! blocks per face) plus 2 per stored term.

use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::{Cubemap, LightVector};
use biscale_core::transfer::TransferMatrix;
use rayon::prelude::*;
use std::time::Instant;

/// Non-linear Haar approximation of every row of `T`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Haar {
    /// Coefficients kept per row (`T` in Ng et al.; the comparison setting is 12). Rows with
    /// fewer non-zero coefficients keep all of them. `terms >= N` keeps every row exactly.
    pub terms: usize,
    /// Rank coefficients by `|c_i| x solid angle of support` (Ng et al.'s area-weighted
    /// selection) instead of `|c_i|`. Default true.
    pub area_weighted: bool,
    /// Store the kept values as IEEE half floats (2 bytes) instead of f32 (4 bytes). Relative
    /// rounding 2^-11 per value. Default false.
    pub f16_values: bool,
}

impl Default for Haar {
    fn default() -> Self {
        Self { terms: 12, area_weighted: true, f16_values: false }
    }
}

impl Haar {
    /// The reference setting with `terms` coefficients per row.
    pub fn with_terms(terms: usize) -> Self {
        Self { terms, ..Self::default() }
    }
}

/// Rows per rayon task in the gather.
const ROWS_PER_TASK: usize = 512;

/// Resolution R of a cubemap with `cols` texels if the Haar transform applies to it
/// (`cols = 6 R^2`, R a power of two, `cols <= 65536` so indices fit u16).
fn face_resolution(t: &TransferMatrix) -> Result<usize, CompressError> {
    let cubemap = t
        .light_basis()
        .cubemap_layout()
        .ok_or_else(|| CompressError::Params(format!("haar: T's light basis is {}, not a cubemap", t.light_basis())))?;
    let r = cubemap.resolution as usize;
    if t.cols() != 6 * r * r {
        return Err(CompressError::Params(format!(
            "haar: T has {} columns, its cubemap (R = {r}) has {}",
            t.cols(),
            6 * r * r
        )));
    }
    if !r.is_power_of_two() {
        return Err(CompressError::Params(format!("haar: cubemap resolution {r} is not a power of two")));
    }
    if t.cols() > u16::MAX as usize + 1 {
        return Err(CompressError::Params(format!("haar: {} texels do not fit u16 coefficient indices", t.cols())));
    }
    Ok(r)
}

/// In-place forward non-standard Haar transform of one R x R face (row-major), standard layout.
pub fn forward_face(face: &mut [f64], r: usize) {
    debug_assert_eq!(face.len(), r * r);
    let mut tmp = vec![0.0f64; r * r];
    let mut s = r;
    while s > 1 {
        let h = s / 2;
        for i in 0..h {
            for j in 0..h {
                let a = face[2 * i * r + 2 * j];
                let b = face[2 * i * r + 2 * j + 1];
                let c = face[(2 * i + 1) * r + 2 * j];
                let d = face[(2 * i + 1) * r + 2 * j + 1];
                tmp[i * r + j] = 0.5 * (a + b + c + d);
                tmp[i * r + j + h] = 0.5 * (a - b + c - d);
                tmp[(i + h) * r + j] = 0.5 * (a + b - c - d);
                tmp[(i + h) * r + j + h] = 0.5 * (a - b - c + d);
            }
        }
        for i in 0..s {
            face[i * r..i * r + s].copy_from_slice(&tmp[i * r..i * r + s]);
        }
        s = h;
    }
}

/// In-place inverse of [`forward_face`].
pub fn inverse_face(face: &mut [f64], r: usize) {
    debug_assert_eq!(face.len(), r * r);
    let mut tmp = vec![0.0f64; r * r];
    let mut s = 2;
    while s <= r {
        let h = s / 2;
        for i in 0..h {
            for j in 0..h {
                let av = face[i * r + j];
                let ho = face[i * r + j + h];
                let ve = face[(i + h) * r + j];
                let di = face[(i + h) * r + j + h];
                tmp[2 * i * r + 2 * j] = 0.5 * (av + ho + ve + di);
                tmp[2 * i * r + 2 * j + 1] = 0.5 * (av - ho + ve - di);
                tmp[(2 * i + 1) * r + 2 * j] = 0.5 * (av + ho - ve - di);
                tmp[(2 * i + 1) * r + 2 * j + 1] = 0.5 * (av - ho - ve + di);
            }
        }
        for i in 0..s {
            face[i * r..i * r + s].copy_from_slice(&tmp[i * r..i * r + s]);
        }
        s *= 2;
    }
}

/// `W v` for a whole cubemap vector (six faces of R x R), f64.
pub fn forward_cubemap(v: &mut [f64], r: usize) {
    for face in v.chunks_mut(r * r) {
        forward_face(face, r);
    }
}

/// `W L` per channel: the transformed light the gather dots every row with.
pub fn transform_light(light: &LightVector) -> Vec<[f64; 3]> {
    let r = light.cubemap().resolution as usize;
    let mut out = vec![[0.0f64; 3]; light.len()];
    for c in 0..3 {
        let mut v: Vec<f64> = light.power.iter().map(|p| p[c] as f64).collect();
        forward_cubemap(&mut v, r);
        for (o, x) in out.iter_mut().zip(v) {
            o[c] = x;
        }
    }
    out
}

/// Solid angle (sr) of the support of every basis function, in coefficient order: the
/// weights of the area-weighted selection.
pub fn support_solid_angles(cubemap: &Cubemap) -> Vec<f64> {
    let r = cubemap.resolution as usize;
    let omega = cubemap.solid_angles();
    let mut out = vec![0.0; omega.len()];
    for face in 0..6 {
        let base = face * r * r;
        for row in 0..r {
            for col in 0..r {
                let (r0, c0, side) = support(row, col, r);
                let mut a = 0.0;
                for y in r0..r0 + side {
                    for x in c0..c0 + side {
                        a += omega[base + y * r + x];
                    }
                }
                out[base + row * r + col] = a;
            }
        }
    }
    out
}

/// Support of the basis function stored at `(row, col)` of an R x R face: its top-left texel
/// and side length. `(0, 0)` is the scaling function (whole face); a detail coefficient at
/// `(row, col)` with `h = 2^floor(log2(max(row, col)))` belongs to the h x h block grid,
/// block `(row mod h, col mod h)`, side `R / h`.
fn support(row: usize, col: usize, r: usize) -> (usize, usize, usize) {
    let m = row.max(col);
    if m == 0 {
        return (0, 0, r);
    }
    let h = 1usize << (usize::BITS - 1 - m.leading_zeros());
    let side = r / h;
    ((row % h) * side, (col % h) * side, side)
}

/// Scratch for the sparse per-row transform (one per worker thread).
struct SparseHaar {
    r: usize,
    cur: Vec<f64>,
    next: Vec<f64>,
    stamp: Vec<u32>,
    epoch: u32,
    active: Vec<usize>,
    parents: Vec<usize>,
}

impl SparseHaar {
    fn new(r: usize) -> Self {
        Self {
            r,
            cur: vec![0.0; r * r],
            next: vec![0.0; r * r],
            stamp: vec![0; r * r],
            epoch: 0,
            active: vec![],
            parents: vec![],
        }
    }

    /// Forward transform of one face given as `(texel within face, value)` pairs, pushing every
    /// non-zero coefficient `(global index, value)` to `out`. Touches only the blocks above the
    /// non-zeros: O(nnz log R) instead of O(R^2). Leaves the scratch zeroed.
    fn face(&mut self, base: usize, entries: &[(usize, f64)], out: &mut Vec<(u32, f64)>) {
        let r = self.r;
        self.active.clear();
        for &(p, v) in entries {
            self.cur[p] = v;
            self.active.push(p);
        }
        let mut s = r;
        while s > 1 {
            let h = s / 2;
            if self.epoch == u32::MAX {
                self.stamp.fill(0);
                self.epoch = 0;
            }
            self.epoch += 1;
            self.parents.clear();
            for &p in &self.active {
                let q = (p / r / 2) * r + (p % r) / 2;
                if self.stamp[q] != self.epoch {
                    self.stamp[q] = self.epoch;
                    self.parents.push(q);
                }
            }
            for &q in &self.parents {
                let (i, j) = (q / r, q % r);
                let ia = 2 * i * r + 2 * j;
                let ic = ia + r;
                let (a, b, c, d) = (self.cur[ia], self.cur[ia + 1], self.cur[ic], self.cur[ic + 1]);
                self.cur[ia] = 0.0;
                self.cur[ia + 1] = 0.0;
                self.cur[ic] = 0.0;
                self.cur[ic + 1] = 0.0;
                self.next[q] = 0.5 * (a + b + c + d);
                for (pos, v) in [
                    (i * r + j + h, 0.5 * (a - b + c - d)),
                    ((i + h) * r + j, 0.5 * (a + b - c - d)),
                    ((i + h) * r + j + h, 0.5 * (a - b - c + d)),
                ] {
                    if v != 0.0 {
                        out.push(((base + pos) as u32, v));
                    }
                }
            }
            std::mem::swap(&mut self.cur, &mut self.next);
            std::mem::swap(&mut self.active, &mut self.parents);
            s = h;
        }
        let v = self.cur[0];
        self.cur[0] = 0.0;
        if v != 0.0 {
            out.push((base as u32, v));
        }
    }

    /// Every non-zero coefficient of a sparse row (`cols` increasing, as in CSR).
    fn row(&mut self, cols: &[usize], vals: &[f32], out: &mut Vec<(u32, f64)>, face_buf: &mut Vec<(usize, f64)>) {
        out.clear();
        let rr = self.r * self.r;
        let mut i = 0;
        while i < cols.len() {
            let face = cols[i] / rr;
            face_buf.clear();
            while i < cols.len() && cols[i] / rr == face {
                if vals[i] != 0.0 {
                    face_buf.push((cols[i] - face * rr, vals[i] as f64));
                }
                i += 1;
            }
            if !face_buf.is_empty() {
                let entries = std::mem::take(face_buf);
                self.face(face * rr, &entries, out);
                *face_buf = entries;
            }
        }
    }
}

/// Keep the `terms` coefficients of largest `|c| * weight` (ties: lower index), sorted by index.
fn select(coeffs: &mut Vec<(u32, f64)>, terms: usize, weight: &[f64]) {
    if coeffs.len() > terms {
        let key = |&(i, v): &(u32, f64)| v.abs() * weight[i as usize];
        coeffs.select_nth_unstable_by(terms - 1, |a, b| key(b).total_cmp(&key(a)).then(a.0.cmp(&b.0)));
        coeffs.truncate(terms);
    }
    coeffs.sort_unstable_by_key(|&(i, _)| i);
}

/// Monochrome flops of the light transform: 12 per 2x2 block, `(R^2 - 1) / 3` blocks per face.
fn light_transform_flops(r: usize) -> u64 {
    6 * 12 * ((r * r - 1) / 3) as u64
}

impl Compressor for Haar {
    fn kind(&self) -> &str {
        "haar"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::json!({ "terms": self.terms, "area_weighted": self.area_weighted, "f16_values": self.f16_values })
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        if self.terms == 0 {
            return Err(CompressError::Params("haar: terms must be at least 1".into()));
        }
        let r = face_resolution(t)?;
        let csr = if t.csr().is_csr() {
            std::borrow::Cow::Borrowed(t.csr())
        } else {
            std::borrow::Cow::Owned(t.csr().to_csr())
        };
        let indptr_view = csr.indptr();
        let indptr = indptr_view.to_proper();
        let (indices, data) = (csr.indices(), csr.data());
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            let row = indptr.partition_point(|&p| p <= i) - 1;
            return Err(CompressError::Params(format!(
                "haar: T has a non-finite value at row {row}, column {}",
                indices[i]
            )));
        }
        let weight = if self.area_weighted {
            support_solid_angles(&t.light_basis().cubemap_layout().expect("face_resolution checked it"))
        } else {
            vec![1.0; t.cols()]
        };
        let terms = self.terms.min(t.cols());
        let rows = t.rows();
        const CHUNK: usize = 2048;
        let chunks = rows.div_ceil(CHUNK);
        let done = std::sync::atomic::AtomicUsize::new(0);
        let truncated = std::sync::atomic::AtomicBool::new(false);
        // Per chunk: (terms per row, indices, values); chunks come back in order (deterministic).
        let parts: Vec<(Vec<u32>, Vec<u16>, Vec<f32>)> = (0..chunks)
            .into_par_iter()
            .map_init(
                || (SparseHaar::new(r), Vec::new(), Vec::new()),
                |(haar, coeffs, face_buf), c| {
                    let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(rows));
                    let mut counts = Vec::with_capacity(hi - lo);
                    let (mut idx, mut val) = (Vec::new(), Vec::new());
                    for row in lo..hi {
                        let span = indptr[row]..indptr[row + 1];
                        haar.row(&indices[span.clone()], &data[span], coeffs, face_buf);
                        if coeffs.len() > terms {
                            truncated.store(true, std::sync::atomic::Ordering::Relaxed);
                        }
                        select(coeffs, terms, &weight);
                        counts.push(coeffs.len() as u32);
                        for &(i, v) in coeffs.iter() {
                            idx.push(i as u16);
                            val.push(v as f32);
                        }
                    }
                    let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                    ctx.report(n as f64 / chunks as f64);
                    (counts, idx, val)
                },
            )
            .collect();
        let total: usize = parts.iter().map(|p| p.1.len()).sum();
        if total > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("haar: {total} terms do not fit u32 row pointers")));
        }
        let mut row_ptr = Vec::with_capacity(rows + 1);
        row_ptr.push(0u32);
        let (mut coeff_idx, mut values) = (Vec::with_capacity(total), Vec::with_capacity(total));
        for (counts, idx, val) in parts {
            for n in counts {
                row_ptr.push(row_ptr.last().unwrap() + n);
            }
            coeff_idx.extend(idx);
            values.extend(val);
        }
        let value_array = if self.f16_values {
            let bits = values.iter().map(|&v| half::f16::from_f32(v).to_bits()).collect();
            NamedArray { name: "coeff_f16".into(), data: ArrayData::U16(bits) }
        } else {
            NamedArray { name: "coeff_val".into(), data: ArrayData::F32(values) }
        };
        let mut form = CompressedForm::new("haar", t.shape());
        form.arrays = vec![
            NamedArray { name: "row_ptr".into(), data: ArrayData::U32(row_ptr) },
            NamedArray { name: "coeff_idx".into(), data: ArrayData::U16(coeff_idx) },
            value_array,
        ];
        form.meta = [
            ("resolution".to_string(), r as u64),
            ("terms".into(), terms as u64),
            ("f16_values".into(), self.f16_values as u64),
        ]
        .into_iter()
        .collect();
        // Exact when no row lost a term (f32 value rounding aside; f16 values never are).
        form.lossless = !self.f16_values && !truncated.into_inner();
        form.flops_per_gather = light_transform_flops(r) + 2 * total as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        let r = form.meta("resolution")? as usize;
        if light.cubemap().resolution as usize != r || 6 * r * r != form.cols() {
            return Err(CompressError::malformed(
                "haar",
                "resolution",
                format!("{r} does not match {} columns", form.cols()),
            ));
        }
        let row_ptr = form.u32s("row_ptr")?;
        let coeff_idx = form.u16s("coeff_idx")?;
        // RGB padded to four f64 lanes: two packed multiply-adds per coefficient.
        let lhat: Vec<[f64; 4]> = transform_light(light).into_iter().map(|[x, y, z]| [x, y, z, 0.0]).collect();
        let out = if form.meta("f16_values")? != 0 {
            // Half floats are widened where they are read, not decoded into a copy first.
            let v = form.u16s("coeff_f16")?;
            rows_dot(form.rows(), row_ptr, coeff_idx, v, |b| half::f16::from_bits(b).to_f64(), &lhat)
        } else {
            rows_dot(form.rows(), row_ptr, coeff_idx, form.f32s("coeff_val")?, |x| x as f64, &lhat)
        }
        .map_err(|what: String| CompressError::malformed("haar", "row_ptr", what))?;
        form.lstar(out)
    }
}

/// `||T - T~||_F / ||T||_F` of the rows `form` stands for. `W` is orthogonal, so each row's
/// squared residual is `||t||^2 - sum_kept c_i^2` (Parseval; the kept values are the exact
/// coefficients up to their storage rounding). f64; 0 when `T` is 0.
pub fn relative_frobenius_error(form: &CompressedForm, t: &TransferMatrix) -> Result<f64, CompressError> {
    let row_ptr = form.u32s("row_ptr")?;
    let values: Vec<f64> = if form.meta("f16_values")? != 0 {
        form.u16s("coeff_f16")?.iter().map(|&b| half::f16::from_bits(b).to_f64()).collect()
    } else {
        form.f32s("coeff_val")?.iter().map(|&v| v as f64).collect()
    };
    if form.rows() != t.rows()
        || row_ptr.len() != form.rows() + 1
        || row_ptr.last().map(|&p| p as usize) != Some(values.len())
    {
        return Err(CompressError::malformed("haar", "row_ptr", "does not match T"));
    }
    let (num, den) = (0..form.rows())
        .into_par_iter()
        .map(|r| {
            let x_sq: f64 = t.csr().outer_view(r).map_or(0.0, |v| v.data().iter().map(|&x| x as f64 * x as f64).sum());
            let kept: f64 = values[row_ptr[r] as usize..row_ptr[r + 1] as usize].iter().map(|v| v * v).sum();
            ((x_sq - kept).max(0.0), x_sq)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok(if den > 0.0 { (num / den).sqrt() } else { 0.0 })
}

/// The gather's row loop: `L*_row = sum_e value(e) * lhat[coeff_idx[e]]` over each row's
/// entries, in f64, rows in parallel chunks.
///
/// Only the shape is checked up front; each row's offsets and each coefficient index are
/// checked where the loop reads them (with `row_ptr[0] = 0` and the last entry equal to the
/// total, the rows' ranges cover every entry), so a corrupt form is an error exactly as with
/// a separate validation pass, without that O(form size) pass (it took a third of the gather
/// on the bunny).
fn rows_dot<V: Copy + Sync>(
    rows: usize,
    row_ptr: &[u32],
    coeff_idx: &[u16],
    values: &[V],
    widen: impl Fn(V) -> f64 + Sync,
    lhat: &[[f64; 4]],
) -> Result<Vec<[f32; 3]>, String> {
    if row_ptr.len() != rows + 1
        || values.len() != coeff_idx.len()
        || row_ptr.first() != Some(&0)
        || row_ptr.last().map(|&p| p as usize) != Some(coeff_idx.len())
    {
        return Err("haar: array lengths or indices do not match the shape".into());
    }
    let mut out = vec![[0.0f32; 3]; rows];
    out.par_chunks_mut(ROWS_PER_TASK).enumerate().try_for_each(|(chunk, rows)| {
        for (j, o) in rows.iter_mut().enumerate() {
            let row = chunk * ROWS_PER_TASK + j;
            let r = row_ptr[row] as usize..row_ptr[row + 1] as usize;
            let (Some(idx), Some(vals)) = (coeff_idx.get(r.clone()), values.get(r)) else {
                return Err(format!("haar: row {row} has offsets out of order"));
            };
            let mut acc = [0.0f64; 4];
            for (&k, &v) in idx.iter().zip(vals) {
                let l = lhat.get(k as usize).ok_or_else(|| format!("haar: row {row}: coefficient {k} out of range"))?;
                let v = widen(v);
                for c in 0..4 {
                    acc[c] += v * l[c];
                }
            }
            *o = [acc[0] as f32, acc[1] as f32, acc[2] as f32];
        }
        Ok(())
    })?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{random_light, random_transfer};
    use biscale_core::basis::LightBasis;
    use biscale_core::gather::{reference_product, relative_l2_error};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The basis function stored at `(row, col)` of an R x R face, built directly from its
    /// definition (support, sign pattern, height `1 / side`), as a dense R x R image.
    fn naive_basis(row: usize, col: usize, r: usize) -> Vec<f64> {
        let (r0, c0, side) = support(row, col, r);
        let m = row.max(col);
        let h = if m == 0 { 0 } else { r / side };
        // Which detail: (row < h, col >= h) horizontal, (row >= h, col < h) vertical, else diagonal.
        let kind = if m == 0 {
            0
        } else if row < h {
            1
        } else if col < h {
            2
        } else {
            3
        };
        let mut img = vec![0.0; r * r];
        let half = side / 2;
        for y in 0..side {
            for x in 0..side {
                let (top, left) = (y < half, x < half);
                let sign = match kind {
                    0 => 1.0,
                    1 => {
                        if left {
                            1.0
                        } else {
                            -1.0
                        }
                    }
                    2 => {
                        if top {
                            1.0
                        } else {
                            -1.0
                        }
                    }
                    _ => {
                        if top == left {
                            1.0
                        } else {
                            -1.0
                        }
                    }
                };
                img[(r0 + y) * r + c0 + x] = sign / side as f64;
            }
        }
        img
    }

    fn random_face(r: usize, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..r * r).map(|_| if rng.gen::<f64>() < 0.3 { rng.gen_range(-2.0..2.0) } else { 0.0 }).collect()
    }

    // The fast transform equals the inner products with the directly built basis, the basis is
    // orthonormal, and the inverse undoes the forward: all to f64 rounding (values O(1), sums
    // of at most R^2 = 64 terms: 1e-12 is thousands of ulps of headroom).
    #[test]
    fn transform_matches_naive_basis_and_inverts() {
        for r in [1usize, 2, 4, 8] {
            let basis: Vec<Vec<f64>> = (0..r * r).map(|i| naive_basis(i / r, i % r, r)).collect();
            for (i, bi) in basis.iter().enumerate() {
                for (j, bj) in basis.iter().enumerate() {
                    let dot: f64 = bi.iter().zip(bj).map(|(a, b)| a * b).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-12, "R={r}: <psi_{i}, psi_{j}> = {dot}");
                }
            }
            for seed in 0..4 {
                let f = random_face(r, seed);
                let mut fast = f.clone();
                forward_face(&mut fast, r);
                for (i, bi) in basis.iter().enumerate() {
                    let naive: f64 = bi.iter().zip(&f).map(|(a, b)| a * b).sum();
                    assert!((fast[i] - naive).abs() < 1e-12, "R={r} coefficient {i}: {} vs {naive}", fast[i]);
                }
                let mut back = fast.clone();
                inverse_face(&mut back, r);
                for (a, b) in back.iter().zip(&f) {
                    assert!((a - b).abs() < 1e-12);
                }
                // Synthesis from the naive basis gives the same image.
                for (k, &fk) in f.iter().enumerate() {
                    let s: f64 = basis.iter().zip(&fast).map(|(b, c)| b[k] * c).sum();
                    assert!((s - fk).abs() < 1e-12);
                }
            }
        }
    }

    // The sparse per-row transform returns exactly the non-zeros of the dense transform
    // (values here are dyadic, so both are exact and must agree bit for bit).
    #[test]
    fn sparse_row_transform_matches_dense() {
        let t = random_transfer(6, 2, 8, 0.05, 3);
        let r = 8;
        let mut haar = SparseHaar::new(r);
        let (mut out, mut buf) = (vec![], vec![]);
        for row in 0..t.rows() {
            let view = t.csr().outer_view(row).unwrap();
            haar.row(view.indices(), view.data(), &mut out, &mut buf);
            let mut dense = vec![0.0; t.cols()];
            for (k, &v) in view.iter() {
                dense[k] = v as f64;
            }
            forward_cubemap(&mut dense, r);
            let want: Vec<(u32, f64)> =
                dense.iter().enumerate().filter(|(_, v)| **v != 0.0).map(|(i, &v)| (i as u32, v)).collect();
            out.sort_by_key(|p| p.0);
            assert_eq!(out, want, "row {row}");
        }
        assert!(haar.cur.iter().chain(&haar.next).all(|&v| v == 0.0), "scratch left dirty");
    }

    #[test]
    fn support_solid_angles_cover_each_face() {
        let cm = Cubemap::new(8);
        let w = support_solid_angles(&cm);
        let omega = cm.solid_angles();
        for face in 0..6 {
            let face_sum: f64 = omega[face * 64..(face + 1) * 64].iter().sum();
            assert!((w[face * 64] - face_sum).abs() < 1e-12);
            // The three coarsest details also cover the whole face.
            for i in [1, 8, 9] {
                assert!((w[face * 64 + i] - face_sum).abs() < 1e-12);
            }
            // Finest details cover 2x2 texels.
            let k = face * 64 + 7 * 8 + 7; // diagonal detail of block (3, 3)
            let want = omega[face * 64 + 6 * 8 + 6]
                + omega[face * 64 + 6 * 8 + 7]
                + omega[face * 64 + 7 * 8 + 6]
                + omega[face * 64 + 7 * 8 + 7];
            assert!((w[k] - want).abs() < 1e-15);
        }
    }

    /// Per-row bound for a gather that is exact up to f32 storage of the coefficients: each
    /// stored value is rounded once (relative 2^-24), so `|error| <= 2^-24 sum |c_i||l̂_i|
    /// <= 2^-24 ||t_r|| ||L||` (Cauchy-Schwarz, W orthogonal); we allow 4x that for the f64
    /// transform and accumulation and the final f32 rounding of the result (relative 2^-24).
    fn assert_exact(form: &CompressedForm, t: &TransferMatrix, light: &LightVector) {
        let got = Haar::default().gather(form, light).unwrap();
        let reference = reference_product(t, light);
        for c in 0..3 {
            let lnorm = light.power.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>().sqrt();
            for (row, (g, e)) in got.values().iter().zip(&reference).enumerate() {
                let tnorm =
                    t.csr().outer_view(row).unwrap().data().iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
                let bound = 4.0 * f32::EPSILON as f64 * (tnorm * lnorm + e[c].abs());
                assert!(
                    (g[c] as f64 - e[c]).abs() <= bound,
                    "row {row} channel {c}: {} vs {} (bound {bound})",
                    g[c],
                    e[c]
                );
            }
        }
    }

    #[test]
    fn all_terms_is_exact_including_hdr_sun() {
        for (r, seed) in [(1u32, 0u64), (2, 1), (4, 2), (8, 3)] {
            let t = random_transfer(5, 2, r, 0.3, seed);
            let haar = Haar::with_terms(t.cols());
            let form = haar.compress(&t, &CompressContext::default()).unwrap();
            assert!(form.lossless);
            for light_seed in [10, 11] {
                // seed 11 is odd: a sun 10^6 times the sky
                assert_exact(&form, &t, &random_light(r, light_seed));
            }
        }
    }

    #[test]
    fn rows_with_few_coefficients_are_exact() {
        // One texel per row: its transform has at most 1 + 3 log2(R) = 10 non-zeros at R = 8,
        // and the cap is 12, so every row is kept exactly although the form is lossy overall.
        let mut t = random_transfer(4, 2, 8, 0.0, 0);
        let rows = t.rows();
        let mut tri = sprs::TriMat::new((rows, t.cols()));
        for row in 0..rows {
            if row % 3 != 0 {
                tri.add_triplet(row, (row * 37) % t.cols(), 0.75f32);
            }
        }
        t = TransferMatrix::new(t.local_basis(), t.light_basis(), tri.to_csr()).unwrap();
        let form = Haar::default().compress(&t, &CompressContext::default()).unwrap();
        assert!(form.lossless, "no row was truncated");
        let row_ptr = form.u32s("row_ptr").unwrap();
        for row in 0..rows {
            let n = row_ptr[row + 1] - row_ptr[row];
            assert!(if row % 3 == 0 { n == 0 } else { (1..=10).contains(&n) }, "row {row}: {n} terms");
        }
        assert_exact(&form, &t, &random_light(8, 5));
    }

    #[test]
    fn error_falls_as_terms_grow() {
        let t = random_transfer(40, 2, 8, 0.15, 9);
        for light_seed in [20, 21] {
            let light = random_light(8, light_seed);
            let reference = reference_product(&t, &light);
            let mut last = f64::INFINITY;
            for terms in [1, 3, 6, 12, 24, 48, 96, 192, 384] {
                let haar = Haar::with_terms(terms);
                let form = haar.compress(&t, &CompressContext::default()).unwrap();
                let err = relative_l2_error(&haar.gather(&form, &light).unwrap().values(), &reference);
                assert_eq!(form.lossless, terms == 384, "terms {terms}");
                // Keeping more of each row's coefficients can only shrink each row's L2
                // residual; the gather error follows it on these dense-ish random rows.
                assert!(err < last, "light {light_seed}: terms {terms}: error {err} >= {last}");
                assert!(form.bytes() == 4 * (t.rows() as u64 + 1) + 6 * (form.u16s("coeff_idx").unwrap().len() as u64));
                last = err;
            }
            assert!(last < 1e-6, "all 384 coefficients kept: error {last}");
        }
    }

    // Parseval's shortcut equals the residual of the dense inverse transform of the kept
    // terms (f64 both; f32 storage of the kept values shifts both alike).
    #[test]
    fn frobenius_error_matches_inverse_transform() {
        let t = random_transfer(6, 2, 4, 0.3, 12);
        for terms in [1, 5, 20, 96] {
            let form = Haar::with_terms(terms).compress(&t, &CompressContext::default()).unwrap();
            let (row_ptr, idx, val) =
                (form.u32s("row_ptr").unwrap(), form.u16s("coeff_idx").unwrap(), form.f32s("coeff_val").unwrap());
            let (mut num, mut den) = (0.0, 0.0);
            for r in 0..t.rows() {
                let mut rec = vec![0.0f64; t.cols()];
                for i in row_ptr[r] as usize..row_ptr[r + 1] as usize {
                    rec[idx[i] as usize] = val[i] as f64;
                }
                for face in rec.chunks_mut(16) {
                    inverse_face(face, 4);
                }
                let mut x = vec![0.0f64; t.cols()];
                for (k, &v) in t.csr().outer_view(r).unwrap().iter() {
                    x[k] = v as f64;
                }
                num += x.iter().zip(&rec).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
                den += x.iter().map(|a| a * a).sum::<f64>();
            }
            let want = (num / den).sqrt();
            let got = relative_frobenius_error(&form, &t).unwrap();
            // Values are dyadic so the kept f32 coefficients are exact: agreement to f64 rounding
            // of sums of ~100 O(1) terms, with the cancellation of ||t||^2 - sum c^2 (1e-7 abs.).
            assert!((got - want).abs() <= 1e-7, "terms {terms}: {got} vs {want}");
        }
    }

    #[test]
    fn area_weighting_helps_for_a_smooth_light() {
        // A constant-radiance sky: T L is the solid-angle-weighted row sum, carried by the
        // coarse coefficients that the area weighting favours.
        let t = random_transfer(40, 2, 8, 0.3, 4);
        let light = LightVector::constant(LightBasis::cubemap(8).unwrap(), [1.0, 0.5, 0.25]);
        let reference = reference_product(&t, &light);
        let err = |area_weighted| {
            let haar = Haar { terms: 12, area_weighted, f16_values: false };
            let form = haar.compress(&t, &CompressContext::default()).unwrap();
            relative_l2_error(&haar.gather(&form, &light).unwrap().values(), &reference)
        };
        let (weighted, plain) = (err(true), err(false));
        assert!(weighted < plain, "area weighted {weighted} vs plain {plain}");
    }

    #[test]
    fn f16_values_halve_value_storage_with_bounded_error() {
        let t = random_transfer(10, 2, 4, 0.3, 6);
        let light = random_light(4, 8);
        let f32_form = Haar::with_terms(96).compress(&t, &CompressContext::default()).unwrap();
        let haar16 = Haar { terms: 96, area_weighted: true, f16_values: true };
        let f16_form = haar16.compress(&t, &CompressContext::default()).unwrap();
        assert!(!f16_form.lossless);
        let n = f16_form.u16s("coeff_idx").unwrap().len() as u64;
        assert_eq!(f32_form.bytes() - f16_form.bytes(), 2 * n);
        let err =
            relative_l2_error(&haar16.gather(&f16_form, &light).unwrap().values(), &reference_product(&t, &light));
        // Each value rounded to 11 significant bits (relative 2^-11 ~ 4.9e-4); the error of a
        // sum of such terms is at most that times sum |c||l| / |sum c l|, a small factor here.
        assert!(err < 2e-3, "f16 error {err}");
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let t = random_transfer(4, 1, 4, 0.3, 0);
        assert!(matches!(Haar::with_terms(0).compress(&t, &CompressContext::default()), Err(CompressError::Params(_))));
        // Not a power-of-two cubemap.
        let t3 = random_transfer(4, 1, 3, 0.3, 0);
        assert!(matches!(Haar::default().compress(&t3, &CompressContext::default()), Err(CompressError::Params(_))));
        // A matrix that is not over a cubemap, or has non-finite entries, cannot be built
        // (TransferMatrix::new), so it never reaches the compressor.
        let one = sprs::CsMat::new((1, 1), vec![0, 1], vec![0], vec![1.0]);
        assert!(TransferMatrix::new(t.local_basis(), t.light_basis(), one).is_err());
        // A light in another basis.
        let form = Haar::default().compress(&t, &CompressContext::default()).unwrap();
        assert!(matches!(Haar::default().gather(&form, &random_light(2, 0)), Err(CompressError::LightBasis { .. })));
    }

    /// The gather before the fused checks: the whole form validated first (lengths, first
    /// and last offset, every offset non-decreasing, every index below the column count),
    /// then a plain serial row loop in the same f64 operation order.
    fn validated_gather(form: &CompressedForm, light: &LightVector) -> Option<Vec<[f32; 3]>> {
        let row_ptr = form.u32s("row_ptr").ok()?;
        let idx = form.u16s("coeff_idx").ok()?;
        let vals = form.f32s("coeff_val").ok()?;
        let valid = row_ptr.len() == form.rows() + 1
            && vals.len() == idx.len()
            && row_ptr.first() == Some(&0)
            && row_ptr.last().map(|&p| p as usize) == Some(idx.len())
            && row_ptr.windows(2).all(|w| w[0] <= w[1])
            && idx.iter().all(|&i| (i as usize) < form.cols());
        if !valid {
            return None;
        }
        let lhat = transform_light(light);
        Some(
            (0..form.rows())
                .map(|row| {
                    let mut acc = [0.0f64; 3];
                    for e in row_ptr[row] as usize..row_ptr[row + 1] as usize {
                        for c in 0..3 {
                            acc[c] += vals[e] as f64 * lhat[idx[e] as usize][c];
                        }
                    }
                    acc.map(|a| a as f32)
                })
                .collect(),
        )
    }

    /// The gather checks offsets and indices where it reads them. On 2,000 randomly corrupted
    /// forms (one offset or index nudged, randomised or set to the extreme, or an array
    /// shortened) it must never panic, must fail exactly when the up-front validation fails,
    /// and otherwise must equal the validated serial gather bit for bit.
    #[test]
    fn corrupt_forms_fail_exactly_when_full_validation_fails() {
        let t = random_transfer(6, 2, 4, 0.3, 21);
        let light = random_light(4, 2);
        let base = Haar::with_terms(5).compress(&t, &CompressContext::default()).unwrap();
        assert_eq!(Haar::default().gather(&base, &light).unwrap().values(), validated_gather(&base, &light).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (mut rejected, mut accepted) = (0, 0);
        for trial in 0..2000 {
            let mut bad = base.clone();
            let name = if trial % 2 == 0 { "row_ptr" } else { "coeff_idx" };
            let a = bad.arrays.iter_mut().find(|a| a.name == name).unwrap();
            let pick = rng.gen_range(0..4);
            match &mut a.data {
                ArrayData::U32(v) if pick == 3 => v.truncate(v.len() - 1),
                ArrayData::U16(v) if pick == 3 => v.truncate(v.len() - 1),
                ArrayData::U32(v) => {
                    let i = rng.gen_range(0..v.len());
                    v[i] = match pick {
                        0 => v[i].saturating_add(1).saturating_sub(2 * rng.gen_range(0..2)),
                        1 => rng.gen_range(0..v.len() as u32 * 6),
                        _ => u32::MAX,
                    };
                }
                ArrayData::U16(v) => {
                    let i = rng.gen_range(0..v.len());
                    v[i] = match pick {
                        0 => v[i].saturating_add(1).saturating_sub(2 * rng.gen_range(0..2)),
                        1 => rng.gen_range(0..(t.cols() as u16) * 2),
                        _ => u16::MAX,
                    };
                }
                other => panic!("unexpected array type {}", other.element_type()),
            }
            match (validated_gather(&bad, &light), Haar::default().gather(&bad, &light)) {
                (Some(want), Ok(got)) => {
                    assert_eq!(got.values(), want, "trial {trial}");
                    accepted += 1;
                }
                (None, Err(e)) => {
                    assert!(matches!(e, CompressError::Malformed { .. }), "{e}");
                    rejected += 1;
                }
                (want, got) => panic!(
                    "trial {trial} ({name}, change {pick}): validation {:?}, gather {:?}",
                    want.is_some(),
                    got.err()
                ),
            }
        }
        // Both outcomes must occur, or the test proves nothing.
        assert!(rejected > 300 && accepted > 300, "rejected {rejected}, accepted {accepted}");
    }

    #[test]
    fn degenerate_shapes() {
        // One row; one texel per face (R = 1: the transform is the identity).
        let t = random_transfer(1, 1, 1, 1.0, 2);
        let form = Haar::with_terms(6).compress(&t, &CompressContext::default()).unwrap();
        assert_exact(&form, &t, &random_light(1, 3));
        // All-zero matrix: nothing stored, gather is zero.
        let z = random_transfer(3, 2, 4, 0.0, 0);
        let form = Haar::default().compress(&z, &CompressContext::default()).unwrap();
        assert!(form.u16s("coeff_idx").unwrap().is_empty());
        let got = Haar::default().gather(&form, &random_light(4, 1)).unwrap();
        assert!(got.values().iter().all(|v| *v == [0.0; 3]));
    }

    #[test]
    fn same_seed_same_bytes() {
        let t = random_transfer(60, 2, 8, 0.1, 1);
        let a = Haar::default().compress(&t, &CompressContext { seed: 1, progress: None }).unwrap();
        let b = Haar::default().compress(&t, &CompressContext { seed: 2, progress: None }).unwrap();
        assert_eq!(a.arrays, b.arrays);
    }
}
