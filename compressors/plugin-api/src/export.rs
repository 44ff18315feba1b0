//! The plugin side of the boundary: generic bodies of the C entry points, which
//! [`crate::export_plugin!`] instantiates for one [`PluginCompressor`]. Every body runs inside
//! `catch_unwind`, so a panic becomes [`STATUS_PANIC`] and a message, never an unwind into the
//! host. What a call returns lives in one boxed [`Owned`] value whose pointer is the `owner`
//! token; `biscale_plugin_free` drops it with this crate's (the plugin's) allocator.

use crate::author::*;
use crate::*;
use serde_json::Value;
use std::any::Any;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Storage behind one returned struct. Pointers in the struct point into these fields, whose
/// heap buffers do not move when the value is boxed.
#[allow(dead_code)] // the fields are only kept alive, never read
enum Owned {
    Error(String),
    Form {
        form: PluginForm,
        arrays: Vec<BpArray>,
        meta: Vec<BpMeta>,
    },
    Kernels {
        kernels: Kernels,
        factors: Vec<Vec<BpFactor>>,
        passes: Vec<BpPass>,
        scratch: Vec<BpScratch>,
        meta_keys: Vec<BpStr>,
        checks: Vec<BpCheck>,
    },
}

fn into_owner(o: Owned) -> *mut c_void {
    Box::into_raw(Box::new(o)).cast()
}

/// `biscale_plugin_free`.
///
/// # Safety
/// `owner` is null or a token this plugin returned and that was not freed yet.
pub unsafe fn free(owner: *mut c_void) {
    if !owner.is_null() {
        // A panic while dropping plain vectors and strings is not possible short of an
        // allocator failure (which aborts); catch anyway, the boundary must not unwind.
        let _ = catch_unwind(AssertUnwindSafe(|| drop(unsafe { Box::from_raw(owner.cast::<Owned>()) })));
    }
}

fn panic_message(payload: &(dyn Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(a panic with a non-string payload)".to_string()
    }
}

/// Run `f` at the boundary: status code, message into `err` on failure.
fn guard(err: *mut BpError, f: impl FnOnce() -> Result<(), String>) -> i32 {
    let (status, message) = match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => return STATUS_OK,
        Ok(Err(m)) => (STATUS_ERROR, m),
        Err(payload) => {
            let m = catch_unwind(AssertUnwindSafe(|| panic_message(&*payload))).unwrap_or_default();
            // Dropping the payload could itself panic (a payload with a panicking Drop).
            let _ = catch_unwind(AssertUnwindSafe(move || drop(payload)));
            (STATUS_PANIC, m)
        }
    };
    if !err.is_null() {
        let message_str = BpStr::of(&message);
        let owner = into_owner(Owned::Error(message));
        unsafe { err.write(BpError { message: message_str, owner }) };
    }
    status
}

/// # Safety
/// `s` points at `len` readable bytes (or `len` = 0).
unsafe fn str_in<'a>(s: BpStr) -> Result<&'a str, String> {
    if s.len == 0 {
        return Ok("");
    }
    if s.ptr.is_null() {
        return Err("null string from the host".into());
    }
    std::str::from_utf8(unsafe { std::slice::from_raw_parts(s.ptr, s.len as usize) })
        .map_err(|e| format!("string from the host is not UTF-8: {e}"))
}

/// # Safety
/// `ptr` points at `len` readable, aligned `T`s (or `len` = 0).
unsafe fn slice_in<'a, T>(ptr: *const T, len: u64, what: &str) -> Result<&'a [T], String> {
    if len == 0 {
        return Ok(&[]);
    }
    if ptr.is_null() || !(ptr as usize).is_multiple_of(std::mem::align_of::<T>()) {
        return Err(format!("{what}: null or misaligned pointer from the host"));
    }
    Ok(unsafe { std::slice::from_raw_parts(ptr, len as usize) })
}

fn params_in(params: BpStr) -> Result<Value, String> {
    let text = unsafe { str_in(params) }?;
    if text.trim().is_empty() {
        return Ok(Value::Object(Default::default()));
    }
    serde_json::from_str(text).map_err(|e| format!("parameters are not JSON: {e}"))
}

fn count_out(c: &Count) -> Vec<BpFactor> {
    c.0.iter()
        .map(|f| {
            let (tag, value, name) = match f {
                Factor::Const(v) => (FACTOR_CONST, *v, BpStr::EMPTY),
                Factor::Rows => (FACTOR_ROWS, 0, BpStr::EMPTY),
                Factor::Cols => (FACTOR_COLS, 0, BpStr::EMPTY),
                Factor::Vertices => (FACTOR_VERTICES, 0, BpStr::EMPTY),
                Factor::LocalDirs => (FACTOR_LOCAL_DIRS, 0, BpStr::EMPTY),
                Factor::Meta(k) => (FACTOR_META, 0, BpStr::of(k)),
                Factor::MetaPlus(k, a) => (FACTOR_META_PLUS, *a, BpStr::of(k)),
                Factor::Len(a) => (FACTOR_LEN, 0, BpStr::of(a)),
            };
            BpFactor { tag, _reserved: 0, value, name }
        })
        .collect()
}

