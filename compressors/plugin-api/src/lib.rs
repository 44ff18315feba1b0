//! # biscale-plugin-api (`biscale_plugin`)
//!
//! The C ABI between biscale and a transfer compressor built as a shared library (a Rust
//! `cdylib`, or anything else that exports these C symbols), plus the Rust side that makes a
//! plugin a few dozen lines: the [`PluginCompressor`] trait and [`export_plugin!`].
//!
//! ```no_run
//! struct MyCompressor;
//! impl biscale_plugin::PluginCompressor for MyCompressor {
//!     const NAME: &'static str = "mine";
//!     fn kernels(params: &serde_json::Value) -> Result<biscale_plugin::Kernels, String> { todo!() }
//!     fn compress(t: &biscale_plugin::CsrView, params: &serde_json::Value) -> Result<biscale_plugin::PluginForm, String> { todo!() }
//!     fn gather_cpu(form: &biscale_plugin::PluginFormView, light: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, String> { todo!() }
//! }
//! biscale_plugin::export_plugin!(MyCompressor);
//! ```
//! and in its `Cargo.toml`: `[lib] crate-type = ["cdylib", "rlib"]`. The experiment names it with
//! `kind = "plugin"`, `path = "target/release/libmine.so"` and free-form `params = { ... }`.
//! A complete example is `compressors/plugins/quantized`.
//!
//! ## The ABI, version 1.0
//!
//! Only plain data crosses the boundary: the `#[repr(C)]` structs of this module (sizes pinned
//! by compile-time asserts on 64-bit targets), integers, and pointers to arrays of them. No
//! Rust type (`String`, `Vec`, trait objects, `Result`) ever crosses; strings are UTF-8 byte
//! ranges ([`BpStr`], not NUL-terminated).
//!
//! **Handshake.** The host resolves and calls `biscale_plugin_abi_version() -> u32` before
//! anything else. The value is `major << 16 | minor` ([`ABI_VERSION`]). A different major is
//! refused without calling any other symbol. Minor versions only ever *append* entry points or
//! use `_reserved` fields, so a host with a newer minor uses only what the plugin's minor has.
//! Second, `biscale_plugin_abi_layout() -> u64` must equal [`ABI_LAYOUT`], a fingerprint of the
//! size and alignment of every struct below (a plugin built against an edited copy of this
//! crate with the same version number is refused too).
//!
//! **Entry points** (all `extern "C"`, unmangled, thread-safe: the host may call them from
//! several threads at once):
//!
//! | symbol | signature | does |
//! |---|---|---|
//! | `biscale_plugin_abi_version` | `() -> u32` | [`ABI_VERSION`] the plugin was built for |
//! | `biscale_plugin_abi_layout` | `() -> u64` | [`ABI_LAYOUT`] of the plugin's copy of this crate |
//! | `biscale_plugin_name` | `() -> BpStr` | static name (`[a-z0-9_]+`); the kind is `plugin:<name>` |
//! | `biscale_plugin_kernels` | `(params: BpStr, out: *mut BpKernels, err: *mut BpError) -> i32` | GPU kernels for these parameters |
//! | `biscale_plugin_compress` | `(t: *const BpCsr, params: BpStr, out: *mut BpForm, err: *mut BpError) -> i32` | compress `T` |
//! | `biscale_plugin_gather` | `(form: *const BpFormView, light: *const f32, light_len: u64, lstar: *mut f32, lstar_len: u64, err: *mut BpError) -> i32` | CPU gather `L* = T L` |
//! | `biscale_plugin_free` | `(owner: *mut c_void)` | frees what one call returned |
//!
//! `params` is the experiment's `params` table as JSON text. `light` is `N` texels x RGB
//! (`light_len = 3 N`), `lstar` is rows x RGB (`lstar_len = 3 rows`), both host memory; the
//! plugin writes every element of `lstar`.
//!
//! **Status.** Fallible calls return [`STATUS_OK`] (then `out` is filled), [`STATUS_ERROR`] (the
//! plugin's own error) or [`STATUS_PANIC`] (a Rust panic was caught at the boundary: a panic
//! never unwinds into the host); on a non-zero status `err` holds a message. Plugins must be
//! built with `panic = "unwind"` (the default) for this to hold.
//!
//! **Ownership.** Everything the plugin returns ([`BpKernels`], [`BpForm`], [`BpError`]) points
//! into memory the plugin allocated and owns, named by the struct's `owner` token. The host
//! copies what it needs and then calls `biscale_plugin_free(owner)` exactly once; it never frees
//! plugin memory with its own allocator. `owner` may be null (nothing to free). Memory the host
//! passes in (`BpCsr`, `BpFormView`, `light`, `lstar`) is only borrowed for the call.
//!
//! **Trust.** The host validates everything a plugin returns before use: UTF-8, names (WGSL
//! identifiers, unique, not reserved), element tags, null and misaligned pointers, and then
//! every [`BpCheck`] the kernels declare, on every form, before any CPU or GPU gather; the WGSL
//! is parsed and validated at load. What the checks do not state (say, an index array with no
//! `Below` check) is not checked: a GPU kernel then reads clamped garbage, never foreign memory.

