//! Bad input gives a clear error that names what and where, never a panic, and never a
//! half-written output file.

use biscale::error::PipelineError;
use biscale::experiment::config::Experiment;
use biscale::run::run;
use biscale::store::RunOptions;
use biscale_core::scene::HdrImage;
use biscale_core::CoreError;
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

/// Run and return the error (a config error or the run's); asserts that no metrics or report
/// were written.
fn run_err(cfg: &Path) -> PipelineError {
    let out = cfg.parent().unwrap().join("out");
    let err = match Experiment::load(cfg) {
        Err(e) => PipelineError::Config(e),
        Ok(exp) => {
            let opts = RunOptions { out_dir: Some(out.clone()), cache_dir: None, no_cache: true };
            run(&exp, &opts).expect_err("run must fail")
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
    assert!(matches!(&err, PipelineError::Config(c) if c.file.ends_with("broken.toml") && c.line == 2), "{err}");
}

#[test]
fn missing_mesh_is_a_config_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = run_err(&config_with(dir.path(), "nothing.obj", SKY));
    let PipelineError::Config(c) = &err else { panic!("{err}") };
    assert!((c.line, c.column) == (3, 8) && c.message.contains("mesh file not found"), "{err}");
}

#[test]
fn corrupt_obj_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nf 1 2 9\n").unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", SKY));
    assert!(matches!(&err, PipelineError::Core(CoreError::Input { path, .. }) if path.ends_with("m.obj")), "{err}");
}

#[test]
fn mesh_without_faces_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", SKY));
    let PipelineError::Core(CoreError::Input { path, message }) = &err else { panic!("{err}") };
    assert!(path.ends_with("m.obj") && message.contains("no faces"), "{err}");
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
    assert!(matches!(&err, PipelineError::Core(CoreError::Input { path, .. }) if path.ends_with("sky.exr")), "{err}");
}

#[test]
fn nan_in_env_map_is_rejected_with_its_pixel() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(workspace_root().join("assets/meshes/bunny.obj"), dir.path().join("m.obj")).unwrap();
    let mut img = HdrImage { width: 16, height: 8, pixels: vec![[1.0; 3]; 128] };
    img.pixels[3 * 16 + 5] = [1.0, f32::NAN, 1.0];
    img.write_exr(&dir.path().join("sky.exr")).unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", "env_map = \"sky.exr\""));
    let PipelineError::Core(CoreError::Input { path, message }) = &err else { panic!("{err}") };
    assert!(path.ends_with("sky.exr") && message.contains("x=5, y=3") && message.contains("NaN"), "{err}");
}

#[test]
fn infinite_env_map_value_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(workspace_root().join("assets/meshes/bunny.obj"), dir.path().join("m.obj")).unwrap();
    let mut img = HdrImage { width: 16, height: 8, pixels: vec![[1.0; 3]; 128] };
    img.pixels[0] = [f32::INFINITY, 1.0, 1.0];
    img.write_exr(&dir.path().join("sky.exr")).unwrap();
    let err = run_err(&config_with(dir.path(), "m.obj", "env_map = \"sky.exr\""));
    let PipelineError::Core(CoreError::Input { message, .. }) = &err else { panic!("{err}") };
    assert!(message.contains("x=0, y=0"), "{err}");
}

/// A config over `m.obj` (written from `obj`) with the given material tables.
fn material_config(dir: &Path, obj: &str, materials: &str) -> std::path::PathBuf {
    std::fs::write(dir.join("m.obj"), obj).unwrap();
    write_config(
        dir,
        "mat",
        &format!(
            "name = \"mat\"\n[scene]\nmesh = \"m.obj\"\n{materials}\n[lighting]\n{SKY}\n[transfer]\ncubemap_resolution = 4\n\
             visibility_resolution = 8\nlocal_grid = 2\n[[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 16\nheight = 16\nrepeats = 1\n"
        ),
    )
}

const TWO_TRIANGLES: &str = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nusemtl stone\nf 1 3 2\nusemtl gold\nf 1 4 3\n";

