//! Sampling stage: the cubemap and hemisphere parameterizations, environment maps and the
//! light vector `L`.

pub mod cubemap;
pub mod envmap;
pub mod hemisphere;

pub use cubemap::Cubemap;
pub use envmap::{EnvMap, LightVector};
pub use hemisphere::HemisphereGrid;
