//! The sharded precompute (`biscale shard`) against a single-machine run of the same config:
//! `T`, every form and every image byte for byte (forms up to their measured build time), and
//! the ways a shard can be incomplete (failed, corrupt, stale) named with the command that
//! reruns it. The `biscale` executable runs the shards, as a job array would. The job files
//! of Slurm, Kubernetes and AWS Batch field by field, and against hostile manifests and flags.

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
    cmd.args(args).env_remove("BISCALE_SHARD_FAIL");
    for var in ["SLURM_ARRAY_TASK_ID", "AWS_BATCH_JOB_ARRAY_INDEX", "JOB_COMPLETION_INDEX"] {
        cmd.env_remove(var);
    }
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
    assert!(
        plan.contains("the merge stacks all of T in memory: the compressor cpca-k4-c2 runs in the merge"),
        "{plan}"
    );

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
    let plan = std::fs::read_to_string(merged_out.join("plan.txt")).unwrap();
    assert!(plan.contains("T from 4 shards' outputs (stacked into one matrix)"), "{plan}");

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

/// The comparable numbers of a run's `metrics.json`: `T`'s record but its timings, and every
/// compressor's errors and statistics but its build time.
fn scores(out: &Path) -> serde_json::Value {
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let t = &m["transfer"];
    let compressors: Vec<_> = m["compressors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let mut stats = c["stats"].clone();
            if let Some(s) = stats.as_object_mut() {
                s.remove("build_seconds");
            }
            serde_json::json!([c["name"], c["bytes"], c["rel_error_lstar"], c["image"], stats])
        })
        .collect();
    serde_json::json!({
        "transfer": [t["rows"], t["nnz"], t["value_histogram"], t["vertices_without_sky"]],
        "compressors": compressors,
    })
}

#[test]
fn a_merge_whose_steps_are_all_row_separable_streams_t_and_matches_the_single_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The test scene without CPCA (the one compressor that needs all of T): every step after
    // the shards is a pass over rows, so the merge never stacks T.
    let text = std::fs::read_to_string(config(d)).unwrap();
    let blocks: Vec<&str> = text.split("[[compressors]]").filter(|b| !b.contains("\"cpca\"")).collect();
    assert_eq!(blocks.len(), 5, "the test config's compressors changed");
    let cfg = d.join("stream.toml");
    std::fs::write(&cfg, blocks.join("[[compressors]]")).unwrap();
    let manifest = d.join("shards/manifest.json");
    let plan = ok(biscale(&["shard", "plan", s(&cfg), "--shards", "3", "--out", s(&d.join("shards"))], &[]));
    assert!(plan.contains("the merge streams T from the shards' files"), "{plan}");
    assert!(plan.contains(" base + ") && plan.contains(" B per non-zero)"), "{plan}");
    for i in 0..3 {
        ok(biscale(&["shard", "run", s(&manifest), "--index", &i.to_string()], &[]));
    }
    let (merged, merged_cache) = (d.join("merged"), d.join("cache-merged"));
    let log = ok(biscale(&["shard", "merge", s(&manifest), "--out", s(&merged), "--cache-dir", s(&merged_cache)], &[]));
    assert!(log.contains("T left in their files"), "{log}");
    // Its plan says where T comes from, and that it neither traces nor caches it.
    let plan = std::fs::read_to_string(merged.join("plan.txt")).unwrap();
    let transfer = plan.lines().find(|l| l.contains(" transfer ")).unwrap();
    assert!(transfer.contains("T from 3 shards' outputs (streamed part by part, never whole)"), "{plan}");
    assert!(!transfer.contains("cached by content"), "{plan}");
    let (single, single_cache) = (d.join("single"), d.join("cache-single"));
    ok(biscale(&["run", s(&cfg), "--out", s(&single), "--cache-dir", s(&single_cache)], &[]));

    // Every image byte for byte, every form byte for byte but its build time, and every
    // score (T's record, each L* and image error, the lossy biclustering's achieved error
    // summed over the parts) equal.
    let (a, b) = (files(&single.join("images")), files(&merged.join("images")));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    assert!(a.len() >= 12, "{:?}", a.keys());
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "image {name} differs");
    }
    let (a, b) = (files(&single_cache), files(&merged_cache));
    let forms: Vec<_> = a.keys().filter(|k| k.starts_with("form-")).collect();
    assert_eq!(forms.len(), 4);
    assert_eq!(forms, b.keys().filter(|k| k.starts_with("form-")).collect::<Vec<_>>());
    for name in forms {
        let (x, y) = (without_build_time(&single_cache.join(name)), without_build_time(&merged_cache.join(name)));
        assert!(x == y, "form {name} differs");
    }
    // T stays in the shards' files: the merge does not write it to the cache.
    assert!(!b.keys().any(|k| k.starts_with("transfer-")), "{:?}", b.keys());
    assert_eq!(scores(&single), scores(&merged));
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("metrics.json")).unwrap()).unwrap();
    let phases = m["memory"]["phases"].to_string();
    assert!(phases.contains("two shards' parts at a time") && !phases.contains("transfer build"), "{phases}");
    // The record says T was streamed, and the report what the uncompressed gather time is then.
    assert_eq!(m["sharded"]["streamed"], true);
    let report = std::fs::read_to_string(merged.join("report.md")).unwrap();
    assert!(report.contains("the products over the shards' parts of T summed"), "{report}");
    // The merge's whole time is in its record (it was written as 0 before the pipeline ended).
    let (whole, load) =
        (m["sharded"]["merge_seconds"].as_f64().unwrap(), m["sharded"]["merge_load_seconds"].as_f64().unwrap());
    assert!(whole > load && load > 0.0, "{}", m["sharded"]);
    let lossy = &m["compressors"][2]["stats"]["error"]["frobenius"];
    assert!(lossy.as_f64().is_some_and(|e| e > 0.0 && e <= 0.05 * (1.0 + 1e-12)), "{lossy}");
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