#[test]
fn an_obj_material_no_entry_names_is_an_error_naming_both() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = material_config(
        dir.path(),
        TWO_TRIANGLES,
        "[[scene.materials]]\nname = \"stone\"\nkind = \"lambertian\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [[scene.materials]]\nname = \"silver\"\nkind = \"lambertian\"\nalbedo = [0.5, 0.5, 0.5]\n",
    );
    let e = run_err(&cfg);
    let PipelineError::Mismatch { path, what } = &e else { panic!("{e}") };
    assert!(
        path.ends_with("m.obj") && what.contains("material \"gold\" (1 triangles)") && what.contains("stone, silver")
    );
}

#[test]
fn material_tables_are_checked_with_their_location() {
    let dir = tempfile::tempdir().unwrap();
    let lam = "kind = \"lambertian\"\nalbedo = [0.5, 0.5, 0.5]\n";
    let cases = [
        (format!("[[scene.materials]]\n{lam}[[scene.materials]]\n{lam}"), "each needs a name"),
        (format!("[[scene.materials]]\nname = \"a\"\n{lam}[[scene.materials]]\nname = \"a\"\n{lam}"), "used twice"),
        (format!("[scene.material]\n{lam}[[scene.materials]]\nname = \"a\"\n{lam}"), "not both"),
        (format!("[scene.material]\n{lam}tiling = -1.0\n"), "tiling must be a positive"),
        (
            "[scene.material]\nkind = \"synthesized\"\npattern = \"bumps\"\namplitude = 0.1\nview_grid = 0\n\
             brdf = { kind = \"phong\", kd = [0.5, 0.5, 0.5], ks = [0.1, 0.1, 0.1], exponent = 8.0 }\n"
                .to_string(),
            "view_grid = 0 (no view axis) needs a lambertian brdf",
        ),
        (
            "[scene.material]\nkind = \"synthesized\"\nheight_map = \"nowhere.png\"\namplitude = 0.1\n\
             brdf = { kind = \"lambertian\", albedo = [0.5, 0.5, 0.5] }\n"
                .to_string(),
            "height_map file not found",
        ),
    ];
    for (table, expect) in cases {
        let cfg = material_config(dir.path(), TWO_TRIANGLES, &table);
        let e = Experiment::load(&cfg).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains(expect) && e.contains("mat.toml:"), "{table}\n=> {e}");
    }
}

#[test]
fn a_height_map_of_the_wrong_shape_is_an_error_naming_the_image() {
    let dir = tempfile::tempdir().unwrap();
    image::GrayImage::new(6, 4).save(dir.path().join("h.png")).unwrap();
    let cfg = material_config(
        dir.path(),
        TWO_TRIANGLES,
        "[scene.material]\nkind = \"synthesized\"\nheight_map = \"h.png\"\namplitude = 0.1\nresolution = 4\nview_grid = 2\n\
         brdf = { kind = \"lambertian\", albedo = [0.5, 0.5, 0.5] }\n",
    );
    let e = run_err(&cfg);
    let PipelineError::Material { source: biscale_shading::ShadingError::File { path, message }, .. } = &e else {
        panic!("{e}")
    };
    assert!(path.ends_with("h.png") && message.contains("must be square") && message.contains("6x4"), "{e}");
}

#[test]
fn an_anisotropic_brdf_on_a_mesh_without_uvs_runs_with_a_warning() {
    // Repair with a warning: the fixed-axis tangent field stands in for UV tangents.
    let dir = tempfile::tempdir().unwrap();
    let cfg = material_config(
        dir.path(),
        "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nf 1 3 2\nf 1 4 3\n",
        "[scene.material]\nkind = \"synthesized\"\npattern = \"weave\"\namplitude = 0.05\nfrequency = 2\nresolution = 4\nview_grid = 2\n\
         brdf = { kind = \"ashikhmin_shirley\", rd = [0.3, 0.3, 0.3], rs = [0.2, 0.2, 0.2], nu = 50.0, nv = 5.0 }\n",
    );
    let exp = Experiment::load(&cfg).unwrap();
    let out = dir.path().join("out");
    let opts = RunOptions { out_dir: Some(out.clone()), cache_dir: None, no_cache: true };
    let (_, m) = run(&exp, &opts).unwrap();
    let notes = m.scene.material_notes.join("\n");
    assert!(notes.contains("anisotropic BRDF on a mesh without texture coordinates"), "{notes}");
    assert!(notes.contains("material ids: left out"), "{notes}");
}
