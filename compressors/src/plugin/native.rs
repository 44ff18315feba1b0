//! A plugin in biscale's own process: [`PluginCompressor::load`] opens the library and speaks
//! the versioned C ABI documented in `biscale_plugin` (the `biscale-plugin-api` crate): the
//! version handshake first (another major is refused before any other symbol is called), then
//! the struct-layout fingerprint, the plugin's name, and its GPU kernels for the given
//! parameters. Everything the library returns is copied out of its memory and checked here
//! (pointers, UTF-8, tags) and by the shared [`Guard`] (names, kernels, forms, `L*`); a Rust
//! panic is caught at the boundary. A crash, `exit` or hang of the library is not: that is
//! what an isolated plugin (`isolate.rs`, which runs this same type in a child process) is
//! for. Every error names the library file.

use super::{resolve_library, Guard, PluginError, MAX_ITEMS, MAX_STR_BYTES};
use biscale_core::compress::{ArrayData, CompressContext, CompressedForm, Compressor, NamedArray};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use biscale_plugin as abi;
use serde_json::Value;
use std::ffi::c_void;
use std::path::Path;
use std::time::Instant;

/// The entry points after the handshake (valid while `_lib` is loaded).
struct Api {
    compress: abi::sig::Compress,
    gather: abi::sig::Gather,
    free: abi::sig::Free,
}

/// A compressor loaded from a shared library into this process (see the module docs).
pub struct PluginCompressor {
    guard: Guard,
    /// Content hash of the library file, read at load ([`Compressor::code_identity`]).
    library_hash: u64,
    params: Value,
    params_json: String,
    api: Api,
    // Last: dropped (unloaded) after everything that points into it.
    _lib: libloading::Library,
}

impl std::fmt::Debug for PluginCompressor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PluginCompressor")
            .field("path", &self.guard.path)
            .field("kind", &self.guard.kind)
            .finish_non_exhaustive()
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
    super::ident(&name, what)?;
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

/// Copy the kernels a plugin returned out of its memory (the [`Guard`] checks them).
unsafe fn read_kernels(k: &abi::BpKernels) -> Result<KernelDesc, String> {
    let wgsl = unsafe { read_str(k.wgsl, "wgsl") }?;
    let mut passes = Vec::new();
    for (i, p) in unsafe { read_slice(k.passes, k.pass_count, MAX_ITEMS, "passes") }?.iter().enumerate() {
        passes.push(PassDesc {
            entry_point: unsafe { read_ident(p.entry_point, &format!("pass {i} entry point")) }?,
            threads: unsafe { read_count(&p.threads, &format!("pass {i} threads")) }?,
        });
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
    // The kind is the guard's to set, from the checked name.
    Ok(KernelDesc { kind: String::new(), wgsl, passes, scratch, meta_keys, checks })
}

impl PluginCompressor {
    /// Load the plugin at `path` with its experiment parameters (any JSON; the plugin reads
    /// them and should reject what it does not know). Runs the handshake, fetches and checks
    /// the kernels (the plugin sees `params` here first, so parameter errors surface at load).
    pub fn load(path: &Path, params: Value) -> Result<Self, PluginError> {
        // Absolute before dlopen: a bare file name ("libq.so") would otherwise be searched for
        // on LD_LIBRARY_PATH and the system folders, loading another library of that name.
        let (path, library_hash) = resolve_library(path)?;
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
        super::check_name(&name).map_err(|m| invalid("biscale_plugin_name", m))?;
        let params_json = serde_json::to_string(&params).expect("a serde_json::Value always serializes");

        // SAFETY: zeroed out-structs are valid (integers and null pointers).
        let (mut out, mut err): (abi::BpKernels, abi::BpError) = unsafe { (std::mem::zeroed(), std::mem::zeroed()) };
        let status = unsafe { kernels_fn(abi::BpStr::of(&params_json), &mut out, &mut err) };
        let call = "biscale_plugin_kernels";
        let kernels = match status {
            abi::STATUS_OK => {
                let _owned = Owned { free: api.free, owner: out.owner };
                unsafe { read_kernels(&out) }.map_err(|m| invalid(call, m))?
            }
            s => return Err(status_error(&path, call, s, &err, api.free)),
        };
        let guard = Guard::new(path, name, kernels)?;
        Ok(Self { guard, library_hash, params, params_json, api, _lib: lib })
    }

    /// The library file as loaded: absolute, with symlinks and `..` resolved.
    pub fn path(&self) -> &Path {
        &self.guard.path
    }

    /// The name the plugin reports (its kind is `plugin:<name>`).
    pub fn name(&self) -> &str {
        &self.guard.name
    }

    /// The GPU gather program as plain data (what `Compressor::kernels` returns).
    pub fn gpu_kernels(&self) -> &KernelDesc {
        &self.guard.kernels
    }

    /// Everything the host can check on a form of this plugin (see the module docs).
    pub fn check_form(&self, form: &CompressedForm) -> Result<(), PluginError> {
        self.guard.check_form(form)
    }

    /// [`Compressor::compress`] with the typed error.
    pub fn compress_plugin(
        &self,
        t: &TransferMatrix,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, PluginError> {
        let start = Instant::now();
        let call = "biscale_plugin_compress";
        let path = &self.guard.path;
        let invalid = |message: String| PluginError::Invalid { path: path.clone(), call, message };
        let csr = t.csr();
        if !csr.is_csr() || csr.nnz() > u32::MAX as usize {
            return Err(PluginError::Plugin {
                path: path.clone(),
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
            return Err(status_error(path, call, status, &err, self.api.free));
        }
        let _owned = Owned { free: self.api.free, owner: out.owner };
        let (arrays, meta) = unsafe { read_form(&out) }.map_err(invalid)?;
        let lossless = match out.lossless {
            0 => false,
            1 => true,
            v => return Err(invalid(format!("lossless flag is {v}, not 0 or 1"))),
        };
        let mut form = CompressedForm::new(self.guard.kind.clone(), t.shape());
        form.arrays = arrays;
        form.meta = meta;
        form.lossless = lossless;
        form.flops_per_gather = out.flops_per_gather;
        form.build_seconds = start.elapsed().as_secs_f64();
        self.guard.check_compressed(&form, t.shape(), call)?;
        ctx.report(1.0);
        Ok(form)
    }

    /// [`Compressor::gather`] with the typed error (the form is checked first).
    pub fn gather_plugin(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, PluginError> {
        let call = "biscale_plugin_gather";
        self.guard.check_gather(form, light, call)?;
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
        // Poisoned, so an element the plugin does not write is caught like a NaN.
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
            return Err(status_error(&self.guard.path, call, status, &err, self.api.free));
        }
        self.guard.lstar(form, lstar, call)
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
    forward_plugin_calls!();

    fn params(&self) -> Value {
        serde_json::json!({ "path": self.guard.path.display().to_string(), "params": self.params })
    }

    fn code_identity(&self) -> Option<u64> {
        Some(self.library_hash)
    }
}
