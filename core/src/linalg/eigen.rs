//! The small dense linear algebra clustered PCA needs, in f64: a cyclic Jacobi eigen solver for the
//! (C + p) x (C + p) Rayleigh-Ritz matrices and Gram-Schmidt orthonormalisation of tall
//! N x l bases. Both are textbook (Golub & Van Loan, sections 8.5 and 5.2) and small enough
//! to own rather than pull a dense linear algebra crate into a 2-core build.

/// Eigen-decomposition of the symmetric `n x n` matrix `a` (row-major; only its symmetric part
/// is used): eigenvalues in decreasing order and the matching orthonormal eigenvectors as the
/// columns of a row-major `n x n` matrix. Cyclic Jacobi rotations until every off-diagonal
/// entry is below `1e-15` of the matrix's norm (converges quadratically; 60 sweeps cap).
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    assert_eq!(a.len(), n * n, "sym_eigen: matrix is not n x n");
    let mut m: Vec<f64> = (0..n * n).map(|i| 0.5 * (a[i] + a[(i % n) * n + i / n])).collect();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    let norm = m.iter().map(|x| x * x).sum::<f64>().sqrt();
    let tol = 1e-15 * norm;
    for _sweep in 0..60 {
        let off =
            (0..n).flat_map(|p| (p + 1..n).map(move |q| (p, q))).map(|(p, q)| m[p * n + q].abs()).fold(0.0, f64::max);
        if off <= tol || norm == 0.0 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq.abs() <= tol {
                    continue;
                }
                // Rotation angle that zeroes (p, q) (Golub & Van Loan, Algorithm 8.5.1).
                let theta = (m[q * n + q] - m[p * n + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (mkp, mkq) = (m[k * n + p], m[k * n + q]);
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let (mpk, mqk) = (m[p * n + k], m[q * n + k]);
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| m[j * n + j].total_cmp(&m[i * n + i]).then(i.cmp(&j)));
    let values = order.iter().map(|&i| m[i * n + i]).collect();
    let mut vectors = vec![0.0; n * n];
    for (new, &old) in order.iter().enumerate() {
        for k in 0..n {
            vectors[k * n + new] = v[k * n + old];
        }
    }
    (values, vectors)
}

/// Orthonormalise the `l` columns of the row-major `rows x l` matrix `q` in place by modified
/// Gram-Schmidt, twice ("twice is enough", Giraud et al. 2005). A column whose norm falls
/// below `1e-10` of its norm before projection lies (numerically) in the span of the earlier
/// ones: it is replaced by `fallback(column)` and orthonormalised again; if that fails too it is
/// set to zero. Returns the number of columns that are non-zero (they come first only if no
/// column was zeroed; callers treat zero columns as absent).
pub fn orthonormalize_columns(
    q: &mut [f64],
    rows: usize,
    l: usize,
    mut fallback: impl FnMut(usize, &mut [f64]),
) -> usize {
    assert_eq!(q.len(), rows * l);
    // Work on a column-major copy: every pass below runs down whole columns, which in the
    // row-major q would be strided by l (a cache line or more per element for tall bases).
    // The arithmetic, and so the result, is the same.
    let mut cols = vec![0.0; rows * l];
    for (i, row) in q.chunks_exact(l.max(1)).enumerate().take(rows) {
        for (j, &x) in row.iter().enumerate() {
            cols[j * rows + i] = x;
        }
    }
    let mut col = vec![0.0; rows];
    let mut live = 0;
    for j in 0..l {
        let mut ok = false;
        for attempt in 0..3 {
            if attempt > 0 {
                fallback(j, &mut col);
            } else {
                col.copy_from_slice(&cols[j * rows..(j + 1) * rows]);
            }
            let before = col.iter().map(|x| x * x).sum::<f64>().sqrt();
            if before == 0.0 || !before.is_finite() {
                continue;
            }
            for _pass in 0..2 {
                for k in 0..j {
                    let qk = &cols[k * rows..(k + 1) * rows];
                    let dot: f64 = qk.iter().zip(&col).map(|(a, b)| a * b).sum();
                    if dot != 0.0 {
                        for (c, &x) in col.iter_mut().zip(qk) {
                            *c -= dot * x;
                        }
                    }
                }
            }
            let after = col.iter().map(|x| x * x).sum::<f64>().sqrt();
            if after > 1e-10 * before {
                for (d, &c) in cols[j * rows..(j + 1) * rows].iter_mut().zip(&col) {
                    *d = c / after;
                }
                ok = true;
                break;
            }
        }
        if ok {
            live += 1;
        } else {
            cols[j * rows..(j + 1) * rows].fill(0.0);
        }
    }
    for (i, row) in q.chunks_exact_mut(l.max(1)).enumerate().take(rows) {
        for (j, x) in row.iter_mut().enumerate() {
            *x = cols[j * rows + i];
        }
    }
    live
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_symmetric(n: usize, rank: usize, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let b: Vec<f64> = (0..n * rank).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..rank).map(|k| b[i * rank + k] * b[j * rank + k]).sum();
            }
        }
        a
    }

    // Reconstruction A V = V diag(lambda) and V^T V = I to 1e-12 relative: Jacobi is backward
    // stable with error O(n eps ||A||) (Golub & Van Loan 8.5); n <= 40 gives ~1e-14.
    #[test]
    fn jacobi_reconstructs_random_and_rank_deficient_matrices() {
        for (n, rank, seed) in [(1, 1, 0), (2, 2, 1), (5, 5, 2), (16, 3, 3), (24, 24, 4), (40, 10, 5), (6, 0, 6)] {
            let a = random_symmetric(n, rank, seed);
            let (values, v) = sym_eigen(&a, n);
            let norm = a.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
            for w in values.windows(2) {
                assert!(w[0] >= w[1]);
            }
            for i in 0..n {
                for j in 0..n {
                    let av: f64 = (0..n).map(|k| a[i * n + k] * v[k * n + j]).sum();
                    assert!((av - values[j] * v[i * n + j]).abs() <= 1e-12 * norm, "n={n} rank={rank}");
                    let vtv: f64 = (0..n).map(|k| v[k * n + i] * v[k * n + j]).sum();
                    assert!((vtv - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
                }
            }
            // A rank-r PSD matrix has n - r zero eigenvalues.
            for &l in &values[rank.min(n)..] {
                assert!(l.abs() <= 1e-12 * norm, "n={n} rank={rank}: {l}");
            }
        }
        // Diagonal input with repeated values: already converged, order is decreasing.
        let (values, _) = sym_eigen(&[1.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 3.0], 3);
        assert_eq!(values, vec![3.0, 3.0, 1.0]);
    }

    #[test]
    fn gram_schmidt_orthonormalises_and_replaces_dependent_columns() {
        let (rows, l) = (50, 6);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut q: Vec<f64> = (0..rows * l).map(|_| rng.gen_range(-1.0..1.0)).collect();
        // Column 3 = column 0 + column 1 (dependent); column 5 = 0.
        for i in 0..rows {
            q[i * l + 3] = q[i * l] + q[i * l + 1];
            q[i * l + 5] = 0.0;
        }
        let mut replaced = vec![];
        let live = orthonormalize_columns(&mut q, rows, l, |j, col| {
            replaced.push(j);
            for (i, x) in col.iter_mut().enumerate() {
                *x = ((i * 31 + j * 7) % 13) as f64 - 6.0;
            }
        });
        assert_eq!(live, 6);
        assert_eq!(replaced, vec![3, 5]);
        for a in 0..l {
            for b in 0..l {
                let d: f64 = (0..rows).map(|i| q[i * l + a] * q[i * l + b]).sum();
                assert!((d - if a == b { 1.0 } else { 0.0 }).abs() < 1e-13);
            }
        }
        // With no usable fallback, dependent columns become zero.
        let mut q2 = vec![1.0, 1.0, 2.0, 2.0]; // 2 x 2, columns equal
        assert_eq!(orthonormalize_columns(&mut q2, 2, 2, |_, col| col.fill(0.0)), 1);
        assert_eq!(q2[1], 0.0);
        assert_eq!(q2[3], 0.0);
    }
}
