//! Greedy constant-column **biclustering** of `T` (Sun et al., "Radiance Transfer
//! Biclustering for Real-time All-frequency Bi-scale Rendering", section 4, Algorithms 1 and 2).
//!
//! A constant-column bicluster `B = [rows j_1..j_r; cols k_1..k_l; values t_1..t_l]` stands for
//! the submatrix whose column `m` is the constant `t_m`. Its product with `L` is one scalar
//! `a = sum_m t_m L_{k_m}` added to each of its `r` rows, at `W(B) = r + 2l - 1` flops. The
//! greedy build ([`greedy`]) repeatedly grows a bicluster from a random non-zero of the current
//! matrix by the row/column insertion or deletion that most increases
//! `dW = 2 nnz(M) - W(B) - 2 nnz(M - B)`, emits it and subtracts it (residuals, possibly
//! negative, stay), until nothing is left: `T = sum_i B_i` exactly.
//!
//! Beyond the paper:
//! * values are exact integer codes `v = code / value_scale` ([`codes`]; `value_scale` = 4 at
//!   the reference 2x2 box filter): the build is exact integer arithmetic and the stored
//!   constants are `i8`, column indices `u16`;
//! * the rows are cut into blocks of `block_vertices` consecutive vertices biclustered
//!   independently in parallel (rayon); a block's random stream is `(seed, block index)`, so
//!   the arrays are byte-identical for any thread count; bicluster ids in the row lists are
//!   then block-local `u16`;
//! * a column's cost in `W(B)` is the `column_cost` key (default 2, the paper's flop count;
//!   the CPU gather's time per entry would weigh a column about 6 rows, and 16 gathers about
//!   5% faster for more flops and bytes: BENCHMARKS, "A gather-aware greedy").
//!
//! # Compressed form (`kind = "bicluster"`)
//!
//! Biclusters are numbered `0..B` in block order, and within a block by their first row (so
//! pass 2 of the gather, walking rows in order, finds the scalars it needs close together).
//! Arrays (all little-endian plain arrays):
//!
//! | name | type | length | meaning |
//! |---|---|---|---|
//! | `bc_col_ptr` | u32 | B + 1 | bicluster `b` owns entries `bc_col_ptr[b]..bc_col_ptr[b+1]` of `bc_cols`/`bc_vals` |
//! | `bc_cols` | u16 | sum l | column (cubemap texel) `k` of each entry |
//! | `bc_vals` | i8 | sum l | the column constant as an integer code: value = code / `value_scale` |
//! | `row_ptr` | u32 | rows + 1 | row `i` owns entries `row_ptr[i]..row_ptr[i+1]` of `row_bc` |
//! | `row_bc` | u16 (`row_bc_local` = 1) or u32 (0) | sum r | the biclusters of the row: block-local id (add `block_bc_base[i / block_rows]`) or global id |
//! | `block_bc_base` | u32 | blocks + 1 | first bicluster id of each block |
//!
//! Meta: `value_scale` (q), `block_rows` (rows per block = block_vertices * M, the last block
//! may be shorter), `blocks`, `biclusters` (B), `row_bc_local`. Lossy forms (`error_budget >
//! 0`, [`prune`]) also carry `dropped_biclusters`, and `error2_codes` / `energy2_codes`, the
//! exact `||T - T'||_F^2` and `||T||_F^2` in squared codes (the achieved relative error is the
//! square root of their ratio). A lossy form is an ordinary form of `T' = T - E`: the gathers
//! (CPU and GPU) read it unchanged.
//!
//! Gather (Algorithm 2), per colour channel: `L'_k = L_k / q` (N multiplies); pass 1, one
//! thread per bicluster: `a_b = sum_{e in b} bc_vals[e] * L'[bc_cols[e]]`; pass 2, one thread
//! per row: `L*_i = sum_{e in row i} a[id(e)]`. Flops: `sum_b (r_b + 2 l_b - 1) + N`.

pub mod analysis;
pub mod codes;
pub mod greedy;
mod params;
pub mod prune;
#[cfg(test)]
mod tests;

pub use analysis::{achieved_error, table_stats, AchievedError, BiclusterStats, Distribution};
pub use params::Bicluster;

use crate::registry::{self, Kind};
use biscale_core::basis::TransferShape;
use biscale_core::compress::{
    concat_parts, ArrayData, CompressContext, CompressError, CompressedForm, Compressor, Separability,
};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::{TransferMatrix, TransferView};
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use codes::CodeMatrix;
use rayon::prelude::*;

impl registry::MakeCompressor for Bicluster {
    fn make(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
        let c = registry::parse::<Bicluster>(p)?;
        c.validate()?;
        Ok(Box::new(c))
    }
}

