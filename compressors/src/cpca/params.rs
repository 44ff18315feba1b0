//! The parameters of the CPCA compressor (config keys, `metrics.json` params, label
//! `cpca-k<clusters>-c<components>`).

use biscale_core::compress::CompressError;
use serde::{Deserialize, Serialize};

/// Clustered PCA of the rows of `T`. Every field is a config key with the default given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct Cpca {
    /// Number of clusters K (at most 65534: ids are u16 with one sentinel). Fewer are made when
    /// the matrix has fewer distinct non-zero rows. Default (the reference): 32.
    pub clusters: usize,
    /// Principal components per cluster C, besides the mean (at most N, an error above; 0 keeps the cluster
    /// means only). Default: 8.
    pub components: usize,
    /// Most assignment/refit rounds (Sloan et al.'s iterative CPCA); stops earlier when no row
    /// changes cluster. At least 1. Default: 12.
    pub iterations: usize,
    /// Subspace (power) iterations per refit, `Q <- orth(A^T A Q)`. Warm starts from the
    /// previous round's components make a few enough. Default: 2.
    pub power_iterations: usize,
    /// Extra columns of the randomised subspace beyond C (Halko et al.'s p). Default: 8.
    pub oversampling: usize,
    /// What is clustered: `row` (default), every row of `T` on its own, or `vertex`, each
    /// vertex's whole block of M rows as one vector of M N values (Sloan et al.'s clustering of
    /// per-vertex transfer matrices; for the low-frequency method's 25 x 25 matrices).
    pub unit: CpcaUnit,
}

/// The unit CPCA clusters (see [`Cpca::unit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CpcaUnit {
    #[default]
    Row,
    Vertex,
}

impl Default for Cpca {
    /// The comparison setting of Sloan et al. and the biclustering paper: 32 clusters x 8
    /// components.
    fn default() -> Self {
        Self { clusters: 32, components: 8, iterations: 12, power_iterations: 2, oversampling: 8, unit: CpcaUnit::Row }
    }
}

impl Cpca {
    /// `clusters` x `components` with the default iteration settings.
    pub fn new(clusters: usize, components: usize) -> Self {
        Self { clusters, components, ..Self::default() }
    }

    /// These parameters, or what is wrong with them.
    pub fn validated(self) -> Result<Self, String> {
        if self.clusters == 0 || self.clusters > u16::MAX as usize - 1 {
            return Err(format!("cpca clusters = {} must be in 1..=65534", self.clusters));
        }
        if self.iterations == 0 {
            return Err("cpca iterations must be at least 1".into());
        }
        Ok(self)
    }

    /// [`Self::validated`] as the compressor's error.
    pub(crate) fn check(&self) -> Result<(), CompressError> {
        self.validated().map(|_| ()).map_err(CompressError::Params)
    }
}
