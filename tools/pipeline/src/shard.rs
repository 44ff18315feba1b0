//! The sharded precompute: `biscale shard plan | run | status | merge | sbatch`.
//!
//! Tracing `T` and the compressors that work row by row outgrow one machine long before the
//! runtime does, so the precompute splits over vertex ranges that a Slurm job array (or plain
//! local processes) runs anywhere, and a merge step puts the pieces back together:
//!
//! * **plan** writes `manifest.json` (versioned): the config's content hash, the vertex range of
//!   every shard and the files it writes, which compressors run in the shards and which in the
//!   merge (and why), and memory estimates. Ranges hold whole multiples of every separable
//!   compressor's `vertex_multiple` (biclustering's blocks), so each shard's parts are exactly
//!   the whole matrix's.
//! * **run** builds `T`'s rows for one range with the whole mesh's transfer scene
//!   ([`biscale_core::transfer::build_range`]: the rows are bit for bit those of a whole
//!   build), compresses them with every separable compressor
//!   ([`biscale_core::compress::Compressor::compress_part`]) and writes them, each file
//!   atomically, then `done.json` with every file's XXH3-128 last. A shard without `done.json`
//!   is not complete, whatever else its folder holds; rerunning one starts by removing it, so
//!   reruns are idempotent.
//! * **merge** checks every shard (missing, stale or corrupt ones are listed with the command
//!   that reruns them), merges the parts' forms
//!   ([`biscale_core::compress::Compressor::merge_parts`]), and runs the rest of the
//!   pipeline ([`crate::run::run_with`]): gathers, shading and the report. When every step
//!   after the shards is row-separable (no compressor that needs all of `T`, such as CPCA's
//!   global k-means; no SH method; no animation) it **streams** `T`: the f64 baseline `T L`,
//!   `T`'s record and the forms' error terms are passes over the shards' files, two parts in
//!   memory at once ([`biscale_core::transfer::TransferView`]), so its peak is the forms,
//!   the per-row vectors and the images, not `T`. Otherwise it stacks `T` whole, and the plan
//!   says why ([`Manifest::stacked`]). Either way `T`'s products, the forms and the images are
//!   byte-identical to `biscale run` of the same config (only timings differ).
//! * **sbatch** writes a job-array script over the shards, a merge script and `submit.sh`,
//!   which submits the merge with `--dependency=afterok` on the array.
//! * **k8s**, **batch**: the same for Kubernetes and AWS Batch (all the writers: [`crate::scheduler`]).
//!
//! No scheduler, queue or protocol of our own: Slurm places and retries the shards; the
//! shared file system carries everything.

use crate::error::{PipelineError, Result};
use crate::estimate::{human, Available};
use crate::experiment::config::{CompressorSetting, Experiment};
use crate::stages::transfer::{build_compressor, Precomputed, TransferRows};
use crate::store::staging::StagedDir;
use crate::store::RunOptions;
use biscale_core::compress::{CompressContext, CompressedForm, Compressor, Separability};
use biscale_core::io::{write_atomic_bytes, ContentHash};
use biscale_core::transfer::{self, PartFile, TransferMatrix, TransferParts};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The manifest's `format` and current `version`.
pub const MANIFEST_FORMAT: &str = "biscale-shard-manifest";
/// Version 2 added `stacked` (whether the merge streams `T`) and a shard's base and
/// per-non-zero memory; a version-1 manifest is refused with "plan again" (the shards stay
/// complete: their records name the config's hash and their ranges, not the manifest).
pub const MANIFEST_VERSION: u32 = 2;
/// Most shards a plan may have (a job array of more is no longer a plan a scheduler takes).
pub const MAX_SHARDS: usize = 100_000;

/// Whether `s` is a name a generated script may carry as it is: 1 to 100 letters, digits,
/// `.`, `_`, `-`, not starting with `.` or `-` (an experiment's name, a shard's folder).
pub fn is_plain_name(s: &str) -> bool {
    (1..=100).contains(&s.len())
        && !s.starts_with(['.', '-'])
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
}

/// The manifest's own checksum: XXH3-128 of its JSON with the checksum field empty.
pub fn manifest_checksum(m: &Manifest) -> String {
    let unsigned = Manifest { checksum: String::new(), ..m.clone() };
    let json = serde_json::to_string(&unsigned).expect("manifest serializes");
    format!("{:032x}", ContentHash::default().write(json.as_bytes()).finish128())
}
/// A finished shard's record (`done.json`).
pub const DONE_FORMAT: &str = "biscale-shard-done";
/// Environment variable naming shard indices (comma-separated) that fail on purpose after
/// tracing, before they are complete: how the Slurm test shows a failed shard being rerun.
pub const FAIL_VAR: &str = "BISCALE_SHARD_FAIL";