/// The registry entry. The label names `block_vertices`, `error_budget` and `column_cost`
/// only when the config gives them (`bicluster-b1024`, `bicluster-e0.05`, `bicluster-c16`).
pub const KIND: Kind = Kind {
    memory,
    report,
    role: registry::Role::Paper,
    flops: form_flops,
    ..Kind::built_in::<Bicluster>(
        "bicluster",
        "greedy constant-column biclustering (Sun et al.), block-parallel; lossless, or lossy within error_budget",
        |p| {
            registry::parse::<Bicluster>(p).map(|_| {
                registry::tagged_label(
                    "bicluster",
                    p,
                    &[("block_vertices", "b"), ("error_budget", "e"), ("column_cost", "c")],
                )
            })
        },
    )
};

/// The flops of one gather of `form`, counted from its own arrays (`eval --form` reports this,
/// not what a file claims).
/// The light's prescale (N) plus `W(B) = r + 2l - 1` per bicluster: the row lists hold
/// every r, the column lists every l, and `bc_col_ptr` has one entry per bicluster more.
fn form_flops(form: &CompressedForm) -> Option<u64> {
    let len = |name: &str| form.array(name).ok().map(|a| a.len() as u64);
    let cols = form.cols() as u64;
    let biclusters = len("bc_col_ptr")?.saturating_sub(1);
    let sum = cols.saturating_add(len("row_bc")?).saturating_add(len("bc_cols")?.saturating_mul(2));
    Some(sum.saturating_sub(biclusters))
}

/// [`Kind::memory`]: the integer codes (u16 column, i8 code, usize row pointer); per block in
/// flight its rows (8 bytes per non-zero) and column views (8, in vectors grown by doubling:
/// 12 on average); the biclusters found (about 2% of the non-zeros, ~170 bytes each: 4 per
/// non-zero) twice, the greedy's output kept for the next setting of a sweep
/// ([`biscale_core::compress::Sweep`]) and the copy pruned; the form (about 1 byte per non-zero
/// lossless: 2).
fn memory(p: &serde_json::Value, t: &registry::MemoryFacts) -> registry::FormMemory {
    let p: Bicluster = registry::parse(p).unwrap_or_default();
    let (rows, vertices) = (t.rows(), t.vertices.max(1));
    let codes = t.nnz * 3 + (rows + 1) * 8;
    let block_vertices = if p.block_vertices == 0 { vertices } else { (p.block_vertices as u64).min(vertices) };
    let blocks = vertices.div_ceil(block_vertices.max(1));
    let in_flight = blocks.min(t.threads) * block_vertices * (t.nnz / vertices) * 20;
    let form = t.nnz * 2 + (rows + 1) * 4;
    registry::FormMemory { working: codes + in_flight + t.nnz * 8 + form, form }
}

/// [`Kind::report`]: how many biclusters, their mean size, the gather's flops against the
/// CSR's, the error the budget bounds (`error.frobenius`, `||T - T'||_F / ||T||_F`) and the
/// `L*` error it makes under a uniform white sky.
fn report(stats: &serde_json::Value) -> Vec<(String, String)> {
    let num = |path: &[&str]| path.iter().try_fold(stats, |v, k| v.get(*k)).and_then(serde_json::Value::as_f64);
    let mut rows = vec![];
    if let Some(b) = num(&["biclusters"]) {
        rows.push(("biclusters".to_string(), format!("{b:.0}")));
    }
    if let (Some(r), Some(l)) = (num(&["r", "mean"]), num(&["l", "mean"])) {
        rows.push(("mean bicluster size (rows x columns)".to_string(), format!("{r:.2} x {l:.2}")));
    }
    if let Some(f) = num(&["flops_ratio"]) {
        rows.push(("gather flops / CSR's".to_string(), format!("{f:.3}")));
    }
    if let Some(e) = num(&["error", "frobenius"]) {
        rows.push(("relative Frobenius error of T (the error budget's measure)".to_string(), format!("{e:.3e}")));
    }
    if let Some(e) = num(&["error", "sky"]) {
        rows.push(("relative L* error under a uniform white sky".to_string(), format!("{e:.3e}")));
    }
    rows
}
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// The arrays of a bicluster form, borrowed and validated.
pub struct BiclusterView<'a> {
    pub rows: usize,
    pub cols: usize,
    pub value_scale: u32,
    pub block_rows: usize,
    pub bc_col_ptr: &'a [u32],
    pub bc_cols: &'a [u16],
    pub bc_vals: &'a [i8],
    pub row_ptr: &'a [u32],
    row_bc: RowBc<'a>,
    pub block_bc_base: &'a [u32],
}

enum RowBc<'a> {
    Local(&'a [u16]),
    Global(&'a [u32]),
}

impl RowBc<'_> {
    fn len(&self) -> usize {
        match self {
            RowBc::Local(v) => v.len(),
            RowBc::Global(v) => v.len(),
        }
    }
}

impl<'a> BiclusterView<'a> {
    /// Borrow and check every array of `form` (lengths, offsets, index ranges): O(form size).
    pub fn new(form: &'a CompressedForm) -> Result<Self, CompressError> {
        let v = Self::header(form)?;
        v.check_indices()?;
        Ok(v)
    }

