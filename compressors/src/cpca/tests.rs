//! CPCA tests: exactness where the model can be exact, agreement with the Eckart-Young optimum
//! (a dense f64 eigen-decomposition) for one cluster, monotone error in K and C, and the stiff
//! and degenerate inputs of docs/DESIGN.md section 6.

use super::*;
use crate::cpca::CpcaUnit;
use crate::testing::{random_light, random_transfer};
use biscale_core::basis::{LightBasis, LocalBasis};
use biscale_core::compress::Separability;
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::sampling::Cubemap;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const EPS: f64 = f32::EPSILON as f64;

/// A transfer matrix from dense rows (R x R cubemap, one local direction per "vertex").
fn from_dense(rows: &[Vec<f64>], resolution: u32) -> TransferMatrix {
    let cubemap = Cubemap::new(resolution);
    let n = cubemap.texel_count();
    let mut tri = sprs::TriMat::new((rows.len(), n));
    for (r, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), n);
        for (k, &v) in row.iter().enumerate() {
            if v != 0.0 {
                tri.add_triplet(r, k, v as f32);
            }
        }
    }
    TransferMatrix::new(LocalBasis::bins(1).unwrap(), LightBasis::Cubemap(cubemap), tri.to_csr()).unwrap()
}

fn to_dense(t: &TransferMatrix) -> Vec<Vec<f64>> {
    (0..t.rows())
        .map(|r| {
            let mut row = vec![0.0; t.cols()];
            for (k, &v) in t.csr().outer_view(r).unwrap().iter() {
                row[k] = v as f64;
            }
            row
        })
        .collect()
}

/// The rows the form stands for, decoded from its arrays in f64 (any unit: row `r` is row
/// `j = r % U` of unit `r / U`, whose vectors' segment `j` it combines).
fn decode(form: &CompressedForm) -> Vec<Vec<f64>> {
    let (k, c, n) = (form.meta("clusters").unwrap() as usize, form.meta("components").unwrap() as usize, form.cols());
    let u = form.meta("unit_rows").unwrap() as usize;
    let (basis, cluster, coeffs) =
        (form.f32s("basis").unwrap(), form.u16s("cluster").unwrap(), form.f32s("coeffs").unwrap());
    (0..form.rows())
        .map(|r| {
            let (unit, j) = (r / u, r % u);
            let id = cluster[unit] as usize;
            if id == k {
                return vec![0.0; n];
            }
            let b = |v: usize| &basis[((id * (c + 1) + v) * u + j) * n..((id * (c + 1) + v) * u + j + 1) * n];
            let mut row: Vec<f64> = b(0).iter().map(|&v| v as f64).collect();
            for v in 0..c {
                let w = coeffs[unit * c + v] as f64;
                for (x, &y) in row.iter_mut().zip(b(v + 1)) {
                    *x += w * y as f64;
                }
            }
            row
        })
        .collect()
}

/// Squared Frobenius distance.
fn frob2(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    a.iter().zip(b).flat_map(|(x, y)| x.iter().zip(y).map(|(p, q)| (p - q).powi(2))).sum()
}

/// Low-rank-plus-noise rows in `groups` groups, each group with its own support (a random
/// 60% of the texels) and its own `rank` basis rows; singular values decay geometrically
/// (`decay^i`), plus uniform noise of size `noise`; values are non-negative like visibility.
fn clustered_low_rank(
    rows_per_group: usize,
    groups: usize,
    rank: usize,
    decay: f64,
    noise: f64,
    resolution: u32,
    seed: u64,
) -> TransferMatrix {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Cubemap::new(resolution).texel_count();
    let mut rows = vec![];
    for _ in 0..groups {
        let support: Vec<bool> = (0..n).map(|_| rng.gen::<f64>() < 0.6).collect();
        let offset: Vec<f64> = (0..n).map(|_| rng.gen_range(0.5..1.0)).collect();
        let basis: Vec<Vec<f64>> = (0..rank).map(|_| (0..n).map(|_| rng.gen_range(-0.5..0.5)).collect()).collect();
        for _ in 0..rows_per_group {
            let w: Vec<f64> = (0..rank).map(|i| rng.gen_range(-1.0..1.0) * decay.powi(i as i32)).collect();
            rows.push(
                (0..n)
                    .map(|k| {
                        if !support[k] {
                            return 0.0;
                        }
                        let v = offset[k]
                            + (0..rank).map(|i| w[i] * basis[i][k]).sum::<f64>() * 0.5
                            + noise * rng.gen_range(-1.0..1.0);
                        v.max(0.0)
                    })
                    .collect(),
            );
        }
    }
    from_dense(&rows, resolution)
}

