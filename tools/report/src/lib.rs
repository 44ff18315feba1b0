//! # biscale-report: what a run says
//!
//! The records a run ends in and every way they are shown. It never imports the pipeline, so
//! a report can be re-rendered from a `metrics.json` alone (`biscale report`), and its tests
//! link neither the pipeline nor wgpu.
//!
//! | module | what it holds |
//! |---|---|
//! | [`metrics`] | the `metrics.json` schema as records that derive `Serialize` and `Deserialize` (with [`metrics::RunRecord`], a run's provenance, and [`metrics::SCHEMA_VERSION`]), and `metrics.csv` |
//! | [`report`] | the document model ([`report::Block`], [`report::Table`]) of a run's report, its Markdown, and [`report::write_documents`], which writes the plots, `report.md` and `report.html` of a [`metrics::Metrics`] |
//! | [`html`] | the document model as one self-contained HTML page (images embedded) |
//! | [`plots`] | log-log plots of error against storage and time (PNG and an SVG twin) |
//! | [`compare`] | the equal-quality comparison: each kind's storage at a target error |
//! | [`inset`] | the comparison figures' thumbnails and magnified insets |
//! | [`viz`] | matrix-structure pictures: sparsity, biclusters, histograms, per-vertex heat maps |
//!
//! ```no_run
//! let text = std::fs::read_to_string("out/smoke/metrics.json").unwrap();
//! let m: biscale_report::metrics::Metrics = serde_json::from_str(&text).unwrap();
//! let plan = std::fs::read_to_string("out/smoke/plan.txt").unwrap();
//! biscale_report::report::write_documents(&m, &plan, "out/smoke".as_ref()).unwrap();
//! ```

pub mod compare;
pub mod html;
pub mod inset;
pub mod metrics;
pub mod plots;
pub mod report;
pub mod viz;
