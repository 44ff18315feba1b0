//! Compressors loaded from shared libraries (docs/DESIGN.md section 4; issue 7): a researcher
//! builds a transfer compressor as a `cdylib` against `biscale-plugin-api` and names it in the
//! experiment (`kind = "plugin"`, `path = ...`, `params = { ... }`); biscale needs no rebuild.
//!
//! [`PluginCompressor::load`] opens the library and speaks the versioned C ABI documented in
//! `biscale_plugin` (the `biscale-plugin-api` crate): the version handshake first (another
//! major is refused before any other symbol is called), then the struct-layout fingerprint,
//! the plugin's name, and its GPU kernels for the given parameters. The result implements
//! [`Compressor`] (kind `plugin:<name>`) and hands its kernels to the GPU runtime as plain data
//! (`Compressor::kernels`, a [`KernelDesc`]), exactly as a built-in compressor does.
//!
//! Nothing a plugin returns is trusted. The host copies every string and array out of plugin
//! memory (then returns it to the plugin's own `free`) after checking: UTF-8; null and
//! misaligned pointers; element tags; array and meta names (WGSL identifiers, unique, not
//! reserved by the GPU prelude); the WGSL, parsed and validated at load by
//! `biscale_kernels::reflect` (with the `wgsl-check` feature: entry points exist, scratch
//! buffers are read-write, and every form array the WGSL binds exists in each form with a
//! compatible element type); and every structural check the plugin declares
//! ([`biscale_kernels::FormCheck`]: lengths, pointer arrays, index bounds, finiteness), run by
//! the host on every form before a CPU or GPU gather. What no check
//! states is not verified: an index array without a `Below` check can make a GPU kernel read
//! wrong (clamped) elements, and a plugin's CPU gather is the plugin's own code, trusted to
//! stay within the arrays it is given (a Rust plugin that indexes out of range panics, which
//! the boundary turns into an error). Every error names the library file.

use crate::registry::{self, Kind};
use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc, RESERVED_NAMES};
use biscale_plugin as abi;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeSet;
use std::ffi::c_void;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The parameters of a `kind = "plugin"` setting.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PluginParams {
    /// The library (the config resolves it against its own folder).
    pub path: PathBuf,
    /// Free-form parameters handed to the plugin as JSON (default: none).
    #[serde(default = "empty_object")]
    pub params: Value,
}

fn empty_object() -> Value {
    Value::Object(Default::default())
}

/// The registry entry: the label is `plugin-<library stem>` (`libquantized.so` gives
/// `plugin-quantized`); building loads the library.
pub const KIND: Kind = Kind {
    name: "plugin",
    about: "a compressor loaded from a shared library through biscale's plugin C ABI (`path`, `params`)",
    label: |p| {
        let stem = registry::parse::<PluginParams>(p)?.path.file_stem().map(|s| s.to_string_lossy().into_owned());
        Ok(format!("plugin-{}", stem.unwrap_or_default().trim_start_matches("lib")))
    },
    check: |p| registry::parse::<PluginParams>(p).map(drop),
    build: |p| {
        let p: PluginParams = registry::parse(p)?;
        Ok(Box::new(PluginCompressor::load(&p.path, p.params)?))
    },
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
}

impl From<PluginError> for CompressError {
    /// Kept whole (it names the library file): `CompressError::External`, which a caller can
    /// downcast back to the [`PluginError`].
    fn from(e: PluginError) -> Self {
        CompressError::External(Box::new(e))
    }
}

/// The entry points after the handshake (valid while `_lib` is loaded).
struct Api {
    compress: abi::sig::Compress,
    gather: abi::sig::Gather,
    free: abi::sig::Free,
}

/// A compressor loaded from a shared library (see the module docs).
pub struct PluginCompressor {
    path: PathBuf,
    /// Content hash of the library file, read at load ([`Compressor::code_identity`]).
    library_hash: u64,
    name: String,
    kind: String,
    params: Value,
    params_json: String,
    kernels: KernelDesc,
    /// The kernels' reflection (which globals bind form arrays), from the load-time check.
    #[cfg(feature = "wgsl-check")]
    reflected: biscale_kernels::reflect::Reflected,
    api: Api,
    // Last: dropped (unloaded) after everything that points into it.
    _lib: libloading::Library,
}

