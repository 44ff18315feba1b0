//! The job files of the sharded precompute ([`crate::shard`]) for the array schedulers that run
//! its shards, and the shard index a task reads from its scheduler:
//!
//! * **sbatch** ([`sbatch`]): `slurm/shards.sbatch` (a job array over the shards),
//!   `slurm/merge.sbatch` and `slurm/submit.sh`, which submits the merge with
//!   `--dependency=afterok` on the array;
//! * **k8s** ([`k8s`]): `k8s/shards.yaml` (a `batch/v1` Job with `completionMode: Indexed`, one
//!   completion per shard), `k8s/merge.yaml` (a plain Job), `k8s/README.txt` and
//!   `k8s/submit.sh`, which creates the merge once the shards' Job completed;
//! * **batch** ([`batch`]): `batch/shards.json` (an AWS Batch `SubmitJob` request of an array
//!   job), `batch/merge.json` (its `dependsOn` filled in by `submit.sh`), `batch/README.txt`,
//!   `batch/submit.sh`, and with `--image` `batch/job-definition.json`;
//! * [`index_from`]: `--index`, else `SLURM_ARRAY_TASK_ID`, `AWS_BATCH_JOB_ARRAY_INDEX` or
//!   `JOB_COMPLETION_INDEX` (Kubernetes), refusing two that disagree.
//!
//! Every value from the manifest or a flag reaches a written file only through serde (the
//! Kubernetes YAML is JSON, which is YAML 1.2, its characters from DEL to U+FFFF escaped) or
//! [`sh_quote`] (shell), after [`Manifest::load`]'s checks and each flag's own character set.
//! Slurm is the path tested on a real cluster (`scripts/slurm-test.sh`); the Kubernetes and AWS
//! Batch files are checked field by field (`tools/cli/tests/cli/shard.rs`): no cluster of
//! theirs runs here. Every file is written atomically.

use crate::error::{PipelineError, Result};
use crate::shard::Manifest;
use crate::store::shared::SharedFolder;
use biscale_core::io::{write_atomic_bytes, ContentHash};
use serde_json::{json, Value};
use std::path::{Component, Path, PathBuf};

fn invalid(path: &Path, what: impl Into<String>) -> PipelineError {
    PipelineError::Mismatch { path: path.to_path_buf(), what: what.into() }
}

/// The variables an array task may find its index in, in the order [`index_from`] reads them:
/// Slurm's, AWS Batch's and a Kubernetes indexed Job's.
pub const INDEX_VARS: [&str; 3] = ["SLURM_ARRAY_TASK_ID", "AWS_BATCH_JOB_ARRAY_INDEX", "JOB_COMPLETION_INDEX"];

/// The shard index from `--index`, else from the scheduler's variable ([`INDEX_VARS`]) in the
/// process's environment.
pub fn index_from(arg: Option<usize>) -> Result<usize> {
    index_from_lookup(arg, |var| std::env::var_os(var).map(|v| v.to_string_lossy().into_owned()))
}

/// [`index_from`] over `lookup` (a variable's value, if set): `--index` wins; else every
/// variable of [`INDEX_VARS`] that is set must be a whole number, and all of them the same.
pub fn index_from_lookup(arg: Option<usize>, lookup: impl Fn(&str) -> Option<String>) -> Result<usize> {
    if let Some(i) = arg {
        return Ok(i);
    }
    let mut found: Option<(&str, usize)> = None;
    for var in INDEX_VARS {
        let Some(value) = lookup(var) else { continue };
        let i: usize = value
            .trim()
            .parse()
            .map_err(|_| invalid(Path::new(var), format!("is {value:?}, not a shard index (a whole number from 0)")))?;
        match found {
            Some((first, j)) if j != i => {
                return Err(invalid(
                    Path::new("--index"),
                    format!("{first} is {j} but {var} is {i}: two schedulers' indices disagree; pass --index I"),
                ))
            }
            Some(_) => {}
            None => found = Some((var, i)),
        }
    }
    found.map(|(_, i)| i).ok_or_else(|| {
        invalid(
            Path::new("--index"),
            "no shard index: pass --index I, or run as an array task of Slurm (SLURM_ARRAY_TASK_ID), AWS Batch \
             (AWS_BATCH_JOB_ARRAY_INDEX) or a Kubernetes indexed Job (JOB_COMPLETION_INDEX)",
        )
    })
}

/// Options of `shard sbatch`: Slurm's own, passed through as `#SBATCH` lines.
#[derive(Clone, Debug, Default)]
pub struct SbatchOptions {
    pub partition: Option<String>,
    /// `--time` (minutes, or Slurm's `D-HH:MM:SS`).
    pub time: Option<String>,
    /// `--mem` per shard (default: the plan's estimate with a quarter more, at least 1 GiB).
    pub mem: Option<String>,
    /// `--mem` of the merge job (default: the plan's estimate with a quarter more).
    pub merge_mem: Option<String>,
    pub cpus: usize,
    /// Arguments of the merge (`--out`, `--cache-dir`), as `biscale shard merge` takes them.
    pub merge_out: Option<PathBuf>,
    pub merge_cache_dir: Option<PathBuf>,
}

/// A shell word: single-quoted unless plainly safe.
pub fn sh_quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c)) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// MiB for a job whose estimate is `bytes`: a quarter more, at least 1 GiB (saturating: a
/// manifest's estimate is read from a file and may be absurd; a scheduler refuses what no node
/// has).
fn mem_mib(bytes: u64) -> u64 {
    bytes.saturating_add(bytes / 4).div_ceil(1 << 20).max(1024)
}

