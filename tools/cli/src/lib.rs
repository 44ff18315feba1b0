//! # biscale-cli: the `biscale` command
//!
//! The arguments ([`Cli`], clap), the small commands' printing, progress, verbosity and the
//! logger that prints the pipeline's `log` events (`StderrLog`); all
//! work is the pipeline's (`biscale`). `src/main.rs` is one call to [`main`]; the library
//! form lets the tests (`tests/cli/`, one binary) check the argument definitions too.

use anyhow::Context;
use biscale::experiment::config::Experiment;
use biscale::store::RunOptions;
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};

/// biscale: all-frequency bi-scale precomputed radiance transfer, as a research pipeline.
///
/// An experiment is one TOML file (see configs/). `biscale run` traces the per-vertex
/// visibility transfer matrix T, compresses it with every compressor the config names,
/// gathers the local incident radiance L* = T L, shades an image per compressor and writes
/// plan.txt, metrics.json, report.md and images/ into the output folder.
#[derive(Parser)]
#[command(name = "biscale", version, about, long_about)]
pub struct Cli {
    /// Worker threads for tracing, compressing and gathering (default: RAYON_NUM_THREADS, or
    /// one per core); at most 4 per logical CPU (more is capped, with a note); recorded in
    /// metrics.json.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Print only warnings and errors: no progress, no notes (batch jobs that log elsewhere).
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    /// Also print each stage's wall time as it ends.
    #[arg(short, long, global = true)]
    verbose: bool,
    /// Override a config value without editing the file: KEY is a dotted path
    /// (runtime.light_moments, compressors.1.terms), VALUE a TOML value (true, 8, [4, 8]
    /// sweeps as in the file, "text"). Repeatable; for every command that reads a config;
    /// recorded in metrics.json (the command line, and the config text as it ran).
    #[arg(long = "set", value_name = "KEY=VALUE", global = true)]
    set: Vec<String>,
    #[command(subcommand)]
    command: Command,
}

/// The `--set` overrides of this invocation, for [`load`].
static OVERRIDES: std::sync::OnceLock<Vec<String>> = std::sync::OnceLock::new();

