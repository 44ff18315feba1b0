//! The built-in gather programs, one small description per compressor kind: its WGSL file
//! (next to this one), its passes with their invocation counts, its scratch buffers and the
//! meta keys it reads. Bindings come from the WGSL itself (see [`super::program`]).
//!
//! Each kind also has a structural check (pointer arrays monotone and in range, indices
//! below their bounds) run on the host before upload: a bad offset array would otherwise make
//! a GPU invocation loop for billions of steps. Out-of-range reads cannot corrupt memory
//! either way (wgpu clamps every storage access).

use super::program::{Count, Factor, GatherProgram, KernelPass, ScratchBuffer};
use biscale_core::compress::CompressedForm;

/// The kinds that have a built-in GPU gather.
pub const BUILTIN_KINDS: &[&str] = &["sparse", "bicluster", "haar", "cpca"];

/// The built-in program for `form`'s kind, if there is one (the Haar program depends on
/// whether the form stores f16 values).
pub fn builtin_program(form: &CompressedForm) -> Option<GatherProgram> {
    let rows = || Count::of([Factor::Rows]);
    let meta = |k: &str| Factor::Meta(k.into());
    match form.kind.as_str() {
        // Raw CSR (compressors/src/sparse.rs): one invocation per row.
        "sparse" => Some(GatherProgram {
            kind: "sparse".into(),
            wgsl: include_str!("sparse.wgsl").into(),
            passes: vec![KernelPass { entry_point: "sparse_rows".into(), threads: rows() }],
            scratch: vec![],
            meta_keys: vec![],
            validate: Some(validate_sparse),
        }),
        // Biclusters (compressors/src/bicluster/mod.rs): per-bicluster scalars, then row sums.
        "bicluster" => Some(GatherProgram {
            kind: "bicluster".into(),
            wgsl: include_str!("bicluster.wgsl").into(),
            passes: vec![
                KernelPass { entry_point: "bicluster_sums".into(), threads: Count::of([meta("biclusters")]) },
                KernelPass { entry_point: "bicluster_rows".into(), threads: rows() },
            ],
            scratch: vec![ScratchBuffer {
                name: "bc_sums".into(),
                words: Count::of([meta("biclusters"), Factor::Const(3)]),
            }],
            meta_keys: vec!["value_scale".into(), "block_rows".into(), "row_bc_local".into()],
            validate: Some(validate_bicluster),
        }),
        // Haar (compressors/src/haar.rs): transform the light, then sparse dots per row.
        "haar" => {
            let f16 = form.meta.get("f16_values").copied().unwrap_or(0) != 0;
            let values = if f16 {
                "@group(0) @binding(6) var<storage, read> coeff_f16: array<u32>; // u16 half bits, packed 2 per word\n\
                 fn coeff_at(i: u32) -> f32 { return unpack2x16float(coeff_f16[i >> 1u])[i & 1u]; }"
            } else {
                "@group(0) @binding(6) var<storage, read> coeff_val: array<f32>;\n\
                 fn coeff_at(i: u32) -> f32 { return coeff_val[i]; }"
            };
            let light_words = Count::of([Factor::Cols, Factor::Const(3)]);
            Some(GatherProgram {
                kind: "haar".into(),
                wgsl: include_str!("haar.wgsl").replace("//#VALUES", values),
                passes: vec![
                    KernelPass { entry_point: "haar_light".into(), threads: Count::of([Factor::Const(18)]) },
                    KernelPass { entry_point: "haar_rows".into(), threads: rows() },
                ],
                scratch: vec![
                    ScratchBuffer { name: "light_hat".into(), words: light_words.clone() },
                    ScratchBuffer { name: "haar_tmp".into(), words: light_words },
                ],
                meta_keys: vec!["resolution".into()],
                validate: Some(validate_haar),
            })
        }
        // Clustered PCA (compressors/src/cpca/mod.rs): project the light on every mean and
        // component (a workgroup each), then combine per row.
        "cpca" => {
            let vectors = [meta("clusters"), Factor::MetaPlus("components".into(), 1)];
            Some(GatherProgram {
                kind: "cpca".into(),
                wgsl: include_str!("cpca.wgsl").into(),
                passes: vec![
                    KernelPass {
                        entry_point: "cpca_project".into(),
                        threads: Count::of(vectors.iter().cloned().chain([Factor::Const(64)])),
                    },
                    KernelPass { entry_point: "cpca_rows".into(), threads: rows() },
                ],
                scratch: vec![ScratchBuffer {
                    name: "proj".into(),
                    words: Count::of(vectors.into_iter().chain([Factor::Const(3)])),
                }],
                meta_keys: vec!["clusters".into(), "components".into()],
                validate: Some(validate_cpca),
            })
        }
        _ => None,
    }
}

type Check = Result<(), String>;

/// `ptr` has `n + 1` non-decreasing entries from 0 to `total`.
fn check_ptr(kind: &str, name: &str, ptr: &[u32], n: usize, total: usize) -> Check {
    if ptr.len() != n + 1 {
        return Err(format!("{kind}: {name} has {} entries, expected {}", ptr.len(), n + 1));
    }
    if ptr[0] != 0 || ptr[n] as usize != total {
        return Err(format!("{kind}: {name} must run from 0 to {total}"));
    }
    if let Some(i) = ptr.windows(2).position(|w| w[1] < w[0]) {
        return Err(format!("{kind}: {name} decreases at {i}"));
    }
    Ok(())
}

fn err(e: impl ToString) -> String {
    e.to_string()
}