/// What `shard plan` writes: everything a shard and the merge need to agree on.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// The biscale that planned it.
    pub created_by: String,
    pub experiment: String,
    /// The config, as an absolute path (shards run from any directory).
    pub config: PathBuf,
    /// XXH3-128 of the config's and the mesh file's bytes ([`config_hash`]).
    pub config_hash: String,
    /// The `--set KEY=VALUE` overrides the plan was made with; every shard and the merge
    /// apply them to the config too.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub overrides: Vec<String>,
    /// XXH3-128 of the manifest as `plan` wrote it ([`manifest_checksum`]): a manifest edited
    /// since (a shard's range or folder, the experiment's name) is refused.
    #[serde(default)]
    pub checksum: String,
    pub vertices: usize,
    /// `T`'s shape, for people.
    pub shape: String,
    pub seed: u64,
    /// Every shard but the last holds a multiple of this many vertices.
    pub vertex_multiple: usize,
    /// Compressors that run in the shards, their parts merged.
    pub separable: Vec<ShardedSetting>,
    /// Compressors that run in the merge step, on all of `T`, and why.
    pub in_merge: Vec<MergeSetting>,
    /// Why the merge stacks all of `T` in memory; `None`: every step after the shards is
    /// row-separable and the merge streams `T` from the shards' files ([`stacked_because`]).
    pub stacked: Option<String>,
    pub estimate: ShardEstimate,
    pub shards: Vec<ShardSpec>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardedSetting {
    pub label: String,
    pub kind: String,
    pub vertex_multiple: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MergeSetting {
    pub label: String,
    pub kind: String,
    pub why: String,
}

/// Estimates made at plan time from a sample of traced vertices (`crate::estimate`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardEstimate {
    /// Non-zeros of `T` per vertex (upper estimate of the sample).
    pub nnz_per_vertex: f64,
    /// Peak memory of the largest shard.
    pub shard_peak_bytes: u64,
    /// What of it does not grow with its non-zeros: the process, the whole mesh and its BVH
    /// (every shard holds them), the per-row arrays of its vertices. (Defaults let an older
    /// manifest parse, so its version is what the refusal names.)
    #[serde(default)]
    pub shard_base_bytes: u64,
    /// What it adds per non-zero of `T` (its CSR, the file's arrays, the compressors).
    #[serde(default)]
    pub shard_bytes_per_nnz: f64,
    /// Bytes the largest shard writes.
    pub shard_output_bytes: u64,
    /// Peak memory of the merge (the run's estimate: with `T` whole, or streamed from the
    /// shards' files, two parts at a time).
    pub merge_peak_bytes: u64,
    /// CPU seconds of tracing all of `T`, from the time the sample took (its wall time x
    /// threads, per sampled vertex, x vertices): a rough guide for `--time`; the
    /// compressors come on top.
    #[serde(default)]
    pub transfer_cpu_seconds: f64,
}

/// One shard: its index, vertex range and the files it writes (relative to the manifest).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardSpec {
    pub index: usize,
    pub first_vertex: usize,
    pub end_vertex: usize,
    pub dir: String,
    pub outputs: Vec<String>,
}

/// A complete shard's record, written last.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardDone {
    pub format: String,
    pub index: usize,
    pub config_hash: String,
    pub first_vertex: usize,
    pub end_vertex: usize,
    pub files: Vec<FileSum>,
    pub nnz: u64,
    /// Its `T`'s stored values that are not 0 (what Table I counts), so the merge need not
    /// read `T` to count them; absent in records of older shards.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nonzero: Option<u64>,
    pub rays_traced: u64,
    pub transfer_seconds: f64,
    /// Build seconds of each separable compressor, by label.
    pub compressor_seconds: Vec<(String, f64)>,
    /// Wall seconds of the whole shard (loading, tracing, compressing, writing).
    pub seconds: f64,
    /// CPU seconds of the process (user + system), when readable.
    pub cpu_seconds: Option<f64>,
    pub peak_rss_bytes: Option<u64>,
    pub threads: usize,
    pub host: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FileSum {
    pub name: String,
    pub bytes: u64,
    pub xxh3: String,
}

/// XXH3-128 over the config's text as it runs (the file's bytes, with any `--set` applied)
/// and the mesh file's bytes: what a shard's outputs depend on (the env map and the
/// materials only enter after the merge).
pub fn config_hash(exp: &Experiment) -> Result<String> {
    let mut h = ContentHash::default();
    h.write_str("biscale shard config v1");
    let mesh = biscale_core::io::read_regular(&exp.mesh_path, u64::MAX, "mesh")
        .map_err(|source| PipelineError::Io { path: exp.mesh_path.clone(), source })?;
    for bytes in [exp.source.as_bytes(), &mesh] {
        h.write(&(bytes.len() as u64).to_le_bytes()).write(bytes);
    }
    Ok(format!("{:032x}", h.finish128()))
}

