//! Sampling stage: the cubemap and hemisphere parameterizations, environment maps (lat-long
//! and cube maps) and the light vector `L`.

pub mod cube_env;
pub mod cubemap;
pub mod envmap;
pub mod hemisphere;

pub use cubemap::Cubemap;
pub use envmap::{EnvLayout, EnvMap, LightVector, TexelDirections};
pub use hemisphere::HemisphereGrid;