/// Per-row bound for a form that represents its rows exactly up to f32 storage: the decoded
/// row `mu + sum_c w_c u_c` (C + 1 stored terms, each rounded to f32, plus the f32 rounding
/// of the coefficients that were computed in f64) differs from x by at most about
/// `(C + 3) eps (||mu|| + ||x - mu||)` in L2, so by Cauchy-Schwarz `|error of L*_r| <=
/// (C + 3) eps (||mu|| + ||x - mu||) ||L||`; we allow 4x for the final f32 rounding of the
/// output and the f32 table used for the coefficients.
fn assert_exact(cpca: &Cpca, form: &CompressedForm, t: &TransferMatrix, light: &LightVector) {
    let got = cpca.gather(form, light).unwrap();
    let reference = reference_product(t, light);
    let dense = to_dense(t);
    let (k, c, n) = (form.meta("clusters").unwrap() as usize, form.meta("components").unwrap() as usize, form.cols());
    let (basis, cluster) = (form.f32s("basis").unwrap(), form.u16s("cluster").unwrap());
    let lnorm: [f64; 3] =
        std::array::from_fn(|ch| light.power.iter().map(|p| (p[ch] as f64).powi(2)).sum::<f64>().sqrt());
    crate::testing::assert_within(&got, &reference, |r, ch| {
        let id = cluster[r] as usize;
        let (mu_norm, res_norm) = if id == k {
            (0.0, 0.0)
        } else {
            let mu = &basis[id * (c + 1) * n..(id * (c + 1) + 1) * n];
            let mu_norm = mu.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
            let res = dense[r].iter().zip(mu).map(|(x, &m)| (x - m as f64).powi(2)).sum::<f64>().sqrt();
            (mu_norm, res)
        };
        4.0 * (c as f64 + 3.0) * EPS * (mu_norm + res_norm) * lnorm[ch] + EPS * reference[r][ch].abs()
    });
}

/// Eigenvalues (decreasing) of the scatter matrix of the centred rows, in f64 (dense, small).
fn centred_spectrum(rows: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (m, n) = (rows.len(), rows[0].len());
    let mean: Vec<f64> = (0..n).map(|k| rows.iter().map(|r| r[k]).sum::<f64>() / m as f64).collect();
    let mut s = vec![0.0; n * n];
    for r in rows {
        for a in 0..n {
            let da = r[a] - mean[a];
            for b in 0..n {
                s[a * n + b] += da * (r[b] - mean[b]);
            }
        }
    }
    let (values, vectors) = biscale_core::linalg::eigen::sym_eigen(&s, n);
    (values, vectors, mean)
}

