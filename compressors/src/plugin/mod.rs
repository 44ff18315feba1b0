//! Compressors loaded from shared libraries (docs/DESIGN.md section 4): a researcher builds a
//! transfer compressor as a `cdylib` against `biscale-plugin-api` and names it in the
//! experiment (`kind = "plugin"`, `path = ...`, `params = { ... }`); biscale needs no rebuild.
//!
//! A plugin runs in one of two ways, chosen per setting:
//!
//! * **In process** (the default): [`PluginCompressor`] (`native.rs`) opens the library in
//!   biscale's own process and speaks the versioned C ABI of `biscale_plugin`.
//! * **Isolated** (`isolate = true`, optionally `timeout_seconds`): [`IsolatedPlugin`]
//!   (`isolate.rs`) starts a child process that runs that same [`PluginCompressor`] and talks
//!   to it through pipes, so a crash, an `exit` or a hang of the plugin is an error naming the
//!   library, the call and the cause, and biscale lives on to report it.
//!
//! Either way the result implements `Compressor` (kind `plugin:<name>`) and hands its GPU
//! kernels to the runtime as plain data (`Compressor::kernels`, a [`KernelDesc`]), exactly as
//! a built-in compressor does.
//!
//! # Trust model
//!
//! Nothing a plugin returns is trusted. The host copies every string and array out of plugin
//! memory (then returns it to the plugin's own `free`) after checking UTF-8, null and
//! misaligned pointers and element tags; names must be WGSL identifiers, unique, not reserved
//! by the GPU prelude; the WGSL is parsed and validated at load by `biscale_kernels::reflect`
//! (with the `wgsl-check` feature: entry points exist, scratch buffers are read-write, and
//! every form array the WGSL binds exists in each form with a compatible element type); and
//! every structural check the plugin declares ([`biscale_kernels::FormCheck`]: lengths,
//! pointer arrays, index bounds, finiteness) is run by the host on every form before a CPU or
//! GPU gather. A gather's `L*` must have every element written and none NaN. These checks are
//! one code path ([`Guard`]): an isolated plugin's child runs them on what the library
//! returns, and the parent runs them again on what comes over the pipe, since the child is
//! the plugin's process and is not trusted either.
//!
//! What no check states is not verified: an index array without a `Below` check can make a
//! GPU kernel read wrong (clamped) elements. And **an in-process plugin is native code in
//! biscale's address space**: its CPU gather and compress run on biscale's memory and are
//! trusted to stay within the arrays they are given. The C boundary turns a Rust panic into
//! an error, but nothing can turn a segfault, an `abort`, a `std::process::exit(0)` (biscale
//! would exit 0 with no metrics) or an endless loop into one, and a plugin could corrupt
//! biscale's memory silently. Use `isolate = true` for a plugin under development, one from
//! someone else, or any run that must finish with a report: the plugin then shares nothing
//! with biscale but the pipes, at the price of copying `T`, each form and each `L*` between
//! the processes (the setting's label gets `-isolated`, its `metrics.json` stats say so, and
//! its `build_seconds` and `gather_ms` include that transfer). Isolation does not sandbox the
//! file system or the network: the child is an ordinary process of the user.

/// The `Compressor` methods both plugin hosts forward the same way: the kind the library
/// declared, and compress, gather and kernels through the host's own calls
/// (`compress_plugin`, `gather_plugin`, its guard's `kernels_for`), whose errors become
/// `CompressError`s. Written once here; each host adds what differs (params, stats, identity).
macro_rules! forward_plugin_calls {
    () => {
        fn kind(&self) -> &str {
            &self.guard.kind
        }

        fn compress(
            &self,
            t: &biscale_core::transfer::TransferMatrix,
            ctx: &biscale_core::compress::CompressContext<'_>,
        ) -> Result<biscale_core::compress::CompressedForm, biscale_core::compress::CompressError> {
            Ok(self.compress_plugin(t, ctx)?)
        }

        fn gather(
            &self,
            form: &biscale_core::compress::CompressedForm,
            light: &biscale_core::sampling::LightVector,
        ) -> Result<biscale_core::gather::LocalRadiance, biscale_core::compress::CompressError> {
            Ok(self.gather_plugin(form, light)?)
        }

        fn kernels(
            &self,
            form: &biscale_core::compress::CompressedForm,
        ) -> Result<biscale_kernels::KernelDesc, biscale_core::compress::CompressError> {
            Ok(self.guard.kernels_for(form)?)
        }
    };
}

