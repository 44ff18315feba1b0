//! The sharded precompute (`biscale shard`) against a single-machine run of the same config:
//! `T`, every form and every image byte for byte (forms up to their measured build time), and
//! the ways a shard can be incomplete (failed, corrupt, stale) named with the command that
//! reruns it. The `biscale` executable runs the shards, as a job array would.

use biscale_core::artifact::{Artifact, Field};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

/// `configs/tests/shard.toml` with absolute asset paths, in `dir` (so the test can change it).
fn config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("configs/tests/shard.toml")).unwrap();
    let text = text.replace("../../assets/", &format!("{}/", root().join("assets").display()));
    let path = dir.join("shard.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn biscale(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_biscale"));
    cmd.args(args).env_remove("BISCALE_SHARD_FAIL").env_remove("SLURM_ARRAY_TASK_ID");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().unwrap()
}

fn ok(out: Output) -> String {
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    text
}

fn failed(out: Output) -> String {
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert_eq!(out.status.code(), Some(1), "{text}");
    text
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every file of a folder (not recursive) by name, with its bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap()))
        .collect()
}

/// A cache file's bytes with a form's measured build time zeroed (the one value a merge
/// cannot share with a single run), re-encoded.
fn without_build_time(path: &Path) -> Vec<u8> {
    let mut a = Artifact::load(path).unwrap();
    if let Some(f) = a.fields.get_mut("build_seconds") {
        *f = Field::F64(0.0);
    }
    a.encode()
}

#[test]
fn a_sharded_precompute_merges_into_the_single_machine_run_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    let manifest = d.join("shards/manifest.json");

    // More shards than whole 128-vertex blocks (1,839 vertices: 15) is refused up front.
    let e = failed(biscale(&["shard", "plan", s(&cfg), "--shards", "16", "--out", s(&d.join("shards"))], &[]));
    assert!(e.contains("only 15 ranges of whole 128-vertex blocks") && e.contains("--shards 15"), "{e}");

    let plan = ok(biscale(&["shard", "plan", s(&cfg), "--shards", "4", "--out", s(&d.join("shards"))], &[]));
    assert!(plan.contains("in the merge:  cpca-k4-c2") && plan.contains("in the shards: bicluster-b128"), "{plan}");

    // Shard 2 fails after tracing (as a crashed array task would): it is incomplete, and the
    // merge refuses, naming it and the command that reruns it.
    for i in 0..4 {
        let out = biscale(&["shard", "run", s(&manifest), "--index", &i.to_string()], &[("BISCALE_SHARD_FAIL", "2")]);
        if i == 2 {
            assert!(failed(out).contains("shard 2 fails on purpose"));
        } else {
            ok(out);
        }
    }
    let status = failed(biscale(&["shard", "status", s(&manifest)], &[]));
    assert!(status.contains("shard 2 (vertices 896..1408): missing") && status.contains("1 of 4 shards"), "{status}");
    let merged_out = d.join("merged");
    let merged_cache = d.join("cache-merged");
    let merge_args = ["shard", "merge", s(&manifest), "--out", s(&merged_out), "--cache-dir", s(&merged_cache)];
    let e = failed(biscale(&merge_args, &[]));
    let rerun = format!("biscale shard run {} --index 2", manifest.display());
    assert!(e.contains("shard 2 is missing") && e.contains(&rerun), "{e}");
    assert!(!merged_out.exists(), "a refused merge wrote its output folder");

    // The index can come from Slurm's array variable; rerunning a complete shard rewrites
    // the same bytes.
    ok(biscale(&["shard", "run", s(&manifest)], &[("SLURM_ARRAY_TASK_ID", "2")]));
    let shard0 = d.join("shards/shards/0000");
    let form = shard0.join("form-bicluster-b128.bsf");
    let (t_before, form_before) = (std::fs::read(shard0.join("transfer.bsf")).unwrap(), without_build_time(&form));
    ok(biscale(&["shard", "run", s(&manifest), "--index", "0"], &[]));
    assert!(std::fs::read(shard0.join("transfer.bsf")).unwrap() == t_before, "T changed on a rerun");
    assert!(without_build_time(&form) == form_before, "the form changed on a rerun");
    ok(biscale(&["shard", "status", s(&manifest)], &[]));
    ok(biscale(&merge_args, &[]));

    let single_out = d.join("single");
    let single_cache = d.join("cache-single");
    ok(biscale(&["run", s(&cfg), "--out", s(&single_out), "--cache-dir", s(&single_cache)], &[]));

    // Every image, byte for byte.
    let (a, b) = (files(&single_out.join("images")), files(&merged_out.join("images")));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    assert!(a.len() >= 12, "{:?}", a.keys());
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "image {name} differs");
    }
    // T byte for byte; every form (those merged from the shards and CPCA, built in the merge)
    // byte for byte but for its build time.
    let (a, b) = (files(&single_cache), files(&merged_cache));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    assert_eq!(a.keys().filter(|k| k.starts_with("form-")).count(), 5);
    for name in a.keys() {
        if name.starts_with("transfer-") {
            assert!(a[name] == b[name], "T differs");
        } else {
            let (x, y) = (without_build_time(&single_cache.join(name)), without_build_time(&merged_cache.join(name)));
            assert!(x == y, "form {name} differs");
        }
    }
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged_out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["sharded"]["shards"], 4);
    assert_eq!(metrics["transfer"]["cached"], false);

    // A corrupt shard file, and a config changed since the plan, are refused by name.
    let t1 = d.join("shards/shards/0001/transfer.bsf");
    let mut bytes = std::fs::read(&t1).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    std::fs::write(&t1, bytes).unwrap();
    let e = failed(biscale(&merge_args, &[]));
    assert!(e.contains("shard 1 is not usable") && e.contains("XXH3-128") && e.contains("--index 1"), "{e}");
    std::fs::write(&cfg, std::fs::read_to_string(&cfg).unwrap() + "# edited\n").unwrap();
    let e = failed(biscale(&merge_args, &[]));
    assert!(e.contains("changed since the plan"), "{e}");
    let e = failed(biscale(&["shard", "run", s(&manifest), "--index", "1"], &[]));
    assert!(e.contains("changed since the plan"), "{e}");
}