// One cluster: CPCA is mean + top-C PCA, whose squared error is the Eckart-Young optimum
// sum_{i > C} lambda_i of the centred scatter matrix, and whose reconstruction is the
// projection onto the top C eigenvectors. The test matrix has singular values decaying by 1/2
// per index, so with l = C + 8 columns and 2 power iterations the randomised subspace is
// exact to ~(2^-8)^5 relative, far below the f32 storage error (~1e-7 relative): the errors
// must agree to 1e-4 relative (plus an f32-storage floor), the gathers to 1e-5.
#[test]
fn one_cluster_matches_dense_eigen_decomposition() {
    let t = clustered_low_rank(80, 1, 16, 0.5, 1e-5, 4, 1);
    let dense = to_dense(&t);
    let (values, vectors, mean) = centred_spectrum(&dense);
    let n = t.cols();
    let total: f64 = dense.iter().flatten().map(|x| x * x).sum();
    for c in [1usize, 2, 4, 8] {
        let cpca = Cpca::new(1, c);
        let form = cpca.compress(&t, &CompressContext::default()).unwrap();
        assert_eq!(form.meta("clusters").unwrap(), 1);
        let got = frob2(&decode(&form), &dense);
        let optimum: f64 = values[c..].iter().map(|v| v.max(0.0)).sum();
        assert!(got >= optimum * (1.0 - 1e-6) - 1e-12 * total, "C={c}: {got} below the optimum {optimum}?");
        assert!(got <= optimum * (1.0 + 1e-4) + 1e-12 * total, "C={c}: error {got}, optimum {optimum}");
        // The same L* as the truncated eigen-decomposition computed here.
        let svd_rows: Vec<Vec<f64>> = dense
            .iter()
            .map(|r| {
                let mut out = mean.clone();
                for j in 0..c {
                    let w: f64 = (0..n).map(|a| (r[a] - mean[a]) * vectors[a * n + j]).sum();
                    (0..n).for_each(|a| out[a] += w * vectors[a * n + j]);
                }
                out
            })
            .collect();
        let light = random_light(4, 3);
        let want = reference_product(&from_dense(&svd_rows, 4), &light);
        let approx = cpca.gather(&form, &light).unwrap();
        let diff = relative_l2_error(approx.values(), &want);
        assert!(diff < 1e-5, "C={c}: L* differs from the truncated SVD's by {diff}");
        // The tolerance discriminates: a random C-dimensional subspace (no power iteration,
        // no oversampling) is far from optimal on this matrix.
        let crippled =
            Cpca { clusters: 1, components: c, iterations: 1, power_iterations: 0, oversampling: 0, ..Cpca::default() };
        let bad = frob2(&decode(&crippled.compress(&t, &CompressContext::default()).unwrap()), &dense);
        assert!(bad > optimum * 1.01, "C={c}: a random subspace scored {bad} against {optimum}");
    }
}

// The objective (squared reconstruction error of T) cannot grow with C for one cluster
// (nested optimal subspaces) and, on data made of well separated groups, falls as K grows
// towards the number of groups; the gather error follows.
#[test]
fn error_falls_as_clusters_and_components_grow() {
    let t = clustered_low_rank(40, 6, 4, 0.7, 0.02, 4, 2);
    let dense = to_dense(&t);
    let light = random_light(4, 4);
    let reference = reference_product(&t, &light);
    let run = |k: usize, c: usize| {
        let cpca = Cpca::new(k, c);
        let form = cpca.compress(&t, &CompressContext { seed: 5, progress: None, sweep: None }).unwrap();
        (frob2(&decode(&form), &dense), relative_l2_error(cpca.gather(&form, &light).unwrap().values(), &reference))
    };
    for k in [1usize, 4] {
        let mut last = (f64::INFINITY, f64::INFINITY);
        for c in [0usize, 1, 2, 4, 8] {
            let e = run(k, c);
            assert!(e.0 <= last.0 * (1.0 + 1e-6), "K={k} C={c}: {e:?} after {last:?}");
            last = e;
        }
    }
    let mut last = (f64::INFINITY, f64::INFINITY);
    for k in [1usize, 2, 3, 6] {
        let e = run(k, 2);
        assert!(e.0 < last.0, "K={k}: {e:?} after {last:?}");
        assert!(e.1 < last.1, "K={k}: {e:?} after {last:?}");
        last = e;
    }
    // Six groups of rank-4 rows with K = 6, C = 4: only the 2% noise remains.
    let (f, g) = run(6, 4);
    assert!(f < 0.01 * dense.iter().flatten().map(|x| x * x).sum::<f64>(), "{f}");
    assert!(g < 0.01, "{g}");
}

#[test]
fn more_components_than_values_is_an_error_naming_both() {
    // Regression (hostile input): components = 6145 with N = 384 was clamped inside while
    // metrics reported 6145.
    let t = random_transfer(6, 2, 2, 0.4, 3);
    let e = Cpca::new(2, 25).compress(&t, &CompressContext::default()).unwrap_err().to_string();
    assert!(e.contains("components = 25") && e.contains("24 values"), "{e}");
}