#[derive(Subcommand)]
enum Command {
    /// Run an experiment and write its output folder (default out/<name>/).
    #[command(after_help = "Example: biscale run configs/bunny.toml --out out/bunny")]
    Run {
        /// The experiment's TOML file.
        config: PathBuf,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// Print what `run` would do and what it leaves out, what the stage cache already holds and
    /// how big each output is, and the peak memory, without running anything.
    #[command(after_help = "Example: biscale plan configs/bunny.toml")]
    Plan {
        /// The experiment's TOML file.
        config: PathBuf,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Write T.mtx (sparse, Matrix Market) and L.mtx (dense N x 3) for other tools, e.g.
    /// `scipy.io.mmread`, with mesh.obj (T's vertex order and traced normals), view.json
    /// (camera and lighting) and irradiance.csv (each vertex's T L irradiance, paper's cosine
    /// and exact) for an external renderer (scripts/mitsuba_check.py).
    #[command(after_help = "Example: biscale export-matrix configs/bunny.toml --out out/bunny-mtx")]
    ExportMatrix {
        /// The experiment's TOML file.
        config: PathBuf,
        /// Folder to write T.mtx and L.mtx into.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Write T, L, the uncompressed L*, every compressor setting's form and the BTFs as NumPy
    /// files (t.npz, l.npz, lstar.npz, form-<label>.npz, btf-<material>.npz; read them with
    /// python/biscale_io.py or numpy.load), or T and L as Matrix Market (--format mtx).
    #[command(after_help = "Example: biscale export configs/bunny.toml --what t,lstar,forms --out out/bunny-npz")]
    Export {
        /// The experiment's TOML file.
        config: PathBuf,
        /// npz: NumPy archives; mtx: T.mtx and L.mtx (what export-matrix writes).
        #[arg(long, value_enum, default_value = "npz")]
        format: biscale::interop::ExportFormat,
        /// What to write, comma-separated: t, l, lstar, forms, btf (default: all the format
        /// holds).
        #[arg(long, value_delimiter = ',')]
        what: Vec<String>,
        /// Folder for the files (default: out/<name>-export/).
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Render and score an L* or a compressed form made outside biscale (e.g. in NumPy) as a
    /// run scores a compressor setting: L* error against T L, image errors against the
    /// uncompressed render and the reference; writes metrics.json and images/ (CPU only).
    #[command(after_help = "Example: biscale eval configs/bunny.toml --lstar out/bunny-npz/lstar.npz --name mine")]
    Eval {
        /// The experiment's TOML file.
        config: PathBuf,
        /// An L*: .npy (float32/float64, (V*M, 3) rows v*M+j, or (V, M, 3)) or .npz (array
        /// `lstar`), e.g. biscale_io.save_lstar's.
        #[arg(long, required_unless_present = "form", conflicts_with = "form")]
        lstar: Option<PathBuf>,
        /// A compressed form (.npz: `export --what forms` or biscale_io.save_form) of a
        /// built-in kind, gathered by that compressor's CPU gather.
        #[arg(long)]
        form: Option<PathBuf>,
        /// The setting's name in metrics.json and the images (default: the form's label, or
        /// the file's stem).
        #[arg(long)]
        name: Option<String>,
        /// Output folder (default: out/<name>-eval-<NAME>/), replaced whole as a run's is.
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Re-render a finished run's report (plots, report.md, report.html) from its metrics.json
    /// and plan.txt, with no tracing: byte for byte what the run wrote, or today's layout of
    /// it. Several runs with --out: one page setting their compressor rows side by side.
    #[command(
        after_help = "Example: biscale report out/bunny/metrics.json\n         biscale report out/bunny out/smoke --out out/compare"
    )]
    Report {
        /// Runs: each an output folder or its metrics.json.
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// Folder to write into (replaced whole, as a run's is). One run: default its own
        /// folder. Several runs: required.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Reproduce the paper's Tables I and II, Figs. 1, 3(b), 5, 6, 7 and 8, its video (as an
    /// animated comparison) and its equal-storage comparison (with the equal-quality one it could not make): runs the
    /// configs of configs/paper/ into DIR/runs/ and writes numbers.csv (every figure: ours, the
    /// paper's, their ratio), tables/*.tex (booktabs), figures/ (PNG panels and a LaTeX
    /// figure each), paper.tex (all of them in one article: pdflatex paper.tex) and index.html, ours beside the published figures (paper/published.toml).
    /// Run it in the biscale checkout (it reads configs/paper/ and assets/). --set applies to
    /// every run's config. Before each run it waits for the load average to fall to the CPU
    /// count (at most 15 s with --quick, 120 s without), and it repeats once a run whose timed
    /// steps another process shared; a figure still taken on a busy machine is marked (busy).
    #[command(
        after_help = "Example: biscale reproduce --quick --out out/paper-quick\n         biscale reproduce --only table1,equal-quality"
    )]
    Reproduce {
        /// Every item at small sizes (6x8x8 light, 4x4 local directions, 96x72 images, one
        /// timing repeat): about 25 s on two cores (release build, empty cache), with figures
        /// not at the paper's scale.
        #[arg(long)]
        quick: bool,
        /// Only these items, comma-separated: table1, table2, equal-quality, low-vs-all, fig8,
        /// fig3b, fig7, animation (default: all).
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        /// Output folder (default: out/paper, or out/paper-quick with --quick), replaced whole
        /// as a run's is.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Cache folder (default: $XDG_CACHE_HOME/biscale, else ~/.cache/biscale): a rerun with
        /// the same folder takes T and every compressed form from it.
        #[arg(long)]
        cache_dir: Option<PathBuf>,
    },
    /// Pictures of the transfer matrix's structure: sparsity and biclusters of a patch of
    /// vertices, bicluster size and value histograms, per-vertex heat maps on the mesh.
    #[command(after_help = "Example: biscale viz configs/bunny.toml --out out/bunny-viz")]
    Viz {
        /// The experiment's TOML file.
        config: PathBuf,
        /// Folder for the PNG files.
        #[arg(long, default_value = "out/viz")]
        out: PathBuf,
        /// First vertex of the patch (default: the window whose biclusters share most).
        #[arg(long)]
        first: Option<usize>,
        /// Vertices in the patch.
        #[arg(long, default_value_t = 8)]
        count: usize,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Open the interactive viewer (needs the `viewer` feature: `cargo run --release
    /// --features viewer -- view CONFIG`): drag to orbit, wheel to zoom, right-drag or
    /// arrows to rotate the sky, Tab to switch compressors, M to switch where light moments
    /// are resolved (per vertex, or at every pixel as runtime.moments_resolve).
    #[cfg(feature = "viewer")]
    #[command(after_help = "Example: biscale view configs/bunny.toml")]
    View {
        /// The experiment's TOML file.
        config: PathBuf,
        /// Show the `[[methods]]` setting with this label (e.g. sh-n5) instead of the
        /// compressors: the low-frequency method, its sky rotated in SH.
        #[arg(long)]
        method: Option<String>,
        /// Render a few frames into this PNG and exit (works under Xvfb).
        #[arg(long)]
        screenshot: Option<PathBuf>,
    },
    /// Open the interactive viewer: not in this build. Rebuild with the `viewer` feature:
    /// `bash scripts/setup-viewer.sh && cargo install --path tools/cli --features viewer` (or
    /// `cargo run --release -p biscale-cli --features viewer -- view CONFIG`).
    #[cfg(not(feature = "viewer"))]
    #[command(after_help = "Example: biscale view configs/bunny.toml (after rebuilding with --features viewer)")]
    View {
        /// What the viewer would take (CONFIG, --method, --screenshot).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Write a generated mesh (OBJ): a test scene, or a subdivided mesh for scaling studies.
    /// `--out` is a new file or an OBJ biscale wrote (it is never written over a user's file,
    /// a link, a device or a FIFO; `--force` replaces a user's regular file), or `-` for
    /// standard output.
    #[command(after_help = "Example: biscale generate scene plane-sphere --out plane_sphere.obj\n         \
                            biscale generate scene plane --out - | gzip > plane.obj.gz")]
    Generate {
        #[command(subcommand)]
        what: Generate,
    },
    /// Build the BTFs of a config's materials (synthesized ones are ray traced from their
    /// height-field patch, or taken from the cache) and write them as .btf files.
    #[command(after_help = "Example: biscale btf configs/bunny.toml --out out/bunny-btf")]
    Btf {
        /// The experiment's TOML file.
        config: PathBuf,
        /// Only the material with this name.
        #[arg(long)]
        material: Option<String>,
        /// Folder for the .btf files (and previews).
        #[arg(long, default_value = "out/btf")]
        out: PathBuf,
        /// Also write a contact sheet PNG per material (the patch under several lights and views)
        /// and, per compressed representation, dense | compressed | |error| sheets side by side.
        #[arg(long)]
        preview: bool,
        #[command(flatten)]
        cache: CacheArgs,
    },
    /// Split the precompute (T and the separable compressors) into shards for a Slurm job
    /// array or local processes, and merge them into what `run` would have produced.
    #[command(after_help = "Example: biscale shard plan configs/bunny.toml --shards 8 --out out/bunny-shards")]
    Shard {
        #[command(subcommand)]
        what: Shard,
    },
    /// List or clean the stage cache.
    #[command(after_help = "Example: biscale cache clean --older-than-days 30 --dry-run")]
    Cache {
        #[command(subcommand)]
        what: Cache,
    },
    /// Compare two EXR images: prints RMSE, PSNR and relative L2 of A against B, and after
    /// the report's tone map LDR PSNR (peak 1), SSIM and FLIP. A of another size is resampled
    /// to B's (box filter for an integer ratio, else bilinear), with a warning.
    #[command(
        after_help = "Example: biscale diff out/bunny/images/bicluster.exr out/bunny/images/uncompressed.exr --mask out/bunny/images/mask.png"
    )]
    Diff {
        /// The image to score (EXR).
        a: PathBuf,
        /// The reference image.
        b: PathBuf,
        /// Only the pixels where this PNG is white (a run's images/mask.png, or
        /// images/reference_mask.png against the reference): the report's own definitions.
        #[arg(long)]
        mask: Option<PathBuf>,
        /// Also write a false-colour error image (PNG): a new file, or one biscale wrote
        /// (a user's file, a link, a device or FIFO is refused); `-` streams it to standard
        /// output (the figures then go to standard error).
        #[arg(long)]
        error_image: Option<PathBuf>,
        /// Replace a regular file at --error-image that biscale did not write (never a link,
        /// a device, a FIFO, a folder or an image being compared).
        #[arg(long)]
        force: bool,
        /// Print the figures as one JSON object (psnr and ldr_psnr are null when the images
        /// are equal).
        #[arg(long)]
        json: bool,
        /// Exposure in stops of the tone map (x 2^exposure, clamp, sRGB) the LDR figures are
        /// measured after: a run's `tone_map.exposure` (metrics.json; its `[report] exposure`
        /// unless that is "auto") gives its report's numbers.
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        exposure: f32,
    },
}

/// The stage cache a command reads and writes.
#[derive(clap::Args)]
struct CacheArgs {
    /// Do not read or write the stage cache (T, compressed forms, BTFs).
    #[arg(long)]
    no_cache: bool,
    /// Cache folder (default: $XDG_CACHE_HOME/biscale, else ~/.cache/biscale; one for every
    /// command).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
}

impl CacheArgs {
    fn options(self, out: Option<PathBuf>) -> RunOptions {
        RunOptions { out_dir: out, cache_dir: self.cache_dir, no_cache: self.no_cache }
    }
}

/// Where a run writes: its output folder and the stage cache.
#[derive(clap::Args)]
struct OutputArgs {
    /// Output folder (default: out/<experiment name>/).
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    cache: CacheArgs,
}

impl OutputArgs {
    fn options(self) -> RunOptions {
        self.cache.options(self.out)
    }
}

#[derive(Subcommand)]
enum Cache {
    /// List the cache's files: kind, size, age and the inputs each was built from.
    #[command(after_help = "Example: biscale cache list")]
    List {
        /// Cache folder (default: $XDG_CACHE_HOME/biscale, else ~/.cache/biscale).
        #[arg(long)]
        cache_dir: Option<PathBuf>,
    },
    /// Remove cache files (all of biscale's by default). A file counts as biscale's only when
    /// its own header proves it (a biscale artifact carrying the key its name names, or an
    /// interrupted write that begins as one); files that merely look like biscale's by name
    /// are listed as `other` and never removed.
    #[command(after_help = "Example: biscale cache clean --kind form --older-than-days 30 --dry-run")]
    Clean {
        /// Cache folder (default: $XDG_CACHE_HOME/biscale, else ~/.cache/biscale).
        #[arg(long)]
        cache_dir: Option<PathBuf>,
        /// Only files of these kinds (transfer, form, sh, btf, lpca, reference, temporary).
        #[arg(long, value_delimiter = ',')]
        kind: Vec<String>,
        /// Only files last written at least this many days ago.
        #[arg(long)]
        older_than_days: Option<f64>,
        /// List what would be removed, remove nothing.
        #[arg(long)]
        dry_run: bool,
    },
}

#[derive(Subcommand)]
enum Shard {
    /// Write DIR/manifest.json: the vertex range and outputs of each shard, which compressors
    /// run in the shards and which in the merge, and memory estimates.
    #[command(after_help = "Example: biscale shard plan configs/bunny.toml --shards 8 --out out/bunny-shards")]
    Plan {
        /// The experiment's TOML file.
        config: PathBuf,
        /// Number of shards (ranges hold whole blocks of the separable compressors).
        #[arg(long)]
        shards: usize,
        /// Folder for the manifest and the shards' outputs (a shared file system on a cluster).
        #[arg(long)]
        out: PathBuf,
    },
    /// Build one shard: T's rows for its vertices and its part of every separable form.
    #[command(after_help = "Example: biscale shard run out/bunny-shards/manifest.json --index 3")]
    Run {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
        /// The shard (default: the array task's index: $SLURM_ARRAY_TASK_ID,
        /// $AWS_BATCH_JOB_ARRAY_INDEX or $JOB_COMPLETION_INDEX, which must agree when several are set).
        #[arg(long)]
        index: Option<usize>,
    },
    /// List the shards that are complete, and the command that reruns each one that is not
    /// (exits 1 unless all are complete).
    #[command(after_help = "Example: biscale shard status out/bunny-shards/manifest.json")]
    Status {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
    },
    /// Check every shard, stack T, merge the forms and run the rest of the pipeline (the
    /// whole-matrix compressors, gathers, images, report) as `biscale run` would.
    #[command(after_help = "Example: biscale shard merge out/bunny-shards/manifest.json --out out/bunny")]
    Merge {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// Write slurm/shards.sbatch (a job array over the shards), slurm/merge.sbatch and
    /// slurm/submit.sh (the array, then the merge with --dependency=afterok) beside the
    /// manifest.
    #[command(
        after_help = "Example: biscale shard sbatch out/bunny-shards/manifest.json --partition cpu --time 60 && bash out/bunny-shards/slurm/submit.sh"
    )]
    Sbatch {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
        /// Slurm partition of the jobs (default: the cluster's default).
        #[arg(long)]
        partition: Option<String>,
        /// Time limit per job (Slurm's format: minutes, or D-HH:MM:SS).
        #[arg(long)]
        time: Option<String>,
        /// Memory per shard (Slurm's format, e.g. 4G; default: the plan's estimate + 25%).
        #[arg(long)]
        mem: Option<String>,
        /// Memory of the merge job (default: the plan's estimate + 25%).
        #[arg(long)]
        merge_mem: Option<String>,
        /// CPUs per shard (and of the merge); the shards' threads follow it (1 to 4096).
        #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_JOB_CPUS))]
        cpus: usize,
        /// The merge's output folder.
        #[arg(long)]
        out: Option<PathBuf>,
        /// The merge's cache folder.
        #[arg(long)]
        cache_dir: Option<PathBuf>,
    },
    /// Write k8s/shards.yaml (a Kubernetes indexed Job: one completion per shard, the index from
    /// $JOB_COMPLETION_INDEX), k8s/merge.yaml (the merge Job), k8s/README.txt and k8s/submit.sh
    /// (the shards, then the merge once they completed) beside the manifest. The YAML is JSON
    /// (YAML 1.2). Every pod needs the plan's folder at its planned path: a hostPath of it (nodes
    /// that mount the shared file system there), or --claim.
    #[command(
        after_help = "Example: biscale shard k8s out/bunny-shards/manifest.json --image ghcr.io/you/biscale:0.1.0 --cpus 4 --claim scratch && bash out/bunny-shards/k8s/submit.sh"
    )]
    K8s {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
        /// Container image with `biscale` on its PATH (default: biscale:<this version>).
        #[arg(long)]
        image: Option<String>,
        /// CPUs of every pod (requests and limits); the shards' threads follow it (1 to 4096).
        #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_JOB_CPUS))]
        cpus: usize,
        /// Memory of a shard's pod (a Kubernetes quantity, e.g. 4Gi; default: the plan's
        /// estimate + 25%, at least 1024Mi).
        #[arg(long)]
        mem: Option<String>,
        /// Memory of the merge's pod (default: the plan's estimate + 25%, at least 1024Mi).
        #[arg(long)]
        merge_mem: Option<String>,
        /// Namespace of the Jobs (default: kubectl's current one).
        #[arg(long)]
        namespace: Option<String>,
        /// A persistentVolumeClaim holding the plan's folder, mounted at the folder's absolute
        /// path (default: hostPath volumes of the same paths).
        #[arg(long)]
        claim: Option<String>,
        /// Shard pods running at once (default: every shard).
        #[arg(long)]
        parallelism: Option<usize>,
        /// The merge's output folder (default: the plan's folder/merged).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The merge's cache folder (default: the plan's folder/cache).
        #[arg(long)]
        cache_dir: Option<PathBuf>,
    },
    /// Write batch/shards.json (an AWS Batch SubmitJob request: an array job over the shards,
    /// the index from $AWS_BATCH_JOB_ARRAY_INDEX), batch/merge.json (the merge, depending on
    /// it), batch/README.txt, batch/submit.sh and, with --image, batch/job-definition.json
    /// beside the manifest. The job definition must mount the plan's folder at its planned path.
    #[command(
        after_help = "Example: biscale shard batch out/bunny-shards/manifest.json --job-queue cpu --image 123456789012.dkr.ecr.us-east-1.amazonaws.com/biscale:0.1.0 --cpus 4 && bash out/bunny-shards/batch/submit.sh"
    )]
    Batch {
        /// The shard plan's manifest.json (`biscale shard plan` wrote it).
        manifest: PathBuf,
        /// Job queue, by name or ARN (default: biscale).
        #[arg(long)]
        job_queue: Option<String>,
        /// Job definition, by name, name:revision or ARN (default: biscale-<experiment>).
        #[arg(long)]
        job_definition: Option<String>,
        /// Also write batch/job-definition.json, registering a definition that runs this image.
        #[arg(long)]
        image: Option<String>,
        /// vCPUs of every job; the shards' threads follow it (1 to 4096).
        #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_JOB_CPUS))]
        cpus: usize,
        /// MiB of a shard's job (default: the plan's estimate + 25%, at least 1024; at most 2^30).
        #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..=1 << 30))]
        mem: Option<u64>,
        /// MiB of the merge's job (default: the plan's estimate + 25%, at least 1024; at most 2^30).
        #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..=1 << 30))]
        merge_mem: Option<u64>,
        /// The merge's output folder (default: the plan's folder/merged).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The merge's cache folder (default: the plan's folder/cache).
        #[arg(long)]
        cache_dir: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum Generate {
    /// A built-in scene.
    #[command(after_help = "Example: biscale generate scene plane-sphere --out plane_sphere.obj")]
    Scene {
        /// Which scene.
        #[arg(value_enum)]
        kind: biscale::commands::GeneratedScene,
        /// The OBJ file to write (`-`: standard output).
        #[arg(long)]
        out: PathBuf,
        /// Replace a regular file at --out that biscale did not write.
        #[arg(long)]
        force: bool,
    },
    /// Add cylindrical texture coordinates (world units, about the vertical axis) to a mesh.
    #[command(after_help = "Example: biscale generate uv assets/meshes/bunny.obj --out bunny_uv.obj")]
    Uv {
        /// The mesh (OBJ or PLY).
        mesh: PathBuf,
        /// The OBJ file to write (`-`: standard output).
        #[arg(long)]
        out: PathBuf,
        /// Replace a regular file at --out that biscale did not write.
        #[arg(long)]
        force: bool,
    },
    /// Midpoint-subdivide a mesh `levels` times (about 4x the vertices per level), or make a
    /// polygon soup of it (`--unweld`).
    #[command(
        after_help = "Example: biscale generate subdivide assets/meshes/bunny.obj --levels 2 --out bunny_l2.obj\n\
                      A polygon soup (74,688 vertices, no shared edge): \
                      biscale generate subdivide assets/meshes/temple.obj --levels 1 --unweld --out temple_soup.obj"
    )]
    Subdivide {
        /// The mesh (OBJ or PLY).
        mesh: PathBuf,
        /// Subdivision levels (each about quadruples the triangles; 0 keeps them).
        #[arg(long, default_value_t = 1)]
        levels: u32,
        /// Then give every triangle three vertices of its own and its own uv chart: a polygon
        /// soup (duplicated vertices, open edges, flat normals) that a welding loader keeps.
        #[arg(long)]
        unweld: bool,
        /// The OBJ file to write (`-`: standard output).
        #[arg(long)]
        out: PathBuf,
        /// Replace a regular file at --out that biscale did not write.
        #[arg(long)]
        force: bool,
    },
}