pub mod author;
#[doc(hidden)]
pub mod export;

pub use author::*;
/// The per-row pass a plugin's WGSL may share with the built-in gathers: define
/// `fn row_lstar(r: u32) -> vec3<f32>`, append [`ROW_PASS`] ([`with_row_pass`]) and name the
/// pass [`ROW_ENTRY`].
pub use biscale_kernels::{with_row_pass, ROW_ENTRY, ROW_PASS};
pub use serde_json;

use std::ffi::c_void;

/// ABI major version: a plugin of another major is refused.
pub const ABI_MAJOR: u32 = 1;
/// ABI minor version: entry points appended since `.0`.
pub const ABI_MINOR: u32 = 0;
/// `major << 16 | minor`, as `biscale_plugin_abi_version` returns it.
pub const ABI_VERSION: u32 = (ABI_MAJOR << 16) | ABI_MINOR;

/// Major part of an encoded version.
pub const fn abi_major(version: u32) -> u32 {
    version >> 16
}
/// Minor part of an encoded version.
pub const fn abi_minor(version: u32) -> u32 {
    version & 0xffff
}

/// The call succeeded; its `out` struct is filled.
pub const STATUS_OK: i32 = 0;
/// The plugin returned an error; `err` holds its message.
pub const STATUS_ERROR: i32 = 1;
/// The plugin panicked; the panic was caught at the boundary and `err` holds its message.
pub const STATUS_PANIC: i32 = 2;

/// Element type tags of [`BpArray::elem`].
pub const ELEM_U8: u32 = 1;
pub const ELEM_I8: u32 = 2;
pub const ELEM_U16: u32 = 3;
pub const ELEM_I16: u32 = 4;
pub const ELEM_U32: u32 = 5;
pub const ELEM_F32: u32 = 6;

/// Bytes per element of a tag, `None` for an unknown tag.
pub const fn elem_bytes(tag: u32) -> Option<usize> {
    match tag {
        ELEM_U8 | ELEM_I8 => Some(1),
        ELEM_U16 | ELEM_I16 => Some(2),
        ELEM_U32 | ELEM_F32 => Some(4),
        _ => None,
    }
}

/// [`BpFactor::tag`] values (mirroring `biscale_core::kernels::Factor`).
pub const FACTOR_CONST: u32 = 1;
pub const FACTOR_ROWS: u32 = 2;
pub const FACTOR_COLS: u32 = 3;
pub const FACTOR_VERTICES: u32 = 4;
pub const FACTOR_LOCAL_DIRS: u32 = 5;
/// `name` is a meta key.
pub const FACTOR_META: u32 = 6;
/// `name` is a meta key, `value` is added to it.
pub const FACTOR_META_PLUS: u32 = 7;
/// `name` is a form array; its element count.
pub const FACTOR_LEN: u32 = 8;