#[test]
fn full_rank_components_are_exact_including_hdr_sun() {
    // 24 rows x 24 columns: C = 24 (= N) spans everything.
    let t = random_transfer(6, 2, 2, 0.4, 3);
    for k in [1usize, 3] {
        let cpca = Cpca::new(k, 24); // C = N
        let form = cpca.compress(&t, &CompressContext::default()).unwrap();
        assert_eq!(form.meta("components").unwrap(), 24);
        for light_seed in [6, 7] {
            assert_exact(&cpca, &form, &t, &random_light(2, light_seed));
        }
    }
    // Clusters with fewer rows than components (rank-deficient): 12 rows, C = 16 < N = 96.
    let t = random_transfer(3, 2, 4, 0.3, 4);
    for k in [1usize, 2, 5] {
        let cpca = Cpca::new(k, 16);
        let form = cpca.compress(&t, &CompressContext::default()).unwrap();
        assert_exact(&cpca, &form, &t, &random_light(4, 9));
    }
}

#[test]
fn all_zero_rows_gather_to_zero() {
    let mut rows = to_dense(&random_transfer(12, 1, 2, 0.5, 8));
    for r in [0, 3, 4, 11] {
        rows[r].fill(0.0);
    }
    let t = from_dense(&rows, 2);
    let cpca = Cpca::new(2, 1);
    let form = cpca.compress(&t, &CompressContext::default()).unwrap();
    let k = form.meta("clusters").unwrap() as u16;
    let cluster = form.u16s("cluster").unwrap();
    let got = cpca.gather(&form, &random_light(2, 1)).unwrap();
    for r in 0..rows.len() {
        let zero = [0, 3, 4, 11].contains(&r);
        assert_eq!(cluster[r] == k, zero, "row {r}");
        if zero {
            assert_eq!(got.values()[r], [0.0; 3]);
        }
    }
    // Only non-zero rows cost flops: 2 N K (C + 1) + 2 C (8 rows).
    assert_eq!(form.flops_per_gather, 2 * 24 * k as u64 * 2 + 2 * 8);
    // An all-zero matrix compresses to nothing and gathers to zero.
    let z = random_transfer(6, 1, 2, 0.0, 0);
    let form = cpca.compress(&z, &CompressContext::default()).unwrap();
    assert!(form.lossless);
    assert_eq!(form.meta("clusters").unwrap(), 0);
    assert!(cpca.gather(&form, &random_light(2, 3)).unwrap().values().iter().all(|v| *v == [0.0; 3]));
}

#[test]
fn more_clusters_than_rows_and_duplicates() {
    // 10 rows, 50 clusters: every row its own cluster (its mean), exact with C = 0.
    let t = random_transfer(10, 1, 2, 0.5, 5);
    let cpca = Cpca::new(50, 0);
    let form = cpca.compress(&t, &CompressContext::default()).unwrap();
    assert_eq!(form.meta("clusters").unwrap(), 10);
    assert_exact(&cpca, &form, &t, &random_light(2, 11));
    // Only two distinct rows, K = 4: seeding stops at 2 clusters, still exact.
    let dense = to_dense(&random_transfer(2, 1, 2, 0.5, 6));
    let rows: Vec<Vec<f64>> = (0..9).map(|i| dense[i % 2].clone()).collect();
    let t = from_dense(&rows, 2);
    let cpca = Cpca::new(4, 2);
    let form = cpca.compress(&t, &CompressContext::default()).unwrap();
    assert_eq!(form.meta("clusters").unwrap(), 2);
    assert_exact(&cpca, &form, &t, &random_light(2, 13));
}

