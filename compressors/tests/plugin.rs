//! Compressor plugins loaded through the C ABI: the example plugin against the same
//! algorithm compiled in and against the f64 reference, and every way a plugin can fail,
//! each of which must be an error that names the library file, never a crash.
//!
//! The plugin cdylibs are workspace members; `plugin::testing::build_plugin` builds them
//! (a no-op when fresh) into the target directory of this test executable.
#![cfg(feature = "plugin")]

use biscale_compressors::plugin::testing::build_plugin;
use biscale_compressors::plugin::{PluginCompressor, PluginError};
use biscale_compressors::testing::{
    assert_lossless, f32_sum_bound, quantized_stored_product, random_light, random_transfer,
};
use biscale_core::basis::LightBasis;
use biscale_core::compress::{ArrayData, CompressContext, CompressedForm, Compressor};
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_plugin::PluginCompressor as _;
use biscale_plugin_quantized::Quantized;
use serde_json::json;
use std::path::{Path, PathBuf};

fn quantized_lib() -> PathBuf {
    build_plugin("biscale-plugin-quantized", &[], None).unwrap()
}

fn faulty_lib() -> PathBuf {
    build_plugin("biscale-plugin-faulty", &[], None).unwrap()
}

fn faulty(fail: &str) -> Result<PluginCompressor, PluginError> {
    PluginCompressor::load(&faulty_lib(), json!({ "fail": fail }))
}

/// A scratch directory of this test process.
fn scratch_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("biscale-plugin-test-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `T` as the view the plugin's own code takes (what the host passes over the ABI).
fn csr_parts(t: &TransferMatrix) -> (Vec<u32>, Vec<u32>) {
    let row_ptr = t.csr().indptr().to_proper().iter().map(|&p| p as u32).collect();
    let col_idx = t.csr().indices().iter().map(|&c| c as u32).collect();
    (row_ptr, col_idx)
}

fn csr_view<'a>(t: &'a TransferMatrix, row_ptr: &'a [u32], col_idx: &'a [u32]) -> biscale_plugin::CsrView<'a> {
    biscale_plugin::CsrView {
        rows: t.rows(),
        cols: t.cols(),
        vertices: t.vertices(),
        local_dirs: t.local_dirs(),
        resolution: t.light_basis().cubemap_layout().unwrap().resolution,
        seed: 0,
        row_ptr,
        col_idx,
        values: t.csr().data(),
    }
}

/// The error names the library file (the contract of every failure).
fn assert_names_file(e: &dyn std::fmt::Display, path: &Path) {
    let s = e.to_string();
    assert!(s.contains(&path.display().to_string()), "error does not name {}: {s}", path.display());
}

#[test]
fn quantized_plugin_equals_the_compiled_in_algorithm_bit_for_bit() {
    let lib = quantized_lib();
    for params in [json!({}), json!({ "scale": 0.25 }), json!({ "scale": 0.01 })] {
        let plugin = PluginCompressor::load(&lib, params.clone()).unwrap();
        assert_eq!(plugin.kind(), "plugin:quantized");
        assert_eq!(plugin.name(), "quantized");
        for (seed, (vertices, dirs, res, density)) in
            [(20, 4, 4, 0.2), (3, 8, 8, 0.05), (1, 1, 1, 1.0), (4, 2, 2, 0.0)].into_iter().enumerate()
        {
            let t = random_transfer(vertices, dirs, res, density, seed as u64);
            let form = plugin.compress(&t, &CompressContext::default()).unwrap();
            let (row_ptr, col_idx) = csr_parts(&t);
            let direct = Quantized::compress(&csr_view(&t, &row_ptr, &col_idx), &params).unwrap();
            assert_eq!((form.rows(), form.cols(), form.local_dirs()), (t.rows(), t.cols(), t.local_dirs()));
            assert_eq!(form.lossless, direct.lossless);
            assert_eq!(form.flops_per_gather, direct.flops_per_gather);
            assert_eq!(form.arrays.len(), direct.arrays.len());
            for (a, (name, d)) in form.arrays.iter().zip(&direct.arrays) {
                assert_eq!(&a.name, name);
                let same = match (&a.data, d) {
                    (ArrayData::U32(x), biscale_plugin::Array::U32(y)) => x == y,
                    (ArrayData::U16(x), biscale_plugin::Array::U16(y)) => x == y,
                    (ArrayData::U8(x), biscale_plugin::Array::U8(y)) => x == y,
                    (ArrayData::F32(x), biscale_plugin::Array::F32(y)) => {
                        x.iter().map(|v| v.to_bits()).eq(y.iter().map(|v| v.to_bits()))
                    }
                    _ => false,
                };
                assert!(same, "array '{name}' differs between the cdylib and the compiled-in code");
            }
            for light_seed in [seed as u64 + 10, seed as u64 + 11] {
                let light = random_light(res, light_seed);
                let got = plugin.gather(&form, &light).unwrap();
                let want =
                    Quantized::gather_cpu(&direct.view(t.rows(), t.cols(), t.local_dirs()), &light.power).unwrap();
                assert_eq!(got.values().len(), want.len());
                for (r, (g, w)) in got.values().iter().zip(&want).enumerate() {
                    assert_eq!(g.map(f32::to_bits), w.map(f32::to_bits), "row {r}: {g:?} vs {w:?}");
                }
            }
        }
    }
}