#[test]
fn sbatch_writes_an_array_a_dependent_merge_and_a_submit_script() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "3", "--out", s(&d.join("sh ards"))], &[]));
    let manifest = d.join("sh ards/manifest.json");
    let out = ok(biscale(
        &["shard", "sbatch", s(&manifest), "--partition", "short", "--time", "10", "--out", s(&d.join("merged"))],
        &[],
    ));
    assert!(out.contains("submit with: bash"), "{out}");
    let read = |name: &str| std::fs::read_to_string(d.join("sh ards/slurm").join(name)).unwrap();
    let shards = read("shards.sbatch");
    assert!(shards.contains("#SBATCH --array=0-2\n") && shards.contains("#SBATCH --partition=short\n"), "{shards}");
    assert!(shards.contains("#SBATCH --mem=1024M\n"), "the small plan's estimate is under the 1 GiB floor: {shards}");
    // The manifest's path has a space: quoted for the shell.
    assert!(shards.contains(&format!("shard run '{}'", manifest.display())), "{shards}");
    let merge = read("merge.sbatch");
    assert!(merge.contains("shard merge") && merge.contains(&format!("--out {}", d.join("merged").display())));
    let submit = read("submit.sh");
    assert!(submit.contains("--dependency=afterok:\"$shards\" merge.sbatch"), "{submit}");
    // The scripts are valid shell.
    for name in ["shards.sbatch", "merge.sbatch", "submit.sh"] {
        let check = Command::new("bash").arg("-n").arg(d.join("sh ards/slurm").join(name)).status().unwrap();
        assert!(check.success(), "{name} is not valid bash");
    }
}