/// Issue class "paths that reach a script": a newline in the plan folder's own path never
/// reaches an `#SBATCH` line (refused, no `logs/` made anywhere); `shard run` never writes
/// through a link in the plan's `shards/` folder nor over a user's files in a shard's folder;
/// `--cpus` and batch `--mem` are bounded.
#[test]
fn plan_paths_and_shard_folders_never_reach_what_biscale_did_not_write() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    let plan = d.join("a\ntouch pwned\n#");
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "2", "--out", s(&plan)], &[]));
    let e = failed(biscale(&["shard", "sbatch", s(&plan.join("manifest.json"))], &[]));
    assert!(e.contains("control character") && e.contains("#SBATCH"), "{e}");
    assert!(!plan.join("slurm").exists(), "nothing was written, no logs/ made");

    let plan = d.join("plan");
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "2", "--out", s(&plan)], &[]));
    let manifest = plan.join("manifest.json");
    let refused = |args: &[&str], flag: &str| {
        let out = biscale(args, &[]);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(flag) && !e.contains("panicked"), "{args:?}: {e}");
    };
    for value in ["18446744073709551615", "0"] {
        refused(&["shard", "sbatch", s(&manifest), "--cpus", value], "--cpus");
    }
    refused(&["shard", "batch", s(&manifest), "--job-queue", "q", "--mem", "18446744073709551615"], "--mem");
    // A link where a shard's folder goes: refused, its target untouched.
    let elsewhere = d.join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let shards = plan.join("shards");
    std::fs::create_dir_all(&shards).unwrap();
    let spec: biscale::shard::Manifest = serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    let shard0 = plan.join(&spec.shards[0].dir);
    std::fs::create_dir_all(shard0.parent().unwrap()).unwrap();
    std::os::unix::fs::symlink(&elsewhere, &shard0).unwrap();
    let e = failed(biscale(&["shard", "run", s(&manifest), "--index", "0"], &[]));
    assert!(e.contains("passes through a link"), "{e}");
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
    std::fs::remove_file(&shard0).unwrap();
    // A user's done.json in a shard's folder: refused, kept byte for byte.
    std::fs::create_dir_all(&shard0).unwrap();
    std::fs::write(shard0.join("done.json"), "my notes\n").unwrap();
    let e = failed(biscale(&["shard", "run", s(&manifest), "--index", "0"], &[]));
    assert!(e.contains("0000") && e.contains("not a biscale output folder"), "{e}");
    assert_eq!(std::fs::read_to_string(shard0.join("done.json")).unwrap(), "my notes\n");
    std::fs::remove_file(shard0.join("done.json")).unwrap();
    // Its own folder is run again and again.
    for _ in 0..2 {
        ok(biscale(&["shard", "run", s(&manifest), "--index", "0"], &[]));
    }
    assert!(shard0.join("done.json").is_file());
}

/// A job file (`k8s/*.yaml` is JSON, which is YAML) parsed as JSON; where `python3` has PyYAML,
/// read as YAML too, to the same value.
fn job_file(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap();
    let value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}\n{text}", path.display()));
    if path.extension().is_some_and(|e| e == "yaml") {
        const SAME: &str = "import json, sys\ntry:\n    import yaml\nexcept ImportError:\n    sys.exit(3)\n\
                            text = open(sys.argv[1], encoding='utf-8').read()\n\
                            sys.exit(0 if yaml.safe_load(text) == json.loads(text) else 1)\n";
        if let Ok(out) = Command::new("python3").arg("-c").arg(SAME).arg(path).output() {
            // 3: no PyYAML here.
            assert!(matches!(out.status.code(), Some(0 | 3)), "{}: YAML reads another value: {out:?}", path.display());
        }
    }
    value
}

