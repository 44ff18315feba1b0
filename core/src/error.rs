//! Typed errors of the core stages. Every variant names the input it concerns.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// A bad or unreadable input file.
    #[error("{}: {message}", path.display())]
    Input { path: PathBuf, message: String },
    /// Input data that is inconsistent or out of range (not tied to a file).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// A request that would need more memory than allowed.
    #[error("too large: {0}")]
    TooLarge(String),
    /// An output path biscale will not write: something is there that it did not write (a
    /// user's file, a link, a device node, a FIFO, a folder).
    #[error("{}: {message}", path.display())]
    Refused { path: PathBuf, message: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A stage output file that cannot be read back.
    #[error(transparent)]
    Artifact(#[from] crate::artifact::ArtifactError),
}

pub type Result<T, E = CoreError> = std::result::Result<T, E>;
