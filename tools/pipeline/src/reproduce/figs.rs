//! The items that are figures of the paper: Figs. 1 and 5 (low- vs all-frequency, a table of
//! ours alone since the paper printed images, and the images), Fig. 8 (the local grid, a
//! table beside the paper's figures), and the image sets of Figs. 3(b), 6 and 7. Every number
//! is read off a run's record like the tables' ([`RunFacts`], the record's own fields); every
//! panel is an image the run wrote ([`FigureSet::add`]).

use super::compose::{cell, row, Context, RunOutcome};
use super::facts::{paper_form, Figure};
use super::figures::FigureSet;
use super::tables::{number, Cell, Column, PaperTable, Row};
use crate::compare::equal_storage;
use crate::error::Result;
use crate::metrics::{CompressorRecord, Metrics};
use biscale_compressors::registry::{self, Role};
use std::path::Path;

fn ours_head(ctx: &Context<'_>) -> &'static str {
    if ctx.quick {
        "ours (quick)"
    } else {
        "ours"
    }
}

fn raw(m: &Metrics) -> Option<&CompressorRecord> {
    m.compressors.iter().find(|c| registry::role_of(&c.kind) == Role::Raw)
}

/// The SH settings of a run by order, ascending.
fn sh_orders(m: &Metrics) -> Vec<(u32, &CompressorRecord)> {
    let mut v: Vec<(u32, &CompressorRecord)> =
        m.methods.iter().filter_map(|r| r.sh.as_ref().map(|s| (s.order, &r.record))).collect();
    v.sort_by_key(|(o, _)| *o);
    v
}

/// One method of the low- vs all-frequency comparison: a column.
struct Method<'a> {
    name: String,
    /// The setting in the paper-rule run, and its counterpart in the moments run (the
    /// all-frequency settings only).
    paper_rule: Option<&'a CompressorRecord>,
    moments: Option<&'a CompressorRecord>,
}

/// The columns: raw T, lossless biclustering, SH at the paper's order 5, at the order whose
/// transfer storage is nearest the biclustered T's, and at the highest order run.
fn methods<'a>(paper: &'a Metrics, moments: Option<&'a Metrics>) -> (Vec<Method<'a>>, Option<u32>) {
    let mut out = vec![];
    let counterpart = |c: &CompressorRecord| moments.and_then(|m| m.compressors.iter().find(|d| d.name == c.name));
    for c in [raw(paper), paper_form(paper)].into_iter().flatten() {
        let name = match registry::role_of(&c.kind) {
            Role::Raw => "all-frequency, raw T".to_string(),
            _ => format!("all-frequency, {}", c.name),
        };
        out.push(Method { name, paper_rule: Some(c), moments: counterpart(c) });
    }
    let sh = sh_orders(paper);
    let equal = paper_form(paper).and_then(|b| {
        let picked = equal_storage(sh.iter().map(|(_, r)| *r), b.bytes);
        picked.first().and_then(|p| sh.iter().find(|(_, r)| r.name == p.name).map(|(o, _)| *o))
    });
    let mut wanted: Vec<(u32, &str)> = vec![(5, "the paper's")];
    if let Some(o) = equal {
        wanted.push((o, "equal storage"));
    }
    if let Some((o, _)) = sh.last() {
        wanted.push((*o, "highest run"));
    }
    for (order, why) in wanted {
        if let Some((_, r)) = sh.iter().find(|(o, _)| *o == order) {
            out.push(Method { name: format!("SH order {order} ({why})"), paper_rule: Some(r), moments: None });
        }
    }
    (out, equal)
}

fn rel_l2(c: Option<&CompressorRecord>) -> Option<f64> {
    c.and_then(|c| c.image.vs_reference.as_ref()).map(|e| e.rel_l2).filter(|x| x.is_finite())
}

