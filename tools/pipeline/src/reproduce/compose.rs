//! The tables from the runs' records and the published figures: Table I, Table II and the
//! equal-storage / equal-quality comparison, each a [`PaperTable`] whose "ours" cells are
//! [`RunFacts::value`]s (and, for the comparison, the report's own read-offs,
//! [`crate::compare`] and [`crate::report::storage_budget`]) and whose "paper" cells are
//! [`Published`] figures.

use super::facts::{Figure, RunFacts};
use super::published::{Published, ScalingColumn, SceneColumn};
use super::tables::{number, Bound, Cell, Column, PaperTable, Row};
use crate::compare::{by_kind, equal_quality_targets, equal_storage, storage_for_error, StorageForError};
use crate::metrics::Metrics;
use biscale_compressors::registry::{self, Role};

/// A run the tables draw on: its name (`runs/<name>/`), record and how its mesh was made.
pub struct RunOutcome<'a> {
    pub name: &'a str,
    pub facts: RunFacts<'a>,
    /// How the command made the run's mesh, when it did.
    pub mesh_how: Option<String>,
}

impl RunOutcome<'_> {
    fn source(&self) -> String {
        format!("runs/{}", self.name)
    }

    fn m(&self) -> &Metrics {
        self.facts.metrics
    }
}

/// What every caption says of how the runs were made.
pub struct Context<'a> {
    pub quick: bool,
    /// `cpu model, N cores` of this machine.
    pub machine: String,
    pub published: &'a Published,
}

/// The run that stands for a Table I scene (none of them is the paper's own asset: see
/// [`table1`]'s caption).
fn run_of_scene(scene: &str) -> Option<&'static str> {
    match scene {
        "Bunny" => Some("bunny"),
        "Armor" => Some("armor"),
        "Chair" => Some("chair"),
        "Temple" => Some("temple"),
        _ => None,
    }
}

/// One "ours"/"paper" cell of a figure.
pub(super) fn cell(run: Option<&RunOutcome<'_>>, f: Figure, paper: Option<f64>, missing: Option<&str>) -> Cell {
    let mut c = Cell { paper, ..Cell::default() };
    match run {
        Some(r) => {
            c.source = Some(r.source());
            match r.facts.value(f) {
                Ok(v) => c.ours = Some(v),
                Err(why) => c.note = Some(why),
            }
            c.busy = r.facts.busy(f);
            c.load = r.facts.load_of(f);
            if let Some(n) = r.facts.note(f) {
                c.note = Some(match c.note.take() {
                    Some(a) => format!("{a}; {n}"),
                    None => n,
                });
            }
        }
        None => c.note = missing.map(str::to_string),
    }
    c
}

pub(super) fn row(f: Figure, cells: Vec<Cell>) -> Row {
    let (key, label, unit, decimals) = f.describe();
    Row::numeric(key, label, unit, decimals, cells)
}

/// A Table I figure as the paper printed it (`None` for the rows the paper does not have).
fn scene_figure(c: &SceneColumn, f: Figure) -> Option<f64> {
    use Figure::*;
    match f {
        Width => Some(c.width as f64),
        Height => Some(c.height as f64),
        Btfs => Some(c.btfs as f64),
        BtfMb => Some(c.btf_mb),
        _ => scaling_figure(&c.figures, f),
    }
}

/// A Table II figure as the paper printed it (`None` for the rows Table II does not have).
fn scaling_figure(c: &ScalingColumn, f: Figure) -> Option<f64> {
    use Figure::*;
    Some(match f {
        Vertices => c.vertices as f64,
        NnzM => c.nnz_m,
        NnzPerVertex => c.nnz_m * 1e6 / c.vertices as f64,
        Mflops => c.mflops,
        ReducedMflops => c.reduced_mflops,
        ComputationPct => c.computation_pct,
        DataMb => c.data_mb,
        ReducedMb => c.reduced_mb,
        DataPct => c.data_pct,
        PrecomputeMin => c.precompute_min,
        FpsFixedLight => c.fps_fixed_light,
        FpsMovingLight => c.fps_moving_light,
        Width | Height | Btfs | BtfMb | ProjectedFpsFixedLight | ProjectedFpsMovingLight => return None,
    })
}

