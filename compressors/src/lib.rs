//! # biscale-compressors
//!
//! The built-in transfer compressors, a closed set dispatched by one `match` on the config
//! `kind` ([`BuiltinCompressor`]). Each compressor lives in its own module with its
//! documentation, its build, its CPU gather on the compressed arrays, and its tests:
//!
//! * [`sparse`]: the raw CSR matrix, the uncompressed baseline.
//! * [`bicluster`]: lossless greedy constant-column biclustering (Sun et al.), block-parallel.
//! * [`cpca`]: clustered principal components (Sloan et al. 2003), lossy.
//! * [`haar`]: non-linear Haar wavelet approximation per row (Ng et al. 2003), lossy.
//!
//! ```
//! use biscale_compressors::sparse::Sparse;
//! use biscale_core::compress::{Compressor, CompressContext};
//! # let t = biscale_compressors::testing::random_transfer(3, 2, 2, 0.3, 7);
//! # let light = biscale_compressors::testing::random_light(2, 8);
//! let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
//! let lstar = Sparse.gather(&form, &light).unwrap();
//! assert_eq!(lstar.values().len(), t.rows());
//! ```

pub mod bicluster;
pub mod cpca;
pub mod haar;
#[cfg(feature = "plugin")]
pub mod plugin;
pub mod sparse;
pub mod testing;

use biscale_core::compress::{CompressContext, CompressError, CompressedForm, Compressor};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;

/// Every compressor compiled into biscale.
pub enum BuiltinCompressor {
    Sparse(sparse::Sparse),
    Bicluster(bicluster::Bicluster),
    Haar(haar::Haar),
    Cpca(cpca::Cpca),
}

impl BuiltinCompressor {
    /// The config `kind` strings of the built-ins.
    pub const KINDS: &'static [&'static str] = &["sparse", "bicluster", "cpca", "haar"];

    fn inner(&self) -> &dyn Compressor {
        match self {
            BuiltinCompressor::Sparse(c) => c,
            BuiltinCompressor::Bicluster(c) => c,
            BuiltinCompressor::Haar(c) => c,
            BuiltinCompressor::Cpca(c) => c,
        }
    }
}

impl Compressor for BuiltinCompressor {
    fn kind(&self) -> &str {
        self.inner().kind()
    }
    fn params(&self) -> serde_json::Value {
        self.inner().params()
    }
    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext) -> Result<CompressedForm, CompressError> {
        self.inner().compress(t, ctx)
    }
    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        self.inner().gather(form, light)
    }
}