#[test]
fn degenerate_tiny_matrices() {
    // One row.
    let t = random_transfer(1, 1, 2, 0.5, 1);
    let cpca = Cpca::default();
    let form = cpca.compress(&t, &CompressContext::default()).unwrap();
    assert_exact(&cpca, &form, &t, &random_light(2, 1));
    // One non-zero column of the smallest cubemap (N = 6).
    let cubemap = LightBasis::cubemap(1).unwrap();
    let one = |vals: Vec<f32>| {
        let rows = vals.len();
        let indptr = (0..=rows).collect();
        let csr = sprs::CsMat::new((rows, 6), indptr, vec![0; rows], vals);
        TransferMatrix::new(LocalBasis::bins(1).unwrap(), cubemap, csr).unwrap()
    };
    let mut power = vec![[0.0; 3]; 6];
    power[0] = [1e6, 2.0, 0.5];
    let light = LightVector::new(cubemap, power).unwrap();
    for vals in [vec![0.5f32], vec![0.25, 1.0, 0.75, 0.25]] {
        let t = one(vals.clone());
        // One cluster with C = 1 or C = N = 6, or a cluster per distinct value.
        for (k, c) in [(1, 1), (1, 6), (3, 0)] {
            let cpca = Cpca::new(k, c);
            let form = cpca.compress(&t, &CompressContext::default()).unwrap();
            assert!(form.meta("components").unwrap() <= 6);
            assert_exact(&cpca, &form, &t, &light);
        }
        // One cluster, no components: every row gathers the mean (exact f32 sums here).
        let cpca = Cpca::new(1, 0);
        let form = cpca.compress(&t, &CompressContext::default()).unwrap();
        let mean = vals.iter().sum::<f32>() / vals.len() as f32;
        for &v in cpca.gather(&form, &light).unwrap().values() {
            assert_eq!(v, [mean * 1e6, mean * 2.0, mean * 0.5]);
        }
    }
}

// The gather equals the decoded rows times L in f64, up to the final f32 rounding of each
// output and the f64 summation order (1e-12 relative to sum |terms|).
#[test]
fn gather_matches_decoded_rows() {
    let t = clustered_low_rank(30, 3, 5, 0.8, 0.05, 4, 7);
    let cpca = Cpca::new(3, 2);
    let form = cpca.compress(&t, &CompressContext::default()).unwrap();
    let decoded = decode(&form);
    for light_seed in [2, 3] {
        let light = random_light(4, light_seed);
        let got = cpca.gather(&form, &light).unwrap();
        for (r, row) in decoded.iter().enumerate() {
            for ch in 0..3 {
                let terms: Vec<f64> = row.iter().zip(&light.power).map(|(x, l)| x * l[ch] as f64).collect();
                let want: f64 = terms.iter().sum();
                let scale: f64 = terms.iter().map(|x| x.abs()).sum();
                // The gather projects first, so its rounding is bounded via the stored terms.
                let bound = EPS * want.abs() + 1e-12 * scale * (form.meta("components").unwrap() as f64 + 1.0);
                assert!((got.values()[r][ch] as f64 - want).abs() <= bound, "row {r}");
            }
        }
    }
}

// The sparse expansion equals the dense residual (both f64; the expansion cancels about
// eps ||T||^2, so 1e-6 relative on an error of order 0.1 is ample).
#[test]
fn frobenius_error_matches_dense_decode() {
    let t = clustered_low_rank(30, 3, 5, 0.8, 0.05, 4, 8);
    let dense = to_dense(&t);
    for (k, c) in [(1, 0), (2, 1), (3, 3)] {
        let form = Cpca::new(k, c).compress(&t, &CompressContext::default()).unwrap();
        let want = (frob2(&decode(&form), &dense) / dense.iter().flatten().map(|x| x * x).sum::<f64>()).sqrt();
        let got = relative_frobenius_error(&form, &t).unwrap();
        assert!((got - want).abs() <= 1e-6 * want.max(1e-3), "K={k} C={c}: {got} vs {want}");
    }
}