/// Slurm's `--mem` of a job whose estimate is `bytes` ([`mem_mib`]).
pub fn mem_default(bytes: u64) -> String {
    format!("{}M", mem_mib(bytes))
}

/// Write `files` (name, text, executable) into `root/sub` (`sub` the scheduler's folder beside
/// the manifest), all or none, over nothing but files the plan folder's marker proves biscale
/// wrote there ([`SharedFolder`]: the plan folder may be a folder of other files); returns
/// their paths.
fn write_all(root: &Path, sub: &str, about: &str, files: Vec<(&str, String, bool)>) -> Result<Vec<PathBuf>> {
    use std::os::unix::fs::PermissionsExt;
    let names: Vec<String> = files.iter().map(|(name, ..)| format!("{sub}/{name}")).collect();
    let shared = SharedFolder::begin(root, about, &names.iter().map(String::as_str).collect::<Vec<_>>())?;
    let dir = shared.path().join(sub);
    std::fs::create_dir_all(&dir).map_err(|source| PipelineError::Io { path: dir.clone(), source })?;
    let mut staged = vec![];
    for (name, text, executable) in files {
        let p = dir.join(name);
        write_atomic_bytes(&p, text.as_bytes())?;
        let mode = if executable { 0o755 } else { 0o644 };
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode))
            .map_err(|source| PipelineError::Io { path: p.clone(), source })?;
        staged.push(p);
    }
    let published = shared.publish()?;
    Ok(staged.iter().map(|p| published.path(p)).collect())
}

/// `shard sbatch`: write `slurm/shards.sbatch`, `slurm/merge.sbatch` and `slurm/submit.sh`
/// beside the manifest; returns their paths.
pub fn sbatch(path: &Path, o: &SbatchOptions) -> Result<Vec<PathBuf>> {
    let (m, root) = Manifest::load(path)?;
    // Values that go onto `#SBATCH` lines, where shell quoting does not apply: Slurm's own
    // characters only (no space, quote, newline or `$`).
    for (flag, value) in
        [("--partition", &o.partition), ("--time", &o.time), ("--mem", &o.mem), ("--merge-mem", &o.merge_mem)]
    {
        if let Some(v) = value {
            let plain = (1..=100).contains(&v.len())
                && v.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-' | b':' | b',' | b'+'));
            if !plain {
                return Err(invalid(
                    path,
                    format!("{flag} {v:?}: use letters, digits and `._-:,+` only (as Slurm writes it)"),
                ));
            }
        }
    }
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let manifest = abs(path);
    let dir = abs(&root).join("slurm");
    let logs = dir.join("logs");
    // The log paths and the experiment's name go onto `#SBATCH` and comment lines, which no
    // quoting protects: a newline there would end the comment and run the next line.
    let logs_text = logs.display().to_string();
    if let Some(c) = logs_text.chars().find(|c| c.is_control()) {
        return Err(invalid(
            path,
            format!(
                "the plan folder's path holds the control character {c:?}, which cannot be written into an #SBATCH \
                 line; plan into a folder whose path has none"
            ),
        ));
    }
    let exe = std::env::current_exe().map_err(|source| PipelineError::Io { path: "biscale".into(), source })?;
    let q = |p: &Path| sh_quote(&p.display().to_string());
    let header = |name: &str, mem: &str| {
        let mut h = format!(
            "#!/bin/bash\n# Written by `biscale shard sbatch` for {}.\n#SBATCH --job-name=biscale-{}-{name}\n#SBATCH --cpus-per-task={}\n#SBATCH --mem={}\n",
            m.experiment.replace(|c: char| c.is_control(), "?"),
            sh_quote(&m.experiment.replace(|c: char| c.is_control(), "?")),
            o.cpus.max(1),
            sh_quote(mem),
        );
        if let Some(p) = &o.partition {
            h += &format!("#SBATCH --partition={}\n", sh_quote(p));
        }
        if let Some(t) = &o.time {
            h += &format!("#SBATCH --time={}\n", sh_quote(t));
        }
        h
    };
    let shard_mem = o.mem.clone().unwrap_or_else(|| mem_default(m.estimate.shard_peak_bytes));
    let merge_mem = o.merge_mem.clone().unwrap_or_else(|| mem_default(m.estimate.merge_peak_bytes));
    let threads = "export RAYON_NUM_THREADS=\"${SLURM_CPUS_PER_TASK:-1}\"\n";
    let shards = format!(
        "{}#SBATCH --array=0-{}\n#SBATCH --output={}\nset -euo pipefail\n{threads}exec {} shard run {}\n",
        header("shards", &shard_mem),
        m.shards.len() - 1,
        q(&logs.join("shard-%A_%a.out")),
        q(&exe),
        q(&manifest),
    );
    let mut merge_args = String::new();
    if let Some(out) = &o.merge_out {
        merge_args += &format!(" --out {}", q(&abs(out)));
    }
    if let Some(c) = &o.merge_cache_dir {
        merge_args += &format!(" --cache-dir {}", q(&abs(c)));
    }
    let merge = format!(
        "{}#SBATCH --output={}\nset -euo pipefail\n{threads}exec {} shard merge {}{merge_args}\n",
        header("merge", &merge_mem),
        q(&logs.join("merge-%j.out")),
        q(&exe),
        q(&manifest),
    );
    let submit = "#!/bin/bash\n# Submit the shards as a job array, then the merge once every shard succeeded.\n\
        # Prints `shards <job id>` and `merge <job id>`. A failed shard leaves the merge pending\n\
        # (DependencyNeverSatisfied): scancel it, rerun the shard with\n\
        # `sbatch --array=<i> shards.sbatch`, then `sbatch merge.sbatch`.\n\
        set -euo pipefail\ncd \"$(dirname \"$0\")\"\n\
        shards=$(sbatch --parsable shards.sbatch)\nshards=${shards%%;*}\n\
        merge=$(sbatch --parsable --dependency=afterok:\"$shards\" merge.sbatch)\nmerge=${merge%%;*}\n\
        echo \"shards $shards\"\necho \"merge $merge\"\n"
        .to_string();
    let about = format!("biscale shard sbatch {}", manifest.display());
    let files = vec![("shards.sbatch", shards, true), ("merge.sbatch", merge, true), ("submit.sh", submit, true)];
    let written = write_all(&abs(&root), "slurm", &about, files)?;
    // Slurm writes its logs there: made only now, inside the `slurm/` folder biscale has just
    // written (never through a link, so a refused plan folder gets no `logs/` anywhere).
    if !std::fs::symlink_metadata(&dir).is_ok_and(|m| m.is_dir()) {
        return Err(invalid(path, format!("{} is not the folder biscale wrote (a link?)", dir.display())));
    }
    match std::fs::create_dir(&logs) {
        Err(e) if e.kind() != std::io::ErrorKind::AlreadyExists => {
            return Err(PipelineError::Io { path: logs.clone(), source: e })
        }
        _ => {}
    }
    Ok(written)
}