/// [`BpCheck::tag`] values (mirroring `biscale_core::kernels::FormCheck`).
/// `len(array) == count`.
pub const CHECK_LEN: u32 = 1;
/// `array` is `count + 1` non-decreasing integers from 0 to `len(target)`.
pub const CHECK_PTR: u32 = 2;
/// Every element of the integer `array` is in `0..count`.
pub const CHECK_BELOW: u32 = 3;
/// Every element of the f32 `array` is finite (`count` unused).
pub const CHECK_FINITE: u32 = 4;

/// A UTF-8 string: `len` bytes at `ptr` (no NUL terminator; `ptr` may be null when `len` = 0).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpStr {
    pub ptr: *const u8,
    pub len: u64,
}

impl BpStr {
    pub const EMPTY: BpStr = BpStr { ptr: std::ptr::null(), len: 0 };
    /// Borrow `s` (valid as long as `s` is).
    pub fn of(s: &str) -> Self {
        BpStr { ptr: s.as_ptr(), len: s.len() as u64 }
    }
}

/// The transfer matrix `T` handed to `biscale_plugin_compress`: CSR, rows = vertices x M.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpCsr {
    pub rows: u64,
    pub cols: u64,
    pub vertices: u64,
    /// Local directions per vertex, M (row `v * M + j`).
    pub local_dirs: u64,
    /// Cubemap resolution R (cols = 6 R^2).
    pub resolution: u32,
    pub _reserved: u32,
    /// Seed for every random choice (same seed, byte-identical output).
    pub seed: u64,
    /// `rows + 1` entries.
    pub row_ptr: *const u32,
    /// `nnz` entries each.
    pub col_idx: *const u32,
    pub values: *const f32,
    pub nnz: u64,
}

/// One named array of a compressed form: `len` elements of type `elem` at `data`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpArray {
    pub name: BpStr,
    /// One of the `ELEM_*` tags.
    pub elem: u32,
    pub _reserved: u32,
    pub len: u64,
    /// Aligned for the element type; may be null when `len` = 0.
    pub data: *const c_void,
}

/// One `meta` key/value of a compressed form.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpMeta {
    pub key: BpStr,
    pub value: u64,
}

/// A compressed form as `biscale_plugin_compress` returns it (the host knows its shape).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpForm {
    pub arrays: *const BpArray,
    pub array_count: u64,
    pub meta: *const BpMeta,
    pub meta_count: u64,
    /// 1 when the gather reproduces `T L` up to rounding, else 0.
    pub lossless: u32,
    pub _reserved: u32,
    /// Floating-point operations of one monochrome gather.
    pub flops_per_gather: u64,
    /// Pass to `biscale_plugin_free` when done.
    pub owner: *mut c_void,
}

/// A compressed form handed to `biscale_plugin_gather` (host memory, borrowed).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpFormView {
    pub rows: u64,
    pub cols: u64,
    pub local_dirs: u64,
    pub arrays: *const BpArray,
    pub array_count: u64,
    pub meta: *const BpMeta,
    pub meta_count: u64,
}

/// One factor of a size: `FACTOR_*` tag, a constant `value`, a meta key or array `name`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpFactor {
    pub tag: u32,
    pub _reserved: u32,
    pub value: u64,
    pub name: BpStr,
}

/// A size: the product of `count` factors (none = 1).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpCount {
    pub factors: *const BpFactor,
    pub count: u64,
}

/// One compute pass: entry point and invocation count.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpPass {
    pub entry_point: BpStr,
    pub threads: BpCount,
}

/// A read-write scratch buffer of `words` 32-bit words.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpScratch {
    pub name: BpStr,
    pub words: BpCount,
}

/// A structural check the host runs on every form (`CHECK_*` tag).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpCheck {
    pub tag: u32,
    pub _reserved: u32,
    pub array: BpStr,
    /// `CHECK_PTR` only: the array the pointers index.
    pub target: BpStr,
    pub count: BpCount,
}

/// The GPU gather program as `biscale_plugin_kernels` returns it.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpKernels {
    /// WGSL without the host's prelude (see `biscale-gpu`, `gather/prelude.wgsl`).
    pub wgsl: BpStr,
    pub passes: *const BpPass,
    pub pass_count: u64,
    pub scratch: *const BpScratch,
    pub scratch_count: u64,
    /// Meta keys copied, in order, into the kernels' `meta_values` array.
    pub meta_keys: *const BpStr,
    pub meta_key_count: u64,
    pub checks: *const BpCheck,
    pub check_count: u64,
    /// Pass to `biscale_plugin_free` when done.
    pub owner: *mut c_void,
}

