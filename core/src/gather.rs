//! Local incident radiance `L* = T L` and its f64 reference.
//!
//! Every compressed gather (CPU or GPU) is checked against [`reference_product`], which
//! accumulates each row of the uncompressed `T` in f64.

pub mod moments;

use crate::basis::LocalBasis;
use crate::error::{CoreError, Result};
use crate::sampling::LightVector;
use crate::transfer::TransferMatrix;
use crate::Rgb;

/// `L*` for every vertex: `values[v * M + j]`, RGB, the coefficient of local basis function
/// `j` (for bins: the power through bin `j`). The length is `vertices * M` by construction.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalRadiance {
    basis: LocalBasis,
    vertices: usize,
    values: Vec<Rgb>,
}

impl LocalRadiance {
    /// `L*` from row values; an error unless there are `vertices * basis.len()` of them.
    pub fn new(basis: LocalBasis, vertices: usize, values: Vec<Rgb>) -> Result<Self> {
        if values.len() != vertices * basis.len() {
            return Err(CoreError::Invalid(format!(
                "L* has {} values, {vertices} vertices of {basis} need {}",
                values.len(),
                vertices * basis.len()
            )));
        }
        Ok(Self { basis, vertices, values })
    }

    /// All zeros.
    pub fn zeros(basis: LocalBasis, vertices: usize) -> Self {
        Self { basis, vertices, values: vec![[0.0; 3]; vertices * basis.len()] }
    }

    /// The exact product rounded to f32 (the uncompressed `L*`).
    pub fn from_f64(basis: LocalBasis, vertices: usize, values: &[[f64; 3]]) -> Result<Self> {
        Self::new(basis, vertices, values.iter().map(|v| v.map(|x| x as f32)).collect())
    }

    pub fn basis(&self) -> LocalBasis {
        self.basis
    }
    pub fn vertices(&self) -> usize {
        self.vertices
    }
    /// `M`, the coefficients per vertex.
    pub fn local_dirs(&self) -> usize {
        self.basis.len()
    }
    /// Every row, `values[v * M + j]`.
    pub fn values(&self) -> &[Rgb] {
        &self.values
    }
    /// Every row, writable (the length stays fixed).
    pub fn values_mut(&mut self) -> &mut [Rgb] {
        &mut self.values
    }

    /// The `M` coefficients of vertex `v`.
    pub fn vertex(&self, v: usize) -> &[Rgb] {
        let m = self.basis.len();
        &self.values[v * m..(v + 1) * m]
    }
}

/// `T L` with every row accumulated in f64 (the reference for all gathers).
///
/// # Panics
/// If `light` is not in `t`'s light basis (a caller bug: the bases come from one
/// `TransferSettings`).
pub fn reference_product(t: &TransferMatrix, light: &LightVector) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    assert_eq!(t.light_basis(), light.basis(), "the light vector must be in T's light basis");
    let csr = t.csr();
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
    crate::stats::relative_l2(num, den)
}
