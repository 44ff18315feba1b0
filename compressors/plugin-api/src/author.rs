//! The Rust side for plugin authors: safe views of what the host passes in, owned types for
//! what the plugin returns, and the [`PluginCompressor`] trait that [`crate::export_plugin!`]
//! turns into the C entry points. Nothing here crosses the boundary itself.

use serde_json::Value;

/// Elements of one array of a plugin's compressed form, at their stored width: the same type
/// the host stores every compressed form's arrays in (`biscale_kernels::ArrayData`).
pub use biscale_kernels::ArrayData as Array;

/// A borrowed array of a form handed back to the plugin's CPU gather.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ArrayRef<'a> {
    U8(&'a [u8]),
    I8(&'a [i8]),
    U16(&'a [u16]),
    I16(&'a [i16]),
    U32(&'a [u32]),
    F32(&'a [f32]),
}

impl<'a> From<&'a Array> for ArrayRef<'a> {
    fn from(a: &'a Array) -> Self {
        match a {
            Array::U8(v) => ArrayRef::U8(v),
            Array::I8(v) => ArrayRef::I8(v),
            Array::U16(v) => ArrayRef::U16(v),
            Array::I16(v) => ArrayRef::I16(v),
            Array::U32(v) => ArrayRef::U32(v),
            Array::F32(v) => ArrayRef::F32(v),
        }
    }
}

impl ArrayRef<'_> {
    pub fn len(&self) -> usize {
        match self {
            ArrayRef::U8(v) => v.len(),
            ArrayRef::I8(v) => v.len(),
            ArrayRef::U16(v) => v.len(),
            ArrayRef::I16(v) => v.len(),
            ArrayRef::U32(v) => v.len(),
            ArrayRef::F32(v) => v.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// `ELEM_*` tag.
    pub fn elem(&self) -> u32 {
        match self {
            ArrayRef::U8(_) => crate::ELEM_U8,
            ArrayRef::I8(_) => crate::ELEM_I8,
            ArrayRef::U16(_) => crate::ELEM_U16,
            ArrayRef::I16(_) => crate::ELEM_I16,
            ArrayRef::U32(_) => crate::ELEM_U32,
            ArrayRef::F32(_) => crate::ELEM_F32,
        }
    }
    pub(crate) fn data_ptr(&self) -> *const std::ffi::c_void {
        match self {
            ArrayRef::U8(v) => v.as_ptr().cast(),
            ArrayRef::I8(v) => v.as_ptr().cast(),
            ArrayRef::U16(v) => v.as_ptr().cast(),
            ArrayRef::I16(v) => v.as_ptr().cast(),
            ArrayRef::U32(v) => v.as_ptr().cast(),
            ArrayRef::F32(v) => v.as_ptr().cast(),
        }
    }
}

/// What [`PluginCompressor::compress`] returns: named arrays, meta values and stats (the host
/// adds the shape, the kind and the build time).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct PluginForm {
    pub arrays: Vec<(String, Array)>,
    pub meta: Vec<(String, u64)>,
    /// True when the gather reproduces `T L` up to floating-point rounding.
    pub lossless: bool,
    /// Floating-point operations of one monochrome gather (multiply and add count one each).
    pub flops_per_gather: u64,
}

impl PluginForm {
    /// Borrow as the view the CPU gather reads (for calling the gather in-process).
    pub fn view(&self, rows: usize, cols: usize, local_dirs: usize) -> PluginFormView<'_> {
        PluginFormView {
            rows,
            cols,
            local_dirs,
            arrays: self.arrays.iter().map(|(n, a)| (n.as_str(), ArrayRef::from(a))).collect(),
            meta: self.meta.iter().map(|(k, v)| (k.as_str(), *v)).collect(),
        }
    }
}

/// The transfer matrix `T` in CSR: rows = vertices x M (row `v * M + j`), cols = 6 R^2.
#[derive(Clone, Copy, Debug)]
pub struct CsrView<'a> {
    pub rows: usize,
    pub cols: usize,
    pub vertices: usize,
    pub local_dirs: usize,
    /// Cubemap resolution R.
    pub resolution: u32,
    /// Seed for every random choice.
    pub seed: u64,
    /// `rows + 1` non-decreasing offsets into `col_idx` / `values`.
    pub row_ptr: &'a [u32],
    pub col_idx: &'a [u32],
    pub values: &'a [f32],
}

impl CsrView<'_> {
    /// The `(col_idx, values)` of row `r`.
    pub fn row(&self, r: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.row_ptr[r] as usize, self.row_ptr[r + 1] as usize);
        (&self.col_idx[a..b], &self.values[a..b])
    }
}

