//! The compression stage's interface (docs/DESIGN.md section 4).
//!
//! A [`Compressor`] turns the transfer matrix `T` into a [`CompressedForm`]: a few named flat
//! arrays at their stored width plus the stats every form reports. The form is plain data:
//! the CPU gather (`L* = T L` evaluated on the compressed arrays) is the compressor's
//! [`Compressor::gather`], and its GPU gather is the program it describes with
//! [`Compressor::kernels`] (a `biscale_kernels::KernelDesc`), which the wgpu runtime runs on
//! the same arrays. Storage is counted honestly: every array the gather reads, at the width it
//! is stored.

use crate::artifact::{Artifact, ArtifactError, Field};
use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::gather::LocalRadiance;
use crate::sampling::LightVector;
use crate::transfer::{TransferMatrix, TransferView};
use biscale_kernels::{FormData, FormError, KernelDesc};
use std::collections::BTreeMap;
use std::path::Path;

pub use biscale_kernels::ArrayData;

/// One named array of a compressed form.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedArray {
    pub name: String,
    pub data: ArrayData,
}

/// A compressed transfer matrix: plain arrays plus the stats every compressor reports.
///
/// The shape (vertices and the bases of rows and columns) is the shape of the `T` it stands
/// for and is fixed at construction ([`CompressedForm::new`]); the arrays and the metadata
/// are the compressor's own and are open, so the host's checks (and the tests that corrupt
/// forms on purpose) can reach them.
#[derive(Clone, Debug, PartialEq)]
pub struct CompressedForm {
    /// The compressor kind that made it and whose gather reads it (`sparse`, `bicluster`, ...).
    pub kind: String,
    shape: TransferShape,
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
    /// An empty form of `kind` for a matrix of `shape` (fill in arrays, meta and stats).
    pub fn new(kind: impl Into<String>, shape: TransferShape) -> Self {
        Self {
            kind: kind.into(),
            shape,
            arrays: vec![],
            meta: BTreeMap::new(),
            lossless: false,
            flops_per_gather: 0,
            build_seconds: 0.0,
        }
    }

    /// Add an array (builder style).
    pub fn with_array(mut self, name: impl Into<String>, data: ArrayData) -> Self {
        self.arrays.push(NamedArray { name: name.into(), data });
        self
    }

    /// The shape of the matrix it stands for.
    pub fn shape(&self) -> TransferShape {
        self.shape
    }
    pub fn local_basis(&self) -> LocalBasis {
        self.shape.local
    }
    pub fn light_basis(&self) -> LightBasis {
        self.shape.light
    }
    /// Rows of `T`: vertices x M.
    pub fn rows(&self) -> usize {
        self.shape.rows()
    }
    /// Columns of `T`: N.
    pub fn cols(&self) -> usize {
        self.shape.cols()
    }
    /// Local directions per vertex, M.
    pub fn local_dirs(&self) -> usize {
        self.shape.local_dirs()
    }
    pub fn vertices(&self) -> usize {
        self.shape.vertices
    }

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
            .ok_or_else(|| CompressError::malformed(&self.kind, name, "the form has no such array"))
    }

    /// A metadata value the gather needs.
    pub fn meta(&self, key: &str) -> Result<u64, CompressError> {
        self.meta
            .get(key)
            .copied()
            .ok_or_else(|| CompressError::malformed(&self.kind, key, "the form has no such meta value"))
    }

    /// An error unless `light` is in the basis of the form's columns.
    pub fn check_light(&self, light: &LightVector) -> Result<(), CompressError> {
        if light.basis() != self.light_basis() {
            return Err(CompressError::LightBasis { got: light.basis(), expected: self.light_basis() });
        }
        Ok(())
    }

    /// `L*` of this form's shape from row values (the gathers' common last step).
    pub fn lstar(&self, values: Vec<crate::Rgb>) -> Result<LocalRadiance, CompressError> {
        LocalRadiance::new(self.local_basis(), self.vertices(), values)
            .map_err(|e| CompressError::malformed(&self.kind, "L*", e.to_string()))
    }

    /// The three lights of a fused [`Compressor::gather_three`], each checked against the
    /// form's light basis, interleaved per texel by `lanes` into the `W`-wide layout the
    /// compressor's kernel reads.
    pub fn interleave_three<const W: usize>(
        &self,
        lights: [&LightVector; 3],
        lanes: impl Fn([crate::Rgb; 3]) -> [f32; W],
    ) -> Result<Vec<[f32; W]>, CompressError> {
        for l in lights {
            self.check_light(l)?;
        }
        let [x, y, z] = lights.map(|l| &l.power);
        Ok((x.iter().zip(y).zip(z)).map(|((a, b), c)| lanes([*a, *b, *c])).collect())
    }

    /// The three `L*` of a fused gather whose rows hold light `i`'s RGB at lanes
    /// `i * stride .. i * stride + 3`.
    pub fn lstar_three<const W: usize>(
        &self,
        wide: &[[f32; W]],
        stride: usize,
    ) -> Result<[LocalRadiance; 3], CompressError> {
        let lane =
            |i: usize| self.lstar(wide.iter().map(|w| [w[stride * i], w[stride * i + 1], w[stride * i + 2]]).collect());
        Ok([lane(0)?, lane(1)?, lane(2)?])
    }
}