    /// Borrow the arrays of `form`, checking only what costs O(header + blocks): the kind, the
    /// meta values, array types and lengths, the first and last entry of `bc_col_ptr` and
    /// `row_ptr`, and all of `block_bc_base`. The offsets in between and the indices are not
    /// checked, so the accessors may panic on such a view; the gather, which only gets this
    /// view, checks each offset and index where it reads it instead.
    fn header(form: &'a CompressedForm) -> Result<Self, CompressError> {
        let bad = |array: &str, m: &str| CompressError::malformed("bicluster", array, m);
        if form.kind != "bicluster" {
            return Err(CompressError::malformed(&form.kind, "kind", "is not bicluster"));
        }
        let value_scale = form.meta("value_scale")?;
        let block_rows = form.meta("block_rows")? as usize;
        let nb = form.meta("biclusters")? as usize;
        let local = form.meta("row_bc_local")? == 1;
        if value_scale == 0 || value_scale > codes::CODE_MAX as u64 {
            return Err(bad("value_scale", &format!("= {value_scale} is out of range")));
        }
        let (bc_col_ptr, bc_cols, bc_vals) = (form.u32s("bc_col_ptr")?, form.u16s("bc_cols")?, form.i8s("bc_vals")?);
        let (row_ptr, block_bc_base) = (form.u32s("row_ptr")?, form.u32s("block_bc_base")?);
        let row_bc = if local { RowBc::Local(form.u16s("row_bc")?) } else { RowBc::Global(form.u32s("row_bc")?) };
        let ends_ok = |p: &[u32], n: usize, total: usize| p.len() == n + 1 && p[0] == 0 && p[n] as usize == total;
        if !ends_ok(bc_col_ptr, nb, bc_cols.len()) || bc_vals.len() != bc_cols.len() {
            return Err(bad("bc_col_ptr", "does not agree with bc_cols / bc_vals"));
        }
        if !ends_ok(row_ptr, form.rows(), row_bc.len()) {
            return Err(bad("row_ptr", "does not match the rows and row_bc"));
        }
        let blocks = if form.rows() == 0 { 0 } else { form.rows().div_ceil(block_rows.max(1)) };
        if block_rows == 0 && form.rows() > 0
            || !ends_ok(block_bc_base, blocks, nb)
            || !block_bc_base.windows(2).all(|w| w[0] <= w[1])
        {
            return Err(bad("block_bc_base", "does not match the blocks"));
        }
        Ok(Self {
            rows: form.rows(),
            cols: form.cols(),
            value_scale: value_scale as u32,
            block_rows,
            bc_col_ptr,
            bc_cols,
            bc_vals,
            row_ptr,
            row_bc,
            block_bc_base,
        })
    }

    /// The O(form size) rest of [`Self::new`]: offsets non-decreasing, columns below `cols`,
    /// and every row's ids naming a bicluster of its own block (any bicluster for global ids).
    fn check_indices(&self) -> Result<(), CompressError> {
        let bad = |array: &str, m: String| CompressError::malformed("bicluster", array, m);
        let monotone = |p: &[u32]| p.windows(2).all(|w| w[0] <= w[1]);
        if !monotone(self.bc_col_ptr) {
            return Err(bad("bc_col_ptr", "does not agree with bc_cols / bc_vals".into()));
        }
        if !monotone(self.row_ptr) {
            return Err(bad("row_ptr", "does not match the rows and row_bc".into()));
        }
        if self.bc_cols.iter().any(|&k| k as usize >= self.cols) {
            return Err(bad("bc_cols", "has a column index out of range".into()));
        }
        let nb = self.biclusters();
        for i in 0..self.rows {
            let b = i / self.block_rows;
            let (lo, hi) = (self.block_bc_base[b] as usize, self.block_bc_base[b + 1] as usize);
            let r = self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize;
            let ok = match self.row_bc {
                RowBc::Local(v) => v[r].iter().all(|&x| lo + (x as usize) < hi),
                RowBc::Global(v) => v[r].iter().all(|&x| (x as usize) < nb),
            };
            if !ok {
                return Err(bad("row_bc", format!("row {i} names a bicluster out of range")));
            }
        }
        Ok(())
    }

    pub fn biclusters(&self) -> usize {
        self.bc_col_ptr.len() - 1
    }

    /// Columns and codes of bicluster `b`.
    pub fn bicluster(&self, b: usize) -> (&'a [u16], &'a [i8]) {
        let r = self.bc_col_ptr[b] as usize..self.bc_col_ptr[b + 1] as usize;
        (&self.bc_cols[r.clone()], &self.bc_vals[r])
    }

    /// Global ids of the biclusters of row `i`.
    pub fn row_biclusters(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let r = self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize;
        let base = self.block_bc_base[i / self.block_rows.max(1)] as usize;
        let (l, g): (&[u16], &[u32]) = match self.row_bc {
            RowBc::Local(v) => (&v[r], &[]),
            RowBc::Global(v) => (&[], &v[r]),
        };
        l.iter().map(move |&x| base + x as usize).chain(g.iter().map(|&x| x as usize))
    }