/// The CPU gather against the f64 product of the matrix the form stores (codes x scale) and of
/// the original `T`. Bounds: a row sums `n` non-negative products `q L_k` in f32 (one rounding
/// per product, `n - 1` additions: at most `(n + 1) u` of the exact sum) and multiplies by the
/// scale once more (`u`): `(n + 3) u` = `f32_sum_bound(n + 1)` leaves a rounding to spare.
/// Against `T` itself, quantization moves every entry (kept or dropped) by at most `s / 2`,
/// so the row moves by at most `s / 2 * sum_k L_k` over the row's non-zeros of `T`.
#[test]
fn quantized_gather_matches_the_f64_reference() {
    let plugin = PluginCompressor::load(&quantized_lib(), json!({})).unwrap();
    // Odd light seeds put a sun 10^6 times the sky into one texel (the stiff case).
    for seed in 0..4u64 {
        let t = random_transfer(12, 8, 4, 0.15, seed);
        let form = plugin.compress(&t, &CompressContext::default()).unwrap();
        let light = random_light(4, seed + 30);
        let got = plugin.gather(&form, &light).unwrap();
        let s = form.f32s("scale").unwrap()[0] as f64;
        for (r, (stored, terms)) in quantized_stored_product(&form, &light).into_iter().enumerate() {
            let bound = f32_sum_bound(terms + 1);
            let row_t = t.csr().outer_view(r).unwrap();
            for c in 0..3 {
                let stored = stored[c];
                let g = got.values()[r][c] as f64;
                assert!((g - stored).abs() <= bound * stored, "row {r} c{c}: {g} vs stored-matrix {stored}");
                let exact: f64 = row_t.iter().map(|(k, &v)| v as f64 * light.power[k][c] as f64).sum();
                let light_sum: f64 = row_t.iter().map(|(k, _)| light.power[k][c] as f64).sum();
                let q_bound = s / 2.0 * light_sum + bound * stored;
                assert!((g - exact).abs() <= q_bound, "row {r} c{c}: {g} vs T {exact} (bound {q_bound:e})");
            }
        }
    }
    // With the step 1/4 the visibility values {1/4, 1/2, 3/4, 1} are stored exactly.
    let plugin = PluginCompressor::load(&quantized_lib(), json!({ "scale": 0.25 })).unwrap();
    for seed in 0..3u64 {
        let t = random_transfer(10, 4, 4, 0.3, seed);
        let form = plugin.compress(&t, &CompressContext::default()).unwrap();
        assert!(form.lossless);
        // 3 bytes per non-zero, 4 per row pointer, 4 for the scale.
        assert_eq!(form.bytes(), 3 * t.nnz() as u64 + 4 * (t.rows() as u64 + 1) + 4);
        assert_lossless(&plugin, &form, &t, &random_light(4, seed + 1));
    }
}

