//! The report crate on its own (no pipeline, no wgpu): a finished run's record read back from
//! `metrics.json` (the smoke config's, kept in `tests/data/`), and a compressor kind the
//! report has never heard of contributing its statistics rows through the registry's `Kind`.

use biscale_compressors::registry::{self, FormMemory, Kind, MemoryFacts};
use biscale_report::metrics::Metrics;
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
