//! The registry of compressor kinds: the one list that maps a config `kind` to a compressor.
//! Each entry is declared in its compressor's folder (`<kind>/mod.rs`, `pub const KIND`);
//! adding a compressor is its folder plus one line in [`KINDS`].
//!
//! A compressor's parameters are its own serde type (unknown keys are errors, every key has a
//! documented default), parsed from the config's table for one setting, i.e. after sweep
//! expansion, as JSON. The same type serves the config, the setting's label and
//! `metrics.json` (`Compressor::params`).

use biscale_core::compress::Compressor;
use biscale_core::transfer::TransferSettings;
use serde::de::DeserializeOwned;
use serde_json::Value;

/// Why a setting's compressor could not be made.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The parameters do not parse or are out of range (serde's or the compressor's message).
    #[error("{0}")]
    Params(String),
    /// A plugin library could not be loaded or refused its parameters.
    #[cfg(feature = "plugin")]
    #[error(transparent)]
    Plugin(#[from] crate::plugin::PluginError),
}

impl From<String> for BuildError {
    fn from(m: String) -> Self {
        BuildError::Params(m)
    }
}

/// One compressor kind.
pub struct Kind {
    /// The config `kind`.
    pub name: &'static str,
    /// One line for plans, `--help` and error messages.
    pub about: &'static str,
    /// The setting's label (file names, report rows) from its parameters, e.g. `cpca-k32-c8`.
    pub label: fn(&Value) -> Result<String, String>,
    /// Check a setting's parameters without building anything expensive (the config calls it
    /// when it is read, so a bad key fails before any work).
    pub check: fn(&Value) -> Result<(), String>,
    /// The compressor of one setting (cheap for built-ins: construction only; a plugin loads
    /// its library).
    pub build: fn(&Value) -> Result<Box<dyn Compressor>, BuildError>,
    /// The limits a setting must meet on a transfer shape (more CPCA components than a unit
    /// has values, more Haar terms than a row has), checked when the config is read so the
    /// error names the entry before anything is traced. [`no_limits`] where there are none.
    pub fits: fn(&Value, &TransferSettings) -> Result<(), String>,
    /// The setting's memory on a transfer matrix ([`MemoryFacts`]): its working set while it
    /// compresses, the form included, and the form alone. The run's memory estimate adds it
    /// up; [`csr_copy_memory`] is what a kind that says nothing better is counted as.
    pub memory: fn(&Value, &MemoryFacts) -> FormMemory,
    /// The rows a form's `stats` (`CompressedForm`'s statistics, `metrics.json`'s `stats`)
    /// contribute to the report's table of compressor statistics: a name and a value, in the
    /// order to show them. Empty for a kind whose statistics the report need not show.
    pub report: fn(&Value) -> Vec<(String, String)>,
    /// The flops of one gather of a form of this kind, counted from the form's own arrays and
    /// meta (what `eval --form` reports instead of what a file claims); `None` where the kind
    /// cannot say. Equals what the compressor reported when it built the form.
    pub flops: fn(&biscale_core::compress::CompressedForm) -> Option<u64>,
    /// The part the kind plays where the application needs one kind of a sort: the raw
    /// matrix, the paper's compressor, or one loaded from outside ([`Role`]).
    pub role: Role,
}

/// The part a kind plays in a run beside being one compressor among others. The application
/// asks for a kind by its role, never by its name, so a new kind is its folder plus one line
/// of [`KINDS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// The uncompressed matrix itself: the storage and error every compressed form is set
    /// against (Table I's all-frequency row), and the default compressor of a transfer that
    /// names none (the SH method's `M_p`).
    Raw,
    /// The paper's compressor (radiance transfer biclustering): Table I's compressed row, and
    /// the storage budget of the equal-storage comparison.
    Paper,
    /// Loaded from a shared library: not offered where a built-in kind is required (`eval
    /// --form`, the SH transfer, the cache listing's built-in kinds).
    External,
    /// Any other compressor.
    Other,
}

