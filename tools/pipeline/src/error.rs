//! The pipeline's error: one enum, each variant naming the stage and input it concerns.

use biscale_compressors::registry::BuildError;
use biscale_shading::error::ShadingError;
use std::path::{Path, PathBuf};

/// Errors of a pipeline run; each says which stage and input it concerns.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Config(#[from] crate::experiment::config::ConfigError),
    #[error(transparent)]
    Core(#[from] biscale_core::CoreError),
    #[error("compressor {name}: {source}")]
    Build { name: String, source: BuildError },
    #[error("compressor {name}: {source}")]
    Compress { name: String, source: biscale_core::compress::CompressError },
    #[cfg(feature = "gpu")]
    #[error("gpu backend: {0}")]
    Gpu(#[from] biscale_gpu::GpuError),
    #[error(transparent)]
    Shading(#[from] ShadingError),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A material entry whose BTF could not be made (`label` names the entry).
    #[error("material {label}: {source}")]
    Material { label: String, source: ShadingError },
    /// Inputs that do not fit together, named by the file they come from (an OBJ whose
    /// materials the config does not name, a material the config does not have).
    #[error("{}: {what}", path.display())]
    Mismatch { path: PathBuf, what: String },
    #[error(transparent)]
    Viz(#[from] crate::viz::VizError),
    #[error(transparent)]
    Staging(#[from] crate::store::staging::StagingError),
    /// The config asks for something this build was compiled without.
    #[error("{what} needs biscale built with the `{feature}` cargo feature")]
    Feature { what: String, feature: &'static str },
}

pub type Result<T, E = PipelineError> = std::result::Result<T, E>;

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io { path: path.to_path_buf(), source }
}