fn file_sum(dir: &Path, name: &str) -> Result<FileSum> {
    let path = dir.join(name);
    let bytes = biscale_core::io::read_regular(&path, u64::MAX, "shard part")
        .map_err(|source| PipelineError::Io { path: path.clone(), source })?;
    Ok(FileSum {
        name: name.to_string(),
        bytes: bytes.len() as u64,
        xxh3: format!("{:032x}", ContentHash::default().write(&bytes).finish128()),
    })
}

fn invalid(path: &Path, what: impl Into<String>) -> PipelineError {
    PipelineError::Mismatch { path: path.to_path_buf(), what: what.into() }
}

/// The file a separable compressor's part is written to, in its shard's folder.
fn form_file(label: &str) -> String {
    let safe: String = label.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
    format!("form-{safe}.bsf")
}
const TRANSFER_FILE: &str = "transfer.bsf";
const DONE_FILE: &str = "done.json";
/// The largest `done.json` read (a shard's record with a checksum per part: a few kilobytes).
const MAX_DONE_BYTES: u64 = 1 << 20;
/// The largest manifest read (one entry per shard, [`MAX_SHARDS`] of them: about 200 bytes
/// each).
const MAX_MANIFEST_BYTES: u64 = 64 << 20;

/// Least common multiple, `None` past `usize`.
fn lcm(a: usize, b: usize) -> Option<usize> {
    fn gcd(a: usize, b: usize) -> usize {
        if b == 0 {
            a
        } else {
            gcd(b, a % b)
        }
    }
    (a / gcd(a, b)).checked_mul(b)
}

/// Why a merge of `exp` must hold all of `T` at once (`in_merge`: the compressors that run
/// in the merge); `None` when every step after the shards is row-separable, so the merge
/// streams `T` from the shards' files.
pub fn stacked_because(exp: &Experiment, in_merge: &[MergeSetting]) -> Option<String> {
    if let Some(c) = in_merge.first() {
        return Some(format!("the compressor {} runs in the merge on all of T ({})", c.label, c.why));
    }
    if let Some(m) = exp.method_settings().first() {
        return Some(format!("the [[methods]] setting {} compares its SH transfer with T projected whole", m.label));
    }
    if exp.file.runtime.animation.any() {
        return Some("[runtime.animation] renders the uncompressed T at every frame".into());
    }
    None
}

/// The plan's compressor settings split into those a shard builds on its rows (with the least
/// common multiple of their vertex blocks, at most the vertex count) and those the merge builds.
fn split_settings(
    exp: &Experiment,
    shape: biscale_core::basis::TransferShape,
    vertices: usize,
) -> Result<(Vec<ShardedSetting>, Vec<MergeSetting>, usize)> {
    let mut separable = vec![];
    let mut in_merge = vec![];
    let mut multiple = 1usize;
    for s in &crate::plan::Plan::new(exp).compressors {
        let c = build_compressor(s)?;
        match c.separability(shape) {
            Separability::Rows { vertex_multiple } => {
                let m = vertex_multiple.max(1);
                multiple = lcm(multiple, m).filter(|&l| l <= vertices.max(1)).unwrap_or(vertices.max(1));
                separable.push(ShardedSetting { label: s.label.clone(), kind: s.kind.clone(), vertex_multiple: m });
            }
            Separability::Whole { why } => {
                in_merge.push(MergeSetting { label: s.label.clone(), kind: s.kind.clone(), why })
            }
        }
    }
    Ok((separable, in_merge, multiple))
}