#[cfg(unix)]
mod isolate;
mod native;

#[cfg(unix)]
pub use isolate::{serve_if_child, wire, IsolateOptions, IsolatedPlugin, CHILD_ENV, HOST_ENV};
pub use native::PluginCompressor;

/// Isolation needs Unix; elsewhere there is never a child to serve.
#[cfg(not(unix))]
pub fn serve_if_child() {}

use crate::registry::{self, Kind};
use biscale_core::compress::CompressedForm;
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_kernels::{Factor, FormCheck, KernelDesc, RESERVED_NAMES};
use biscale_plugin as abi;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The parameters of a `kind = "plugin"` setting.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PluginParams {
    /// The library (the config resolves it against its own folder).
    pub path: PathBuf,
    /// Free-form parameters handed to the plugin as JSON (default: none).
    #[serde(default = "empty_object")]
    pub params: Value,
    /// Run the plugin in a child process (default false; see the module docs).
    #[serde(default)]
    pub isolate: bool,
    /// With `isolate`: the seconds each call (load, compress, one gather) may take before the
    /// child is killed (default [`PluginParams::DEFAULT_TIMEOUT_SECONDS`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout_seconds: Option<f64>,
}

impl PluginParams {
    /// Time an isolated call may take by default: ten minutes, for a compress of a large `T`.
    pub const DEFAULT_TIMEOUT_SECONDS: f64 = 600.0;
    /// The longest timeout accepted (a week).
    pub const MAX_TIMEOUT_SECONDS: f64 = 7.0 * 86_400.0;

    /// Everything about the setting that can be checked without loading the library.
    pub fn check(&self) -> Result<(), String> {
        if self.timeout_seconds.is_some() && !self.isolate {
            return Err("timeout_seconds needs isolate = true (a plugin in biscale's own process cannot be \
                        stopped)"
                .into());
        }
        if self.isolate && !cfg!(unix) {
            return Err("isolate = true needs a Unix system (the child is watched through pipes and signals)".into());
        }
        self.timeout().map(drop)
    }

    /// The timeout of each isolated call.
    pub fn timeout(&self) -> Result<Duration, String> {
        let s = self.timeout_seconds.unwrap_or(Self::DEFAULT_TIMEOUT_SECONDS);
        if !(s > 0.0 && s <= Self::MAX_TIMEOUT_SECONDS) {
            return Err(format!(
                "timeout_seconds = {s} must be above 0 and at most {} (a week)",
                Self::MAX_TIMEOUT_SECONDS
            ));
        }
        Ok(Duration::from_secs_f64(s))
    }
}

fn empty_object() -> Value {
    Value::Object(Default::default())
}

