//! # biscale-compressors
//!
//! The transfer compressors. Each built-in is one folder, `<kind>/`, holding everything
//! about it: its documentation and form layout (`mod.rs`), its parameters (`params.rs`: a
//! serde type that serves the config, the setting's label and `metrics.json`), its CPU gather,
//! its GPU gather program (`gather.wgsl`, described by `Compressor::kernels` with the
//! declarative checks the host runs), and its tests (`tests.rs`). [`registry`] lists the kinds
//! (one line each); [`plugin`] loads compressors from shared libraries, which take the same
//! path.
//!
//! * [`sparse`]: the raw CSR matrix, the uncompressed baseline.
//! * [`bicluster`]: lossless greedy constant-column biclustering (Sun et al.), block-parallel.
//! * [`cpca`]: clustered principal components (Sloan et al. 2003), lossy.
//! * [`haar`]: non-linear Haar wavelet approximation per row (Ng et al. 2003), lossy.
//! * [`hosted`]: a compressor the program running biscale supplies (a Python object).
//!
//! ```
//! use biscale_compressors::sparse::Sparse;
//! use biscale_core::compress::{Compressor, CompressContext};
//! # let t = biscale_compressors::testing::random_transfer(3, 2, 2, 0.3, 7);
//! # let light = biscale_compressors::testing::random_light(2, 8);
//! let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
//! let lstar = Sparse.gather(&form, &light).unwrap();
//! assert_eq!(lstar.values().len(), t.rows());
//! // The same form's GPU program, as plain data.
//! assert_eq!(Sparse.kernels(&form).unwrap().kind, "sparse");
//! ```

pub mod bicluster;
pub mod cpca;
pub mod haar;
pub mod hosted;
#[cfg(feature = "plugin")]
pub mod plugin;
pub mod registry;
pub mod sparse;
pub mod testing;