/// Figs. 1 and 5: one table per scene, ours alone (the paper printed images), and the caption
/// saying what the numbers say at each order.
pub fn low_vs_all(
    ctx: &Context<'_>,
    file: &str,
    title: &str,
    paper_says: &str,
    run: &RunOutcome<'_>,
    moments: Option<&RunOutcome<'_>>,
) -> PaperTable {
    let m = run.facts.metrics;
    let mm = moments.map(|r| r.facts.metrics);
    let (methods, equal) = methods(m, mm);
    let columns = methods.iter().map(|x| Column::ours(x.name.clone(), ours_head(ctx))).collect();
    let src = |mom: bool| Some(format!("runs/{}", if mom { moments.map_or(run.name, |r| r.name) } else { run.name }));
    let cell = |v: Option<f64>, mom: bool, note: Option<&str>| Cell {
        ours: v,
        source: src(mom),
        note: note.map(str::to_string),
        ..Cell::default()
    };
    let row = Row::numeric;
    let rows = vec![
        row(
            "transfer_mb",
            "transfer storage",
            "MB",
            2,
            methods.iter().map(|x| cell(x.paper_rule.map(|c| c.bytes as f64 / 1e6), false, None)).collect(),
        ),
        row(
            "error_paper_rule",
            "image error vs ground truth, paper's rule",
            "rel. L2",
            4,
            methods.iter().map(|x| cell(rel_l2(x.paper_rule), false, None)).collect(),
        ),
        row(
            "error_light_moments",
            "image error vs ground truth, light moments",
            "rel. L2",
            4,
            methods
                .iter()
                .map(|x| match x.moments {
                    Some(c) => cell(rel_l2(Some(c)), true, None),
                    None => cell(None, true, Some("light moments change the all-frequency gather only")),
                })
                .collect(),
        ),
        row(
            "gather_ms",
            "gather (CPU, median)",
            "ms",
            2,
            methods.iter().map(|x| cell(x.paper_rule.map(|c| c.gather_ms), false, None)).collect(),
        ),
        row(
            "shade_ms",
            "shade (CPU, median)",
            "ms",
            1,
            methods.iter().map(|x| cell(x.paper_rule.map(|c| c.shade_ms), false, None)).collect(),
        ),
    ];
    let mut caption = format!(
        "{paper_says} Ours: {}, {} vertices, {}; errors are relative L2 against the ray-traced ground truth (direct \
         light, each texel's own visibility). The all-frequency rows are the same T and BTFs shaded by the paper's \
         rule (each 8x8 bin's mean cosine) and with light moments (`runtime.light_moments = true`, run \
         `{}`). ",
        file_name(&m.scene.mesh),
        number(m.scene.vertices as f64, 0),
        m.scene.material,
        moments.map_or("none", |r| r.name),
    );
    caption += &verdict(m, mm, equal);
    caption += &format!(" Run on this machine ({}).", ctx.machine);
    if ctx.quick {
        caption += " Made with --quick: small transfer, BTFs and images, so the errors show the pipeline, not the paper's scale.";
    }
    PaperTable { item: "low-vs-all".into(), file: file.into(), title: title.into(), caption, columns, rows }
}

/// What the numbers say: the best SH order against each all-frequency rule, and where SH wins.
fn verdict(m: &Metrics, mm: Option<&Metrics>, equal: Option<u32>) -> String {
    let Some(b) = paper_form(m) else { return "No lossless biclustering ran.".into() };
    let sh = sh_orders(m);
    let (Some(paper_rule), false) = (rel_l2(Some(b)), sh.is_empty()) else {
        return "No ground truth or SH setting to compare.".into();
    };
    let moments = mm.and_then(|mm| rel_l2(mm.compressors.iter().find(|c| c.name == b.name)));
    let beats = |x: f64| -> Vec<String> {
        sh.iter().filter(|(_, r)| rel_l2(Some(r)).is_some_and(|e| e < x)).map(|(o, _)| o.to_string()).collect()
    };
    let order_err = |o: u32| sh.iter().find(|(k, _)| *k == o).and_then(|(_, r)| rel_l2(Some(r)));
    let mut s = format!("Lossless biclustering: {paper_rule:.4} by the paper's rule");
    if let Some(x) = moments {
        s += &format!(", {x:.4} with light moments");
    }
    s += ". SH: ";
    s += &sh
        .iter()
        .filter_map(|(o, r)| rel_l2(Some(r)).map(|e| format!("order {o} {e:.4}")))
        .collect::<Vec<_>>()
        .join(", ");
    s += ". ";
    if let Some(o) = equal {
        s += &format!("At equal transfer storage the SH order is {o}. ");
    }
    let w = beats(paper_rule);
    s += &match w.is_empty() {
        true => "No SH order run beats the paper's rule.".to_string(),
        false => format!("SH beats the paper's rule at order {}.", w.join(", ")),
    };
    if let Some(x) = moments {
        let w = beats(x);
        s += &match w.is_empty() {
            true => " With light moments the all-frequency method beats every SH order run.".to_string(),
            false => format!(" With light moments SH still wins at order {}.", w.join(", ")),
        };
    }
    if let Some(e5) = order_err(5) {
        s += &format!(
            " Against SH order 5, the paper's setting, the all-frequency error is {:.2}x by the paper's rule",
            paper_rule / e5
        );
        s += &match moments {
            Some(x) => format!(" and {:.2}x with light moments.", x / e5),
            None => ".".into(),
        };
    }
    s
}