#[test]
fn kernels_are_plain_data_the_host_checked() {
    let plugin = PluginCompressor::load(&quantized_lib(), json!({})).unwrap();
    let k = plugin.gpu_kernels();
    assert_eq!(k.kind, "plugin:quantized");
    assert_eq!(k.passes.len(), 1);
    assert_eq!(k.passes[0].entry_point, biscale_plugin::ROW_ENTRY);
    assert!(k.wgsl.contains("fn row_lstar") && k.wgsl.contains(biscale_plugin::ROW_PASS));
    assert_eq!(k.checks.len(), 5);
    // A form tampered with after compression is refused by the declared checks, before the
    // plugin's gather runs.
    let t = random_transfer(4, 2, 2, 0.5, 1);
    let form = plugin.compress(&t, &CompressContext::default()).unwrap();
    let light = random_light(2, 1);
    let tamper = |name: &str, f: &dyn Fn(&mut ArrayData)| {
        let mut bad: CompressedForm = form.clone();
        f(&mut bad.arrays.iter_mut().find(|a| a.name == name).unwrap().data);
        bad
    };
    let cases = [
        (
            tamper("row_ptr", &|d| {
                if let ArrayData::U32(v) = d {
                    v[1] = v[2] + 1
                }
            }),
            "decreases",
        ),
        (
            tamper("col_idx", &|d| {
                if let ArrayData::U16(v) = d {
                    v[0] = 24
                }
            }),
            "'col_idx' element 0 is 24",
        ),
        (
            tamper("codes", &|d| {
                if let ArrayData::U8(v) = d {
                    v.pop();
                }
            }),
            "'codes' has",
        ),
        (tamper("scale", &|d| *d = ArrayData::F32(vec![f32::INFINITY])), "'scale' element 0"),
        (tamper("col_idx", &|d| *d = ArrayData::U32(vec![0; 4])), "ptr"),
    ];
    for (bad, needle) in cases {
        let e = plugin.gather_plugin(&bad, &light).unwrap_err();
        assert!(matches!(e, PluginError::Invalid { .. }), "{e}");
        assert!(e.to_string().contains(needle), "{e} lacks {needle}");
        assert_names_file(&e, plugin.path());
    }
    let mut other = form.clone();
    other.kind = "sparse".into();
    assert_names_file(&plugin.gather(&other, &light).unwrap_err(), plugin.path());
    assert!(plugin.gather(&form, &random_light(4, 1)).is_err(), "light of the wrong size");
}

#[test]
fn bad_parameters_fail_at_load() {
    let lib = quantized_lib();
    for params in [json!({ "bogus": 1 }), json!({ "scale": -1.0 }), json!([1, 2])] {
        let e = PluginCompressor::load(&lib, params.clone()).unwrap_err();
        assert!(matches!(e, PluginError::Plugin { call: "biscale_plugin_kernels", .. }), "{params}: {e}");
        assert_names_file(&e, &lib);
    }
}

#[test]
fn a_relative_plugin_path_is_loaded_as_that_absolute_file() {
    // Regression (hostile input): a path without a folder went to dlopen as it was, which
    // searches LD_LIBRARY_PATH and the system folders for a library of that name.
    let lib = quantized_lib().canonicalize().unwrap();
    let cwd = std::env::current_dir().unwrap().canonicalize().unwrap();
    let common = cwd.ancestors().find(|a| lib.starts_with(a)).unwrap();
    let up = cwd.strip_prefix(common).unwrap().components().count();
    let rel = PathBuf::from("../".repeat(up)).join(lib.strip_prefix(common).unwrap());
    assert!(rel.is_relative());
    let plugin = PluginCompressor::load(&rel, json!({})).unwrap();
    assert_eq!(plugin.path(), lib);
}

#[test]
fn missing_or_non_library_files_are_load_errors() {
    let missing = scratch_dir().join("no-such-plugin.so");
    let e = PluginCompressor::load(&missing, json!({})).unwrap_err();
    assert!(matches!(e, PluginError::Load { .. }), "{e}");
    assert_names_file(&e, &missing);

    let text = scratch_dir().join("not-a-library.so");
    std::fs::write(&text, "this is not an ELF file").unwrap();
    let e = PluginCompressor::load(&text, json!({})).unwrap_err();
    assert!(matches!(e, PluginError::Load { .. }), "{e}");
    assert_names_file(&e, &text);
}

