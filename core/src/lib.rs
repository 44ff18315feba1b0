//! # biscale-core
//!
//! The plain data that flows between biscale's stages, the conventions every stage agrees
//! on (docs/DESIGN.md section 3), and the CPU stages that produce the transfer matrix:
//!
//! * [`basis`]: the bases stage outputs carry (the light basis of `L`, the local basis of `L*`).
//! * [`sampling`]: the cubemap layout and its exact texel solid angles, the Shirley-Chiu
//!   hemisphere grids that index local light and view directions, lat-long and cube-map
//!   environment maps and the light vector `L` (power per cubemap texel).
//! * [`geometry`]: triangle meshes (OBJ and PLY loading, repair), per-vertex frames, and the BVH used for
//!   every ray query, with the coverage rasteriser that decides the transfer stage's rays by
//!   default (`geometry/bvh/coverage.rs`).
//! * [`transfer`]: the per-vertex visibility transfer matrix `T` ((n M) x N, CSR).
//! * [`compress`]: the [`compress::Compressor`] interface and the compressed form as plain
//!   arrays (docs/DESIGN.md section 4).
//! * [`gather`]: local incident radiance `L* = T L` and its f64 reference product.
//! * [`scene`]: what every shader takes and returns: the shade scene (mesh, frames,
//!   materials), BTF tables, the camera, the RGB image type and its files.
//! * [`sh`]: real spherical harmonics (evaluation, exact quadrature, rotation) for the
//!   low-frequency method.
//! * [`artifact`]: the one file format of stage outputs (T, compressed forms, BTFs).
//! * [`io`]: the atomic writer and the content hash of cache keys; [`stats`]: the median.
//!
//! Shortest use, from a mesh and an env map to `L*`:
//!
//! ```no_run
//! use biscale_core::{geometry::Mesh, sampling::{EnvMap, LightVector}, transfer};
//! let settings = transfer::TransferSettings::default(); // 6x32x32 cubemap, 8x8 bins
//! let mesh = Mesh::load_obj("assets/meshes/bunny.obj".as_ref()).unwrap().mesh;
//! let (env, _warnings) = EnvMap::load("assets/envmaps/blender_forest.exr".as_ref()).unwrap();
//! let light = LightVector::from_env(&env, settings.cubemap(), 0.0);
//! let t = transfer::build(&mesh, &settings, None).unwrap().matrix;
//! let lstar = biscale_core::gather::reference_product(&t, &light);
//! ```

pub mod artifact;
pub mod basis;
pub mod compress;
pub mod error;
pub mod gather;
pub mod geometry;
pub mod io;
pub mod linalg;
pub mod sampling;
pub mod scene;
pub mod sh;
pub mod stats;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
pub mod transfer;

pub use error::{CoreError, Result};

/// RGB triple in linear radiometric units (f32 storage).
pub type Rgb = [f32; 3];
