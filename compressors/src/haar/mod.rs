//! Non-linear Haar wavelet approximation of the transfer rows (Ng, Ramamoorthi, Hanrahan 2003,
//! "All-frequency shadows using non-linear wavelet lighting approximation"), applied to the
//! rows of `T` as in the biclustering paper's comparison (Sun et al.).
//!
//! # Transform
//!
//! Each row of `T` (N = 6 R^2 texels) is viewed as six R x R cubemap faces and every face is
//! transformed by the orthonormal 2D **non-standard** Haar basis (R a power of two): at each
//! level the current s x s averages are split into 2x2 blocks `(a b; c d)` (rows, then
//! columns) and replaced by
//!
//! ```text
//! average    (a + b + c + d) / 2      stored at (i,     j    )
//! horizontal (a - b + c - d) / 2      stored at (i,     j + h)
//! vertical   (a + b - c - d) / 2      stored at (i + h, j    )
//! diagonal   (a - b - c + d) / 2      stored at (i + h, j + h)      h = s / 2
//! ```
//!
//! down to one scaling coefficient per face at (0, 0) (the usual in-place "standard layout").
//! Coefficient `i = face*R*R + row*R + col` therefore lives in the same index space as the
//! texels. The 4x4 block matrix is orthonormal, so the whole transform `W` is orthogonal
//! (block-diagonal over faces) and `T L = (T W^T)(W L)`: the runtime transforms the light once
//! and every row is a short sparse dot product with the transformed light.
//!
//! # Selection (area-weighted, Ng et al. 2003 section 5)
//!
//! Each row keeps its `terms` coefficients of largest **area-weighted magnitude**
//! `|c_i| * A_i`, where `A_i` is the solid angle (steradians) of the support of basis
//! function `i`: the sum of the exact solid angles of the texels it covers (2x2 texels for the
//! finest details, the whole face for the scaling coefficient). Why: plain `|c_i|` ranking is
//! L2-optimal for the row itself, but what we need is `T L`, and the light vector carries the
//! solid angle (`L_k` = radiance x texel solid angle), so a broad basis function meets light
//! energy in proportion to the solid angle it covers; weighting by it keeps the low-frequency
//! terms that carry most of `T L` for typical environments (Ng et al. report area weighting as
//! their best heuristic). Using exact solid angles rather than texel counts also accounts for
//! the cube's distortion (corner texels subtend about 5x less than centre texels at R = 32).
//! `weighting = "side"` ranks by `|c_i| sqrt(A_i)` instead: for an orthonormal basis the
//! transformed light's coefficient `(W L)_i` of a light smooth over the support grows as the
//! square root of the support, so `|c_i| sqrt(A_i)` is the expected size of the term's share of
//! `T L`, and the area weighting over-favours coarse terms (BENCHMARKS.md measures both over
//! the bundled skies). `weighting = "magnitude"` ranks by `|c_i|` alone. Ties break towards the lower
//! index, so the selection is deterministic. Rows whose transform has at most `terms` non-zero
//! coefficients are stored exactly (all of them); all-zero rows store nothing.
//!
//! # Compressed form (`kind = "haar"`)
//!
//! | array       | type            | length        | meaning |
//! |-------------|-----------------|---------------|---------|
//! | `row_ptr`   | u32             | rows + 1      | row r's terms are `row_ptr[r] .. row_ptr[r+1]` |
//! | `coeff_idx` | u16             | total terms   | coefficient index `face*R*R + row*R + col` in the layout above, increasing within a row |
//! | `coeff_val` | f32             | total terms   | coefficient value `(W t_r)_i` (present unless `f16_values`) |
//! | `coeff_f16` | u16 (f16 bits)  | total terms   | the same values as IEEE half floats (present when `f16_values`) |
//!
//! meta: `terms` (the per-row cap), `f16_values` (0 or 1). The cubemap resolution R is the
//! form's light basis.
//!
//! Gather: `l̂ = W L` per channel (the forward transform above on each face of the light), then
//! `L*_r = sum_{i in row r} coeff_val[i] * l̂[coeff_idx[i]]`. The CPU gather transforms and
//! accumulates in f64 (the light may hold a 10^6 sun next to a dim sky). Flops per monochrome
//! gather: `12` per 2x2 block of the light transform (8 adds, 4 halvings; `(R^2 - 1) / 3`
//! blocks per face) plus 2 per stored term. The GPU gather (`gather.wgsl`) runs the same two
//! steps in f32: a pass per (face, channel) transforms the light, a pass per row dots.

