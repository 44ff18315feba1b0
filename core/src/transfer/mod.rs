//! Transfer stage: per-vertex visibility transfer matrices. (Build in progress.)

use crate::sampling::Cubemap;

/// Settings that determine `T`.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferSettings {
    /// Cubemap resolution R of the light (N = 6 R^2). Reference: 32.
    pub cubemap_resolution: u32,
    /// Resolution of the visibility cubemap; a multiple of `cubemap_resolution`.
    /// Reference: 64 (2x2 box filter).
    pub visibility_resolution: u32,
    /// Local direction grid m (M = m^2 bins). Reference: 8.
    pub local_grid: u32,
}

impl Default for TransferSettings {
    fn default() -> Self {
        Self { cubemap_resolution: 32, visibility_resolution: 64, local_grid: 8 }
    }
}

/// The stacked transfer matrix: row `v * M + j`, column = cubemap texel `k`.
/// Values are visibility fractions in (0, 1], multiples of `1 / s^2` for supersampling `s`.
#[derive(Clone, Debug)]
pub struct TransferMatrix {
    pub vertices: usize,
    pub local_dirs: usize,
    pub cubemap: Cubemap,
    pub csr: sprs::CsMat<f32>,
}

impl TransferMatrix {
    pub fn rows(&self) -> usize {
        self.csr.rows()
    }
    pub fn cols(&self) -> usize {
        self.csr.cols()
    }
    pub fn nnz(&self) -> usize {
        self.csr.nnz()
    }
}