/// What `shard k8s` and `shard batch` wrote: every file, the script that submits them, and
/// notes for people.
#[derive(Clone, Debug)]
pub struct JobFiles {
    pub files: Vec<PathBuf>,
    pub submit: PathBuf,
    pub notes: Vec<String>,
}

/// `p` absolute, `.` and `..` resolved by its text (no link followed).
fn absolute(p: &Path) -> PathBuf {
    let a = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut out = PathBuf::new();
    for c in a.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

/// A path as the text a job file carries; refused unless UTF-8 (a lossy one would name
/// another file).
fn utf8(p: &Path, what: &str) -> Result<String> {
    p.to_str()
        .map(str::to_string)
        .ok_or_else(|| invalid(p, format!("{what} is not UTF-8, which a JSON or YAML job file cannot carry")))
}

/// What a container's shard and merge run with: the manifest and the plan's folder as
/// absolute paths, the merge's output and cache folders (the plan's `merged` and `cache`
/// unless given: a container's own folders vanish with it), and the folders every container
/// must share with the submitter (the plan's folder first; then the merge's output's parent
/// and its cache, unless they lie inside one listed already).
struct Shared {
    m: Manifest,
    manifest: String,
    root: PathBuf,
    /// `root` as text.
    root_text: String,
    out: String,
    cache: String,
    dirs: Vec<PathBuf>,
}

fn shared(path: &Path, out: Option<&Path>, cache: Option<&Path>) -> Result<Shared> {
    let (m, _) = Manifest::load(path)?;
    let manifest = absolute(path);
    let root = manifest.parent().map_or_else(|| PathBuf::from("/"), Path::to_path_buf);
    let out = out.map_or_else(|| root.join("merged"), absolute);
    let cache = cache.map_or_else(|| root.join("cache"), absolute);
    let mut dirs = vec![root.clone()];
    for d in [out.parent().map_or_else(|| out.clone(), Path::to_path_buf), cache.clone()] {
        if !dirs.iter().any(|s| d.starts_with(s)) {
            dirs.push(d);
        }
    }
    for d in &dirs {
        utf8(d, "a shared folder")?;
    }
    Ok(Shared {
        manifest: utf8(&manifest, "the manifest's path")?,
        root_text: utf8(&root, "the plan's folder")?,
        root,
        out: utf8(&out, "--out")?,
        cache: utf8(&cache, "--cache-dir")?,
        m,
        dirs,
    })
}

/// Check a flag's value against a character set, naming the flag and the set when it fails.
fn check(path: &Path, flag: &str, value: &str, ok: bool, what: &str) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(invalid(path, format!("{flag} {value:?}: {what}")))
    }
}

/// A container image reference (`registry/name:tag@digest`).
fn is_image(s: &str) -> bool {
    (1..=512).contains(&s.len())
        && s.starts_with(|c: char| c.is_ascii_alphanumeric())
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-/:@".contains(&b))
}

/// A DNS-1123 label (a Kubernetes namespace, a Job's name): 1 to 63 of `a-z0-9-`, a letter or
/// digit at both ends.
pub fn is_dns_label(s: &str) -> bool {
    (1..=63).contains(&s.len())
        && s.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
        && !s.starts_with('-')
        && !s.ends_with('-')
}

/// A DNS-1123 subdomain (a persistentVolumeClaim's name): labels joined by `.`, 253 at most.
fn is_dns_subdomain(s: &str) -> bool {
    s.len() <= 253 && s.split('.').all(|l| !l.is_empty() && l.len() <= 63 && is_dns_label(l))
}

/// A Kubernetes memory quantity: a number and an optional suffix (`4Gi`, `1280Mi`, `2G`).
fn is_quantity(s: &str) -> bool {
    let digits_end = s.find(|c: char| !c.is_ascii_digit() && c != '.').unwrap_or(s.len());
    let (number, suffix) = s.split_at(digits_end);
    let mut parts = number.split('.');
    let whole = parts.next().unwrap_or("");
    let fraction = parts.next();
    s.len() <= 32
        && !whole.is_empty()
        && parts.next().is_none()
        && fraction.is_none_or(|f| !f.is_empty())
        && ["", "Ki", "Mi", "Gi", "Ti", "Pi", "Ei", "k", "M", "G", "T", "P", "E"].contains(&suffix)
}