mod params;
pub use params::{Haar, HaarWeighting};

use crate::registry::{self, Kind};
use biscale_core::basis::TransferShape;
use biscale_core::compress::{
    concat_parts, ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray, Separability,
};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::{Cubemap, LightVector};
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use rayon::prelude::*;
use std::time::Instant;

impl registry::MakeCompressor for Haar {
    fn make(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
        Ok(Box::new(registry::parse::<Haar>(p)?.validated()?))
    }
}

/// The registry entry.
pub const KIND: Kind = Kind {
    fits,
    memory,
    flops: form_flops,
    ..Kind::built_in::<Haar>(
        "haar",
        "non-linear Haar wavelets: the `terms` largest area-weighted coefficients per row (lossy)",
        |p| {
            let haar = registry::parse::<Haar>(p)?;
            let label = registry::tagged_label("haar", &serde_json::to_value(haar).unwrap(), &[("terms", "t")]);
            // The default ranking is left out of the label, as settings before it was a key.
            Ok(match haar.weighting {
                HaarWeighting::Area => label,
                w => format!("{label}-{}", w.name()),
            })
        },
    )
};

/// The flops of one gather of `form`, counted from its own arrays (`eval --form` reports this,
/// not what a file claims).
/// The light's Haar transform (12 per 2x2 block, `(R^2 - 1) / 3` blocks on each of 6
/// faces) plus 2 per stored term.
fn form_flops(form: &CompressedForm) -> Option<u64> {
    let len = |name: &str| form.array(name).ok().map(|a| a.len() as u64);
    let r = u64::from(form.light_basis().cubemap_layout()?.resolution);
    let transform = 6 * 12 * ((r * r).saturating_sub(1) / 3);
    Some(transform.saturating_add(len("coeff_idx")?.saturating_mul(2)))
}

/// [`Kind::fits`]: no more terms than a row has coefficients (a count above that was once
/// accepted and reported while the form held fewer).
fn fits(p: &serde_json::Value, t: &biscale_core::transfer::TransferSettings) -> Result<(), String> {
    let p: Haar = registry::parse(p)?;
    let n = t.light_basis().len();
    if p.terms > n {
        return Err(format!(
            "terms = {} is more than the {n} coefficients of a row at {}; terms = {n} keeps every row exactly",
            p.terms,
            t.light_basis()
        ));
    }
    Ok(())
}

/// [`Kind::memory`]: per row its kept terms (u16 index, f32 value) in chunks, then the form
/// again.
fn memory(p: &serde_json::Value, t: &registry::MemoryFacts) -> registry::FormMemory {
    let p: Haar = registry::parse(p).unwrap_or_default();
    let kept = t.rows() * (p.terms as u64).min(t.light_dirs);
    let form = kept * 6 + (t.rows() + 1) * 4;
    registry::FormMemory { working: kept * 6 + t.rows() * 4 + form, form }
}

/// Rows per rayon task in the gather.
const ROWS_PER_TASK: usize = 512;

/// Resolution R of the cubemap of `basis` if the Haar transform applies to it (a cubemap, R a
/// power of two, `N <= 65536` so indices fit u16).
fn face_resolution(basis: biscale_core::basis::LightBasis) -> Result<usize, CompressError> {
    let cubemap = basis
        .cubemap_layout()
        .ok_or_else(|| CompressError::Params(format!("haar: the light basis is {basis}, not a cubemap")))?;
    let r = cubemap.resolution as usize;
    if !r.is_power_of_two() {
        return Err(CompressError::Params(format!("haar: cubemap resolution {r} is not a power of two")));
    }
    // N = 6 R^2 <= 65536 by the basis, so indices fit u16.
    Ok(r)
}

