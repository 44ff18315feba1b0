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

/// The cache folder the tests give a run whose output folder is `out`: beside it, since a run
/// replaces its output folder whole (and refuses a cache inside it).
pub fn cache_beside(out: &Path) -> PathBuf {
    let name = out.file_name().map_or("out".into(), |n| n.to_string_lossy().into_owned());
    out.with_file_name(format!("{name}.cache"))
}