/// The registry entry: the label is `plugin-<library stem>` (`libquantized.so` gives
/// `plugin-quantized`), with `-isolated` appended for `isolate = true`; building loads the
/// library (in this process, or in a child started here).
pub const KIND: Kind = Kind {
    name: "plugin",
    about: "a compressor loaded from a shared library through biscale's plugin C ABI (`path`, `params`, \
            `isolate`, `timeout_seconds`)",
    label: |p| {
        let p = registry::parse::<PluginParams>(p)?;
        let stem = p.path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let isolated = if p.isolate { "-isolated" } else { "" };
        Ok(format!("plugin-{}{isolated}", stem.trim_start_matches("lib")))
    },
    check: |p| registry::parse::<PluginParams>(p)?.check(),
    fits: registry::no_limits,
    memory: registry::csr_copy_memory,
    report: registry::no_rows,
    build: |p| {
        let p: PluginParams = registry::parse(p)?;
        p.check()?;
        #[cfg(unix)]
        if p.isolate {
            let opts = IsolateOptions { host: None, timeout: p.timeout()? };
            return Ok(Box::new(IsolatedPlugin::spawn(&p.path, p.params, &opts)?));
        }
        Ok(Box::new(PluginCompressor::load(&p.path, p.params)?))
    },
    role: registry::Role::External,
    flops: |_| None,
};

/// Upper bounds on what a plugin may return (far above any real use; they keep a garbage
/// count from turning into a huge allocation or read).
const MAX_ITEMS: u64 = 4096;
const MAX_STR_BYTES: u64 = 64 << 20;