/// Compile a one-file cdylib with rustc (a real shared library without the plugin symbols).
fn tiny_cdylib(name: &str, source: &str) -> PathBuf {
    let dir = scratch_dir();
    let src = dir.join(format!("{name}.rs"));
    std::fs::write(&src, source).unwrap();
    let out = dir.join(format!("{}{name}{}", std::env::consts::DLL_PREFIX, std::env::consts::DLL_SUFFIX));
    let rustc = Path::new(env!("CARGO")).with_file_name("rustc");
    let rustc = if rustc.is_file() { rustc } else { PathBuf::from("rustc") };
    let status = std::process::Command::new(rustc)
        .args(["--crate-type", "cdylib", "--edition", "2021", "-o"])
        .arg(&out)
        .arg(&src)
        .status()
        .unwrap();
    assert!(status.success(), "rustc failed on {}", src.display());
    out
}

#[test]
fn libraries_without_the_plugin_symbols_are_refused() {
    let empty = tiny_cdylib("empty_lib", "#[no_mangle] pub extern \"C\" fn unrelated() -> u32 { 7 }\n");
    let e = PluginCompressor::load(&empty, json!({})).unwrap_err();
    assert!(matches!(&e, PluginError::MissingSymbol { symbol, .. } if symbol == "biscale_plugin_abi_version"), "{e}");
    assert_names_file(&e, &empty);

    // Passes the handshake, lacks everything after it.
    let half = tiny_cdylib(
        "handshake_only",
        "#[no_mangle] pub extern \"C\" fn biscale_plugin_abi_version() -> u32 { 1 << 16 }\n",
    );
    let e = PluginCompressor::load(&half, json!({})).unwrap_err();
    assert!(matches!(&e, PluginError::MissingSymbol { symbol, .. } if symbol == "biscale_plugin_abi_layout"), "{e}");
    assert_names_file(&e, &half);
}

#[test]
fn a_plugin_of_another_abi_major_is_refused_before_any_other_call() {
    // The faulty plugin built with `wrong_abi` claims 2.0 and aborts this process if the host
    // calls anything past the version (so passing proves the host stopped there). Built into a
    // target directory of its own so the normal faulty build is never replaced.
    let normal = faulty_lib();
    let dir = normal.parent().unwrap().parent().unwrap().join("plugin-wrong-abi");
    let lib = build_plugin("biscale-plugin-faulty", &["wrong_abi"], Some(&dir)).unwrap();
    let e = PluginCompressor::load(&lib, json!({ "fail": "none" })).unwrap_err();
    assert!(matches!(e, PluginError::AbiVersion { found, .. } if found == 2 << 16), "{e}");
    assert!(e.to_string().contains("ABI 2.0"), "{e}");
    assert_names_file(&e, &lib);
}

#[test]
fn plugin_errors_and_panics_are_errors_naming_the_file() {
    let lib = faulty_lib();
    let t = random_transfer(6, 2, 2, 0.4, 3);
    let light = random_light(2, 3);
    let ctx = CompressContext::default();

    // Sanity: without a fault the faulty plugin is a correct raw-CSR compressor.
    let ok = faulty("none").unwrap();
    let form = ok.compress(&t, &ctx).unwrap();
    assert_lossless(&ok, &form, &t, &light);

    let e = faulty("error").unwrap().compress_plugin(&t, &ctx).unwrap_err();
    assert!(matches!(&e, PluginError::Plugin { message, .. } if message.contains("failed on purpose")), "{e}");
    assert_names_file(&e, &lib);
    // Through the Compressor trait the message (and file) survive.
    assert_names_file(&faulty("error").unwrap().compress(&t, &ctx).unwrap_err(), &lib);

    let p = faulty("panic").unwrap();
    let e = p.compress_plugin(&t, &ctx).unwrap_err();
    assert!(matches!(&e, PluginError::Panic { message, .. } if message.contains("panicked on purpose")), "{e}");
    assert_names_file(&e, &lib);
    // The boundary survived the panic: the same library still works.
    assert_lossless(&ok, &ok.compress(&t, &ctx).unwrap(), &t, &light);

    let e = faulty("kernels_panic").unwrap_err();
    assert!(matches!(&e, PluginError::Panic { call: "biscale_plugin_kernels", .. }), "{e}");
    assert_names_file(&e, &lib);

    for (mode, needle) in [("bad_arrays", "row_ptr"), ("bad_name", "lstar")] {
        let e = faulty(mode).unwrap().compress_plugin(&t, &ctx).unwrap_err();
        assert!(matches!(&e, PluginError::Invalid { call: "biscale_plugin_compress", .. }), "{mode}: {e}");
        assert!(e.to_string().contains(needle), "{mode}: {e}");
        assert_names_file(&e, &lib);
    }

    for (mode, variant) in [("gather_error", "Plugin"), ("gather_panic", "Panic"), ("gather_nan", "Invalid")] {
        let p = faulty(mode).unwrap();
        let form = p.compress(&t, &ctx).unwrap();
        let e = p.gather_plugin(&form, &light).unwrap_err();
        assert!(format!("{e:?}").starts_with(variant), "{mode}: {e:?}");
        assert_names_file(&e, &lib);
    }
}

