//! `kill -9` at any stage of a run leaves the output folder holding one whole run: the earlier
//! one, or after the swap the new one, never a mix, and no temporary file survives the next
//! run. The `biscale` executable is killed with SIGKILL at each of five points through its
//! fault-injection variable (`BISCALE_FAULT_KILL_AT`, see `biscale::store::staging`).

use std::collections::BTreeMap;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

/// A small run named `name` with the given compressor tables.
fn config(dir: &Path, name: &str, compressors: &str) -> PathBuf {
    let r = root();
    let body = format!(
        "name = \"{name}\"\n[scene]\nmesh = \"{}\"\n[lighting]\nenv_map = \"{}\"\n[transfer]\ncubemap_resolution = 4\n\
         visibility_resolution = 8\nlocal_grid = 2\n{compressors}[runtime]\nwidth = 32\nheight = 24\nrepeats = 1\n",
        r.join("assets/meshes/bunny.obj").display(),
        r.join("assets/envmaps/pmndrs_apartment.exr").display()
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, body).unwrap();
    path
}

/// Every file under `dir` by relative path, with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.insert(p.strip_prefix(base).unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

fn run(cfg: &Path, out: &Path, cache: &Path, kill_at: Option<&str>) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_biscale"));
    cmd.args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--cache-dir", cache.to_str().unwrap()]);
    match kill_at {
        Some(point) => cmd.env("BISCALE_FAULT_KILL_AT", point),
        None => cmd.env_remove("BISCALE_FAULT_KILL_AT"),
    };
    cmd.output().unwrap()
}

#[test]
fn killed_runs_leave_the_earlier_run_whole_and_nothing_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let out = dir.path().join("out");
    let first =
        config(dir.path(), "first", "[[compressors]]\nkind = \"sparse\"\n[[compressors]]\nkind = \"bicluster\"\n");
    let second = config(dir.path(), "second", "[[compressors]]\nkind = \"haar\"\nterms = 4\n");
    let done = run(&first, &out, &cache, None);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let earlier = snapshot(&out);
    assert!(earlier.contains_key("images/bicluster.png") && earlier.contains_key("report.html"));

    for point in ["transfer", "images", "compression", "metrics", "report"] {
        let killed = run(&second, &out, &cache, Some(point));
        let stderr = String::from_utf8_lossy(&killed.stderr);
        assert_eq!(killed.status.signal(), Some(9), "{point}: not killed by SIGKILL: {stderr}");
        assert!(stderr.contains(&format!("BISCALE_FAULT_KILL_AT={point}")), "{point}: {stderr}");
        // Byte for byte the earlier run: no file of the killed one, none of the earlier lost.
        let now = snapshot(&out);
        assert_eq!(now.keys().collect::<Vec<_>>(), earlier.keys().collect::<Vec<_>>(), "{point}");
        assert!(now == earlier, "{point}: a file of the earlier run changed");
    }

    let done = run(&second, &out, &cache, None);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let new = snapshot(&out);
    // The new run whole, with none of the earlier run's files (its compressors' images).
    assert!(new.contains_key("images/haar-t4.png") && new.contains_key("report.html"));
    assert!(!new.keys().any(|k| k.contains("bicluster") || k.contains("sparse")), "{:?}", new.keys());
    let metrics = String::from_utf8_lossy(&new["metrics.json"]).into_owned();
    assert!(metrics.contains("second.toml"), "metrics of the new run");
    // The killed runs' staging folders are gone, and no temporary file is anywhere.
    let mut beside: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    beside.sort();
    assert_eq!(beside, ["cache", "first.toml", "out", "second.toml"]);
    assert!(!new.keys().any(|k| k.contains(".tmp")), "{:?}", new.keys());
}

/// `--out` at a folder that is not a run's is refused, and the folder is left as it was (a
/// run replaces its output folder whole, so it must never take over someone's files). Issue
/// class "--out replaces a user's folder": a `plan.txt` is no proof; `--out .` is refused
/// with nothing left beside it; a linked `--out` stays a link.
#[test]
fn out_at_a_folder_of_other_files_is_refused_and_left_alone() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let cfg = config(dir.path(), "x", "[[compressors]]\nkind = \"sparse\"\n");
    let precious = dir.path().join("notes");
    std::fs::create_dir(&precious).unwrap();
    std::fs::write(precious.join("thesis.tex"), "x").unwrap();
    let r = run(&cfg, &precious, &cache, None);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && stderr.contains("not a biscale output folder"), "{stderr}");
    std::fs::write(precious.join("plan.txt"), "notes").unwrap();
    let r = run(&cfg, &precious, &cache, None);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && stderr.contains("not a biscale output folder"), "{stderr}");
    assert_eq!(snapshot(&precious).len(), 2);
    assert_eq!(std::fs::read_to_string(precious.join("thesis.tex")).unwrap(), "x");

    // `--out .` from inside a folder of one's work.
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_biscale"));
    cmd.current_dir(&precious).args([
        "run",
        cfg.to_str().unwrap(),
        "--out",
        ".",
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    let r = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && stderr.contains("working in"), "{stderr}");
    assert_eq!(snapshot(&precious).len(), 2);
    let mut beside: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    beside.sort();
    assert_eq!(beside, ["notes", "x.toml"], "no staging folder left behind");

    // A link to an output folder: the run lands there and the link stays.
    let real = dir.path().join("real");
    std::fs::create_dir(&real).unwrap();
    let link = dir.path().join("link");
    std::os::unix::fs::symlink(&real, &link).unwrap();
    for _ in 0..2 {
        let r = run(&cfg, &link, &cache, None);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    assert!(link.is_symlink() && real.join("metrics.json").is_file());
}