/// The message of a failed call.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BpError {
    pub message: BpStr,
    /// Pass to `biscale_plugin_free` when done.
    pub owner: *mut c_void,
}

impl BpError {
    pub const EMPTY: BpError = BpError { message: BpStr::EMPTY, owner: std::ptr::null_mut() };
}

/// Exported signatures, for the host's symbol lookups.
pub mod sig {
    use super::*;
    pub type AbiVersion = unsafe extern "C" fn() -> u32;
    pub type AbiLayout = unsafe extern "C" fn() -> u64;
    pub type Name = unsafe extern "C" fn() -> BpStr;
    pub type Kernels = unsafe extern "C" fn(BpStr, *mut BpKernels, *mut BpError) -> i32;
    pub type Compress = unsafe extern "C" fn(*const BpCsr, BpStr, *mut BpForm, *mut BpError) -> i32;
    pub type Gather = unsafe extern "C" fn(*const BpFormView, *const f32, u64, *mut f32, u64, *mut BpError) -> i32;
    pub type Free = unsafe extern "C" fn(*mut c_void);
}

/// Exported symbol names (NUL-terminated for `dlsym`).
pub mod symbols {
    pub const ABI_VERSION: &[u8] = b"biscale_plugin_abi_version\0";
    pub const ABI_LAYOUT: &[u8] = b"biscale_plugin_abi_layout\0";
    pub const NAME: &[u8] = b"biscale_plugin_name\0";
    pub const KERNELS: &[u8] = b"biscale_plugin_kernels\0";
    pub const COMPRESS: &[u8] = b"biscale_plugin_compress\0";
    pub const GATHER: &[u8] = b"biscale_plugin_gather\0";
    pub const FREE: &[u8] = b"biscale_plugin_free\0";
}

// Layouts pinned on 64-bit targets (the only ones biscale builds for): a field added,
// removed or reordered fails the build here before it can fail at run time.
#[cfg(target_pointer_width = "64")]
const _: () = {
    use std::mem::size_of;
    assert!(size_of::<BpStr>() == 16);
    assert!(size_of::<BpCsr>() == 80);
    assert!(size_of::<BpArray>() == 40);
    assert!(size_of::<BpMeta>() == 24);
    assert!(size_of::<BpForm>() == 56);
    assert!(size_of::<BpFormView>() == 56);
    assert!(size_of::<BpFactor>() == 32);
    assert!(size_of::<BpCount>() == 16);
    assert!(size_of::<BpPass>() == 32);
    assert!(size_of::<BpScratch>() == 32);
    assert!(size_of::<BpCheck>() == 56);
    assert!(size_of::<BpKernels>() == 88);
    assert!(size_of::<BpError>() == 24);
};

/// Fingerprint of every boundary struct's size and alignment (FNV-1a over them, with the
/// version), returned by `biscale_plugin_abi_layout`.
pub const ABI_LAYOUT: u64 = {
    use std::mem::{align_of, size_of};
    let parts = [
        ABI_VERSION as usize,
        size_of::<BpStr>(),
        align_of::<BpStr>(),
        size_of::<BpCsr>(),
        align_of::<BpCsr>(),
        size_of::<BpArray>(),
        align_of::<BpArray>(),
        size_of::<BpMeta>(),
        size_of::<BpForm>(),
        size_of::<BpFormView>(),
        size_of::<BpFactor>(),
        size_of::<BpCount>(),
        size_of::<BpPass>(),
        size_of::<BpScratch>(),
        size_of::<BpCheck>(),
        size_of::<BpKernels>(),
        size_of::<BpError>(),
        align_of::<BpKernels>(),
        size_of::<usize>(),
    ];
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut i = 0;
    while i < parts.len() {
        h ^= parts[i] as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
        i += 1;
    }
    h
};
