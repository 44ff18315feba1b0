//! Rendering methods beside the all-frequency one (`[[methods]]` in a config). The
//! all-frequency method (bins `T`, the compressors of `[[compressors]]`, the BTFs) always runs;
//! each method setting here runs the same scene, light, camera and reference through another
//! transfer, light basis and BTF representation, and gets a record in `metrics.json`
//! (`methods[]`) with the fields of a compressor record plus its own.
//!
//! * [`sh`]: low-frequency bi-scale rendering (Sloan, Liu, Shum, Snyder 2003): the light in
//!   world SH, a per-vertex SH transfer matrix `M_p`, radiance transfer textures.
//!
//! A method's parameters are its own serde type, parsed from its table after sweep expansion
//! (a list value sweeps, as for compressors); [`KINDS`] is the one list of method kinds.

pub mod sh;

use serde_json::Value;

/// One method kind.
pub struct MethodKind {
    /// The config `kind`.
    pub name: &'static str,
    pub about: &'static str,
    /// The setting's label (file names, report rows), e.g. `sh-n5`.
    pub label: fn(&Value) -> Result<String, String>,
    /// Check a setting's parameters when the config is read.
    pub check: fn(&Value) -> Result<(), String>,
}

/// Every method kind, in report order.
pub const KINDS: &[MethodKind] = &[sh::KIND];

/// The kind called `name`.
pub fn find(name: &str) -> Option<&'static MethodKind> {
    KINDS.iter().find(|k| k.name == name)
}

/// The names of every kind, for messages.
pub fn names() -> Vec<&'static str> {
    KINDS.iter().map(|k| k.name).collect()
}
