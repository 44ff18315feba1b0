//! The raw sparse matrix: `T` as plain CSR (u32 row pointers, u32 column indices, f32
//! values: 8 bytes per non-zero plus 4 per row). The uncompressed baseline every other
//! compressor is compared with; its gather is the row-wise sparse dot product.

use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use rayon::prelude::*;
use std::time::Instant;

/// The raw CSR baseline (no parameters).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sparse;

impl Compressor for Sparse {
    fn kind(&self) -> &str {
        "sparse"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::json!({})
    }

    fn compress(&self, t: &TransferMatrix, _ctx: &CompressContext) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        let csr = t.csr();
        if csr.nnz() > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("{} non-zeros do not fit u32 row pointers", csr.nnz())));
        }
        let row_ptr: Vec<u32> = csr.indptr().as_slice().expect("CSR indptr").iter().map(|&p| p as u32).collect();
        let col_idx: Vec<u32> = csr.indices().iter().map(|&c| c as u32).collect();
        let values = csr.data().to_vec();
        let mut form = CompressedForm::new("sparse", t.shape());
        form.arrays = vec![
            NamedArray { name: "row_ptr".into(), data: ArrayData::U32(row_ptr) },
            NamedArray { name: "col_idx".into(), data: ArrayData::U32(col_idx) },
            NamedArray { name: "values".into(), data: ArrayData::F32(values) },
        ];
        form.lossless = true;
        form.flops_per_gather = 2 * csr.nnz() as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        let row_ptr = form.u32s("row_ptr")?;
        let col_idx = form.u32s("col_idx")?;
        let values = form.f32s("values")?;
        if row_ptr.len() != form.rows() + 1 || col_idx.len() != values.len() {
            return Err(CompressError::malformed("sparse", "row_ptr", "and col_idx/values do not match the shape"));
        }
        // Row pointers must be monotone and end at nnz, columns in range: checked where read
        // (`get`), so a corrupt form is an error, never a panic, at no measurable cost.
        let malformed = |r: usize| {
            CompressError::malformed("sparse", "row_ptr", format!("row {r} has an out-of-range offset or column"))
        };
        let values_out: Vec<[f32; 3]> = (0..form.rows())
            .into_par_iter()
            .map(|r| {
                let (start, end) = (row_ptr[r] as usize, row_ptr[r + 1] as usize);
                let (cols, vals) = match (col_idx.get(start..end), values.get(start..end)) {
                    (Some(c), Some(v)) => (c, v),
                    _ => return Err(malformed(r)),
                };
                let mut acc = [0.0f32; 3];
                for (&k, &v) in cols.iter().zip(vals) {
                    let l = light.power.get(k as usize).ok_or_else(|| malformed(r))?;
                    for c in 0..3 {
                        acc[c] += v * l[c];
                    }
                }
                Ok(acc)
            })
            .collect::<Result<_, _>>()?;
        form.lstar(values_out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{assert_lossless, random_light, random_transfer};

    #[test]
    fn matches_f64_reference_on_random_matrices() {
        for seed in 0..5 {
            let t = random_transfer(20, 4, 4, 0.2, seed);
            let light = random_light(4, seed + 100);
            let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
            assert_eq!(form.bytes(), 4 * (t.rows() as u64 + 1) + 8 * t.nnz() as u64);
            assert_lossless(&Sparse, &form, &t, &light);
        }
    }

    #[test]
    fn corrupt_offsets_and_columns_are_errors_not_panics() {
        let t = random_transfer(12, 2, 4, 0.5, 3);
        let light = random_light(4, 7);
        let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
        let corrupt = |array: &str, at: usize, value: u32| {
            let mut f = form.clone();
            let a = f.arrays.iter_mut().find(|a| a.name == array).unwrap();
            let biscale_core::compress::ArrayData::U32(v) = &mut a.data else { panic!("u32 array") };
            let at = at.min(v.len() - 1);
            v[at] = value;
            f
        };
        let nnz = t.nnz() as u32;
        for bad in [
            corrupt("col_idx", 3, 1_000_000),
            corrupt("row_ptr", 2, nnz + 5),
            corrupt("row_ptr", 1, nnz),
            corrupt("row_ptr", usize::MAX, nnz + 1),
        ] {
            let r = Sparse.gather(&bad, &light);
            // Either an error, or (a still-consistent edit) a result: never a panic.
            if let Ok(l) = r {
                assert_eq!(l.values().len(), form.rows());
            }
        }
        assert!(Sparse.gather(&corrupt("col_idx", 0, 1_000_000), &light).is_err());
    }
}
