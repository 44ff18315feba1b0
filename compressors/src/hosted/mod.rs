//! Compressors the program running biscale supplies at run time (`kind = "hosted"`): the
//! Python module registers each Python compressor object passed to `Experiment.run` here
//! under a fresh name and adds a setting `{ name, label }` to the experiment; the run then
//! builds it through the registry like any other kind, so it is planned, gathered, imaged,
//! timed and reported exactly as a built-in is.
//!
//! The registry knows nothing of what a hosted compressor is: [`register`] takes a factory of
//! [`Compressor`]s. A hosted kind is never named in a config file (a setting whose name is
//! not registered is an error saying so), its forms are never cached (the host's code is not
//! biscale's to identify: the compressor's [`Compressor::cacheable`] says so) and it has no
//! GPU gather unless its compressor describes one.

use crate::registry::{self, Kind};
use biscale_core::compress::Compressor;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

/// Makes the compressor of a hosted setting (called once per build, cheaply).
pub type Factory = Arc<dyn Fn() -> Box<dyn Compressor> + Send + Sync>;

static HOSTED: Mutex<BTreeMap<String, Factory>> = Mutex::new(BTreeMap::new());

fn table() -> std::sync::MutexGuard<'static, BTreeMap<String, Factory>> {
    // A panic while the table was held leaves it whole (inserts and removes only).
    HOSTED.lock().unwrap_or_else(|e| e.into_inner())
}

/// The parameters of a hosted setting.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostedParams {
    /// The name it was registered under ([`register`]).
    pub name: String,
    /// The setting's label (report rows, file names).
    pub label: String,
}

/// A hosted compressor's registration; dropping it removes the compressor from the registry.
#[derive(Debug)]
pub struct Registration {
    name: String,
}

impl Registration {
    /// The name the compressor is registered under.
    pub fn name(&self) -> &str {
        &self.name
    }
}

impl Drop for Registration {
    fn drop(&mut self) {
        table().remove(&self.name);
    }
}

/// Register `factory` under `name` (refused when the name is taken) until the returned
/// [`Registration`] is dropped.
pub fn register(name: &str, factory: Factory) -> Result<Registration, String> {
    let mut t = table();
    if t.contains_key(name) {
        return Err(format!("a hosted compressor named `{name}` is registered already"));
    }
    t.insert(name.to_string(), factory);
    Ok(Registration { name: name.to_string() })
}

impl registry::MakeCompressor for HostedParams {
    fn make(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
        let params: HostedParams = registry::parse(p)?;
        let factory = table().get(&params.name).cloned().ok_or_else(|| {
            format!(
                "no hosted compressor `{}` is registered: a hosted compressor is passed by the program that runs \
                 biscale (in Python, `Experiment.run(compressors=[...])`), never named in a config file",
                params.name
            )
        })?;
        Ok(factory())
    }
}

/// The registry entry.
/// What a host's form costs is its own claim: nothing is counted from its arrays
/// ([`registry::no_flops`]).
pub const KIND: Kind = Kind {
    role: registry::Role::External,
    ..Kind::built_in::<HostedParams>(
        "hosted",
        "a compressor the program running biscale supplies (a Python object given to Experiment.run)",
        |p| registry::parse::<HostedParams>(p).map(|p| p.label),
    )
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sparse::Sparse;

    #[test]
    fn a_registered_compressor_builds_until_its_registration_drops() {
        let params = serde_json::json!({ "name": "test-hosted-1", "label": "mine" });
        let e = registry::build("hosted", &params).err().expect("not registered yet").to_string();
        assert!(e.contains("never named in a config file"), "{e}");
        let reg = register("test-hosted-1", Arc::new(|| Box::new(Sparse) as Box<dyn Compressor>)).unwrap();
        assert!(register("test-hosted-1", Arc::new(|| Box::new(Sparse) as Box<dyn Compressor>)).is_err());
        let c = registry::build("hosted", &params).unwrap();
        assert_eq!(c.kind(), "sparse");
        assert_eq!((KIND.label)(&params).unwrap(), "mine");
        drop(reg);
        assert!(registry::build("hosted", &params).is_err());
        assert!((KIND.check)(&serde_json::json!({ "name": "x" })).is_err(), "a label is required");
    }
}