    /// Column count l of every bicluster.
    pub fn bicluster_cols(&self) -> Vec<u32> {
        self.bc_col_ptr.windows(2).map(|w| w[1] - w[0]).collect()
    }

    /// Row count r of every bicluster.
    pub fn bicluster_rows(&self) -> Vec<u32> {
        let mut r = vec![0u32; self.biclusters()];
        for i in 0..self.rows {
            for b in self.row_biclusters(i) {
                r[b] += 1;
            }
        }
        r
    }
}

impl Compressor for Bicluster {
    registry::kind_and_params!();

    /// The two passes of `gather.wgsl`. The checks make every read of both passes in range
    /// (the GPU would otherwise loop over a decreasing pointer array for billions of steps):
    /// the pointer arrays are monotone and end where their targets do, columns are below N,
    /// and each row's ids name a bicluster of its own block (or, with global ids, any).
    fn kernels(&self, form: &CompressedForm) -> Result<KernelDesc, CompressError> {
        let local = form.meta("row_bc_local")? == 1;
        let want = if local { "u16" } else { "u32" };
        if form.array("row_bc")?.element_type() != want {
            return Err(CompressError::malformed(
                KIND.name,
                "row_bc",
                format!("must be {want} with row_bc_local = {}", local as u8),
            ));
        }
        let meta = |k: &str| Count::of([Factor::Meta(k.into())]);
        let len = |a: &str| Count::of([Factor::Len(a.into())]);
        let ids = if local {
            FormCheck::Grouped {
                ids: "row_bc".into(),
                ptr: "row_ptr".into(),
                group_rows: meta("block_rows"),
                bases: "block_bc_base".into(),
            }
        } else {
            FormCheck::Below { array: "row_bc".into(), bound: meta("biclusters") }
        };
        Ok(KernelDesc {
            kind: KIND.name.into(),
            wgsl: biscale_kernels::with_row_pass(include_str!("gather.wgsl")),
            passes: vec![
                PassDesc { entry_point: "bicluster_sums".into(), threads: meta("biclusters") },
                PassDesc { entry_point: biscale_kernels::ROW_ENTRY.into(), threads: Count::of([Factor::Rows]) },
            ],
            scratch: vec![ScratchDesc {
                name: "bc_sums".into(),
                words: Count::of([Factor::Meta("biclusters".into()), Factor::Const(3)]),
            }],
            meta_keys: vec!["value_scale".into(), "block_rows".into(), "row_bc_local".into()],
            checks: vec![
                FormCheck::Range { count: meta("value_scale"), min: 1, max: codes::CODE_MAX as u64 },
                FormCheck::Range { count: meta("block_rows"), min: 1, max: u64::MAX },
                FormCheck::Len { array: "bc_vals".into(), count: len("bc_cols") },
                FormCheck::Ptr { array: "bc_col_ptr".into(), count: meta("biclusters"), total: len("bc_cols") },
                FormCheck::Below { array: "bc_cols".into(), bound: Count::of([Factor::Cols]) },
                FormCheck::Ptr { array: "block_bc_base".into(), count: meta("blocks"), total: meta("biclusters") },
                FormCheck::Ptr { array: "row_ptr".into(), count: Count::of([Factor::Rows]), total: len("row_bc") },
                ids,
            ],
        })
    }

    fn stats(&self, form: &CompressedForm, t: TransferView<'_>) -> Option<serde_json::Value> {
        match table_stats(form, t) {
            Ok(s) => serde_json::to_value(s).ok(),
            Err(e) => {
                eprintln!("warning: bicluster stats: {e}");
                None
            }
        }
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        self.compress_blocks(t, 0, ctx)
    }

    /// Blocks are independent and each one's random stream is keyed by its index in the whole
    /// matrix, so blocks of consecutive vertex ranges are the blocks of the whole.
    fn separability(&self, _shape: TransferShape) -> Separability {
        match self.block_vertices {
            0 => Separability::Whole {
                why: "block_vertices = 0 biclusters all rows as one block (set block_vertices to shard it)".into(),
            },
            b => Separability::Rows { vertex_multiple: b },
        }
    }

