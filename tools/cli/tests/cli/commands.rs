//! The `biscale` binary as a user meets it: help text, plan, export, diff, and errors that
//! name the file instead of panicking.

use std::path::{Path, PathBuf};
use std::process::Command;

fn biscale(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale")).args(args).current_dir(root()).output().expect("run biscale");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

#[test]
fn help_explains_every_command() {
    let (ok, out, _) = biscale(&["--help"]);
    assert!(ok);
    for cmd in ["run", "plan", "export-matrix", "diff", "viz", "generate"] {
        assert!(out.contains(cmd), "{out}");
    }
    let (ok, out, _) = biscale(&["run", "--help"]);
    assert!(ok && out.contains("--out") && out.contains("--no-cache"), "{out}");
}

#[test]
fn plan_lists_what_runs_and_what_is_left_out() {
    let (ok, out, err) = biscale(&["plan", "configs/smoke.toml"]);
    assert!(ok, "{err}");
    assert!(out.contains("run   transfer"), "{out}");
    assert!(out.contains("skip  reference") || out.contains("run   reference"), "{out}");
    assert!(out.contains("the light does not change"), "{out}");
    assert!(
        out.contains("run   compress   haar-t4") && out.contains("run   compress   haar-t8"),
        "sweep expanded: {out}"
    );
}

#[test]
fn plan_says_what_the_cache_holds_and_how_big_each_output_is() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let cache_arg = cache.to_str().unwrap();
    let outputs =
        ["transfer   T", "compress   sparse", "compress   bicluster", "compress   cpca", "compress   haar-t4"];
    let (ok, out, err) = biscale(&["plan", "configs/smoke.toml", "--cache-dir", cache_arg]);
    assert!(ok, "{err}");
    assert!(out.contains("(0 of 7 outputs cached, 0.0 MiB)"), "{out}");
    for o in outputs {
        assert!(out.contains(&format!("build {o}")), "{o}: {out}");
    }
    let run_out = dir.path().join("out");
    let (ok, _, err) =
        biscale(&["run", "-q", "configs/smoke.toml", "--cache-dir", cache_arg, "--out", run_out.to_str().unwrap()]);
    assert!(ok, "{err}");
    // The plan computes the keys the run wrote under: every output is now loaded, and its
    // size is its file's.
    let (ok, out, err) = biscale(&["plan", "configs/smoke.toml", "--cache-dir", cache_arg]);
    assert!(ok, "{err}");
    assert!(out.contains("(7 of 7 outputs cached"), "{out}");
    for o in outputs {
        let line = out.lines().find(|l| l.contains(&format!("load  {o}"))).unwrap_or_else(|| panic!("{o}: {out}"));
        let file = line.split_whitespace().last().unwrap();
        let bytes = std::fs::metadata(cache.join(file)).unwrap().len();
        let mib = format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64);
        assert!(line.contains(&mib), "{line}: {mib}");
    }
    let (ok, out, _) = biscale(&["plan", "configs/smoke.toml", "--no-cache"]);
    assert!(ok && out.contains("cache: off"), "{out}");
}

