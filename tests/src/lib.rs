//! Helpers shared by the integration tests: writing meshes and configs into temporary
//! folders, and locating the workspace's bundled files.

use biscale_core::geometry::Mesh;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The workspace root (where `configs/` and `assets/` live).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

/// Write `mesh` as a minimal OBJ (`v` and `f` lines, 1-based).
pub fn write_obj(path: &Path, mesh: &Mesh) {
    let mut s = String::new();
    for p in &mesh.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).expect("write obj");
}

/// Write `body` as `dir/name.toml` and return its path.
pub fn write_config(dir: &Path, name: &str, body: &str) -> PathBuf {
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, body).expect("write config");
    p
}