/// Table I's rows, in the paper's order (the figure per vertex added after nnz(T), the
/// projected ceilings last).
const TABLE1: [Figure; 18] = [
    Figure::Width,
    Figure::Height,
    Figure::Vertices,
    Figure::Btfs,
    Figure::BtfMb,
    Figure::NnzM,
    Figure::NnzPerVertex,
    Figure::Mflops,
    Figure::ReducedMflops,
    Figure::ComputationPct,
    Figure::DataMb,
    Figure::ReducedMb,
    Figure::DataPct,
    Figure::PrecomputeMin,
    Figure::FpsFixedLight,
    Figure::FpsMovingLight,
    Figure::ProjectedFpsFixedLight,
    Figure::ProjectedFpsMovingLight,
];

/// The settings the runs share, from the first run's record: `6x32x32 cubemap light, ...`.
fn settings(m: &Metrics) -> String {
    let r = m.lighting.cubemap_resolution;
    let grid = (m.transfer.local_dirs as f64).sqrt().round() as usize;
    format!(
        "6x{r}x{r} cubemap light, 6x{v}x{v} visibility box-filtered to it, {grid}x{grid} local directions",
        v = m.transfer.visibility_resolution
    )
}

/// The sentence on how `--quick` differs, or that the paper's settings were used.
fn mode(ctx: &Context<'_>, m: &Metrics) -> String {
    match ctx.quick {
        true => format!(
            "Made with --quick: {}, small images and one timing repeat, so the figures show the pipeline end to end at \
             small sizes, not the paper's scale.",
            settings(m)
        ),
        false => format!("Transfer settings as the paper's: {}.", settings(m)),
    }
}

const DEFINITIONS: &str = "MFLOPs: 2 nnz(T), one multiply-add per non-zero and one channel; reduced to: the lossless \
    biclustered gather's count, the sum over biclusters of r + 2l - 1 (the paper's W(B)); computation: their ratio \
    (both from the bicluster form's `stats`). Data size: the dense T at one byte per entry, vertices x M x 6R^2 \
    (Table II's 4,868 and 18,859 MB are exactly that for 12,380 and 47,960 vertices; its and Table I's 1,400 MB for \
    3,286 vertices is 8% above the 1,292 MB that gives). Reduced to: the bytes of the lossless biclustered form, \
    biclustered in 1,024-vertex blocks (the paper's is one global greedy). Precomputation: tracing T plus \
    biclustering it, on the CPU cores of this machine. fps: CPU gather and CPU shading on this machine (fixed light: \
    1000 / shade ms; moving light: 1000 / (gather + shade) ms, medians), where the paper's gather and shade run on \
    the GPU. Every time carries its load (numbers.csv's note, the cell's title in the page); one taken while the \
    load exceeded the machine's CPUs is marked (busy): it measures the queue as much as the method. fps ceiling \
    (projected): the frame-time model's floor of the lossless biclustered form's shade (fixed light) and gather plus \
    shade (moving light) at the run's image size on an NVIDIA H100 SXM5, from its published bandwidth and fp32 peak \
    (report's \"Frame-time model\"): a lower bound on that GPU's time, so a ceiling on its frame rate, not a \
    measurement, and not comparable with the measured rows above it.";

