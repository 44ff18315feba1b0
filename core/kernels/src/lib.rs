//! # biscale-kernels
//!
//! What a compressed transfer form is to a GPU, as plain data (docs/DESIGN.md section 4:
//! compressed forms are data), in one small crate without wgpu that every party shares:
//! `biscale-core` (whose `Compressor` declares its gather program with a [`KernelDesc`]), the
//! built-in compressors and the plugin host (`biscale-compressors`), and the wgpu runtime
//! (`biscale-gpu`).
//!
//! * [`ArrayData`]: one array of a form at its stored width (u8/i8/u16/i16/u32/f32).
//! * [`KernelDesc`]: a form's GPU gather program: WGSL text (compiled after [`PRELUDE`]),
//!   its passes with their invocation counts ([`Count`]), its scratch buffers, the meta keys
//!   it reads, and the declarative [`FormCheck`]s the host runs on every form before a gather
//!   reads it, so that a corrupt offset array is an error and never an out-of-bounds read or a
//!   GPU loop of billions of steps. Built-in compressors and plugins describe their programs
//!   the same way; the checks are run by the host, never by the compressor.
//! * [`GatherParams`] and [`PRELUDE`]: the uniform block and the WGSL every gather program
//!   starts with (the bindings of `params`, `light`, `lstar`, `meta_values`, the invocation
//!   index and the narrow-integer unpacking helpers); [`ROW_PASS`]: the per-row pass a program
//!   that computes each row of `L*` on its own shares.
//! * [`reflect`] (feature `reflect`): naga parses and validates a program and lists which
//!   global binds what, by name: form array `col_idx` <-> `var<storage, read> col_idx:
//!   array<u32>`. One name per concept from the compressor to the kernel, and no hand-written
//!   binding table to drift out of sync with the WGSL.
//!
//! ```
//! use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc};
//! let sparse = KernelDesc {
//!     kind: "sparse".into(),
//!     wgsl: "/* ... */".into(),
//!     passes: vec![PassDesc { entry_point: "sparse_rows".into(), threads: Count::of([Factor::Rows]) }],
//!     scratch: vec![],
//!     meta_keys: vec![],
//!     checks: vec![FormCheck::Below { array: "col_idx".into(), bound: Count::of([Factor::Cols]) }],
//! };
//! assert_eq!(sparse.passes.len(), 1);
//! ```

mod array;
mod check;
#[cfg(feature = "reflect")]
pub mod reflect;

pub use array::ArrayData;
pub use check::{Count, Factor, FormCheck};

/// The WGSL every gather program is compiled with, before its own text.
pub const PRELUDE: &str = include_str!("prelude.wgsl");

/// The per-row pass: the entry point [`ROW_ENTRY`] runs one thread per row and stores the
/// program's `fn row_lstar(r: u32) -> vec3<f32>` as row `r` of `L*` ([`with_row_pass`]).
pub const ROW_PASS: &str = include_str!("row_pass.wgsl");

/// The entry point [`ROW_PASS`] declares.
pub const ROW_ENTRY: &str = "gather_rows";

/// `wgsl` followed by [`ROW_PASS`], for a program that defines `row_lstar`.
pub fn with_row_pass(wgsl: &str) -> String {
    format!("{wgsl}\n{ROW_PASS}")
}

/// Names the prelude declares: no form array, meta key or scratch buffer may take them.
pub const RESERVED_NAMES: &[&str] = &["params", "light", "lstar", "meta_values"];

/// What the checks and counts read of a form: its shape, its arrays and its meta values.
/// `biscale_core::compress::CompressedForm` implements it.
pub trait FormData {
    /// The compressor kind that made the form.
    fn kind(&self) -> &str;
    /// The array called `name`, if the form has one.
    fn find_array(&self, name: &str) -> Option<&ArrayData>;
    /// The meta value `key`, if the form has one.
    fn find_meta(&self, key: &str) -> Option<u64>;
    /// Rows of `T` (vertices x M).
    fn rows(&self) -> usize;
    /// Columns of `T` (N).
    fn cols(&self) -> usize;
    fn vertices(&self) -> usize;
    /// Rows per vertex, M.
    fn local_dirs(&self) -> usize;
}

/// A form that does not fit its description: `array` names the array, meta key or count
/// concerned and `what` what is wrong with it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("malformed {kind} form: '{array}' {what}")]
pub struct FormError {
    pub kind: String,
    pub array: String,
    pub what: String,
}

