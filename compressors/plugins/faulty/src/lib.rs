//! # biscale-plugin-faulty (test only)
//!
//! A plugin that misbehaves on request, so the host's tests can prove that every failure is a
//! clear error naming the library and never a crash. With `{"fail": "none"}` it is a correct
//! raw-CSR compressor (row_ptr u32, col_idx u32, values f32) with a WGSL gather; otherwise
//! `fail` picks the fault:
//!
//! | `fail` | fault |
//! |---|---|
//! | `error` / `panic` | `compress` returns an error / panics |
//! | `bad_arrays` | `row_ptr` one entry short (its declared `Ptr` check fails) |
//! | `bad_name` | an array named `lstar` (reserved by the GPU prelude) |
//! | `bad_binding` | the WGSL binds an array the form does not have |
//! | `bad_wgsl` | `kernels` returns WGSL that does not compile |
//! | `kernels_panic` | `kernels` panics (the host calls it at load) |
//! | `gather_error` / `gather_panic` / `gather_nan` | the CPU gather errs / panics / writes NaN |
//! | `false_lossless` | every value doubled while the form claims `lossless` |
//!
//! The faults no boundary can catch end or stall the whole process, so the host's tests use
//! them only with `isolate = true` (the plugin in a child process):
//!
//! | `fail` | fault |
//! |---|---|
//! | `segfault` / `gather_segfault` | `compress` / the CPU gather writes to an unmapped address |
//! | `abort` / `gather_abort` / `kernels_abort` | `compress` / the gather / `kernels` aborts |
//! | `exit` / `gather_exit` | `compress` / the gather calls `std::process::exit(0)` |
//! | `hang` / `gather_hang` | `compress` / the gather sleeps for an hour |
//! | `noisy` | prints to stdout in `kernels`, `compress` and the gather, otherwise correct |
//!
//! Built with the `wrong_abi` feature it claims ABI 2.0 and aborts the process if anything
//! beyond the handshake is called, which proves the host stops at the version check.

use biscale_plugin::serde_json::Value;
use biscale_plugin::{
    Array, Check, Count, CsrView, Factor, Kernels, Pass, PluginCompressor, PluginForm, PluginFormView,
};

pub struct Faulty;

const WGSL: &str = r#"
@group(0) @binding(4) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(5) var<storage, read> col_idx: array<u32>;
@group(0) @binding(6) var<storage, read> values: array<f32>;

fn row_lstar(r: u32) -> vec3<f32> {
    var acc = vec3<f32>(0.0);
    for (var i = row_ptr[r]; i < row_ptr[r + 1u]; i++) {
        acc += values[i] * light_at(col_idx[i]);
    }
    return acc;
}
"#;

/// Gather faults, stored in the form's meta so the (parameter-less) gather can act on them.
const GATHER_OK: u64 = 0;
const GATHER_ERROR: u64 = 1;
const GATHER_PANIC: u64 = 2;
const GATHER_NAN: u64 = 3;
const GATHER_SEGFAULT: u64 = 4;
const GATHER_ABORT: u64 = 5;
const GATHER_EXIT: u64 = 6;
const GATHER_HANG: u64 = 7;
const GATHER_NOISY: u64 = 8;

/// A process-ending or process-stalling fault (see the module docs).
fn fatal(fault: &str) {
    match fault {
        // Page zero is never mapped. Not the null pointer itself: in a debug build std checks
        // `write_volatile`'s pointer first and aborts, which is not the fault wanted here.
        "segfault" => unsafe { std::ptr::write_volatile(std::ptr::without_provenance_mut::<u32>(8), 1) },
        "abort" => std::process::abort(),
        "exit" => std::process::exit(0),
        "hang" => std::thread::sleep(std::time::Duration::from_secs(3600)),
        "noisy" => println!("faulty plugin: this line on stdout must not disturb the host"),
        _ => {}
    }
}

fn mode(params: &Value) -> Result<String, String> {
    if cfg!(feature = "wrong_abi") {
        // The host must never get this far with an ABI 2.0 library.
        std::process::abort();
    }
    match params.get("fail").and_then(Value::as_str) {
        Some(m) => Ok(m.to_string()),
        None => Err(format!("faulty needs params {{\"fail\": \"...\"}}, got {params}")),
    }
}

impl PluginCompressor for Faulty {
    const NAME: &'static str = "faulty";

