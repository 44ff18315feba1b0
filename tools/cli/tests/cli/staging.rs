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

/// What a decoy is: a file's bytes, a folder, or a link's target (never followed).
#[derive(Debug, PartialEq)]
enum Entry {
    File(Vec<u8>),
    Folder,
    Link(PathBuf),
}

/// Every entry under `dir` (links not followed), by path relative to it.
fn entries(dir: &Path) -> BTreeMap<String, Entry> {
    fn walk(base: &Path, dir: &Path, out: &mut BTreeMap<String, Entry>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            let name = p.strip_prefix(base).unwrap().to_string_lossy().into_owned();
            let kind = std::fs::symlink_metadata(&p).unwrap().file_type();
            if kind.is_symlink() {
                out.insert(name, Entry::Link(std::fs::read_link(&p).unwrap()));
            } else if kind.is_dir() {
                out.insert(name, Entry::Folder);
                walk(base, &p, out);
            } else {
                out.insert(name, Entry::File(std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// The decoys of `decoys` (paths relative to `base`) that are gone or not as they were.
fn changed(base: &Path, decoys: &BTreeMap<String, Entry>) -> Vec<String> {
    decoys
        .iter()
        .filter(|(name, was)| {
            let p = base.join(name);
            let now = match std::fs::symlink_metadata(&p) {
                Err(_) => return true,
                Ok(m) if m.file_type().is_symlink() => Entry::Link(std::fs::read_link(&p).unwrap()),
                Ok(m) if m.is_dir() => Entry::Folder,
                Ok(_) => Entry::File(std::fs::read(&p).unwrap()),
            };
            now != **was
        })
        .map(|(name, _)| name.clone())
        .collect()
}

/// Whether a command is expected to do its work, or to refuse (an output aimed at a folder
/// that is not biscale's, a file path that is a folder).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Expect {
    Writes,
    Refuses,
}

/// A folder of a user's files (`work/`) and one outside it that links point into, then every
/// command that writes or cleans aimed at the folder or at a new name inside it, on the smoke
/// config with its own cache: after each command every decoy is still there, byte for byte,
/// links still links to the same place, whether the command wrote or refused. `extra` adds
/// decoys (relative path, contents) to the folder.
fn no_command_touches_a_decoy(extra: &[(&str, &str)]) {
    let dir = tempfile::tempdir().unwrap();
    let (work, elsewhere, cache) = (dir.path().join("work"), dir.path().join("elsewhere"), dir.path().join("cache"));
    let w = |name: &str| work.join(name).to_str().unwrap().to_string();
    let wd = work.to_str().unwrap();
    let write = |p: PathBuf, text: &str| {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    };
    write(elsewhere.join("data.txt"), "data kept elsewhere\n");
    write(elsewhere.join("results/table.csv"), "a,b\n1,2\n");
    for (name, text) in [
        ("thesis.tex", "\\documentclass{book}\n"),
        ("plan.txt", "my plan, not biscale's\n"),
        ("metrics.json", "{\"mine\": true}\n"),
        ("report.md", "# notes\n"),
        ("btf-wool.btf", "wool measurements\n"),
        // Named as the stage cache names its files, contents of someone else.
        ("transfer-0123456789abcdef0123456789abcdef.bsf", "not an artifact\n"),
        ("form-0123456789abcdef0123456789abcdef-sparse.bsf", "BSF"),
        // Named as the staging and set-aside folders of runs into `work/out`: one of a live
        // process (pid 1), ones of a dead process with a hand-written marker.
        (".out.staging-1-1/thesis.tex", "draft\n"),
        (".out.staging-999999-1/notes.txt", "notes\n"),
        (
            ".out.staging-999999-1/.biscale-run",
            "{\"run_id\": \"0\", \"proof\": \"0\", \"about\": \"\", \"files\": {}, \"folders\": []}",
        ),
        (".out.old-999999-2/notes.txt", "older notes\n"),
        ("images/figure.png", "not a png\n"),
    ]
    .iter()
    .chain(extra)
    {
        write(work.join(name), text);
    }
    std::fs::create_dir(work.join("empty")).unwrap();
    std::os::unix::fs::symlink("../elsewhere/data.txt", work.join("data.lnk")).unwrap();
    std::os::unix::fs::symlink("../elsewhere/results", work.join("results")).unwrap();
    let decoys = entries(&work);
    let outside = entries(&elsewhere);

    let cache_dir = ["--cache-dir", cache.to_str().unwrap()];
    let cfg = "configs/smoke.toml";
    let biscale = |expect: Expect, args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
            .args(args)
            .current_dir(root())
            .env_remove("BISCALE_FAULT_KILL_AT")
            .env_remove("BISCALE_SHARD_FAIL")
            .env_remove("SLURM_ARRAY_TASK_ID")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let got = if out.status.success() { Expect::Writes } else { Expect::Refuses };
        assert_eq!(got, expect, "biscale {}:\n{stderr}", args.join(" "));
        assert!(!stderr.contains("panicked"), "biscale {}:\n{stderr}", args.join(" "));
        let (here, there) = (changed(&work, &decoys), changed(&elsewhere, &outside));
        assert!(here.is_empty() && there.is_empty(), "biscale {} changed {here:?} {there:?}", args.join(" "));
    };
    fn with<'a>(args: &[&'a str], extra: &[&'a str]) -> Vec<&'a str> {
        [args, extra].concat()
    }
    use Expect::{Refuses, Writes};

    // Run folders (staged, replaced whole): the folder itself, the links, a new subfolder
    // whose name the decoy staging folders carry (twice: the second replaces the first).
    biscale(Refuses, &with(&["-q", "run", cfg, "--out", wd], &cache_dir));
    biscale(Refuses, &with(&["-q", "run", cfg, "--out", &w("data.lnk")], &cache_dir));
    biscale(Refuses, &with(&["-q", "run", cfg, "--out", &w("results")], &cache_dir));
    biscale(Refuses, &with(&["-q", "run", cfg, "--out", &w("images")], &cache_dir));
    biscale(Writes, &with(&["-q", "run", cfg, "--out", &w("out")], &cache_dir));
    biscale(Writes, &with(&["-q", "run", cfg, "--out", &w("out")], &cache_dir));
    // Exports and pictures into the folder itself and beside the decoys.
    // With decoys named like their files they refuse; a second run replaces their own files.
    let named = !extra.is_empty();
    let in_place = if named { Refuses } else { Writes };
    biscale(in_place, &with(&["-q", "export", cfg, "--what", "t,l,lstar", "--out", wd], &cache_dir));
    biscale(Writes, &with(&["-q", "export", cfg, "--format", "mtx", "--out", &w("exp")], &cache_dir));
    for _ in 0..2 {
        biscale(in_place, &with(&["-q", "export-matrix", cfg, "--out", wd], &cache_dir));
    }
    biscale(in_place, &with(&["-q", "btf", cfg, "--preview", "--out", wd], &cache_dir));
    biscale(in_place, &with(&["-q", "viz", cfg, "--count", "4", "--out", wd], &cache_dir));
    let lstar = match named {
        false => w("lstar.npz"),
        true => {
            biscale(Writes, &with(&["-q", "export", cfg, "--what", "lstar", "--out", &w("own")], &cache_dir));
            w("own/lstar.npz")
        }
    };
    // eval and report write run folders: refused at the folder, written beside it.
    biscale(Refuses, &with(&["-q", "eval", cfg, "--lstar", &lstar, "--out", wd], &cache_dir));
    biscale(Writes, &with(&["-q", "eval", cfg, "--lstar", &lstar, "--out", &w("eval")], &cache_dir));
    biscale(Refuses, &["-q", "report", &w("out"), "--out", wd]);
    biscale(Refuses, &["-q", "report", &w("out"), &w("eval"), "--out", wd]);
    biscale(Refuses, &["-q", "report", wd]);
    biscale(Writes, &["-q", "report", &w("out")]);
    biscale(Writes, &["-q", "report", &w("out"), "--out", &w("report")]);
    // The sharded precompute planned into the folder: its shards, a merge refused at the
    // folder and written beside it.
    biscale(in_place, &["-q", "shard", "plan", cfg, "--shards", "2", "--out", wd]);
    let plan = if named { w("plan") } else { wd.to_string() };
    if named {
        biscale(Writes, &["-q", "shard", "plan", cfg, "--shards", "2", "--out", &plan]);
    }
    let manifest = format!("{plan}/manifest.json");
    for index in ["0", "1"] {
        biscale(Writes, &["-q", "shard", "run", &manifest, "--index", index]);
    }
    biscale(Writes, &["-q", "shard", "status", &manifest]);
    biscale(Writes, &["-q", "shard", "sbatch", &manifest]);
    biscale(Writes, &["-q", "shard", "k8s", &manifest]);
    biscale(Writes, &["-q", "shard", "batch", &manifest]);
    biscale(Refuses, &with(&["-q", "shard", "merge", &manifest, "--out", wd], &cache_dir));
    biscale(Writes, &with(&["-q", "shard", "merge", &manifest, "--out", &w("merged")], &cache_dir));
    // The folder as a stage cache: filled, listed, cleaned (biscale's own files only).
    let here = ["--cache-dir", wd];
    biscale(Writes, &with(&["-q", "export", cfg, "--what", "forms", "--out", &w("forms")], &here));
    for clean in [&[][..], &["--kind", "temporary"], &["--older-than-days", "0"], &["--dry-run"]] {
        biscale(Writes, &with(&["-q", "cache", "clean"], &[&here[..], clean].concat()));
    }
    biscale(Writes, &with(&["-q", "cache", "list"], &here));
    // Single files: the folder, a link (forced or not) and a user's file are refused; a new
    // name is written, and written again over biscale's own file; a decoy of its name refuses.
    biscale(Refuses, &["-q", "generate", "scene", "plane-sphere", "--out", wd]);
    for force in [&[][..], &["--force"]] {
        biscale(Refuses, &with(&["-q", "generate", "scene", "plane", "--out", &w("data.lnk")], force));
    }
    biscale(Refuses, &["-q", "generate", "scene", "plane", "--out", &w("thesis.tex")]);
    for _ in 0..2 {
        biscale(Writes, &["-q", "generate", "scene", "plane-sphere", "--out", &w("gen.obj")]);
    }
    biscale(in_place, &["-q", "generate", "scene", "plane", "--out", &w("scene.obj")]);
    biscale(Refuses, &["-q", "generate", "uv", &w("gen.obj"), "--out", wd]);
    biscale(Writes, &["-q", "generate", "uv", &w("gen.obj"), "--out", &w("scene_uv.obj")]);
    let (a, b) = (w("out/images/sparse.exr"), w("out/images/haar-t4.exr"));
    biscale(Refuses, &["-q", "diff", &a, &b, "--error-image", wd]);
    biscale(Refuses, &["-q", "diff", &a, &b, "--error-image", &w("images/figure.png")]);
    biscale(Refuses, &["-q", "diff", &a, &b, "--error-image", &a, "--force"]);
    biscale(in_place, &["-q", "diff", &a, &b, "--error-image", &w("diff.png")]);
    biscale(Writes, &["-q", "diff", &a, &b, "--error-image", &w("diff2.png")]);

    // The decoys' folder holds what the commands wrote beside them (so they did run).
    for f in [
        "out/metrics.json",
        "eval/metrics.json",
        "report/report.md",
        "merged/metrics.json",
        "scene_uv.obj",
        "diff2.png",
    ] {
        assert!(work.join(f).is_file(), "{f}");
    }
    // (With decoys of their names, the refusals above are checked by the decoys being intact.)
    for f in
        ["T.mtx", "t.npz", "sparsity_panels.png", "lambertian.btf", "diff.png", "scene.obj", "shards/0000/done.json"]
    {
        assert!(named || work.join(f).is_file(), "{f}");
    }
    assert_eq!(work.join("plan/shards/0000/done.json").is_file(), named);
    assert_eq!(work.join("own/lstar.npz").is_file(), named);
}

/// Issue class "a command removes or replaces a file it did not write": see
/// [`no_command_touches_a_decoy`].
#[test]
fn no_command_removes_or_replaces_a_file_it_did_not_write() {
    no_command_touches_a_decoy(&[]);
}

/// The same with decoys named as the files the commands that write into a folder (not a staged
/// run folder) write there: `export`'s `l.npz`, `export-matrix`'s `T.mtx` and `view.json`,
/// `btf`'s `lambertian.btf`, `viz`'s `sparsity_panels.png`, `shard plan`'s `manifest.json`:
/// those commands then refuse (they stage their files and publish them only over files the
/// folder's marker proves theirs); and as the single files `generate` and `diff` are asked
/// for (`scene.obj`, `diff.png`): they refuse a file that lacks biscale's mark.
#[test]
fn no_command_replaces_a_file_named_like_its_output() {
    no_command_touches_a_decoy(&[
        ("l.npz", "my L\n"),
        ("T.mtx", "my matrix\n"),
        ("view.json", "{\"mine\": true}\n"),
        ("lambertian.btf", "my BTF\n"),
        ("sparsity_panels.png", "my picture\n"),
        ("manifest.json", "{\"mine\": true}\n"),
        ("scene.obj", "v 0 0 0\n"),
        ("diff.png", "my picture\n"),
    ]);
}