/// The shards' and the merge's memory, output and time, by the run's model (`crate::estimate`)
/// at the largest shard's vertex count, and why the merge stacks `T` whole (if it does).
fn shard_estimate(
    exp: &Experiment,
    geometry: &crate::stages::scene::Geometry,
    separable: &[ShardedSetting],
    in_merge: &[MergeSetting],
    specs: &[ShardSpec],
) -> Result<(ShardEstimate, Option<String>)> {
    // Estimates: the run's model (crate::estimate) at the largest shard's vertex count.
    let settings = exp.transfer_settings();
    let vertices = geometry.mesh.vertex_count();
    let lighting = crate::stages::scene::load_lighting(exp)?;
    let run = crate::estimate::estimate(exp, geometry, &lighting, true);
    let per_vertex = run.nnz.upper as f64 / vertices.max(1) as f64;
    let largest = specs.iter().map(|s| s.end_vertex - s.first_vertex).max().unwrap_or(0);
    let shard_nnz = (per_vertex * largest as f64).ceil() as u64;
    let threads = rayon::current_num_threads();
    // Every shard holds the whole mesh and its BVH (the rays of its vertices may hit any
    // triangle); the rest grows with its non-zeros.
    let common = crate::estimate::process_and_geometry_bytes(&geometry.mesh);
    let plan_settings: Vec<CompressorSetting> = crate::plan::Plan::new(exp).compressors;
    let shard_at = |nnz: u64| {
        let t = transfer::TransferMemory::new(&settings, largest, nnz, threads);
        let parts: Vec<_> = plan_settings
            .iter()
            .filter(|s| separable.iter().any(|p| p.label == s.label))
            .map(|s| crate::estimate::compressor_memory(s, &settings, largest, nnz, threads as u64))
            .collect();
        // A shard keeps every separable form until it writes them all (after `T`), so each
        // compressor works beside the forms built before it, and `T`'s file is encoded beside
        // all of them (measured on the bunny: the estimate without that was 20% under the peak).
        let forms: u64 = parts.iter().map(|c| c.form).sum();
        let working = parts.iter().map(|c| c.working).max().unwrap_or(0);
        let peak = common + t.build_peak().max(t.csr + forms + working).max(t.save_peak() + forms);
        // What the model leaves out (allocator slack, the binary's own pages): measured at up to
        // 4% of the peak on the small test scene, so a tenth on top keeps the estimate an upper
        // bound (measured 1.06-1.17x the peak on the bunny, the low-vs-all bunny and the temple).
        let peak = peak + peak / 10;
        (peak, t.file_bytes + parts.iter().map(|c| c.form).sum::<u64>())
    };
    let (shard_peak, shard_output) = shard_at(shard_nnz);
    let (shard_base, _) = shard_at(0);
    let stacked = stacked_because(exp, in_merge);
    let merge = match stacked {
        Some(_) => run.peak().bytes,
        None => {
            let shape = crate::estimate::RunShape {
                streamed_part: Some(largest),
                ..crate::estimate::run_shape(geometry, &lighting, true)
            };
            crate::estimate::RunMemory::new(exp, &shape, run.nnz).peak().bytes
        }
    };
    let estimate = ShardEstimate {
        nnz_per_vertex: per_vertex,
        shard_peak_bytes: shard_peak,
        shard_base_bytes: shard_base,
        shard_bytes_per_nnz: (shard_peak - shard_base) as f64 / shard_nnz.max(1) as f64,
        shard_output_bytes: shard_output,
        merge_peak_bytes: merge,
        transfer_cpu_seconds: run.nnz.seconds * threads as f64 * vertices as f64 / run.nnz.sampled.max(1) as f64,
    };
    Ok((estimate, stacked))
}

/// `shard plan`: the manifest of `exp` in `shards` shards (written to `out/manifest.json`).
pub fn plan(exp: &Experiment, shards: usize, out: &Path) -> Result<(PathBuf, Manifest)> {
    if shards == 0 || shards > MAX_SHARDS {
        return Err(invalid(out, format!("--shards must be 1 to {MAX_SHARDS}, not {shards}")));
    }
    if !is_plain_name(exp.name()) {
        return Err(invalid(
            &exp.config_path,
            format!(
                "the experiment's name {:?} becomes a job name and a folder: use 1 to 100 letters, digits, `.`, `_` \
                 or `-` (not first: `.` or `-`) to shard it",
                exp.name()
            ),
        ));
    }
    let geometry = crate::stages::scene::load_geometry(exp)?;
    let vertices = geometry.mesh.vertex_count();
    let settings = exp.transfer_settings();
    let shape = settings.shape(vertices);
    let (separable, in_merge, multiple) = split_settings(exp, shape, vertices)?;
    let units = vertices.div_ceil(multiple).max(1);
    if shards > units {
        return Err(invalid(
            &exp.config_path,
            format!(
                "{shards} shards asked for, but {vertices} vertices make only {units} ranges of whole {multiple}-vertex \
                 blocks (the lcm of the separable compressors' blocks: {}); use --shards {units} or fewer",
                separable.iter().map(|s| format!("{} {}", s.label, s.vertex_multiple)).collect::<Vec<_>>().join(", ")
            ),
        ));
    }
    let outputs: Vec<String> =
        std::iter::once(TRANSFER_FILE.to_string()).chain(separable.iter().map(|s| form_file(&s.label))).collect();
    let specs: Vec<ShardSpec> = (0..shards)
        .map(|i| {
            let (a, b) = (i * units / shards, (i + 1) * units / shards);
            ShardSpec {
                index: i,
                first_vertex: (a * multiple).min(vertices),
                end_vertex: (b * multiple).min(vertices),
                dir: format!("shards/{i:04}"),
                outputs: outputs.clone(),
            }
        })
        .collect();

    let (estimate, stacked) = shard_estimate(exp, &geometry, &separable, &in_merge, &specs)?;

    let manifest = Manifest {
        format: MANIFEST_FORMAT.into(),
        version: MANIFEST_VERSION,
        created_by: format!("biscale {}", env!("CARGO_PKG_VERSION")),
        experiment: exp.name().to_string(),
        config: std::path::absolute(&exp.config_path).unwrap_or_else(|_| exp.config_path.clone()),
        config_hash: config_hash(exp)?,
        overrides: exp.overrides.clone(),
        vertices,
        shape: shape.to_string(),
        seed: exp.file.seed,
        vertex_multiple: multiple,
        separable,
        in_merge,
        stacked,
        estimate,
        shards: specs,
        checksum: String::new(),
    };
    let manifest = Manifest { checksum: manifest_checksum(&manifest), ..manifest };
    // Beside a person's files, never over them (a `manifest.json` biscale did not write is an
    // error naming it).
    let about = format!("biscale shard plan {}", exp.config_path.display());
    let shared = crate::store::shared::SharedFolder::begin(out, &about, &["manifest.json"])?;
    let staged = shared.path().join("manifest.json");
    let json = serde_json::to_string_pretty(&manifest).expect("manifest serializes");
    write_atomic_bytes(&staged, json.as_bytes())?;
    let path = shared.publish()?.path(&staged);
    Ok((path, manifest))
}

