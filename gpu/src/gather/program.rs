//! A gather program: the data that tells the generic host how to run one compressed form's
//! WGSL kernels (DESIGN.md section 4: compressed forms are data).
//!
//! A program is WGSL text plus a short description: its passes (entry point and how many
//! invocations), its scratch buffers, and which `meta` keys it reads. Bindings are not listed
//! by hand: the host parses the WGSL with naga and binds every `@group(0)` global by *name*
//! (form array `col_idx` <-> `var<storage, read> col_idx: array<u32>`), checking element types
//! and access modes. One name per concept from the compressor to the kernel, and the table
//! cannot drift out of sync with the WGSL. A plugin hands over exactly these plain parts.

use crate::error::{GpuError, Result};
use biscale_core::compress::{ArrayData, CompressedForm};

/// Sizes computed from a form (a product of factors: rows, columns, meta values, array
/// lengths), shared with the plugin interface in `biscale-core` so built-in and plugin
/// programs use one definition. `Count::eval` returns a `CompressError`, which `?` turns
/// into [`GpuError::Form`].
pub use biscale_core::kernels::{Count, Factor};

/// One compute dispatch: a WGSL entry point run for `threads` invocations.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KernelPass {
    pub entry_point: String,
    pub threads: Count,
}

/// A read-write buffer the program needs between passes, `words` 32-bit words.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScratchBuffer {
    pub name: String,
    pub words: Count,
}

/// A structural check of a form: `Err` says what is wrong.
pub type ValidateFn = fn(&CompressedForm) -> std::result::Result<(), String>;

/// Everything the host needs to run a form's gather on the GPU.
#[derive(Clone, Debug)]
pub struct GatherProgram {
    /// The compressor kind it runs (`sparse`, ...); must equal the form's kind.
    pub kind: String,
    /// WGSL source, without the prelude (`gather/prelude.wgsl` is prepended).
    pub wgsl: String,
    /// Passes in order; all run in one submission, each in its own compute pass.
    pub passes: Vec<KernelPass>,
    pub scratch: Vec<ScratchBuffer>,
    /// Meta keys copied, in this order, into the `meta_values` array.
    pub meta_keys: Vec<String>,
    /// Structural check of the form run before anything is uploaded, so a malformed form is
    /// a clear error and never an endless loop on the GPU (built-ins only; a plugin's host
    /// adapter may supply one too).
    pub validate: Option<ValidateFn>,
}

/// The prelude every program is compiled with.
pub const PRELUDE: &str = include_str!("prelude.wgsl");

/// Element type of a reflected storage array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Elem {
    F32,
    U32,
    I32,
    /// Anything else (a struct, a vector, ...): allowed only for scratch buffers.
    Other,
}

/// One reflected `@group(0)` global.
#[derive(Clone, Debug)]
pub(crate) struct Global {
    pub name: String,
    pub binding: u32,
    pub kind: GlobalKind,
}

#[derive(Clone, Debug)]
pub(crate) enum GlobalKind {
    Uniform { size: u64 },
    Storage { read_only: bool, elem: Elem },
}

/// A parsed program: the full source, its globals and its entry points' workgroup sizes.
pub(crate) struct Reflected {
    pub source: String,
    pub globals: Vec<Global>,
    pub workgroup_sizes: Vec<(String, [u32; 3])>,
}