/// A folder of stand-ins for `sbatch`, `kubectl` and `aws` that append their command line to
/// `$FAKE_LOG` and answer as the real ones would.
fn fake_tools(dir: &Path) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let bin = dir.join("fake-bin");
    std::fs::create_dir_all(&bin).unwrap();
    let stub = r#"#!/bin/bash
{ printf '%s' "$(basename "$0")"; printf ' %s' "$@"; printf '\n'; } >>"$FAKE_LOG"
case "$(basename "$0") $1" in
"sbatch "*) echo "123;cluster" ;;
"kubectl get") echo "SuccessCriteriaMet Complete" ;;
"aws batch") echo "job-1" ;;
esac
"#;
    for tool in ["sbatch", "kubectl", "aws"] {
        std::fs::write(bin.join(tool), stub).unwrap();
        std::fs::set_permissions(bin.join(tool), std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    bin
}

/// Run `bash script` from `cwd` with the fake tools first on PATH; returns its output and the
/// command lines the tools saw.
fn run_script(script: &Path, cwd: &Path, bin: &Path, env: &[(&str, &str)]) -> (Output, String) {
    let log = bin.join("log");
    let _ = std::fs::remove_file(&log);
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let mut cmd = Command::new("bash");
    cmd.arg(script).current_dir(cwd).env("PATH", path).env("FAKE_LOG", &log).env("BISCALE_K8S_POLL", "0");
    for var in ["BISCALE_SHARD_FAIL", "SLURM_ARRAY_TASK_ID", "AWS_BATCH_JOB_ARRAY_INDEX", "JOB_COMPLETION_INDEX"] {
        cmd.env_remove(var);
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    (out, std::fs::read_to_string(&log).unwrap_or_default())
}

fn bash_n(path: &Path) {
    let out = Command::new("bash").arg("-n").arg(path).output().unwrap();
    assert!(out.status.success(), "{} is not valid bash: {out:?}", path.display());
}

/// Every file named `name` under `dir` (its links not followed).
fn find_named(dir: &Path, name: &str, found: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if e.file_name() == name {
            found.push(p.clone());
        }
        if e.file_type().unwrap().is_dir() {
            find_named(&p, name, found);
        }
    }
}

#[test]
fn k8s_and_batch_write_an_indexed_job_and_an_array_job_request() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    let root = d.join("plan");
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "3", "--out", s(&root)], &[]));
    let manifest = root.join("manifest.json");
    let m = s(&manifest);
    let bin = fake_tools(d);

    // Kubernetes: an indexed Job, one completion per shard, and a plain merge Job.
    let out = ok(biscale(
        &["shard", "k8s", m, "--image", "ghcr.io/you/biscale:1", "--cpus", "4", "--mem", "3Gi", "--namespace", "prt"],
        &[],
    ));
    assert!(out.contains("submit with: bash") && out.contains("k8s/submit.sh"), "{out}");
    let job = job_file(&root.join("k8s/shards.yaml"));
    assert_eq!((job["apiVersion"].as_str(), job["kind"].as_str()), (Some("batch/v1"), Some("Job")), "{job}");
    assert_eq!(job["metadata"]["name"], "biscale-shard-shards");
    assert_eq!(job["metadata"]["namespace"], "prt");
    assert_eq!(job["metadata"]["annotations"]["biscale/manifest"], m);
    let spec = &job["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    assert_eq!(spec["completions"], 3);
    assert_eq!(spec["parallelism"], 3, "every shard at once by default");
    assert!(spec["backoffLimitPerIndex"].as_u64().is_some(), "{spec}");
    let pod = &spec["template"]["spec"];
    assert_eq!(pod["restartPolicy"], "Never");
    let c = &pod["containers"][0];
    assert_eq!(c["image"], "ghcr.io/you/biscale:1");
    assert_eq!(c["command"], serde_json::json!(["biscale"]));
    assert_eq!(c["args"], serde_json::json!(["shard", "run", m]));
    assert_eq!(c["env"], serde_json::json!([{"name": "RAYON_NUM_THREADS", "value": "4"}]));
    for kind in ["requests", "limits"] {
        assert_eq!(c["resources"][kind], serde_json::json!({"cpu": "4", "memory": "3Gi"}), "{kind}");
    }
    // The plan's folder, at its own path (hostPath: nodes mount the shared file system there).
    assert_eq!(c["workingDir"], s(&root));
    assert_eq!(
        pod["volumes"],
        serde_json::json!([{"name": "shared-0", "hostPath": {"path": s(&root), "type": "Directory"}}])
    );
    assert_eq!(c["volumeMounts"], serde_json::json!([{"name": "shared-0", "mountPath": s(&root)}]));
    let merge = job_file(&root.join("k8s/merge.yaml"));
    assert_eq!(merge["metadata"]["name"], "biscale-shard-merge");
    assert!(merge["spec"].get("completionMode").is_none(), "{merge}");
    let c = &merge["spec"]["template"]["spec"]["containers"][0];
    let (merged, cache) = (root.join("merged"), root.join("cache"));
    assert_eq!(c["args"], serde_json::json!(["shard", "merge", m, "--out", s(&merged), "--cache-dir", s(&cache)]));
    // The small plan's estimate is under the 1 GiB floor.
    assert_eq!(c["resources"]["limits"]["memory"], "1024Mi");
    let (run, log) = run_script(&root.join("k8s/submit.sh"), d, &bin, &[]);
    assert!(run.status.success(), "{run:?}");
    let lines: Vec<&str> = log.lines().collect();
    assert_eq!(lines[0], "kubectl create --namespace=prt -f shards.yaml", "{log}");
    assert!(lines[1].starts_with("kubectl get --namespace=prt job biscale-shard-shards -o jsonpath="), "{log}");
    assert_eq!(lines[2], "kubectl create --namespace=prt -f merge.yaml", "{log}");

    // --claim: a persistentVolumeClaim at the plan's path; the merge must then write inside it.
    ok(biscale(&["shard", "k8s", m, "--claim", "scratch", "--parallelism", "2"], &[]));
    let job = job_file(&root.join("k8s/shards.yaml"));
    assert_eq!(job["spec"]["parallelism"], 2);
    let pod = &job["spec"]["template"]["spec"];
    assert_eq!(
        pod["volumes"],
        serde_json::json!([{"name": "shared-0", "persistentVolumeClaim": {"claimName": "scratch"}}])
    );
    assert_eq!(pod["containers"][0]["volumeMounts"][0]["mountPath"], s(&root));
    assert_eq!(pod["containers"][0]["resources"]["requests"]["memory"], "1024Mi");
    assert_eq!(pod["containers"][0]["image"], format!("biscale:{}", env!("CARGO_PKG_VERSION")));
    let e = failed(biscale(&["shard", "k8s", m, "--claim", "scratch", "--out", s(&d.join("elsewhere/out"))], &[]));
    assert!(e.contains("--claim") && e.contains("inside the plan's folder"), "{e}");
    // Outside the plan's folder, the merge's output's parent is a volume of its own.
    ok(biscale(&["shard", "k8s", m, "--out", s(&d.join("elsewhere/out"))], &[]));
    let merge = job_file(&root.join("k8s/merge.yaml"));
    let vols = &merge["spec"]["template"]["spec"]["volumes"];
    assert_eq!(vols[1]["hostPath"]["path"], s(&d.join("elsewhere")), "{vols}");

    // AWS Batch: an array job of one child per shard, the merge depending on it.
    let image = "123456789012.dkr.ecr.us-east-1.amazonaws.com/biscale:1";
    let out =
        ok(biscale(&["shard", "batch", m, "--job-queue", "q1", "--cpus", "2", "--mem", "2048", "--image", image], &[]));
    assert!(out.contains("batch/submit.sh"), "{out}");
    let batch = root.join("batch");
    let shards = job_file(&batch.join("shards.json"));
    assert_eq!(shards["jobName"], "biscale-shard-shards");
    assert_eq!(shards["jobQueue"], "q1");
    assert_eq!(shards["jobDefinition"], "biscale-shard");
    assert_eq!(shards["arrayProperties"]["size"], 3);
    let o = &shards["containerOverrides"];
    assert_eq!(o["command"], serde_json::json!(["biscale", "shard", "run", m]));
    assert_eq!(o["environment"], serde_json::json!([{"name": "RAYON_NUM_THREADS", "value": "2"}]));
    assert_eq!(
        o["resourceRequirements"],
        serde_json::json!([{"type": "VCPU", "value": "2"}, {"type": "MEMORY", "value": "2048"}])
    );
    let merge = job_file(&batch.join("merge.json"));
    assert_eq!(merge["dependsOn"], serde_json::json!([{"jobId": "SHARDS_JOB_ID"}]));
    assert!(merge.get("arrayProperties").is_none());
    let o = &merge["containerOverrides"];
    assert_eq!(
        o["command"],
        serde_json::json!(["biscale", "shard", "merge", m, "--out", s(&merged), "--cache-dir", s(&cache)])
    );
    assert_eq!(o["resourceRequirements"][1], serde_json::json!({"type": "MEMORY", "value": "1024"}));
    let def = job_file(&batch.join("job-definition.json"));
    assert_eq!(def["jobDefinitionName"], "biscale-shard");
    assert_eq!(def["containerProperties"]["image"], image);
    assert_eq!(def["containerProperties"]["mountPoints"][0]["containerPath"], s(&root));
    assert_eq!(def["containerProperties"]["volumes"][0]["host"]["sourcePath"], s(&root));
    let readme = std::fs::read_to_string(batch.join("README.txt")).unwrap();
    assert!(readme.contains("aws batch submit-job --cli-input-json file://shards.json"), "{readme}");
    assert!(readme.contains("--depends-on jobId=") && readme.contains("SHARDS_JOB_ID"), "{readme}");
    let (run, log) = run_script(&batch.join("submit.sh"), d, &bin, &[]);
    assert!(run.status.success() && String::from_utf8_lossy(&run.stdout).contains("merge job-1"), "{run:?}");
    let lines: Vec<&str> = log.lines().collect();
    assert_eq!(lines[0], "aws batch register-job-definition --cli-input-json file://job-definition.json", "{log}");
    assert_eq!(lines[1], "aws batch submit-job --cli-input-json file://shards.json --query jobId --output text");
    assert_eq!(
        lines[2],
        "aws batch submit-job --cli-input-json file://merge.json --depends-on jobId=job-1 --query jobId --output text"
    );
    // Without --image, no definition is registered (an earlier one is left as it is, unused:
    // biscale deletes no file).
    ok(biscale(&["shard", "batch", m], &[]));
    assert!(batch.join("job-definition.json").exists());
    assert_eq!(job_file(&batch.join("shards.json"))["jobQueue"], "biscale");
    let (run, log) = run_script(&batch.join("submit.sh"), d, &bin, &[]);
    assert!(run.status.success() && !log.contains("register-job-definition"), "{run:?} {log}");

    // A plan of one shard: a single job, which gets its index from the command line.
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "1", "--out", s(&d.join("one"))], &[]));
    let one = d.join("one/manifest.json");
    let out = ok(biscale(&["shard", "batch", s(&one)], &[]));
    assert!(out.contains("1 shard") && out.contains("--index 0"), "{out}");
    let shards = job_file(&d.join("one/batch/shards.json"));
    assert!(shards.get("arrayProperties").is_none(), "{shards}");
    assert_eq!(
        shards["containerOverrides"]["command"],
        serde_json::json!(["biscale", "shard", "run", s(&one), "--index", "0"])
    );
    // More shards than an AWS Batch array holds is refused (Kubernetes takes them).
    let mut big: biscale::shard::Manifest = serde_json::from_str(&std::fs::read_to_string(&one).unwrap()).unwrap();
    big.vertices = 10_001;
    big.shards = (0..10_001)
        .map(|i| biscale::shard::ShardSpec {
            index: i,
            first_vertex: i,
            end_vertex: i + 1,
            dir: format!("shards/{i:05}"),
            outputs: big.shards[0].outputs.clone(),
        })
        .collect();
    big.checksum = biscale::shard::manifest_checksum(&big);
    std::fs::write(&one, serde_json::to_string(&big).unwrap()).unwrap();
    let e = failed(biscale(&["shard", "batch", s(&one)], &[]));
    assert!(e.contains("10001 shards") && e.contains("10000"), "{e}");
    ok(biscale(&["shard", "k8s", s(&one)], &[]));
    assert_eq!(job_file(&d.join("one/k8s/shards.yaml"))["spec"]["completions"], 10_001);

    // The index from each scheduler's variable; two that disagree, or none, are refused.
    let e = failed(biscale(&["shard", "run", m], &[("JOB_COMPLETION_INDEX", "7")]));
    assert!(e.contains("there is no shard 7"), "{e}");
    let e = failed(biscale(&["shard", "run", m], &[("AWS_BATCH_JOB_ARRAY_INDEX", "9")]));
    assert!(e.contains("there is no shard 9"), "{e}");
    let e = failed(biscale(&["shard", "run", m], &[("SLURM_ARRAY_TASK_ID", "2"), ("AWS_BATCH_JOB_ARRAY_INDEX", "1")]));
    assert!(e.contains("SLURM_ARRAY_TASK_ID is 2") && e.contains("AWS_BATCH_JOB_ARRAY_INDEX is 1"), "{e}");
    let e = failed(biscale(&["shard", "run", m], &[("JOB_COMPLETION_INDEX", "two")]));
    assert!(e.contains("JOB_COMPLETION_INDEX") && e.contains("not a shard index"), "{e}");
    let e = failed(biscale(&["shard", "run", m], &[]));
    assert!(e.contains("--index") && e.contains("SLURM_ARRAY_TASK_ID") && e.contains("JOB_COMPLETION_INDEX"), "{e}");
}