/// In-place forward non-standard Haar transform of one R x R face (row-major), standard layout.
pub fn forward_face(face: &mut [f64], r: usize) {
    debug_assert_eq!(face.len(), r * r);
    let mut tmp = vec![0.0f64; r * r];
    let mut s = r;
    while s > 1 {
        let h = s / 2;
        for i in 0..h {
            for j in 0..h {
                let a = face[2 * i * r + 2 * j];
                let b = face[2 * i * r + 2 * j + 1];
                let c = face[(2 * i + 1) * r + 2 * j];
                let d = face[(2 * i + 1) * r + 2 * j + 1];
                tmp[i * r + j] = 0.5 * (a + b + c + d);
                tmp[i * r + j + h] = 0.5 * (a - b + c - d);
                tmp[(i + h) * r + j] = 0.5 * (a + b - c - d);
                tmp[(i + h) * r + j + h] = 0.5 * (a - b - c + d);
            }
        }
        for i in 0..s {
            face[i * r..i * r + s].copy_from_slice(&tmp[i * r..i * r + s]);
        }
        s = h;
    }
}

/// In-place inverse of [`forward_face`].
pub fn inverse_face(face: &mut [f64], r: usize) {
    debug_assert_eq!(face.len(), r * r);
    let mut tmp = vec![0.0f64; r * r];
    let mut s = 2;
    while s <= r {
        let h = s / 2;
        for i in 0..h {
            for j in 0..h {
                let av = face[i * r + j];
                let ho = face[i * r + j + h];
                let ve = face[(i + h) * r + j];
                let di = face[(i + h) * r + j + h];
                tmp[2 * i * r + 2 * j] = 0.5 * (av + ho + ve + di);
                tmp[2 * i * r + 2 * j + 1] = 0.5 * (av - ho + ve - di);
                tmp[(2 * i + 1) * r + 2 * j] = 0.5 * (av + ho - ve - di);
                tmp[(2 * i + 1) * r + 2 * j + 1] = 0.5 * (av - ho - ve + di);
            }
        }
        for i in 0..s {
            face[i * r..i * r + s].copy_from_slice(&tmp[i * r..i * r + s]);
        }
        s *= 2;
    }
}

/// `W v` for a whole cubemap vector (six faces of R x R), f64.
pub fn forward_cubemap(v: &mut [f64], r: usize) {
    for face in v.chunks_mut(r * r) {
        forward_face(face, r);
    }
}

/// `W L` per channel: the transformed light the gather dots every row with (an error for a
/// light that is not on a power-of-two cubemap).
pub fn transform_light(light: &LightVector) -> Result<Vec<[f64; 3]>, CompressError> {
    let r = face_resolution(light.basis())?;
    let mut out = vec![[0.0f64; 3]; light.len()];
    for c in 0..3 {
        let mut v: Vec<f64> = light.power.iter().map(|p| p[c] as f64).collect();
        forward_cubemap(&mut v, r);
        for (o, x) in out.iter_mut().zip(v) {
            o[c] = x;
        }
    }
    Ok(out)
}

/// Solid angle (sr) of the support of every basis function, in coefficient order: the
/// weights of the area-weighted selection.
pub fn support_solid_angles(cubemap: &Cubemap) -> Vec<f64> {
    let r = cubemap.resolution as usize;
    let omega = cubemap.solid_angles();
    let mut out = vec![0.0; omega.len()];
    for face in 0..6 {
        let base = face * r * r;
        for row in 0..r {
            for col in 0..r {
                let (r0, c0, side) = support(row, col, r);
                let mut a = 0.0;
                for y in r0..r0 + side {
                    for x in c0..c0 + side {
                        a += omega[base + y * r + x];
                    }
                }
                out[base + row * r + col] = a;
            }
        }
    }
    out
}

/// Support of the basis function stored at `(row, col)` of an R x R face: its top-left texel
/// and side length. `(0, 0)` is the scaling function (whole face); a detail coefficient at
/// `(row, col)` with `h = 2^floor(log2(max(row, col)))` belongs to the h x h block grid,
/// block `(row mod h, col mod h)`, side `R / h`.
fn support(row: usize, col: usize, r: usize) -> (usize, usize, usize) {
    let m = row.max(col);
    if m == 0 {
        return (0, 0, r);
    }
    let h = 1usize << (usize::BITS - 1 - m.leading_zeros());
    let side = r / h;
    ((row % h) * side, (col % h) * side, side)
}

