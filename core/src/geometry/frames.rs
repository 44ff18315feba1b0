//! Per-vertex orthonormal frames. (Implementation in progress.)

use glam::Vec3;

/// Orthonormal frame: local +X = tangent, +Y = bitangent, +Z = normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexFrame {
    pub tangent: Vec3,
    pub bitangent: Vec3,
    pub normal: Vec3,
}

pub fn vertex_frames(_mesh: &crate::geometry::Mesh) -> Vec<VertexFrame> {
    unimplemented!()
}