impl Manifest {
    /// Read and check a manifest; returns it and the folder it lies in.
    pub fn load(path: &Path) -> Result<(Self, PathBuf)> {
        let text = biscale_core::io::read_regular_text(path, MAX_MANIFEST_BYTES, "shard manifest")
            .map_err(|source| PipelineError::Io { path: path.into(), source })?;
        let m: Manifest = serde_json::from_str(&text)
            .map_err(|e| invalid(path, format!("not a shard manifest (`biscale shard plan` writes one): {e}")))?;
        if m.format != MANIFEST_FORMAT || m.version != MANIFEST_VERSION {
            return Err(invalid(
                path,
                format!(
                    "format {} version {}; this biscale reads {MANIFEST_FORMAT} version {MANIFEST_VERSION}: plan again",
                    m.format, m.version
                ),
            ));
        }
        if m.checksum != manifest_checksum(&m) {
            return Err(invalid(
                path,
                "the manifest was changed since `biscale shard plan` wrote it (its checksum does not match): plan again",
            ));
        }
        if m.shards.is_empty() || m.shards.len() > MAX_SHARDS {
            return Err(invalid(path, format!("{} shards: a plan has 1 to {MAX_SHARDS}", m.shards.len())));
        }
        if !is_plain_name(&m.experiment) {
            return Err(invalid(path, format!("the experiment's name {:?} is not a plain name", m.experiment)));
        }
        let mut at = 0;
        for (i, s) in m.shards.iter().enumerate() {
            // A shard's folder lies inside the plan's folder: relative, every part of it a
            // plain name (never `..`, never absolute).
            let plain_dir = !s.dir.starts_with('/') && s.dir.split('/').all(is_plain_name);
            if s.index != i || s.first_vertex != at || s.end_vertex < s.first_vertex || !plain_dir {
                return Err(invalid(path, format!("shard {i}'s entry is inconsistent (index, range or folder)")));
            }
            at = s.end_vertex;
        }
        if at != m.vertices {
            return Err(invalid(path, format!("the shards cover {at} of {} vertices", m.vertices)));
        }
        let dir = path.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf);
        Ok((m, dir))
    }

    /// The experiment, checked to be the one that was planned.
    pub fn experiment(&self, path: &Path) -> Result<Experiment> {
        let exp = Experiment::load_with(&self.config, &self.overrides)?;
        let now = config_hash(&exp)?;
        if now != self.config_hash {
            return Err(invalid(
                path,
                format!(
                    "the config {} or its mesh changed since the plan (content hash {now}, planned {}): plan again \
                     with `biscale shard plan`",
                    self.config.display(),
                    self.config_hash
                ),
            ));
        }
        Ok(exp)
    }

    fn shard(&self, index: usize, path: &Path) -> Result<&ShardSpec> {
        self.shards.get(index).ok_or_else(|| {
            invalid(
                path,
                format!("there is no shard {index}: the manifest has {} (0..{})", self.shards.len(), self.shards.len()),
            )
        })
    }

    /// The compressor of the separable setting `label`, built from the config.
    fn compressor(&self, exp: &Experiment, label: &str, path: &Path) -> Result<Box<dyn Compressor>> {
        let setting = crate::plan::Plan::new(exp)
            .compressors
            .into_iter()
            .find(|c| c.label == label)
            .ok_or_else(|| invalid(path, format!("the config has no compressor '{label}' any more")))?;
        build_compressor(&setting)
    }

    /// The command that (re)runs shard `index`.
    pub fn rerun_command(&self, manifest: &Path, index: usize) -> String {
        format!("biscale shard run {} --index {index}", manifest.display())
    }
}

