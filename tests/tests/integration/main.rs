//! biscale's cross-crate tests, as one test binary: each test binary that links the pipeline
//! (and so wgpu) costs a link step and tens of megabytes, so the suites are modules of one.
//!
//! * [`end_to_end`]: the bundled smoke config, analytic scenes with closed-form radiance, the
//!   stage cache, and the wgpu backend checked against the CPU.
//! * [`golden`]: the smoke config's renders and figures against blessed PNGs
//!   (`BISCALE_BLESS=1` re-blesses).
//! * [`bad_input`]: every bad input is a typed error naming what and where, with nothing
//!   half-written left behind.
//! * [`fuzz_seeds`]: the fuzzing suite's committed seeds through its targets' bodies.
//! * [`hostile`]: careless and hostile input that used to give wrong results silently (extreme
//!   mesh scales, a camera that sees nothing, foreign cache files).
//! * [`materials`]: BTF materials from the config (synthesis, the cache, several materials).
//! * [`low_frequency`]: the SH method end to end (an analytic scene, records, the GPU).
//! * [`inputs`]: PLY meshes and cube-map skies (cross, six faces) through config, plan and run.
//!
//! Elsewhere: the `biscale` executable's tests are `biscale-cli`'s one test binary
//! (`tools/cli/tests/cli/`: only the package that builds an executable can run it), and
//! `gpu/tests/viewer.rs` opens a window (winit allows one event loop per process).

mod bad_input;
mod end_to_end;
mod fuzz_seeds;
mod golden;
mod hostile;
mod inputs;
mod low_frequency;
mod materials;

/// `config` run into `out` (its stage cache beside it): the record it wrote.
fn run_in(config: &std::path::Path, out: &std::path::Path) -> biscale::metrics::Metrics {
    let exp = biscale::experiment::config::Experiment::load(config).unwrap();
    let opts = biscale::store::RunOptions {
        out_dir: Some(out.to_path_buf()),
        cache_dir: Some(biscale_tests::cache_beside(out)),
        no_cache: false,
    };
    biscale::run::run(&exp, &opts).unwrap().1
}