/// An AWS Batch job queue or job definition: a name (`name`, `name:revision`) or an ARN.
fn is_aws_name(s: &str) -> bool {
    (1..=512).contains(&s.len())
        && s.starts_with(|c: char| c.is_ascii_alphanumeric())
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || b"-_:/.".contains(&b))
}

/// A name AWS Batch registers (a job definition's, a job's): 1 to 128 letters, digits, `-`,
/// `_`, a letter or digit first.
fn is_aws_plain(s: &str) -> bool {
    (1..=128).contains(&s.len())
        && s.starts_with(|c: char| c.is_ascii_alphanumeric())
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// A DNS-1123 label for `name` of at most `max` (at least 8) characters: lowercase, every
/// other character `-`, trimmed of `-`; when that changed or shortened the name, cut to fit
/// and ended by `-` and 6 hex digits of the name's hash (so two names that map alike stay
/// apart). `None` when nothing is left.
pub fn dns_label(name: &str, max: usize) -> Option<String> {
    let lower: String =
        name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '-' }).collect();
    let trimmed = lower.trim_matches('-');
    if trimmed.is_empty() {
        return None;
    }
    if trimmed == name && trimmed.len() <= max {
        return Some(trimmed.to_string());
    }
    let hash = ContentHash::default().write(name.as_bytes()).finish128();
    let head = trimmed[..trimmed.len().min(max.saturating_sub(7).max(1))].trim_end_matches('-');
    Some(format!("{head}-{:06x}", hash & 0xff_ffff))
}

/// The pretty JSON of `v`, every character from DEL to U+FFFF as a `\u` escape: JSON as any
/// YAML reader takes it too (YAML refuses raw C1 controls, and YAML 1.1 readers fold a raw
/// NEL, LS or PS in a quoted string into a space). Characters past U+FFFF stay raw: YAML
/// refuses the surrogate escapes JSON would need, and prints them as they are.
fn portable_json(v: &Value) -> String {
    let text = serde_json::to_string_pretty(v).expect("a JSON value serializes");
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        if ('\x7f'..='\u{ffff}').contains(&c) {
            out += &format!("\\u{:04x}", c as u32);
        } else {
            out.push(c);
        }
    }
    out + "\n"
}

/// Options of `shard k8s`.
#[derive(Clone, Debug, Default)]
pub struct K8sOptions {
    /// The image holding `biscale` on its PATH (default: `biscale:<this version>`).
    pub image: Option<String>,
    /// CPUs of every pod (requests and limits), and the shards' threads.
    pub cpus: usize,
    /// Memory of a shard's pod, a Kubernetes quantity (default: the plan's estimate + 25%).
    pub mem: Option<String>,
    /// Memory of the merge's pod (default: the plan's estimate + 25%).
    pub merge_mem: Option<String>,
    pub namespace: Option<String>,
    /// A persistentVolumeClaim holding the plan's folder, mounted at its path (default: a
    /// hostPath volume of the same path, for nodes that mount the shared file system there).
    pub claim: Option<String>,
    /// Pods running at once (default: every shard).
    pub parallelism: Option<usize>,
    pub merge_out: Option<PathBuf>,
    pub merge_cache_dir: Option<PathBuf>,
}

/// Retries of each shard's pod before its index counts as failed.
const K8S_BACKOFF_PER_INDEX: u32 = 2;

/// `k8s/README.txt`, for people (no value of the plan's in it).
const K8S_README: &str =
    "Written by `biscale shard k8s`: Kubernetes Jobs (batch/v1) for the shards of a plan and its merge.
The YAML files are JSON (which is YAML 1.2; kubectl reads them as JSON).

  shards.yaml  an indexed Job: one completion per shard, the shard's index from JOB_COMPLETION_INDEX
  merge.yaml   a plain Job running `biscale shard merge` (its output and cache in the plan's folder
               unless --out and --cache-dir said otherwise)
  submit.sh    creates shards.yaml, waits until that Job has completed, then creates merge.yaml

Every pod reads and writes the plan's folder at the absolute path it was planned at: on a file
system every node mounts there (the hostPath volumes, by default), or on the persistentVolumeClaim
that --claim names, mounted at that path. The config, its mesh and env map must be readable in the
image at their planned paths too (on the same volume, or in the image), and the image must hold
`biscale` on its PATH.

A shard that still fails after its retries fails the shards' Job, and submit.sh stops:
`biscale shard status MANIFEST` names the shard and the command that reruns it; once every shard is
complete, `kubectl create -f merge.yaml`.
";

/// The image `shard k8s` runs, after its options are checked against the plan: names,
/// quantities, a claim that holds every shared folder, and counts of at least 1.
fn check_k8s(path: &Path, o: &K8sOptions, sh: &Shared) -> Result<String> {
    let default_image = format!("biscale:{}", env!("CARGO_PKG_VERSION"));
    let image = o.image.clone().unwrap_or(default_image);
    check(path, "--image", &image, is_image(&image), "use letters, digits and `._-/:@` only, a letter or digit first")?;
    for (flag, v) in [("--mem", &o.mem), ("--merge-mem", &o.merge_mem)] {
        if let Some(v) = v {
            check(path, flag, v, is_quantity(v), "use a Kubernetes memory quantity such as 4Gi or 1280Mi")?;
        }
    }
    if let Some(ns) = &o.namespace {
        check(path, "--namespace", ns, is_dns_label(ns), "a namespace is 1 to 63 of `a-z0-9-`, no `-` at either end")?;
    }
    if let Some(c) = &o.claim {
        check(path, "--claim", c, is_dns_subdomain(c), "a claim's name is `a-z0-9-` and `.`, 253 at most")?;
        if let Some(d) = sh.dirs.iter().find(|d| !d.starts_with(&sh.root)) {
            return Err(invalid(
                d,
                "with --claim (mounted at the plan's folder) the merge's --out and --cache-dir must lie inside the \
                 plan's folder",
            ));
        }
    }
    if o.cpus == 0 {
        return Err(invalid(path, "--cpus must be at least 1"));
    }
    Ok(image)
}