impl FormError {
    pub fn new(form: &dyn FormData, array: &str, what: impl Into<String>) -> Self {
        Self { kind: form.kind().to_string(), array: array.to_string(), what: what.into() }
    }
}

/// The array `name` of `form`, or an error naming it.
pub(crate) fn array<'a>(form: &'a dyn FormData, name: &str) -> Result<&'a ArrayData, FormError> {
    form.find_array(name).ok_or_else(|| FormError::new(form, name, "the form has no such array"))
}

/// The meta value `key` of `form`, or an error naming it.
pub(crate) fn meta(form: &dyn FormData, key: &str) -> Result<u64, FormError> {
    form.find_meta(key).ok_or_else(|| FormError::new(form, key, "the form has no such meta value"))
}

/// One compute dispatch: a WGSL entry point run for `threads` invocations.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PassDesc {
    pub entry_point: String,
    pub threads: Count,
}

/// A read-write buffer of `words` 32-bit words that the kernels use between passes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScratchDesc {
    pub name: String,
    pub words: Count,
}

/// Everything a GPU runtime needs to run a form's gather, as plain data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KernelDesc {
    /// The compressor kind whose forms these kernels read (equals the form's `kind`).
    pub kind: String,
    /// WGSL source without the [`PRELUDE`], which declares `params`, `light`, `lstar`,
    /// `meta_values` and the packing helpers.
    pub wgsl: String,
    /// Passes in order, all in one submission.
    pub passes: Vec<PassDesc>,
    pub scratch: Vec<ScratchDesc>,
    /// Meta keys copied, in this order, into the `meta_values` array.
    pub meta_keys: Vec<String>,
    /// Structural checks the host runs on every form before a gather.
    pub checks: Vec<FormCheck>,
}

impl KernelDesc {
    /// Run every declared check on `form` and evaluate every count (so a pass or scratch size
    /// that names a missing meta key or array fails here, before any upload).
    pub fn check_form(&self, form: &dyn FormData) -> Result<(), FormError> {
        if form.kind() != self.kind {
            return Err(FormError::new(form, "kind", format!("given to the kernels of '{}'", self.kind)));
        }
        for c in &self.checks {
            c.run(form)?;
        }
        for k in &self.meta_keys {
            meta(form, k)?;
        }
        for p in &self.passes {
            p.threads.eval(form)?;
        }
        for s in &self.scratch {
            s.words.eval(form)?;
        }
        Ok(())
    }
}

/// Uniform block of every gather pass, declared once here and mirrored by `GatherParams` in
/// [`PRELUDE`] (size and offsets checked by a layout test).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GatherParams {
    pub rows: u32,
    pub cols: u32,
    pub local_dirs: u32,
    pub vertices: u32,
    /// Invocations of this pass; the rounded-up grid's extra invocations return early.
    pub threads: u32,
    pub pass_index: u32,
    /// Texels per cubemap face edge `R` of the form's light basis (0 for another basis).
    pub light_resolution: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<GatherParams>() == 32);

#[cfg(all(test, feature = "reflect"))]
mod layout_tests {
    use super::*;
    use std::mem::offset_of;

    #[test]
    fn gather_params_layout_matches_the_prelude() {
        let module = naga::front::wgsl::parse_str(PRELUDE).expect("the prelude parses");
        let ty = module.types.iter().find(|(_, t)| t.name.as_deref() == Some("GatherParams")).expect("declared").1;
        let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("GatherParams is not a struct") };
        type P = GatherParams;
        assert_eq!(*span as usize, std::mem::size_of::<P>());
        let want = [
            ("rows", offset_of!(P, rows)),
            ("cols", offset_of!(P, cols)),
            ("local_dirs", offset_of!(P, local_dirs)),
            ("vertices", offset_of!(P, vertices)),
            ("threads", offset_of!(P, threads)),
            ("pass_index", offset_of!(P, pass_index)),
            ("light_resolution", offset_of!(P, light_resolution)),
            ("pad0", offset_of!(P, _pad)),
        ];
        assert_eq!(members.len(), want.len());
        for (m, (name, offset)) in members.iter().zip(want) {
            assert_eq!((m.name.as_deref(), m.offset as usize), (Some(name), offset));
        }
    }
}