/// `shard run`: build and write shard `index` of the manifest at `path`.
pub fn run(path: &Path, index: usize) -> Result<ShardDone> {
    let start = Instant::now();
    let (m, root) = Manifest::load(path)?;
    let spec = m.shard(index, path)?.clone();
    let exp = m.experiment(path)?;
    // The shard's folder is an output like a run folder: never reached through a link (in the
    // plan's `shards/` or as the shard itself), written whole into a staging folder and swapped
    // in only over an empty folder or one whose marker proves biscale wrote all of it (a user's
    // `done.json` or `transfer.bsf` there is an error naming it, never overwritten).
    let dir = biscale_core::io::inside_folder(&root, &spec.dir).map_err(|why| {
        invalid(path, format!("shard {index}'s folder {} {why}: it is written only where the plan made it", spec.dir))
    })?;
    let parent = dir.parent().unwrap_or(&root).to_path_buf();
    std::fs::create_dir_all(&parent).map_err(|source| PipelineError::Io { path: parent.clone(), source })?;
    // The plan's estimate of a shard's peak, against the memory there is here, before tracing
    // (a shard node may have less than the planning machine).
    crate::estimate::refuse(
        &format!("{}: shard {index}", path.display()),
        m.estimate.shard_peak_bytes,
        " (the plan's estimate of a shard's peak)",
        &crate::estimate::available()?,
        "plan more shards (`biscale shard plan --shards N`) or run it where more memory is free",
    )?;
    let staged = StagedDir::begin(&dir, &format!("biscale shard run {} --index {index}", path.display()))?;
    let range = spec.first_vertex..spec.end_vertex;
    eprintln!(
        "shard {index} of {}: vertices {}..{} of {} ({}), {} threads",
        m.shards.len(),
        range.start,
        range.end,
        m.vertices,
        m.experiment,
        rayon::current_num_threads()
    );
    let geometry = crate::stages::scene::load_geometry(&exp)?;
    if geometry.mesh.vertex_count() != m.vertices {
        return Err(invalid(
            path,
            format!("the mesh has {} vertices, the plan {}", geometry.mesh.vertex_count(), m.vertices),
        ));
    }
    let settings = exp.transfer_settings();
    let step = (range.len() / 10).max(1);
    let t0 = Instant::now();
    let tick = |done: usize| {
        if done.is_multiple_of(step) {
            eprintln!("shard {index}: transfer {done}/{} vertices ({:.1} s)", range.len(), t0.elapsed().as_secs_f64());
        }
    };
    let build = transfer::build_range(&geometry.transfer, &settings, range.clone(), Some(&tick))?;
    eprintln!("shard {index}: transfer {build}");
    let mut compressor_seconds = vec![];
    let mut forms: Vec<(String, CompressedForm)> = vec![];
    for s in &m.separable {
        let c = m.compressor(&exp, &s.label, path)?;
        let ctx = CompressContext { seed: exp.file.seed, progress: None, sweep: None };
        let form = c
            .compress_part(&build.matrix, range.start, &ctx)
            .map_err(|source| PipelineError::Compress { name: s.label.clone(), source })?;
        eprintln!("shard {index}: {} {:.2} MB in {:.2} s", s.label, form.bytes() as f64 / 1e6, form.build_seconds);
        compressor_seconds.push((s.label.clone(), form.build_seconds));
        forms.push((form_file(&s.label), form));
    }
    if let Ok(list) = std::env::var(FAIL_VAR) {
        if list.split(',').any(|x| x.trim().parse() == Ok(index)) {
            return Err(invalid(
                Path::new(FAIL_VAR),
                format!("shard {index} fails on purpose ({FAIL_VAR}={list}); it is left incomplete"),
            ));
        }
    }
    let out = staged.path().to_path_buf();
    build.matrix.save(&out.join(TRANSFER_FILE))?;
    for (file, form) in &forms {
        form.save(&out.join(file))?;
    }
    let files = spec.outputs.iter().map(|f| file_sum(&out, f)).collect::<Result<Vec<_>>>()?;
    let done = ShardDone {
        format: DONE_FORMAT.into(),
        index,
        config_hash: m.config_hash.clone(),
        first_vertex: range.start,
        end_vertex: range.end,
        files,
        nnz: build.matrix.nnz() as u64,
        nonzero: Some(build.matrix.nonzero_values() as u64),
        rays_traced: build.stats.rays_traced,
        transfer_seconds: build.stats.seconds,
        compressor_seconds,
        seconds: start.elapsed().as_secs_f64(),
        cpu_seconds: crate::provenance::process_cpu_seconds(),
        peak_rss_bytes: crate::estimate::peak_rss(),
        threads: rayon::current_num_threads(),
        host: std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_default(),
    };
    let json = serde_json::to_string_pretty(&done).expect("record serializes");
    write_atomic_bytes(&out.join(DONE_FILE), json.as_bytes())?;
    staged.commit()?;
    eprintln!(
        "shard {index}: complete in {:.1} s, peak memory {}",
        done.seconds,
        done.peak_rss_bytes.map_or("unknown".into(), human)
    );
    Ok(done)
}

/// What is wrong with a shard, if anything.
#[derive(Clone, Debug)]
pub enum ShardState {
    Complete(Box<ShardDone>),
    Missing,
    Stale(String),
    Corrupt(String),
}