/// Scratch for the sparse per-row transform (one per worker thread).
struct SparseHaar {
    r: usize,
    cur: Vec<f64>,
    next: Vec<f64>,
    stamp: Vec<u32>,
    epoch: u32,
    active: Vec<usize>,
    parents: Vec<usize>,
}

impl SparseHaar {
    fn new(r: usize) -> Self {
        Self {
            r,
            cur: vec![0.0; r * r],
            next: vec![0.0; r * r],
            stamp: vec![0; r * r],
            epoch: 0,
            active: vec![],
            parents: vec![],
        }
    }

    /// Forward transform of one face given as `(texel within face, value)` pairs, pushing every
    /// non-zero coefficient `(global index, value)` to `out`. Touches only the blocks above the
    /// non-zeros: O(nnz log R) instead of O(R^2). Leaves the scratch zeroed.
    fn face(&mut self, base: usize, entries: &[(usize, f64)], out: &mut Vec<(u32, f64)>) {
        let r = self.r;
        self.active.clear();
        for &(p, v) in entries {
            self.cur[p] = v;
            self.active.push(p);
        }
        let mut s = r;
        while s > 1 {
            let h = s / 2;
            if self.epoch == u32::MAX {
                self.stamp.fill(0);
                self.epoch = 0;
            }
            self.epoch += 1;
            self.parents.clear();
            for &p in &self.active {
                let q = (p / r / 2) * r + (p % r) / 2;
                if self.stamp[q] != self.epoch {
                    self.stamp[q] = self.epoch;
                    self.parents.push(q);
                }
            }
            for &q in &self.parents {
                let (i, j) = (q / r, q % r);
                let ia = 2 * i * r + 2 * j;
                let ic = ia + r;
                let (a, b, c, d) = (self.cur[ia], self.cur[ia + 1], self.cur[ic], self.cur[ic + 1]);
                self.cur[ia] = 0.0;
                self.cur[ia + 1] = 0.0;
                self.cur[ic] = 0.0;
                self.cur[ic + 1] = 0.0;
                self.next[q] = 0.5 * (a + b + c + d);
                for (pos, v) in [
                    (i * r + j + h, 0.5 * (a - b + c - d)),
                    ((i + h) * r + j, 0.5 * (a + b - c - d)),
                    ((i + h) * r + j + h, 0.5 * (a - b - c + d)),
                ] {
                    if v != 0.0 {
                        out.push(((base + pos) as u32, v));
                    }
                }
            }
            std::mem::swap(&mut self.cur, &mut self.next);
            std::mem::swap(&mut self.active, &mut self.parents);
            s = h;
        }
        let v = self.cur[0];
        self.cur[0] = 0.0;
        if v != 0.0 {
            out.push((base as u32, v));
        }
    }

    /// Every non-zero coefficient of a sparse row (`cols` increasing, as in CSR).
    fn row(&mut self, cols: &[usize], vals: &[f32], out: &mut Vec<(u32, f64)>, face_buf: &mut Vec<(usize, f64)>) {
        out.clear();
        let rr = self.r * self.r;
        let mut i = 0;
        while i < cols.len() {
            let face = cols[i] / rr;
            face_buf.clear();
            while i < cols.len() && cols[i] / rr == face {
                if vals[i] != 0.0 {
                    face_buf.push((cols[i] - face * rr, vals[i] as f64));
                }
                i += 1;
            }
            if !face_buf.is_empty() {
                let entries = std::mem::take(face_buf);
                self.face(face * rr, &entries, out);
                *face_buf = entries;
            }
        }
    }
}

/// Keep the `terms` coefficients of largest `|c| * weight` (ties: lower index), sorted by index.
fn select(coeffs: &mut Vec<(u32, f64)>, terms: usize, weight: &[f64]) {
    if coeffs.len() > terms {
        let key = |&(i, v): &(u32, f64)| v.abs() * weight[i as usize];
        coeffs.select_nth_unstable_by(terms - 1, |a, b| key(b).total_cmp(&key(a)).then(a.0.cmp(&b.0)));
        coeffs.truncate(terms);
    }
    coeffs.sort_unstable_by_key(|&(i, _)| i);
}

/// Monochrome flops of the light transform: 12 per 2x2 block, `(R^2 - 1) / 3` blocks per face.
fn light_transform_flops(r: usize) -> u64 {
    6 * 12 * ((r * r - 1) / 3) as u64
}