/// Read a config with this invocation's `--set` overrides applied.
fn load(config: &Path) -> anyhow::Result<Experiment> {
    Ok(Experiment::load_with(config, OVERRIDES.get().map_or(&[], Vec::as_slice))?)
}

/// The largest `cache clean --older-than-days` (a million days: older than any file).
const MAX_AGE_DAYS: f64 = 1e6;

/// The most CPUs a scheduler job may ask for (`--cpus` of `shard sbatch|k8s|batch`).
const MAX_JOB_CPUS: u64 = 4096;

/// Most worker threads per logical CPU: past a few per core, threads only add contention
/// (1000 threads made a 0.4 s job take 27.6 s, and 100,000 hung the machine for minutes).
const THREADS_PER_CORE: usize = 4;

/// The worker threads to start, when not rayon's default: `--threads`, else
/// `RAYON_NUM_THREADS`, either capped at [`THREADS_PER_CORE`] per logical CPU with a note.
fn worker_threads(flag: Option<usize>) -> anyhow::Result<Option<usize>> {
    let (asked, from) = match flag {
        Some(n) => (n, "--threads"),
        None => match std::env::var("RAYON_NUM_THREADS") {
            Err(_) => return Ok(None),
            Ok(v) => match v.trim().parse::<usize>() {
                Ok(n) if n > 0 => (n, "RAYON_NUM_THREADS"),
                // 0 is rayon's own "one per core"; anything else is not a count. Either way the
                // run uses one thread per logical CPU, and says so.
                Ok(_) => {
                    eprintln!("note: RAYON_NUM_THREADS=0: one worker thread per logical CPU");
                    return Ok(None);
                }
                Err(_) => {
                    eprintln!(
                        "note: RAYON_NUM_THREADS={v:?} is not a number of threads; ignored (one worker thread per \
                         logical CPU)"
                    );
                    // rayon would read it too (and fall back the same way): take it out of its sight.
                    std::env::remove_var("RAYON_NUM_THREADS");
                    return Ok(None);
                }
            },
        },
    };
    anyhow::ensure!(asked >= 1, "{from} must be at least 1");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let cap = THREADS_PER_CORE * cores;
    if asked > cap {
        eprintln!(
            "note: {from} = {asked} is more than {THREADS_PER_CORE} threads per logical CPU ({cores}); using {cap}"
        );
        return Ok(Some(cap));
    }
    Ok(Some(asked))
}