/// A compressed form as a file ([`crate::artifact`], kind `form`): the compressor kind, the
/// shape, the stats, every meta value as a field `meta.<key>`, and the arrays as they are.
impl CompressedForm {
    /// The artifact kind of a compressed form.
    pub const ARTIFACT: &'static str = "form";

    pub fn to_artifact(&self) -> Artifact {
        let mut a = Artifact::new(Self::ARTIFACT)
            .with_shape(self.shape)
            .with("compressor", Field::Str(self.kind.clone()))
            .with("lossless", Field::U64(self.lossless as u64))
            .with("flops_per_gather", Field::U64(self.flops_per_gather))
            .with("build_seconds", Field::F64(self.build_seconds));
        for (k, v) in &self.meta {
            a = a.with(&format!("{META_PREFIX}{k}"), Field::U64(*v));
        }
        a.arrays = self.arrays.clone();
        a
    }

    /// The form an artifact holds. What the arrays mean is the compressor's to check: its
    /// gather bounds-checks what it reads, and its `KernelDesc` checks run before any GPU
    /// upload or plugin gather.
    pub fn from_artifact(mut a: Artifact) -> Result<Self, ArtifactError> {
        a.expect_kind(Self::ARTIFACT)?;
        let mut form = Self::new(a.str("compressor")?, a.shape()?);
        form.lossless = match a.u64("lossless")? {
            0 => false,
            1 => true,
            x => return Err(a.corrupt(format!("field 'lossless' is {x}, not 0 or 1"))),
        };
        form.flops_per_gather = a.u64("flops_per_gather")?;
        form.build_seconds = a.f64("build_seconds")?;
        for (name, value) in &a.fields {
            if let Some(key) = name.strip_prefix(META_PREFIX) {
                match value {
                    Field::U64(v) => form.meta.insert(key.to_string(), *v),
                    _ => return Err(a.corrupt(format!("field '{name}' is not an integer"))),
                };
            }
        }
        form.arrays = std::mem::take(&mut a.arrays);
        Ok(form)
    }

    /// Write the form to `path` atomically.
    pub fn save(&self, path: &Path) -> crate::Result<()> {
        self.to_artifact().save(path)
    }

    /// Read a form written by [`Self::save`].
    pub fn load(path: &Path) -> Result<Self, ArtifactError> {
        Self::from_artifact(Artifact::load(path)?)
    }
}

/// Field-name prefix of a form's meta values in its file.
const META_PREFIX: &str = "meta.";