impl Compressor for Haar {
    registry::kind_and_params!();

    fn kernels(&self, form: &CompressedForm) -> Result<KernelDesc, CompressError> {
        // The light transform needs a power-of-two cubemap (the kernel reads R from
        // `params.light_resolution`); the value array's type is spliced into the WGSL.
        face_resolution(form.light_basis())?;
        let f16 = form.meta("f16_values")? != 0;
        let (values, declaration, finite) = if f16 {
            (
                "coeff_f16",
                "@group(0) @binding(6) var<storage, read> coeff_f16: array<u32>; // u16 half bits, packed 2 per word\n\
                 fn coeff_at(i: u32) -> f32 { return unpack2x16float(coeff_f16[i >> 1u])[i & 1u]; }",
                FormCheck::FiniteHalf { array: "coeff_f16".into() },
            )
        } else {
            (
                "coeff_val",
                "@group(0) @binding(6) var<storage, read> coeff_val: array<f32>;\n\
                 fn coeff_at(i: u32) -> f32 { return coeff_val[i]; }",
                FormCheck::Finite { array: "coeff_val".into() },
            )
        };
        let len = |a: &str| Count::of([Factor::Len(a.into())]);
        let light_words = Count::of([Factor::Cols, Factor::Const(3)]);
        Ok(KernelDesc {
            kind: KIND.name.into(),
            wgsl: biscale_kernels::with_row_pass(&include_str!("gather.wgsl").replace("//#VALUES", declaration)),
            passes: vec![
                // One invocation per (face, channel).
                PassDesc { entry_point: "haar_light".into(), threads: Count::of([Factor::Const(18)]) },
                PassDesc { entry_point: biscale_kernels::ROW_ENTRY.into(), threads: Count::of([Factor::Rows]) },
            ],
            scratch: vec![
                ScratchDesc { name: "light_hat".into(), words: light_words.clone() },
                ScratchDesc { name: "haar_tmp".into(), words: light_words },
            ],
            meta_keys: vec![],
            checks: vec![
                FormCheck::Ptr { array: "row_ptr".into(), count: Count::of([Factor::Rows]), total: len("coeff_idx") },
                FormCheck::Below { array: "coeff_idx".into(), bound: Count::of([Factor::Cols]) },
                FormCheck::Len { array: values.into(), count: len("coeff_idx") },
                finite,
            ],
        })
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        self.check()?;
        let r = face_resolution(t.light_basis())?;
        // T is CSR with finite values by construction (TransferMatrix::new).
        let csr = t.csr();
        let indptr_view = csr.indptr();
        let indptr = indptr_view.to_proper();
        let (indices, data) = (csr.indices(), csr.data());
        let weight: Vec<f64> =
            support_solid_angles(&t.light_basis().cubemap_layout().expect("face_resolution checked it"))
                .into_iter()
                .map(|a| self.weighting.weight(a))
                .collect();
        let terms = self.terms.min(t.cols());
        let rows = t.rows();
        const CHUNK: usize = 2048;
        let chunks = rows.div_ceil(CHUNK);
        let done = std::sync::atomic::AtomicUsize::new(0);
        let truncated = std::sync::atomic::AtomicBool::new(false);
        // Per chunk: (terms per row, indices, values); chunks come back in order (deterministic).
        let parts: Vec<(Vec<u32>, Vec<u16>, Vec<f32>)> = (0..chunks)
            .into_par_iter()
            .map_init(
                || (SparseHaar::new(r), Vec::new(), Vec::new()),
                |(haar, coeffs, face_buf), c| {
                    let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(rows));
                    let mut counts = Vec::with_capacity(hi - lo);
                    let (mut idx, mut val) = (Vec::new(), Vec::new());
                    for row in lo..hi {
                        let span = indptr[row]..indptr[row + 1];
                        haar.row(&indices[span.clone()], &data[span], coeffs, face_buf);
                        if coeffs.len() > terms {
                            truncated.store(true, std::sync::atomic::Ordering::Relaxed);
                        }
                        select(coeffs, terms, &weight);
                        counts.push(coeffs.len() as u32);
                        for &(i, v) in coeffs.iter() {
                            idx.push(i as u16);
                            val.push(v as f32);
                        }
                    }
                    let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                    ctx.report(n as f64 / chunks as f64);
                    (counts, idx, val)
                },
            )
            .collect();
        let total: usize = parts.iter().map(|p| p.1.len()).sum();
        if total > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("haar: {total} terms do not fit u32 row pointers")));
        }
        let mut row_ptr = Vec::with_capacity(rows + 1);
        row_ptr.push(0u32);
        let (mut coeff_idx, mut values) = (Vec::with_capacity(total), Vec::with_capacity(total));
        for (counts, idx, val) in parts {
            for n in counts {
                row_ptr.push(row_ptr.last().unwrap() + n);
            }
            coeff_idx.extend(idx);
            values.extend(val);
        }
        let value_array = if self.f16_values {
            let bits = values.iter().map(|&v| half::f16::from_f32(v).to_bits()).collect();
            NamedArray { name: "coeff_f16".into(), data: ArrayData::U16(bits) }
        } else {
            NamedArray { name: "coeff_val".into(), data: ArrayData::F32(values) }
        };
        let mut form = CompressedForm::new(KIND.name, t.shape());
        form.arrays = vec![
            NamedArray { name: "row_ptr".into(), data: ArrayData::U32(row_ptr) },
            NamedArray { name: "coeff_idx".into(), data: ArrayData::U16(coeff_idx) },
            value_array,
        ];
        form.meta =
            [("terms".to_string(), terms as u64), ("f16_values".into(), self.f16_values as u64)].into_iter().collect();
        // Exact when no row lost a term (f32 value rounding aside; f16 values never are).
        form.lossless = !self.f16_values && !truncated.into_inner();
        form.flops_per_gather = light_transform_flops(r) + 2 * total as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    /// Each row is transformed and truncated alone: any vertex range is a part.
    fn separability(&self, _shape: TransferShape) -> Separability {
        Separability::Rows { vertex_multiple: 1 }
    }

    /// Each part's flops count the light's transform once; the whole does too.
    fn merge_parts(&self, shape: TransferShape, parts: Vec<CompressedForm>) -> Result<CompressedForm, CompressError> {
        let mut form = concat_parts(KIND.name, shape, &parts, &["row_ptr"])?;
        if parts.iter().any(|p| p.meta != form.meta) {
            return Err(CompressError::malformed(KIND.name, "terms", "differs between the parts"));
        }
        let transform = light_transform_flops(face_resolution(shape.light)?);
        form.flops_per_gather -= (parts.len() as u64 - 1) * transform;
        Ok(form)
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        // RGB padded to four f64 lanes: two packed multiply-adds per coefficient.
        let lhat: Vec<[f64; 4]> = transform_light(light)?.into_iter().map(|[x, y, z]| [x, y, z, 0.0]).collect();
        let out = gather_lanes(form, &lhat)?;
        form.lstar(out.iter().map(|o| [o[0] as f32, o[1] as f32, o[2] as f32]).collect())
    }

    /// The three lights in one pass over the coefficients, twelve lanes wide (three RGB lights
    /// padded): the indices and values are read once instead of three times. Each lane's sums
    /// run in the order of [`Compressor::gather`], so the result is its three gathers bit for bit.
    fn gather_three(
        &self,
        form: &CompressedForm,
        lights: [&LightVector; 3],
    ) -> Result<[LocalRadiance; 3], CompressError> {
        for l in lights {
            form.check_light(l)?;
        }
        let [a, b, c] = [transform_light(lights[0])?, transform_light(lights[1])?, transform_light(lights[2])?];
        let lhat: Vec<[f64; 12]> = (a.iter().zip(&b).zip(&c))
            .map(|((a, b), c)| [a[0], a[1], a[2], 0.0, b[0], b[1], b[2], 0.0, c[0], c[1], c[2], 0.0])
            .collect();
        let wide: Vec<[f32; 12]> = gather_lanes(form, &lhat)?.iter().map(|o| o.map(|x| x as f32)).collect();
        form.lstar_three(&wide, 4)
    }
}