/// Whether a command reads a config (and so takes `--set`).
fn reads_config(c: &Command) -> bool {
    match c {
        Command::Shard { what } => matches!(what, Shard::Plan { .. }),
        Command::Report { .. } | Command::Generate { .. } | Command::Cache { .. } | Command::Diff { .. } => false,
        _ => true,
    }
}

/// The pipeline's `log` events on stderr, as the CLI prints them: a note (`info`) as it is, a
/// stage's time (`debug`) with `-v`, warnings and errors always (`warning: `, `error: `).
/// Only biscale's own crates are heard: wgpu and the other libraries stay quiet.
struct StderrLog {
    level: log::LevelFilter,
}

impl StderrLog {
    fn install(verbosity: biscale::util::Verbosity) {
        use biscale::util::Verbosity;
        let level = match verbosity {
            Verbosity::Quiet => log::LevelFilter::Warn,
            Verbosity::Normal => log::LevelFilter::Info,
            Verbosity::Verbose => log::LevelFilter::Debug,
        };
        static LOG: std::sync::OnceLock<StderrLog> = std::sync::OnceLock::new();
        let logger = LOG.get_or_init(|| StderrLog { level });
        if log::set_logger(logger).is_ok() {
            log::set_max_level(level);
        }
    }
}

impl log::Log for StderrLog {
    fn enabled(&self, m: &log::Metadata<'_>) -> bool {
        m.level() <= self.level && m.target().starts_with("biscale")
    }

