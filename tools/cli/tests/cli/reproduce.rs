//! `biscale reproduce --quick`: every item at small sizes into a fresh folder, then checked from
//! the outside: the files exist and parse, every "ours" figure of `numbers.csv` is what its
//! run's `metrics.json` says (re-read here, by this file's own definitions), every published
//! figure the tables quote has its row, and a rerun with the same cache takes `T` from it and
//! keeps the precomputation time the first run measured.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

fn biscale(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale")).args(args).current_dir(root()).output().expect("run biscale");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// One line of `numbers.csv`, by column name.
type Line = BTreeMap<String, String>;

/// RFC 4180 fields (quotes doubled inside quoted fields); no field spans lines here.
fn fields(line: &str) -> Vec<String> {
    let (mut out, mut cur, mut quoted, mut chars) = (vec![], String::new(), false, line.chars().peekable());
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut cur)),
            _ => cur.push(c),
        }
    }
    out.push(cur);
    out
}

fn read_csv(path: &Path) -> Vec<Line> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = fields(lines.next().unwrap());
    assert_eq!(header, ["item", "row", "column", "ours", "paper", "ratio", "unit", "source", "note"]);
    lines
        .map(|l| {
            let f = fields(l);
            assert_eq!(f.len(), header.len(), "{l}");
            header.iter().cloned().zip(f).collect()
        })
        .collect()
}

fn num(s: &str) -> Option<f64> {
    (!s.is_empty()).then(|| s.parse::<f64>().unwrap_or_else(|e| panic!("{s}: {e}")))
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-300)
}

fn f(v: &Value, path: &str) -> f64 {
    path.split('.').fold(v, |v, k| &v[k]).as_f64().unwrap_or_else(|| panic!("{path} in a metrics.json"))
}

/// A `[runtime]` integer of the config a run ran, read off its text.
fn runtime_value(m: &Value, key: &str) -> f64 {
    let text = m["run"]["config_text"].as_str().unwrap();
    let mut in_runtime = false;
    for line in text.lines() {
        let l = line.trim();
        if l.starts_with('[') {
            in_runtime = l == "[runtime]";
        } else if in_runtime && l.starts_with(key) {
            let value = l.split('=').nth(1).unwrap().split('#').next().unwrap().trim();
            return value.parse().unwrap();
        }
    }
    panic!("no runtime.{key} in the run's config")
}