/// Issue class "a scheduler's job file carries what the manifest or a flag says": every field
/// of the manifest and every flag of `shard sbatch`, `k8s` and `batch` is fed newlines,
/// `$(touch PWNED)`, backticks, quotes, `;`, unicode and very long text. A value the manifest
/// check or a flag's character set refuses is refused by name; a value that is accepted (a plan
/// folder, merge output and cache with such names; manifest fields no job file carries) is
/// written only quoted (shell) or serialised (YAML/JSON): the scripts are valid bash that,
/// run with stand-ins for sbatch, kubectl and aws, and as the array task and merge
/// themselves, run no injected command, and the job files hold every path verbatim.
#[test]
fn every_scheduler_writer_quotes_hostile_manifest_fields() {
    let long = format!("{}$(touch PWNED)", "y".repeat(3000));
    let hostile: Vec<&str> = vec![
        "a\nb $(touch PWNED)",
        "`touch PWNED`",
        "'; touch PWNED; '",
        "\"$(touch PWNED)\"",
        "x && touch PWNED #",
        "ünï ✓ 😀 \u{85}\u{2028}\u{7f}",
        "\\'\\\"",
        &long,
    ];
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = config(d);
    let bin = fake_tools(d);
    // A plan folder whose path holds control characters (a newline, NEL): no quoting protects
    // an `#SBATCH` line, so `shard sbatch` refuses it by the character; the job files of k8s
    // and AWS Batch (JSON) carry it verbatim.
    let controls = d.join("p\u{85}x\nshould not run");
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "2", "--out", s(&controls)], &[]));
    let cm = controls.join("manifest.json");
    let e = failed(biscale(&["shard", "sbatch", s(&cm)], &[]));
    assert!(e.contains("control character") && e.contains("#SBATCH"), "{e}");
    ok(biscale(&["shard", "k8s", s(&cm)], &[]));
    ok(biscale(&["shard", "batch", s(&cm), "--job-queue", "q"], &[]));
    assert!(!controls.join("slurm").exists() && controls.join("k8s/shards.yaml").is_file());
    // A plan folder whose path holds all the rest (but `/`), long.
    let name = "p l'a\"n $(touch PWNED) `touch PWNED`; touch PWNED & ü😀\u{2028}\\x";
    let root = d.join(name).join("L".repeat(200)).join(format!("{name}-2"));
    ok(biscale(&["shard", "plan", s(&cfg), "--shards", "2", "--out", s(&root)], &[]));
    let manifest = root.join("manifest.json");
    let m = s(&manifest);
    let good = std::fs::read_to_string(&manifest).unwrap();
    let plan: biscale::shard::Manifest = serde_json::from_str(&good).unwrap();
    let writers: [&[&str]; 3] = [&["shard", "sbatch", m], &["shard", "k8s", m], &["shard", "batch", m]];
    let with = |w: &[&str], more: &[&str]| -> Vec<String> { w.iter().chain(more).map(|a| a.to_string()).collect() };
    let call = |args: Vec<String>| biscale(&args.iter().map(String::as_str).collect::<Vec<_>>(), &[]);
    let forge = |m: &biscale::shard::Manifest| {
        let forged = biscale::shard::Manifest { checksum: biscale::shard::manifest_checksum(m), ..m.clone() };
        std::fs::write(&manifest, serde_json::to_string(&forged).unwrap()).unwrap();
    };

    // Fields the manifest check refuses, even with the checksum recomputed for the edit.
    let mut refused: Vec<(&str, biscale::shard::Manifest)> = vec![];
    for h in &hostile {
        refused.push(("experiment", biscale::shard::Manifest { experiment: h.to_string(), ..plan.clone() }));
        let mut m = plan.clone();
        m.shards[0].dir = format!("shards/{h}");
        refused.push(("shard 0", m));
        refused.push(("format", biscale::shard::Manifest { format: h.to_string(), ..plan.clone() }));
    }
    refused.push(("version", biscale::shard::Manifest { version: 99, ..plan.clone() }));
    refused.push(("shards", biscale::shard::Manifest { shards: vec![], vertices: 0, ..plan.clone() }));
    for (what, m) in &refused {
        forge(m);
        for w in writers {
            let e = failed(call(with(w, &[])));
            assert!(e.contains(what), "{w:?} {what}: {e}");
        }
    }
    // An edit without the checksum recomputed is refused as such.
    let edited = biscale::shard::Manifest { experiment: "x; touch PWNED".into(), ..plan.clone() };
    std::fs::write(&manifest, serde_json::to_string(&edited).unwrap()).unwrap();
    for w in writers {
        assert!(failed(call(with(w, &[]))).contains("checksum"));
    }
    for sub in ["slurm", "k8s", "batch"] {
        assert!(!root.join(sub).exists(), "a refused manifest wrote {sub}/");
    }

    // Fields the check accepts, which no job file carries: hostile text in every one of them
    // (and an absurd estimate) is written nowhere, and the memory saturates.
    let field = format!("FIELD {}", hostile.join(" "));
    let mut fields = plan.clone();
    fields.created_by = field.clone();
    fields.config = PathBuf::from(&field);
    fields.config_hash = field.clone();
    fields.overrides = vec![field.clone()];
    fields.shape = field.clone();
    for c in &mut fields.separable {
        (c.label, c.kind) = (field.clone(), field.clone());
    }
    for c in &mut fields.in_merge {
        (c.label, c.kind, c.why) = (field.clone(), field.clone(), field.clone());
    }
    for sh in &mut fields.shards {
        sh.outputs = vec![field.clone()];
    }
    fields.estimate.shard_peak_bytes = u64::MAX;
    fields.estimate.merge_peak_bytes = u64::MAX;
    fields.estimate.nnz_per_vertex = f64::MAX;
    forge(&fields);
    for w in writers {
        ok(call(with(w, &[])));
    }
    let mib = u64::MAX.div_ceil(1 << 20);
    for (sub, mem) in
        [("slurm", format!("--mem={mib}M")), ("k8s", format!("\"{mib}Mi\"")), ("batch", format!("\"{mib}\""))]
    {
        let texts: Vec<String> = std::fs::read_dir(root.join(sub))
            .unwrap()
            .flatten()
            .filter(|e| e.path().is_file())
            .map(|e| std::fs::read_to_string(e.path()).unwrap())
            .collect();
        assert!(texts.iter().all(|t| !t.contains("FIELD")), "{sub}: a manifest field reached a job file");
        assert!(texts.iter().any(|t| t.contains(&mem)), "{sub}: no saturated memory {mem}");
    }
    // A plain name that is no DNS label becomes one (with a hash); one that leaves nothing is
    // refused by k8s alone.
    forge(&biscale::shard::Manifest { experiment: format!("Odd.Name_{}", "x".repeat(91)), ..plan.clone() });
    for w in writers {
        ok(call(with(w, &[])));
    }
    let job = job_file(&root.join("k8s/shards.yaml"));
    let k8s_name = job["metadata"]["name"].as_str().unwrap().to_string();
    let dns = |n: &str| {
        (1..=63).contains(&n.len())
            && n.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
            && !n.starts_with('-')
            && !n.ends_with('-')
    };
    assert!(dns(&k8s_name) && k8s_name.starts_with("biscale-odd-name-x"), "{k8s_name}");
    let batch_name = job_file(&root.join("batch/shards.json"))["jobName"].as_str().unwrap().to_string();
    assert!(batch_name.len() <= 128 && batch_name.bytes().all(|b| b.is_ascii_alphanumeric() || b"-_".contains(&b)));
    forge(&biscale::shard::Manifest { experiment: "___".into(), ..plan.clone() });
    let e = failed(call(with(writers[1], &[])));
    assert!(e.contains("DNS-1123"), "{e}");
    ok(call(with(writers[0], &[])));
    ok(call(with(writers[2], &[])));
    std::fs::write(&manifest, &good).unwrap();

    // Every flag that takes text, given each hostile value, is refused by name; numbers are
    // numbers, at least 1.
    let flags: [(&[&str], &[&str]); 3] = [
        (writers[0], &["--partition", "--time", "--mem", "--merge-mem"]),
        (writers[1], &["--image", "--mem", "--merge-mem", "--namespace", "--claim"]),
        (writers[2], &["--job-queue", "--job-definition", "--image"]),
    ];
    for (w, names) in flags {
        for flag in names {
            for h in &hostile {
                let e = failed(call(with(w, &[&format!("{flag}={h}")])));
                assert!(e.contains(flag), "{w:?} {flag}={h:?}: {e}");
            }
        }
    }
    for (w, flag) in [(writers[0], "--cpus"), (writers[1], "--cpus"), (writers[1], "--parallelism")]
        .into_iter()
        .chain([(writers[2], "--cpus"), (writers[2], "--mem"), (writers[2], "--merge-mem")])
    {
        for h in &hostile {
            let out = call(with(w, &[&format!("{flag}={h}")]));
            let e = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success() && e.contains(flag), "{w:?} {flag}={h:?}: {e}");
        }
        if w != writers[0] {
            let out = call(with(w, &[&format!("{flag}=0")]));
            let e = String::from_utf8_lossy(&out.stderr);
            let says = e.contains("at least 1") || e.contains("is not in 1..=");
            assert!(!out.status.success() && e.contains(flag) && says, "{w:?} {flag}=0: {e}");
        }
    }
    let e = failed(call(with(writers[2], &["--image=biscale:1", "--job-definition=def:3"])));
    assert!(e.contains("--job-definition") && e.contains("register"), "{e}");

    // Paths are accepted: a merge output and cache with hostile names, beside the plan.
    let out_dir = d.join(format!("out {}", hostile[..7].join(" ").replace('/', "_"))).join("merged");
    let cache_dir = d.join(format!("cache {}", hostile[2]));
    let paths = ["--out", s(&out_dir), "--cache-dir", s(&cache_dir)];
    let sbatch_out = ok(call(with(writers[0], &paths)));
    ok(call(with(writers[1], &[&["--namespace", "prt"], &paths[..]].concat())));
    ok(call(with(writers[2], &[&["--image", "biscale:1"], &paths[..]].concat())));
    assert!(sbatch_out.contains("submit with: bash"), "{sbatch_out}");

    // The shell: valid, and running it runs only what biscale wrote.
    let scripts = ["slurm/shards.sbatch", "slurm/merge.sbatch", "slurm/submit.sh", "k8s/submit.sh", "batch/submit.sh"];
    for script in scripts {
        bash_n(&root.join(script));
    }
    let (run, log) = run_script(&root.join("slurm/submit.sh"), d, &bin, &[]);
    assert!(run.status.success(), "{run:?}");
    assert_eq!(log, "sbatch --parsable shards.sbatch\nsbatch --parsable --dependency=afterok:123 merge.sbatch\n");
    let (run, log) = run_script(&root.join("k8s/submit.sh"), d, &bin, &[]);
    assert!(run.status.success() && log.lines().count() == 3 && log.contains("-f merge.yaml"), "{run:?} {log}");
    let (run, log) = run_script(&root.join("batch/submit.sh"), d, &bin, &[]);
    assert!(run.status.success() && log.lines().count() == 3 && log.contains("jobId=job-1"), "{run:?} {log}");
    // The array task and the merge themselves reach biscale with the manifest's path whole:
    // it names it in its refusals (a shard that is not in the plan; shards not yet run).
    let shown = manifest.display().to_string();
    let (run, _) = run_script(&root.join("slurm/shards.sbatch"), d, &bin, &[("SLURM_ARRAY_TASK_ID", "7")]);
    let e = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && e.contains("there is no shard 7") && e.contains(&shown), "{e}");
    let (run, _) = run_script(&root.join("slurm/merge.sbatch"), d, &bin, &[]);
    let e = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && e.contains("2 of 2 shards are not complete") && e.contains(&shown), "{e}");
    assert!(!out_dir.exists(), "the refused merge wrote its output");

    // The job files hold every path verbatim, and run as a container runtime would run them
    // (the list, no shell), they reach biscale whole.
    let (root_s, out_s, cache_s) = (s(&root), s(&out_dir), s(&cache_dir));
    let shards = job_file(&root.join("k8s/shards.yaml"));
    let pod = &shards["spec"]["template"]["spec"];
    assert_eq!(pod["containers"][0]["args"], serde_json::json!(["shard", "run", m]));
    assert_eq!(pod["containers"][0]["workingDir"], root_s);
    assert_eq!(shards["metadata"]["annotations"]["biscale/manifest"], m);
    let merge = job_file(&root.join("k8s/merge.yaml"));
    let pod = &merge["spec"]["template"]["spec"];
    assert_eq!(
        pod["containers"][0]["args"],
        serde_json::json!(["shard", "merge", m, "--out", out_s, "--cache-dir", cache_s])
    );
    let host_paths: Vec<&str> =
        pod["volumes"].as_array().unwrap().iter().map(|v| v["hostPath"]["path"].as_str().unwrap()).collect();
    assert_eq!(host_paths, [root_s, s(out_dir.parent().unwrap()), cache_s]);
    let mounts: Vec<&str> = pod["containers"][0]["volumeMounts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["mountPath"].as_str().unwrap())
        .collect();
    assert_eq!(mounts, host_paths);
    let batch_shards = job_file(&root.join("batch/shards.json"));
    assert_eq!(batch_shards["containerOverrides"]["command"], serde_json::json!(["biscale", "shard", "run", m]));
    let batch_merge = job_file(&root.join("batch/merge.json"));
    assert_eq!(
        batch_merge["containerOverrides"]["command"],
        serde_json::json!(["biscale", "shard", "merge", m, "--out", out_s, "--cache-dir", cache_s])
    );
    let def = job_file(&root.join("batch/job-definition.json"));
    assert_eq!(def["containerProperties"]["mountPoints"][0]["containerPath"], root_s);
    let runs = [
        (&shards["spec"]["template"]["spec"]["containers"][0]["args"], ("JOB_COMPLETION_INDEX", "7")),
        (&batch_shards["containerOverrides"]["command"], ("AWS_BATCH_JOB_ARRAY_INDEX", "7")),
    ];
    for (args, var) in runs {
        let args: Vec<&str> = args.as_array().unwrap().iter().map(|a| a.as_str().unwrap()).collect();
        let args = if args[0] == "biscale" { &args[1..] } else { &args[..] };
        let e = failed(biscale(args, &[var]));
        assert!(e.contains("there is no shard 7") && e.contains(&shown), "{var:?}: {e}");
    }

    let mut pwned = vec![];
    find_named(d, "PWNED", &mut pwned);
    assert!(pwned.is_empty() && !Path::new("PWNED").exists(), "an injected command ran: {pwned:?}");
}