/// Why a plugin could not be loaded or used. Every variant names the library file.
#[derive(Debug, thiserror::Error)]
pub enum PluginError {
    #[error("plugin {}: cannot load the library: {message}", path.display())]
    Load { path: PathBuf, message: String },
    #[error("plugin {}: missing symbol '{symbol}' (is it a biscale plugin? build it with biscale_plugin::export_plugin!): {message}", path.display())]
    MissingSymbol { path: PathBuf, symbol: String, message: String },
    #[error("plugin {}: built for plugin ABI {}.{}, this biscale speaks {}.{} (the major version must match; rebuild the plugin against this biscale's biscale-plugin-api)", path.display(), abi::abi_major(*found), abi::abi_minor(*found), abi::ABI_MAJOR, abi::ABI_MINOR)]
    AbiVersion { path: PathBuf, found: u32 },
    #[error("plugin {}: its ABI structs differ from this biscale's (layout fingerprint {found:#018x}, expected {:#018x}); rebuild it against this biscale's biscale-plugin-api", path.display(), abi::ABI_LAYOUT)]
    AbiLayout { path: PathBuf, found: u64 },
    #[error("plugin {}: {call} failed: {message}", path.display())]
    Plugin { path: PathBuf, call: &'static str, message: String },
    #[error("plugin {}: {call} panicked (caught at the plugin boundary): {message}", path.display())]
    Panic { path: PathBuf, call: &'static str, message: String },
    #[error("plugin {}: {call}: invalid data: {message}", path.display())]
    Invalid { path: PathBuf, call: &'static str, message: String },
    #[error("plugin {}: its WGSL kernels do not compile or break the gather conventions:\n{message}", path.display())]
    Wgsl { path: PathBuf, message: String },
    /// An isolated plugin's child was killed by a signal (`cause`: "killed by signal 11
    /// (SIGSEGV)") during `call` (`load`, `compress` or `gather`).
    #[error("plugin {} crashed in {call}: {cause}", path.display())]
    Crashed { path: PathBuf, call: &'static str, cause: String },
    /// An isolated plugin's child exited (the plugin called `exit`) before answering `call`.
    #[error("plugin {} exited with status {code} during {call} without answering", path.display())]
    Exited { path: PathBuf, call: &'static str, code: i32 },
    /// An isolated plugin's child did not answer `call` within its timeout and was killed.
    #[error("plugin {} did not answer {call} within {seconds} s; killed", path.display())]
    Timeout { path: PathBuf, call: &'static str, seconds: f64 },
    /// The child process could not be started, or broke the protocol during `call` (it was
    /// killed then).
    #[error("plugin {}: isolated host {} during {call}: {message}", path.display(), host.display())]
    Host { path: PathBuf, host: PathBuf, call: &'static str, message: String },
    /// A call on an isolated plugin whose child an earlier error ended.
    #[error("plugin {}: its isolated host is gone after an earlier error ({message}); load the plugin again", path.display())]
    Gone { path: PathBuf, message: String },
}

impl From<PluginError> for biscale_core::compress::CompressError {
    /// Kept whole (it names the library file): `CompressError::External`, which a caller can
    /// downcast back to the [`PluginError`].
    fn from(e: PluginError) -> Self {
        biscale_core::compress::CompressError::External(Box::new(e))
    }
}

/// Is `s` a WGSL-style identifier (so an array can be bound by name)?
fn is_ident(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && s.len() <= 128
}

fn ident(s: &str, what: &str) -> Result<(), String> {
    match is_ident(s) {
        true => Ok(()),
        false => Err(format!("{what} '{s}' is not an identifier ([A-Za-z_][A-Za-z0-9_]*, at most 128 bytes)")),
    }
}

/// The names a count refers to are identifiers.
fn check_count(c: &biscale_kernels::Count, what: &str) -> Result<(), String> {
    for (i, f) in c.0.iter().enumerate() {
        if let Factor::Meta(n) | Factor::MetaPlus(n, _) | Factor::Len(n) = f {
            ident(n, &format!("{what} factor {i} name"))?;
        }
    }
    Ok(())
}

/// The structural rules of a plugin's kernel description, wherever it came from: every name
/// an identifier, at least one pass, scratch buffers neither reserved nor repeated, at most
/// [`MAX_ITEMS`] of anything.
fn check_kernels(k: &KernelDesc) -> Result<(), String> {
    if k.passes.is_empty() {
        return Err("no passes: a gather needs at least one".into());
    }
    for (n, what) in [(k.passes.len(), "passes"), (k.scratch.len(), "scratch"), (k.meta_keys.len(), "meta keys")]
        .into_iter()
        .chain([(k.checks.len(), "checks")])
    {
        if n as u64 > MAX_ITEMS {
            return Err(format!("{what}: {n} is more than the {MAX_ITEMS} allowed"));
        }
    }
    if k.wgsl.len() as u64 > MAX_STR_BYTES {
        return Err(format!("wgsl: {} bytes is more than the {MAX_STR_BYTES} allowed", k.wgsl.len()));
    }
    for (i, p) in k.passes.iter().enumerate() {
        ident(&p.entry_point, &format!("pass {i} entry point"))?;
        check_count(&p.threads, &format!("pass {i} threads"))?;
    }
    let mut seen = BTreeSet::new();
    for (i, s) in k.scratch.iter().enumerate() {
        ident(&s.name, &format!("scratch {i} name"))?;
        check_count(&s.words, &format!("scratch {i} words"))?;
        if RESERVED_NAMES.contains(&s.name.as_str()) || !seen.insert(&s.name) {
            return Err(format!("scratch buffer '{}' is reserved or declared twice", s.name));
        }
    }
    for (i, m) in k.meta_keys.iter().enumerate() {
        ident(m, &format!("meta key {i}"))?;
    }
    for (i, c) in k.checks.iter().enumerate() {
        let what = format!("check {i}");
        match c {
            FormCheck::Len { array, count } | FormCheck::Below { array, bound: count } => {
                ident(array, &format!("{what} array"))?;
                check_count(count, &format!("{what} count"))?;
            }
            FormCheck::Ptr { array, count, total } => {
                ident(array, &format!("{what} array"))?;
                check_count(count, &format!("{what} count"))?;
                check_count(total, &format!("{what} target"))?;
            }
            FormCheck::Finite { array } | FormCheck::FiniteHalf { array } => ident(array, &format!("{what} array"))?,
            FormCheck::Range { count, .. } => check_count(count, &format!("{what} count"))?,
            FormCheck::Grouped { ids, ptr, group_rows, bases } => {
                for n in [ids, ptr, bases] {
                    ident(n, &format!("{what} array"))?;
                }
                check_count(group_rows, &format!("{what} count"))?;
            }
        }
    }
    Ok(())
}

/// The name a plugin reports must be 1-64 characters of `[a-z0-9_]`.
fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty()
        || name.len() > 64
        || !name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
    {
        return Err(format!("name '{name}' must be 1-64 characters of [a-z0-9_]"));
    }
    Ok(())
}

/// The library file as the host opens it (absolute, symlinks resolved: a bare file name would
/// otherwise be searched for on the library path) and the content hash of its bytes
/// (`Compressor::code_identity`).
fn resolve_library(path: &Path) -> Result<(PathBuf, u64), PluginError> {
    let path = match path.canonicalize() {
        Ok(p) if p.is_file() => p,
        _ => return Err(PluginError::Load { path: path.to_path_buf(), message: "no such file".into() }),
    };
    let bytes = std::fs::read(&path).map_err(|e| PluginError::Load { path: path.clone(), message: e.to_string() })?;
    let hash = biscale_core::io::ContentHash::default().write(&bytes).finish();
    Ok((path, hash))
}

/// What the host checks on everything a plugin returns, in whichever process it ran: its
/// name and kernels at load, every form before any gather, every `L*` (see the module docs).
pub(crate) struct Guard {
    path: PathBuf,
    name: String,
    kind: String,
    kernels: KernelDesc,
    /// The kernels' reflection (which globals bind form arrays), from the load-time check.
    #[cfg(feature = "wgsl-check")]
    reflected: biscale_kernels::reflect::Reflected,
}

impl Guard {
    /// Check a plugin's `name` and `kernels` (whose `kind` is set here, from the name).
    fn new(path: PathBuf, name: String, mut kernels: KernelDesc) -> Result<Self, PluginError> {
        let invalid = |call, message| PluginError::Invalid { path: path.clone(), call, message };
        check_name(&name).map_err(|m| invalid("biscale_plugin_name", m))?;
        let kind = format!("plugin:{name}");
        kernels.kind = kind.clone();
        check_kernels(&kernels).map_err(|m| invalid("biscale_plugin_kernels", m))?;
        #[cfg(feature = "wgsl-check")]
        let reflected = biscale_kernels::reflect::reflect(&kernels)
            .map_err(|e| PluginError::Wgsl { path: path.clone(), message: e.message })?;
        Ok(Self {
            path,
            name,
            kind,
            kernels,
            #[cfg(feature = "wgsl-check")]
            reflected,
        })
    }

    /// Everything the host can check on a form of this plugin.
    fn check_form(&self, form: &CompressedForm) -> Result<(), PluginError> {
        let invalid = |message: String| PluginError::Invalid { path: self.path.clone(), call: "form check", message };
        let mut names = BTreeSet::new();
        for a in &form.arrays {
            if !is_ident(&a.name) || RESERVED_NAMES.contains(&a.name.as_str()) || !names.insert(a.name.as_str()) {
                return Err(invalid(format!(
                    "array name '{}' is not an identifier, is reserved ({RESERVED_NAMES:?}) or is repeated",
                    a.name
                )));
            }
        }
        if let Some(k) = form.meta.keys().find(|k| !is_ident(k)) {
            return Err(invalid(format!("meta key '{k}' is not an identifier")));
        }
        self.kernels.check_form(form).map_err(|e| invalid(format!("'{}' {}", e.array, e.what)))?;
        #[cfg(feature = "wgsl-check")]
        self.reflected.check_arrays(form).map_err(|e| invalid(format!("'{}' {}", e.array, e.what)))?;
        Ok(())
    }

    /// A form `compress` returned for `t`'s shape: its kind, shape and every form check, the
    /// errors blamed on `call`.
    fn check_compressed(
        &self,
        form: &CompressedForm,
        shape: biscale_core::basis::TransferShape,
        call: &'static str,
    ) -> Result<(), PluginError> {
        let invalid = |message: String| PluginError::Invalid { path: self.path.clone(), call, message };
        if form.kind != self.kind || form.shape() != shape {
            return Err(invalid(format!(
                "returned a '{}' form of {}, expected a '{}' form of {shape}",
                form.kind,
                form.shape(),
                self.kind
            )));
        }
        self.check_form(form).map_err(|e| match e {
            PluginError::Invalid { message, .. } => invalid(message),
            e => e,
        })
    }

    /// What must hold before `form` is gathered with `light`.
    fn check_gather(&self, form: &CompressedForm, light: &LightVector, call: &'static str) -> Result<(), PluginError> {
        let fail = |message: String| PluginError::Plugin { path: self.path.clone(), call, message };
        if form.kind != self.kind {
            return Err(fail(format!("given a '{}' form, this plugin's kind is '{}'", form.kind, self.kind)));
        }
        form.check_light(light).map_err(|e| fail(e.to_string()))?;
        self.check_form(form)
    }

    /// `L*` from the rows a gather wrote (poisoned with NaN beforehand, so an element the
    /// plugin did not write is caught like a NaN it did).
    fn lstar(
        &self,
        form: &CompressedForm,
        rows: Vec<[f32; 3]>,
        call: &'static str,
    ) -> Result<LocalRadiance, PluginError> {
        if let Some(r) = rows.iter().position(|v| v.iter().any(|x| x.is_nan())) {
            return Err(PluginError::Invalid {
                path: self.path.clone(),
                call,
                message: format!("L* row {r} is NaN or was not written: {:?}", rows[r]),
            });
        }
        form.lstar(rows).map_err(|e| PluginError::Plugin { path: self.path.clone(), call, message: e.to_string() })
    }

    /// `Compressor::kernels`: every form this plugin's compress returns was checked; a form
    /// from elsewhere (a cache) is checked here before the runtime sees it.
    fn kernels_for(&self, form: &CompressedForm) -> Result<KernelDesc, PluginError> {
        self.check_form(form)?;
        Ok(self.kernels.clone())
    }
}

/// Test support: find (building it first) a plugin crate of this workspace, next to the
/// running test executable (`target/<profile>/`).
pub mod testing {
    use std::path::{Path, PathBuf};
    use std::process::Command;
    use std::sync::Mutex;

    /// `target/<profile>` of the running executable (`target/<profile>/deps/<test>`).
    fn profile_dir() -> Result<PathBuf, String> {
        let exe = std::env::current_exe().map_err(|e| format!("current_exe: {e}"))?;
        let mut dir = exe.parent().ok_or("executable has no directory")?.to_path_buf();
        if dir.file_name().is_some_and(|n| n == "deps" || n == "examples") {
            dir.pop();
        }
        Ok(dir)
    }

    /// Build the cdylib of workspace package `package` with `features` into `target_dir`
    /// (default: the running executable's target directory, same profile) and return the
    /// library's path. Builds are serialised within the process; cargo's lock does the rest.
    pub fn build_plugin(package: &str, features: &[&str], target_dir: Option<&Path>) -> Result<PathBuf, String> {
        static LOCK: Mutex<()> = Mutex::new(());
        let _guard = LOCK.lock().unwrap_or_else(|p| p.into_inner());
        let profile_dir = profile_dir()?;
        let profile = profile_dir.file_name().and_then(|n| n.to_str()).ok_or("no profile directory")?.to_string();
        let target_dir = match target_dir {
            Some(t) => t.to_path_buf(),
            None => profile_dir.parent().ok_or("no target directory")?.to_path_buf(),
        };
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../Cargo.toml");
        let mut cmd = Command::new(env!("CARGO"));
        cmd.args(["build", "--quiet", "-p", package, "--manifest-path"]).arg(&manifest);
        cmd.env("CARGO_TARGET_DIR", &target_dir);
        match profile.as_str() {
            "debug" => {}
            "release" => {
                cmd.arg("--release");
            }
            p => {
                cmd.args(["--profile", p]);
            }
        }
        if !features.is_empty() {
            cmd.args(["--features", &features.join(",")]);
        }
        let out = cmd.output().map_err(|e| format!("running cargo: {e}"))?;
        if !out.status.success() {
            return Err(format!("cargo build -p {package} failed:\n{}", String::from_utf8_lossy(&out.stderr)));
        }
        let file =
            format!("{}{}{}", std::env::consts::DLL_PREFIX, package.replace('-', "_"), std::env::consts::DLL_SUFFIX);
        let path = target_dir.join(&profile).join(file);
        if !path.is_file() {
            return Err(format!("built {package} but {} does not exist", path.display()));
        }
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn isolate_and_timeout_are_checked_and_named_in_the_label() {
        let label = |p: Value| (KIND.label)(&p);
        assert_eq!(label(json!({ "path": "/x/libq.so" })).unwrap(), "plugin-q");
        assert_eq!(label(json!({ "path": "/x/libq.so", "isolate": true })).unwrap(), "plugin-q-isolated");
        let check = |p: Value| (KIND.check)(&p);
        check(json!({ "path": "q.so", "isolate": true, "timeout_seconds": 2 })).unwrap();
        check(json!({ "path": "q.so", "isolate": false })).unwrap();
        let e = check(json!({ "path": "q.so", "timeout_seconds": 2 })).unwrap_err();
        assert!(e.contains("timeout_seconds needs isolate = true"), "{e}");
        for bad in [json!(0), json!(-1.0), json!(1e9)] {
            let e = check(json!({ "path": "q.so", "isolate": true, "timeout_seconds": bad })).unwrap_err();
            assert!(e.contains("must be above 0 and at most 604800"), "{bad}: {e}");
        }
        let e = check(json!({ "path": "q.so", "isolated": true })).unwrap_err();
        assert!(e.contains("unknown field `isolated`"), "{e}");
        let p: PluginParams = registry::parse(&json!({ "path": "q.so", "isolate": true })).unwrap();
        assert_eq!(p.timeout().unwrap(), Duration::from_secs(600));
        let p: PluginParams =
            registry::parse(&json!({ "path": "q.so", "isolate": true, "timeout_seconds": 0.5 })).unwrap();
        assert_eq!(p.timeout().unwrap(), Duration::from_millis(500));
    }

    #[test]
    fn kernels_are_checked_whoever_sends_them() {
        let ok = || KernelDesc {
            kind: String::new(),
            wgsl: String::new(),
            passes: vec![biscale_kernels::PassDesc {
                entry_point: "gather_rows".into(),
                threads: biscale_kernels::Count::of([Factor::Rows]),
            }],
            scratch: vec![],
            meta_keys: vec!["k".into()],
            checks: vec![FormCheck::Finite { array: "values".into() }],
        };
        check_kernels(&ok()).unwrap();
        let mut k = ok();
        k.passes.clear();
        assert!(check_kernels(&k).unwrap_err().contains("no passes"));
        let mut k = ok();
        k.meta_keys.push("not an ident".into());
        assert!(check_kernels(&k).unwrap_err().contains("meta key 1 'not an ident'"));
        let mut k = ok();
        k.checks
            .push(FormCheck::Len { array: "a".into(), count: biscale_kernels::Count::of([Factor::Len("b-c".into())]) });
        assert!(check_kernels(&k).unwrap_err().contains("check 1 count factor 0 name 'b-c'"));
        let mut k = ok();
        k.scratch.push(biscale_kernels::ScratchDesc {
            name: RESERVED_NAMES[0].into(),
            words: biscale_kernels::Count(vec![]),
        });
        assert!(check_kernels(&k).unwrap_err().contains("reserved"));
        assert!(check_name("quantized_2").is_ok());
        assert!(check_name("Quantized").is_err() && check_name("").is_err());
    }
}