/// CSR structure, finite values.
fn validate_sparse(form: &CompressedForm) -> Check {
    let row_ptr = form.u32s("row_ptr").map_err(err)?;
    let col_idx = form.u32s("col_idx").map_err(err)?;
    let values = form.f32s("values").map_err(err)?;
    if col_idx.len() != values.len() {
        return Err(format!("sparse: {} column indices but {} values", col_idx.len(), values.len()));
    }
    check_ptr("sparse", "row_ptr", row_ptr, form.rows(), values.len())?;
    if let Some(i) = col_idx.iter().position(|&c| c as usize >= form.cols()) {
        return Err(format!("sparse: col_idx[{i}] = {} is not below cols = {}", col_idx[i], form.cols()));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(format!("sparse: values[{i}] = {} is not finite", values[i]));
    }
    Ok(())
}

/// Bicluster and row lists, ids within their block, codes' scale.
fn validate_bicluster(form: &CompressedForm) -> Check {
    let nb = form.meta("biclusters").map_err(err)? as usize;
    let q = form.meta("value_scale").map_err(err)?;
    let block_rows = form.meta("block_rows").map_err(err)? as usize;
    let local = form.meta("row_bc_local").map_err(err)? == 1;
    if q == 0 {
        return Err("bicluster: value_scale is 0".into());
    }
    let (bc_col_ptr, bc_cols, bc_vals) =
        (form.u32s("bc_col_ptr").map_err(err)?, form.u16s("bc_cols").map_err(err)?, form.i8s("bc_vals").map_err(err)?);
    if bc_vals.len() != bc_cols.len() {
        return Err("bicluster: bc_cols and bc_vals differ in length".into());
    }
    check_ptr("bicluster", "bc_col_ptr", bc_col_ptr, nb, bc_cols.len())?;
    if bc_cols.iter().any(|&k| k as usize >= form.cols()) {
        return Err("bicluster: a column index is out of range".into());
    }
    let row_ptr = form.u32s("row_ptr").map_err(err)?;
    let blocks = if form.rows() == 0 { 0 } else { form.rows().div_ceil(block_rows.max(1)) };
    let base = form.u32s("block_bc_base").map_err(err)?;
    if block_rows == 0 && form.rows() > 0 {
        return Err("bicluster: block_rows is 0".into());
    }
    check_ptr("bicluster", "block_bc_base", base, blocks, nb)?;
    let ids: Vec<usize> = if local {
        form.u16s("row_bc").map_err(err)?.iter().map(|&x| x as usize).collect()
    } else {
        form.u32s("row_bc").map_err(err)?.iter().map(|&x| x as usize).collect()
    };
    check_ptr("bicluster", "row_ptr", row_ptr, form.rows(), ids.len())?;
    for i in 0..form.rows() {
        let (lo, hi, off) = if local {
            let b = i / block_rows;
            (base[b] as usize, base[b + 1] as usize, base[b] as usize)
        } else {
            (0, nb, 0)
        };
        if ids[row_ptr[i] as usize..row_ptr[i + 1] as usize].iter().any(|&x| x + off < lo || x + off >= hi) {
            return Err(format!("bicluster: row {i} names a bicluster outside its block"));
        }
    }
    Ok(())
}

/// Row lists, coefficient indices below N = 6 R^2, finite values.
fn validate_haar(form: &CompressedForm) -> Check {
    let r = form.meta("resolution").map_err(err)? as usize;
    if r == 0 || !r.is_power_of_two() || 6 * r * r != form.cols() {
        return Err(format!("haar: resolution {r} does not give {} columns", form.cols()));
    }
    let row_ptr = form.u32s("row_ptr").map_err(err)?;
    let idx = form.u16s("coeff_idx").map_err(err)?;
    let n = if form.meta("f16_values").map_err(err)? != 0 {
        let h = form.u16s("coeff_f16").map_err(err)?;
        // Exponent bits all ones: an f16 infinity or NaN.
        if let Some(i) = h.iter().position(|&b| b & 0x7c00 == 0x7c00) {
            return Err(format!("haar: coeff_f16[{i}] is not finite"));
        }
        h.len()
    } else {
        let v = form.f32s("coeff_val").map_err(err)?;
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(format!("haar: coeff_val[{i}] is not finite"));
        }
        v.len()
    };
    if n != idx.len() {
        return Err("haar: coefficient indices and values differ in length".into());
    }
    check_ptr("haar", "row_ptr", row_ptr, form.rows(), idx.len())?;
    if idx.iter().any(|&k| k as usize >= form.cols()) {
        return Err("haar: a coefficient index is out of range".into());
    }
    Ok(())
}

/// Array lengths against K, C, N and the rows; cluster ids at most K (K = all-zero row).
fn validate_cpca(form: &CompressedForm) -> Check {
    let k = form.meta("clusters").map_err(err)? as usize;
    let c = form.meta("components").map_err(err)? as usize;
    let basis = form.f32s("basis").map_err(err)?;
    let cluster = form.u16s("cluster").map_err(err)?;
    let coeffs = form.f32s("coeffs").map_err(err)?;
    let expect = k.checked_mul(c + 1).and_then(|x| x.checked_mul(form.cols()));
    if expect != Some(basis.len()) || cluster.len() != form.rows() || Some(coeffs.len()) != form.rows().checked_mul(c) {
        return Err(format!(
            "cpca: array lengths do not match K = {k}, C = {c}, N = {}, rows = {}",
            form.cols(),
            form.rows()
        ));
    }
    if let Some(r) = cluster.iter().position(|&id| id as usize > k) {
        return Err(format!("cpca: row {r} has cluster id {} > K = {k}", cluster[r]));
    }
    if let Some(i) = basis.iter().chain(coeffs).position(|x| !x.is_finite()) {
        return Err(format!("cpca: non-finite value at position {i} of basis ++ coeffs"));
    }
    Ok(())
}