/// The kind that plays `role` (the first, in [`KINDS`] order).
pub fn by_role(role: Role) -> Option<&'static Kind> {
    KINDS.iter().find(|k| k.role == role)
}

/// The role of the kind called `name` ([`Role::Other`] for a name no kind has).
pub fn role_of(name: &str) -> Role {
    find(name).map_or(Role::Other, |k| k.role)
}

/// What a kind's memory model knows of the transfer matrix it will compress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryFacts {
    /// Light directions `N` (columns of `T`) and local directions `M` (rows per vertex).
    pub light_dirs: u64,
    pub local_dirs: u64,
    pub vertices: u64,
    pub nnz: u64,
    /// Worker threads (blocks in flight).
    pub threads: u64,
}

impl MemoryFacts {
    pub fn rows(&self) -> u64 {
        self.vertices * self.local_dirs
    }

    /// Bytes of `T` as a CSR with u32 indices and f32 values.
    pub fn u32_csr_bytes(&self) -> u64 {
        self.nnz * 8 + (self.rows() + 1) * 4
    }
}

/// A setting's memory: the most it holds while compressing (its form included), and its
/// form alone (what the cache write copies and encodes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FormMemory {
    pub working: u64,
    pub form: u64,
}

/// [`Kind::fits`] of a kind with no shape limits.
pub fn no_limits(_: &Value, _: &TransferSettings) -> Result<(), String> {
    Ok(())
}

/// [`Kind::memory`] of a kind that says nothing better: a u32 CSR copy of `T` (what the
/// plugin host hands a plugin) plus a form of the same size.
pub fn csr_copy_memory(_: &Value, t: &MemoryFacts) -> FormMemory {
    FormMemory { working: 2 * t.u32_csr_bytes(), form: t.u32_csr_bytes() }
}

/// [`Kind::report`] of a kind whose statistics the report does not show.
pub fn no_rows(_: &Value) -> Vec<(String, String)> {
    vec![]
}

/// How a built-in kind makes the compressor of one setting from its parameters (parsed and
/// checked; building a built-in costs nothing, so checking a setting is building it): what
/// [`Kind::built_in`] turns into the entry's `check` and `build`.
pub trait MakeCompressor {
    fn make(p: &Value) -> Result<Box<dyn Compressor>, String>;
}

fn check_by<M: MakeCompressor>(p: &Value) -> Result<(), String> {
    M::make(p).map(drop)
}

fn build_by<M: MakeCompressor>(p: &Value) -> Result<Box<dyn Compressor>, BuildError> {
    Ok(M::make(p)?)
}

/// [`Kind::flops`] of a kind that cannot count its forms' flops from their arrays.
pub fn no_flops(_: &biscale_core::compress::CompressedForm) -> Option<u64> {
    None
}

impl Kind {
    /// The entry of a built-in kind `name` whose settings `M` makes: `check` and `build` from
    /// it, and the defaults an entry overrides where it differs ([`no_limits`],
    /// [`csr_copy_memory`], [`no_rows`], [`no_flops`], [`Role::Other`]), so each entry lists
    /// only what is its own: `Kind { memory, flops, ..Kind::built_in::<Cpca>("cpca", ABOUT,
    /// label) }`.
    pub const fn built_in<M: MakeCompressor>(
        name: &'static str,
        about: &'static str,
        label: fn(&Value) -> Result<String, String>,
    ) -> Kind {
        Kind {
            name,
            about,
            label,
            check: check_by::<M>,
            build: build_by::<M>,
            fits: no_limits,
            memory: csr_copy_memory,
            report: no_rows,
            flops: no_flops,
            role: Role::Other,
        }
    }
}

/// Every compressor kind biscale knows, in report order.
pub const KINDS: &[Kind] = &[
    crate::sparse::KIND,
    crate::bicluster::KIND,
    crate::cpca::KIND,
    crate::haar::KIND,
    crate::hosted::KIND,
    #[cfg(feature = "plugin")]
    crate::plugin::KIND,
];