/// Parse `program` (prelude included) with naga and list its bindings.
pub(crate) fn reflect(program: &GatherProgram) -> Result<Reflected> {
    let source = format!("{PRELUDE}\n{}", program.wgsl);
    let err = |message: String| GpuError::Wgsl { program: program.kind.clone(), message };
    let module = naga::front::wgsl::parse_str(&source).map_err(|e| err(e.emit_to_string(&source)))?;
    let mut globals = Vec::new();
    for (_, g) in module.global_variables.iter() {
        let Some(rb) = &g.binding else { continue };
        let name = g.name.clone().unwrap_or_default();
        if rb.group != 0 {
            return Err(err(format!("global '{name}' is in group {}; gather programs use group 0 only", rb.group)));
        }
        let kind = match g.space {
            naga::AddressSpace::Uniform => {
                let size = module.types[g.ty].inner.size(module.to_ctx()) as u64;
                GlobalKind::Uniform { size }
            }
            naga::AddressSpace::Storage { access } => {
                let elem = match &module.types[g.ty].inner {
                    naga::TypeInner::Array { base, .. } => match module.types[*base].inner {
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Float, width: 4 }) => Elem::F32,
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Uint, width: 4 }) => Elem::U32,
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Sint, width: 4 }) => Elem::I32,
                        _ => Elem::Other,
                    },
                    _ => Elem::Other,
                };
                GlobalKind::Storage { read_only: !access.contains(naga::StorageAccess::STORE), elem }
            }
            other => return Err(err(format!("global '{name}' has unsupported address space {other:?}"))),
        };
        globals.push(Global { name, binding: rb.binding, kind });
    }
    globals.sort_by_key(|g| g.binding);
    for w in globals.windows(2) {
        if w[0].binding == w[1].binding {
            return Err(err(format!("'{}' and '{}' share binding {}", w[0].name, w[1].name, w[0].binding)));
        }
    }
    let workgroup_sizes = module
        .entry_points
        .iter()
        .filter(|e| e.stage == naga::ShaderStage::Compute)
        .map(|e| (e.name.clone(), e.workgroup_size))
        .collect();
    Ok(Reflected { source, globals, workgroup_sizes })
}

/// Does a form array of this element type fit a WGSL array of `elem`? Floats need `f32`;
/// integer arrays are uploaded as packed 32-bit words and read as `u32` (or `i32`).
pub(crate) fn compatible(data: &ArrayData, elem: Elem) -> bool {
    match data {
        ArrayData::F32(_) => elem == Elem::F32,
        _ => matches!(elem, Elem::U32 | Elem::I32),
    }
}

/// The bytes uploaded for a form array: f32 and u32 as they are; u8/i8 four and u16/i16 two
/// to a 32-bit word, element `i` in the low-to-high byte order of word `i / 4` (or `i / 2`),
/// i.e. the array's little-endian bytes zero-padded to a multiple of 4.
pub fn pack_words(data: &ArrayData) -> Vec<u32> {
    fn words(bytes: &[u8]) -> Vec<u32> {
        bytes
            .chunks(4)
            .map(|c| {
                let mut w = [0u8; 4];
                w[..c.len()].copy_from_slice(c);
                u32::from_le_bytes(w)
            })
            .collect()
    }
    match data {
        ArrayData::U8(v) => words(v),
        ArrayData::I8(v) => words(&v.iter().map(|&x| x as u8).collect::<Vec<_>>()),
        ArrayData::U16(v) => words(&v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>()),
        ArrayData::I16(v) => words(&v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>()),
        ArrayData::U32(v) => v.clone(),
        ArrayData::F32(v) => v.iter().map(|x| x.to_bits()).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_puts_element_i_in_word_i_over_k() {
        let w = pack_words(&ArrayData::U8(vec![1, 2, 3, 4, 5]));
        assert_eq!(w, vec![0x0403_0201, 0x0000_0005]);
        let w = pack_words(&ArrayData::I8(vec![-1, 2]));
        assert_eq!(w, vec![0x0000_02ff]);
        let w = pack_words(&ArrayData::U16(vec![0xabcd, 0x1234, 7]));
        assert_eq!(w, vec![0x1234_abcd, 7]);
        let w = pack_words(&ArrayData::I16(vec![-2]));
        assert_eq!(w, vec![0x0000_fffe]);
        assert_eq!(pack_words(&ArrayData::F32(vec![1.5])), vec![1.5f32.to_bits()]);
    }
}