/// Typed accessors: `form.u32s("row_ptr")?` etc.
macro_rules! typed_accessor {
    ($fn:ident, $variant:ident, $t:ty) => {
        impl CompressedForm {
            pub fn $fn(&self, name: &str) -> Result<&[$t], CompressError> {
                match self.array(name)? {
                    ArrayData::$variant(v) => Ok(v),
                    other => Err(CompressError::malformed(
                        &self.kind,
                        name,
                        format!("is {}, expected {}", other.element_type(), stringify!($t)),
                    )),
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
    /// What the settings of one sweep share (`None`: nothing is kept between calls).
    pub sweep: Option<&'a Sweep>,
}

/// What the settings of one sweep (a run's settings of one compressor kind on one matrix) may
/// share: a kind keeps here an intermediate its next setting can reuse, under a key of its own
/// that says what it was computed from (the bicluster kind keeps its greedy output, which every
/// error budget of the sweep prunes). One entry: keeping another replaces it. The sweep's
/// owner holds it for the sweep and drops it after, with whatever it holds; no compressor
/// keeps state of its own between calls.
#[derive(Default)]
pub struct Sweep {
    slot: std::sync::Mutex<Option<SweepEntry>>,
}

type SweepEntry = (Box<dyn std::any::Any + Send + Sync>, std::sync::Arc<dyn std::any::Any + Send + Sync>);

impl Sweep {
    /// The value kept under `key`, when the entry is of that key (and of type `V`).
    pub fn get<K, V>(&self, key: &K) -> Option<std::sync::Arc<V>>
    where
        K: PartialEq + std::any::Any + Send + Sync,
        V: std::any::Any + Send + Sync,
    {
        let slot = self.slot.lock().unwrap_or_else(|e| e.into_inner());
        let (k, v) = slot.as_ref()?;
        (k.downcast_ref::<K>()? == key).then(|| v.clone().downcast::<V>().ok()).flatten()
    }

    /// Keep `value` under `key`, replacing what was kept.
    pub fn keep<K, V>(&self, key: K, value: std::sync::Arc<V>)
    where
        K: PartialEq + std::any::Any + Send + Sync,
        V: std::any::Any + Send + Sync,
    {
        *self.slot.lock().unwrap_or_else(|e| e.into_inner()) = Some((Box::new(key), value));
    }

    /// Whether anything is kept.
    pub fn is_empty(&self) -> bool {
        self.slot.lock().unwrap_or_else(|e| e.into_inner()).is_none()
    }
}

impl CompressContext<'_> {
    pub fn report(&self, fraction: f64) {
        if let Some(p) = self.progress {
            p(fraction);
        }
    }
}

/// What can go wrong compressing or gathering. Every variant says what it concerns.
#[derive(Debug, thiserror::Error)]
pub enum CompressError {
    #[error("invalid compressor parameter: {0}")]
    Params(String),
    /// A form whose arrays do not fit together: `array` names the array (or meta key) and
    /// `what` what is wrong with it.
    #[error("malformed {kind} form: '{array}' {what}")]
    Malformed { kind: String, array: String, what: String },
    #[error("the light vector is in {got}, the compressed matrix's columns are {expected}")]
    LightBasis { got: LightBasis, expected: LightBasis },
    #[error("too large: {0}")]
    TooLarge(String),
    /// A failure of a compressor's own code (a plugin library's), kept whole so a caller can
    /// `downcast_ref` it to its type.
    #[error(transparent)]
    External(Box<dyn std::error::Error + Send + Sync>),
}

/// A failure outside the compressor, met on its way (reading a part of `T`).
impl From<crate::error::CoreError> for CompressError {
    fn from(e: crate::error::CoreError) -> Self {
        CompressError::External(Box::new(e))
    }
}

impl From<FormError> for CompressError {
    fn from(e: FormError) -> Self {
        CompressError::Malformed { kind: e.kind, array: e.array, what: e.what }
    }
}

impl FormData for CompressedForm {
    fn kind(&self) -> &str {
        &self.kind
    }
    fn find_array(&self, name: &str) -> Option<&ArrayData> {
        self.arrays.iter().find(|a| a.name == name).map(|a| &a.data)
    }
    fn find_meta(&self, key: &str) -> Option<u64> {
        self.meta.get(key).copied()
    }
    fn rows(&self) -> usize {
        self.shape.rows()
    }
    fn cols(&self) -> usize {
        self.shape.cols()
    }
    fn vertices(&self) -> usize {
        self.shape.vertices
    }
    fn local_dirs(&self) -> usize {
        self.shape.local_dirs()
    }
}

impl CompressError {
    /// A [`CompressError::Malformed`].
    pub fn malformed(kind: &str, array: &str, what: impl Into<String>) -> Self {
        CompressError::Malformed { kind: kind.to_string(), array: array.to_string(), what: what.into() }
    }
}

/// A transfer compressor as one self-describing unit: it builds a compressed form, evaluates
/// the form's CPU gather, describes the form's GPU gather program, and reports its own
/// statistics. Built-in compressors and plugins implement it alike.
pub trait Compressor: Send + Sync {
    /// The config `kind` of this compressor (`sparse`, `bicluster`, `cpca`, `haar`, ...).
    fn kind(&self) -> &str;
    /// Its parameters, as they go into `metrics.json`.
    fn params(&self) -> serde_json::Value;
    /// Compress `t`.
    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError>;
    /// The CPU gather on the compressed arrays: `L*` for every row of `T`, RGB.
    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError>;

    /// [`Compressor::gather`] of three lights, bit for bit (the light moments of
    /// [`crate::gather::moments`]). The default gathers them one after another; a compressor
    /// may fuse them into one pass over its form.
    fn gather_three(
        &self,
        form: &CompressedForm,
        lights: [&LightVector; 3],
    ) -> Result<[LocalRadiance; 3], CompressError> {
        Ok([self.gather(form, lights[0])?, self.gather(form, lights[1])?, self.gather(form, lights[2])?])
    }
    /// The GPU gather program of `form` (a form of this compressor), as plain data with the
    /// structural checks the host runs before any upload.
    fn kernels(&self, form: &CompressedForm) -> Result<KernelDesc, CompressError>;
    /// Compressor-specific statistics of `form` for the report (biclustering: the paper's
    /// Table I quantities); none by default. `t` may be a sharded run's parts, read one at a
    /// time ([`TransferView::for_each_part`]): statistics that need `T`'s values make one pass.
    fn stats(&self, _form: &CompressedForm, _t: TransferView<'_>) -> Option<serde_json::Value> {
        None
    }
    /// A hash of the code that makes this compressor's forms when it is not biscale's own
    /// (a plugin: its library's bytes), so a cached form is not reused after that code
    /// changes; `None` for built-ins (biscale's build identifies their code).
    fn code_identity(&self) -> Option<u64> {
        None
    }
    /// Whether this compressor's forms may be kept in the stage cache and reused. A compressor
    /// whose code biscale cannot identify (one a host program supplies at run time, such as a
    /// Python object) says no, so a form is never reused after that code changes.
    fn cacheable(&self) -> bool {
        true
    }
    /// Whether [`Self::kernels`] describes a GPU gather. A compressor without one (a hosted
    /// one, whose gather is its host's code) is gathered on the CPU only.
    fn has_kernels(&self) -> bool {
        true
    }
    /// Whether a form of `T` can be built from forms of its vertex ranges (a sharded
    /// precompute: [`Self::compress_part`] per shard, [`Self::merge_parts`] at the end).
    /// Whole by default: a compressor says it separates only when its merge reproduces
    /// [`Self::compress`] of the whole matrix exactly.
    fn separability(&self, _shape: TransferShape) -> Separability {
        Separability::Whole { why: "this compressor does not declare its work separable over vertices".into() }
    }
    /// The form of the rows of one vertex range of the whole `T`: `t` holds those rows alone,
    /// and `first_vertex` is the range's first vertex in the whole matrix (a multiple of
    /// [`Separability::Rows`]' `vertex_multiple`). By default a separable compressor's part
    /// is [`Self::compress`] of its rows (override it when the part depends on where the range
    /// lies, as biclustering's block seeds do); a whole one compresses a range that is the
    /// whole matrix and refuses any other.
    fn compress_part(
        &self,
        t: &TransferMatrix,
        first_vertex: usize,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, CompressError> {
        match (self.separability(t.shape()), first_vertex) {
            (Separability::Rows { .. }, _) | (_, 0) => self.compress(t, ctx),
            _ => Err(CompressError::Params(format!("{} does not compress vertex ranges separately", self.kind()))),
        }
    }
    /// The form of the whole matrix (of `shape`) from the forms of its consecutive vertex
    /// ranges, in order: equal, array for array, to [`Self::compress`] of the whole.
    fn merge_parts(&self, shape: TransferShape, parts: Vec<CompressedForm>) -> Result<CompressedForm, CompressError> {
        match <[CompressedForm; 1]>::try_from(parts) {
            Ok([only]) if only.shape() == shape => Ok(only),
            _ => Err(CompressError::Params(format!("{} does not merge forms of vertex ranges", self.kind()))),
        }
    }
}

/// How a compressor's work splits over the vertices of `T` (see
/// [`Compressor::separability`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Separability {
    /// Forms of consecutive vertex ranges merge into the form of the whole, when every range
    /// but the last holds a multiple of `vertex_multiple` vertices (biclustering's blocks;
    /// 1 for per-row compressors).
    Rows { vertex_multiple: usize },
    /// The form needs all of `T` at once; `why` says what is global about it.
    Whole { why: String },
}

/// Join forms of consecutive row ranges of one matrix (of `shape`) by concatenating every
/// array, in the parts' order. Arrays named in `pointers` are offset arrays (entry `r` of a
/// part's own range starts at `ptr[r]`, `ptr[0] = 0`, one more entry than its count): the
/// merged array keeps one leading 0 and shifts each part's offsets by the total of the parts
/// before it. Stats: lossless when every part is, flops and build seconds summed (the caller
/// corrects flops that count a per-gather cost once), meta taken from the first part (the
/// caller sets the values that are sums).
pub fn concat_parts(
    kind: &str,
    shape: TransferShape,
    parts: &[CompressedForm],
    pointers: &[&str],
) -> Result<CompressedForm, CompressError> {
    let bad = |array: &str, what: String| CompressError::malformed(kind, array, what);
    let first = parts.first().ok_or_else(|| bad("parts", "none to merge".into()))?;
    let vertices: usize = parts.iter().map(|p| p.vertices()).sum();
    if vertices != shape.vertices {
        return Err(bad("parts", format!("hold {vertices} vertices, the matrix has {}", shape.vertices)));
    }
    let mut out = CompressedForm::new(kind, shape);
    out.meta = first.meta.clone();
    out.lossless = true;
    for (i, p) in parts.iter().enumerate() {
        if p.kind != kind || p.local_basis() != shape.local || p.light_basis() != shape.light {
            return Err(bad("parts", format!("part {i} is a {} form of {}, not {kind} of {shape}", p.kind, p.shape())));
        }
        let names = |f: &CompressedForm| f.arrays.iter().map(|a| a.name.clone()).collect::<Vec<_>>();
        if names(p) != names(first) {
            return Err(bad("parts", format!("part {i} has arrays {:?}, part 0 {:?}", names(p), names(first))));
        }
        out.lossless &= p.lossless;
        out.flops_per_gather += p.flops_per_gather;
        out.build_seconds += p.build_seconds;
    }
    for (a, template) in first.arrays.iter().enumerate() {
        let name = template.name.as_str();
        let merged = if pointers.contains(&name) {
            let mut ptr = vec![0u32];
            for (i, p) in parts.iter().enumerate() {
                let ArrayData::U32(part) = &p.arrays[a].data else {
                    return Err(bad(name, format!("of part {i} is not u32 offsets")));
                };
                if part.first() != Some(&0) {
                    return Err(bad(name, format!("of part {i} does not start at 0")));
                }
                let base = *ptr.last().expect("starts with 0");
                for &x in &part[1..] {
                    ptr.push(
                        base.checked_add(x).ok_or_else(|| {
                            CompressError::TooLarge(format!("{kind}: merged '{name}' offsets pass u32"))
                        })?,
                    );
                }
            }
            ArrayData::U32(ptr)
        } else {
            let mut data = template.data.clone();
            for (i, p) in parts.iter().enumerate().skip(1) {
                if !data.append(&p.arrays[a].data) {
                    return Err(bad(
                        name,
                        format!("of part {i} is {}, part 0's {}", p.arrays[a].data.element_type(), data.element_type()),
                    ));
                }
            }
            data
        };
        out.arrays.push(NamedArray { name: name.to_string(), data: merged });
    }
    Ok(out)
}
