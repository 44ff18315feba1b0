//! # biscale-plugin-quantized
//!
//! An example transfer compressor loaded by biscale as a plugin (`kind = "plugin"`,
//! `path = ".../libbiscale_plugin_quantized.so"`): quantized sparse rows. Every non-zero
//! `T_ik >= 0` is stored as an 8-bit code `q = round(T_ik / s)` with one scale `s` for the whole
//! matrix, and its column as a u16; rows keep u32 pointers. 3 bytes per non-zero plus 4 per row
//! (raw CSR: 8 per non-zero). Entries whose code rounds to 0 are dropped.
//!
//! Gather (CPU and WGSL, same order): `L*_i = s * sum_e q_e L_{k_e}`, summed in f32 over the
//! row's entries in column order. The codes are integers <= 255, exact in f32.
//!
//! Parameters: `scale` (optional number > 0): the step `s`; default `max T / 255`. With the
//! box-filtered visibility values {1/4, 1/2, 3/4, 1}, `scale = 0.25` makes the form lossless.
//! Unknown parameters are errors.

use biscale_plugin::serde_json::Value;
use biscale_plugin::{
    Array, Check, Count, CsrView, Factor, Kernels, Pass, PluginCompressor, PluginForm, PluginFormView,
};

/// The quantized sparse-row compressor.
pub struct Quantized;

/// The WGSL gather: `row_lstar`, run one invocation per row by the shared row pass.
pub const WGSL: &str = include_str!("quantized.wgsl");

/// The scale from the parameters (`None`: derive from the matrix).
fn scale_param(params: &Value) -> Result<Option<f32>, String> {
    let Some(obj) = params.as_object() else {
        return Err(format!("parameters must be a table, got {params}"));
    };
    if let Some(k) = obj.keys().find(|k| *k != "scale") {
        return Err(format!("unknown parameter '{k}' (quantized takes only 'scale')"));
    }
    match obj.get("scale") {
        None => Ok(None),
        Some(v) => match v.as_f64() {
            Some(s) if s > 0.0 && (s as f32).is_finite() && s as f32 > 0.0 => Ok(Some(s as f32)),
            _ => Err(format!("'scale' must be a positive finite number, got {v}")),
        },
    }
}

impl PluginCompressor for Quantized {
    const NAME: &'static str = "quantized";

    fn kernels(params: &Value) -> Result<Kernels, String> {
        scale_param(params)?;
        let rows = || Count::of([Factor::Rows]);
        Ok(Kernels {
            wgsl: biscale_plugin::with_row_pass(WGSL),
            passes: vec![Pass { entry_point: biscale_plugin::ROW_ENTRY.into(), threads: rows() }],
            scratch: vec![],
            meta_keys: vec![],
            // Enough that the kernel's loop is bounded and every index is in range.
            checks: vec![
                Check::Ptr { array: "row_ptr".into(), count: rows(), target: "col_idx".into() },
                Check::Len { array: "codes".into(), count: Count::of([Factor::Len("col_idx".into())]) },
                Check::Below { array: "col_idx".into(), bound: Count::of([Factor::Cols]) },
                Check::Len { array: "scale".into(), count: Count::of([Factor::Const(1)]) },
                Check::Finite { array: "scale".into() },
            ],
        })
    }

    fn compress(t: &CsrView<'_>, params: &Value) -> Result<PluginForm, String> {
        if t.cols > 1 << 16 {
            return Err(format!("{} columns do not fit u16 column indices (at most 65536)", t.cols));
        }
        if let Some(i) = t.values.iter().position(|v| !v.is_finite() || *v < 0.0) {
            return Err(format!("value {i} of T is {}: quantized codes need finite values >= 0", t.values[i]));
        }
        let max = t.values.iter().copied().fold(0.0f32, f32::max);
        let scale = match scale_param(params)? {
            Some(s) => s,
            None if max > 0.0 => max / 255.0,
            None => 1.0,
        };
        let mut row_ptr = Vec::with_capacity(t.rows + 1);
        row_ptr.push(0u32);
        let (mut col_idx, mut codes) = (Vec::new(), Vec::new());
        let mut lossless = true;
        for r in 0..t.rows {
            let (cols, values) = t.row(r);
            for (&k, &v) in cols.iter().zip(values) {
                let q = (v as f64 / scale as f64).round();
                if q > 255.0 {
                    return Err(format!("T value {v} in row {r} is above 255 x scale = {}", 255.0 * scale));
                }
                lossless &= q as f32 * scale == v;
                if q >= 1.0 {
                    col_idx.push(k as u16);
                    codes.push(q as u8);
                }
            }
            row_ptr.push(col_idx.len() as u32);
        }
        let kept = codes.len() as u64;
        Ok(PluginForm {
            arrays: vec![
                ("row_ptr".into(), Array::U32(row_ptr)),
                ("col_idx".into(), Array::U16(col_idx)),
                ("codes".into(), Array::U8(codes)),
                ("scale".into(), Array::F32(vec![scale])),
            ],
            meta: vec![],
            lossless,
            // A multiply and an add per kept entry, one multiply by the scale per row.
            flops_per_gather: 2 * kept + t.rows as u64,
        })
    }

    fn gather_cpu(form: &PluginFormView<'_>, light: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, String> {
        let (row_ptr, col_idx, codes) = (form.u32s("row_ptr")?, form.u16s("col_idx")?, form.u8s("codes")?);
        let scale = form.f32s("scale")?[0];
        let row = |r: usize| {
            let mut acc = [0.0f32; 3];
            for e in row_ptr[r] as usize..row_ptr[r + 1] as usize {
                let (q, l) = (codes[e] as f32, light[col_idx[e] as usize]);
                for c in 0..3 {
                    acc[c] += q * l[c];
                }
            }
            acc.map(|a| scale * a)
        };
        // Rows are independent: split them over the machine's threads.
        let mut out = vec![[0.0f32; 3]; form.rows];
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let chunk = form.rows.div_ceil(threads).max(1024);
        std::thread::scope(|s| {
            for (i, part) in out.chunks_mut(chunk).enumerate() {
                s.spawn(move || {
                    for (j, v) in part.iter_mut().enumerate() {
                        *v = row(i * chunk + j);
                    }
                });
            }
        });
        Ok(out)
    }
}

biscale_plugin::export_plugin!(Quantized);