    fn compress_part(
        &self,
        t: &TransferMatrix,
        first_vertex: usize,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, CompressError> {
        match self.block_vertices {
            b if b > 0 && first_vertex.is_multiple_of(b) => self.compress_blocks(t, first_vertex / b, ctx),
            0 if first_vertex == 0 => self.compress(t, ctx),
            b => Err(CompressError::Params(format!(
                "bicluster: a vertex range starting at vertex {first_vertex} does not start a block of {b} vertices"
            ))),
        }
    }

    /// Blocks, biclusters and rows are concatenated in order; the pointer arrays are shifted.
    /// Block-local ids stay as they are when every part kept them (then the whole would
    /// have: its blocks are the parts' blocks); otherwise every id becomes global, as
    /// [`assemble`] would have made them.
    fn merge_parts(&self, shape: TransferShape, parts: Vec<CompressedForm>) -> Result<CompressedForm, CompressError> {
        let mut parts = parts;
        let local = parts.iter().map(|p| p.meta("row_bc_local")).collect::<Result<Vec<_>, _>>()?;
        if local.iter().any(|&l| l != 1) {
            let mut offset = 0u64;
            for p in &mut parts {
                let biclusters = p.meta("biclusters")?;
                if offset + biclusters >= u32::MAX as u64 {
                    return Err(CompressError::TooLarge(format!("bicluster: {} biclusters", offset + biclusters)));
                }
                with_global_ids(p, offset as u32)?;
                offset += biclusters;
            }
        }
        let mut form = concat_parts(KIND.name, shape, &parts, &["bc_col_ptr", "row_ptr", "block_bc_base"])?;
        for key in ["blocks", "biclusters", "dropped_biclusters", "error2_codes", "energy2_codes"] {
            if form.meta.contains_key(key) {
                let sum = parts.iter().map(|p| p.meta(key)).sum::<Result<u64, _>>()?;
                form.meta.insert(key.into(), sum);
            }
        }
        for key in ["value_scale", "block_rows"] {
            if parts.iter().any(|p| p.meta.get(key) != form.meta.get(key)) {
                return Err(CompressError::malformed(KIND.name, key, "differs between the parts"));
            }
        }
        // Each part's flops count the light's prescale (N multiplies) once; the whole does too.
        form.flops_per_gather -= (parts.len() as u64 - 1) * shape.cols() as u64;
        Ok(form)
    }

    /// Algorithm 2 on the stored arrays. Only the form's header is checked up front
    /// ([`BiclusterView::header`], O(blocks)); each offset, column and bicluster id is checked
    /// where the kernel reads it, failing into an error instead of a panic. A corrupt form is
    /// therefore rejected exactly when [`BiclusterView::new`] would reject it, without a
    /// separate O(form size) validation pass on every call.
    ///
    /// The inner loops are [`bicluster_sum`] and [`row_sum`], plain in-order sums (split
    /// accumulators, 16-byte lanes and a padded light table without bounds checks were each
    /// tried on the bunny and gained nothing measurable). Work is handed to rayon in chunks
    /// of biclusters and rows, not one task per element.
    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        let v = BiclusterView::header(form)?;
        form.lstar(gather_lanes(&v, &prescaled_light(light, v.value_scale))?)
    }

    /// The three lights in one pass over the form, nine lanes wide: the codes, columns and
    /// row ids are read once instead of three times. Each lane's sums run in the order of
    /// [`Compressor::gather`], so the result is its three gathers bit for bit.
    fn gather_three(
        &self,
        form: &CompressedForm,
        lights: [&LightVector; 3],
    ) -> Result<[LocalRadiance; 3], CompressError> {
        let v = BiclusterView::header(form)?;
        // The same prescaling as `prescaled_light`, lane by lane.
        let inv_q = 1.0 / v.value_scale as f32;
        let lp = form.interleave_three(lights, |[a, b, c]| {
            [a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]].map(|x| x * inv_q)
        })?;
        form.lstar_three(&gather_lanes(&v, &lp)?, 3)
    }
}

/// The two passes of the gather for `W` lanes of prescaled light per texel (3: one RGB light;
/// 9: three of them): one `W`-vector per bicluster, then each row's sum of its biclusters'.
fn gather_lanes<const W: usize>(v: &BiclusterView<'_>, lp: &[[f32; W]]) -> Result<Vec<[f32; W]>, CompressError> {
    // Pass 1: one scalar per bicluster.
    let mut a = vec![[0.0f32; W]; v.biclusters()];
    a.par_chunks_mut(PASS1_CHUNK)
        .enumerate()
        .try_for_each(|(chunk, out)| {
            for (j, out) in out.iter_mut().enumerate() {
                let b = chunk * PASS1_CHUNK + j;
                // `bc_col_ptr` has B + 1 entries (header): `b + 1` is in range.
                let r = v.bc_col_ptr[b] as usize..v.bc_col_ptr[b + 1] as usize;
                let (Some(ks), Some(ts)) = (v.bc_cols.get(r.clone()), v.bc_vals.get(r)) else {
                    return Err(format!("bicluster {b}: offsets out of order or past bc_cols"));
                };
                *out = bicluster_sum(ks, ts, lp).map_err(|k| format!("bicluster {b}: column {k} out of range"))?;
            }
            Ok(())
        })
        .map_err(|what: String| CompressError::malformed("bicluster", "bc_col_ptr", what))?;
    // Pass 2: each row sums the scalars of its biclusters.
    let mut values = vec![[0.0f32; W]; v.rows];
    values
        .par_chunks_mut(PASS2_CHUNK)
        .enumerate()
        .try_for_each(|(chunk, out)| {
            // The row's block, and the block's range of `a`, are advanced as the rows go
            // by, not divided out per row (the division was 8% of the gather on the bunny).
            // The header checked `block_rows > 0` (rows > 0 here) and all of
            // `block_bc_base` (blocks + 1 non-decreasing entries ending at B), so each
            // block's range of `a` is in bounds; `row_ptr` has rows + 1 entries.
            let first = chunk * PASS2_CHUNK;
            let mut block = first / v.block_rows;
            let mut next_block_row = (block + 1) * v.block_rows;
            let own_of = |block: usize| &a[v.block_bc_base[block] as usize..v.block_bc_base[block + 1] as usize];
            let mut own = own_of(block);
            for (j, out) in out.iter_mut().enumerate() {
                let i = first + j;
                if i == next_block_row {
                    block += 1;
                    next_block_row += v.block_rows;
                    own = own_of(block);
                }
                let err = || format!("row {i} names a bicluster out of range or has bad offsets");
                let r = v.row_ptr[i] as usize..v.row_ptr[i + 1] as usize;
                let sum = match v.row_bc {
                    RowBc::Local(ids) => row_sum(ids.get(r).ok_or_else(err)?, own),
                    RowBc::Global(ids) => row_sum(ids.get(r).ok_or_else(err)?, &a),
                };
                *out = sum.ok_or_else(err)?;
            }
            Ok(())
        })
        .map_err(|what: String| CompressError::malformed("bicluster", "row_bc", what))?;
    Ok(values)
}