/// This file's own definition of each Table I / II figure, from a run's `metrics.json`.
fn expected(m: &Value, row: &str) -> f64 {
    let b = m["compressors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["kind"] == "bicluster" && c["lossless"] == true)
        .expect("a lossless bicluster record");
    let vertices = f(m, "scene.vertices");
    match row {
        "width" => runtime_value(m, "width"),
        "height" => runtime_value(m, "height"),
        "vertices" => vertices,
        "btfs" => m["scene"]["btfs"].as_array().unwrap().iter().filter(|b| b["primary"] == true).count() as f64,
        "btf_size" => f(m, "scene.btf_bytes") / 1e6,
        "nnz" => f(m, "transfer.nnz") / 1e6,
        "nnz_per_vertex" => f(m, "transfer.nnz") / vertices,
        "mflops" => 2.0 * f(b, "stats.nnz") / 1e6,
        "reduced_mflops" => f(b, "stats.mflops_biclustered"),
        "computation" => 100.0 * f(b, "stats.mflops_biclustered") / (2.0 * f(b, "stats.nnz") / 1e6),
        "data_size" => f(m, "transfer.rows") * f(m, "transfer.cols") / 1e6,
        "reduced_size" => f(b, "bytes") / 1e6,
        "data_size_pct" => 100.0 * f(b, "bytes") / (f(m, "transfer.rows") * f(m, "transfer.cols")),
        "precompute" => {
            assert_eq!(m["transfer"]["cached"], false, "a fresh cache traces T");
            (f(m, "transfer.build_seconds") + f(b, "build_seconds")) / 60.0
        }
        "fps_fixed_light" => 1000.0 / f(b, "shade_ms"),
        "fps_moving_light" => 1000.0 / (f(b, "gather_ms") + f(b, "shade_ms")),
        // The frame-time model's floors on the projected GPU, recomputed from the stages'
        // counts and the GPU's published figures: max(bytes / bandwidth, flops / peak).
        "projected_fps_fixed_light" | "projected_fps_moving_light" => {
            let model = &m["frame_model"];
            let gpu = &model["projection"];
            let floor_s = |s: &Value| {
                (f(s, "bytes") / (f(gpu, "bandwidth_gb_s") * 1e9)).max(f(s, "flops") / (f(gpu, "peak_gflop_s") * 1e9))
            };
            let form = model["forms"].as_array().unwrap().iter().find(|x| x["name"] == b["name"]).unwrap();
            let shade = floor_s(&form["shade"]);
            match row {
                "projected_fps_fixed_light" => 1.0 / shade,
                _ => 1.0 / (floor_s(&form["gather"]) + shade),
            }
        }
        other => panic!("a row this test has no definition of: {other}"),
    }
}

/// The record a low- vs all-frequency column names, in a run's `metrics.json`.
fn low_vs_all_record<'a>(column: &str, m: &'a Value) -> &'a Value {
    let compressors = m["compressors"].as_array().unwrap();
    if column == "all-frequency, raw T" {
        return compressors.iter().find(|c| c["kind"] == "sparse").unwrap();
    }
    if let Some(name) = column.strip_prefix("all-frequency, ") {
        return compressors.iter().find(|c| c["name"] == name).unwrap_or_else(|| panic!("{column}"));
    }
    let order: f64 = column.strip_prefix("SH order ").unwrap().split(' ').next().unwrap().parse().unwrap();
    m["methods"].as_array().unwrap().iter().find(|r| f(r, "sh.order") == order).unwrap_or_else(|| panic!("{column}"))
}

/// Figs. 1 and 5's rows against the runs' records; `paper_run` is the paper-rule run whose
/// `-moments` twin holds the light-moments errors.
fn check_low_vs_all(line: &Line, metrics: &BTreeMap<String, Value>) {
    let ours = num(&line["ours"]).unwrap();
    let m = &metrics[&line["source"]];
    let c = low_vs_all_record(&line["column"], m);
    let want = match line["row"].as_str() {
        "transfer_mb" => f(c, "bytes") / 1e6,
        "error_paper_rule" | "error_light_moments" => f(c, "image.vs_reference.rel_l2"),
        "gather_ms" => f(c, "gather_ms"),
        "shade_ms" => f(c, "shade_ms"),
        other => panic!("a low- vs all-frequency row this test does not know: {other}"),
    };
    assert!(close(ours, want), "{line:?}: {want}");
    let moments = line["source"].ends_with("-moments");
    assert_eq!(moments, line["row"] == "error_light_moments", "{line:?}");
    assert_eq!(m["uncompressed"]["light_moments"], moments, "{line:?}");
    // The equal-storage order: the SH setting nearest the lossless biclustering in log storage.
    if let Some(rest) = line["column"].strip_suffix(" (equal storage)") {
        let b = m["compressors"].as_array().unwrap().iter().find(|c| c["kind"] == "bicluster" && c["lossless"] == true);
        let target = f(b.unwrap(), "bytes");
        let dist = |r: &Value| (f(r, "bytes") / target).ln().abs();
        let best = m["methods"].as_array().unwrap().iter().min_by(|a, b| dist(a).total_cmp(&dist(b))).unwrap();
        assert_eq!(rest, format!("SH order {}", f(best, "sh.order")), "{line:?}");
    }
}

