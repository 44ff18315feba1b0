//! Helpers shared by the integration tests: writing meshes and configs into temporary
//! folders, and locating the workspace's bundled files.

use biscale_core::geometry::Mesh;
use std::path::{Path, PathBuf};

/// The workspace root (where `configs/` and `assets/` live).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

/// Write `mesh` as an OBJ file.
pub fn write_obj(path: &Path, mesh: &Mesh) {
    std::fs::write(path, mesh.to_obj()).expect("write obj");
}

/// Write `body` as `dir/name.toml` and return its path.
pub fn write_config(dir: &Path, name: &str, body: &str) -> PathBuf {
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, body).expect("write config");
    p
}