/// Table I: the paper's four scenes, each by an open stand-in ([`run_of_scene`]).
pub fn table1(ctx: &Context<'_>, runs: &[RunOutcome<'_>]) -> PaperTable {
    let find = |name: &str| runs.iter().find(|r| r.name == name);
    let scenes = &ctx.published.table1;
    let ours_head = if ctx.quick { "ours (quick)" } else { "ours" };
    let columns = scenes
        .iter()
        .map(|s| Column {
            name: s.scene.clone(),
            ours_head: ours_head.into(),
            paper_head: Some(format!("paper ({})", s.figure)),
        })
        .collect();
    let rows = TABLE1
        .iter()
        .map(|&f| {
            let cells = scenes
                .iter()
                .map(|s| {
                    let run = run_of_scene(&s.scene).and_then(&find);
                    cell(run, f, scene_figure(s, f), Some("its run did not take place"))
                })
                .collect();
            row(f, cells)
        })
        .collect();
    let p = &ctx.published.platform;
    let mut caption = String::from("Ours: ");
    let mut described = vec![];
    for s in scenes {
        let scene = s.scene.as_str();
        if let Some(r) = run_of_scene(scene).and_then(&find) {
            let mesh = r.mesh_how.clone().unwrap_or_else(|| format!("`{}`", file_name(&r.m().scene.mesh)));
            let btfs = r.m().scene.btfs.iter().filter(|b| b.primary).count();
            let material = match btfs {
                1 => r.m().scene.material.clone(),
                n => format!("{n} synthesized BTFs"),
            };
            described.push(format!("{scene}, {mesh}, {} vertices, {material}", number(r.m().scene.vertices as f64, 0)));
        }
    }
    caption += &described.join("; ");
    caption += &format!(
        ". Run by `biscale reproduce` on this machine ({}); the paper's on a {} with an {}. ",
        ctx.machine, p.cpu, p.gpu
    );
    if let Some(r) = runs.first() {
        caption += &mode(ctx, r.m());
        caption.push(' ');
    }
    caption += DEFINITIONS;
    caption += " BTF size: the materials' dense tables at f32 (synthesized BTFs here, measured ones in the paper). ";
    caption += "None of the paper's meshes or measured BTFs is bundled: each column is an open stand-in of the same \
                character, the bumpy bunny, the glossy teapot of Fig. 5 at the Armor's 12x12 local directions, a \
                generated chair with three BTFs and the generated five-BTF temple, each near the paper's vertex count.";
    PaperTable { item: "table1".into(), file: "table1".into(), title: "Table I".into(), caption, columns, rows }
}

/// Table II: the bunny at three vertex counts, the first being Table I's bunny run.
pub fn table2(ctx: &Context<'_>, runs: &[RunOutcome<'_>]) -> PaperTable {
    let names = ["bunny", "bunny-l1", "bunny-l2"];
    // Table I's rows but the image and BTF ones (Table II has none).
    let figures: Vec<Figure> = TABLE1
        .iter()
        .copied()
        .filter(|f| !matches!(f, Figure::Width | Figure::Height | Figure::Btfs | Figure::BtfMb))
        .collect();
    let ours_head = if ctx.quick { "ours (quick)" } else { "ours" };
    let columns = ctx
        .published
        .table2
        .iter()
        .map(|c| Column {
            name: format!("bunny {}", c.vertices),
            ours_head: ours_head.into(),
            paper_head: Some("paper".into()),
        })
        .collect();
    let rows = figures
        .iter()
        .map(|&f| {
            let cells = ctx
                .published
                .table2
                .iter()
                .zip(names)
                .map(|(c, n)| {
                    cell(runs.iter().find(|r| r.name == n), f, scaling_figure(c, f), Some("its run did not take place"))
                })
                .collect();
            row(f, cells)
        })
        .collect();
    let vertices: Vec<String> = names
        .iter()
        .filter_map(|n| runs.iter().find(|r| r.name == *n))
        .map(|r| number(r.m().scene.vertices as f64, 0))
        .collect();
    let mut caption = format!(
        "Ours: the bundled bunny (`bunny_uv.obj`) and the same midpoint-subdivided once and twice, {} vertices, all at \
         Table I's Bunny settings (the first column is Table I's Bunny run, as the paper's is); the paper's bunnies have \
         3,286, 12,380 and 47,960 vertices. The subdivided bunnies are the coarse one's facets cut finer, so their T \
         grows with the vertex count as the paper's does but their shadows are the coarse shape's. Run on this machine \
         ({}). ",
        vertices.join(", "),
        ctx.machine
    );
    if let Some(r) = runs.iter().find(|r| names.contains(&r.name)) {
        caption += &mode(ctx, r.m());
        caption.push(' ');
    }
    caption += "Definitions as in Table I.";
    PaperTable { item: "table2".into(), file: "table2".into(), title: "Table II".into(), caption, columns, rows }
}