fn file_name(path: &str) -> String {
    Path::new(path).file_name().map_or(path.to_string(), |n| n.to_string_lossy().into_owned())
}

/// The figure of Figs. 1 and 5: ground truth, each method's image (thumbnails with the inset
/// marked) and its inset, the light-moments biclustering beside the paper rule's.
pub fn low_vs_all_figure(
    out: &Path,
    id: &str,
    title: &str,
    run: &RunOutcome<'_>,
    moments: Option<&RunOutcome<'_>>,
) -> Result<FigureSet> {
    let m = run.facts.metrics;
    let (methods, _) = methods(m, moments.map(|r| r.facts.metrics));
    let mut panels: Vec<(&str, String, String)> = vec![]; // run, figure row name, label
    panels.push((run.name, "reference".into(), "ground truth".into()));
    for x in &methods {
        let Some(c) = x.paper_rule else { continue };
        if registry::role_of(&c.kind) == Role::Raw {
            continue;
        }
        panels.push((run.name, c.name.clone(), format!("{} (paper's rule)", x.name)));
        if let (Some(r), Some(_)) = (moments, x.moments) {
            panels.push((r.name, c.name.clone(), format!("{} (light moments)", x.name)));
        }
    }
    let scale = m.figures.as_ref().and_then(|f| f.reference_error_scale);
    let caption = format!(
        "{title}: the ground truth and each method's image (the inset's region marked), the insets magnified, and each \
         method's |error| against the ground truth on one shared colour bar{}, from `runs/{}`{}.{}",
        scale.map_or(String::new(), |s| format!(" (full scale {s:.3e})")),
        run.name,
        moments.map_or(String::new(), |r| format!(" and `runs/{}`", r.name)),
        m.tone_map.as_ref().map_or(String::new(), |t| format!(
            " Every image is tone mapped at {:+.1} stops{}, which clips {:.1}% of the mesh's pixels.",
            t.exposure,
            if t.auto { " (chosen so that at most 1% of the mesh's pixels clip)" } else { "" },
            100.0 * t.clipped
        ))
    );
    let mut f = FigureSet::new("low-vs-all", id, title, caption, panels.len());
    let runs = [Some(run), moments];
    let record = |name: &str| runs.iter().flatten().find(|r| r.name == name).map(|r| r.facts.metrics);
    for (kind, pick) in [("image", 0), ("inset", 1), ("error", 2)] {
        for (i, (run_name, row, label)) in panels.iter().enumerate() {
            let Some(figs) = record(run_name).and_then(|m| m.figures.as_ref()) else { continue };
            let Some(r) = figs.rows.iter().find(|r| &r.name == row) else { continue };
            let from = match pick {
                0 => Some(&r.thumbnail),
                1 => Some(&r.inset),
                _ => r.error_vs_reference_png.as_ref(),
            };
            let label = match pick {
                2 => format!("{label}: |error|"),
                _ => label.clone(),
            };
            match from {
                Some(from) if pick == 2 => {
                    f.add_error(out, &format!("runs/{run_name}/{from}"), &format!("{kind}-{i}"), label)?
                }
                Some(from) => f.add(out, &format!("runs/{run_name}/{from}"), &format!("{kind}-{i}"), label)?,
                // The ground truth has no error image: its place in the row stays empty.
                None if pick == 2 && i == 0 => f.spacer(),
                None => {}
            }
        }
    }
    reference_bar(&mut f, out, scale)?;
    Ok(f)
}