#[test]
fn bad_config_is_a_located_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("x.toml");
    std::fs::write(&cfg, "name = \"x\"\nbogus = 1\n").unwrap();
    let (ok, _, err) = biscale(&["plan", cfg.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("x.toml:2:1") && err.contains("unknown field `bogus`"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn export_matrix_writes_matrix_market_files_that_parse_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mtx");
    let (ok, stdout, err) =
        biscale(&["export-matrix", "-q", "configs/smoke.toml", "--out", out.to_str().unwrap(), "--no-cache"]);
    assert!(ok, "{err}");
    assert!(stdout.contains("T.mtx"), "{stdout}");
    // -q: no progress and no notes on stderr (this run has no warnings).
    assert!(err.is_empty(), "-q printed: {err}");
    let t = std::fs::read_to_string(out.join("T.mtx")).unwrap();
    let mut lines = t.lines().filter(|l| !l.starts_with('%'));
    assert!(t.starts_with("%%MatrixMarket matrix coordinate real general"));
    let dims: Vec<usize> = lines.next().unwrap().split_whitespace().map(|x| x.parse().unwrap()).collect();
    assert_eq!(&dims[..2], &[1839 * 16, 384]);
    let mut count = 0;
    for l in lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        let (r, c, v): (usize, usize, f32) = (f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].parse().unwrap());
        assert!(r >= 1 && r <= dims[0] && c >= 1 && c <= dims[1] && v > 0.0 && v <= 1.0);
        count += 1;
    }
    assert_eq!(count, dims[2]);
    let l = std::fs::read_to_string(out.join("L.mtx")).unwrap();
    assert!(l.starts_with("%%MatrixMarket matrix array real general"));
    let values: Vec<&str> = l.lines().filter(|l| !l.starts_with('%')).collect();
    assert_eq!(values[0], "384 3");
    assert_eq!(values.len(), 1 + 3 * 384);
    // mesh.obj: one unit normal per vertex, faces naming vertex and normal alike.
    let obj = std::fs::read_to_string(out.join("mesh.obj")).unwrap();
    let count = |tag: &str| obj.lines().filter(|l| l.starts_with(tag)).count();
    assert_eq!((count("v "), count("vn ")), (1839, 1839));
    for l in obj.lines().filter(|l| l.starts_with("vn ")) {
        let n: Vec<f64> = l.split_whitespace().skip(1).map(|x| x.parse().unwrap()).collect();
        assert!((n.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-5, "{l}");
    }
    for l in obj.lines().filter(|l| l.starts_with("f ")) {
        for corner in l.split_whitespace().skip(1) {
            let (v, n) = corner.split_once("//").unwrap();
            assert_eq!(v, n, "{l}");
            assert!((1..=1839).contains(&v.parse::<usize>().unwrap()), "{l}");
        }
    }
    let view: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("view.json")).unwrap()).unwrap();
    assert_eq!((view["camera"]["width"].as_u64(), view["camera"]["height"].as_u64()), (Some(96), Some(72)));
    assert!(Path::new(view["env_map"].as_str().unwrap()).exists(), "{view}");
    // irradiance.csv: one row per vertex, the paper's and the exact-cosine irradiance; an open
    // vertex's two values differ by the bin rule only (a few percent), never by a factor.
    let csv = std::fs::read_to_string(out.join("irradiance.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv.lines().skip(1).map(|l| l.split(',').map(|x| x.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 1839);
    let (paper, exact): (f64, f64) = (rows.iter().map(|r| r[1]).sum(), rows.iter().map(|r| r[4]).sum());
    assert!(paper > 0.0 && (exact / paper - 1.0).abs() < 0.1, "paper {paper}, exact cosine {exact}");
}

#[test]
fn diff_reports_known_errors_and_names_bad_files() {
    use biscale_core::scene::HdrImage;
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.exr");
    let b = dir.path().join("b.exr");
    HdrImage { width: 4, height: 2, pixels: vec![[1.0, 1.0, 1.0]; 8] }.write_exr(&a).unwrap();
    HdrImage { width: 4, height: 2, pixels: vec![[1.5, 1.0, 1.0]; 8] }.write_exr(&b).unwrap();
    let e = dir.path().join("e.png");
    let (ok, out, err) =
        biscale(&["diff", a.to_str().unwrap(), b.to_str().unwrap(), "--error-image", e.to_str().unwrap()]);
    assert!(ok, "{err}");
    // Every pixel differs by 0.5 in one of three channels: RMSE = sqrt(0.25 / 3).
    let rmse: f64 =
        out.lines().find(|l| l.starts_with("rmse")).unwrap().split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!((rmse - (0.25f64 / 3.0).sqrt()).abs() < 1e-6, "{out}");
    for key in ["ldr_psnr", "ssim", "flip"] {
        assert!(out.lines().any(|l| l.starts_with(key)), "{key} missing: {out}");
    }
    assert!(e.is_file());
    // Another size is resampled to the reference's, with a warning: 2x2 blocks of 1.0 give a.
    let big = dir.path().join("big.exr");
    HdrImage { width: 8, height: 4, pixels: vec![[1.0, 1.0, 1.0]; 32] }.write_exr(&big).unwrap();
    let (ok, json, err) = biscale(&["diff", big.to_str().unwrap(), a.to_str().unwrap(), "--json"]);
    assert!(ok && err.contains("warning: ") && err.contains("is 8x4, the reference"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!((v["rmse"].as_f64(), v["ssim"].as_f64(), v["pixels"].as_u64()), (Some(0.0), Some(1.0), Some(8)), "{v}");
    let (ok, _, err) = biscale(&["diff", a.to_str().unwrap(), "/nonexistent/x.exr"]);
    assert!(!ok && err.contains("/nonexistent/x.exr") && !err.contains("panicked"), "{err}");
}

/// Issue class "a single-file writer renames over whatever the path is": `generate --out` and
/// `diff --error-image` write a new file or their own, stream to standard output with `-`, and
/// refuse a user's file (unless --force), an input, a link, a FIFO and a device node (one this
/// test makes, where it may: never a system one), leaving each as it was.
#[test]
fn single_file_writers_never_replace_what_biscale_did_not_write() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let c = |s: &str| std::ffi::CString::new(s).unwrap();
    // SAFETY: NUL-terminated paths.
    assert_eq!(unsafe { libc::mkfifo(c(&p("fifo")).as_ptr(), 0o644) }, 0);
    let device = unsafe { libc::mknod(c(&p("null")).as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) } == 0;
    std::fs::write(p("mine.obj"), "my mesh\n").unwrap();
    std::os::unix::fs::symlink(p("mine.obj"), p("link.obj")).unwrap();

    // Streamed: the OBJ on standard output, the note on standard error.
    let (ok, out, err) = biscale(&["generate", "scene", "plane", "--out", "-"]);
    assert!(ok && out.starts_with("# written by biscale") && err.contains("standard output"), "{err}");
    assert_eq!(out.lines().filter(|l| l.starts_with("v ")).count(), 41 * 41);
    // A new file, then the same file again (its own); a user's file refused, then forced.
    for _ in 0..2 {
        let (ok, _, err) = biscale(&["generate", "scene", "plane", "--out", &p("plane.obj")]);
        assert!(ok, "{err}");
    }
    let (ok, _, err) = biscale(&["generate", "uv", &p("plane.obj"), "--out", &p("mine.obj")]);
    assert!(!ok && err.contains("mine.obj") && err.contains("--force") && !err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read_to_string(p("mine.obj")).unwrap(), "my mesh\n");
    let mut specials = vec![("link.obj", "a symbolic link"), ("fifo", "a FIFO")];
    if device {
        specials.push(("null", "a device node"));
    } else {
        eprintln!("note: mknod not permitted here; the device-node case runs where it is (CI runs as root)");
    }
    for (name, kind) in &specials {
        for force in [&[][..], &["--force"]] {
            let at = p(name);
            let args = [&["generate", "scene", "plane", "--out", &at][..], force].concat();
            let (ok, _, err) = biscale(&args);
            assert!(!ok && err.contains(&format!("is {kind}")), "{name}: {err}");
        }
    }
    assert_eq!(std::fs::read_to_string(p("mine.obj")).unwrap(), "my mesh\n");
    assert!(std::fs::symlink_metadata(p("link.obj")).unwrap().file_type().is_symlink());
    assert!(std::fs::symlink_metadata(p("fifo")).unwrap().file_type().is_fifo());
    assert!(!device || std::fs::symlink_metadata(p("null")).unwrap().file_type().is_char_device());
    let (ok, _, err) = biscale(&["generate", "uv", &p("plane.obj"), "--out", &p("mine.obj"), "--force"]);
    assert!(ok, "{err}");
    assert!(std::fs::read_to_string(p("mine.obj")).unwrap().starts_with("# written by biscale"));

    // diff: never over an input, even forced; the PNG streamed; its own PNG replaced.
    use biscale_core::scene::HdrImage;
    HdrImage { width: 4, height: 2, pixels: vec![[1.0; 3]; 8] }.write_exr(Path::new(&p("a.exr"))).unwrap();
    HdrImage { width: 4, height: 2, pixels: vec![[2.0; 3]; 8] }.write_exr(Path::new(&p("b.exr"))).unwrap();
    let a_bytes = std::fs::read(p("a.exr")).unwrap();
    let diff = |e: &str, force: bool| {
        let mut args = vec!["diff".to_string(), p("a.exr"), p("b.exr"), "--error-image".into(), e.into()];
        args.extend(force.then(|| "--force".to_string()));
        let out = Command::new(env!("CARGO_BIN_EXE_biscale")).args(&args).output().unwrap();
        (out.status.success(), out.stdout, String::from_utf8_lossy(&out.stderr).into_owned())
    };
    for force in [false, true] {
        let (ok, _, err) = diff(&p("a.exr"), force);
        assert!(!ok && err.contains("an input of this comparison"), "{err}");
    }
    assert_eq!(std::fs::read(p("a.exr")).unwrap(), a_bytes);
    let (ok, png, err) = diff("-", false);
    assert!(ok && png.starts_with(b"\x89PNG") && err.contains("rmse"), "{err}");
    for _ in 0..2 {
        let (ok, _, err) = diff(&p("e.png"), false);
        assert!(ok, "{err}");
    }
    assert_eq!(std::fs::read(p("e.png")).unwrap(), png);
    let (ok, _, err) = diff(&p("plane.obj"), false);
    assert!(!ok && err.contains("not a PNG image biscale wrote"), "{err}");
}

#[test]
fn viz_writes_the_structure_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("viz");
    let (ok, stdout, err) = biscale(&["viz", "configs/smoke.toml", "--out", out.to_str().unwrap(), "--count", "4"]);
    assert!(ok, "{err}");
    for f in [
        "sparsity_panels.png",
        "biclusters_panels.png",
        "bicluster_sizes.png",
        "values.png",
        "heat_gather_cost.png",
        "heat_nnz.png",
    ] {
        assert!(out.join(f).is_file(), "{f}: {stdout}");
    }
}

#[test]
fn errors_are_one_line_of_causes_without_a_backtrace() {
    // Regression: with RUST_BACKTRACE=1 set, a config typo printed anyhow's 40-line backtrace.
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("typo.toml");
    std::fs::write(&cfg, "name = \"t\"\n[scene]\nmesh = \"m.obj\"\n[transfer]\nlocal_grd = 8\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
        .args(["plan", cfg.to_str().unwrap()])
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("run biscale");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.starts_with("error: ") && err.contains("typo.toml:5:1") && err.contains("local_grd"), "{err}");
    assert!(!err.contains("Stack backtrace") && !err.contains("backtrace") && err.lines().count() <= 3, "{err}");
}

#[test]
fn an_isolated_plugin_that_crashes_fails_the_run_with_its_cause() {
    // A plugin that segfaults in compress, run in a child process (`isolate = true`): biscale
    // (its own child host) reports the library, the call and the signal, and exits non-zero.
    let lib = biscale_compressors::plugin::testing::build_plugin("biscale-plugin-faulty", &[], None).unwrap();
    let lib = lib.canonicalize().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("isolated.toml");
    std::fs::write(
        &cfg,
        format!(
            "name = \"isolated\"\n[scene]\nmesh = \"{}\"\n[scene.material]\nkind = \"lambertian\"\nalbedo = [0.8, 0.8, 0.8]\n\
             [lighting]\nconstant = [1, 1, 1]\n[transfer]\ncubemap_resolution = 4\nvisibility_resolution = 8\n\
             local_grid = 2\n[[compressors]]\nkind = \"plugin\"\npath = \"{}\"\nparams = {{ fail = \"segfault\" }}\n\
             isolate = true\ntimeout_seconds = 60\n[runtime]\nwidth = 32\nheight = 24\nrepeats = 1\n",
            root().join("assets/meshes/bunny.obj").display(),
            lib.display()
        ),
    )
    .unwrap();
    let out = dir.path().join("out");
    let (ok, _, err) = biscale(&["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-cache"]);
    assert!(!ok, "a run whose plugin crashed exited 0:\n{err}");
    let want = format!("plugin {} crashed in compress: killed by signal 11 (SIGSEGV)", lib.display());
    assert!(err.contains(&want), "stderr lacks '{want}':\n{err}");
    assert!(err.contains("compressor plugin-biscale_plugin_faulty-isolated: "), "the setting is named:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.join("metrics.json").exists(), "a failed run wrote metrics");
}

#[test]
fn every_run_records_how_it_was_made() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let cfg = root().join("configs/smoke.toml");
    let args = ["--threads", "1", "run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()];
    let (ok, _, err) = biscale(&[&args[..], &["--cache-dir", cache.to_str().unwrap()]].concat());
    assert!(ok, "{err}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["schema_version"], 2);
    let r = &m["run"];
    assert_eq!(r["threads"], 1, "--threads");
    assert_eq!(r["config_text"], std::fs::read_to_string(&cfg).unwrap());
    assert_eq!(r["seed"], 7);
    assert_eq!(r["biscale_version"], env!("CARGO_PKG_VERSION"));
    assert!(r["command"].as_array().unwrap().iter().any(|a| a == "--threads"));
    assert!(r["rustc"].as_str().unwrap().starts_with("rustc "), "{}", r["rustc"]);
    let stages: Vec<&str> = r["stages"].as_array().unwrap().iter().map(|s| s["stage"].as_str().unwrap()).collect();
    for want in ["geometry", "transfer", "uncompressed baseline", "reference", "compressor bicluster"] {
        assert!(stages.contains(&want), "{stages:?}");
    }
    let sum: f64 = r["stages"].as_array().unwrap().iter().map(|s| s["wall_seconds"].as_f64().unwrap()).sum();
    assert!(sum <= r["wall_seconds"].as_f64().unwrap(), "stages {sum} s > run {}", r["wall_seconds"]);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("Run: biscale ") && report.contains("| compressor bicluster |"), "{report}");

    // One error scale for every compressor; the lossless ones sit far below it; every error
    // figure carries its colour bar (under the 96x72 picture, magnified 4x to fill the bar's
    // 300 pixels).
    let cs = m["compressors"].as_array().unwrap();
    let scale = cs[0]["image"]["error_scale"].as_f64().unwrap();
    assert!(scale > 0.0 && cs.iter().all(|c| c["image"]["error_scale"].as_f64() == Some(scale)), "{cs:?}");
    let lossy_max = cs.iter().filter(|c| c["lossless"] == false).map(|c| c["image"]["error_max"].as_f64().unwrap());
    assert!(lossy_max.fold(0.0, f64::max) >= scale, "the shared scale is a lossy setting's 99th percentile");
    for c in cs.iter().filter(|c| c["lossless"] == true) {
        assert!(c["image"]["error_max"].as_f64().unwrap() < 1e-3 * scale, "{c}");
    }
    let figure = image::open(out.join(cs[0]["image"]["error_png"].as_str().unwrap())).unwrap();
    assert_eq!((figure.width(), figure.height()), (4 * 96, 4 * 72 + biscale::plots::colour_bar_height(4 * 96)));
    assert!(report.contains("one colour scale, full scale"), "{report}");

    // metrics.csv: one row per setting, the same numbers as metrics.json.
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header, biscale::metrics::CSV_COLUMNS);
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), cs.len());
    for (row, c) in rows.iter().zip(cs) {
        assert_eq!(row[col("setting")], c["name"].as_str().unwrap());
        assert_eq!(row[col("bytes")].parse::<u64>().unwrap(), c["bytes"].as_u64().unwrap());
        // serde_json's float parser (without its float_roundtrip feature) may be an ulp off.
        let same = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs();
        let e: f64 = row[col("rel_error_lstar")].parse().unwrap();
        assert!(same(e, c["rel_error_lstar"].as_f64().unwrap()), "{row:?}");
        let r: f64 = row[col("image_rel_l2_vs_reference")].parse().unwrap();
        assert!(same(r, c["image"]["vs_reference"]["rel_l2"].as_f64().unwrap()), "{row:?}");
        for (column, key) in
            [("image_ssim_vs_reference", "vs_reference"), ("image_ssim_vs_uncompressed", "vs_uncompressed")]
        {
            let x: f64 = row[col(column)].parse().unwrap();
            assert!(same(x, c["image"][key]["ssim"].as_f64().unwrap()), "{column}: {row:?}");
        }
        let f: f64 = row[col("image_flip_vs_reference")].parse().unwrap();
        assert!(same(f, c["image"]["vs_reference"]["flip"].as_f64().unwrap()), "{row:?}");
        // Lossless settings are equal after the tone map: +inf in the CSV, null in JSON.
        let l = row[col("image_ldr_psnr_vs_uncompressed")];
        match c["image"]["vs_uncompressed"]["ldr_psnr"].as_f64() {
            Some(want) => assert!(same(l.parse().unwrap(), want), "{row:?}"),
            None => assert_eq!(l, "inf", "{row:?}"),
        }
        assert_eq!(row[col("gpu_gather_ms")], "", "a CPU run has no GPU column");
    }

    // `diff` with the run's mask gives the report's own numbers; without it the background
    // counts too (the report and `diff` used to disagree on the same pair).
    let img = |name: &str| out.join("images").join(name).to_str().unwrap().to_string();
    let record = m["compressors"].as_array().unwrap().iter().find(|c| c["name"] == "cpca-k4-c2").unwrap();
    let pair = [img("cpca-k4-c2.exr"), img("uncompressed.exr")];
    let mask = img("mask.png");
    let (ok, json, err) = biscale(&["diff", &pair[0], &pair[1], "--mask", &mask, "--json"]);
    assert!(ok, "{err}");
    let masked: serde_json::Value = serde_json::from_str(&json).unwrap();
    for key in ["rmse", "psnr", "rel_l2", "ldr_psnr", "ssim", "flip"] {
        let (got, want) = (masked[key].as_f64().unwrap(), record["image"]["vs_uncompressed"][key].as_f64().unwrap());
        assert!((got - want).abs() <= 1e-12 * want.abs(), "{key}: diff {got}, report {want}");
    }
    let (ok, json, err) = biscale(&["diff", &pair[0], &pair[1], "--json"]);
    assert!(ok, "{err}");
    let all: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(all["pixels"], 96 * 72);
    assert!(masked["pixels"].as_u64().unwrap() < 96 * 72 && masked["pixels"].as_u64().unwrap() > 1000, "{masked}");
    // The reference's mask is at the reference's resolution: refused for these images.
    let (ok, _, err) = biscale(&["diff", &pair[0], &pair[1], "--mask", &img("reference_mask.png")]);
    assert!(!ok && err.contains("the mask is 48x36, the images 96x72"), "{err}");
    let (ok, _, err) = biscale(&["--threads", "0", "plan", cfg.to_str().unwrap()]);
    assert!(!ok && err.contains("--threads must be at least 1"), "{err}");
}

