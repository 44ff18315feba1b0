//! Where a run writes: the output folder and cache folder a command is given ([`RunOptions`]),
//! the stage cache ([`cache`]), output folders swapped in whole and owned by proof
//! ([`staging`]), and files written into a folder of other files without touching them
//! ([`shared`]).

pub mod cache;
pub mod shared;
pub mod staging;

use std::path::PathBuf;

/// Options of `biscale run`.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Output folder (default `out/<name>/`).
    pub out_dir: Option<PathBuf>,
    /// Cache folder for stage outputs (default [`crate::store::cache::default_dir`]); `None` with
    /// `no_cache` disables caching.
    pub cache_dir: Option<PathBuf>,
    pub no_cache: bool,
}
