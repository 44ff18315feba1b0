//! Typed errors of the shading crate. Every variant names the input or file it concerns.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ShadingError {
    /// An I/O failure on a file (reading, creating the temporary file, renaming).
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A file that exists but cannot be decoded or encoded (bad OpenEXR, PNG encoder failure).
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    /// Inputs that do not fit together or are out of range (sizes, grids, parameters).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// A core type refused its inputs (a scene, a BTF, an image file).
    #[error(transparent)]
    Core(#[from] biscale_core::CoreError),
    /// NaN or infinite values where finite ones are required.
    #[error("{what}: {count} non-finite value(s), first at pixel ({}, {})", first.0, first.1)]
    NonFinite { what: String, count: usize, first: (u32, u32) },
}

pub type Result<T, E = ShadingError> = std::result::Result<T, E>;