/// report.html prints every table as an HTML `<table>` from the model report.md prints (no
/// Markdown table left in a `<pre>`, as one was), section for section; the comparison section
/// has one row per image with its thumbnail, errors and inset; every plot has an SVG twin.
#[test]
fn report_html_tables_are_tables_and_every_plot_has_an_svg_twin() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let args =
        ["run", "-v", "configs/smoke.toml", "--out", out.to_str().unwrap(), "--cache-dir", cache.to_str().unwrap()];
    let (ok, _, err) = biscale(&args);
    assert!(ok, "{err}");
    // -v adds each stage's wall time as it ends.
    assert!(err.contains("stage transfer: ") && err.contains("stage reference: "), "{err}");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    // No Markdown table inside a <pre>.
    for pre in html.split("<pre>").skip(1).map(|p| p.split("</pre>").next().unwrap()) {
        let table = pre.lines().any(|l| l.trim_start().starts_with('|') && l.contains("|---"));
        assert!(!table, "a Markdown table in a <pre>:\n{pre}");
    }
    assert!(!html.contains("|---|"), "Markdown table syntax in report.html");
    // The same sections in the same order, each with at least as many <table>s as report.md
    // has pipe tables there.
    let md_sections: Vec<(&str, usize)> = md
        .split("\n## ")
        .skip(1)
        .map(|s| {
            let (title, body) = s.split_once('\n').unwrap();
            (title.trim(), body.lines().filter(|l| l.starts_with("|---")).count())
        })
        .collect();
    let html_sections: Vec<(String, usize)> = html
        .split("<h2")
        .skip(1)
        .map(|s| {
            let title = s.split_once('>').unwrap().1.split("</h2>").next().unwrap().to_string();
            (title, s.matches("<table").count())
        })
        .collect();
    let titles = |v: &[(String, usize)]| v.iter().map(|(t, _)| t.clone()).collect::<Vec<_>>();
    let md_titles: Vec<String> = md_sections.iter().map(|(t, _)| t.to_string()).collect();
    assert_eq!(titles(&html_sections), md_titles);
    for ((title, md_tables), (_, html_tables)) in md_sections.iter().zip(&html_sections) {
        assert!(html_tables >= md_tables, "{title}: {md_tables} tables in report.md, {html_tables} in report.html");
    }
    for want in ["Transfer matrix", "Compressors", "Equal storage", "Equal quality", "Comparison"] {
        let n = html_sections.iter().find(|(t, _)| t == want).map_or(0, |s| s.1);
        assert!(n >= 1, "no <table> in section {want}");
    }
    // The comparison: one row per image (uncompressed, five settings, the ground truth), each
    // with its thumbnail (the region marked in red) and inset; all insets but the ground
    // truth's (traced at half the resolution) the same size.
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let f = &m["figures"];
    let inset: Vec<u64> = f["inset"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert_eq!(&inset[2..], &[9, 9], "an eighth of the 72-pixel side");
    assert!(f["inset_from"].as_str().unwrap().contains("haar-t4"), "the worst lossy setting: {f}");
    let rows = f["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["uncompressed", "sparse", "bicluster", "cpca-k4-c2", "haar-t4", "haar-t8", "reference"]);
    let comparison = md.split("\n## Comparison").nth(1).unwrap().split("\n## ").next().unwrap();
    assert_eq!(comparison.lines().filter(|l| l.starts_with("| ")).count(), 1 + rows.len(), "{comparison}");
    let magnification = f["inset_magnification"].as_u64().unwrap() as u32;
    for r in rows {
        let inset = image::open(out.join(r["inset"].as_str().unwrap())).unwrap();
        if r["name"] != "reference" {
            assert_eq!((inset.width(), inset.height()), (9 * magnification, 9 * magnification), "{r}");
            assert!(r["error_vs_reference_png"].is_string(), "{r}");
        }
        let thumb = image::open(out.join(r["thumbnail"].as_str().unwrap())).unwrap().to_rgb8();
        assert!(thumb.width() >= 300, "{r}");
        assert!(thumb.pixels().any(|p| p.0 == biscale::inset::MARK.0), "no marked region: {r}");
        for key in ["inset", "thumbnail"] {
            assert!(md.contains(r[key].as_str().unwrap()), "report.md lacks {}", r[key]);
        }
    }
    // Every plot has an SVG twin that parses, and the page links to it.
    let plots: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert_eq!(plots.len(), 2, "{plots:?}");
    for png in plots {
        let svg = std::fs::read_to_string(png.with_extension("svg")).unwrap();
        assert!(svg.starts_with("<svg"), "{}", png.display());
        biscale::plots::xml_tags_balance(&svg).unwrap_or_else(|e| panic!("{}: {e}", png.display()));
        let name = png.with_extension("svg").file_name().unwrap().to_str().unwrap().to_string();
        assert!(html.contains(&format!("href=\"{name}\"")) && md.contains(&format!("]({name})")), "{name}");
    }
}

#[test]
fn every_command_shares_one_default_cache_that_cache_lists_and_cleans() {
    let dir = tempfile::tempdir().unwrap();
    let xdg = dir.path().join("xdg");
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
            .args(args)
            .current_dir(root())
            .env("XDG_CACHE_HOME", &xdg)
            .output()
            .unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "{args:?}: {text}");
        text
    };
    let out = dir.path().join("out");
    run(&["run", "configs/smoke.toml", "--out", out.to_str().unwrap()]);
    let cache = xdg.join("biscale");
    let listed = run(&["cache", "list"]);
    assert!(listed.starts_with(&format!("{}: 7 files", cache.display())), "{listed}");
    assert!(listed.contains("transfer ") && listed.contains("of the mesh of 1839 vertices"), "{listed}");
    // Another command finds T there (the cache is shared, not beside each output folder).
    let export = run(&["export-matrix", "configs/smoke.toml", "--out", dir.path().join("mtx").to_str().unwrap()]);
    assert!(export.contains("transfer: loaded from cache"), "{export}");
    let cleaned = run(&["cache", "clean", "--kind", "form"]);
    assert!(cleaned.contains("removed 5 files"), "{cleaned}");
    assert!(run(&["cache", "list"]).starts_with(&format!("{}: 2 files", cache.display())));
    run(&["cache", "clean"]);
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 0);
}