impl Bicluster {
    /// [`Compressor::compress`] of `t` as the rows of blocks `first_block..` of a larger
    /// matrix: block `b` of `t` draws the random stream of block `first_block + b`.
    fn compress_blocks(
        &self,
        t: &TransferMatrix,
        first_block: usize,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        let codes = codes::quantize(t, self.value_scale)?;
        let (rows, cols) = (codes.rows, codes.cols);
        if rows > u32::MAX as usize || codes.nnz() > u32::MAX as usize / 2 {
            return Err(CompressError::TooLarge(format!("bicluster: {rows} rows / {} non-zeros", codes.nnz())));
        }
        let block_rows =
            if self.block_vertices == 0 { rows.max(1) } else { self.block_vertices * t.local_dirs().max(1) };
        let nblocks = if rows == 0 { 0 } else { rows.div_ceil(block_rows) };
        let key = SharedKey::of(&codes, block_rows, ctx.seed, first_block, self.column_cost);
        // Every setting of an error-budget sweep prunes the same greedy output of the same T:
        // the sweep keeps it (the lossless setting is the sweep's budget 0), so the greedy runs
        // once; the result is identical to a fresh build (the greedy is deterministic in its key).
        let greedy = match ctx.sweep.and_then(|sw| sw.get::<SharedKey, Vec<Vec<greedy::Bc>>>(&key)) {
            Some(g) => {
                ctx.report(1.0);
                g
            }
            None => {
                let max_code = codes.codes.iter().map(|&c| (c as i32).abs()).max().unwrap_or(1);
                let done = AtomicUsize::new(0);
                let g: Vec<Vec<greedy::Bc>> = (0..nblocks)
                    .into_par_iter()
                    .with_max_len(1)
                    .map_init(
                        || greedy::Workspace::new(cols, max_code),
                        |ws, b| {
                            let range = b * block_rows..((b + 1) * block_rows).min(rows);
                            let out = greedy::bicluster_block(
                                &codes,
                                range,
                                ctx.seed,
                                (first_block + b) as u64,
                                self.costs(),
                                ws,
                            );
                            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                            ctx.report(d as f64 / nblocks as f64);
                            out
                        },
                    )
                    .collect();
                let g = std::sync::Arc::new(g);
                if let Some(sw) = ctx.sweep {
                    sw.keep(key, g.clone());
                }
                g
            }
        };
        let blocks: Vec<(Vec<greedy::Bc>, prune::Pruned)> = (0..nblocks)
            .into_par_iter()
            .map(|b| {
                let range = b * block_rows..((b + 1) * block_rows).min(rows);
                let energy2: u64 = codes.codes[codes.indptr[range.start]..codes.indptr[range.end]]
                    .iter()
                    .map(|&c| (c as i64 * c as i64) as u64)
                    .sum();
                let (mut out, pruned) = prune::prune(greedy[b].clone(), range.len(), energy2, self.error_budget);
                // Number the block's biclusters by their first row (stable, so ties keep
                // the greedy order): pass 2 of the gather walks rows in order, and a
                // bicluster's scalar then sits near those of the other biclusters that
                // start nearby, instead of wherever the random greedy emitted it.
                out.sort_by_key(|bc| bc.rows.iter().min().copied());
                (out, pruned)
            })
            .collect();
        drop(greedy);
        let (blocks, pruned): (Vec<_>, Vec<_>) = blocks.into_iter().unzip();
        let mut form = assemble(t, &codes, block_rows, &blocks)?;
        let error2: u64 = pruned.iter().map(|p| p.error2).sum();
        form.lossless = error2 == 0;
        // The form is the same whichever way its greedy output came (a pure function of T
        // and the setting, for the cache and the shard merge); only its build time, then the
        // pruning's alone, tells.
        if self.error_budget > 0.0 {
            let energy2: u64 = pruned.iter().map(|p| p.energy2).sum();
            form.meta.insert("dropped_biclusters".into(), pruned.iter().map(|p| p.dropped as u64).sum());
            form.meta.insert("error2_codes".into(), error2);
            form.meta.insert("energy2_codes".into(), energy2);
        }
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }
}

