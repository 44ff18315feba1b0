//! `biscale report`: a finished run's report from its record alone, with no tracing.
//!
//! * **One run** ([`rerender`]): `metrics.json` and the `plan.txt` beside it are read back
//!   ([`FinishedRun::load`]) and the plots, `report.html` and `report.md` are written by the
//!   same code a run writes them with (`crate::report::write_documents`), so the pages are
//!   byte-identical to the run's own when nothing changed, and show today's layout when the
//!   report code did. In place, or into `--out` (the run's files are copied there first).
//! * **Several runs** ([`side_by_side`]): one page that sets every run's compressor and method
//!   rows side by side (a table and the storage and time plots, one curve per run and kind).
//!
//! Both write through a staged folder (`crate::store::staging`), so a report is replaced whole, and a
//! folder is only ever replaced when its marker proves it biscale's.

use crate::error::{io_err, PipelineError, Result};
use crate::metrics::{CompressorRecord, Metrics};
use crate::report::{Block, Table};
use crate::store::staging::{StagedDir, MARKER};
use std::path::{Path, PathBuf};

/// A finished run as `biscale report` reads it back.
#[derive(Debug)]
pub struct FinishedRun {
    /// The run's folder (where its `metrics.json` is).
    pub dir: PathBuf,
    pub metrics: Metrics,
    /// The text of its `plan.txt`.
    pub plan: String,
}

/// The largest `metrics.json` read back (a run's is tens of kilobytes).
const MAX_METRICS_BYTES: u64 = 256 << 20;
/// The largest `plan.txt` read back (a run's is a few kilobytes; a sweep's lists a line per
/// setting).
const MAX_PLAN_BYTES: u64 = 64 << 20;

impl FinishedRun {
    /// Read a run from its folder or its `metrics.json`.
    pub fn load(path: &Path) -> Result<Self> {
        let (dir, json) = if path.is_dir() {
            (path.to_path_buf(), path.join("metrics.json"))
        } else {
            (path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf(), path.into())
        };
        let invalid = |what: String| PipelineError::Mismatch { path: json.clone(), what };
        let text = biscale_core::io::read_regular_text(&json, MAX_METRICS_BYTES, "run's metrics.json")
            .map_err(io_err(&json))?;
        let metrics: Metrics = serde_json::from_str(&text)
            .map_err(|e| invalid(format!("not a biscale metrics.json this build reads: {e}")))?;
        // A record names files inside its own run folder only: the report reads and embeds
        // them, so a tampered path (absolute, climbing out, through a link) is refused here.
        let value: serde_json::Value = serde_json::from_str(&text).expect("parsed just above");
        for (field, rel) in crate::metrics::named_files(&value) {
            if let Err(why) = biscale_core::io::inside_folder(&dir, &rel) {
                return Err(invalid(format!(
                    "field `{field}` names {rel:?}, which {why}: a record names files inside its own run folder only"
                )));
            }
        }
        if metrics.schema_version != crate::provenance::SCHEMA_VERSION {
            return Err(invalid(format!(
                "schema version {}, this build reads version {}",
                metrics.schema_version,
                crate::provenance::SCHEMA_VERSION
            )));
        }
        let plan_path = dir.join("plan.txt");
        let plan = biscale_core::io::read_regular_text(&plan_path, MAX_PLAN_BYTES, "run's plan.txt")
            .map_err(io_err(&plan_path))?;
        Ok(Self { dir, metrics, plan })
    }
}

/// Copy every file and folder of `from` (links and the marker left out) into `to`.
fn copy_run(from: &Path, to: &Path) -> Result<()> {
    for e in std::fs::read_dir(from).map_err(io_err(from))? {
        let e = e.map_err(io_err(from))?;
        let (src, dst) = (e.path(), to.join(e.file_name()));
        let kind = std::fs::symlink_metadata(&src).map_err(io_err(&src))?.file_type();
        if e.file_name() == MARKER || kind.is_symlink() {
            continue;
        }
        if kind.is_dir() {
            std::fs::create_dir_all(&dst).map_err(io_err(&dst))?;
            copy_run(&src, &dst)?;
        } else if kind.is_file() {
            std::fs::copy(&src, &dst).map_err(io_err(&dst))?;
        }
    }
    Ok(())
}

/// Re-render `run`'s plots, `report.html` and `report.md` into `out` (default: the run's own
/// folder): the run's files are staged with the new documents and swapped in whole.
pub fn rerender(run: &FinishedRun, out: Option<&Path>) -> Result<PathBuf> {
    let target = out.unwrap_or(&run.dir);
    let staged = StagedDir::begin(target, &format!("biscale report {}", run.dir.join("metrics.json").display()))?;
    copy_run(&run.dir, staged.path())?;
    crate::report::write_documents(&run.metrics, &run.plan, staged.path())?;
    Ok(staged.commit()?)
}