#[cfg(feature = "wgsl-check")]
#[test]
fn wgsl_that_does_not_compile_or_bind_is_caught_on_the_host() {
    let lib = faulty_lib();
    let e = faulty("bad_wgsl").unwrap_err();
    assert!(matches!(&e, PluginError::Wgsl { message, .. } if message.contains("undeclared_thing")), "{e}");
    assert_names_file(&e, &lib);

    // Compiles, but binds an array no form has: refused on the first form, before any GPU.
    let p = faulty("bad_binding").unwrap();
    let e = p.compress_plugin(&random_transfer(2, 2, 1, 0.5, 1), &CompressContext::default()).unwrap_err();
    assert!(e.to_string().contains("'not_in_form'"), "{e}");
    assert_names_file(&e, &lib);
}

#[test]
fn an_all_zero_transfer_and_a_black_light_give_zeros() {
    let plugin = PluginCompressor::load(&quantized_lib(), json!({})).unwrap();
    let t = random_transfer(3, 2, 2, 0.0, 0);
    let form = plugin.compress(&t, &CompressContext::default()).unwrap();
    assert!(form.lossless);
    let got = plugin.gather(&form, &random_light(2, 1)).unwrap();
    assert!(got.values().iter().all(|v| *v == [0.0; 3]));
    let t = random_transfer(3, 2, 2, 0.5, 0);
    let form = plugin.compress(&t, &CompressContext::default()).unwrap();
    let got = plugin.gather(&form, &LightVector::constant(LightBasis::cubemap(2).unwrap(), [0.0; 3])).unwrap();
    assert!(got.values().iter().all(|v| *v == [0.0; 3]));
}