    fn kernels(params: &Value) -> Result<Kernels, String> {
        let mode = mode(params)?;
        let wgsl = match mode.as_str() {
            "bad_wgsl" => WGSL.replace("acc += values[i]", "acc += undeclared_thing[i]"),
            "bad_binding" => format!("{WGSL}\n@group(0) @binding(9) var<storage, read> not_in_form: array<u32>;\n"),
            "kernels_panic" => panic!("faulty plugin: kernels panicked on purpose"),
            "kernels_abort" => std::process::abort(),
            "noisy" => {
                fatal("noisy");
                WGSL.to_string()
            }
            _ => WGSL.to_string(),
        };
        let wgsl = biscale_plugin::with_row_pass(&wgsl);
        let rows = || Count::of([Factor::Rows]);
        Ok(Kernels {
            wgsl,
            passes: vec![Pass { entry_point: biscale_plugin::ROW_ENTRY.into(), threads: rows() }],
            scratch: vec![],
            meta_keys: vec![],
            checks: vec![
                Check::Ptr { array: "row_ptr".into(), count: rows(), target: "col_idx".into() },
                Check::Len { array: "values".into(), count: Count::of([Factor::Len("col_idx".into())]) },
                Check::Below { array: "col_idx".into(), bound: Count::of([Factor::Cols]) },
                Check::Finite { array: "values".into() },
            ],
        })
    }

    fn compress(t: &CsrView<'_>, params: &Value) -> Result<PluginForm, String> {
        let mode = mode(params)?;
        let mut row_ptr = t.row_ptr.to_vec();
        let mut values = t.values.to_vec();
        let mut gather = GATHER_OK;
        let mut values_name = "values";
        match mode.as_str() {
            "error" => return Err("faulty plugin: compress failed on purpose".into()),
            "panic" => panic!("faulty plugin: compress panicked on purpose"),
            "bad_arrays" => {
                row_ptr.pop();
            }
            "bad_name" => values_name = "lstar",
            "gather_error" => gather = GATHER_ERROR,
            "gather_panic" => gather = GATHER_PANIC,
            "gather_nan" => gather = GATHER_NAN,
            "gather_segfault" => gather = GATHER_SEGFAULT,
            "gather_abort" => gather = GATHER_ABORT,
            "gather_exit" => gather = GATHER_EXIT,
            "gather_hang" => gather = GATHER_HANG,
            "noisy" => {
                fatal("noisy");
                gather = GATHER_NOISY;
            }
            "segfault" | "abort" | "exit" | "hang" => fatal(&mode),
            // Claims lossless while every value is doubled (the host must catch the lie).
            "false_lossless" => values.iter_mut().for_each(|v| *v *= 2.0),
            _ => {}
        }
        Ok(PluginForm {
            arrays: vec![
                ("row_ptr".into(), Array::U32(row_ptr)),
                ("col_idx".into(), Array::U32(t.col_idx.to_vec())),
                (values_name.into(), Array::F32(values)),
            ],
            meta: vec![("gather_fault".into(), gather)],
            lossless: true,
            flops_per_gather: 2 * t.values.len() as u64,
        })
    }

    fn gather_cpu(form: &PluginFormView<'_>, light: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, String> {
        match form.meta("gather_fault")? {
            GATHER_ERROR => return Err("faulty plugin: gather failed on purpose".into()),
            GATHER_PANIC => panic!("faulty plugin: gather panicked on purpose"),
            GATHER_SEGFAULT => fatal("segfault"),
            GATHER_ABORT => fatal("abort"),
            GATHER_EXIT => fatal("exit"),
            GATHER_HANG => fatal("hang"),
            GATHER_NOISY => fatal("noisy"),
            _ => {}
        }
        let (row_ptr, col_idx, values) = (form.u32s("row_ptr")?, form.u32s("col_idx")?, form.f32s("values")?);
        let mut out: Vec<[f32; 3]> = (0..form.rows)
            .map(|r| {
                let mut acc = [0.0f32; 3];
                for i in row_ptr[r] as usize..row_ptr[r + 1] as usize {
                    for c in 0..3 {
                        acc[c] += values[i] * light[col_idx[i] as usize][c];
                    }
                }
                acc
            })
            .collect();
        if form.meta("gather_fault")? == GATHER_NAN {
            if let Some(v) = out.last_mut() {
                v[1] = f32::NAN;
            }
        }
        Ok(out)
    }
}

#[cfg(not(feature = "wrong_abi"))]
biscale_plugin::export_plugin!(Faulty);
#[cfg(feature = "wrong_abi")]
biscale_plugin::export_plugin!(Faulty, abi_version = 2 << 16);