/// One page setting the compressor and method rows of several runs side by side, written into
/// `out` (`report.md`, `report.html` and the plots).
pub fn side_by_side(runs: &[FinishedRun], out: &Path) -> Result<PathBuf> {
    // The page goes into a folder of its own: never over one of the runs it compares (a run
    // folder is replaceable by biscale, so `report A B --out A` would have deleted run A).
    for r in runs {
        if biscale_core::io::same_file(out, &r.dir) {
            return Err(PipelineError::Mismatch {
                path: out.into(),
                what: format!(
                    "is the run folder {}, one of the runs compared; give --out a new folder for the side-by-side page",
                    r.dir.display()
                ),
            });
        }
    }
    let staged = StagedDir::begin(out, &format!("biscale report of {} runs", runs.len()))?;
    let dir = staged.path();
    let plots = comparison_plots(runs, dir);
    let blocks = comparison_blocks(runs, &plots);
    let title = format!("{} runs side by side", runs.len());
    biscale_core::io::write_atomic_bytes(
        &dir.join("report.html"),
        crate::html::page(&title, blocks.clone(), dir).as_bytes(),
    )?;
    biscale_core::io::write_atomic_bytes(&dir.join("report.md"), crate::report::markdown_of(blocks).as_bytes())?;
    Ok(staged.commit()?)
}

/// Each run's label: its folder's name (`#2`, `#3`, ... appended where two are named alike).
fn labels(runs: &[FinishedRun]) -> Vec<String> {
    let mut out: Vec<String> = vec![];
    for r in runs {
        let name = r.dir.file_name().map_or(r.metrics.experiment.clone(), |n| n.to_string_lossy().into_owned());
        let taken = out.iter().filter(|l| l.split(" #").next() == Some(name.as_str())).count();
        out.push(if taken == 0 { name } else { format!("{name} #{}", taken + 1) });
    }
    out
}

/// Every compressor and method record of every run with the run's label and the record's
/// kind.
fn named_records(runs: &[FinishedRun]) -> Vec<(String, String, &CompressorRecord)> {
    let mut out = vec![];
    for (r, label) in runs.iter().zip(labels(runs)) {
        for c in &r.metrics.compressors {
            out.push((label.clone(), c.kind.clone(), c));
        }
        for m in &r.metrics.methods {
            out.push((label.clone(), m.record.kind.clone(), &m.record));
        }
    }
    out
}

fn comparison_plots(runs: &[FinishedRun], dir: &Path) -> Vec<(String, String)> {
    type Axis = fn(&CompressorRecord) -> f64;
    let records = named_records(runs);
    let plots: [(&str, &str, &str, Axis); 2] = [
        ("error_vs_storage", "relative error of L* against storage", "storage (MB)", |r| r.bytes as f64 / 1e6),
        ("error_vs_time", "relative error of L* against gather time", "gather time (ms, CPU)", |r| r.gather_ms),
    ];
    let mut out = vec![];
    for (file, title, x_label, x) in plots {
        let named = records.iter().map(|(exp, kind, r)| (format!("{exp}: {kind}"), *r));
        let series = crate::plots::series_by(named, x, |r| r.rel_error_lstar);
        let rel = format!("{file}.png");
        match crate::plots::log_log_plot_with(&dir.join(&rel), title, x_label, "relative L2 error of L*", &series, None)
        {
            Ok(()) => out.push((rel, title.to_string())),
            Err(e) => crate::util::warn(format_args!("plot {file}: {e}")),
        }
    }
    out
}

fn comparison_blocks(runs: &[FinishedRun], plots: &[(String, String)]) -> Vec<Block> {
    let mut d = vec![Block::Heading(1, format!("{} runs side by side", runs.len()))];
    let sources: Vec<String> = runs
        .iter()
        .zip(labels(runs))
        .map(|(r, label)| {
            let m = &r.metrics;
            let when = m.run.as_ref().map_or(String::new(), |p| format!(", run {} on {}", p.started_at, p.host));
            format!(
                "`{label}`: experiment `{}`, config `{}`, {} vertices, {} x {} cubemap{when} (`{}`)",
                m.experiment,
                m.config,
                m.scene.vertices,
                m.lighting.cubemap_resolution,
                m.lighting.cubemap_resolution,
                r.dir.join("metrics.json").display()
            )
        })
        .collect();
    d.push(Block::List(sources));
    let mut t = Table::new(&[
        "run",
        "setting",
        "kind",
        "lossless",
        "storage (MB)",
        "gather (ms)",
        "build (s)",
        "L* rel. error",
        "image rel. L2 vs uncompressed",
        "image rel. L2 vs reference",
    ]);
    for (exp, _, r) in named_records(runs) {
        t.text_row([
            exp,
            r.name.clone(),
            r.kind.clone(),
            if r.lossless { "yes" } else { "no" }.to_string(),
            format!("{:.3}", r.bytes as f64 / 1e6),
            format!("{:.2}", r.gather_ms),
            format!("{:.2}", r.build_seconds),
            format!("{:.2e}", r.rel_error_lstar),
            format!("{:.2e}", r.image.vs_uncompressed.rel_l2),
            r.image.vs_reference.map_or("-".to_string(), |e| format!("{:.2e}", e.rel_l2)),
        ]);
    }
    d.push(Block::Table(t));
    if !plots.is_empty() {
        let figures = plots
            .iter()
            .map(|(src, caption)| crate::report::Figure {
                src: src.clone(),
                caption: caption.clone(),
                link: Some(crate::report::svg_twin(src)),
            })
            .collect();
        d.push(Block::Figures { figures, wide: true });
    }
    d
}
