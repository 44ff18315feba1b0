//! Geometry: triangle meshes (OBJ and PLY loading, polygon triangulation and repair),
//! per-vertex frames, and the BVH behind every ray query.

pub mod bvh;
mod bvh4;
pub mod frames;
pub mod mesh;
pub mod placement;
mod ply;
pub mod polygon;
pub mod shapes;
pub mod winding;

pub use bvh::{Hit, SceneBvh};
pub use frames::{vertex_frames, VertexFrame};
pub use mesh::{MaterialIds, Mesh, MeshLoad};
pub use placement::Placement;