impl std::fmt::Debug for PluginCompressor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PluginCompressor").field("path", &self.path).field("kind", &self.kind).finish_non_exhaustive()
    }
}

/// Frees what one plugin call returned, however the caller leaves (early returns included).
struct Owned {
    free: abi::sig::Free,
    owner: *mut c_void,
}

impl Drop for Owned {
    fn drop(&mut self) {
        if !self.owner.is_null() {
            // SAFETY: `owner` came from this plugin's last call and is freed exactly once.
            unsafe { (self.free)(self.owner) };
        }
    }
}

/// Is `s` a WGSL-style identifier (so an array can be bound by name)?
fn is_ident(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && s.len() <= 128
}

/// A string from plugin memory.
///
/// # Safety
/// `s.ptr` must point at `s.len` readable bytes when non-null.
unsafe fn read_str(s: abi::BpStr, what: &str) -> Result<String, String> {
    if s.len == 0 {
        return Ok(String::new());
    }
    if s.len > MAX_STR_BYTES {
        return Err(format!("{what}: {} bytes is more than the {MAX_STR_BYTES} allowed", s.len));
    }
    if s.ptr.is_null() {
        return Err(format!("{what}: null pointer with length {}", s.len));
    }
    let bytes = unsafe { std::slice::from_raw_parts(s.ptr, s.len as usize) };
    String::from_utf8(bytes.to_vec()).map_err(|e| format!("{what} is not UTF-8: {e}"))
}

/// A name from plugin memory that must be an identifier.
unsafe fn read_ident(s: abi::BpStr, what: &str) -> Result<String, String> {
    let name = unsafe { read_str(s, what) }?;
    if !is_ident(&name) {
        return Err(format!("{what} '{name}' is not an identifier ([A-Za-z_][A-Za-z0-9_]*, at most 128 bytes)"));
    }
    Ok(name)
}

/// A slice in plugin memory.
///
/// # Safety
/// `ptr` must point at `len` readable `T`s when non-null.
unsafe fn read_slice<'a, T>(ptr: *const T, len: u64, max: u64, what: &str) -> Result<&'a [T], String> {
    if len == 0 {
        return Ok(&[]);
    }
    if len > max || len.checked_mul(std::mem::size_of::<T>() as u64).is_none_or(|b| b > isize::MAX as u64) {
        return Err(format!("{what}: length {len} is implausible"));
    }
    if ptr.is_null() {
        return Err(format!("{what}: null pointer with length {len}"));
    }
    if !(ptr as usize).is_multiple_of(std::mem::align_of::<T>()) {
        return Err(format!("{what}: pointer {ptr:p} is not aligned to {} bytes", std::mem::align_of::<T>()));
    }
    Ok(unsafe { std::slice::from_raw_parts(ptr, len as usize) })
}

unsafe fn read_count(c: &abi::BpCount, what: &str) -> Result<Count, String> {
    let mut factors = Vec::new();
    for (i, f) in unsafe { read_slice(c.factors, c.count, 64, what) }?.iter().enumerate() {
        let name = || unsafe { read_ident(f.name, &format!("{what} factor {i} name")) };
        factors.push(match f.tag {
            abi::FACTOR_CONST => Factor::Const(f.value),
            abi::FACTOR_ROWS => Factor::Rows,
            abi::FACTOR_COLS => Factor::Cols,
            abi::FACTOR_VERTICES => Factor::Vertices,
            abi::FACTOR_LOCAL_DIRS => Factor::LocalDirs,
            abi::FACTOR_META => Factor::Meta(name()?),
            abi::FACTOR_META_PLUS => Factor::MetaPlus(name()?, f.value),
            abi::FACTOR_LEN => Factor::Len(name()?),
            t => return Err(format!("{what} factor {i}: unknown factor tag {t}")),
        });
    }
    Ok(Count(factors))
}