fn bp_count(f: &[BpFactor]) -> BpCount {
    BpCount { factors: f.as_ptr(), count: f.len() as u64 }
}

/// `biscale_plugin_name`.
pub fn name<P: PluginCompressor>() -> BpStr {
    BpStr::of(P::NAME)
}

/// `biscale_plugin_kernels`.
///
/// # Safety
/// `params` is a valid string; `out` and `err` are writable (or null).
pub unsafe fn kernels<P: PluginCompressor>(params: BpStr, out: *mut BpKernels, err: *mut BpError) -> i32 {
    guard(err, || {
        if out.is_null() {
            return Err("null output pointer".into());
        }
        let kernels = P::kernels(&params_in(params)?)?;
        // Every count's factors live in `factors` (owned with the kernels); each inner Vec's
        // buffer stays put as more are pushed, so the pointers stay valid.
        let mut factors: Vec<Vec<BpFactor>> = Vec::new();
        let mut count = |c: &Count| {
            factors.push(count_out(c));
            bp_count(factors.last().unwrap())
        };
        let passes: Vec<BpPass> = kernels
            .passes
            .iter()
            .map(|p| BpPass { entry_point: BpStr::of(&p.entry_point), threads: count(&p.threads) })
            .collect();
        let scratch: Vec<BpScratch> =
            kernels.scratch.iter().map(|s| BpScratch { name: BpStr::of(&s.name), words: count(&s.words) }).collect();
        let checks: Vec<BpCheck> = kernels
            .checks
            .iter()
            .map(|c| {
                let (tag, array, target, n) = match c {
                    Check::Len { array, count } => (CHECK_LEN, array, None, Some(count)),
                    Check::Ptr { array, count, target } => (CHECK_PTR, array, Some(target), Some(count)),
                    Check::Below { array, bound } => (CHECK_BELOW, array, None, Some(bound)),
                    Check::Finite { array } => (CHECK_FINITE, array, None, None),
                };
                BpCheck {
                    tag,
                    _reserved: 0,
                    array: BpStr::of(array),
                    target: target.map(|t| BpStr::of(t)).unwrap_or(BpStr::EMPTY),
                    count: count(n.unwrap_or(&Count(vec![]))),
                }
            })
            .collect();
        let meta_keys: Vec<BpStr> = kernels.meta_keys.iter().map(|k| BpStr::of(k)).collect();
        let value = BpKernels {
            wgsl: BpStr::of(&kernels.wgsl),
            passes: passes.as_ptr(),
            pass_count: passes.len() as u64,
            scratch: scratch.as_ptr(),
            scratch_count: scratch.len() as u64,
            meta_keys: meta_keys.as_ptr(),
            meta_key_count: meta_keys.len() as u64,
            checks: checks.as_ptr(),
            check_count: checks.len() as u64,
            owner: std::ptr::null_mut(),
        };
        let owner = into_owner(Owned::Kernels { kernels, factors, passes, scratch, meta_keys, checks });
        unsafe { out.write(BpKernels { owner, ..value }) };
        Ok(())
    })
}

/// `biscale_plugin_compress`.
///
/// # Safety
/// `t` points at a valid [`BpCsr`] whose arrays are readable; `out`, `err` writable (or null).
pub unsafe fn compress<P: PluginCompressor>(
    t: *const BpCsr,
    params: BpStr,
    out: *mut BpForm,
    err: *mut BpError,
) -> i32 {
    guard(err, || {
        if t.is_null() || out.is_null() {
            return Err("null input or output pointer".into());
        }
        let t = unsafe { &*t };
        let view = CsrView {
            rows: t.rows as usize,
            cols: t.cols as usize,
            vertices: t.vertices as usize,
            local_dirs: t.local_dirs as usize,
            resolution: t.resolution,
            seed: t.seed,
            row_ptr: unsafe { slice_in(t.row_ptr, t.rows + 1, "row_ptr") }?,
            col_idx: unsafe { slice_in(t.col_idx, t.nnz, "col_idx") }?,
            values: unsafe { slice_in(t.values, t.nnz, "values") }?,
        };
        let form = P::compress(&view, &params_in(params)?)?;
        let arrays: Vec<BpArray> = form
            .arrays
            .iter()
            .map(|(name, a)| {
                let a = crate::author::ArrayRef::from(a);
                BpArray { name: BpStr::of(name), elem: a.elem(), _reserved: 0, len: a.len() as u64, data: a.data_ptr() }
            })
            .collect();
        let meta: Vec<BpMeta> = form.meta.iter().map(|(k, v)| BpMeta { key: BpStr::of(k), value: *v }).collect();
        let value = BpForm {
            arrays: arrays.as_ptr(),
            array_count: arrays.len() as u64,
            meta: meta.as_ptr(),
            meta_count: meta.len() as u64,
            lossless: form.lossless as u32,
            _reserved: 0,
            flops_per_gather: form.flops_per_gather,
            owner: std::ptr::null_mut(),
        };
        let owner = into_owner(Owned::Form { form, arrays, meta });
        unsafe { out.write(BpForm { owner, ..value }) };
        Ok(())
    })
}

