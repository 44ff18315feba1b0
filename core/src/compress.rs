//! The compression stage's interface (DESIGN.md section 4).
//!
//! A [`Compressor`] turns the transfer matrix `T` into a [`CompressedForm`]: a few named flat
//! arrays at their stored width plus the stats every form reports. The form is plain data:
//! the CPU gather (`L* = T L` evaluated on the compressed arrays) is the compressor's
//! [`Compressor::gather`], and the wgpu runtime runs the same arrays through WGSL kernels.
//! Storage is counted honestly: every array the gather reads, at the width it is stored.

use crate::gather::LocalRadiance;
use crate::sampling::LightVector;
use crate::transfer::TransferMatrix;
use std::collections::BTreeMap;

/// Element storage of one array of a compressed form.
#[derive(Clone, Debug, PartialEq)]
pub enum ArrayData {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    F32(Vec<f32>),
}

impl ArrayData {
    pub fn len(&self) -> usize {
        match self {
            ArrayData::U8(v) => v.len(),
            ArrayData::I8(v) => v.len(),
            ArrayData::U16(v) => v.len(),
            ArrayData::I16(v) => v.len(),
            ArrayData::U32(v) => v.len(),
            ArrayData::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes per element as stored.
    pub fn element_bytes(&self) -> usize {
        match self {
            ArrayData::U8(_) | ArrayData::I8(_) => 1,
            ArrayData::U16(_) | ArrayData::I16(_) => 2,
            ArrayData::U32(_) | ArrayData::F32(_) => 4,
        }
    }

    /// Element type name (`u8`, `i8`, `u16`, `i16`, `u32`, `f32`).
    pub fn element_type(&self) -> &'static str {
        match self {
            ArrayData::U8(_) => "u8",
            ArrayData::I8(_) => "i8",
            ArrayData::U16(_) => "u16",
            ArrayData::I16(_) => "i16",
            ArrayData::U32(_) => "u32",
            ArrayData::F32(_) => "f32",
        }
    }

    /// Stored size in bytes.
    pub fn bytes(&self) -> u64 {
        (self.len() * self.element_bytes()) as u64
    }
}

/// One named array of a compressed form.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedArray {
    pub name: String,
    pub data: ArrayData,
}

/// A compressed transfer matrix: plain arrays plus the stats every compressor reports.
#[derive(Clone, Debug, PartialEq)]
pub struct CompressedForm {
    /// The compressor kind that made it and whose gather reads it (`sparse`, `bicluster`, ...).
    pub kind: String,
    /// Shape of the matrix it stands for: rows = vertices * M, cols = N.
    pub rows: usize,
    pub cols: usize,
    /// Local directions per vertex, M.
    pub local_dirs: usize,
    pub arrays: Vec<NamedArray>,
    /// Small integer parameters the gather needs (cluster counts, term counts, ...).
    pub meta: BTreeMap<String, u64>,
    /// True when the gather reproduces `T L` up to floating-point rounding.
    pub lossless: bool,
    /// Floating-point operations of one monochrome gather (multiply and add count one each).
    pub flops_per_gather: u64,
    /// Wall-clock seconds the compressor took.
    pub build_seconds: f64,
}

impl CompressedForm {
    /// Total stored bytes over all arrays.
    pub fn bytes(&self) -> u64 {
        self.arrays.iter().map(|a| a.data.bytes()).sum()
    }

    /// Stored bytes per array, by name.
    pub fn bytes_by_array(&self) -> BTreeMap<String, u64> {
        self.arrays.iter().map(|a| (a.name.clone(), a.data.bytes())).collect()
    }

    /// The array called `name`.
    pub fn array(&self, name: &str) -> Result<&ArrayData, CompressError> {
        self.arrays
            .iter()
            .find(|a| a.name == name)
            .map(|a| &a.data)
            .ok_or_else(|| CompressError::Malformed(format!("{} form has no array '{name}'", self.kind)))
    }

    /// A metadata value the gather needs.
    pub fn meta(&self, key: &str) -> Result<u64, CompressError> {
        self.meta
            .get(key)
            .copied()
            .ok_or_else(|| CompressError::Malformed(format!("{} form has no meta '{key}'", self.kind)))
    }
}

/// Typed accessors: `form.u32s("row_ptr")?` etc.
macro_rules! typed_accessor {
    ($fn:ident, $variant:ident, $t:ty) => {
        impl CompressedForm {
            pub fn $fn(&self, name: &str) -> Result<&[$t], CompressError> {
                match self.array(name)? {
                    ArrayData::$variant(v) => Ok(v),
                    other => Err(CompressError::Malformed(format!(
                        "{} form: array '{name}' is {}, expected {}",
                        self.kind,
                        other.element_type(),
                        stringify!($t)
                    ))),
                }
            }
        }
    };
}
typed_accessor!(u8s, U8, u8);
typed_accessor!(i8s, I8, i8);
typed_accessor!(u16s, U16, u16);
typed_accessor!(i16s, I16, i16);
typed_accessor!(u32s, U32, u32);
typed_accessor!(f32s, F32, f32);

/// What a compressor may use while it works.
#[derive(Clone, Copy, Default)]
pub struct CompressContext<'a> {
    /// Seed for every random choice; the same seed gives byte-identical output.
    pub seed: u64,
    /// Called with a fraction in [0, 1] as work completes (may be called from many threads).
    pub progress: Option<&'a (dyn Fn(f64) + Sync)>,
}

impl CompressContext<'_> {
    pub fn report(&self, fraction: f64) {
        if let Some(p) = self.progress {
            p(fraction);
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CompressError {
    #[error("invalid compressor parameter: {0}")]
    Params(String),
    #[error("malformed compressed form: {0}")]
    Malformed(String),
    #[error("light vector has {got} texels, the compressed matrix has {expected} columns")]
    LightSize { got: usize, expected: usize },
    #[error("too large: {0}")]
    TooLarge(String),
    #[error("{0}")]
    Other(String),
}

/// A transfer compressor: builds a compressed form and evaluates its CPU gather.
pub trait Compressor: Send + Sync {
    /// The config `kind` of this compressor (`sparse`, `bicluster`, `cpca`, `haar`, ...).
    fn kind(&self) -> &str;
    /// Its parameters, as they go into `metrics.json`.
    fn params(&self) -> serde_json::Value;
    /// Compress `t`.
    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext) -> Result<CompressedForm, CompressError>;
    /// The CPU gather on the compressed arrays: `L*` for every row of `T`, RGB.
    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError>;
}
