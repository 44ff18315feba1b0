//! Linear algebra shared by the stages that compress with principal components: the clustered
//! PCA of the CPCA transfer compressor and of local-PCA BTFs ([`cpca`]), and the small dense
//! f64 routines it needs ([`eigen`]). One copy, so both compressions have the same build and
//! the same guarantees.

pub mod cpca;
pub mod eigen;

pub use cpca::{clustered_pca, ClusteredPca, CpcaSettings, DenseRows, RowSet, SparseRows};