/// Fig. 8's rows against the runs' records (the ratio row against the 8x8 run's).
fn check_fig8(line: &Line, metrics: &BTreeMap<String, Value>) {
    let ours = num(&line["ours"]).unwrap();
    let m = &metrics[&line["source"]];
    let b = |m: &Value| -> Value {
        m["compressors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["kind"] == "bicluster" && c["lossless"] == true)
            .unwrap()
            .clone()
    };
    let want = match line["row"].as_str() {
        "storage_over_8x8" => f(&b(m), "bytes") / f(&b(&metrics["runs/fig8-8"]), "bytes"),
        "transfer_ms" => f(&b(m), "gather_ms"),
        row => expected(m, row),
    };
    assert!(close(ours, want), "{line:?}: {want}");
}

/// The equal-storage and equal-quality rows against the comparison run's records.
fn check_comparison(line: &Line, m: &Value) {
    let records = m["compressors"].as_array().unwrap();
    let of_kind: Vec<&Value> = records.iter().filter(|r| r["kind"] == line["column"].as_str()).collect();
    assert!(!of_kind.is_empty(), "{line:?}");
    let ours = num(&line["ours"]).unwrap_or_else(|| panic!("{line:?}"));
    let named = |l: &Line| {
        let name = l["note"].strip_prefix("ours: ").unwrap_or_else(|| panic!("{l:?}"));
        *of_kind.iter().find(|r| r["name"] == name).unwrap_or_else(|| panic!("{name}"))
    };
    match line["row"].as_str() {
        "equal_storage_mb" => assert!(close(ours, f(named(line), "bytes") / 1e6), "{line:?}"),
        "equal_storage_ratio" | "equal_storage_error_pct" | "equal_storage_build_s" => {}
        row if row.starts_with("equal_quality_mb_") => {
            let bytes: Vec<f64> = of_kind.iter().map(|r| f(r, "bytes") / 1e6).collect();
            let (lo, hi) = bytes.iter().fold((f64::MAX, 0f64), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(ours >= lo * (1.0 - 1e-12) && ours <= hi * (1.0 + 1e-12), "{line:?}: outside {lo}..{hi}");
        }
        other => panic!("a comparison row this test does not know: {other}"),
    }
}

#[test]
fn reproduce_quick_sets_each_runs_figures_beside_the_papers_and_a_rerun_reuses_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("paper"), dir.path().join("cache"));
    let (out_s, cache_s) = (out.to_str().unwrap(), cache.to_str().unwrap());
    let (ok, stdout, err) = biscale(&["reproduce", "--quick", "--out", out_s, "--cache-dir", cache_s]);
    assert!(ok, "{err}");
    assert!(err.contains("reproduce: run 1/14 `bunny`"), "a progress line per run: {err}");
    assert!(stdout.contains("numbers.csv") && stdout.contains("index.html"), "{stdout}");

    // Every file, and each table in LaTeX with booktabs and a caption, all of them in paper.tex.
    let paper = std::fs::read_to_string(out.join("paper.tex")).unwrap();
    assert!(paper.contains("\\documentclass{article}") && paper.trim_end().ends_with("\\end{document}"));
    for t in ["table1", "table2", "equal_quality", "fig1_low_vs_all", "fig5_low_vs_all", "fig8"] {
        assert!(paper.contains(&format!("\\input{{tables/{t}}}")), "paper.tex inputs {t}");
        let tex = std::fs::read_to_string(out.join("tables").join(format!("{t}.tex"))).unwrap();
        for must in ["\\begin{tabular}", "\\toprule", "\\midrule", "\\bottomrule", "\\caption{", "\\end{table*}"] {
            assert!(tex.contains(must), "{t}.tex lacks {must}");
        }
        assert_eq!(tex.matches('{').count(), tex.matches('}').count(), "{t}.tex: unbalanced braces");
        assert!(tex.contains("quick"), "{t}.tex says it is a quick run");
    }
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert!(!html.contains("<script") && !html.contains("<link"), "self-contained");
    for must in ["Table I", "Table II", "equal-quality", "<caption>", "Not reproduced yet", "Machine:"] {
        assert!(html.contains(must), "index.html lacks {must}");
    }
    // Every figure: its LaTeX and its panels, each a PNG the page embeds.
    for (id, at_least) in
        [("fig1", 6), ("fig5", 6), ("fig6", 4), ("fig8", 3), ("fig3b", 4), ("fig7", 1), ("animation", 8)]
    {
        let tex = std::fs::read_to_string(out.join("figures").join(format!("{id}.tex"))).unwrap();
        let panels: Vec<&str> =
            tex.lines().filter_map(|l| l.split("\\includegraphics[width=\\linewidth]{").nth(1)).collect();
        assert!(panels.len() >= at_least, "{id}: {} panels", panels.len());
        for p in panels {
            let file = p.split('}').next().unwrap();
            let bytes = std::fs::read(out.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
            assert!(bytes.starts_with(b"\x89PNG"), "{file}");
        }
        assert!(html.contains(&format!("<h2 id=\"{id}\">")), "{id} on the page");
    }
    assert!(html.matches("data:image/png;base64,").count() >= 24, "the panels are embedded");
    // Both paths of the paper's video, each with its plot.
    for path in ["light", "camera"] {
        assert!(out.join(format!("figures/animation/per-frame-{path}.png")).is_file(), "{path}");
    }
    // A figure of errors on one scale has one colour bar, across it; its error panels are the
    // runs' pictures without theirs. (Fig. 6's quick run traces no ground truth: no errors.)
    for id in ["fig1", "fig5", "fig6"] {
        let tex = std::fs::read_to_string(out.join("figures").join(format!("{id}.tex"))).unwrap();
        let error_panel = tex
            .lines()
            .filter_map(|l| l.split("\\includegraphics[width=\\linewidth]{").nth(1))
            .map(|p| p.split('}').next().unwrap())
            .find(|p| p.contains("/error-"));
        let bar = out.join(format!("figures/{id}/colour-bar.png"));
        assert_eq!(bar.is_file(), error_panel.is_some(), "{id}: a bar when there are errors");
        let Some(error_panel) = error_panel else {
            assert_eq!(id, "fig6", "{tex}");
            continue;
        };
        assert_eq!(image::open(&bar).unwrap().width(), 1200, "{id}");
        // The picture under the bar is the render's thumbnail's size: the panel beside it.
        let panel = image::open(out.join(error_panel)).unwrap();
        let image = image::open(out.join(error_panel.replace("/error-", "/image-"))).unwrap();
        assert_eq!((panel.width(), panel.height()), (image.width(), image.height()), "{error_panel}");
    }
    let provenance: Value = serde_json::from_slice(&std::fs::read(out.join("reproduce.json")).unwrap()).unwrap();
    assert_eq!(provenance["quick"], true);
    assert!(provenance["run"]["started_at"].is_string() && provenance["run"]["host"].is_string());
    let mut metrics = BTreeMap::new();
    for run in [
        "bunny",
        "bunny-l1",
        "bunny-l2",
        "armor",
        "chair",
        "temple",
        "equal-quality",
        "fig1-bunny",
        "fig1-bunny-moments",
        "fig5-glossy",
        "fig5-glossy-moments",
        "fig8-8",
        "fig8-16",
        "fig8-32",
    ] {
        let path = out.join("runs").join(run).join("metrics.json");
        let m: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert!(out.join("runs").join(run).join("report.html").is_file());
        metrics.insert(format!("runs/{run}"), m);
    }
    // Every run's images are tone mapped at an exposure chosen from its render ("auto" in the
    // paper's configs), clipping at most 1% of the mesh; a moments twin takes its partner's.
    for (run, m) in &metrics {
        let tone = &m["tone_map"];
        match run.ends_with("-moments") {
            false => assert!(tone["auto"] == true && tone["clipped"].as_f64().unwrap() <= 0.01, "{run}: {tone}"),
            true => {
                let partner = &metrics[run.trim_end_matches("-moments")]["tone_map"];
                assert_eq!((tone["auto"].as_bool(), &tone["exposure"]), (Some(false), &partner["exposure"]), "{run}");
            }
        }
    }
    // The bunny grows by subdivision, about 4x a level.
    let v = |r: &str| f(&metrics[r], "scene.vertices");
    assert!(v("runs/bunny-l1") > 3.5 * v("runs/bunny") && v("runs/bunny-l2") > 3.5 * v("runs/bunny-l1"));

    // Every "ours" figure is its run's, by this file's definitions; every ratio is ours / paper.
    let lines = read_csv(&out.join("numbers.csv"));
    let mut checked = 0;
    for l in &lines {
        if let (Some(o), Some(p)) = (num(&l["ours"]), num(&l["paper"])) {
            assert!(close(num(&l["ratio"]).unwrap(), o / p), "{l:?}");
        } else {
            assert!(l["ratio"].is_empty(), "{l:?}");
        }
        let Some(ours) = num(&l["ours"]) else {
            assert!(!l["note"].is_empty(), "a figure left out says why: {l:?}");
            continue;
        };
        let m = &metrics[&l["source"]];
        match l["item"].as_str() {
            "table1" | "table2" => assert!(close(ours, expected(m, &l["row"])), "{l:?}: {}", expected(m, &l["row"])),
            "equal-quality" => check_comparison(l, m),
            "low-vs-all" => check_low_vs_all(l, &metrics),
            "fig8" => check_fig8(l, &metrics),
            other => panic!("an item this test does not know: {other}"),
        }
        checked += 1;
    }
    assert!(checked > 150, "{checked} figures checked");
    // Figs. 1 and 5 name the paper's order, the equal-storage one and the highest; Fig. 8's
    // grids grow.
    for scene in ["fig1-bunny", "fig5-glossy"] {
        let columns: Vec<&str> = lines
            .iter()
            .filter(|l| {
                l["item"] == "low-vs-all" && l["row"] == "transfer_mb" && l["source"] == format!("runs/{scene}")
            })
            .map(|l| l["column"].as_str())
            .collect();
        assert_eq!(columns.len(), 5, "{scene}: {columns:?}");
        assert!(
            columns.contains(&"SH order 5 (the paper's)") && columns.contains(&"SH order 8 (highest run)"),
            "{columns:?}"
        );
    }
    // A light-moments twin magnifies the same pixels as its paper-rule run, and draws its
    // errors against the ground truth on the same colour bar.
    for scene in ["fig1-bunny", "fig5-glossy"] {
        for key in ["inset", "reference_error_scale"] {
            let v = |r: &str| metrics[r]["figures"][key].clone();
            assert!(!v(&format!("runs/{scene}")).is_null(), "{scene} {key}");
            assert_eq!(v(&format!("runs/{scene}")), v(&format!("runs/{scene}-moments")), "{scene} {key}");
        }
    }
    let grid = |r: &str| f(&metrics[r], "transfer.local_dirs");
    assert!(grid("runs/fig8-8") < grid("runs/fig8-16") && grid("runs/fig8-16") < grid("runs/fig8-32"));

    // Every published figure the tables quote has its row, with the paper's value.
    let published = biscale::reproduce::published::Published::get();
    let paper = |item: &str, row: &str, column: &str| -> Option<f64> {
        let l = lines.iter().find(|l| l["item"] == item && l["row"] == row && l["column"] == column);
        num(&l.unwrap_or_else(|| panic!("no row {item} {row} {column}"))["paper"])
    };
    for s in &published.table1 {
        let quoted = [
            ("vertices", s.figures.vertices as f64),
            ("btfs", s.btfs as f64),
            ("btf_size", s.btf_mb),
            ("nnz", s.figures.nnz_m),
            ("mflops", s.figures.mflops),
            ("reduced_mflops", s.figures.reduced_mflops),
            ("computation", s.figures.computation_pct),
            ("data_size", s.figures.data_mb),
            ("reduced_size", s.figures.reduced_mb),
            ("data_size_pct", s.figures.data_pct),
            ("precompute", s.figures.precompute_min),
            ("fps_fixed_light", s.figures.fps_fixed_light),
            ("fps_moving_light", s.figures.fps_moving_light),
            ("width", s.width as f64),
            ("height", s.height as f64),
        ];
        for (row, value) in quoted {
            assert_eq!(paper("table1", row, &s.scene), Some(value), "{} {row}", s.scene);
        }
    }
    for c in &published.table2 {
        let column = format!("bunny {}", c.vertices);
        let quoted = [
            ("vertices", c.vertices as f64),
            ("nnz", c.nnz_m),
            ("mflops", c.mflops),
            ("reduced_mflops", c.reduced_mflops),
            ("computation", c.computation_pct),
            ("data_size", c.data_mb),
            ("reduced_size", c.reduced_mb),
            ("data_size_pct", c.data_pct),
            ("precompute", c.precompute_min),
            ("fps_fixed_light", c.fps_fixed_light),
            ("fps_moving_light", c.fps_moving_light),
        ];
        for (row, value) in quoted {
            assert_eq!(paper("table2", row, &column), Some(value), "{column} {row}");
        }
    }
    for (kind, mb) in &published.fig6.storage_mb {
        assert_eq!(paper("equal-quality", "equal_storage_mb", kind), Some(*mb), "{kind}");
    }
    for c in &published.fig8 {
        let column = format!("{0}x{0}", c.local_grid);
        let quoted = [
            ("reduced_size", c.compressed_mb),
            ("precompute", c.precompute_min),
            ("transfer_ms", c.transfer_ms),
            ("fps_fixed_light", c.fps_fixed_light),
            ("fps_moving_light", c.fps_moving_light),
            ("storage_over_8x8", c.compressed_mb / published.fig8[0].compressed_mb),
        ];
        for (row, value) in quoted {
            assert_eq!(paper("fig8", row, &column), Some(value), "{column} {row}");
        }
    }
    // Every scene of Table I has its stand-in's figures: the three BTFs of the chair, the
    // teapot at the Armor's local grid (4x4 at --quick).
    for (scene, run) in [("Bunny", "bunny"), ("Armor", "armor"), ("Chair", "chair"), ("Temple", "temple")] {
        let l = lines.iter().find(|l| l["row"] == "nnz" && l["column"] == scene).unwrap();
        assert!(num(&l["ours"]).is_some_and(|x| x > 0.0) && l["source"] == format!("runs/{run}"), "{l:?}");
    }
    let primary =
        |run: &str| metrics[run]["scene"]["btfs"].as_array().unwrap().iter().filter(|b| b["primary"] == true).count();
    assert_eq!((primary("runs/chair"), primary("runs/armor")), (3, 1));

    // A rerun with the same cache: T from the cache, and the precomputation is the first run's.
    let (ok, _, err) = biscale(&["-q", "reproduce", "--quick", "--out", out_s, "--cache-dir", cache_s]);
    assert!(ok, "{err}");
    let again = read_csv(&out.join("numbers.csv"));
    let m: Value = serde_json::from_slice(&std::fs::read(out.join("runs/bunny/metrics.json")).unwrap()).unwrap();
    assert_eq!(m["transfer"]["cached"], true);
    let precompute = |ls: &[Line]| -> Vec<String> {
        ls.iter().filter(|l| l["row"] == "precompute" && !l["source"].is_empty()).map(|l| l["ours"].clone()).collect()
    };
    assert_eq!(precompute(&again), precompute(&lines));
    assert!(again.iter().any(|l| l["row"] == "precompute" && l["note"].contains("earlier reproduce")));
}

#[test]
fn reproduce_names_the_items_when_only_names_another() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("paper");
    let (ok, _, err) = biscale(&["reproduce", "--quick", "--only", "table3", "--out", out.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("--only") && err.contains("table1, table2, equal-quality"), "{err}");
    assert!(!out.exists(), "nothing is written");
}
