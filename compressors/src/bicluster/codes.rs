//! Exact integer value codes of `T` (docs/DESIGN.md section 3: visibility fractions are multiples
//! of `1 / s^2`). Every stored value `v` becomes `code = round(v q)` for the smallest scale `q`
//! that represents all of them exactly (up to the f32 rounding of `code / q` itself), so the
//! whole biclustering runs in exact integer arithmetic: no float drift, residuals are exact.

use biscale_core::compress::CompressError;
use biscale_core::transfer::TransferMatrix;
use std::collections::BTreeSet;

/// Largest |code| stored (i8 value arrays).
pub const CODE_MAX: i32 = 127;

/// At most this many distinct stored values are examined when detecting the scale.
const MAX_DISTINCT: usize = 4096;

/// `T` in integer codes, CSR: row `i` has columns `cols[indptr[i]..indptr[i + 1]]`
/// (increasing) with values `codes[..] / scale`. Explicit zeros of the input are dropped.
#[derive(Clone, Debug, PartialEq)]
pub struct CodeMatrix {
    pub rows: usize,
    pub cols: usize,
    pub scale: u32,
    pub indptr: Vec<usize>,
    pub col_idx: Vec<u16>,
    pub codes: Vec<i8>,
}

impl CodeMatrix {
    pub fn nnz(&self) -> usize {
        self.codes.len()
    }

    /// Row `i` as `(column, code)` pairs.
    pub fn row(&self, i: usize) -> impl Iterator<Item = (u16, i8)> + '_ {
        let r = self.indptr[i]..self.indptr[i + 1];
        self.col_idx[r.clone()].iter().copied().zip(self.codes[r].iter().copied())
    }
}

/// Whether `v` is `c / q` for an integer `c` to within the f32 rounding of `c / q`
/// (checked in f64: `|v q - c| <= 2 eps_f32 |c|`), returning `c`.
fn code_of(v: f32, q: u32) -> Option<i32> {
    let x = v as f64 * q as f64;
    let c = x.round();
    let tol = 2.0 * f32::EPSILON as f64 * c.abs();
    if (x - c).abs() <= tol && c != 0.0 && c.abs() <= CODE_MAX as f64 {
        Some(c as i32)
    } else {
        None
    }
}

/// The smallest scale `q` in `1..=CODE_MAX` for which every value of `t` is a code.
pub fn detect_scale(t: &TransferMatrix) -> Result<u32, CompressError> {
    let mut distinct = BTreeSet::new();
    for &v in t.csr().data() {
        if v != 0.0 {
            if !v.is_finite() {
                return Err(CompressError::Params(format!("bicluster: T holds a non-finite value {v}")));
            }
            distinct.insert(v.to_bits());
            if distinct.len() > MAX_DISTINCT {
                return Err(CompressError::Params(format!(
                    "bicluster: T holds more than {MAX_DISTINCT} distinct values; biclustering needs \
                     quantized visibility fractions (multiples of 1/s^2)"
                )));
            }
        }
    }
    (1..=CODE_MAX as u32).find(|&q| distinct.iter().all(|&b| code_of(f32::from_bits(b), q).is_some())).ok_or_else(
        || {
            CompressError::Params(format!(
                "bicluster: the {} distinct values of T are not multiples of 1/q for any q <= {CODE_MAX} \
                 with codes in [-{CODE_MAX}, {CODE_MAX}]",
                distinct.len()
            ))
        },
    )
}

/// Convert `t` to codes at scale `scale` (0: detect it).
pub fn quantize(t: &TransferMatrix, scale: u32) -> Result<CodeMatrix, CompressError> {
    let q = if scale == 0 { detect_scale(t)? } else { scale };
    if q as i32 > CODE_MAX {
        return Err(CompressError::Params(format!("bicluster: value_scale {q} exceeds {CODE_MAX}")));
    }
    if t.cols() > u16::MAX as usize + 1 {
        return Err(CompressError::TooLarge(format!("bicluster: {} columns do not fit u16 indices", t.cols())));
    }
    let owned;
    let csr = if t.csr().is_csr() {
        t.csr()
    } else {
        owned = t.csr().to_csr();
        &owned
    };
    let mut indptr = Vec::with_capacity(csr.rows() + 1);
    indptr.push(0);
    let mut col_idx = Vec::with_capacity(csr.nnz());
    let mut codes = Vec::with_capacity(csr.nnz());
    for (i, row) in csr.outer_iterator().enumerate() {
        let mut prev: Option<usize> = None;
        for (k, &v) in row.iter() {
            if prev.is_some_and(|p| p >= k) {
                return Err(CompressError::Params(format!("bicluster: row {i} of T has unsorted or repeated columns")));
            }
            prev = Some(k);
            if v == 0.0 {
                continue;
            }
            let c = code_of(v, q).ok_or_else(|| {
                CompressError::Params(format!("bicluster: T[{i}, {k}] = {v} is not a multiple of 1/{q} in code range"))
            })?;
            col_idx.push(k as u16);
            codes.push(c as i8);
        }
        indptr.push(codes.len());
    }
    Ok(CodeMatrix { rows: csr.rows(), cols: csr.cols(), scale: q, indptr, col_idx, codes })
}
