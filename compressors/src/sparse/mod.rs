//! The raw sparse matrix: `T` as plain CSR (u32 row pointers, u32 column indices, f32
//! values: 8 bytes per non-zero plus 4 per row). The uncompressed baseline every other
//! compressor is compared with; its gather is the row-wise sparse dot product, on the CPU
//! here and on the GPU in `gather.wgsl` (one invocation per row, in the same f32 order).
//!
//! Form (`kind = "sparse"`): `row_ptr` (u32, rows + 1), `col_idx` (u32, nnz), `values`
//! (f32, nnz); no meta values.

mod params;
pub use params::SparseParams;

use crate::registry::{self, Kind};
use biscale_core::basis::TransferShape;
use biscale_core::compress::{
    concat_parts, ArrayData, CompressContext, CompressError, CompressedForm, Compressor, NamedArray, Separability,
};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc};
use rayon::prelude::*;
use std::time::Instant;

/// Rows per rayon task of the CPU gather.
const ROWS_PER_TASK: usize = 256;

impl registry::MakeCompressor for Sparse {
    fn make(p: &serde_json::Value) -> Result<Box<dyn Compressor>, String> {
        Ok(Box::new(Sparse::new(registry::parse(p)?)))
    }
}

/// The registry entry.
pub const KIND: Kind = Kind {
    // The form is `T` itself as a u32 CSR, and compressing copies it once.
    memory: |_, t| registry::FormMemory { working: t.u32_csr_bytes(), form: t.u32_csr_bytes() },
    role: registry::Role::Raw,
    flops: form_flops,
    ..Kind::built_in::<Sparse>("sparse", "the raw CSR matrix: the uncompressed baseline", |p| {
        registry::parse::<SparseParams>(p).map(|_| "sparse".into())
    })
};

/// The flops of one gather of `form`, counted from its own arrays (`eval --form` reports this,
/// not what a file claims).
/// One multiply and one add per stored non-zero.
fn form_flops(form: &CompressedForm) -> Option<u64> {
    let len = |name: &str| form.array(name).ok().map(|a| a.len() as u64);
    Some(len("values")?.saturating_mul(2))
}

/// The raw CSR baseline (no parameters).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sparse;

impl Sparse {
    pub fn new(_params: SparseParams) -> Self {
        Sparse
    }
}

impl Compressor for Sparse {
    fn kind(&self) -> &str {
        KIND.name
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(SparseParams {}).expect("plain struct serializes")
    }

    fn kernels(&self, _form: &CompressedForm) -> Result<KernelDesc, CompressError> {
        let len = |a: &str| Count::of([Factor::Len(a.into())]);
        Ok(KernelDesc {
            kind: KIND.name.into(),
            wgsl: biscale_kernels::with_row_pass(include_str!("gather.wgsl")),
            passes: vec![PassDesc {
                entry_point: biscale_kernels::ROW_ENTRY.into(),
                threads: Count::of([Factor::Rows]),
            }],
            scratch: vec![],
            meta_keys: vec![],
            checks: vec![
                FormCheck::Len { array: "values".into(), count: len("col_idx") },
                FormCheck::Ptr { array: "row_ptr".into(), count: Count::of([Factor::Rows]), total: len("col_idx") },
                FormCheck::Below { array: "col_idx".into(), bound: Count::of([Factor::Cols]) },
                FormCheck::Finite { array: "values".into() },
            ],
        })
    }

    fn compress(&self, t: &TransferMatrix, _ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        let start = Instant::now();
        let csr = t.csr();
        if csr.nnz() > u32::MAX as usize {
            return Err(CompressError::TooLarge(format!("{} non-zeros do not fit u32 row pointers", csr.nnz())));
        }
        let row_ptr: Vec<u32> = csr.indptr().as_slice().expect("CSR indptr").iter().map(|&p| p as u32).collect();
        let col_idx: Vec<u32> = csr.indices().iter().map(|&c| c as u32).collect();
        let values = csr.data().to_vec();
        let mut form = CompressedForm::new("sparse", t.shape());
        form.arrays = vec![
            NamedArray { name: "row_ptr".into(), data: ArrayData::U32(row_ptr) },
            NamedArray { name: "col_idx".into(), data: ArrayData::U32(col_idx) },
            NamedArray { name: "values".into(), data: ArrayData::F32(values) },
        ];
        form.lossless = true;
        form.flops_per_gather = 2 * csr.nnz() as u64;
        form.build_seconds = start.elapsed().as_secs_f64();
        Ok(form)
    }

    /// Rows are stored as they are: any vertex range is a part.
    fn separability(&self, _shape: TransferShape) -> Separability {
        Separability::Rows { vertex_multiple: 1 }
    }