/// What identifies a greedy run: the exact codes (by a 64-bit hash of their arrays), the block
/// rows, the seed, the first block's index and the column cost.
#[derive(Clone, Debug, PartialEq, Eq)]
struct SharedKey {
    fingerprint: u64,
    rows: usize,
    cols: usize,
    scale: u32,
    nnz: usize,
    block_rows: usize,
    seed: u64,
    first_block: usize,
    column_cost: u32,
}

impl SharedKey {
    fn of(codes: &CodeMatrix, block_rows: usize, seed: u64, first_block: usize, column_cost: u32) -> Self {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        codes.indptr.hash(&mut h);
        codes.col_idx.hash(&mut h);
        codes.codes.hash(&mut h);
        Self {
            fingerprint: h.finish(),
            rows: codes.rows,
            cols: codes.cols,
            scale: codes.scale,
            nnz: codes.nnz(),
            block_rows,
            seed,
            first_block,
            column_cost,
        }
    }
}

/// Store `form`'s row lists as global bicluster ids plus `offset` (u32, `row_bc_local` = 0):
/// what [`assemble`] writes when a block has more biclusters than u16 ids, and what a part
/// of a larger matrix needs when another part had to.
pub fn with_global_ids(form: &mut CompressedForm, offset: u32) -> Result<(), CompressError> {
    let global: Vec<u32> = {
        let v = BiclusterView::new(form)?;
        let mut ids = Vec::with_capacity(v.row_bc.len());
        for i in 0..v.rows {
            ids.extend(v.row_biclusters(i).map(|b| b as u32 + offset));
        }
        ids
    };
    let a = form.arrays.iter_mut().find(|a| a.name == "row_bc").expect("BiclusterView checked it");
    a.data = ArrayData::U32(global);
    form.meta.insert("row_bc_local".into(), 0);
    Ok(())
}

/// Biclusters per rayon task in pass 1 of the gather.
const PASS1_CHUNK: usize = 512;
/// Rows per rayon task in pass 2 of the gather.
const PASS2_CHUNK: usize = 512;

/// The light prescaled by `1 / value_scale`: `L'_k = L_k / q`.
pub(crate) fn prescaled_light(light: &LightVector, value_scale: u32) -> Vec<[f32; 3]> {
    let inv_q = 1.0 / value_scale as f32;
    light.power.iter().map(|p| p.map(|x| x * inv_q)).collect()
}

/// Pass 1 for one bicluster: `sum_m t_m L'_{k_m}` over its entries, in order, or the first
/// column past `lp`.
#[inline]
pub(crate) fn bicluster_sum<const W: usize>(ks: &[u16], ts: &[i8], lp: &[[f32; W]]) -> Result<[f32; W], u16> {
    let mut acc = [0.0f32; W];
    for (&k, &t) in ks.iter().zip(ts) {
        let l = lp.get(k as usize).ok_or(k)?;
        let t = t as f32;
        for c in 0..W {
            acc[c] += t * l[c];
        }
    }
    Ok(acc)
}

/// Pass 2 for one row: the sum, in order, of the scalars `a[id]` of its biclusters, or `None`
/// when an id is past `a`.
#[inline]
pub(crate) fn row_sum<I: Copy + Into<u64>, const W: usize>(ids: &[I], a: &[[f32; W]]) -> Option<[f32; W]> {
    let mut acc = [0.0f32; W];
    for &i in ids {
        let x = a.get(i.into() as usize)?;
        for c in 0..W {
            acc[c] += x[c];
        }
    }
    Some(acc)
}

