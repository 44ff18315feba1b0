//! NumPy interop end to end (`biscale export`, `biscale eval`, `python/biscale_io.py`) on
//! `configs/tests/interop.toml` (the coarse bunny, a Phong BTF with a view axis, one setting of
//! every built-in compressor and a traced reference; seconds per command).
//!
//! The Python round trip runs when the interpreter in `BISCALE_PYTHON` (else the repository's
//! `.venv/bin/python`, else `python3`) imports NumPy; with `BISCALE_REQUIRE_PYTHON=1` (CI,
//! `scripts/test.sh` installs NumPy into `.venv`) a missing NumPy fails the test instead.

use biscale::interop::npy::{self, ArrayRef, Elements, NpyArray, NpyData};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

const CONFIG: &str = "configs/tests/interop.toml";

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

fn biscale(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale")).args(args).current_dir(root()).output().expect("run biscale");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// Run biscale and insist that it succeeds.
fn ok(args: &[&str]) -> String {
    let (ok, stdout, err) = biscale(args);
    assert!(ok, "biscale {}:\n{err}", args.join(" "));
    stdout
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn npz(p: &Path) -> Vec<(String, NpyArray)> {
    npy::read_npz(p).unwrap_or_else(|e| panic!("{e}"))
}

fn member<'a>(arrays: &'a [(String, NpyArray)], name: &str) -> &'a NpyArray {
    &arrays.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no array '{name}'")).1
}

fn meta(arrays: &[(String, NpyArray)]) -> Value {
    match &member(arrays, biscale::interop::META).data {
        NpyData::Str(s) => serde_json::from_str(s).unwrap(),
        other => panic!("metadata is {other:?}"),
    }
}

fn f32s(a: &NpyArray) -> &[f32] {
    match &a.data {
        NpyData::F32(v) => v,
        other => panic!("not float32: {}", other.dtype_name()),
    }
}