/// The colour bar, 0 to `scale`, under a figure whose panels include errors against the
/// ground truth (labelled `...: |error|`); none without them.
fn reference_bar(f: &mut FigureSet, out: &Path, scale: Option<f32>) -> Result<()> {
    match scale.filter(|_| f.pictures().any(|p| p.label.ends_with("|error|"))) {
        Some(s) => f.add_colour_bar(out, s, "luminance of |error| against the ground truth (linear radiance)"),
        None => Ok(()),
    }
}

/// Fig. 8: lossless biclustering at each local grid beside the paper's.
pub fn fig8(ctx: &Context<'_>, runs: &[RunOutcome<'_>]) -> PaperTable {
    let names = ["fig8-8", "fig8-16", "fig8-32"];
    let published = &ctx.published.fig8;
    let found: Vec<Option<&RunOutcome<'_>>> = names.iter().map(|n| runs.iter().find(|r| r.name == *n)).collect();
    let grid = |r: &RunOutcome<'_>| (r.facts.metrics.transfer.local_dirs as f64).sqrt().round() as u32;
    let columns = published
        .iter()
        .zip(&found)
        .map(|(p, r)| {
            let ours =
                r.map_or(ours_head(ctx).to_string(), |r| format!("{} ({}x{})", ours_head(ctx), grid(r), grid(r)));
            Column::pair(format!("{0}x{0}", p.local_grid), ours, "paper")
        })
        .collect();
    let base_mb = found[0].and_then(|r| r.facts.value(Figure::ReducedMb).ok());
    let paper_base = published.first().map(|p| p.compressed_mb);
    let figure = |f: Figure, paper: &dyn Fn(&super::published::GridColumn) -> f64| -> Row {
        let missing = Some("its run did not take place");
        let cells = published.iter().zip(&found).map(|(p, r)| cell(*r, f, Some(paper(p)), missing)).collect();
        row(f, cells)
    };
    // A row of a figure the facts do not define: `ours` of each grid's run, the paper's.
    type Ours<'a> = &'a dyn Fn(&RunOutcome<'_>) -> Option<f64>;
    let derived = |key: &str,
                   label: &str,
                   unit: &str,
                   ours: Ours<'_>,
                   paper: &dyn Fn(&super::published::GridColumn) -> Option<f64>| {
        let cells = published
            .iter()
            .zip(&found)
            .map(|(p, r)| Cell {
                ours: r.and_then(ours),
                paper: paper(p),
                source: r.map(|r| format!("runs/{}", r.name)),
                ..Cell::default()
            })
            .collect();
        Row::numeric(key, label, unit, 2, cells)
    };
    let ratio = derived(
        "storage_over_8x8",
        "compressed T over the first grid's",
        "x",
        &|r| r.facts.value(Figure::ReducedMb).ok().zip(base_mb).map(|(a, b)| a / b),
        &|p| paper_base.map(|b| p.compressed_mb / b),
    );
    let gather = derived(
        "transfer_ms",
        "macro-scale transfer per frame (gather)",
        "ms",
        &|r| paper_form(r.facts.metrics).map(|b| b.gather_ms),
        &|p| Some(p.transfer_ms),
    );
    let rows = vec![
        figure(Figure::NnzM, &|_| f64::NAN),
        figure(Figure::ReducedMb, &|p| p.compressed_mb),
        ratio,
        figure(Figure::PrecomputeMin, &|p| p.precompute_min),
        gather,
        figure(Figure::FpsFixedLight, &|p| p.fps_fixed_light),
        figure(Figure::FpsMovingLight, &|p| p.fps_moving_light),
    ];
    // The paper prints no nnz(T) for Fig. 8.
    let rows: Vec<Row> = rows
        .into_iter()
        .map(|mut r| {
            for c in &mut r.cells {
                c.paper = c.paper.filter(|x| x.is_finite());
            }
            r
        })
        .collect();
    let limit = ctx.published.fig8_note.storage_32_over_8_less_than;
    let last = rows[2].cells.last().and_then(|c| c.ours);
    let mut caption = format!(
        "Lossless biclustering of the glossy bumpy bunny (Phong exponent 128, a 16x16-texel BTF patch, as the paper's \
         figure) at three local grids; the BTF's light directions follow the grid. The paper's text: the storage at \
         32x32 is less than {limit} times that at 8x8. "
    );
    caption += &match last {
        Some(x) => format!(
            "Ours: {x:.2} times{}. ",
            if x < limit { ", within the paper's bound" } else { ", above the paper's bound" }
        ),
        None => "Ours: not measured. ".into(),
    };
    caption += &format!(
        "Precomputation, gather and fps as in Table I (CPU gather and shading on this machine, {}; a time taken \
         while the load exceeded the CPUs is marked (busy)).",
        ctx.machine
    );
    if ctx.quick {
        caption += " Made with --quick: the grids are 2x2, 4x4 and 8x8 at small sizes, so the ratios show the pipeline, not the paper's scale.";
    }
    PaperTable { item: "fig8".into(), file: "fig8".into(), title: "Fig. 8".into(), caption, columns, rows }
}

/// Fig. 8's images: the lossless biclustering's render at each grid.
pub fn fig8_figure(out: &Path, runs: &[RunOutcome<'_>]) -> Result<FigureSet> {
    let mut f = FigureSet::new(
        "fig8",
        "fig8",
        "Fig. 8: local grids",
        "The glossy bumpy bunny rendered from lossless biclustering at each local grid (the runs' own images).",
        3,
    );
    for r in runs.iter().filter(|r| r.name.starts_with("fig8-")) {
        let m = r.facts.metrics;
        let Some(b) = paper_form(m) else { continue };
        let g = (m.transfer.local_dirs as f64).sqrt().round() as u32;
        f.add(out, &format!("runs/{}/{}", r.name, b.image.png), r.name, format!("{g}x{g} local directions"))?;
    }
    Ok(f)
}

/// Fig. 6's images: the equal-storage setting of each kind beside the ground truth, thumbnails,
/// insets and errors against the ground truth on one shared scale.
pub fn fig6_figure(out: &Path, run: &RunOutcome<'_>) -> Result<FigureSet> {
    let m = run.facts.metrics;
    let picked: Vec<String> = crate::report::storage_budget(m)
        .map(|(b, _)| equal_storage(&m.compressors, b).iter().map(|r| r.name.clone()).collect())
        .unwrap_or_default();
    let scale = m.figures.as_ref().and_then(|f| f.reference_error_scale);
    let caption = format!(
        "Each kind's setting nearest lossless biclustering's storage, from `runs/{}`: images with the inset's region \
         marked, the insets magnified, and |error| against the ground truth on one shared scale{}.",
        run.name,
        scale.map_or(String::new(), |s| format!(" (full scale {s:.3e})"))
    );
    let mut f = FigureSet::new("equal-quality", "fig6", "Fig. 6: at equal storage", caption, picked.len() + 1);
    let Some(figs) = m.figures.as_ref() else { return Ok(f) };
    let mut names = picked.clone();
    names.push("reference".into());
    for (kind, i) in [("image", 0), ("inset", 1), ("error", 2)] {
        for name in &names {
            let Some(r) = figs.rows.iter().find(|r| &r.name == name) else { continue };
            let from = match i {
                0 => Some(&r.thumbnail),
                1 => Some(&r.inset),
                _ => r.error_vs_reference_png.as_ref(),
            };
            let Some(from) = from else { continue };
            let label = match (name.as_str(), i) {
                ("reference", _) => "ground truth".to_string(),
                (n, 2) => format!("{n}: |error|"),
                (n, _) => n.to_string(),
            };
            let (from, name) = (format!("runs/{}/{from}", run.name), format!("{kind}-{name}"));
            match i {
                2 => f.add_error(out, &from, &name, label)?,
                _ => f.add(out, &from, &name, label)?,
            }
        }
    }
    reference_bar(&mut f, out, scale)?;
    Ok(f)
}

/// Fig. 7: the temple's render from lossless biclustering.
pub fn fig7_figure(out: &Path, run: &RunOutcome<'_>) -> Result<FigureSet> {
    let m = run.facts.metrics;
    let caption = format!(
        "The generated temple ({} vertices, {} synthesized BTFs) rendered from lossless biclustering, from `runs/{}`.",
        number(m.scene.vertices as f64, 0),
        m.scene.btfs.iter().filter(|b| b.primary).count(),
        run.name
    );
    let mut f = FigureSet::new("fig7", "fig7", "Fig. 7: the temple", caption, 2);
    if let Some(b) = paper_form(m) {
        f.add(out, &format!("runs/{}/{}", run.name, b.image.png), "temple", b.name.clone())?;
    }
    Ok(f)
}

/// Fig. 3(b): `biscale viz`'s pictures of the bunny's T, written into `viz/` of the output
/// folder.
pub fn fig3b_figure(out: &Path, files: &[std::path::PathBuf]) -> Result<FigureSet> {
    let mut f = FigureSet::new(
        "fig3b",
        "fig3b",
        "Fig. 3(b): the structure of T",
        "The bunny's T (Table I's run) by `biscale viz`: the non-zeros of eight neighbouring vertices as cube-map \
         panels, the same coloured by bicluster, the biclusters' sizes, and T's values.",
        2,
    );
    for (name, what) in crate::commands::VIZ_FILES {
        if !files.iter().any(|p| p.ends_with(name)) || name.starts_with("heat_") {
            continue;
        }
        f.add(out, &format!("viz/{name}"), name.trim_end_matches(".png"), what)?;
    }
    Ok(f)
}

/// The paper's video as a comparison: Fig. 1's bunny with the light turned about +Y, and with
/// the camera orbited about it, the animated PNG of each setting and the per-frame plot of
/// error and frame time for each path.
pub fn animation_figure(out: &Path, run: &RunOutcome<'_>) -> Result<Option<FigureSet>> {
    let m = run.facts.metrics;
    if m.animations.is_empty() {
        return Ok(None);
    }
    let what = |a: &crate::metrics::AnimationRecord| match a.path.as_str() {
        "light" => format!("the light turned about +Y in {} frames ({:.0} degrees apart)", a.frames, a.step_degrees),
        _ => {
            format!("the camera orbited about its target in {} frames ({:.0} degrees apart)", a.frames, a.step_degrees)
        }
    };
    let worst = |a: &crate::metrics::AnimationRecord| -> String {
        let w: Vec<String> = (a.series.iter().skip(1))
            .map(|s| format!("{} {:.2e}", s.name, s.rel_l2.iter().fold(0f64, |x, &y| x.max(y))))
            .collect();
        w.join(", ")
    };
    let paths: Vec<String> = m.animations.iter().map(|a| format!("{} (worst frame: {})", what(a), worst(a))).collect();
    let caption = format!(
        "The paper's video shows its scenes under a turning light; here Fig. 1's bunny (`runs/{}`) with {}: each \
         setting rendered per frame on the CPU beside the uncompressed T (animated PNGs at {} fps: they play in a \
         browser; the PDF shows frame 0), and each frame's error against the uncompressed frame and its time.",
        run.name,
        paths.join("; then "),
        m.animations[0].fps,
    );
    let per_row = m.animations.iter().map(|a| a.series.len()).max().unwrap_or(1);
    let mut f = FigureSet::new(
        "animation",
        "animation",
        "The light turned and the camera orbited (the paper's video)",
        caption,
        per_row,
    );
    for a in &m.animations {
        for s in &a.series {
            let name = format!("{}-{}", a.path, s.name.replace([':', '/'], "-"));
            f.add(out, &format!("runs/{}/{}", run.name, s.apng), &name, format!("{}: {}", a.path, s.name))?;
        }
        // A shorter row leaves its places empty, so each path starts a row of its own.
        for _ in a.series.len()..per_row {
            f.spacer();
        }
        let label = format!("per-frame error and frame time, {} path", a.path);
        f.add_wide(out, &format!("runs/{}/{}", run.name, a.plot), &format!("per-frame-{}", a.path), label)?;
    }
    Ok(Some(f))
}