/// The pods' volumes and mounts: the claim, mounted at the plan's folder, or a hostPath per
/// shared folder (the plan's folder must exist, the others are made).
fn k8s_volumes(o: &K8sOptions, sh: &Shared) -> Result<(Vec<Value>, Vec<Value>)> {
    Ok(match &o.claim {
        Some(claim) => (
            vec![json!({"name": "shared-0", "persistentVolumeClaim": {"claimName": claim}})],
            vec![json!({"name": "shared-0", "mountPath": sh.root_text})],
        ),
        None => sh
            .dirs
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let d = utf8(d, "a shared folder")?;
                let kind = if i == 0 { "Directory" } else { "DirectoryOrCreate" };
                Ok((
                    json!({"name": format!("shared-{i}"), "hostPath": {"path": d, "type": kind}}),
                    json!({"name": format!("shared-{i}"), "mountPath": d}),
                ))
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .unzip(),
    })
}

/// `k8s/submit.sh`: create the shards' Job, wait until it has completed, create the merge's.
fn k8s_submit(namespace: Option<&str>, shards_job: &str) -> String {
    let ns = namespace.map_or(String::new(), |n| format!(" --namespace={}", sh_quote(n)));
    format!(
        "#!/bin/bash\n# Written by `biscale shard k8s`: create the indexed Job over the shards, wait until it has\n\
         # completed, then create the merge Job. A shard that still fails after {K8S_BACKOFF_PER_INDEX} retries fails the\n\
         # Job: `biscale shard status MANIFEST` names it and the command that reruns it; then\n\
         # `kubectl create -f merge.yaml`. BISCALE_K8S_POLL sets the seconds between checks (30).\n\
         set -euo pipefail\ncd \"$(dirname \"$0\")\"\n\
         kubectl create{ns} -f shards.yaml\n\
         while :; do\n    \
             state=$(kubectl get{ns} job {} -o 'jsonpath={{.status.conditions[?(@.status==\"True\")].type}}')\n    \
             case \"$state\" in\n    \
             *Complete*) break ;;\n    \
             *Failed*)\n        \
                 echo \"submit.sh: the shards' Job failed ($state)\" >&2\n        \
                 exit 1\n        \
                 ;;\n    \
             esac\n    \
             sleep \"${{BISCALE_K8S_POLL:-30}}\"\n\
         done\n\
         kubectl create{ns} -f merge.yaml\n",
        sh_quote(shards_job),
    )
}

/// `shard k8s`: write `k8s/shards.yaml` (an indexed Job over the shards), `k8s/merge.yaml`,
/// `k8s/README.txt` and `k8s/submit.sh` beside the manifest.
pub fn k8s(path: &Path, o: &K8sOptions) -> Result<JobFiles> {
    let sh = shared(path, o.merge_out.as_deref(), o.merge_cache_dir.as_deref())?;
    let m = &sh.m;
    let image = check_k8s(path, o, &sh)?;
    let parallelism = o.parallelism.unwrap_or(m.shards.len());
    if parallelism == 0 {
        return Err(invalid(path, "--parallelism must be at least 1"));
    }
    let base = dns_label(&m.experiment, 48)
        .ok_or_else(|| invalid(path, format!("the experiment's name {:?} leaves no DNS-1123 label", m.experiment)))?;
    let name = |role: &str| format!("biscale-{base}-{role}");
    let cpus = o.cpus.to_string();
    let shard_mem = o.mem.clone().unwrap_or_else(|| format!("{}Mi", mem_mib(m.estimate.shard_peak_bytes)));
    let merge_mem = o.merge_mem.clone().unwrap_or_else(|| format!("{}Mi", mem_mib(m.estimate.merge_peak_bytes)));

    let (volumes, mounts) = k8s_volumes(o, &sh)?;
    let labels = json!({"app.kubernetes.io/name": "biscale", "app.kubernetes.io/instance": base});
    let metadata = |role: &str| {
        let mut meta = json!({
            "name": name(role),
            "labels": labels,
            "annotations": {"biscale/experiment": m.experiment, "biscale/manifest": sh.manifest},
        });
        if let Some(ns) = &o.namespace {
            meta["namespace"] = json!(ns);
        }
        meta
    };
    let pod = |container: &str, args: Vec<&str>, mem: &str| {
        json!({
            "metadata": {"labels": labels},
            "spec": {
                "restartPolicy": "Never",
                "containers": [{
                    "name": container,
                    "image": image,
                    "command": ["biscale"],
                    "args": args,
                    "workingDir": sh.root_text,
                    "env": [{"name": "RAYON_NUM_THREADS", "value": cpus}],
                    "resources": {
                        "requests": {"cpu": cpus, "memory": mem},
                        "limits": {"cpu": cpus, "memory": mem},
                    },
                    "volumeMounts": mounts,
                }],
                "volumes": volumes,
            },
        })
    };
    let shards = json!({
        "apiVersion": "batch/v1",
        "kind": "Job",
        "metadata": metadata("shards"),
        "spec": {
            "completionMode": "Indexed",
            "completions": m.shards.len(),
            "parallelism": parallelism,
            "backoffLimitPerIndex": K8S_BACKOFF_PER_INDEX,
            "template": pod("shard", vec!["shard", "run", &sh.manifest], &shard_mem),
        },
    });
    let merge_args = vec!["shard", "merge", &sh.manifest, "--out", &sh.out, "--cache-dir", &sh.cache];
    let merge = json!({
        "apiVersion": "batch/v1",
        "kind": "Job",
        "metadata": metadata("merge"),
        "spec": {"backoffLimit": 0, "template": pod("merge", merge_args, &merge_mem)},
    });
    let submit = k8s_submit(o.namespace.as_deref(), &name("shards"));
    let files = write_all(
        &sh.root,
        "k8s",
        &format!("biscale shard k8s {}", path.display()),
        vec![
            ("shards.yaml", portable_json(&shards), false),
            ("merge.yaml", portable_json(&merge), false),
            ("README.txt", K8S_README.to_string(), false),
            ("submit.sh", submit, true),
        ],
    )?;
    let notes = vec![format!(
        "the pods mount {} at the same path{}; the image {image} must hold biscale on its PATH",
        sh.dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", "),
        o.claim.as_ref().map_or(" (hostPath: every node must mount the shared file system there)".into(), |c| format!(
            " (from persistentVolumeClaim {c})"
        )),
    )];
    Ok(JobFiles { submit: files[3].clone(), files, notes })
}