/// `[runtime] light_moments = true` on the smoke config: every form's `L*` matches the
/// per-texel-cosine product, the paper's image is kept beside the moments' one, and against
/// the (exact-cosine) reference the moments' uncompressed image is the closer of the two.
#[test]
fn light_moments_are_measured_side_by_side_with_the_papers_cosine() {
    let dir = tempfile::tempdir().unwrap();
    let assets = root().join("assets");
    let text = std::fs::read_to_string(root().join("configs/smoke.toml"))
        .unwrap()
        .replace("../assets", assets.to_str().unwrap())
        .replace("repeats = 1", "repeats = 1\nlight_moments = true");
    let cfg = dir.path().join("moments.toml");
    std::fs::write(&cfg, text).unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let (ok, _, err) = biscale(&[
        "run",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let u = &m["uncompressed"];
    assert_eq!(u["light_moments"], true);
    // At 4x4 bins the outer ring's mean cosine is far from its texels' own: the pictures differ.
    let change = u["paper_vs_moments"]["rel_l2"].as_f64().unwrap();
    assert!(change > 1e-3, "the moments changed nothing: {change}");
    let r = &m["reference"];
    let (moments, paper) = (
        r["uncompressed_vs_reference"]["rel_l2"].as_f64().unwrap(),
        r["uncompressed_paper_vs_reference"]["rel_l2"].as_f64().unwrap(),
    );
    assert!(moments < paper, "against the ground truth: moments {moments}, paper {paper}");
    // Lossless forms gathered through the moments agree with the f64 per-texel product to f32
    // rounding (every term of a traced T is positive: its texels lie above the horizon).
    let sparse = m["compressors"].as_array().unwrap().iter().find(|c| c["kind"] == "sparse").unwrap();
    let e = sparse["rel_error_lstar"].as_f64().unwrap();
    assert!(e < 1e-6, "sparse rel. error of L* {e}");
    assert!(out.join("images/uncompressed_paper.png").exists());
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("Cosine rule: light moments"), "{report}");
}

/// `runtime.moments_resolve = "pixel"` on the smoke bunny with moments: every form's `L*` (and
/// so its `L*` error) is the per-vertex one, while the images resolve the three moment gathers
/// at each pixel, which on this coarse mesh is closer to the reference than the per-vertex
/// blend; an `L*` file cannot be scored that way and is refused before any work. The ground
/// truth takes each cubemap texel's light from its centre, so the moments here do too
/// (`lighting.texel_directions = "centre"`, the default): like against like. With `"mean"`
/// the record says so and the image moves (checked against Mitsuba, whose light is the map
/// itself, by scripts/texel-directions-study.sh; the rule's own tests are in core).
#[test]
fn moments_resolved_per_pixel_are_closer_to_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let run_with = |out: &Path, resolve: &str, directions: &str| {
        let (ok, _, err) = biscale(&[
            "run",
            "configs/smoke.toml",
            "--set",
            "runtime.light_moments=true",
            "--set",
            &format!("lighting.texel_directions=\"{directions}\""),
            "--set",
            &format!("runtime.moments_resolve=\"{resolve}\""),
            "--set",
            "compressors=[{kind=\"sparse\"}, {kind=\"haar\", terms=[8]}]",
            "--out",
            out.to_str().unwrap(),
            "--cache-dir",
            cache.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap()
    };
    let run = |out: &Path, resolve: &str| run_with(out, resolve, "centre");
    let (vertex, pixel) = (run(&dir.path().join("v"), "vertex"), run(&dir.path().join("p"), "pixel"));
    let vs_ref = |m: &serde_json::Value| m["reference"]["uncompressed_vs_reference"]["rel_l2"].as_f64().unwrap();
    let (v, p) = (vs_ref(&vertex), vs_ref(&pixel));
    assert!(p < v, "against the reference: per pixel {p}, per vertex {v}");
    // The record and the report say which resolve made the images.
    assert_eq!(vertex["uncompressed"]["moments_resolve"], "vertex");
    assert_eq!(pixel["uncompressed"]["moments_resolve"], "pixel");
    assert_eq!(pixel["lighting"]["texel_directions"], "centre");
    let mean = run_with(&dir.path().join("m"), "pixel", "mean");
    assert_eq!(mean["lighting"]["texel_directions"], "mean");
    assert_ne!(vs_ref(&mean), vs_ref(&pixel), "the mean directions move the image");
    let report = std::fs::read_to_string(dir.path().join("m/report.md")).unwrap();
    assert!(report.contains("power-weighted mean direction"), "{report}");
    let report = std::fs::read_to_string(dir.path().join("p/report.md")).unwrap();
    assert!(report.contains("Resolved per pixel"), "{report}");
    for (a, b) in vertex["compressors"].as_array().unwrap().iter().zip(pixel["compressors"].as_array().unwrap()) {
        assert_eq!(a["rel_error_lstar"], b["rel_error_lstar"], "{}: the same L*", a["name"]);
    }
    // The analytic resolve of the smoke's Lambertian material: `sum_j f (n . D_j)` with a
    // constant `f` is what the tables' resolve gives too (the bins' redistribution of each
    // bin's exact-cosine light is undone by their mean cosines), except in bins whose mean
    // light comes from below the pixel's interpolated horizon (near silhouettes), which the
    // analytic BRDF zeroes and the tables take at their net `n . D`. Measured 0.01176 against
    // 0.01294 from the reference: no further from it than the tables (5% slack), and not
    // suspiciously far below (a lost cosine or frame moves it by far more than half). The
    // record and the report name the resolve.
    let analytic = run(&dir.path().join("a"), "pixel_analytic");
    assert_eq!(analytic["uncompressed"]["moments_resolve"], "pixel_analytic");
    let a = vs_ref(&analytic);
    assert!(a < 1.05 * p && a > 0.5 * p, "against the reference: analytic {a}, tables {p}");
    let report = std::fs::read_to_string(dir.path().join("a/report.md")).unwrap();
    assert!(report.contains("Resolved per pixel with the analytic BRDF"), "{report}");
    let sparse = &pixel["compressors"][0];
    let e = sparse["image"]["vs_uncompressed"]["rel_l2"].as_f64().unwrap();
    assert!(e < 1e-5, "the raw form's per-pixel image is the uncompressed one to rounding: {e}");
    let haar = &pixel["compressors"][1];
    assert!(haar["image"]["vs_uncompressed"]["rel_l2"].as_f64().unwrap() > 1e-3, "a lossy form differs");
    // An L* file holds no moments to resolve.
    let lstar = dir.path().join("lstar");
    let (ok, _, err) = biscale(&["export", "configs/smoke.toml", "--what", "lstar", "--out", lstar.to_str().unwrap()]);
    assert!(ok, "{err}");
    let (ok, _, err) = biscale(&[
        "eval",
        "configs/smoke.toml",
        "--set",
        "runtime.light_moments=true",
        "--set",
        "runtime.moments_resolve=\"pixel\"",
        "--lstar",
        lstar.join("lstar.npz").to_str().unwrap(),
        "--out",
        dir.path().join("e").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("moments_resolve = \"pixel\" shades the three moment gathers"), "{err}");
    assert!(!dir.path().join("e").exists());
}

/// Every file under `dir` by relative path with its bytes, the run marker left out.
fn files_of(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut std::collections::BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(base, &p, out);
            } else if e.file_name() != ".biscale-run" {
                out.insert(p.strip_prefix(base).unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = Default::default();
    walk(dir, dir, &mut out);
    out
}

/// `biscale report` re-renders a finished run's plots, report.md and report.html from its
/// metrics.json and plan.txt alone, byte for byte what the run wrote (in place and into
/// `--out`); several runs go side by side into one page; a file that is not a run's
/// metrics.json is a located error.
#[test]
fn report_rerenders_a_finished_run_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (cache, run) = (dir.path().join("cache"), dir.path().join("run"));
    let (ok, _, err) = biscale(&["run", "-q", "configs/smoke.toml", "--cache-dir", &s(&cache), "--out", &s(&run)]);
    assert!(ok, "{err}");
    let written = files_of(&run);
    for f in ["report.md", "report.html", "error_vs_storage.png", "error_vs_storage.svg", "error_vs_time.png"] {
        assert!(written.contains_key(f), "{f}");
    }
    // Remove what is re-rendered, so the test sees it written again, not left.
    for f in ["report.md", "report.html", "error_vs_storage.png", "error_vs_time.svg"] {
        std::fs::remove_file(run.join(f)).unwrap();
    }
    let (ok, out, err) = biscale(&["report", &s(&run.join("metrics.json"))]);
    assert!(ok && out.contains("report.html"), "{err}");
    let again = files_of(&run);
    assert_eq!(again.keys().collect::<Vec<_>>(), written.keys().collect::<Vec<_>>());
    for (name, bytes) in &written {
        assert!(&again[name] == bytes, "{name} differs from what the run wrote");
    }
    // The re-rendered folder is still provably biscale's: a run may replace it.
    let copy = dir.path().join("copy");
    let (ok, _, err) = biscale(&["report", &s(&run), "--out", &s(&copy)]);
    assert!(ok, "{err}");
    assert!(files_of(&copy) == written, "--out holds the run's files and the same documents");

    let both = dir.path().join("both");
    let (ok, _, err) = biscale(&["report", &s(&run), &s(&copy)]);
    assert!(!ok && err.contains("--out"), "{err}");
    let (ok, _, err) = biscale(&["report", &s(&run), &s(&copy), "--out", &s(&both)]);
    assert!(ok, "{err}");
    let md = std::fs::read_to_string(both.join("report.md")).unwrap();
    assert!(md.contains("2 runs side by side"), "{md}");
    for (label, setting) in [("run", "bicluster"), ("copy", "bicluster"), ("run", "haar-t8"), ("copy", "haar-t8")] {
        assert!(md.contains(&format!("| {label} | {setting} |")), "{label} {setting}: {md}");
    }
    assert!(both.join("error_vs_storage.png").is_file() && both.join("report.html").is_file());

    // Not a run's metrics.json: the file and the reason.
    std::fs::write(dir.path().join("other.json"), "{\"experiment\": 3}").unwrap();
    let (ok, _, err) = biscale(&["report", &s(&dir.path().join("other.json"))]);
    assert!(!ok && err.contains("other.json") && err.contains("not a biscale metrics.json"), "{err}");
    let (ok, _, err) = biscale(&["run", "-q", "configs/smoke.toml", "--cache-dir", &s(&cache), "--out", &s(&run)]);
    assert!(ok, "a re-rendered run folder can be run into again: {err}");
}

/// Issue classes "report embeds any file a record names", "report A B --out A" and "a record
/// whose figures stretch a plot without end": every field of `metrics.json` that names a file
/// of the run (found by what the run wrote) is tampered in turn to an absolute path, a path
/// climbing out and a path through a link; each is refused with the field named, and nothing
/// outside the run is read into a page. A side-by-side page is never written over one of the
/// runs it compares; absurd timings still give a report.
#[test]
fn report_reads_nothing_a_record_names_outside_its_run() {
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (cache, run) = (dir.path().join("cache"), dir.path().join("run"));
    let (ok, _, err) = biscale(&["run", "-q", "configs/smoke.toml", "--cache-dir", &s(&cache), "--out", &s(&run)]);
    assert!(ok, "{err}");
    let secret = dir.path().join("secret.png");
    std::fs::write(&secret, b"\x89PNG a secret that must not be embedded").unwrap();
    std::os::unix::fs::symlink(dir.path(), run.join("up")).unwrap();
    let text = std::fs::read_to_string(run.join("metrics.json")).unwrap();
    let original: serde_json::Value = serde_json::from_str(&text).unwrap();
    // Every string leaf naming a file the run wrote, by its JSON pointer.
    fn leaves(v: &serde_json::Value, at: String, out: &mut Vec<(String, String)>) {
        match v {
            serde_json::Value::String(t) => out.push((at, t.clone())),
            serde_json::Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| leaves(x, format!("{at}/{i}"), out)),
            serde_json::Value::Object(o) => o.iter().for_each(|(k, x)| leaves(x, format!("{at}/{k}"), out)),
            _ => {}
        }
    }
    let mut all = vec![];
    leaves(&original, String::new(), &mut all);
    let files: Vec<(String, String)> =
        all.into_iter().filter(|(_, t)| t.contains('/') && t.ends_with(".png") && run.join(t).is_file()).collect();
    assert!(files.len() >= 10, "{files:?}");
    for (pointer, _) in &files {
        for bad in [s(&secret), "../secret.png".to_string(), "up/secret.png".to_string()] {
            let mut v = original.clone();
            *v.pointer_mut(pointer).unwrap() = serde_json::Value::String(bad.clone());
            std::fs::write(run.join("metrics.json"), serde_json::to_string(&v).unwrap()).unwrap();
            let (ok, _, err) = biscale(&["report", &s(&run)]);
            let field = pointer.trim_start_matches('/').split('/').next_back().unwrap();
            assert!(!ok && err.contains("a record names files inside its own run folder only"), "{pointer}: {err}");
            assert!(err.contains(field) && err.contains(&bad), "{pointer} = {bad}: {err}");
        }
    }
    std::fs::remove_file(run.join("up")).unwrap();
    // Timings a plot cannot draw: the report is still written, in bounded time.
    let mut v = original.clone();
    v["compressors"][0]["gather_ms"] = serde_json::json!(5e-324);
    v["compressors"][1]["gather_ms"] = serde_json::json!(1e308);
    std::fs::write(run.join("metrics.json"), serde_json::to_string(&v).unwrap()).unwrap();
    let absurd = dir.path().join("absurd");
    let (ok, _, err) = biscale(&["report", &s(&run), "--out", &s(&absurd)]);
    assert!(ok, "{err}");
    assert!(absurd.join("report.html").is_file());
    std::fs::write(run.join("metrics.json"), &text).unwrap();
    // report A B --out A: refused, run A intact.
    let before = files_of(&run);
    let other = dir.path().join("other");
    let (ok, _, err) = biscale(&["report", &s(&run), "--out", &s(&other)]);
    assert!(ok, "{err}");
    let (ok, _, err) = biscale(&["report", &s(&run), &s(&other), "--out", &s(&run)]);
    assert!(!ok && err.contains("one of the runs compared"), "{err}");
    assert!(files_of(&run) == before, "run A was changed");
}

/// Issue class "smaller ones": absurd numbers and names are clear errors or notes, never a
/// panic or a silent default.
#[test]
fn absurd_ages_thread_counts_and_names_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().to_str().unwrap();
    let (ok, _, err) = biscale(&["cache", "clean", "--cache-dir", cache, "--older-than-days", "1e308"]);
    assert!(!ok && err.contains("--older-than-days") && !err.contains("panicked"), "{err}");
    for (value, note) in
        [("abc", "is not a number of threads"), ("-3", "is not a number of threads"), ("0", "RAYON_NUM_THREADS=0")]
    {
        let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
            .args(["plan", "configs/smoke.toml"])
            .current_dir(root())
            .env("RAYON_NUM_THREADS", value)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success() && err.contains(note), "{value}: {err}");
    }
    for name in ["x".repeat(100_000), "run\u{202e}txt.exe".to_string()] {
        let (ok, _, err) = biscale(&["plan", "configs/smoke.toml", "--set", &format!("name=\"{name}\"")]);
        assert!(
            !ok && err.contains("name must be a plain folder name") && err.len() < 5000,
            "{}",
            &err[..err.len().min(500)]
        );
    }
}