/// Copy and check the kernels a plugin returned.
unsafe fn read_kernels(k: &abi::BpKernels, kind: &str) -> Result<KernelDesc, String> {
    let wgsl = unsafe { read_str(k.wgsl, "wgsl") }?;
    let mut passes = Vec::new();
    for (i, p) in unsafe { read_slice(k.passes, k.pass_count, MAX_ITEMS, "passes") }?.iter().enumerate() {
        passes.push(PassDesc {
            entry_point: unsafe { read_ident(p.entry_point, &format!("pass {i} entry point")) }?,
            threads: unsafe { read_count(&p.threads, &format!("pass {i} threads")) }?,
        });
    }
    if passes.is_empty() {
        return Err("no passes: a gather needs at least one".into());
    }
    let mut scratch = Vec::new();
    for (i, s) in unsafe { read_slice(k.scratch, k.scratch_count, MAX_ITEMS, "scratch") }?.iter().enumerate() {
        scratch.push(ScratchDesc {
            name: unsafe { read_ident(s.name, &format!("scratch {i} name")) }?,
            words: unsafe { read_count(&s.words, &format!("scratch {i} words")) }?,
        });
    }
    let mut meta_keys = Vec::new();
    for (i, s) in unsafe { read_slice(k.meta_keys, k.meta_key_count, MAX_ITEMS, "meta keys") }?.iter().enumerate() {
        meta_keys.push(unsafe { read_ident(*s, &format!("meta key {i}")) }?);
    }
    let mut checks = Vec::new();
    for (i, c) in unsafe { read_slice(k.checks, k.check_count, MAX_ITEMS, "checks") }?.iter().enumerate() {
        let what = format!("check {i}");
        let array = unsafe { read_ident(c.array, &format!("{what} array")) }?;
        let count = || unsafe { read_count(&c.count, &format!("{what} count")) };
        checks.push(match c.tag {
            abi::CHECK_LEN => FormCheck::Len { array, count: count()? },
            abi::CHECK_PTR => FormCheck::Ptr {
                array,
                count: count()?,
                total: Count::of([Factor::Len(unsafe { read_ident(c.target, &format!("{what} target")) }?)]),
            },
            abi::CHECK_BELOW => FormCheck::Below { array, bound: count()? },
            abi::CHECK_FINITE => FormCheck::Finite { array },
            t => return Err(format!("{what}: unknown check tag {t}")),
        });
    }
    let mut seen = BTreeSet::new();
    for n in scratch.iter().map(|s| &s.name) {
        if RESERVED_NAMES.contains(&n.as_str()) || !seen.insert(n) {
            return Err(format!("scratch buffer '{n}' is reserved or declared twice"));
        }
    }
    Ok(KernelDesc { kind: kind.to_string(), wgsl, passes, scratch, meta_keys, checks })
}