/// The comparison at equal storage (the paper's Fig. 6) and at equal quality (which the paper
/// did not make), from the equal-quality run.
pub fn equal_quality(ctx: &Context<'_>, run: &RunOutcome<'_>) -> PaperTable {
    let m = run.m();
    let fig6 = &ctx.published.fig6;
    let kinds = by_kind(&m.compressors);
    let paper_kind = registry::by_role(Role::Paper).map(|k| k.name);
    let budget = crate::report::storage_budget(m);
    let picked = budget.as_ref().map(|(b, _)| equal_storage(&m.compressors, *b)).unwrap_or_default();
    let at_budget = |kind: &str| picked.iter().find(|r| crate::compare::series_of(r) == kind).copied();
    let paper_mb = |kind: &str| fig6.storage_mb.get(kind).copied();
    let paper_budget = paper_kind.and_then(paper_mb);
    let source = Some(run.source());
    let ours_head = if ctx.quick { "ours (quick)" } else { "ours" };
    let columns = kinds
        .iter()
        .map(|(k, _)| Column {
            name: k.clone(),
            ours_head: ours_head.into(),
            paper_head: Some(format!("paper ({})", fig6.scene)),
        })
        .collect();
    let numeric = Row::numeric;
    let mut rows = vec![];
    rows.push(Row {
        key: "setting".into(),
        label: "setting at equal storage".into(),
        unit: String::new(),
        decimals: 0,
        text: true,
        cells: kinds
            .iter()
            .map(|(k, _)| Cell {
                ours_text: Some(at_budget(k).map_or("--".into(), |r| r.name.clone())),
                paper_text: Some(fig6.setting.get(k).cloned().unwrap_or_else(|| "--".into())),
                ..Cell::default()
            })
            .collect(),
    });
    let per_kind = |f: &dyn Fn(&str) -> Cell| kinds.iter().map(|(k, _)| f(k)).collect::<Vec<Cell>>();
    rows.push(numeric(
        "equal_storage_mb",
        "storage at equal storage",
        "MB",
        2,
        per_kind(&|k| Cell {
            ours: at_budget(k).map(|r| r.bytes as f64 / 1e6),
            paper: paper_mb(k),
            note: at_budget(k).map(|r| format!("ours: {}", r.name)),
            source: source.clone(),
            ..Cell::default()
        }),
    ));
    rows.push(numeric(
        "equal_storage_ratio",
        "storage / lossless biclustering's",
        "",
        3,
        per_kind(&|k| Cell {
            ours: at_budget(k).zip(budget.as_ref()).map(|(r, (b, _))| r.bytes as f64 / *b as f64),
            paper: paper_mb(k).zip(paper_budget).map(|(a, b)| a / b),
            source: source.clone(),
            ..Cell::default()
        }),
    ));
    rows.push(numeric(
        "equal_storage_error_pct",
        "rel. L* error at equal storage",
        "%",
        2,
        per_kind(&|k| Cell {
            ours: at_budget(k).map(|r| 100.0 * r.rel_error_lstar),
            source: source.clone(),
            ..Cell::default()
        }),
    ));
    rows.push(numeric(
        "equal_storage_build_s",
        "build at equal storage",
        "s",
        2,
        per_kind(&|k| Cell {
            ours: at_budget(k).map(|r| r.build_seconds),
            source: source.clone(),
            note: at_budget(k)
                .filter(|r| r.cached)
                .map(|_| "form from the stage cache: its build time as measured then".into()),
            ..Cell::default()
        }),
    ));
    for target in equal_quality_targets(m.target_error) {
        let cells = kinds
            .iter()
            .map(|(_, recs)| equal_quality_cell(recs, target, source.clone(), &fig6.equal_quality_note))
            .collect();
        rows.push(numeric(
            &format!("equal_quality_mb_{target:.0e}"),
            &format!("storage for rel. L* error {}", percent(target)),
            "MB",
            2,
            cells,
        ));
    }
    let budget_text = budget.as_ref().map_or("--".into(), |(b, why)| format!("{why}, {:.2} MB", *b as f64 / 1e6));
    let caption = equal_quality_caption(ctx, m, &budget_text);
    PaperTable {
        item: "equal-quality".into(),
        file: "equal_quality".into(),
        title: "Fig. 6 and the equal-quality comparison".into(),
        caption,
        columns,
        rows,
    }
}