/// Options of `shard batch`.
#[derive(Clone, Debug, Default)]
pub struct BatchOptions {
    /// The job queue (default: `biscale`).
    pub job_queue: Option<String>,
    /// The job definition (default: `biscale-<experiment>`, which `--image` registers).
    pub job_definition: Option<String>,
    /// With it, `batch/job-definition.json` registers a definition running this image.
    pub image: Option<String>,
    pub cpus: usize,
    /// MiB of a shard (default: the plan's estimate + 25%).
    pub mem_mib: Option<u64>,
    /// MiB of the merge (default: the plan's estimate + 25%).
    pub merge_mem_mib: Option<u64>,
    pub merge_out: Option<PathBuf>,
    pub merge_cache_dir: Option<PathBuf>,
}

/// Children of an AWS Batch array job: 2 to 10,000.
pub const BATCH_ARRAY_MAX: usize = 10_000;

/// The placeholder of `batch/merge.json`'s `dependsOn`, replaced by `--depends-on`.
pub const BATCH_DEPENDS_PLACEHOLDER: &str = "SHARDS_JOB_ID";

/// `shard batch`'s queue, job definition and job names' stem, after its options are checked:
/// names AWS accepts, an image with a definition it can register, counts of at least 1.
fn check_batch(path: &Path, o: &BatchOptions, experiment: &str) -> Result<(String, String, String)> {
    let queue = o.job_queue.clone().unwrap_or_else(|| "biscale".into());
    check(path, "--job-queue", &queue, is_aws_name(&queue), "a queue's name or ARN: letters, digits and `-_:/.`")?;
    let jobs_base = format!("biscale-{}", experiment.replace('.', "_"));
    let definition = o.job_definition.clone().unwrap_or_else(|| jobs_base.clone());
    check(
        path,
        "--job-definition",
        &definition,
        is_aws_name(&definition),
        "a job definition's name, name:revision or ARN: letters, digits and `-_:/.`",
    )?;
    if let Some(image) = &o.image {
        check(
            path,
            "--image",
            image,
            is_image(image),
            "use letters, digits and `._-/:@` only, a letter or digit first",
        )?;
        check(
            path,
            "--job-definition",
            &definition,
            is_aws_plain(&definition),
            "with --image it names the definition to register: 1 to 128 letters, digits, `-` and `_`",
        )?;
    }
    if o.cpus == 0 {
        return Err(invalid(path, "--cpus must be at least 1"));
    }
    for (flag, v) in [("--mem", o.mem_mib), ("--merge-mem", o.merge_mem_mib)] {
        if v == Some(0) {
            return Err(invalid(path, format!("{flag} must be at least 1 (MiB)")));
        }
    }
    Ok((queue, definition, jobs_base))
}

/// `batch/README.txt` for a plan of `n` shards.
fn batch_readme(n: usize) -> String {
    format!(
        "Written by `biscale shard batch`: AWS Batch requests for the {n} shard(s) of the plan and its merge.\n\
         \n\
         Every job reads and writes the plan's folder at the absolute path it was planned at, so the job\n\
         definition must mount the shared file system (EFS, FSx, NFS on the hosts) there, and the\n\
         config, its mesh and env map must be readable at their planned paths too. With --image,\n\
         job-definition.json registers such a definition (host volumes of the shared folders):\n\
         \n    aws batch register-job-definition --cli-input-json file://job-definition.json\n\
         \n\
         Submit the shards, then the merge once every shard succeeded (submit.sh does both):\n\
         \n    aws batch submit-job --cli-input-json file://shards.json\n    \
         aws batch submit-job --cli-input-json file://merge.json --depends-on jobId=<the shards' jobId>\n\
         \n\
         merge.json's dependsOn holds the placeholder {BATCH_DEPENDS_PLACEHOLDER}, which --depends-on replaces.\n\
         A shard that fails leaves the merge never runnable: `biscale shard status MANIFEST` names the\n\
         shard and the command that reruns it; then submit merge.json again.\n{}",
        if n == 1 {
            "\nThe plan has 1 shard: shards.json is a single job, not an array (arrays hold 2 to 10000).\n"
        } else {
            ""
        }
    )
}

