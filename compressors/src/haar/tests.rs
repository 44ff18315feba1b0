//! Tests of the Haar compressor: the transform's orthogonality and inverse, the selection,
//! the gather against the f64 reference and the inverse transform, f16 values, stiff and
//! degenerate inputs, corrupt forms.

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
            let tnorm = t.csr().outer_view(row).unwrap().data().iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
            let bound = 4.0 * f32::EPSILON as f64 * (tnorm * lnorm + e[c].abs());
            assert!((g[c] as f64 - e[c]).abs() <= bound, "row {row} channel {c}: {} vs {} (bound {bound})", g[c], e[c]);
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
            let err = relative_l2_error(haar.gather(&form, &light).unwrap().values(), &reference);
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
    let err = |weighting| {
        let haar = Haar { terms: 12, weighting, f16_values: false };
        let form = haar.compress(&t, &CompressContext::default()).unwrap();
        relative_l2_error(haar.gather(&form, &light).unwrap().values(), &reference)
    };
    let (area, side, plain) = (err(HaarWeighting::Area), err(HaarWeighting::Side), err(HaarWeighting::Magnitude));
    assert!(area < plain && side < plain, "area {area}, side {side} vs plain {plain}");
}

#[test]
fn f16_values_halve_value_storage_with_bounded_error() {
    let t = random_transfer(10, 2, 4, 0.3, 6);
    let light = random_light(4, 8);
    let f32_form = Haar::with_terms(96).compress(&t, &CompressContext::default()).unwrap();
    let haar16 = Haar { terms: 96, weighting: HaarWeighting::Area, f16_values: true };
    let f16_form = haar16.compress(&t, &CompressContext::default()).unwrap();
    assert!(!f16_form.lossless);
    let n = f16_form.u16s("coeff_idx").unwrap().len() as u64;
    assert_eq!(f32_form.bytes() - f16_form.bytes(), 2 * n);
    let err = relative_l2_error(haar16.gather(&f16_form, &light).unwrap().values(), &reference_product(&t, &light));
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
    let lhat = transform_light(light).unwrap();
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
            (want, got) => {
                panic!("trial {trial} ({name}, change {pick}): validation {:?}, gather {:?}", want.is_some(), got.err())
            }
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

/// The same input and seed give the same bytes whatever the thread count (the transform
/// and the term selection run in parallel over vertices), and Haar uses no randomness, so
/// another seed gives the same bytes too.
#[test]
fn same_seed_same_bytes() {
    let t = random_transfer(60, 2, 8, 0.1, 1);
    let compress = |threads: usize, seed: u64| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            Haar::with_terms(12).compress(&t, &CompressContext { seed, progress: None, sweep: None }).unwrap()
        })
    };
    let one = compress(1, 1);
    assert!(!one.u16s("coeff_idx").unwrap().is_empty(), "the form holds terms");
    for (threads, seed) in [(1, 1), (2, 1), (4, 1), (3, 2)] {
        assert_eq!(compress(threads, seed).arrays, one.arrays, "{threads} threads, seed {seed}");
    }
}

#[test]
fn forms_of_vertex_ranges_merge_into_the_whole_form() {
    // Truncating (4 terms) and exact (every term) settings, f32 and f16 values.
    let t = crate::testing::random_transfer(19, 2, 4, 0.3, 12);
    for haar in [Haar::with_terms(4), Haar { f16_values: true, ..Haar::with_terms(4) }, Haar::with_terms(96)] {
        for cuts in [&[][..], &[3], &[1, 2, 10]] {
            let merged = crate::testing::assert_parts_merge_to_whole(&haar, &t, cuts);
            assert_eq!(merged.lossless, haar.terms == 96);
        }
    }
}

#[test]
fn the_weighting_is_a_config_key_and_names_its_setting() {
    let label = |p: serde_json::Value| (KIND.label)(&p).unwrap();
    assert_eq!(label(serde_json::json!({ "terms": 12 })), "haar-t12");
    assert_eq!(label(serde_json::json!({ "terms": 12, "weighting": "area" })), "haar-t12");
    assert_eq!(label(serde_json::json!({ "terms": 12, "weighting": "side" })), "haar-t12-side");
    assert_eq!(label(serde_json::json!({ "terms": 6, "weighting": "magnitude" })), "haar-t6-magnitude");
    assert!((KIND.build)(&serde_json::json!({ "weighting": "volume" })).is_err());
    for a in [0.0, 0.25, 2.0] {
        assert_eq!(HaarWeighting::Area.weight(a), a);
        assert_eq!(HaarWeighting::Side.weight(a), a.sqrt());
        assert_eq!(HaarWeighting::Magnitude.weight(a), 1.0);
    }
}