/// One kind's storage for relative `L*` error `target`, read off its sweep `recs`
/// ([`storage_for_error`]) with how it was read, beside the paper's "not made" (`note`).
fn equal_quality_cell(
    recs: &[&crate::metrics::CompressorRecord],
    target: f64,
    source: Option<String>,
    note: &str,
) -> Cell {
    let mut c = Cell { source, paper_text: Some("not made".into()), note: Some(note.to_string()), ..Cell::default() };
    let read = storage_for_error(recs, target);
    let (ours, bound, how) = match &read {
        Some(StorageForError::AtMost { bytes, setting }) => {
            (Some(*bytes as f64), Bound::AtMost, format!("{setting} already meets it"))
        }
        Some(StorageForError::Between { bytes, below, above }) => {
            (Some(*bytes), Bound::Exact, format!("interpolated between {below} and {above}"))
        }
        Some(StorageForError::NotReached { best_error, setting }) => (
            recs.iter().map(|r| r.bytes).max().map(|b| b as f64),
            Bound::MoreThan,
            format!("not reached by the sweep (best {best_error:.2e} at {setting})"),
        ),
        None => (None, Bound::Exact, "no setting".into()),
    };
    c.ours = ours.map(|b| b / 1e6);
    c.bound = bound;
    c.note = Some(format!("{how}; {}", c.note.take().unwrap_or_default()));
    c
}

/// The equal-quality table's caption: what ran, in which mode, and how each figure is read.
fn equal_quality_caption(ctx: &Context<'_>, m: &Metrics, budget_text: &str) -> String {
    let fig6 = &ctx.published.fig6;
    let mut caption = format!(
        "Ours: `{}`, a copy of `configs/compare_bunny.toml`: the {}-vertex bunny, raw sparse, lossless and lossy \
         biclustering, CPCA and Haar with sweeps, run on this machine ({}). ",
        file_name(&m.config),
        number(m.scene.vertices as f64, 0),
        ctx.machine
    );
    caption += &mode(ctx, m);
    caption += &format!(
        " Equal storage (the paper's Fig. 6): each kind's setting closest in log ratio to {budget_text}. The paper's \
         figures are of another scene, a {}-vertex {} with measured BTFs, which is not bundled: compare the ratios to \
         biclustering's storage and the settings, not the megabytes. Equal quality: the storage each kind needs for a \
         relative L* error of each target, log-log interpolated between the two settings of its sweep that bracket it, \
         never extrapolated (<= where the cheapest setting already meets it; > where none of the sweep does, so it needs \
         more than its largest). The paper did not make this comparison: {}.",
        number(fig6.vertices as f64, 0),
        fig6.scene.to_lowercase(),
        fig6.equal_quality_note.trim_start_matches("not made in the paper: ")
    );
    caption
}

/// A relative error as a percentage for a label: `0.1%`, `5%`.
fn percent(x: f64) -> String {
    let p = 100.0 * x;
    let s = format!("{p:.3}");
    format!("{}%", s.trim_end_matches('0').trim_end_matches('.'))
}

/// The last component of a path as written in a record.
fn file_name(path: &str) -> String {
    std::path::Path::new(path).file_name().map_or(path.to_string(), |n| n.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentages_read_plainly() {
        assert_eq!(percent(1e-3), "0.1%");
        assert_eq!(percent(0.05), "5%");
        assert_eq!(percent(0.1), "10%");
    }

    #[test]
    fn every_table1_scene_has_its_run() {
        for s in &Published::get().table1 {
            let run = run_of_scene(&s.scene).unwrap_or_else(|| panic!("{}", s.scene));
            assert!(super::super::items::RUNS.iter().any(|r| r.name == run), "{run}");
        }
    }
}