#[test]
fn export_writes_every_kind_and_reads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("export"), dir.path().join("cache"));
    let stdout = ok(&["export", CONFIG, "--out", s(&out), "--cache-dir", s(&cache)]);
    for f in ["t.npz", "l.npz", "lstar.npz", "form-sparse.npz", "form-bicluster-b128.npz", "btf-phong.npz"] {
        assert!(stdout.contains(f), "{f}: {stdout}");
    }

    // The same stages in memory, without the cache: T traced again, forms compressed again.
    let exp = biscale::experiment::config::Experiment::load(&root().join(CONFIG)).unwrap();
    let geometry = biscale::stages::scene::load_geometry(&exp).unwrap();
    let lighting = biscale::stages::scene::load_lighting(&exp).unwrap();
    let t = biscale::stages::transfer::transfer_matrix(&exp, &geometry, None).unwrap();
    let matrix = t.whole("the test").unwrap();
    let csr = matrix.csr();

    let a = npz(&out.join("t.npz"));
    let names: Vec<&str> = a.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["indptr", "indices", "data", "shape", "__biscale__"]);
    let indptr: Vec<i64> = csr.indptr().raw_storage().iter().map(|&x| x as i64).collect();
    let indices: Vec<i32> = csr.indices().iter().map(|&x| x as i32).collect();
    assert_eq!(member(&a, "indptr").data, NpyData::I64(indptr));
    assert_eq!(member(&a, "indices").data, NpyData::I32(indices));
    assert_eq!(f32s(member(&a, "data")), csr.data());
    assert_eq!(member(&a, "shape").data, NpyData::I64(vec![1839 * 16, 384]));
    let m = meta(&a);
    assert_eq!(
        (m["what"].as_str(), m["version"].as_u64(), m["nnz"].as_u64()),
        (Some("t"), Some(1), Some(matrix.nnz() as u64))
    );
    let shape = &m["shape"];
    assert_eq!(
        (
            shape["vertices"].as_u64(),
            shape["local_dirs"].as_u64(),
            shape["local_basis"].as_str(),
            shape["light_basis"].as_str()
        ),
        (Some(1839), Some(16), Some("bins:4"), Some("cubemap:8")),
        "{m}"
    );

    let a = npz(&out.join("l.npz"));
    assert_eq!(member(&a, "l").shape, [384, 3]);
    assert_eq!(f32s(member(&a, "l")), lighting.light.power.as_flattened());
    let cube = lighting.light.cubemap().unwrap();
    assert_eq!(member(&a, "solid_angles").data, NpyData::F64(cube.solid_angles()));
    assert_eq!(meta(&a)["light_basis"], "cubemap:8");

    let a = npz(&out.join("lstar.npz"));
    let exact = biscale_core::gather::reference_product(matrix, &lighting.light);
    let lstar = biscale_core::gather::LocalRadiance::from_f64(matrix.local_basis(), 1839, &exact).unwrap();
    assert_eq!(member(&a, "lstar").shape, [1839 * 16, 3]);
    assert_eq!(f32s(member(&a, "lstar")), lstar.values().as_flattened());
    assert_eq!((meta(&a)["product"].as_str(), &meta(&a)["shape"]), (Some("paper"), shape));

    for setting in exp.compressor_settings() {
        let compressor = biscale::stages::transfer::build_compressor(setting).unwrap();
        let (form, _) = biscale::stages::transfer::compressed_form(
            setting,
            compressor.as_ref(),
            matrix,
            &t.key,
            (exp.file.seed, None),
            None,
        )
        .unwrap();
        let a = npz(&out.join(format!("form-{}.npz", setting.label)));
        assert_eq!(a.len(), form.arrays.len() + 1, "{}", setting.label);
        for (named, (name, array)) in form.arrays.iter().zip(&a) {
            assert_eq!(&named.name, name);
            let same = match (&named.data, &array.data) {
                (biscale_core::compress::ArrayData::U8(x), NpyData::U8(y)) => x == y,
                (biscale_core::compress::ArrayData::I8(x), NpyData::I8(y)) => x == y,
                (biscale_core::compress::ArrayData::U16(x), NpyData::U16(y)) => x == y,
                (biscale_core::compress::ArrayData::I16(x), NpyData::I16(y)) => x == y,
                (biscale_core::compress::ArrayData::U32(x), NpyData::U32(y)) => x == y,
                (biscale_core::compress::ArrayData::F32(x), NpyData::F32(y)) => x == y,
                _ => false,
            };
            assert!(same && array.shape == [named.data.len()], "{}: array {name}", setting.label);
        }
        let m = meta(&a);
        assert_eq!(
            (m["what"].as_str(), m["kind"].as_str(), m["label"].as_str()),
            (Some("form"), Some(form.kind.as_str()), Some(setting.label.as_str()))
        );
        assert_eq!(m["meta"], serde_json::to_value(&form.meta).unwrap(), "{}", setting.label);
        assert_eq!(
            (m["lossless"].as_bool(), m["flops_per_gather"].as_u64()),
            (Some(form.lossless), Some(form.flops_per_gather))
        );
        assert_eq!((&m["params"], &m["shape"]), (&setting.params, shape));
    }

    let a = npz(&out.join("btf-phong.npz"));
    let cfg = &exp.materials()[0];
    let (btf, _) = biscale::stages::materials::material_btf(cfg, matrix.local_basis(), None, "phong").unwrap();
    assert_eq!(member(&a, "data").shape, [1, 1, 9, 16, 3]);
    assert_eq!(f32s(member(&a, "data")), btf.data().as_flattened());
    assert_eq!(member(&a, "view_directions").shape, [9, 3]);
    let m = meta(&a);
    assert_eq!(
        (m["view_grid"].as_u64(), m["light_grid"].as_u64(), m["spatial"].clone()),
        (Some(3), Some(4), serde_json::json!([1, 1]))
    );

    // --format mtx is export-matrix's Matrix Market, byte for byte.
    let (mtx, em) = (dir.path().join("mtx"), dir.path().join("em"));
    ok(&["export", CONFIG, "--format", "mtx", "--out", s(&mtx), "--cache-dir", s(&cache)]);
    ok(&["export-matrix", CONFIG, "--out", s(&em), "--cache-dir", s(&cache)]);
    for f in ["T.mtx", "L.mtx"] {
        assert_eq!(std::fs::read(mtx.join(f)).unwrap(), std::fs::read(em.join(f)).unwrap(), "{f}");
    }
    // --what picks: only the BTF (no T is traced for it).
    let only = dir.path().join("only");
    ok(&["export", CONFIG, "--what", "btf", "--out", s(&only), "--no-cache"]);
    let files: Vec<_> = std::fs::read_dir(&only).unwrap().map(|e| e.unwrap().file_name()).collect();
    let files: Vec<_> = files.into_iter().filter(|f| f != ".biscale-run").collect();
    assert_eq!(files, ["btf-phong.npz"], "and the folder's marker, which lists it");
}