impl PluginCompressor {
    /// Load the plugin at `path` with its experiment parameters (any JSON; the plugin reads
    /// them and should reject what it does not know). Runs the handshake, fetches and checks
    /// the kernels (the plugin sees `params` here first, so parameter errors surface at load).
    pub fn load(path: &Path, params: Value) -> Result<Self, PluginError> {
        // Absolute before dlopen: a bare file name ("libq.so") would otherwise be searched for
        // on LD_LIBRARY_PATH and the system folders, loading another library of that name.
        let path = match path.canonicalize() {
            Ok(p) if p.is_file() => p,
            _ => return Err(PluginError::Load { path: path.to_path_buf(), message: "no such file".into() }),
        };
        let bytes =
            std::fs::read(&path).map_err(|e| PluginError::Load { path: path.clone(), message: e.to_string() })?;
        let library_hash = biscale_core::io::ContentHash::default().write(&bytes).finish();
        drop(bytes);
        // SAFETY: loading runs the library's initialisers; a biscale plugin is a Rust cdylib
        // (or C library) whose initialisers do nothing unusual. This is the trust the user
        // extends by naming the file.
        let lib = unsafe { libloading::Library::new(&path) }
            .map_err(|e| PluginError::Load { path: path.clone(), message: e.to_string() })?;
        let missing = |symbol: &[u8], e: libloading::Error| PluginError::MissingSymbol {
            path: path.clone(),
            symbol: String::from_utf8_lossy(&symbol[..symbol.len() - 1]).into_owned(),
            message: e.to_string(),
        };
        // SAFETY (all lookups): the symbols have the types the ABI documents; a library that
        // exports these names with other signatures is not a biscale plugin of this major.
        let version: abi::sig::AbiVersion =
            *unsafe { lib.get(abi::symbols::ABI_VERSION) }.map_err(|e| missing(abi::symbols::ABI_VERSION, e))?;
        let found = unsafe { version() };
        if abi::abi_major(found) != abi::ABI_MAJOR {
            return Err(PluginError::AbiVersion { path, found });
        }
        let layout: abi::sig::AbiLayout =
            *unsafe { lib.get(abi::symbols::ABI_LAYOUT) }.map_err(|e| missing(abi::symbols::ABI_LAYOUT, e))?;
        let found = unsafe { layout() };
        if found != abi::ABI_LAYOUT {
            return Err(PluginError::AbiLayout { path, found });
        }
        let name_fn: abi::sig::Name =
            *unsafe { lib.get(abi::symbols::NAME) }.map_err(|e| missing(abi::symbols::NAME, e))?;
        let kernels_fn: abi::sig::Kernels =
            *unsafe { lib.get(abi::symbols::KERNELS) }.map_err(|e| missing(abi::symbols::KERNELS, e))?;
        let api = Api {
            compress: *unsafe { lib.get(abi::symbols::COMPRESS) }.map_err(|e| missing(abi::symbols::COMPRESS, e))?,
            gather: *unsafe { lib.get(abi::symbols::GATHER) }.map_err(|e| missing(abi::symbols::GATHER, e))?,
            free: *unsafe { lib.get(abi::symbols::FREE) }.map_err(|e| missing(abi::symbols::FREE, e))?,
        };
        let invalid = |call, message| PluginError::Invalid { path: path.clone(), call, message };
        // The name is static data in the library (not freed).
        let name = unsafe { read_str(name_fn(), "name") }.map_err(|m| invalid("biscale_plugin_name", m))?;
        if name.is_empty()
            || name.len() > 64
            || !name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
        {
            return Err(invalid("biscale_plugin_name", format!("name '{name}' must be 1-64 characters of [a-z0-9_]")));
        }
        let kind = format!("plugin:{name}");
        let params_json = serde_json::to_string(&params).expect("a serde_json::Value always serializes");

        // SAFETY: zeroed out-structs are valid (integers and null pointers).
        let (mut out, mut err): (abi::BpKernels, abi::BpError) = unsafe { (std::mem::zeroed(), std::mem::zeroed()) };
        let status = unsafe { kernels_fn(abi::BpStr::of(&params_json), &mut out, &mut err) };
        let call = "biscale_plugin_kernels";
        let kernels = match status {
            abi::STATUS_OK => {
                let _owned = Owned { free: api.free, owner: out.owner };
                unsafe { read_kernels(&out, &kind) }.map_err(|m| invalid(call, m))?
            }
            s => return Err(status_error(&path, call, s, &err, api.free)),
        };
        #[cfg(feature = "wgsl-check")]
        let reflected = biscale_kernels::reflect::reflect(&kernels)
            .map_err(|e| PluginError::Wgsl { path: path.clone(), message: e.message })?;
        Ok(Self {
            path,
            library_hash,
            name,
            kind,
            params,
            params_json,
            kernels,
            #[cfg(feature = "wgsl-check")]
            reflected,
            api,
            _lib: lib,
        })
    }

    /// The library file as loaded: absolute, with symlinks and `..` resolved.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The name the plugin reports (its kind is `plugin:<name>`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The GPU gather program as plain data (what `Compressor::kernels` returns).
    pub fn gpu_kernels(&self) -> &KernelDesc {
        &self.kernels
    }

