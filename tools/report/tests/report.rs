//! The report crate on its own (no pipeline, no wgpu): a finished run's record read back from
//! `metrics.json` (the smoke config's, kept in `tests/data/`), and a compressor kind the
//! report has never heard of contributing its statistics rows through the registry's `Kind`.

use biscale_compressors::registry::{self, FormMemory, Kind, MemoryFacts};
use biscale_report::metrics::{LoadRecord, Metrics, Timing};
use biscale_report::report::timing_warning;
use serde_json::{json, Value};

fn smoke() -> Metrics {
    let text = include_str!("data/smoke-metrics.json");
    serde_json::from_str(text).expect("the smoke run's metrics.json reads back")
}

/// A toy compressor kind, declared as a compressor folder declares its `KIND`.
const TOY: Kind = Kind {
    name: "toy",
    about: "a kind only this test knows",
    label: |_| Ok("toy".into()),
    check: |_| Ok(()),
    build: |_| Err("a toy builds nothing".to_string().into()),
    fits: |_, _| Err("never fits".into()),
    memory: |_, t: &MemoryFacts| FormMemory { working: t.nnz, form: 1 },
    report: |stats: &Value| vec![("toy figure".into(), stats["answer"].to_string())],
    role: registry::Role::Other,
    flops: |_| None,
};

#[test]
fn a_kind_says_which_rows_its_statistics_add_to_the_report() {
    let mut m = smoke();
    // The smoke run's bicluster setting reports through its own kind's rows.
    let table = biscale_report::report::statistics_table(&m).expect("bicluster reports its statistics");
    let rows: Vec<Vec<String>> = table.rows.iter().map(|r| r.iter().map(|c| c.plain()).collect()).collect();
    assert!(rows.iter().any(|r| r[0] == "bicluster" && r[1] == "biclusters"), "{rows:?}");
    assert!(rows.iter().any(|r| r[1].contains("Frobenius") && r[2] == "0.000e0"), "lossless: {rows:?}");

    // A toy kind's rows reach the table through its `Kind::report` alone.
    m.compressors.truncate(1);
    m.compressors[0].kind = "toy".into();
    m.compressors[0].name = "toy-1".into();
    m.compressors[0].stats = Some(json!({ "answer": 42 }));
    let find = |name: &str| if name == "toy" { Some(&TOY) } else { registry::find(name) };
    let t = biscale_report::report::statistics_table_with(&m, find).expect("the toy reports");
    let rows: Vec<Vec<String>> = t.rows.iter().map(|r| r.iter().map(|c| c.plain()).collect()).collect();
    assert_eq!(rows, [["toy-1", "toy figure", "42"]]);
    // A kind the lookup does not know adds nothing.
    assert!(biscale_report::report::statistics_table(&m).is_none());
}

#[test]
fn a_finished_runs_documents_render_from_its_record_alone() {
    let m = smoke();
    let plan = include_str!("data/smoke-plan.txt");
    let dir = tempfile::tempdir().unwrap();
    biscale_report::report::write_documents(&m, plan, dir.path()).unwrap();
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("haar-t4") && md.contains("What each compressor reports of its form"), "{md}");
    assert!(dir.path().join("error_vs_storage.png").is_file() && dir.path().join("report.html").is_file());
}

/// The smoke record with every step timed quietly over 5 repeats, and a quiet machine.
fn quiet() -> Metrics {
    let mut m = smoke();
    let quiet = || Some(Timing::from_samples(&[1.0, 1.01, 1.02, 1.03, 1.5]));
    (m.uncompressed.gather_timing, m.uncompressed.shade_timing) = (quiet(), quiet());
    for c in &mut m.compressors {
        (c.gather_timing, c.shade_timing) = (quiet(), quiet());
    }
    m.load = Some(LoadRecord { load_before: Some(0.4), load_after: Some(1.1), cpus_online: 2 });
    m
}

fn documents(m: &Metrics) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    biscale_report::report::write_documents(m, include_str!("data/smoke-plan.txt"), dir.path()).unwrap();
    let read = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap();
    (read("report.md"), read("report.html"))
}

#[test]
fn an_older_record_without_timings_or_load_reads_back_and_reports_medians_alone() {
    // The fixture predates the timing record: its medians stay, the details are absent.
    let m = smoke();
    assert!(m.load.is_none() && m.uncompressed.gather_timing.is_none());
    assert!(m.compressors.iter().all(|c| c.gather_timing.is_none() && c.shade_timing.is_none()));
    assert!(timing_warning(&m).is_none());
    let table = biscale_report::report::compressor_table(&m);
    assert!(table.header.iter().any(|h| h == "gather ms"), "{:?}", table.header);
    let (md, html) = documents(&m);
    assert!(!md.contains("Warning") && !html.contains("Warning"));
}

#[test]
fn a_noisy_timing_is_named_in_one_warning_line_of_both_reports() {
    let mut m = quiet();
    // The compressor table prints `median (min-max)`.
    let table = biscale_report::report::compressor_table(&m);
    let gather = table.header.iter().position(|h| h == "gather ms, median (min-max)").expect("a ranged column");
    assert_eq!(table.rows[0][gather].plain(), "1.02 (1.00-1.50)");
    // Quiet repeats on a quiet machine: no warning anywhere.
    assert!(timing_warning(&m).is_none());
    let (md, html) = documents(&m);
    assert!(!md.contains("Warning") && !html.contains("Warning"), "{md}");
    assert!(md.contains("gather 1.02 (1.00-1.50) ms (f64 reference)"), "{md}");

    // One gather whose repeats disagree as a body.
    m.compressors[1].gather_timing = Some(Timing::from_samples(&[6.4, 6.5, 6.6, 30.0, 36.0]));
    let w = timing_warning(&m).expect("a noisy gather is warned of");
    assert!(
        w.starts_with("timings are noisy")
            && w.contains("gather of `bicluster` ranged 6.40-36.0 ms over 5 repeats (median 6.60, spread 3.56)")
            && w.contains("(load 1.1 on 2 CPUs)")
            && w.ends_with("treat speed ratios with care"),
        "{w}"
    );
    assert!(!w.contains('\n'));
    let (md, html) = documents(&m);
    let lines: Vec<&str> = md.lines().filter(|l| l.starts_with("Warning: ")).collect();
    assert_eq!(lines, [format!("Warning: {w}.")], "{md}");
    assert!(html.contains("<p>Warning: timings are noisy") && html.contains("gather of <code>bicluster</code> ranged"));
}

#[test]
fn a_load_above_the_cpus_is_warned_of_even_when_the_repeats_agree() {
    let mut m = quiet();
    m.load = Some(LoadRecord { load_before: Some(1.2), load_after: Some(3.1), cpus_online: 2 });
    let w = timing_warning(&m).expect("an overloaded machine is warned of");
    assert_eq!(
        w,
        "the machine was busy while the run timed its steps (load 3.1 on 2 CPUs); treat speed ratios with care"
    );
    // Both conditions: the noisy steps, then the load.
    m.uncompressed.shade_timing = Some(Timing::from_samples(&[5.5, 9.0, 13.8, 16.0, 16.8]));
    let w = timing_warning(&m).unwrap();
    assert!(
        w.contains("shade of uncompressed `T` ranged 5.50-16.8 ms")
            && w.contains("; the machine was busy (load 3.1 on 2 CPUs)"),
        "{w}"
    );
}
