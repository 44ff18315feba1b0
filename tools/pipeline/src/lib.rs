//! # biscale (the pipeline)
//!
//! Reads a TOML experiment ([`config`]), prints a plan of what will run and what is left
//! out ([`plan`]), runs the stages of `biscale-core`, `biscale-compressors` and
//! `biscale-shading` ([`pipeline`]), and writes the output folder: `plan.txt`,
//! `metrics.json` ([`metrics`]), `report.md` ([`report`]) and `images/`.
//!
//! ```no_run
//! let exp = biscale::config::Experiment::load("configs/smoke.toml".as_ref()).unwrap();
//! let (out_dir, metrics) = biscale::pipeline::run(&exp, &Default::default()).unwrap();
//! ```

pub mod btf_study;
pub mod cache;
pub mod commands;
pub mod compare;
pub mod config;
#[cfg(feature = "gpu")]
pub mod gpu_backend;
pub mod html;
pub mod inset;
pub mod interop;
pub mod materials;
pub mod memory;
pub mod methods;
pub mod metrics;
pub mod npy;
pub mod pipeline;
pub mod plan;
pub mod plots;
pub mod provenance;
pub mod report;
pub mod rerender;
pub mod shard;
pub mod staging;
pub mod temple;
pub mod util;
pub mod viz;