/// The kind called `name`.
pub fn find(name: &str) -> Option<&'static Kind> {
    KINDS.iter().find(|k| k.name == name)
}

/// The names of every kind, for messages.
pub fn names() -> Vec<&'static str> {
    KINDS.iter().map(|k| k.name).collect()
}

/// Parameters of type `P` from a JSON object: serde's message on an unknown key, a missing
/// one or a wrong type (`unknown field `x`, expected one of ...`).
pub fn parse<P: DeserializeOwned>(params: &Value) -> Result<P, String> {
    serde_json::from_value(params.clone()).map_err(|e| e.to_string())
}

/// The two `Compressor` methods every built-in writes the same way: its kind is its registry
/// entry's name (`KIND` in scope) and its parameters are itself, serialized (the params type
/// is the compressor). Use inside `impl Compressor for ...`.
macro_rules! kind_and_params {
    () => {
        fn kind(&self) -> &str {
            KIND.name
        }

        fn params(&self) -> serde_json::Value {
            serde_json::to_value(self).expect("plain struct serializes")
        }
    };
}
pub(crate) use kind_and_params;

/// The kind called `name` builds the compressor of `params`.
pub fn build(name: &str, params: &Value) -> Result<Box<dyn Compressor>, BuildError> {
    let kind = find(name).ok_or_else(|| {
        BuildError::Params(format!("unknown compressor kind `{name}`, expected one of {:?}", names()))
    })?;
    (kind.build)(params)
}

/// `name` followed by `-{tag}{value}` for each `(key, tag)` whose value `params` has: the
/// label of a setting (`haar-t12`). Values print as they would in a config file.
pub fn tagged_label(name: &str, params: &Value, tags: &[(&str, &str)]) -> String {
    let mut label = name.to_string();
    for (key, tag) in tags {
        if let Some(v) = params.get(*key) {
            let v = match v {
                Value::String(s) => s.clone(),
                v => v.to_string(),
            };
            label.push_str(&format!("-{tag}{v}"));
        }
    }
    label
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn every_kind_builds_with_defaults_and_refuses_unknown_keys() {
        // Kinds loaded or supplied from outside need their library or their host (their own
        // tests: plugin/, hosted/).
        for k in KINDS.iter().filter(|k| k.role != Role::External) {
            let c = (k.build)(&json!({})).unwrap_or_else(|e| panic!("{}: {e}", k.name));
            assert_eq!(c.kind(), k.name);
            (k.check)(&json!({})).unwrap();
            let e = (k.build)(&json!({ "no_such_key": 1 })).err().expect("unknown key accepted").to_string();
            assert!(e.contains("unknown field `no_such_key`"), "{}: {e}", k.name);
            let e = (k.check)(&json!({ "no_such_key": 1 })).unwrap_err();
            assert!(e.contains("unknown field `no_such_key`"), "{}: {e}", k.name);
            assert!((k.label)(&json!({})).unwrap().starts_with(k.name));
        }
        assert!(find("zip").is_none());
        assert_eq!(&names()[..4], ["sparse", "bicluster", "cpca", "haar"]);
    }

    #[test]
    fn labels_name_the_setting() {
        assert_eq!((find("cpca").unwrap().label)(&json!({})).unwrap(), "cpca-k32-c8");
        assert_eq!((find("cpca").unwrap().label)(&json!({ "clusters": 4, "components": 2 })).unwrap(), "cpca-k4-c2");
        assert_eq!((find("haar").unwrap().label)(&json!({ "terms": 6 })).unwrap(), "haar-t6");
        assert_eq!((find("haar").unwrap().label)(&json!({})).unwrap(), "haar-t12");
        assert_eq!((find("bicluster").unwrap().label)(&json!({})).unwrap(), "bicluster");
        assert_eq!((find("bicluster").unwrap().label)(&json!({ "block_vertices": 1024 })).unwrap(), "bicluster-b1024");
        assert_eq!((find("sparse").unwrap().label)(&json!({})).unwrap(), "sparse");
    }
}
