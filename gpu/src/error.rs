//! Typed errors of the GPU runtime. Every variant says what was being done, so a failure on
//! a machine without a GPU (or with a small one) reads as a sentence, never as a panic.

/// Errors of the wgpu runtime.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter at all (no Vulkan driver: run `scripts/setup-vulkan.sh`).
    #[error("no GPU adapter found ({0}); on a machine without a GPU run scripts/setup-vulkan.sh to install lavapipe")]
    NoAdapter(String),
    /// The adapter refused the device we asked for.
    #[error("could not open a device on adapter '{adapter}': {message}")]
    RequestDevice { adapter: String, message: String },
    /// A resource exceeds one of the adapter's limits; `limit` is the wgpu `Limits` field.
    #[error("{what} needs {needed} but the adapter's {limit} is {max}")]
    Limit { what: String, limit: &'static str, needed: u64, max: u64 },
    /// The compressed form does not fit its gather program or the adapter's indices.
    #[error("compressed form: {0}")]
    Form(String),
    /// A compressed form failed a structural check (missing array, wrong type or length, an
    /// offset or index out of range).
    #[error(transparent)]
    Compress(#[from] biscale_core::compress::CompressError),
    /// Core data refused its inputs (e.g. `L*` read back in the wrong shape).
    #[error(transparent)]
    Core(#[from] biscale_core::CoreError),
    /// A WGSL program failed to parse or does not follow the binding conventions.
    #[error("WGSL program '{program}': {message}")]
    Wgsl { program: String, message: String },
    /// wgpu reported a validation or out-of-memory error (caught by an error scope).
    #[error("wgpu error while {during}: {message}")]
    Validation { during: String, message: String },
    /// Reading a buffer back failed.
    #[error("reading back {what} failed: {message}")]
    Readback { what: String, message: String },
    /// Inputs that cannot be shaded or gathered (mismatched sizes, NaN, ...).
    #[error("invalid input: {0}")]
    Input(String),
    /// The viewer's window or its surface could not be created or used (no display, ...).
    #[error("viewer window: {0}")]
    Window(String),
}

pub type Result<T, E = GpuError> = std::result::Result<T, E>;