/// The interpreter with NumPy for the Python round trip, or `None` (skip) unless
/// `BISCALE_REQUIRE_PYTHON=1`, which makes its absence a failure.
fn python() -> Option<String> {
    let venv = root().join(".venv/bin/python");
    let py = std::env::var("BISCALE_PYTHON").ok().filter(|p| !p.is_empty()).unwrap_or_else(|| {
        if venv.is_file() {
            venv.display().to_string()
        } else {
            "python3".into()
        }
    });
    let has_numpy = Command::new(&py).args(["-c", "import numpy"]).output().is_ok_and(|o| o.status.success());
    match (has_numpy, std::env::var("BISCALE_REQUIRE_PYTHON").as_deref()) {
        (true, _) => Some(py),
        (false, Ok("1")) => panic!(
            "BISCALE_REQUIRE_PYTHON=1 but `{py} -c 'import numpy'` fails: run scripts/setup-python.sh --numpy-only \
             (scripts/test.sh does) or point BISCALE_PYTHON at an interpreter with NumPy"
        ),
        (false, _) => {
            eprintln!(
                "skipping the Python round trip: `{py}` cannot import numpy (scripts/setup-python.sh --numpy-only)"
            );
            None
        }
    }
}

/// `biscale eval` into `out`: its one record.
fn eval(input: &[&str], out: &Path, cache: &Path) -> Value {
    let mut args = vec!["eval", CONFIG];
    args.extend_from_slice(input);
    args.extend_from_slice(&["--out", s(out), "--cache-dir", s(cache)]);
    ok(&args);
    let m = read_json(&out.join("metrics.json"));
    assert_eq!(m["compressors"].as_array().map(Vec::len), Some(1), "{m}");
    for f in ["images/uncompressed.exr", "images/reference.exr", "images/mask.png", "metrics.csv"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    m["compressors"][0].clone()
}

#[test]
fn eval_reproduces_the_runs_own_numbers_and_the_python_round_trip() {
    let python = python();
    let dir = tempfile::tempdir().unwrap();
    let (run, exp, cache) = (dir.path().join("run"), dir.path().join("export"), dir.path().join("cache"));
    ok(&["run", CONFIG, "--out", s(&run), "--cache-dir", s(&cache)]);
    ok(&["export", CONFIG, "--out", s(&exp), "--cache-dir", s(&cache)]);
    let metrics = read_json(&run.join("metrics.json"));
    let run_reference = &metrics["reference"]["uncompressed_vs_reference"];
    assert!(run_reference.is_object(), "{metrics}");
    let run_record =
        |name: &str| metrics["compressors"].as_array().unwrap().iter().find(|c| c["name"] == name).cloned().unwrap();

    // The run's own uncompressed L*: no error against the uncompressed image, and against the
    // reference exactly the run's uncompressed figures.
    let own = |r: &Value| {
        let u = &r["image"]["vs_uncompressed"];
        assert_eq!(
            (u["rmse"].as_f64(), u["rel_l2"].as_f64(), u["ssim"].as_f64(), u["flip"].as_f64()),
            (Some(0.0), Some(0.0), Some(1.0), Some(0.0)),
            "{r}"
        );
        assert!(u["psnr"].is_null(), "{r}");
        assert_eq!(&r["image"]["vs_reference"], run_reference);
        assert!(r["rel_error_lstar"].as_f64().unwrap() < 1e-6, "{r}");
    };
    let r = eval(&["--lstar", s(&exp.join("lstar.npz"))], &dir.path().join("ev-lstar"), &cache);
    assert_eq!(
        (r["name"].as_str(), r["kind"].as_str(), r["params"]["dtype"].as_str()),
        (Some("lstar"), Some("lstar"), Some("float32"))
    );
    own(&r);

    // An exported form, gathered by its compressor: that setting's record, figure for figure.
    let same_as_run = |r: &Value, label: &str| {
        let want = run_record(label);
        for key in [
            "kind",
            "params",
            "lossless",
            "bytes",
            "bytes_by_array",
            "bytes_per_nnz",
            "flops_per_gather",
            "rel_error_lstar",
        ] {
            assert_eq!(r[key], want[key], "{label}: {key}");
        }
        // The statistics too, but the build time: eval built nothing (issue 36), so where the
        // statistics carry it (biclustering's Table I) it is 0, and so is the record's.
        let (mut stats, mut want_stats) = (r["stats"].clone(), want["stats"].clone());
        if let (Some(s), Some(w)) = (stats.as_object_mut(), want_stats.as_object_mut()) {
            assert_eq!(s.remove("build_seconds").and_then(|b| b.as_f64()), Some(0.0), "{label}");
            w.remove("build_seconds");
        }
        assert_eq!(stats, want_stats, "{label}: stats");
        assert_eq!(r["build_seconds"].as_f64(), Some(0.0), "{label}");
        for key in ["vs_uncompressed", "vs_reference"] {
            assert_eq!(r["image"][key], want["image"][key], "{label}: {key}");
        }
    };
    for label in ["sparse", "bicluster-b128"] {
        let r = eval(
            &["--form", s(&exp.join(format!("form-{label}.npz")))],
            &dir.path().join(format!("ev-{label}")),
            &cache,
        );
        assert_eq!(r["name"].as_str(), Some(label));
        same_as_run(&r, label);
    }

    let Some(py) = python else { return };
    let start = std::time::Instant::now();
    let out = Command::new(&py).arg("python/test_biscale_io.py").arg(&exp).current_dir(root()).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "python/test_biscale_io.py:\n{text}");
    assert!(text.contains("biscale_io round trip: ok"), "{text}");
    eprintln!("python round trip: {:.2} s", start.elapsed().as_secs_f64());
    let py_dir = exp.join("py");
    // Half the L*: half the L* error exactly, about half the image (silhouette pixels mix in
    // the unscaled background).
    let r = eval(&["--lstar", s(&py_dir.join("lstar_half.npz"))], &dir.path().join("ev-half"), &cache);
    assert!((r["rel_error_lstar"].as_f64().unwrap() - 0.5).abs() < 1e-6, "{r}");
    let image = r["image"]["vs_uncompressed"]["rel_l2"].as_f64().unwrap();
    assert!((0.4..=0.5 + 1e-6).contains(&image), "{r}");
    // The same L* as a bare float64 (V, M, 3) .npy: rounded to float32, the run's own.
    let r = eval(&["--lstar", s(&py_dir.join("lstar_same.npy"))], &dir.path().join("ev-same"), &cache);
    assert_eq!(r["params"]["dtype"].as_str(), Some("float64, rounded to float32"));
    own(&r);
    // Forms loaded and saved again by biscale_io gather to the run's figures.
    for label in ["sparse", "bicluster-b128"] {
        let path = py_dir.join(format!("form-{label}.npz"));
        let r = eval(&["--form", s(&path), "--name", "resaved"], &dir.path().join(format!("ev-py-{label}")), &cache);
        assert_eq!(r["name"].as_str(), Some("resaved"));
        same_as_run(&r, label);
    }
}

