//! The memory estimate against the memory runs really take: the `biscale` binary runs as a
//! child at three sizes of `T`, and the estimate it made before tracing (`metrics.json`
//! `memory.estimate_bytes`) must be at or above the child's measured peak resident memory
//! (the kernel's `ru_maxrss` of that child, and the run's own VmHWM) and within 20% of it.
//! Also: `biscale plan` prints the estimate, and a run that does not fit is refused before it
//! traces anything.
#![cfg(target_os = "linux")]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

/// A config in `dir`: the bunny (1,839 vertices) at cubemap and visibility `r` (so every ray
/// is a texel: the most non-zeros per second of tracing), 8x8 local directions, the sparse
/// compressor, a constant sky, a 64x48 image and no reference: `T` is nearly all of the run.
fn config(dir: &Path, r: u32) -> PathBuf {
    let cfg = dir.join(format!("bunny{r}.toml"));
    let mesh = root().join("assets/meshes/bunny.obj");
    std::fs::write(
        &cfg,
        format!(
            "name = \"bunny{r}\"\n[scene]\nmesh = \"{}\"\n[lighting]\nconstant = [1.0, 1.0, 1.0]\n\
             [transfer]\ncubemap_resolution = {r}\nvisibility_resolution = {r}\nlocal_grid = 8\n\
             [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 64\nheight = 48\nrepeats = 1\n\
             [report]\nreference = false\n",
            mesh.display()
        ),
    )
    .unwrap();
    cfg
}

/// Run `biscale args` as a child with `env`; wait for it with `wait4`, which returns that
/// child's own resource usage. Returns (success, stderr, peak resident bytes).
fn run_measured(args: &[&str], env: &[(&str, &str)], dir: &Path) -> (bool, String, u64) {
    let log = dir.join("stderr.txt");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_biscale"));
    cmd.args(args).current_dir(root()).stdout(Stdio::null()).stderr(std::fs::File::create(&log).unwrap());
    for (k, v) in env {
        cmd.env(k, v);
    }
    // Reaped by wait4 below, not by `Child::wait`, which does not return the child's usage.
    #[allow(clippy::zombie_processes)]
    let child = cmd.spawn().expect("start biscale");
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it and `status`.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as libc::pid_t, "wait4: {}", std::io::Error::last_os_error());
    let ok = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    // ru_maxrss is in KiB on Linux.
    (ok, std::fs::read_to_string(&log).unwrap(), usage.ru_maxrss as u64 * 1024)
}

#[test]
fn the_estimate_is_at_most_20_percent_above_the_measured_peak_and_never_below() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let mut rows = vec![];
    for r in [24, 32, 48] {
        let cfg = config(dir.path(), r);
        let out = dir.path().join(format!("out{r}"));
        let (ok, err, child_peak) = run_measured(
            &["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--cache-dir", cache.to_str().unwrap()],
            &[],
            dir.path(),
        );
        assert!(ok, "{err}");
        let m: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
        let mem = &m["memory"];
        let estimate = mem["estimate_bytes"].as_u64().unwrap();
        let own_peak = mem["peak_rss_bytes"].as_u64().expect("VmHWM read on Linux");
        // The run's own peak is read before its report is written; the child's is the whole.
        assert!(own_peak <= child_peak && child_peak - own_peak < 16 << 20, "{own_peak} {child_peak}");
        let measured = child_peak.max(own_peak);
        let ratio = estimate as f64 / measured as f64;
        rows.push(format!("R = {r}: estimate {estimate} bytes, measured {measured} bytes, ratio {ratio:.3}"));
        assert!((1.0..=1.2).contains(&ratio), "{}", rows.join("\n"));
        // T dominates the run (its estimate peaks compressing it, well above the process), and
        // the sampled non-zeros bound the true count from above, within a few percent.
        assert_eq!(mem["estimate_phase"], "compress sparse");
        assert!(measured > 100 << 20, "{}", rows.join("\n"));
        let nnz = m["transfer"]["nnz"].as_u64().unwrap();
        let (expected, upper) = (mem["nnz_expected"].as_u64().unwrap(), mem["nnz_upper"].as_u64().unwrap());
        assert!(upper >= nnz && (upper as f64) < 1.1 * nnz as f64, "{nnz} {upper}");
        assert!((expected as f64 - nnz as f64).abs() < 0.05 * nnz as f64, "{nnz} {expected}");
        assert!(mem["nnz_worst_case"].as_u64().unwrap() >= upper);
        assert_eq!(mem["nnz_sampled_vertices"], 192);
    }
    eprintln!("{}", rows.join("\n"));
}

#[test]
fn plan_prints_the_estimated_peak_each_phase_and_the_available_memory() {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
        .args(["plan", "configs/smoke.toml"])
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("memory:\n  estimated peak ") && stdout.contains("available (MemAvailable"), "{stdout}");
    for line in ["phase transfer build", "phase transfer cache write", "phase compress bicluster", "part  T: CSR"] {
        assert!(stdout.contains(line), "{line}: {stdout}");
    }
    // The smoke config's bunny has 1,839 vertices of at most N / 2 = 192 non-zeros each.
    assert!(stdout.contains("353088 worst case (192 of 1839 vertices traced"), "{stdout}");
}

#[test]
fn a_run_that_does_not_fit_is_refused_before_tracing() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), 32);
    let out = dir.path().join("out");
    let args = ["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-cache"];
    let start = std::time::Instant::now();
    let (ok, err, _) = run_measured(&args, &[("BISCALE_MEMORY_LIMIT", "64M")], dir.path());
    assert!(!ok, "{err}");
    assert!(err.contains("this run needs about") && err.contains("(peak in: compress sparse)"), "{err}");
    assert!(err.contains("more than the 64.0 MiB available (BISCALE_MEMORY_LIMIT)"), "{err}");
    assert!(err.contains("lower [transfer] cubemap_resolution or visibility_resolution"), "{err}");
    // Refused before the transfer build (which prints `transfer: ...` when done) and quickly.
    assert!(!err.contains("transfer:") && !err.contains("panicked"), "{err}");
    assert!(start.elapsed().as_secs() < 10);
    assert!(!out.join("metrics.json").exists());
    // A limit that is not a size is an error naming the variable.
    let (ok, err, _) = run_measured(&args, &[("BISCALE_MEMORY_LIMIT", "lots")], dir.path());
    assert!(!ok && err.contains("BISCALE_MEMORY_LIMIT=lots: not a size"), "{err}");
    // `generate subdivide` is refused the same way.
    let dense = dir.path().join("dense.obj");
    let bunny = root().join("assets/meshes/bunny.obj");
    let (ok, err, _) = run_measured(
        &["generate", "subdivide", bunny.to_str().unwrap(), "--levels", "3", "--out", dense.to_str().unwrap()],
        &[("BISCALE_MEMORY_LIMIT", "16M")],
        dir.path(),
    );
    assert!(!ok && err.contains("3 levels of subdivision needs about") && err.contains("use fewer levels"), "{err}");
    assert!(!dense.exists());
}
