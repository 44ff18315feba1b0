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
    // Each edit breaks the form: a column past the light, an offset past nnz, a row pointer
    // that runs backwards (row 0 ending at nnz, so row 1 starts after it ends), the last
    // offset past the arrays. Every one is an error naming the array, never a panic or a
    // result read from outside the form.
    assert!(form.u32s("row_ptr").unwrap()[2] < nnz, "the test needs rows after row 1");
    for (what, bad) in [
        ("column out of range", corrupt("col_idx", 3, 1_000_000)),
        ("column out of range in the first row", corrupt("col_idx", 0, 1_000_000)),
        ("offset past nnz", corrupt("row_ptr", 2, nnz + 5)),
        ("row pointers running backwards", corrupt("row_ptr", 1, nnz)),
        ("last offset past the arrays", corrupt("row_ptr", usize::MAX, nnz + 1)),
    ] {
        let e = Sparse.gather(&bad, &light).expect_err(what).to_string();
        assert!(e.contains("row_ptr") || e.contains("col_idx"), "{what}: {e}");
    }
}

/// The CPU gather interleaves four rows; each row must still be summed in column order from
/// zero, the order `gather.wgsl` uses, so the result equals a plain per-row f32 loop bit for
/// bit. An SH-shaped matrix (9 rows per vertex, 37 vertices: 333 rows, one full 256-row task
/// and a last one ending in a partial quad) with rows of random length, empty ones included,
/// and a light with negative coefficients.
#[test]
fn interleaved_rows_keep_each_rows_f32_order() {
    use biscale_core::basis::{LightBasis, LocalBasis};
    use biscale_core::sh::ShOrder;
    use rand::{Rng, SeedableRng};
    let order = ShOrder::new(3).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let (rows, cols) = (37 * order.len(), order.len());
    let (mut indptr, mut indices, mut data) = (vec![0usize], vec![], vec![]);
    for _ in 0..rows {
        let density = rng.gen_range(0.0..1.0);
        for c in 0..cols {
            if rng.gen::<f64>() < density {
                indices.push(c);
                data.push(rng.gen_range(-1.0..1.0f32));
            }
        }
        indptr.push(indices.len());
    }
    let csr = sprs::CsMat::new((rows, cols), indptr, indices, data);
    let t = TransferMatrix::new(LocalBasis::Sh(order), LightBasis::Sh(order), csr).unwrap();
    let power: Vec<[f32; 3]> = (0..cols).map(|_| [(); 3].map(|_| rng.gen_range(-2.0..2.0f32))).collect();
    let light = LightVector::new(LightBasis::Sh(order), power).unwrap();
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let got = Sparse.gather(&form, &light).unwrap();
    for (r, row) in t.csr().outer_iterator().enumerate() {
        let mut want = [0.0f32; 3];
        for (k, &v) in row.iter() {
            for c in 0..3 {
                want[c] += v * light.power[k][c];
            }
        }
        assert_eq!(got.values()[r], want, "row {r}");
    }
}

#[test]
fn forms_of_vertex_ranges_merge_into_the_whole_form() {
    let t = random_transfer(23, 2, 4, 0.3, 11);
    for cuts in [&[][..], &[1], &[5, 6, 17], &[22]] {
        crate::testing::assert_parts_merge_to_whole(&Sparse, &t, cuts);
    }
    assert_eq!(Sparse.separability(t.shape()), Separability::Rows { vertex_multiple: 1 });
}