/// The state of shard `spec` of `m` (rooted at `root`): complete only when its record exists,
/// names this plan and range, and every file's checksum matches.
pub fn state(m: &Manifest, root: &Path, spec: &ShardSpec) -> ShardState {
    let dir = root.join(&spec.dir);
    let text = match biscale_core::io::read_regular_text(&dir.join(DONE_FILE), MAX_DONE_BYTES, "shard's done.json") {
        Ok(t) => t,
        Err(_) => return ShardState::Missing,
    };
    let done: ShardDone = match serde_json::from_str(&text) {
        Ok(d) => d,
        Err(e) => return ShardState::Corrupt(format!("{}: {e}", dir.join(DONE_FILE).display())),
    };
    if done.config_hash != m.config_hash || (done.first_vertex, done.end_vertex) != (spec.first_vertex, spec.end_vertex)
    {
        return ShardState::Stale(format!(
            "built for config hash {} and vertices {}..{}, the plan has {} and {}..{}",
            done.config_hash, done.first_vertex, done.end_vertex, m.config_hash, spec.first_vertex, spec.end_vertex
        ));
    }
    for name in &spec.outputs {
        let Some(expected) = done.files.iter().find(|f| &f.name == name) else {
            return ShardState::Stale(format!("its record lists no {name}"));
        };
        match file_sum(&dir, name) {
            Ok(got) if &got == expected => {}
            Ok(got) => {
                return ShardState::Corrupt(format!(
                    "{}: {} bytes, XXH3-128 {}; its record says {} bytes, {}",
                    dir.join(name).display(),
                    got.bytes,
                    got.xxh3,
                    expected.bytes,
                    expected.xxh3
                ))
            }
            Err(e) => return ShardState::Corrupt(e.to_string()),
        }
    }
    ShardState::Complete(Box::new(done))
}

/// `shard status`: one line per shard; `Err` listing the incomplete ones.
pub fn status(path: &Path) -> Result<Vec<String>> {
    let (m, root) = Manifest::load(path)?;
    let mut lines = vec![];
    let mut bad = vec![];
    for s in &m.shards {
        let head = format!("shard {} (vertices {}..{})", s.index, s.first_vertex, s.end_vertex);
        match state(&m, &root, s) {
            ShardState::Complete(d) => lines.push(format!(
                "{head}: complete ({:.1} s on {}, peak memory {})",
                d.seconds,
                d.host,
                d.peak_rss_bytes.map_or("unknown".into(), human)
            )),
            other => {
                let why = match other {
                    ShardState::Missing => "missing (not run, running, or failed)".to_string(),
                    ShardState::Stale(w) => format!("stale: {w}"),
                    ShardState::Corrupt(w) => format!("corrupt: {w}"),
                    ShardState::Complete(_) => unreachable!(),
                };
                let line = format!("{head}: {why}; rerun: {}", m.rerun_command(path, s.index));
                lines.push(line.clone());
                bad.push(line);
            }
        }
    }
    for l in &lines {
        println!("{l}");
    }
    if !bad.is_empty() {
        return Err(invalid(path, format!("{} of {} shards are not complete", bad.len(), m.shards.len())));
    }
    Ok(lines)
}