/// Plugins in a child process (`isolate = true`): the same forms, `L*` and errors as in
/// process, and what no boundary in one process survives (a segfault, an abort, an `exit`, a
/// hang) as errors naming the library, the call and the cause, with the child reaped.
#[cfg(unix)]
mod isolated {
    use super::*;
    use biscale_compressors::plugin::{wire, IsolateOptions, IsolatedPlugin, CHILD_ENV};
    use std::io::Read;
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};

    /// The child executable of these tests (the `biscale` binary is its own).
    const HOST: &str = env!("CARGO_BIN_EXE_biscale-plugin-host");

    fn options(timeout_seconds: f64) -> IsolateOptions {
        IsolateOptions { host: Some(HOST.into()), timeout: Duration::from_secs_f64(timeout_seconds) }
    }

    fn isolated(lib: &Path, params: serde_json::Value) -> Result<IsolatedPlugin, PluginError> {
        IsolatedPlugin::spawn(lib, params, &options(60.0))
    }

    /// The process is gone and reaped: `kill(pid, 0)` still succeeds on a zombie, and fails
    /// with ESRCH only once the parent has waited for it.
    fn assert_reaped(pid: u32) {
        // SAFETY: signal 0 only asks whether the process exists.
        let r = unsafe { libc::kill(pid as libc::pid_t, 0) };
        let errno = std::io::Error::last_os_error().raw_os_error();
        assert!(r == -1 && errno == Some(libc::ESRCH), "child {pid} is still there (kill: {r}, errno {errno:?})");
    }

    /// Every field of two forms but the build time (the parent's includes the pipes).
    fn assert_same_form(a: &CompressedForm, b: &CompressedForm) {
        assert_eq!(
            (&a.kind, a.shape(), a.lossless, a.flops_per_gather),
            (&b.kind, b.shape(), b.lossless, b.flops_per_gather)
        );
        assert_eq!(a.meta, b.meta);
        assert_eq!(a.arrays.len(), b.arrays.len());
        for (x, y) in a.arrays.iter().zip(&b.arrays) {
            assert_eq!(x.name, y.name);
            let same = match (&x.data, &y.data) {
                (ArrayData::F32(p), ArrayData::F32(q)) => {
                    p.iter().map(|v| v.to_bits()).eq(q.iter().map(|v| v.to_bits()))
                }
                (p, q) => p == q,
            };
            assert!(same, "array '{}' differs", x.name);
        }
    }

    fn assert_same_lstar(a: &biscale_core::gather::LocalRadiance, b: &biscale_core::gather::LocalRadiance) {
        assert_eq!(a.values().len(), b.values().len());
        for (r, (x, y)) in a.values().iter().zip(b.values()).enumerate() {
            assert_eq!(x.map(f32::to_bits), y.map(f32::to_bits), "row {r}: {x:?} vs {y:?}");
        }
    }

    #[test]
    fn an_isolated_plugin_gives_the_in_process_forms_and_lstar_bit_for_bit() {
        let lib = quantized_lib();
        for params in [json!({}), json!({ "scale": 0.25 })] {
            let local = PluginCompressor::load(&lib, params.clone()).unwrap();
            let child = isolated(&lib, params.clone()).unwrap();
            assert_eq!((child.kind(), child.name(), child.path()), (local.kind(), local.name(), local.path()));
            assert_eq!(child.gpu_kernels(), local.gpu_kernels(), "the kernels crossed the pipe unchanged");
            assert_eq!(child.code_identity(), local.code_identity());
            assert_eq!(child.params()["isolate"], json!(true));
            assert_eq!(
                child
                    .stats(
                        &CompressedForm::new("x", random_transfer(1, 1, 1, 0.0, 0).shape()),
                        (&random_transfer(1, 1, 1, 0.0, 0)).into()
                    )
                    .unwrap()["isolated"],
                json!(true)
            );
            for (seed, (vertices, dirs, res, density)) in
                [(20, 4, 4, 0.2), (3, 8, 8, 0.05), (4, 2, 2, 0.0)].into_iter().enumerate()
            {
                let t = random_transfer(vertices, dirs, res, density, seed as u64);
                let ctx = CompressContext { seed: 5, progress: None, sweep: None };
                let (a, b) = (child.compress(&t, &ctx).unwrap(), local.compress(&t, &ctx).unwrap());
                assert_same_form(&a, &b);
                for light_seed in [seed as u64 + 10, seed as u64 + 11] {
                    let light = random_light(res, light_seed);
                    let want = local.gather(&b, &light).unwrap();
                    // The form the child holds (its own), then one it is sent (the in-process
                    // form, equal but not resident after the other compress below).
                    assert_same_lstar(&child.gather(&a, &light).unwrap(), &want);
                    assert_same_lstar(&child.gather(&b, &light).unwrap(), &want);
                }
            }
            // A form the child never made (gathered first with another form resident).
            let t = random_transfer(5, 4, 4, 0.3, 9);
            let f1 = local.compress(&t, &CompressContext::default()).unwrap();
            let f2 = local.compress(&random_transfer(5, 4, 4, 0.3, 10), &CompressContext::default()).unwrap();
            let light = random_light(4, 3);
            for f in [&f1, &f2, &f1] {
                assert_same_lstar(&child.gather(f, &light).unwrap(), &local.gather(f, &light).unwrap());
            }
        }
    }

    #[test]
    fn an_isolated_plugin_checks_forms_in_the_parent_before_any_gather() {
        let child = isolated(&quantized_lib(), json!({})).unwrap();
        let t = random_transfer(4, 2, 2, 0.5, 1);
        let mut bad = child.compress(&t, &CompressContext::default()).unwrap();
        if let Some(ArrayData::U16(v)) = bad.arrays.iter_mut().find(|a| a.name == "col_idx").map(|a| &mut a.data) {
            v[0] = 24;
        }
        let e = child.gather_plugin(&bad, &random_light(2, 1)).unwrap_err();
        assert!(matches!(e, PluginError::Invalid { call: "form check", .. }), "{e}");
        assert!(e.to_string().contains("'col_idx' element 0 is 24"), "{e}");
        assert_names_file(&e, child.path());
        // A refused form is no failure of the child: it serves on.
        let good = child.compress(&t, &CompressContext::default()).unwrap();
        child.gather(&good, &random_light(2, 1)).unwrap();
    }

    #[test]
    fn an_isolated_plugins_own_errors_are_the_in_process_errors_and_the_child_serves_on() {
        let lib = faulty_lib();
        let t = random_transfer(6, 2, 2, 0.4, 3);
        let light = random_light(2, 3);
        let ctx = CompressContext::default();
        for mode in ["error", "panic", "bad_arrays", "bad_name", "kernels_panic", "bad_wgsl"] {
            let local = faulty(mode).and_then(|p| p.compress_plugin(&t, &ctx)).unwrap_err();
            let child = isolated(&lib, json!({ "fail": mode })).and_then(|p| p.compress_plugin(&t, &ctx)).unwrap_err();
            assert_eq!(child.to_string(), local.to_string(), "{mode}");
            assert_eq!(format!("{child:?}"), format!("{local:?}"), "{mode}");
        }
        for mode in ["gather_error", "gather_panic", "gather_nan"] {
            let local = faulty(mode).unwrap();
            let form = local.compress(&t, &ctx).unwrap();
            let want = local.gather_plugin(&form, &light).unwrap_err().to_string();
            let child = isolated(&lib, json!({ "fail": mode })).unwrap();
            let form = child.compress(&t, &ctx).unwrap();
            // Twice: the plugin's error leaves the child serving.
            for _ in 0..2 {
                assert_eq!(child.gather_plugin(&form, &light).unwrap_err().to_string(), want, "{mode}");
            }
        }
        // The version handshake, in the child: refused before any other call there too.
        let dir = lib.parent().unwrap().parent().unwrap().join("plugin-wrong-abi");
        let wrong = build_plugin("biscale-plugin-faulty", &["wrong_abi"], Some(&dir)).unwrap();
        let e = isolated(&wrong, json!({ "fail": "none" })).unwrap_err();
        assert!(matches!(e, PluginError::AbiVersion { found, .. } if found == 2 << 16), "{e}");
        assert_names_file(&e, &wrong);
    }

    /// What one fatal fault (in the gather for `gather_*` modes, else in compress) must give:
    /// the error names the library and says `call` and `cause`; the child is reaped; later
    /// calls say the child is gone.
    fn assert_fatal(mode: &str, timeout_seconds: f64, call: &str, cause: &str) {
        let lib = faulty_lib().canonicalize().unwrap();
        let t = random_transfer(6, 2, 2, 0.4, 3);
        let light = random_light(2, 3);
        let ctx = CompressContext::default();
        let p = IsolatedPlugin::spawn(&lib, json!({ "fail": mode }), &options(timeout_seconds)).unwrap();
        let pid = p.child_id();
        let start = Instant::now();
        let e = match mode.starts_with("gather_") {
            false => p.compress_plugin(&t, &ctx).unwrap_err(),
            true => {
                let form = p.compress(&t, &ctx).unwrap();
                p.gather_plugin(&form, &light).unwrap_err()
            }
        };
        let seconds = start.elapsed().as_secs_f64();
        let s = e.to_string();
        assert!(s.starts_with(&format!("plugin {} ", lib.display())), "{mode}: {s}");
        assert!(s.contains(call) && s.contains(cause), "{mode}: {s} lacks '{call}' or '{cause}'");
        assert!(seconds < timeout_seconds + 5.0, "{mode}: the error took {seconds:.1} s");
        assert_reaped(pid);
        let again = p.compress_plugin(&t, &ctx).unwrap_err();
        assert!(matches!(again, PluginError::Gone { .. }), "{mode}: {again}");
        assert!(again.to_string().contains(cause), "{mode}: {again}");
        assert_names_file(&again, &lib);
    }

    #[test]
    fn crashes_and_exits_in_compress_or_gather_are_errors_naming_library_call_and_cause() {
        assert_fatal("segfault", 60.0, "crashed in compress", "killed by signal 11 (SIGSEGV)");
        assert_fatal("abort", 60.0, "crashed in compress", "(SIGABRT)");
        assert_fatal("exit", 60.0, "exited with status 0 during compress without answering", "status 0");
        assert_fatal("gather_segfault", 60.0, "crashed in gather", "(SIGSEGV)");
        assert_fatal("gather_abort", 60.0, "crashed in gather", "(SIGABRT)");
        assert_fatal("gather_exit", 60.0, "exited with status 0 during gather without answering", "status 0");
        let e = IsolatedPlugin::spawn(&faulty_lib(), json!({ "fail": "kernels_abort" }), &options(60.0)).unwrap_err();
        assert!(matches!(&e, PluginError::Crashed { call: "load", .. }), "{e}");
        assert!(e.to_string().contains("crashed in load: killed by signal 6 (SIGABRT)"), "{e}");
    }

    #[test]
    fn a_hang_in_compress_is_killed_after_its_timeout() {
        let start = Instant::now();
        assert_fatal("hang", 2.0, "compress", "did not answer compress within 2 s; killed");
        assert!(start.elapsed() >= Duration::from_secs(2), "killed before the timeout");
    }

    #[test]
    fn a_hang_in_gather_is_killed_after_its_timeout() {
        assert_fatal("gather_hang", 2.0, "gather", "did not answer gather within 2 s; killed");
    }

    #[test]
    fn what_a_plugin_prints_does_not_disturb_the_protocol() {
        let t = random_transfer(6, 2, 2, 0.4, 3);
        let light = random_light(2, 3);
        let ctx = CompressContext::default();
        let noisy = isolated(&faulty_lib(), json!({ "fail": "noisy" })).unwrap();
        let quiet = faulty("none").unwrap();
        let form = noisy.compress(&t, &ctx).unwrap();
        assert_same_lstar(
            &noisy.gather(&form, &light).unwrap(),
            &quiet.gather(&quiet.compress(&t, &ctx).unwrap(), &light).unwrap(),
        );
    }

    #[test]
    fn dropping_an_isolated_plugin_reaps_its_child() {
        let p = isolated(&quantized_lib(), json!({})).unwrap();
        let pid = p.child_id();
        // SAFETY: signal 0 only asks whether the process exists.
        assert_eq!(unsafe { libc::kill(pid as libc::pid_t, 0) }, 0, "the child runs while the plugin is held");
        drop(p);
        assert_reaped(pid);
    }

    #[test]
    fn a_child_whose_requests_close_exits_even_while_its_plugin_hangs() {
        // The parent dying closes the child's stdin; played here by hand, mid-compress.
        let mut child = Command::new(HOST)
            .env(CHILD_ENV, wire::PROTOCOL)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let (mut stdin, mut stdout) = (child.stdin.take().unwrap(), child.stdout.take().unwrap());
        let mut greeting = [0u8; 8];
        stdout.read_exact(&mut greeting).unwrap();
        assert_eq!(&greeting, wire::GREETING);
        let lib = faulty_lib().canonicalize().unwrap();
        wire::write_frame_bytes(&mut stdin, &wire::load_request(&lib, &json!({ "fail": "hang" })).encode()).unwrap();
        let loaded = wire::read_frame(&mut stdout, 1 << 26).unwrap().unwrap();
        assert_eq!(biscale_core::artifact::Artifact::decode(&loaded, Path::new("x")).unwrap().kind, "plugin-loaded");
        let t = random_transfer(3, 2, 2, 0.5, 1);
        wire::write_frame_bytes(&mut stdin, &wire::compress_request(&t, 0).unwrap().encode()).unwrap();
        std::thread::sleep(Duration::from_millis(300));
        assert!(child.try_wait().unwrap().is_none(), "the plugin hangs in compress");
        drop(stdin);
        let start = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if start.elapsed() > Duration::from_secs(10) {
                let _ = child.kill();
                panic!("the child outlived its requests by 10 s");
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        assert!(status.success(), "{status}");
    }

    #[test]
    fn an_executable_that_does_not_serve_the_protocol_is_refused() {
        let lib = quantized_lib();
        let with = |host: &str| {
            IsolatedPlugin::spawn(
                &lib,
                json!({}),
                &IsolateOptions { host: Some(host.into()), timeout: Duration::from_secs(20) },
            )
        };
        // Exits at once without a word.
        let e = with("true").unwrap_err();
        assert!(matches!(&e, PluginError::Host { call: "load", .. }), "{e}");
        assert!(e.to_string().contains("before greeting") && e.to_string().contains("serve_if_child"), "{e}");
        // Writes something else to its stdout, forever.
        let e = with("yes").unwrap_err();
        assert!(
            e.to_string().contains("does not serve the plugin protocol") && e.to_string().contains("killed"),
            "{e}"
        );
        let e = with("/no/such/host").unwrap_err();
        assert!(e.to_string().contains("cannot start it") && e.to_string().contains("/no/such/host"), "{e}");
        assert_names_file(&e, &lib.canonicalize().unwrap());
    }
}