    fn merge_parts(&self, shape: TransferShape, parts: Vec<CompressedForm>) -> Result<CompressedForm, CompressError> {
        concat_parts("sparse", shape, &parts, &["row_ptr"])
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        form.check_light(light)?;
        // The light padded to four lanes, so each term is one 4-wide multiply-add.
        let power: Vec<[f32; 4]> = light.power.iter().map(|p| [p[0], p[1], p[2], 0.0]).collect();
        form.lstar(gather_lanes(form, &power)?.into_iter().map(|a| [a[0], a[1], a[2]]).collect())
    }

    /// The three lights in one pass over the rows, twelve lanes wide (each light padded to
    /// four): columns and values are read once. Each lane's sum runs in the order of
    /// [`Compressor::gather`], so the result is its three gathers bit for bit.
    fn gather_three(
        &self,
        form: &CompressedForm,
        lights: [&LightVector; 3],
    ) -> Result<[LocalRadiance; 3], CompressError> {
        let power = form.interleave_three(lights, |[a, b, c]| {
            [a[0], a[1], a[2], 0.0, b[0], b[1], b[2], 0.0, c[0], c[1], c[2], 0.0]
        })?;
        form.lstar_three(&gather_lanes(form, &power)?, 4)
    }
}

/// Every row's dot product with `W` lanes of light per texel.
fn gather_lanes<const W: usize>(form: &CompressedForm, power: &[[f32; W]]) -> Result<Vec<[f32; W]>, CompressError> {
    let row_ptr = form.u32s("row_ptr")?;
    let col_idx = form.u32s("col_idx")?;
    let values = form.f32s("values")?;
    if row_ptr.len() != form.rows() + 1 || col_idx.len() != values.len() {
        return Err(CompressError::malformed("sparse", "row_ptr", "and col_idx/values do not match the shape"));
    }
    // Row pointers must be monotone and end at nnz, columns in range: checked where read
    // (`get`), so a corrupt form is an error, never a panic, at no measurable cost.
    let malformed = |r: usize| {
        CompressError::malformed("sparse", "row_ptr", format!("row {r} has an out-of-range offset or column"))
    };
    // Rows in chunks written in place, four rows interleaved over their common length: each
    // row's sum is a chain of dependent adds (its f32 order is the GPU kernel's, kept), so
    // four independent chains hide the add latency that bounds one row alone.
    let row = |r: usize| -> Result<(&[u32], &[f32]), CompressError> {
        let (start, end) = (row_ptr[r] as usize, row_ptr[r + 1] as usize);
        match (col_idx.get(start..end), values.get(start..end)) {
            (Some(c), Some(v)) => Ok((c, v)),
            _ => Err(malformed(r)),
        }
    };
    // One row's dot product, `acc` starting at the sum of its first `from` terms.
    let dot = |r: usize, from: usize, mut acc: [f32; W]| -> Result<[f32; W], CompressError> {
        let (cols, vals) = row(r)?;
        for (&k, &v) in cols[from..].iter().zip(&vals[from..]) {
            let l = power.get(k as usize).ok_or_else(|| malformed(r))?;
            for c in 0..W {
                acc[c] += v * l[c];
            }
        }
        Ok(acc)
    };
    let mut values_out = vec![[0.0f32; W]; form.rows()];
    values_out.par_chunks_mut(ROWS_PER_TASK).enumerate().try_for_each(|(chunk, out)| {
        let first = chunk * ROWS_PER_TASK;
        let rest = first + out.len() / 4 * 4;
        let mut quads = out.chunks_exact_mut(4);
        for (q, quad) in (&mut quads).enumerate() {
            let r0 = first + 4 * q;
            let rows = [row(r0)?, row(r0 + 1)?, row(r0 + 2)?, row(r0 + 3)?];
            let common = rows.iter().map(|(c, _)| c.len()).min().unwrap_or(0);
            let cols = rows.map(|(c, _)| &c[..common]);
            let vals = rows.map(|(_, v)| &v[..common]);
            let mut acc = [[0.0f32; W]; 4];
            for j in 0..common {
                for i in 0..4 {
                    let l = power.get(cols[i][j] as usize).ok_or_else(|| malformed(r0 + i))?;
                    for c in 0..W {
                        acc[i][c] += vals[i][j] * l[c];
                    }
                }
            }
            for (i, o) in quad.iter_mut().enumerate() {
                *o = dot(r0 + i, common, acc[i])?;
            }
        }
        for (i, o) in quads.into_remainder().iter_mut().enumerate() {
            *o = dot(rest + i, 0, [0.0; W])?;
        }
        Ok::<(), CompressError>(())
    })?;
    Ok(values_out)
}

#[cfg(test)]
mod tests;