#[test]
fn bad_exports_and_inputs_are_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fails = |args: &[&str]| {
        let (ok, _, err) = biscale(args);
        assert!(!ok, "biscale {} succeeded", args.join(" "));
        assert!(!err.contains("panicked"), "{err}");
        err
    };
    let err = fails(&["export", CONFIG, "--what", "t,bogus", "--out", s(&d.join("x"))]);
    assert!(err.contains("--what: unknown item 'bogus' (known: t, l, lstar, forms, btf)"), "{err}");
    let err = fails(&["export", CONFIG, "--format", "mtx", "--what", "forms", "--out", s(&d.join("x"))]);
    assert!(err.contains("--format mtx writes t and l only"), "{err}");
    assert!(!d.join("x").exists());

    let out = d.join("never");
    let eval_err = |input: &[&str]| {
        let mut args = vec!["eval", CONFIG];
        args.extend_from_slice(input);
        args.extend_from_slice(&["--out", s(&out), "--no-cache"]);
        let err = fails(&args);
        assert!(!out.exists(), "a refused input made the output folder");
        err
    };
    let rows = 1839 * 16;
    let write = |name: &str, shape: &[usize], e: Elements<'_>| {
        let p = d.join(name);
        npy::write_npy(&p, &ArrayRef::new(shape, e)).unwrap();
        p
    };
    let p = write("short.npy", &[10, 3], Elements::F32(&[0.0; 30]));
    let err = eval_err(&["--lstar", s(&p)]);
    assert!(err.contains("short.npy") && err.contains("has shape (10, 3), this config's L* is (29424, 3)"), "{err}");
    let other_mesh = vec![0.0f32; 1000 * 16 * 3];
    let p = write("other.npy", &[1000 * 16, 3], Elements::F32(&other_mesh));
    let err = eval_err(&["--lstar", s(&p)]);
    assert!(err.contains("its 16000 rows are 1000 vertices of 16"), "{err}");
    let p = write("int.npy", &[rows, 3], Elements::I32(&vec![0; rows * 3]));
    let err = eval_err(&["--lstar", s(&p)]);
    assert!(err.contains("is int32; an L* must be float32 or float64"), "{err}");
    let mut nan = vec![0.0f32; rows * 3];
    nan[17 * 3 + 1] = f32::NAN;
    let p = write("nan.npy", &[rows, 3], Elements::F32(&nan));
    let err = eval_err(&["--lstar", s(&p)]);
    assert!(err.contains("row 17 (vertex 1, local direction 1), channel G is NaN"), "{err}");
    let p = d.join("two.npz");
    npy::write_npz(&p, &[("a", ArrayRef::flat(Elements::U8(&[1]))), ("b", ArrayRef::flat(Elements::U8(&[2])))])
        .unwrap();
    let err = eval_err(&["--lstar", s(&p)]);
    assert!(err.contains("has no array 'lstar' (arrays: a, b)"), "{err}");
    let ok_lstar = write("fine.npy", &[rows, 3], Elements::F32(&vec![0.0; rows * 3]));
    let err = eval_err(&["--lstar", s(&ok_lstar), "--name", "uncompressed"]);
    assert!(err.contains("the run's own images are called so"), "{err}");
    let err = eval_err(&["--lstar", s(&ok_lstar), "--form", s(&ok_lstar)]);
    assert!(err.contains("cannot be used with"), "{err}");

    let form = |name: &str, meta: Value| {
        let p = d.join(name);
        let text = meta.to_string();
        npy::write_npz(
            &p,
            &[("row_ptr", ArrayRef::flat(Elements::U32(&[0]))), (biscale::interop::META, ArrayRef::string(&text))],
        )
        .unwrap();
        p
    };
    let shape = |local: &str| serde_json::json!({"vertices": 1839, "local_basis": local, "light_basis": "cubemap:8"});
    let p = form("grid.npz", serde_json::json!({"what": "form", "kind": "sparse", "shape": shape("bins:8")}));
    let err = eval_err(&["--form", s(&p)]);
    assert!(
        err.contains(
            "grid.npz: was written for a local basis of 8x8 bins (bins:8), this config's T has 4x4 bins (bins:4)"
        ),
        "{err}"
    );
    let p =
        form("plugin.npz", serde_json::json!({"what": "form", "kind": "plugin:quantized", "shape": shape("bins:4")}));
    let err = eval_err(&["--form", s(&p)]);
    assert!(err.contains("a form of kind 'plugin:quantized': eval --form gathers built-in kinds only"), "{err}");
    let p = form("lstar-meta.npz", serde_json::json!({"what": "lstar", "shape": shape("bins:4")}));
    let err = eval_err(&["--form", s(&p)]);
    assert!(err.contains("holds a 'lstar' export, not a compressed form"), "{err}");
    let p = form("broken.npz", serde_json::json!({"what": "form", "kind": "sparse", "shape": shape("bins:4")}));
    let err = eval_err(&["--form", s(&p)]);
    assert!(err.contains("malformed sparse form"), "{err}");
}

