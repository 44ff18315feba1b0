//! Bad input gives a clear error that names what and where, never a panic, and never a
//! half-written output file.

use biscale::config::Experiment;
use biscale::pipeline::{run, RunOptions};
use biscale_shading::image::HdrImage;
use biscale_tests::{workspace_root, write_config};
use std::path::Path;

fn config_with(dir: &Path, mesh: &str, lighting: &str) -> std::path::PathBuf {
    write_config(
        dir,
        "bad",
        &format!(
            "name = \"bad\"\n[scene]\nmesh = \"{mesh}\"\n[lighting]\n{lighting}\n[transfer]\ncubemap_resolution = 4\nvisibility_resolution = 8\nlocal_grid = 2\n\
             [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 16\nheight = 16\nrepeats = 1\n"
        ),
    )
}

/// Run and return the error text; asserts that no metrics or report were written.
fn run_err(cfg: &Path) -> String {
    let out = cfg.parent().unwrap().join("out");
    let err = match Experiment::load(cfg) {
        Err(e) => e.to_string(),
        Ok(exp) => {
            let opts = RunOptions { out_dir: Some(out.clone()), cache_dir: None, no_cache: true };
            run(&exp, &opts).err().expect("run must fail").to_string()
        }
    };
    assert!(!out.join("metrics.json").exists() && !out.join("report.md").exists());
    if out.exists() {
        for e in walk(&out) {
            let name = e.file_name().unwrap().to_string_lossy().into_owned();
            assert!(!name.contains(".tmp"), "temporary file left behind: {}", e.display());
        }
    }
    err
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v = vec![];
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        if e.path().is_dir() {
            v.extend(walk(&e.path()));
        } else {
            v.push(e.path());
        }
    }
    v
}

const SKY: &str = "constant = [1, 1, 1]";

#[test]
fn malformed_toml_names_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "broken", "name = \"x\"\n[scene\nmesh = 1\n");
    let err = run_err(&cfg);
    assert!(err.contains("broken.toml:2:"), "{err}");
}

#[test]
fn missing_mesh_is_a_config_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = run_err(&config_with(dir.path(), "nothing.obj", SKY));
    assert!(err.contains("bad.toml:3:8") && err.contains("mesh file not found"), "{err}");
}

#[test]
fn corrupt_obj_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nf 1 2 9\n").unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", SKY));
    assert!(err.contains("m.obj"), "{err}");
}

#[test]
fn mesh_without_faces_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", SKY));
    assert!(err.contains("m.obj") && err.contains("no faces"), "{err}");
}

#[test]
fn degenerate_triangles_and_duplicate_vertices_are_repaired_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    // A quad as two triangles with a duplicated corner, plus a zero-area and a repeated-index
    // triangle.
    std::fs::write(
        dir.path().join("m.obj"),
        "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 1 0 1\nv 2 0 0\nf 1 4 3\nf 1 5 2\nf 1 2 6\nf 1 1 2\n",
    )
    .unwrap();
    let cfg = config_with(dir.path(), "m.obj", SKY);
    let exp = Experiment::load(&cfg).unwrap();
    let opts = RunOptions { out_dir: Some(dir.path().join("out")), cache_dir: None, no_cache: true };
    let (_, m) = run(&exp, &opts).unwrap();
    assert_eq!(m.scene.triangles, 2, "{:?}", m.scene.repairs);
    assert_eq!(m.scene.vertices, 4, "{:?}", m.scene.repairs);
    assert!(m.scene.repairs.len() >= 2, "{:?}", m.scene.repairs);
}

#[test]
fn corrupt_exr_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(workspace_root().join("assets/meshes/bunny.obj"), dir.path().join("m.obj")).unwrap();
    std::fs::write(dir.path().join("sky.exr"), b"this is not an OpenEXR file").unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", "env_map = \"sky.exr\""));
    assert!(err.contains("sky.exr"), "{err}");
}

#[test]
fn nan_in_env_map_is_rejected_with_its_pixel() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(workspace_root().join("assets/meshes/bunny.obj"), dir.path().join("m.obj")).unwrap();
    let mut img = HdrImage { width: 16, height: 8, pixels: vec![[1.0; 3]; 128] };
    img.pixels[3 * 16 + 5] = [1.0, f32::NAN, 1.0];
    img.write_exr(&dir.path().join("sky.exr")).unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", "env_map = \"sky.exr\""));
    assert!(err.contains("sky.exr") && err.contains("x=5, y=3") && err.contains("NaN"), "{err}");
}

#[test]
fn infinite_env_map_value_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(workspace_root().join("assets/meshes/bunny.obj"), dir.path().join("m.obj")).unwrap();
    let mut img = HdrImage { width: 16, height: 8, pixels: vec![[1.0; 3]; 128] };
    img.pixels[0] = [f32::INFINITY, 1.0, 1.0];
    img.write_exr(&dir.path().join("sky.exr")).unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", "env_map = \"sky.exr\""));
    assert!(err.contains("x=0, y=0"), "{err}");
}
