//! The experiment: the TOML file read with located errors and `--set` overrides ([`config`]),
//! the method kinds beside the all-frequency one and their parameters ([`methods`]), and the
//! plan of what a run will do and leave out ([`plan`]).

pub mod config;
pub mod methods;
pub mod plan;
