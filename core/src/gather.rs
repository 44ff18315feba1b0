//! Local incident radiance `L* = T L` and its f64 reference.
//!
//! Every compressed gather (CPU or GPU) is checked against [`reference_product`], which
//! accumulates each row of the uncompressed `T` in f64.

use crate::sampling::LightVector;
use crate::transfer::TransferMatrix;
use crate::Rgb;

/// `L*` for every vertex and local direction: `values[v * local_dirs + j]`, RGB power per bin.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalRadiance {
    pub vertices: usize,
    pub local_dirs: usize,
    pub values: Vec<Rgb>,
}

impl LocalRadiance {
    pub fn zeros(vertices: usize, local_dirs: usize) -> Self {
        Self { vertices, local_dirs, values: vec![[0.0; 3]; vertices * local_dirs] }
    }

    /// The `M` bins of vertex `v`.
    pub fn vertex(&self, v: usize) -> &[Rgb] {
        &self.values[v * self.local_dirs..(v + 1) * self.local_dirs]
    }
}

/// `T L` with every row accumulated in f64 (the reference for all gathers).
pub fn reference_product(t: &TransferMatrix, light: &LightVector) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    assert_eq!(t.cols(), light.len(), "light vector size must match T's columns");
    let csr = &t.csr;
    (0..csr.rows())
        .into_par_iter()
        .map(|r| {
            let row = csr.outer_view(r).expect("row in range");
            let mut acc = [0.0f64; 3];
            for (k, &v) in row.iter() {
                let l = light.power[k];
                for c in 0..3 {
                    acc[c] += v as f64 * l[c] as f64;
                }
            }
            acc
        })
        .collect()
}

/// Relative L2 error `||a - ref|| / ||ref||` over all rows and channels (0 when both are 0).
pub fn relative_l2_error(approx: &[Rgb], reference: &[[f64; 3]]) -> f64 {
    assert_eq!(approx.len(), reference.len());
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, r) in approx.iter().zip(reference) {
        for c in 0..3 {
            let d = a[c] as f64 - r[c];
            num += d * d;
            den += r[c] * r[c];
        }
    }
    if den == 0.0 {
        if num == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (num / den).sqrt()
    }
}