/// The gather for `W` lanes of transformed light per coefficient, on either value type.
fn gather_lanes<const W: usize>(form: &CompressedForm, lhat: &[[f64; W]]) -> Result<Vec<[f64; W]>, CompressError> {
    let row_ptr = form.u32s("row_ptr")?;
    let coeff_idx = form.u16s("coeff_idx")?;
    if form.meta("f16_values")? != 0 {
        // Half floats are widened where they are read, not decoded into a copy first.
        let v = form.u16s("coeff_f16")?;
        rows_dot(form.rows(), row_ptr, coeff_idx, v, |b| half::f16::from_bits(b).to_f64(), lhat)
    } else {
        rows_dot(form.rows(), row_ptr, coeff_idx, form.f32s("coeff_val")?, |x| x as f64, lhat)
    }
    .map_err(|what: String| CompressError::malformed("haar", "row_ptr", what))
}

/// `||T - T~||_F / ||T||_F` of the rows `form` stands for. `W` is orthogonal, so each row's
/// squared residual is `||t||^2 - sum_kept c_i^2` (Parseval; the kept values are the exact
/// coefficients up to their storage rounding). f64; 0 when `T` is 0.
pub fn relative_frobenius_error(form: &CompressedForm, t: &TransferMatrix) -> Result<f64, CompressError> {
    let row_ptr = form.u32s("row_ptr")?;
    let values: Vec<f64> = if form.meta("f16_values")? != 0 {
        form.u16s("coeff_f16")?.iter().map(|&b| half::f16::from_bits(b).to_f64()).collect()
    } else {
        form.f32s("coeff_val")?.iter().map(|&v| v as f64).collect()
    };
    if form.rows() != t.rows()
        || row_ptr.len() != form.rows() + 1
        || row_ptr.last().map(|&p| p as usize) != Some(values.len())
    {
        return Err(CompressError::malformed("haar", "row_ptr", "does not match T"));
    }
    let (num, den) = (0..form.rows())
        .into_par_iter()
        .map(|r| {
            let x_sq: f64 = t.csr().outer_view(r).map_or(0.0, |v| v.data().iter().map(|&x| x as f64 * x as f64).sum());
            let kept: f64 = values[row_ptr[r] as usize..row_ptr[r + 1] as usize].iter().map(|v| v * v).sum();
            ((x_sq - kept).max(0.0), x_sq)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok(if den > 0.0 { (num / den).sqrt() } else { 0.0 })
}

/// The gather's row loop: `L*_row = sum_e value(e) * lhat[coeff_idx[e]]` over each row's
/// entries, in f64, rows in parallel chunks.
///
/// Only the shape is checked up front; each row's offsets and each coefficient index are
/// checked where the loop reads them (with `row_ptr[0] = 0` and the last entry equal to the
/// total, the rows' ranges cover every entry), so a corrupt form is an error exactly as with
/// a separate validation pass, without that O(form size) pass (it took a third of the gather
/// on the bunny).
fn rows_dot<V: Copy + Sync, const W: usize>(
    rows: usize,
    row_ptr: &[u32],
    coeff_idx: &[u16],
    values: &[V],
    widen: impl Fn(V) -> f64 + Sync,
    lhat: &[[f64; W]],
) -> Result<Vec<[f64; W]>, String> {
    if row_ptr.len() != rows + 1
        || values.len() != coeff_idx.len()
        || row_ptr.first() != Some(&0)
        || row_ptr.last().map(|&p| p as usize) != Some(coeff_idx.len())
    {
        return Err("haar: array lengths or indices do not match the shape".into());
    }
    let mut out = vec![[0.0f64; W]; rows];
    out.par_chunks_mut(ROWS_PER_TASK).enumerate().try_for_each(|(chunk, rows)| {
        for (j, o) in rows.iter_mut().enumerate() {
            let row = chunk * ROWS_PER_TASK + j;
            let r = row_ptr[row] as usize..row_ptr[row + 1] as usize;
            let (Some(idx), Some(vals)) = (coeff_idx.get(r.clone()), values.get(r)) else {
                return Err(format!("haar: row {row} has offsets out of order"));
            };
            let mut acc = [0.0f64; W];
            for (&k, &v) in idx.iter().zip(vals) {
                let l = lhat.get(k as usize).ok_or_else(|| format!("haar: row {row}: coefficient {k} out of range"))?;
                let v = widen(v);
                for c in 0..W {
                    acc[c] += v * l[c];
                }
            }
            *o = acc;
        }
        Ok(())
    })?;
    Ok(out)
}

#[cfg(test)]
mod tests;