/// `batch/submit.sh`: register `job-definition.json` when this call wrote one, submit the
/// shards, then the merge depending on them.
fn batch_submit(with_image: bool) -> String {
    // Registers job-definition.json only when this call wrote one (with --image): a copy of an
    // earlier call's is left as it is, and not used.
    let register = if with_image {
        "aws batch register-job-definition --cli-input-json file://job-definition.json >/dev/null\n"
    } else {
        ""
    };
    format!(
        "#!/bin/bash\n# Written by `biscale shard batch`: register job-definition.json if it wrote one, submit\n\
         # shards.json, then merge.json depending on it. Prints `shards <job id>` and `merge <job id>`.\n\
         set -euo pipefail\ncd \"$(dirname \"$0\")\"\n\
         {register}\
         shards=$(aws batch submit-job --cli-input-json file://shards.json --query jobId --output text)\n\
         merge=$(aws batch submit-job --cli-input-json file://merge.json --depends-on \"jobId=$shards\" --query jobId --output text)\n\
         echo \"shards $shards\"\necho \"merge $merge\"\n"
    )
}

/// `shard batch`: write `batch/shards.json` (an AWS Batch `SubmitJob` request of an array job
/// over the shards), `batch/merge.json`, `batch/README.txt`, `batch/submit.sh` and, with an
/// image, `batch/job-definition.json` beside the manifest.
pub fn batch(path: &Path, o: &BatchOptions) -> Result<JobFiles> {
    let sh = shared(path, o.merge_out.as_deref(), o.merge_cache_dir.as_deref())?;
    let m = &sh.m;
    let n = m.shards.len();
    if n > BATCH_ARRAY_MAX {
        return Err(invalid(
            path,
            format!(
                "{n} shards: an AWS Batch array job holds 2 to {BATCH_ARRAY_MAX} children; plan again with \
                 --shards {BATCH_ARRAY_MAX} or fewer"
            ),
        ));
    }
    let (queue, definition, jobs_base) = check_batch(path, o, &m.experiment)?;
    let cpus = o.cpus.to_string();
    let shard_mem = o.mem_mib.unwrap_or_else(|| mem_mib(m.estimate.shard_peak_bytes)).to_string();
    let merge_mem = o.merge_mem_mib.unwrap_or_else(|| mem_mib(m.estimate.merge_peak_bytes)).to_string();
    let resources = |mem: &str| json!([{"type": "VCPU", "value": cpus}, {"type": "MEMORY", "value": mem}]);
    let env = json!([{"name": "RAYON_NUM_THREADS", "value": cpus}]);
    let mut run = vec!["biscale", "shard", "run", &sh.manifest];
    let mut notes = vec![];
    if n == 1 {
        // A job of one: no array, so no AWS_BATCH_JOB_ARRAY_INDEX to read the index from.
        run.extend(["--index", "0"]);
        notes.push(
            "the plan has 1 shard: batch/shards.json submits a single job (AWS Batch arrays hold 2 to 10000), \
             which runs it with --index 0"
                .to_string(),
        );
    }
    let mut shards = json!({
        "jobName": format!("{jobs_base}-shards"),
        "jobQueue": queue,
        "jobDefinition": definition,
        "containerOverrides": {"command": run, "environment": env, "resourceRequirements": resources(&shard_mem)},
    });
    if n > 1 {
        shards["arrayProperties"] = json!({"size": n});
    }
    let merge = json!({
        "jobName": format!("{jobs_base}-merge"),
        "jobQueue": queue,
        "jobDefinition": definition,
        "dependsOn": [{"jobId": BATCH_DEPENDS_PLACEHOLDER}],
        "containerOverrides": {
            "command": ["biscale", "shard", "merge", &sh.manifest, "--out", &sh.out, "--cache-dir", &sh.cache],
            "environment": env,
            "resourceRequirements": resources(&merge_mem),
        },
    });
    let mut files = vec![("shards.json", portable_json(&shards), false), ("merge.json", portable_json(&merge), false)];
    if let Some(image) = &o.image {
        let dirs = sh.dirs.iter().map(|d| utf8(d, "a shared folder")).collect::<Result<Vec<_>>>()?;
        let definition = json!({
            "jobDefinitionName": definition,
            "type": "container",
            "containerProperties": {
                "image": image,
                "command": ["biscale", "--version"],
                "resourceRequirements": resources(&shard_mem),
                "volumes": dirs.iter().enumerate().map(|(i, d)| json!({"name": format!("shared-{i}"), "host": {"sourcePath": d}})).collect::<Vec<_>>(),
                "mountPoints": dirs.iter().enumerate().map(|(i, d)| json!({"sourceVolume": format!("shared-{i}"), "containerPath": d, "readOnly": false})).collect::<Vec<_>>(),
            },
        });
        files.push(("job-definition.json", portable_json(&definition), false));
    }
    let readme = batch_readme(n);
    files.push(("README.txt", readme, false));
    let submit = batch_submit(o.image.is_some());
    files.push(("submit.sh", submit, true));
    let files = write_all(&sh.root, "batch", &format!("biscale shard batch {}", path.display()), files)?;
    let submit = files.last().expect("submit.sh").clone();
    notes.push(format!(
        "the jobs run {} and need {} mounted at the same path",
        if o.image.is_some() { "the job definition of job-definition.json" } else { "the job definition you name" },
        sh.dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", ")
    ));
    Ok(JobFiles { files, submit, notes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        let map: HashMap<&str, &str> = vars.iter().copied().collect();
        move |k| map.get(k).map(|v| v.to_string())
    }

    #[test]
    fn an_absurd_memory_estimate_gives_a_saturated_mem_not_an_overflow() {
        // Regression (hostile manifest): `bytes + bytes / 4` overflowed (a panic in debug, a
        // wrong `--mem` in release) on an estimate of 2^64 - 1 bytes.
        assert_eq!(mem_default(u64::MAX), format!("{}M", u64::MAX.div_ceil(1 << 20)));
        assert_eq!(mem_default(0), "1024M");
        assert_eq!(mem_default(4 << 30), "5120M");
    }

    #[test]
    fn the_index_comes_from_the_flag_else_from_the_one_scheduler_variable_set() {
        let none = env(&[]);
        assert_eq!(index_from_lookup(Some(3), env(&[("SLURM_ARRAY_TASK_ID", "5")])).unwrap(), 3);
        assert_eq!(index_from_lookup(None, env(&[("SLURM_ARRAY_TASK_ID", " 5\n")])).unwrap(), 5);
        assert_eq!(index_from_lookup(None, env(&[("AWS_BATCH_JOB_ARRAY_INDEX", "7")])).unwrap(), 7);
        assert_eq!(index_from_lookup(None, env(&[("JOB_COMPLETION_INDEX", "0")])).unwrap(), 0);
        // Two that agree are one index.
        let both = env(&[("SLURM_ARRAY_TASK_ID", "2"), ("JOB_COMPLETION_INDEX", "2")]);
        assert_eq!(index_from_lookup(None, both).unwrap(), 2);

        let e = index_from_lookup(None, none).unwrap_err().to_string();
        for source in ["--index", "SLURM_ARRAY_TASK_ID", "AWS_BATCH_JOB_ARRAY_INDEX", "JOB_COMPLETION_INDEX"] {
            assert!(e.contains(source), "{e}");
        }
        let e = index_from_lookup(None, env(&[("AWS_BATCH_JOB_ARRAY_INDEX", "1"), ("JOB_COMPLETION_INDEX", "4")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("AWS_BATCH_JOB_ARRAY_INDEX is 1") && e.contains("JOB_COMPLETION_INDEX is 4"), "{e}");
        for bad in ["x", "-1", "", "1.5", "$(id)"] {
            let e = index_from_lookup(None, env(&[("JOB_COMPLETION_INDEX", bad)])).unwrap_err().to_string();
            assert!(e.starts_with("JOB_COMPLETION_INDEX:") && e.contains("not a shard index"), "{bad}: {e}");
        }
        // A bad one is refused even beside a good one.
        let e = index_from_lookup(None, env(&[("SLURM_ARRAY_TASK_ID", "1"), ("AWS_BATCH_JOB_ARRAY_INDEX", "one")]))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("AWS_BATCH_JOB_ARRAY_INDEX:"), "{e}");
    }

    #[test]
    fn names_become_dns_labels_or_are_refused() {
        assert_eq!(dns_label("bunny", 48).as_deref(), Some("bunny"));
        assert_eq!(dns_label("bunny-2", 48).as_deref(), Some("bunny-2"));
        // Changed names carry a hash, so `Bunny_x` and `bunny-x` stay apart.
        let (a, b) = (dns_label("Bunny_x", 48).unwrap(), dns_label("bunny.x", 48).unwrap());
        assert!(a.starts_with("bunny-x-") && b.starts_with("bunny-x-") && a != b, "{a} {b}");
        let long = dns_label(&"a".repeat(100), 48).unwrap();
        assert_eq!(long.len(), 48);
        let cut = dns_label(&format!("{}_{}", "a".repeat(40), "b".repeat(40)), 48).unwrap();
        assert!(cut.len() <= 48 && !cut.contains("--"), "{cut}");
        for name in ["a", "Bunny_x", "_x_", "9.lives", &"Z".repeat(100), &format!("{}-_", "a".repeat(40))] {
            let label = dns_label(name, 48).unwrap();
            assert!(is_dns_label(&label) && label.len() <= 48, "{name}: {label}");
            assert!(is_dns_label(&format!("biscale-{label}-shards")), "{name}");
        }
        assert_eq!(dns_label("___", 48), None);
        assert_eq!(dns_label("", 48), None);
    }

    #[test]
    fn flag_character_sets() {
        for ok in ["biscale:0.1.0", "ghcr.io/you/biscale:v1", "reg:5000/b@sha256:abc123"] {
            assert!(is_image(ok), "{ok}");
        }
        for bad in ["", "-x", "a b", "a\nb", "$(id)", "a;b", "ä", "'a'"] {
            assert!(!is_image(bad), "{bad:?}");
        }
        for ok in ["4Gi", "1280Mi", "2G", "512", "1.5Gi"] {
            assert!(is_quantity(ok), "{ok}");
        }
        for bad in ["", "Gi", "4 Gi", "4GB", "1.", ".5Gi", "1..2", "4Gi;x", "1e3"] {
            assert!(!is_quantity(bad), "{bad:?}");
        }
        assert!(is_dns_subdomain("shared.scratch-1") && !is_dns_subdomain("a..b") && !is_dns_subdomain("A"));
        assert!(is_aws_name("arn:aws:batch:us-east-1:123456789012:job-queue/q-1") && !is_aws_name("q 1"));
        assert!(is_aws_plain("biscale-bunny_2") && !is_aws_plain("def:3"));
    }

    #[test]
    fn json_past_ascii_is_escaped_and_reads_back_verbatim() {
        let text = "ü\u{7f}\u{85}\u{2028}\u{feff}😀\n'\"$(x)`";
        let out = portable_json(&json!({ "v": text }));
        assert!(out.chars().all(|c| (c.is_ascii() && c != '\x7f') || c > '\u{ffff}'), "{out}");
        assert!(out.contains("\\u0085") && out.contains("\\u2028") && out.contains('😀'), "{out}");
        let back: Value = serde_json::from_str(&out).unwrap();
        assert_eq!(back["v"], text);
    }

    #[test]
    fn quoting_is_one_shell_word() {
        assert_eq!(sh_quote("plain/path-1.txt"), "plain/path-1.txt");
        assert_eq!(sh_quote(""), "''");
        assert_eq!(sh_quote("it's $(x)"), r"'it'\''s $(x)'");
    }
}
