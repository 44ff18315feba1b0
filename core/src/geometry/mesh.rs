//! Triangle meshes: OBJ loading, validation and repair.
//! (Implementation in progress: see the transfer helper's task.)

use crate::error::Result;
use glam::{Vec2, Vec3};
use std::path::Path;

/// An indexed triangle mesh, +Y up, counter-clockwise triangles facing outward.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex texture coordinates, when the mesh has them (used for tangents).
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
}

/// A loaded (and possibly repaired) mesh with a human-readable line per repair made.
#[derive(Clone, Debug)]
pub struct MeshLoad {
    pub mesh: Mesh,
    pub repairs: Vec<String>,
}

impl Mesh {
    pub fn load_obj(_path: &Path) -> Result<MeshLoad> {
        unimplemented!("mesh loading")
    }
}