/// A compressed form as the CPU gather sees it (every declared check has passed).
#[derive(Clone, Debug)]
pub struct PluginFormView<'a> {
    pub rows: usize,
    pub cols: usize,
    pub local_dirs: usize,
    pub arrays: Vec<(&'a str, ArrayRef<'a>)>,
    pub meta: Vec<(&'a str, u64)>,
}

macro_rules! typed {
    ($fn:ident, $variant:ident, $t:ty) => {
        /// The array called `name`, which must have this element type.
        pub fn $fn(&self, name: &str) -> Result<&'a [$t], String> {
            match self.array(name)? {
                ArrayRef::$variant(v) => Ok(v),
                _ => Err(format!("array '{name}' is not {}", stringify!($t))),
            }
        }
    };
}

impl<'a> PluginFormView<'a> {
    /// The array called `name`.
    pub fn array(&self, name: &str) -> Result<ArrayRef<'a>, String> {
        self.arrays.iter().find(|(n, _)| *n == name).map(|(_, a)| *a).ok_or_else(|| format!("no array '{name}'"))
    }
    /// The meta value `key`.
    pub fn meta(&self, key: &str) -> Result<u64, String> {
        self.meta.iter().find(|(k, _)| *k == key).map(|(_, v)| *v).ok_or_else(|| format!("no meta '{key}'"))
    }
    typed!(u8s, U8, u8);
    typed!(i8s, I8, i8);
    typed!(u16s, U16, u16);
    typed!(i16s, I16, i16);
    typed!(u32s, U32, u32);
    typed!(f32s, F32, f32);
}

/// Sizes the host computes from a form (the factors and their product), as the host's own
/// kernel descriptions use them.
pub use biscale_kernels::{Count, Factor};

/// One compute pass of the GPU gather.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pass {
    pub entry_point: String,
    pub threads: Count,
}

/// A read-write scratch buffer of `words` 32-bit words.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Scratch {
    pub name: String,
    pub words: Count,
}

/// A structural fact the host verifies on every form before any gather (see the ABI's
/// `CHECK_*` tags). Declare enough that no kernel can loop or index far out of range.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Check {
    Len { array: String, count: Count },
    Ptr { array: String, count: Count, target: String },
    Below { array: String, bound: Count },
    Finite { array: String },
}

/// The GPU gather program: WGSL (binding form arrays by name, see `gather/prelude.wgsl` in
/// biscale-gpu), its passes, scratch buffers, meta keys and the checks.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct Kernels {
    pub wgsl: String,
    pub passes: Vec<Pass>,
    pub scratch: Vec<Scratch>,
    pub meta_keys: Vec<String>,
    pub checks: Vec<Check>,
}

/// A transfer compressor in a plugin. Stateless: every call gets what it needs. All three
/// functions may be called from several threads at once. Errors are plain messages; panics
/// are caught at the boundary and reported as errors.
pub trait PluginCompressor {
    /// The plugin's name (`[a-z0-9_]+`); its config kind is `plugin:<NAME>`.
    const NAME: &'static str;
    /// The GPU gather for these parameters (called once, when the host loads the plugin: a good
    /// place to reject unknown or invalid parameters).
    fn kernels(params: &Value) -> Result<Kernels, String>;
    /// Compress `t`.
    fn compress(t: &CsrView<'_>, params: &Value) -> Result<PluginForm, String>;
    /// The CPU gather: `L*` (rows x RGB) from `light` (N texels x RGB, power per texel).
    fn gather_cpu(form: &PluginFormView<'_>, light: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, String>;
}