    /// Everything the host can check on a form of this plugin (see the module docs).
    pub fn check_form(&self, form: &CompressedForm) -> Result<(), PluginError> {
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

    /// [`Compressor::compress`] with the typed error.
    pub fn compress_plugin(
        &self,
        t: &TransferMatrix,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, PluginError> {
        let start = Instant::now();
        let call = "biscale_plugin_compress";
        let invalid = |message: String| PluginError::Invalid { path: self.path.clone(), call, message };
        let csr = t.csr();
        if !csr.is_csr() || csr.nnz() > u32::MAX as usize {
            return Err(PluginError::Plugin {
                path: self.path.clone(),
                call,
                message: format!("T must be CSR with at most 2^32 - 1 non-zeros (has {})", csr.nnz()),
            });
        }
        let row_ptr: Vec<u32> = csr.indptr().to_proper().iter().map(|&p| p as u32).collect();
        let col_idx: Vec<u32> = csr.indices().iter().map(|&c| c as u32).collect();
        let input = abi::BpCsr {
            rows: t.rows() as u64,
            cols: t.cols() as u64,
            vertices: t.vertices() as u64,
            local_dirs: t.local_dirs() as u64,
            resolution: t.light_basis().cubemap_layout().map_or(0, |c| c.resolution),
            _reserved: 0,
            seed: ctx.seed,
            row_ptr: row_ptr.as_ptr(),
            col_idx: col_idx.as_ptr(),
            values: csr.data().as_ptr(),
            nnz: csr.nnz() as u64,
        };
        // SAFETY: zeroed out-structs are valid; the input borrows live vectors.
        let (mut out, mut err): (abi::BpForm, abi::BpError) = unsafe { (std::mem::zeroed(), std::mem::zeroed()) };
        let status = unsafe { (self.api.compress)(&input, abi::BpStr::of(&self.params_json), &mut out, &mut err) };
        if status != abi::STATUS_OK {
            return Err(status_error(&self.path, call, status, &err, self.api.free));
        }
        let _owned = Owned { free: self.api.free, owner: out.owner };
        let (arrays, meta) = unsafe { read_form(&out) }.map_err(invalid)?;
        let lossless = match out.lossless {
            0 => false,
            1 => true,
            v => return Err(invalid(format!("lossless flag is {v}, not 0 or 1"))),
        };
        let mut form = CompressedForm::new(self.kind.clone(), t.shape());
        form.arrays = arrays;
        form.meta = meta;
        form.lossless = lossless;
        form.flops_per_gather = out.flops_per_gather;
        form.build_seconds = start.elapsed().as_secs_f64();
        self.check_form(&form).map_err(|e| match e {
            PluginError::Invalid { message, .. } => invalid(message),
            e => e,
        })?;
        ctx.report(1.0);
        Ok(form)
    }

    /// [`Compressor::gather`] with the typed error (the form is checked first).
    pub fn gather_plugin(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, PluginError> {
        let call = "biscale_plugin_gather";
        let fail = |message: String| PluginError::Plugin { path: self.path.clone(), call, message };
        if form.kind != self.kind {
            return Err(fail(format!("given a '{}' form, this plugin's kind is '{}'", form.kind, self.kind)));
        }
        form.check_light(light).map_err(|e| fail(e.to_string()))?;
        self.check_form(form)?;
        let arrays: Vec<abi::BpArray> = form
            .arrays
            .iter()
            .map(|a| {
                let (elem, data): (u32, *const c_void) = match &a.data {
                    ArrayData::U8(v) => (abi::ELEM_U8, v.as_ptr().cast()),
                    ArrayData::I8(v) => (abi::ELEM_I8, v.as_ptr().cast()),
                    ArrayData::U16(v) => (abi::ELEM_U16, v.as_ptr().cast()),
                    ArrayData::I16(v) => (abi::ELEM_I16, v.as_ptr().cast()),
                    ArrayData::U32(v) => (abi::ELEM_U32, v.as_ptr().cast()),
                    ArrayData::F32(v) => (abi::ELEM_F32, v.as_ptr().cast()),
                };
                abi::BpArray { name: abi::BpStr::of(&a.name), elem, _reserved: 0, len: a.data.len() as u64, data }
            })
            .collect();
        let meta: Vec<abi::BpMeta> =
            form.meta.iter().map(|(k, v)| abi::BpMeta { key: abi::BpStr::of(k), value: *v }).collect();
        let view = abi::BpFormView {
            rows: form.rows() as u64,
            cols: form.cols() as u64,
            local_dirs: form.local_dirs() as u64,
            arrays: arrays.as_ptr(),
            array_count: arrays.len() as u64,
            meta: meta.as_ptr(),
            meta_count: meta.len() as u64,
        };
        // Poisoned, so an element the plugin does not write is caught below like a NaN.
        let mut lstar = vec![[f32::NAN; 3]; form.rows()];
        // SAFETY: zeroed error struct is valid; every pointer borrows a live host vector of the
        // stated length for the duration of the call.
        let mut err: abi::BpError = unsafe { std::mem::zeroed() };
        let status = unsafe {
            (self.api.gather)(
                &view,
                light.power.as_ptr().cast(),
                3 * light.power.len() as u64,
                lstar.as_mut_ptr().cast(),
                3 * lstar.len() as u64,
                &mut err,
            )
        };
        if status != abi::STATUS_OK {
            return Err(status_error(&self.path, call, status, &err, self.api.free));
        }
        if let Some(r) = lstar.iter().position(|v| v.iter().any(|x| x.is_nan())) {
            return Err(PluginError::Invalid {
                path: self.path.clone(),
                call,
                message: format!("L* row {r} is NaN or was not written: {:?}", lstar[r]),
            });
        }
        form.lstar(lstar).map_err(|e| fail(e.to_string()))
    }
}

/// Copy a returned form's arrays and meta out of plugin memory, checking names and tags.
unsafe fn read_form(out: &abi::BpForm) -> Result<(Vec<NamedArray>, std::collections::BTreeMap<String, u64>), String> {
    let mut arrays = Vec::new();
    for (i, a) in unsafe { read_slice(out.arrays, out.array_count, MAX_ITEMS, "arrays") }?.iter().enumerate() {
        let name = unsafe { read_ident(a.name, &format!("array {i} name")) }?;
        let what = format!("array '{name}'");
        let max = u64::MAX;
        let data = match a.elem {
            abi::ELEM_U8 => ArrayData::U8(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            abi::ELEM_I8 => ArrayData::I8(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            abi::ELEM_U16 => ArrayData::U16(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            abi::ELEM_I16 => ArrayData::I16(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            abi::ELEM_U32 => ArrayData::U32(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            abi::ELEM_F32 => ArrayData::F32(unsafe { read_slice(a.data.cast(), a.len, max, &what) }?.to_vec()),
            t => return Err(format!("{what}: unknown element tag {t}")),
        };
        arrays.push(NamedArray { name, data });
    }
    let mut meta = std::collections::BTreeMap::new();
    for (i, m) in unsafe { read_slice(out.meta, out.meta_count, MAX_ITEMS, "meta") }?.iter().enumerate() {
        let key = unsafe { read_ident(m.key, &format!("meta key {i}")) }?;
        if meta.insert(key.clone(), m.value).is_some() {
            return Err(format!("meta key '{key}' appears twice"));
        }
    }
    Ok((arrays, meta))
}

/// The error of a call that returned a non-OK status (the message is copied, then freed).
fn status_error(path: &Path, call: &'static str, status: i32, err: &abi::BpError, free: abi::sig::Free) -> PluginError {
    let _owned = Owned { free, owner: err.owner };
    let message =
        unsafe { read_str(err.message, "error message") }.unwrap_or_else(|e| format!("(unreadable message: {e})"));
    let path = path.to_path_buf();
    match status {
        abi::STATUS_ERROR => PluginError::Plugin { path, call, message },
        abi::STATUS_PANIC => PluginError::Panic { path, call, message },
        s => PluginError::Invalid { path, call, message: format!("unknown status {s} (message: {message})") },
    }
}

impl Compressor for PluginCompressor {
    fn kind(&self) -> &str {
        &self.kind
    }

    fn params(&self) -> Value {
        serde_json::json!({ "path": self.path.display().to_string(), "params": self.params })
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        Ok(self.compress_plugin(t, ctx)?)
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        Ok(self.gather_plugin(form, light)?)
    }

    fn kernels(&self, form: &CompressedForm) -> Result<KernelDesc, CompressError> {
        // Every form this plugin's compress returns was checked; a form from elsewhere (a
        // cache) is checked here before the runtime sees it.
        self.check_form(form)?;
        Ok(self.kernels.clone())
    }

    fn code_identity(&self) -> Option<u64> {
        Some(self.library_hash)
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
