//! The `biscale` executable as a user meets it, one test binary with a module per concern:
//!
//! * [`animation`]: `[runtime.animation]`'s frames against the run's own still images;
//! * [`args`]: every argument has help and every command an example;
//! * [`commands`]: help text, plan, export, diff, viz, report, errors that name the file;
//! * [`interop`]: `export` and `eval` with NumPy files, and the Python round trip;
//! * [`memory`]: the memory estimate and the refusals made before anything is allocated;
//! * [`reproduce`]: `reproduce --quick`, its tables checked against the runs' own records;
//! * [`shard`]: the sharded precompute (`shard plan`, `run`, `status`, `merge`, `sbatch`);
//! * [`staging`]: output folders that a `kill -9` at any stage leaves whole, and never take
//!   what is not theirs.

mod animation;
mod args;
mod commands;
mod interop;
mod memory;
mod reference_cache;
mod reproduce;
mod shard;
mod staging;
