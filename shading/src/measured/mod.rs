//! Measured BTFs: importers that turn a directory of photographs of a material sample into a
//! [`Btf`](biscale_core::scene::Btf) table on biscale's own light bins and view grid.
//!
//! * [`bonn`]: the Bonn BTF Database layout (UBO2003: one folder per view direction, one
//!   rectified image per light direction), resampled by inverse-distance weighting over the
//!   measured directions ([`load_bonn`]).
//!
//! Shortest use:
//!
//! ```no_run
//! use biscale_core::basis::LocalBasis;
//! use biscale_shading::measured::{load_bonn, BonnImport};
//! let opts = BonnImport {
//!     local_basis: LocalBasis::bins(8).unwrap(),
//!     view_grid: 6,
//!     resolution: 64,
//!     scale: 1.0,
//!     name: "wool".into(),
//! };
//! let (btf, report) = load_bonn("UBO2003/wool".as_ref(), &opts).unwrap();
//! println!("{} views x {} lights, {:.1} deg from the grid", report.views, report.lights,
//!     report.max_interpolation_angle_deg);
//! # let _ = btf;
//! ```

pub mod bonn;

pub use bonn::{load_bonn, BonnImport, BonnReport};