#[test]
fn same_seed_same_bytes_and_storage_is_counted() {
    let t = clustered_low_rank(50, 4, 3, 0.7, 0.05, 4, 9);
    let cpca = Cpca::new(5, 3);
    let ctx = CompressContext { seed: 42, progress: None, sweep: None };
    let a = cpca.compress(&t, &ctx).unwrap();
    let b = cpca.compress(&t, &ctx).unwrap();
    assert_eq!(a.arrays, b.arrays);
    let k = a.meta("clusters").unwrap();
    assert_eq!(a.bytes(), 4 * k * 4 * 96 + 2 * 200 + 4 * 200 * 3);
    assert!(!a.lossless);
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let t = random_transfer(4, 1, 2, 0.5, 0);
    let ctx = CompressContext::default();
    assert!(matches!(Cpca::new(0, 2).compress(&t, &ctx), Err(CompressError::Params(_))));
    assert!(matches!(Cpca::new(70_000, 2).compress(&t, &ctx), Err(CompressError::Params(_))));
    assert!(matches!(Cpca { iterations: 0, ..Cpca::default() }.compress(&t, &ctx), Err(CompressError::Params(_))));
    // A non-finite value cannot reach a compressor: T refuses it.
    let mut csr = t.csr().clone();
    csr.data_mut()[0] = f32::INFINITY;
    assert!(TransferMatrix::new(t.local_basis(), t.light_basis(), csr).is_err());
    let form = Cpca::default().compress(&t, &ctx).unwrap();
    assert!(matches!(Cpca::default().gather(&form, &random_light(4, 0)), Err(CompressError::LightBasis { .. })));
    let mut broken = form.clone();
    broken.meta.insert("clusters".into(), 99);
    assert!(matches!(Cpca::default().gather(&broken, &random_light(2, 0)), Err(CompressError::Malformed { .. })));
}

/// Vertex units (Sloan et al.'s clustering of whole per-vertex matrices): one cluster id and one
/// coefficient set per vertex; with a cluster per vertex and no components every vertex is its
/// own mean (exact), the gather equals the decoded rows, the Frobenius error matches the dense
/// decode, and a request too large to fit is refused with its estimate before anything is
/// allocated.
#[test]
fn vertex_units_cluster_whole_blocks() {
    let t = random_transfer(12, 2, 2, 0.4, 5);
    let ctx = CompressContext::default();
    let vertex = |k: usize, c: usize| Cpca { unit: CpcaUnit::Vertex, ..Cpca::new(k, c) };
    let form = vertex(12, 0).compress(&t, &ctx).unwrap();
    assert_eq!(form.meta("unit_rows").unwrap(), 4);
    assert_eq!((form.u16s("cluster").unwrap().len(), form.f32s("coeffs").unwrap().len()), (12, 0));
    let light = random_light(2, 4);
    crate::testing::assert_lossless(&vertex(12, 0), &form, &t, &light);
    let dense = to_dense(&t);
    for (k, c) in [(1usize, 0usize), (2, 2), (3, 5)] {
        let cpca = vertex(k, c);
        let form = cpca.compress(&t, &ctx).unwrap();
        let decoded = decode(&form);
        let want = (frob2(&decoded, &dense) / dense.iter().flatten().map(|x| x * x).sum::<f64>()).sqrt();
        let got = relative_frobenius_error(&form, &t).unwrap();
        assert!((got - want).abs() <= 1e-6 * want.max(1e-3), "K={k} C={c}: {got} vs {want}");
        let lstar = cpca.gather(&form, &light).unwrap();
        let reference: Vec<[f64; 3]> = decoded
            .iter()
            .map(|row| std::array::from_fn(|ch| row.iter().zip(&light.power).map(|(x, l)| x * l[ch] as f64).sum()))
            .collect();
        crate::testing::assert_within(&lstar, &reference, |r, ch| {
            let scale: f64 = decoded[r].iter().zip(&light.power).map(|(x, l)| (x * l[ch] as f64).abs()).sum();
            EPS * reference[r][ch].abs() + 1e-12 * scale * (c as f64 + 1.0)
        });
    }
    // The reference bins T as vertex units: 64 clusters x 9 vectors of 64 x 6144 values.
    let big = random_transfer(2, 8, 32, 0.01, 1);
    let e = vertex(64, 8).compress(&big, &ctx).unwrap_err();
    assert!(matches!(&e, CompressError::TooLarge(m) if m.contains("GiB")), "{e}");
}

#[test]
fn cpca_declares_itself_whole_and_refuses_parts() {
    let t = random_transfer(8, 2, 4, 0.3, 14);
    let c = Cpca::default();
    let Separability::Whole { why } = c.separability(t.shape()) else { panic!("cpca is not separable") };
    assert!(why.contains("k-means"), "{why}");
    let part = t.vertex_rows(4..8).unwrap();
    assert!(c.compress_part(&part, 4, &CompressContext::default()).is_err());
    assert!(c.merge_parts(t.shape(), vec![]).is_err());
}