/// `shard merge`: check every shard, stack `T`, merge the separable forms and run the rest of
/// the pipeline into `opts`' output folder.
pub fn merge(path: &Path, opts: &RunOptions) -> Result<(PathBuf, crate::metrics::Metrics)> {
    let start = Instant::now();
    let (m, root) = Manifest::load(path)?;
    let exp = m.experiment(path)?;
    let mut dones = vec![];
    let mut problems = vec![];
    for s in &m.shards {
        match state(&m, &root, s) {
            ShardState::Complete(d) => dones.push(*d),
            ShardState::Missing => {
                problems.push(format!("shard {} is missing; rerun: {}", s.index, m.rerun_command(path, s.index)))
            }
            ShardState::Stale(w) | ShardState::Corrupt(w) => problems.push(format!(
                "shard {} is not usable ({w}); rerun: {}",
                s.index,
                m.rerun_command(path, s.index)
            )),
        }
    }
    if !problems.is_empty() {
        return Err(invalid(
            path,
            format!("{} of {} shards are not complete:\n  {}", problems.len(), m.shards.len(), problems.join("\n  ")),
        ));
    }
    let load_start = Instant::now();
    let files = || m.shards.iter().map(|s| root.join(&s.dir).join(TRANSFER_FILE));
    let rows = match &m.stacked {
        Some(why) => {
            eprintln!("merge: stacking T whole: {why}");
            let mut error = None;
            let parts = files().map_while(|p| match TransferMatrix::load(&p) {
                Ok(t) => Some(t),
                Err(e) => {
                    error = Some(e);
                    None
                }
            });
            let stacked = TransferMatrix::stack(parts);
            if let Some(e) = error {
                return Err(biscale_core::CoreError::from(e).into());
            }
            TransferRows::Whole(stacked?)
        }
        None => {
            // The shards' records say what each file holds (their checksums were just
            // checked); every pass checks each part against its record as it reads it.
            let records = m.shards.iter().zip(&dones).zip(files()).map(|((s, d), path)| PartFile {
                path,
                vertices: s.end_vertex - s.first_vertex,
                nnz: d.nnz as usize,
                nonzero: d.nonzero.map(|n| n as usize),
            });
            let shape = exp.transfer_settings().shape(m.vertices);
            TransferRows::Parts(TransferParts::new(shape, records.collect())?)
        }
    };
    let shape = rows.view().shape();
    let mut forms = std::collections::BTreeMap::new();
    for s in &m.separable {
        let c = m.compressor(&exp, &s.label, path)?;
        let parts = m
            .shards
            .iter()
            .map(|sh| {
                let p = root.join(&sh.dir).join(form_file(&s.label));
                CompressedForm::load(&p).map_err(|e| biscale_core::CoreError::from(e).into())
            })
            .collect::<Result<Vec<_>>>()?;
        let form =
            c.merge_parts(shape, parts).map_err(|source| PipelineError::Compress { name: s.label.clone(), source })?;
        forms.insert(s.label.clone(), form);
    }
    let merge_load_seconds = load_start.elapsed().as_secs_f64();
    eprintln!(
        "merge: {} shards {} ({} non-zeros) and {} forms in {merge_load_seconds:.2} s",
        m.shards.len(),
        match &rows {
            TransferRows::Whole(_) => "stacked into T",
            TransferRows::Parts(_) => "checked, T left in their files",
        },
        rows.view().nnz(),
        forms.len()
    );
    let sharded = crate::metrics::ShardedMetrics {
        shards: m.shards.len(),
        shard_seconds_sum: dones.iter().map(|d| d.seconds).sum(),
        shard_seconds_max: dones.iter().map(|d| d.seconds).fold(0.0, f64::max),
        shard_cpu_seconds_sum: dones.iter().map(|d| d.cpu_seconds).sum(),
        shard_peak_rss_max: dones.iter().filter_map(|d| d.peak_rss_bytes).max(),
        merge_load_seconds,
        merge_seconds: 0.0,
        streamed: matches!(rows, TransferRows::Parts(_)),
    };
    let pre = Precomputed {
        rows,
        rays_traced: dones.iter().map(|d| d.rays_traced).sum(),
        transfer_seconds: dones.iter().map(|d| d.transfer_seconds).sum(),
        forms,
        sharded,
        started: start,
    };
    crate::run::run_with(&exp, opts, Some(pre))
}

/// The plan's summary for people: shards, what runs where, estimates, how to run it.
pub fn describe(m: &Manifest, path: &Path, available: Option<&Available>) -> String {
    let sizes: Vec<usize> = m.shards.iter().map(|s| s.end_vertex - s.first_vertex).collect();
    let mut s = format!(
        "{}: {} vertices in {} shards of {}..{} vertices (ranges of whole {}-vertex blocks), T {}\n",
        path.display(),
        m.vertices,
        m.shards.len(),
        sizes.iter().min().unwrap_or(&0),
        sizes.iter().max().unwrap_or(&0),
        m.vertex_multiple,
        m.shape
    );
    for c in &m.separable {
        s += &format!("  in the shards: {} ({})\n", c.label, c.kind);
    }
    for c in &m.in_merge {
        s += &format!("  in the merge:  {} ({}): {}\n", c.label, c.kind, c.why);
    }
    s += &match &m.stacked {
        None => "  the merge streams T from the shards' files, part by part (every step after the shards is \
                 row-separable)\n"
            .to_string(),
        Some(why) => format!("  the merge stacks all of T in memory: {why}\n"),
    };
    let e = &m.estimate;
    s += &format!(
        "  estimates: {:.0} non-zeros per vertex; per shard peak {} ({} base + {:.1} B per non-zero) and {} \
         written; merge peak {}",
        e.nnz_per_vertex,
        human(e.shard_peak_bytes),
        human(e.shard_base_bytes),
        e.shard_bytes_per_nnz,
        human(e.shard_output_bytes),
        human(e.merge_peak_bytes)
    );
    if let Some(a) = available {
        s += &format!(" ({} available here, {})", human(a.bytes), a.source);
    }
    let largest = sizes.iter().max().copied().unwrap_or(0) as f64 / m.vertices.max(1) as f64;
    s += &format!(
        "\n  tracing: about {:.1} CPU-minutes in all, {:.1} for the largest shard (from the sample's speed; \
         compressors come on top)",
        e.transfer_cpu_seconds / 60.0,
        e.transfer_cpu_seconds * largest / 60.0
    );
    s += &format!(
        "\n  run: biscale shard sbatch {p} (Slurm), or locally: seq 0 {} | xargs -P 2 -I{{}} biscale shard run {p} --index {{}}\n  then: biscale shard merge {p}\n",
        m.shards.len() - 1,
        p = path.display()
    );
    s
}
