//! Tests of the raw sparse form: the gather against the f64 reference, and corrupt forms.

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