    fn log(&self, r: &log::Record<'_>) {
        if !self.enabled(r.metadata()) {
            return;
        }
        match r.level() {
            log::Level::Error => eprintln!("error: {}", r.args()),
            log::Level::Warn => eprintln!("warning: {}", r.args()),
            _ => eprintln!("{}", r.args()),
        }
    }

    fn flush(&self) {}
}

/// An error prints as one line of causes (`error: running x.toml: ...: ...`) and exits 1, with
/// no backtrace even under `RUST_BACKTRACE=1`: that variable is for panics, and a config typo
/// is not one.
pub fn main() -> std::process::ExitCode {
    // As the child process of an isolated plugin (`isolate = true`), serve it and exit here.
    biscale_compressors::plugin::serve_if_child();
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> anyhow::Result<()> {
    let cli = Cli::parse();
    use biscale::util::{set_verbosity, Verbosity};
    let verbosity = match (cli.quiet, cli.verbose) {
        (true, _) => Verbosity::Quiet,
        (_, true) => Verbosity::Verbose,
        _ => Verbosity::Normal,
    };
    set_verbosity(verbosity);
    StderrLog::install(verbosity);
    anyhow::ensure!(
        cli.set.is_empty() || reads_config(&cli.command),
        "--set {}: this command reads no config (--set overrides a config's values for run, plan, export, eval, viz, view, btf and shard plan)",
        cli.set[0]
    );
    let _ = OVERRIDES.set(cli.set.clone());
    if let Some(n) = worker_threads(cli.threads)? {
        // Pools that libraries build for themselves (the OpenEXR reader and writer make one
        // per file) size by this variable: they get the same, capped count (100,000 threads
        // per EXR file hung the machine). Set while this is the process's only thread.
        std::env::set_var("RAYON_NUM_THREADS", n.to_string());
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    match cli.command {
        Command::Run { config, output } => {
            let exp = load(&config)?;
            biscale::run::run(&exp, &output.options()).with_context(|| format!("running {}", config.display()))?;
        }
        Command::Plan { config, cache } => {
            let exp = load(&config)?;
            print!("{}", biscale::plan::Plan::new(&exp).with_estimates(&exp, &cache.options(None))?);
        }
        Command::ExportMatrix { config, out, cache } => {
            let exp = load(&config)?;
            let opts = cache.options(Some(out.clone()));
            let (t, l) = biscale::commands::export_matrix(&exp, &out, &opts)?;
            println!(
                "wrote {} ({} x {}, {} non-zeros), {} ({} x 3), mesh.obj, view.json and irradiance.csv",
                out.join("T.mtx").display(),
                t.rows(),
                t.cols(),
                t.nnz(),
                out.join("L.mtx").display(),
                l.len()
            );
        }
        Command::Export { config, format, what, out, cache } => {
            let items = biscale::interop::Item::parse_list(&what, format).map_err(anyhow::Error::msg)?;
            let exp = load(&config)?;
            let out = out.unwrap_or_else(|| Path::new("out").join(format!("{}-export", exp.name())));
            let opts = cache.options(Some(out.clone()));
            let written = biscale::interop::export(&exp, &out, format, &items, &opts)
                .with_context(|| format!("exporting {}", config.display()))?;
            for w in &written {
                println!("wrote {} ({})", w.path.display(), w.about);
            }
        }
        Command::Report { runs, out } => report(runs, out)?,
        Command::Eval { config, lstar, form, name, out, cache } => eval(config, lstar, form, name, out, cache)?,
        Command::Reproduce { quick, only, out, cache_dir } => reproduce(quick, only, out, cache_dir)?,
        Command::Viz { config, out, first, count, cache } => {
            let exp = load(&config)?;
            let opts = cache.options(Some(out.clone()));
            for p in biscale::commands::viz(&exp, &out, first, count, &opts)? {
                println!("wrote {}", p.display());
            }
        }
        #[cfg(not(feature = "viewer"))]
        Command::View { .. } => anyhow::bail!(
            "this biscale was built without the viewer: rebuild it with `bash scripts/setup-viewer.sh && cargo install \
             --path tools/cli --features viewer` (or run `cargo run --release -p biscale-cli --features viewer -- view CONFIG`)"
        ),
        #[cfg(feature = "viewer")]
        Command::View { config, method, screenshot } => {
            let exp = load(&config)?;
            biscale::commands::view(&exp, method.as_deref(), screenshot, &RunOptions::default())?;
        }
        Command::Generate { what } => {
            let (mesh, out) = match what {
                Generate::Scene { kind, out, force } => (biscale::commands::generate_scene(kind, &out, force)?, out),
                Generate::Subdivide { mesh, levels, unweld, out, force } => {
                    (biscale::commands::subdivide(&mesh, levels, unweld, &out, force)?, out)
                }
                Generate::Uv { mesh, out, force } => (biscale::commands::cylindrical_uv(&mesh, &out, force)?, out),
            };
            let what = format!("({} vertices, {} triangles)", mesh.positions.len(), mesh.triangles.len());
            match out.as_os_str() == "-" {
                true => eprintln!("wrote the mesh to standard output {what}"),
                false => println!("wrote {} {what}", out.display()),
            }
        }
        Command::Btf { config, material, out, preview, cache } => btf(config, material, out, preview, cache)?,
        Command::Shard { what } => shard(what)?,
        Command::Cache { what } => cache(what)?,
        Command::Diff { a, b, mask, error_image, force, json, exposure } => {
            diff(a, b, mask, error_image, force, json, exposure)?
        }
    }
    Ok(())
}

/// `biscale report`: one finished run's report made again (in place or into `--out`), or
/// several runs side by side into `--out`.
fn report(runs: Vec<PathBuf>, out: Option<PathBuf>) -> anyhow::Result<()> {
    let loaded = runs
        .iter()
        .map(|r| biscale::rerender::FinishedRun::load(r).with_context(|| format!("reading the run {}", r.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let dir = match (&loaded[..], &out) {
        ([one], _) => biscale::rerender::rerender(one, out.as_deref())?,
        (_, Some(out)) => biscale::rerender::side_by_side(&loaded, out)?,
        (_, None) => anyhow::bail!("several runs go side by side into one new folder: give --out DIR"),
    };
    println!("wrote {}", dir.join("report.html").display());
    Ok(())
}

/// `biscale reproduce`: the paper's tables and figures, each file it wrote named.
fn reproduce(quick: bool, only: Vec<String>, out: Option<PathBuf>, cache_dir: Option<PathBuf>) -> anyhow::Result<()> {
    let overrides = OVERRIDES.get().cloned().unwrap_or_default();
    let opts = biscale::reproduce::Options { quick, only, out, cache_dir, overrides };
    let done = biscale::reproduce::reproduce(&opts).context("reproducing the paper")?;
    for t in &done.tables {
        println!("wrote {}", done.out_dir.join("tables").join(format!("{}.tex", t.file)).display());
    }
    for f in &done.figures {
        println!(
            "wrote {} ({} panels)",
            done.out_dir.join("figures").join(format!("{}.tex", f.id)).display(),
            f.pictures().count()
        );
    }
    println!("wrote {}", done.out_dir.join("numbers.csv").display());
    println!("wrote {}", done.out_dir.join("index.html").display());
    Ok(())
}

/// `biscale eval`: score an outside L* or form and print its errors.
fn eval(
    config: PathBuf,
    lstar: Option<PathBuf>,
    form: Option<PathBuf>,
    name: Option<String>,
    out: Option<PathBuf>,
    cache: CacheArgs,
) -> anyhow::Result<()> {
    let exp = load(&config)?;
    let input = match (lstar, form) {
        (Some(p), None) => biscale::interop::EvalInput::Lstar(p),
        (None, Some(p)) => biscale::interop::EvalInput::Form(p),
        _ => anyhow::bail!("give one of --lstar FILE or --form FILE"),
    };
    let (dir, metrics) = biscale::interop::eval(&exp, &input, name.as_deref(), &cache.options(out))
        .with_context(|| format!("evaluating {} for {}", input.path().display(), config.display()))?;
    let r = &metrics.compressors[0];
    let img = &r.image.vs_uncompressed;
    println!("{}: rel. error of L* {:.3e}", r.name, r.rel_error_lstar);
    println!("  image vs uncompressed: rel. L2 {:.3e}, PSNR {:.2} dB, SSIM {:.4}", img.rel_l2, img.psnr, img.ssim);
    if let Some(e) = &r.image.vs_reference {
        println!("  image vs reference:    rel. L2 {:.3e}, PSNR {:.2} dB, SSIM {:.4}", e.rel_l2, e.psnr, e.ssim);
    }
    println!("wrote {}", dir.join("metrics.json").display());
    Ok(())
}

/// `biscale btf`: build the config's BTFs and say where each came from.
fn btf(config: PathBuf, material: Option<String>, out: PathBuf, preview: bool, cache: CacheArgs) -> anyhow::Result<()> {
    let exp = load(&config)?;
    let opts = cache.options(Some(out.clone()));
    for w in biscale::commands::btf(&exp, &out, material.as_deref(), preview, &opts)? {
        let how = match &w.origin {
            biscale::stages::materials::Origin::Analytic => "analytic".to_string(),
            biscale::stages::materials::Origin::Synthesized { seconds } => format!("synthesized in {seconds:.1} s"),
            biscale::stages::materials::Origin::Cached(p) => format!("from cache {}", p.display()),
            biscale::stages::materials::Origin::Measured(r, seconds) => format!(
                "resampled from {} views x {} lights in {seconds:.1} s, bins up to {:.1} deg from a measurement",
                r.views, r.lights, r.max_interpolation_angle_deg
            ),
        };
        println!("{}: wrote {} ({:.2} MB, {how})", w.label, w.path.display(), w.bytes as f64 / 1e6);
        if let Some(p) = &w.preview {
            println!("{}: wrote {}", w.label, p.display());
        }
        for c in &w.comparisons {
            println!(
                "{}: wrote {} (dense | {} | |error| x{:.1}; table rel. RMS error {:.2}%)",
                w.label,
                c.path.display(),
                c.representation,
                c.error_gain,
                100.0 * c.relative_rms_error
            );
        }
    }
    Ok(())
}

/// `biscale diff`: two EXR images compared, as text or JSON.
fn diff(
    a: PathBuf,
    b: PathBuf,
    mask: Option<PathBuf>,
    error_image: Option<PathBuf>,
    force: bool,
    json: bool,
    exposure: f32,
) -> anyhow::Result<()> {
    let opts =
        biscale::commands::DiffOptions { mask: mask.as_deref(), error_image: error_image.as_deref(), force, exposure };
    // With the error image on standard output, the figures go to standard error.
    let to_stderr = error_image.as_deref().is_some_and(|p| p.as_os_str() == "-");
    let say = |text: String| match to_stderr {
        true => eprintln!("{text}"),
        false => println!("{text}"),
    };
    let m = biscale::commands::diff(&a, &b, opts, &mut |w| eprintln!("warning: {w}"))?;
    if json {
        let v = serde_json::json!({
            "rmse": m.rmse,
            "psnr": m.psnr.is_finite().then_some(m.psnr),
            "rel_l2": m.rel_l2,
            "pixels": m.pixels,
            "ldr_psnr": m.ldr_psnr.is_finite().then_some(m.ldr_psnr),
            "ssim": m.ssim,
            "flip": m.flip,
        });
        say(v.to_string());
    } else {
        say(format!("rmse {:.6e}\npsnr {:.3} dB\nrel_l2 {:.6e}\npixels {}", m.rmse, m.psnr, m.rel_l2, m.pixels));
        say(format!("ldr_psnr {:.3} dB\nssim {:.6}\nflip {:.6}", m.ldr_psnr, m.ssim, m.flip));
    }
    Ok(())
}

fn shard(what: Shard) -> anyhow::Result<()> {
    use biscale::{scheduler, shard};
    match what {
        Shard::Plan { config, shards, out } => {
            let exp = load(&config)?;
            let (path, m) =
                shard::plan(&exp, shards, &out).with_context(|| format!("planning {}", config.display()))?;
            let available = biscale::estimate::available().ok();
            print!("{}", shard::describe(&m, &path, available.as_ref()));
        }
        Shard::Run { manifest, index } => {
            let index = scheduler::index_from(index)?;
            shard::run(&manifest, index).with_context(|| format!("shard {index} of {}", manifest.display()))?;
        }
        Shard::Status { manifest } => {
            shard::status(&manifest)?;
        }
        Shard::Merge { manifest, output } => {
            shard::merge(&manifest, &output.options()).with_context(|| format!("merging {}", manifest.display()))?;
        }
        Shard::Sbatch { manifest, partition, time, mem, merge_mem, cpus, out, cache_dir } => {
            let o = scheduler::SbatchOptions {
                partition,
                time,
                mem,
                merge_mem,
                cpus,
                merge_out: out,
                merge_cache_dir: cache_dir,
            };
            let files = scheduler::sbatch(&manifest, &o)?;
            for f in &files {
                println!("wrote {}", f.display());
            }
            println!("submit with: bash {}", files[2].display());
        }
        Shard::K8s { manifest, image, cpus, mem, merge_mem, namespace, claim, parallelism, out, cache_dir } => {
            let o = scheduler::K8sOptions {
                image,
                cpus,
                mem,
                merge_mem,
                namespace,
                claim,
                parallelism,
                merge_out: out,
                merge_cache_dir: cache_dir,
            };
            print_job_files(&scheduler::k8s(&manifest, &o)?);
        }
        Shard::Batch { manifest, job_queue, job_definition, image, cpus, mem, merge_mem, out, cache_dir } => {
            let o = scheduler::BatchOptions {
                job_queue,
                job_definition,
                image,
                cpus,
                mem_mib: mem,
                merge_mem_mib: merge_mem,
                merge_out: out,
                merge_cache_dir: cache_dir,
            };
            print_job_files(&scheduler::batch(&manifest, &o)?);
        }
    }
    Ok(())
}

fn print_job_files(j: &biscale::scheduler::JobFiles) {
    for f in &j.files {
        println!("wrote {}", f.display());
    }
    for n in &j.notes {
        println!("note: {n}");
    }
    println!("submit with: bash {}", j.submit.display());
}

fn cache(what: Cache) -> anyhow::Result<()> {
    use biscale::estimate::human;
    use biscale::store::cache;
    let age = |m: std::time::SystemTime| {
        let s = std::time::SystemTime::now().duration_since(m).unwrap_or_default().as_secs_f64();
        match s {
            s if s < 3600.0 => format!("{:.0} min", s / 60.0),
            s if s < 2.0 * 86400.0 => format!("{:.1} h", s / 3600.0),
            s => format!("{:.0} d", s / 86400.0),
        }
    };
    match what {
        Cache::List { cache_dir } => {
            let dir = cache_dir.unwrap_or_else(cache::default_dir);
            let entries = cache::list(&dir).with_context(|| format!("listing {}", dir.display()))?;
            println!("{}: {} files, {}", dir.display(), entries.len(), human(entries.iter().map(|e| e.bytes).sum()));
            for e in &entries {
                println!(
                    "{:<9} {:>10} {:>7}  {}{}",
                    e.kind,
                    human(e.bytes),
                    age(e.modified),
                    e.name,
                    e.inputs.as_ref().map_or(String::new(), |i| format!("\n{:29}{i}", ""))
                );
            }
        }
        Cache::Clean { cache_dir, kind, older_than_days, dry_run } => {
            if let Some(k) = kind.iter().find(|k| !cache::KINDS.contains(&k.as_str())) {
                anyhow::bail!("--kind {k}: not a kind of cache file (one of {})", cache::KINDS.join(", "));
            }
            anyhow::ensure!(
                older_than_days.is_none_or(|d| d.is_finite() && (0.0..=MAX_AGE_DAYS).contains(&d)),
                "--older-than-days must be a number of days from 0 to {MAX_AGE_DAYS}"
            );
            let dir = cache_dir.unwrap_or_else(cache::default_dir);
            let filter = cache::CleanFilter {
                kinds: kind,
                older_than: older_than_days.map(|d| std::time::Duration::from_secs_f64(d * 86400.0)),
            };
            let removed =
                cache::clean(&dir, &filter, dry_run).with_context(|| format!("cleaning {}", dir.display()))?;
            for e in &removed {
                println!("{} {}", if dry_run { "would remove" } else { "removed" }, e.name);
            }
            println!(
                "{}: {} {} files, {}",
                dir.display(),
                if dry_run { "would remove" } else { "removed" },
                removed.len(),
                human(removed.iter().map(|e| e.bytes).sum())
            );
        }
    }
    Ok(())
}