/// `biscale_plugin_gather`.
///
/// # Safety
/// `form` points at a valid [`BpFormView`]; `light` holds `light_len` floats, `lstar`
/// `lstar_len` writable floats; `err` writable (or null).
pub unsafe fn gather<P: PluginCompressor>(
    form: *const BpFormView,
    light: *const f32,
    light_len: u64,
    lstar: *mut f32,
    lstar_len: u64,
    err: *mut BpError,
) -> i32 {
    guard(err, || {
        if form.is_null() {
            return Err("null form pointer".into());
        }
        let f = unsafe { &*form };
        let mut arrays = Vec::with_capacity(f.array_count as usize);
        for a in unsafe { slice_in(f.arrays, f.array_count, "arrays") }? {
            let name = unsafe { str_in(a.name) }?;
            let r = match a.elem {
                ELEM_U8 => ArrayRef::U8(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                ELEM_I8 => ArrayRef::I8(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                ELEM_U16 => ArrayRef::U16(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                ELEM_I16 => ArrayRef::I16(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                ELEM_U32 => ArrayRef::U32(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                ELEM_F32 => ArrayRef::F32(unsafe { slice_in(a.data.cast(), a.len, name) }?),
                other => return Err(format!("array '{name}': unknown element tag {other}")),
            };
            arrays.push((name, r));
        }
        let mut meta = Vec::with_capacity(f.meta_count as usize);
        for m in unsafe { slice_in(f.meta, f.meta_count, "meta") }? {
            meta.push((unsafe { str_in(m.key) }?, m.value));
        }
        let view = PluginFormView {
            rows: f.rows as usize,
            cols: f.cols as usize,
            local_dirs: f.local_dirs as usize,
            arrays,
            meta,
        };
        if light_len != 3 * f.cols || lstar_len != 3 * f.rows {
            return Err(format!(
                "light has {light_len} floats and L* {lstar_len}, expected 3 x {} and 3 x {}",
                f.cols, f.rows
            ));
        }
        let light: &[[f32; 3]] = unsafe { slice_in(light.cast::<[f32; 3]>(), f.cols, "light") }?;
        let values = P::gather_cpu(&view, light)?;
        if values.len() as u64 != f.rows {
            return Err(format!("gather_cpu returned {} rows, the form has {}", values.len(), f.rows));
        }
        if f.rows > 0 {
            if lstar.is_null() || !(lstar as usize).is_multiple_of(4) {
                return Err("null or misaligned L* pointer".into());
            }
            let out = unsafe { std::slice::from_raw_parts_mut(lstar.cast::<[f32; 3]>(), f.rows as usize) };
            out.copy_from_slice(&values);
        }
        Ok(())
    })
}

/// Export a [`PluginCompressor`] as the C entry points of the biscale plugin ABI (one per
/// `cdylib`). Usage: `biscale_plugin::export_plugin!(MyCompressor);`.
#[macro_export]
macro_rules! export_plugin {
    ($t:ty) => {
        $crate::export_plugin!($t, abi_version = $crate::ABI_VERSION);
    };
    // Tests only: claim another ABI version (the host must refuse it before calling anything).
    ($t:ty, abi_version = $v:expr) => {
        #[no_mangle]
        pub extern "C" fn biscale_plugin_abi_version() -> u32 {
            $v
        }
        #[no_mangle]
        pub extern "C" fn biscale_plugin_abi_layout() -> u64 {
            $crate::ABI_LAYOUT
        }
        #[no_mangle]
        pub extern "C" fn biscale_plugin_name() -> $crate::BpStr {
            $crate::export::name::<$t>()
        }
        /// # Safety
        /// See the biscale plugin ABI.
        #[no_mangle]
        pub unsafe extern "C" fn biscale_plugin_kernels(
            params: $crate::BpStr,
            out: *mut $crate::BpKernels,
            err: *mut $crate::BpError,
        ) -> i32 {
            unsafe { $crate::export::kernels::<$t>(params, out, err) }
        }
        /// # Safety
        /// See the biscale plugin ABI.
        #[no_mangle]
        pub unsafe extern "C" fn biscale_plugin_compress(
            t: *const $crate::BpCsr,
            params: $crate::BpStr,
            out: *mut $crate::BpForm,
            err: *mut $crate::BpError,
        ) -> i32 {
            unsafe { $crate::export::compress::<$t>(t, params, out, err) }
        }
        /// # Safety
        /// See the biscale plugin ABI.
        #[no_mangle]
        pub unsafe extern "C" fn biscale_plugin_gather(
            form: *const $crate::BpFormView,
            light: *const f32,
            light_len: u64,
            lstar: *mut f32,
            lstar_len: u64,
            err: *mut $crate::BpError,
        ) -> i32 {
            unsafe { $crate::export::gather::<$t>(form, light, light_len, lstar, lstar_len, err) }
        }
        /// # Safety
        /// `owner` is null or an unfreed token this plugin returned.
        #[no_mangle]
        pub unsafe extern "C" fn biscale_plugin_free(owner: *mut ::std::ffi::c_void) {
            unsafe { $crate::export::free(owner) }
        }
    };
}
