//! The experiment: the TOML file read with located errors and `--set` overrides ([`config`]) and
//! the method kinds beside the all-frequency one and their parameters ([`methods`]). What a run
//! will do with it is planned above it, in [`crate::plan`].

pub mod config;
pub mod methods;