/// Flatten the blocks' biclusters into the form's arrays.
fn assemble(
    t: &TransferMatrix,
    codes: &CodeMatrix,
    block_rows: usize,
    blocks: &[Vec<greedy::Bc>],
) -> Result<CompressedForm, CompressError> {
    let nb: usize = blocks.iter().map(|b| b.len()).sum();
    let local = blocks.iter().all(|b| b.len() <= u16::MAX as usize + 1);
    let sum_l: usize = blocks.iter().flatten().map(|b| b.cols.len()).sum();
    let sum_r: usize = blocks.iter().flatten().map(|b| b.rows.len()).sum();
    if nb >= u32::MAX as usize || sum_l > u32::MAX as usize || sum_r > u32::MAX as usize {
        return Err(CompressError::TooLarge(format!("bicluster: {nb} biclusters, {sum_l} columns, {sum_r} rows")));
    }
    let mut bc_col_ptr = Vec::with_capacity(nb + 1);
    bc_col_ptr.push(0u32);
    let (mut bc_cols, mut bc_vals) = (Vec::with_capacity(sum_l), Vec::with_capacity(sum_l));
    let mut block_bc_base = vec![0u32];
    let mut row_len = vec![0u32; codes.rows];
    let mut flops: u64 = codes.cols as u64;
    for (bi, block) in blocks.iter().enumerate() {
        let row0 = bi * block_rows;
        for bc in block {
            bc_cols.extend_from_slice(&bc.cols);
            bc_vals.extend_from_slice(&bc.vals);
            bc_col_ptr.push(bc_cols.len() as u32);
            for &j in &bc.rows {
                row_len[row0 + j as usize] += 1;
            }
            flops += (bc.rows.len() + 2 * bc.cols.len() - 1) as u64;
        }
        block_bc_base.push(bc_col_ptr.len() as u32 - 1);
    }
    let mut row_ptr = Vec::with_capacity(codes.rows + 1);
    row_ptr.push(0u32);
    for &n in &row_len {
        row_ptr.push(row_ptr.last().unwrap() + n);
    }
    let mut fill: Vec<u32> = row_ptr[..codes.rows].to_vec();
    let mut ids = vec![0u32; sum_r];
    for (bi, block) in blocks.iter().enumerate() {
        let (row0, base) = (bi * block_rows, block_bc_base[bi]);
        for (i, bc) in block.iter().enumerate() {
            let id = if local { i as u32 } else { base + i as u32 };
            for &j in &bc.rows {
                let r = row0 + j as usize;
                ids[fill[r] as usize] = id;
                fill[r] += 1;
            }
        }
    }
    let row_bc = if local { ArrayData::U16(ids.iter().map(|&x| x as u16).collect()) } else { ArrayData::U32(ids) };
    let meta = BTreeMap::from([
        ("value_scale".to_string(), codes.scale as u64),
        ("block_rows".to_string(), block_rows as u64),
        ("blocks".to_string(), blocks.len() as u64),
        ("biclusters".to_string(), nb as u64),
        ("row_bc_local".to_string(), local as u64),
    ]);
    let mut form = CompressedForm::new(KIND.name, t.shape())
        .with_array("bc_col_ptr", ArrayData::U32(bc_col_ptr))
        .with_array("bc_cols", ArrayData::U16(bc_cols))
        .with_array("bc_vals", ArrayData::I8(bc_vals))
        .with_array("row_ptr", ArrayData::U32(row_ptr))
        .with_array("row_bc", row_bc)
        .with_array("block_bc_base", ArrayData::U32(block_bc_base));
    form.meta = meta;
    form.lossless = true;
    form.flops_per_gather = flops;
    Ok(form)
}

/// The matrix a form stands for, `sum_i B_i` as f32 values `code / value_scale`: `T` itself
/// for a lossless form, `T' = T - E` for a lossy one (what its gathers compute exactly).
pub fn decompress(form: &CompressedForm) -> Result<TransferMatrix, CompressError> {
    let c = decompress_codes(form)?;
    let q = c.scale as f32;
    let csr = sprs::CsMat::new(
        (c.rows, c.cols),
        c.indptr,
        c.col_idx.iter().map(|&k| k as usize).collect(),
        c.codes.iter().map(|&x| x as f32 / q).collect(),
    );
    TransferMatrix::new(form.local_basis(), form.light_basis(), csr)
        .map_err(|e| CompressError::malformed("bicluster", "T'", e.to_string()))
}

/// Rebuild `T` in integer codes from a form's biclusters (`sum_i B_i`, exact).
pub fn decompress_codes(form: &CompressedForm) -> Result<CodeMatrix, CompressError> {
    let v = BiclusterView::new(form)?;
    let mut acc = vec![0i32; v.cols];
    let mut touched: Vec<u16> = Vec::new();
    let mut indptr = vec![0usize];
    let (mut col_idx, mut out) = (Vec::new(), Vec::new());
    for i in 0..v.rows {
        for b in v.row_biclusters(i) {
            let (ks, ts) = v.bicluster(b);
            for (&k, &t) in ks.iter().zip(ts) {
                if acc[k as usize] == 0 {
                    touched.push(k);
                }
                // A column whose sum returns to zero stays in `touched` and is skipped below.
                acc[k as usize] += t as i32;
            }
        }
        touched.sort_unstable();
        touched.dedup();
        for &k in &touched {
            let c = std::mem::take(&mut acc[k as usize]);
            if c != 0 {
                if c.abs() > codes::CODE_MAX {
                    return Err(CompressError::malformed(
                        "bicluster",
                        "bc_vals",
                        format!("row {i} column {k} sums to code {c}"),
                    ));
                }
                col_idx.push(k);
                out.push(c as i8);
            }
        }
        touched.clear();
        indptr.push(out.len());
    }
    Ok(CodeMatrix { rows: v.rows, cols: v.cols, scale: v.value_scale, indptr, col_idx, codes: out })
}
