//! # biscale (the pipeline)
//!
//! Reads a TOML experiment ([`experiment`]), prints a plan of what will run and what is left
//! out, runs the stages of `biscale-core`, `biscale-compressors` and `biscale-shading`
//! ([`stages`], in the order [`run`] gives them), and writes the output folder: `plan.txt`,
//! `metrics.json` ([`metrics`]), `report.md` ([`report`]) and `images/`. The application layer
//! is three crates, `biscale-cli -> biscale (this one) -> biscale-report`; the report's modules
//! are re-exported here under their own names ([`metrics`], [`report`], [`html`], [`plots`],
//! [`compare`], [`inset`], [`viz`]).
//!
//! | module | what it holds |
//! |---|---|
//! | [`error`] | [`error::PipelineError`], the one error of the crate, naming stage and input |
//! | [`experiment`] | the experiment file (`config`: located errors, sweeps, `--set`) and the method kinds |
//! | [`plan`] | what a run will do and leave out, with its memory estimate (`plan.txt`) |
//! | [`stages`] | scene, transfer, materials, the view, evaluation, figures, the BTF study, the SH method, the GPU backend |
//! | [`run`] | the script of a run and the [`run::RunContext`] that `run`, `eval` and `shard merge` share |
//! | [`store`] | the stage cache, and output folders swapped in whole and owned by proof |
//! | [`estimate`], [`provenance`] | the memory estimate and guard; how a run was made, stage by stage |
//! | [`shard`] | the sharded precompute (`shard plan`, `run`, `status`, `merge`) |
//! | [`scheduler`] | its job files (`shard sbatch`, `k8s`, `batch`: Slurm, Kubernetes, AWS Batch) and the task's index |
//! | [`interop`] | NumPy files in and out (`export`, `eval`), with its `.npy`/`.npz` codec |
//! | [`rerender`] | `biscale report`: a finished run's report from its record alone |
//! | [`reproduce`] | `biscale reproduce`: the paper's Tables I and II and its comparisons beside our runs' figures |
//! | [`commands`], [`temple`], [`chair`] | the smaller commands (`export-matrix`, `diff`, `btf`, `generate`, `viz`, `view`); the generated scenes |
//! | [`util`] | verbosity, notes and progress bars |
//!
//! Imports run one way, each module using only those before it: `experiment` and `store` (and
//! `util`), then `error` (which wraps their errors), `provenance`, `stages`, `estimate` (of the
//! stages' geometry and light), `plan` (with the estimate), then `run`, and on top `shard`,
//! `interop`, `commands`, `rerender` and `reproduce`.
//!
//! ```no_run
//! let exp = biscale::experiment::config::Experiment::load("configs/smoke.toml".as_ref()).unwrap();
//! let (out_dir, metrics) = biscale::run::run(&exp, &Default::default()).unwrap();
//! ```

pub mod chair;
pub mod commands;
pub mod error;
pub mod estimate;
pub mod experiment;
pub mod interop;
pub mod plan;
pub mod provenance;
pub mod reproduce;
pub mod rerender;
pub mod run;
pub mod scheduler;
pub mod shard;
pub mod stages;
pub mod store;
pub mod temple;
pub mod util;

pub use biscale_report::{compare, html, inset, metrics, plots, report, viz};
