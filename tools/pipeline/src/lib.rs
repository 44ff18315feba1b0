//! # biscale (the pipeline)
//!
//! Reads a TOML experiment ([`config`]), prints a plan of what will run and what is left
//! out ([`plan`]), runs the stages of `biscale-core`, `biscale-compressors` and
//! `biscale-shading` ([`pipeline`]), and writes the output folder: `plan.txt`,
//! `metrics.json` ([`metrics`]), `report.md` ([`report`]) and `images/`. The application layer
//! is three crates, `biscale-cli -> biscale (this one) -> biscale-report`; the report's modules
//! are re-exported here under their own names ([`metrics`], [`report`], [`html`], [`plots`],
//! [`compare`], [`inset`], [`viz`]).
//!
//! | module | what it holds |
//! |---|---|
//! | [`config`] | the experiment file: parsing with located errors, sweeps, method settings |
//! | [`plan`] | what a run will do and leave out, with cache state and the memory estimate |
//! | [`pipeline`] | the script of a run: its stages as functions from plain records to plain records, [`pipeline::PipelineError`] |
//! | [`materials`], [`btf_study`] | the scene's BTFs (analytic, synthesized, measured, local PCA) and their study |
//! | [`methods`] | the low-frequency (SH) method beside the all-frequency one |
//! | [`cache`], [`staging`] | the stage cache, and output folders swapped in whole and owned by proof |
//! | [`memory`], [`provenance`] | the memory estimate and guard; how a run was made, stage by stage |
//! | [`shard`] | the sharded precompute (`shard plan`, `run`, `merge`, `sbatch`) |
//! | [`interop`], [`npy`] | NumPy files in and out (`export`, `eval`) |
//! | [`rerender`] | `biscale report`: a finished run's report from its record alone |
//! | [`commands`], [`temple`] | the smaller commands (`export-matrix`, `diff`, `btf`, `generate`, `viz`, `view`) |
//! | [`util`] | verbosity, notes and progress bars |
//!
//! ```no_run
//! let exp = biscale::config::Experiment::load("configs/smoke.toml".as_ref()).unwrap();
//! let (out_dir, metrics) = biscale::pipeline::run(&exp, &Default::default()).unwrap();
//! ```

pub mod btf_study;
pub mod cache;
pub mod commands;
pub mod config;
#[cfg(feature = "gpu")]
pub mod gpu_backend;
pub mod interop;
pub mod materials;
pub mod memory;
pub mod methods;
pub mod npy;
pub mod pipeline;
pub mod plan;
pub mod provenance;
pub mod rerender;
pub mod shard;
pub mod staging;
pub mod temple;
pub mod util;

pub use biscale_report::{compare, html, inset, metrics, plots, report, viz};