/// Issue class "shard sbatch writes what the manifest says into a shell script": a manifest
/// edited since `plan` (a newline and a command in its experiment's name, an absolute or
/// escaping shard folder, no shards) is refused, even with its checksum recomputed for the
/// edit; `#SBATCH` values that are not Slurm's own characters are refused; what is written
/// is valid bash whose only commands are the ones biscale writes.
#[test]
fn hostile_manifests_and_options_never_reach_a_script() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "2", "--out", s(&d.join("plan"))], &[]));
    let manifest = d.join("plan/manifest.json");
    let good = std::fs::read_to_string(&manifest).unwrap();
    let plan: biscale::shard::Manifest = serde_json::from_str(&good).unwrap();
    let hostile: Vec<(&str, biscale::shard::Manifest)> = vec![
        ("experiment", biscale::shard::Manifest { experiment: "x\ntouch /tmp/pwned\n#".into(), ..plan.clone() }),
        ("experiment", biscale::shard::Manifest { experiment: "$(touch /tmp/pwned)".into(), ..plan.clone() }),
        ("shard 1", {
            let mut m = plan.clone();
            m.shards[1].dir = "/tmp/elsewhere".into();
            m
        }),
        ("shard 0", {
            let mut m = plan.clone();
            m.shards[0].dir = "shards/../../x".into();
            m
        }),
        ("shards", biscale::shard::Manifest { shards: vec![], vertices: 0, ..plan.clone() }),
    ];
    for (what, m) in hostile {
        // Edited by hand: the checksum no longer matches.
        std::fs::write(
            &manifest,
            serde_json::to_string(&biscale::shard::Manifest { checksum: plan.checksum.clone(), ..m.clone() }).unwrap(),
        )
        .unwrap();
        let e = failed(biscale(&["shard", "sbatch", s(&manifest)], &[]));
        assert!(e.contains("checksum"), "{what}: {e}");
        // Edited with the checksum recomputed: the field itself is refused.
        let forged = biscale::shard::Manifest { checksum: biscale::shard::manifest_checksum(&m), ..m };
        std::fs::write(&manifest, serde_json::to_string(&forged).unwrap()).unwrap();
        let e = failed(biscale(&["shard", "sbatch", s(&manifest)], &[]));
        assert!(e.contains(what), "{what}: {e}");
        let e = failed(biscale(&["shard", "run", s(&manifest), "--index", "0"], &[]));
        assert!(e.contains(what), "{what}: {e}");
    }
    assert!(!d.join("plan/slurm").exists(), "nothing was written");
    assert!(!Path::new("/tmp/elsewhere").exists());

    std::fs::write(&manifest, &good).unwrap();
    for (flag, value) in
        [("--partition", "a\ntouch /tmp/pwned"), ("--mem", "1G; touch /tmp/pwned"), ("--time", "$(id)")]
    {
        let e = failed(biscale(&["shard", "sbatch", s(&manifest), flag, value], &[]));
        assert!(e.contains(flag) && e.contains("Slurm"), "{flag}: {e}");
    }
    ok(biscale(&["shard", "sbatch", s(&manifest), "--partition", "short", "--mem", "2G", "--time", "1-00:00:00"], &[]));
    for name in ["shards.sbatch", "merge.sbatch", "submit.sh"] {
        let path = d.join("plan/slurm").join(name);
        assert!(Command::new("bash").arg("-n").arg(&path).status().unwrap().success(), "{name} is not valid bash");
        // Every line is a comment, a directive, or one of the commands biscale writes.
        let text = std::fs::read_to_string(&path).unwrap();
        for line in text.lines().filter(|l| !l.starts_with('#') && !l.is_empty()) {
            let known =
                ["set -euo pipefail", "export RAYON_NUM_THREADS=", "exec ", "cd ", "shards=", "merge=", "echo "];
            assert!(known.iter().any(|k| line.starts_with(k)), "{name}: unexpected line {line:?}");
        }
    }
}