/// `--set KEY=VALUE` overrides a config's values without editing it: the run uses them and
/// records them (its command line and the config text as it ran, each set line marked); an
/// error in a set value is reported as `--set KEY`, and a command without a config refuses it.
#[test]
fn set_overrides_a_config_value_and_errors_name_the_set() {
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (cache, out) = (dir.path().join("cache"), dir.path().join("run"));
    let (ok, _, err) = biscale(&[
        "run",
        "-q",
        "configs/smoke.toml",
        "--cache-dir",
        &s(&cache),
        "--out",
        &s(&out),
        "--set",
        "runtime.light_moments=true",
        "--set",
        "compressors.3.terms=[4]",
    ]);
    assert!(ok, "{err}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["uncompressed"]["light_moments"], serde_json::Value::Bool(true));
    let names: Vec<&str> = m["compressors"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"haar-t4") && !names.contains(&"haar-t8"), "the sweep was replaced: {names:?}");
    let text = m["run"]["config_text"].as_str().unwrap();
    assert!(text.contains("light_moments = true # --set runtime.light_moments"), "{text}");
    let command: Vec<&str> = m["run"]["command"].as_array().unwrap().iter().map(|c| c.as_str().unwrap()).collect();
    assert!(command.contains(&"runtime.light_moments=true"), "{command:?}");

    for (set, expect) in [
        ("transfer.local_grd=4", "--set transfer.local_grd: unknown field `local_grd`"),
        ("transfer.local_grid=abc", "--set transfer.local_grid: invalid type: string \"abc\""),
        ("compressors.9.kind=\"haar\"", "--set compressors.9.kind: `compressors` has 4 entries"),
        ("transfer.local_grid.x=1", "--set transfer.local_grid.x: `transfer.local_grid` is a value, not a table"),
        ("runtime", "--set runtime: expected KEY=VALUE"),
    ] {
        let (ok, _, err) = biscale(&["plan", "configs/smoke.toml", "--set", set]);
        assert!(!ok && err.contains(expect), "{set}: {err}");
    }
    let (ok, _, err) = biscale(&["cache", "list", "--cache-dir", &s(&cache), "--set", "a=1"]);
    assert!(!ok && err.contains("reads no config"), "{err}");
}

/// Issue class "--threads 100000 hangs": more worker threads than 4 per logical CPU are
/// capped with a note (from the flag or from RAYON_NUM_THREADS), so the run starts at once;
/// 0 is refused.
#[test]
fn absurd_thread_counts_are_capped_with_a_note() {
    let t = std::time::Instant::now();
    let (ok, out, err) = biscale(&["plan", "configs/smoke.toml", "--threads", "100000"]);
    assert!(ok && out.contains("plan"), "{err}");
    assert!(err.contains("--threads = 100000 is more than 4 threads per logical CPU"), "{err}");
    let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
        .args(["plan", "configs/smoke.toml"])
        .env("RAYON_NUM_THREADS", "100000")
        .current_dir(root())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("RAYON_NUM_THREADS = 100000"), "{err}");
    assert!(t.elapsed().as_secs() < 60, "capped runs start at once: {:?}", t.elapsed());
    let (ok, _, err) = biscale(&["plan", "configs/smoke.toml", "--threads", "0"]);
    assert!(!ok && err.contains("--threads must be at least 1"), "{err}");
}