/// Issue class "eval reports the statistics a form file claims" (issue 36): a form whose
/// metadata claims absurd flops and a negative build time is scored with the flops its arrays
/// give (the compressor's own count, which `export` wrote) and a build time of 0, for every
/// built-in kind; the claim is named in a warning. A form saved without either (as a Python
/// writer may) gets the same true count.
#[test]
fn eval_reports_a_forms_own_flops_not_the_flops_and_build_time_its_file_claims() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (exp, cache) = (d.join("export"), d.join("cache"));
    ok(&["export", CONFIG, "--what", "forms", "--out", s(&exp), "--cache-dir", s(&cache)]);
    let mut forms: Vec<PathBuf> =
        std::fs::read_dir(&exp).unwrap().map(|e| e.unwrap().path()).filter(|p| !p.ends_with(".biscale-run")).collect();
    forms.sort();
    assert_eq!(forms.len(), 4, "one form per built-in kind: {forms:?}");
    // `meta` rewritten: the arrays as they are, the metadata replaced.
    let rewrite = |from: &Path, to: &Path, edit: &dyn Fn(&mut serde_json::Map<String, Value>)| {
        let arrays = npz(from);
        let Value::Object(mut m) = meta(&arrays) else { panic!("metadata is not an object") };
        edit(&mut m);
        let text = Value::Object(m).to_string();
        let members: Vec<(&str, ArrayRef<'_>)> = arrays
            .iter()
            .map(|(n, a)| (n.as_str(), if n == biscale::interop::META { ArrayRef::string(&text) } else { a.as_ref() }))
            .collect();
        npy::write_npz(to, &members).unwrap();
    };
    for (i, form) in forms.iter().enumerate() {
        let truth = meta(&npz(form))["flops_per_gather"].as_u64().unwrap();
        assert!(truth > 0 && truth < 1 << 40, "{}: {truth}", form.display());
        let lying = d.join(format!("lying-{i}.npz"));
        rewrite(form, &lying, &|m| {
            m.insert("flops_per_gather".into(), Value::from(u64::MAX));
            m.insert("build_seconds".into(), Value::from(-5.0));
        });
        let out = d.join(format!("ev-lying-{i}"));
        let args = ["eval", CONFIG, "--form", s(&lying), "--out", s(&out), "--cache-dir", s(&cache)];
        let (success, _, err) = biscale(&args);
        assert!(success, "biscale {}:\n{err}", args.join(" "));
        let r = &read_json(&out.join("metrics.json"))["compressors"][0];
        assert_eq!(
            (r["flops_per_gather"].as_u64(), r["build_seconds"].as_f64()),
            (Some(truth), Some(0.0)),
            "{}: {r}",
            form.display()
        );
        let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
        assert!(!csv.contains(&u64::MAX.to_string()) && !csv.contains("-5e0"), "{csv}");
        assert!(err.contains(&format!("metadata flops_per_gather is {}", u64::MAX)), "{err}");
    }
    // No claim at all: the same count.
    let bare = d.join("bare.npz");
    rewrite(&forms[0], &bare, &|m| {
        m.remove("flops_per_gather");
        m.remove("build_seconds");
    });
    let r = eval(&["--form", s(&bare)], &d.join("ev-bare"), &cache);
    assert_eq!(r["flops_per_gather"].as_u64(), meta(&npz(&forms[0]))["flops_per_gather"].as_u64(), "{r}");
}
