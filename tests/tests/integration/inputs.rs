//! Inputs researchers have, end to end: a PLY mesh and a cube-map sky (a cross image or six
//! face files) go through config, plan, run and the mesh commands exactly as their OBJ and
//! cross twins do.

use biscale::experiment::config::Experiment;
use biscale::run::run;
use biscale::store::RunOptions;
use biscale_core::geometry::{shapes, Mesh};
use biscale_core::scene::HdrImage;
use biscale_tests::{write_config, write_obj};
use glam::{DVec3, Vec3};
use std::path::Path;

/// `mesh` as a binary little-endian PLY (float positions and uvs, int index lists).
fn write_ply(path: &Path, mesh: &Mesh) {
    let uv = mesh.uvs.is_some();
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n{}\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertex_count(),
        if uv { "property float u\nproperty float v\n" } else { "" },
        mesh.triangle_count()
    )
    .into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        for x in p.to_array().into_iter().chain(mesh.uvs.iter().flat_map(|u| u[i].to_array())) {
            b.extend(x.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        b.push(3);
        for &i in t {
            b.extend((i as i32).to_le_bytes());
        }
    }
    std::fs::write(path, b).unwrap();
}

/// The sky: a gradient and a bright spot, seen along unit direction `d`.
fn sky(d: DVec3) -> [f32; 3] {
    let sun = DVec3::new(0.5, 0.7, 0.3).normalize();
    let spot = if d.dot(sun) > 0.98 { 40.0 } else { 0.0 };
    [(0.3 + 0.2 * d.y + spot) as f32, (0.4 + 0.1 * d.x + spot) as f32, (0.5 + spot) as f32]
}

/// The sky's six faces (`f x f`, OpenGL orientation: biscale's own) and its horizontal cross.
fn write_skies(dir: &Path, f: usize) {
    let face = |k: usize| -> Vec<[f32; 3]> {
        let cube = biscale_core::sampling::Cubemap::new(f as u32);
        (0..f * f).map(|i| sky(cube.texel_direction_f64(k * f * f + i))).collect()
    };
    let mut cross = HdrImage::new(4 * f as u32, 3 * f as u32);
    // Cells of +X -X +Y -Y +Z -Z in the horizontal cross.
    let cells = [(2, 1), (0, 1), (1, 0), (1, 2), (1, 1), (3, 1)];
    for (k, tag) in biscale_core::sampling::cube_env::FACE_TAGS.iter().enumerate() {
        let pixels = face(k);
        for (i, p) in pixels.iter().enumerate() {
            let (x, y) = (cells[k].0 * f + i % f, cells[k].1 * f + i / f);
            cross.pixels[y * 4 * f + x] = *p;
        }
        HdrImage { width: f as u32, height: f as u32, pixels }.write_exr(&dir.join(format!("sky_{tag}.exr"))).unwrap();
    }
    cross.write_exr(&dir.join("cross.exr")).unwrap();
}

fn config(dir: &Path, name: &str, mesh: &str, env: &str) -> Experiment {
    let path = write_config(
        dir,
        name,
        &format!(
            "name = \"{name}\"\n[scene]\nmesh = \"{mesh}\"\n[scene.material]\nkind = \"lambertian\"\nalbedo = [0.7, 0.7, 0.7]\n\
             [lighting]\nenv_map = \"{env}\"\nrotation_degrees = 30\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\n\
             local_grid = 4\n[[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 40\nheight = 30\nrepeats = 1\n\
             samples_per_pixel = 1\n"
        ),
    );
    Experiment::load(&path).unwrap()
}

#[test]
fn a_ply_mesh_under_six_sky_faces_runs_exactly_as_its_obj_under_the_cross() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A mesh as the OBJ loader numbers it (first use), so both files hold the same vertex order.
    write_obj(&d.join("first.obj"), &shapes::uv_sphere(Vec3::ZERO, 1.0, 6, 10));
    let mesh = Mesh::load(&d.join("first.obj")).unwrap().mesh;
    write_obj(&d.join("m.obj"), &mesh);
    write_ply(&d.join("m.ply"), &mesh);
    assert_eq!(Mesh::load(&d.join("m.ply")).unwrap().mesh, mesh);
    write_skies(d, 16);

    let a = config(d, "obj_cross", "m.obj", "cross.exr");
    let b = config(d, "ply_faces", "m.ply", "sky_{face}.exr");
    // plan: the memory estimate loads the mesh and the sky (and keys T by the PLY's content).
    let opts = biscale::store::RunOptions { out_dir: None, cache_dir: Some(d.join("cache")), no_cache: false };
    let plan = biscale::plan::Plan::new(&b).with_estimates(&b, &opts).unwrap().to_string();
    assert!(plan.contains("build transfer   T"), "{plan}");
    assert!(plan.contains("sky_{face}.exr"), "{plan}");
    let la = biscale::stages::scene::load_lighting(&a).unwrap();
    let lb = biscale::stages::scene::load_lighting(&b).unwrap();
    assert_eq!(la.light, lb.light);
    assert!(la.warnings.is_empty(), "{:?}", la.warnings);
    // The light holds the sky's power (the gradient averages to its constant term, and the spot).
    let total = la.light.total();
    let spot = 2.0 * std::f64::consts::PI * (1.0 - 0.98) * 40.0;
    assert!((total[2] - (4.0 * std::f64::consts::PI * 0.5 + spot)).abs() < 0.05 * total[2], "{total:?}");

    let opts = |out: &str| RunOptions { out_dir: Some(d.join(out)), cache_dir: None, no_cache: true };
    let (out_a, ma) = run(&a, &opts("a")).unwrap();
    let (out_b, mb) = run(&b, &opts("b")).unwrap();
    assert_eq!((mb.scene.vertices, mb.scene.triangles), (mesh.vertex_count(), mesh.triangle_count()));
    assert_eq!(ma.lighting.total_power, mb.lighting.total_power);
    let image = |out: &Path| HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    let (ia, ib) = (image(&out_a), image(&out_b));
    assert_eq!(ia.pixels, ib.pixels);
    // The background is the rotated cube sky: a corner pixel sees it, not black.
    assert!(ia.pixels[0].iter().all(|&c| c > 0.1), "{:?}", ia.pixels[0]);

    // The mesh commands take a PLY too.
    let from_ply = biscale::commands::cylindrical_uv(&d.join("m.ply"), &d.join("uv_ply.obj"), false).unwrap();
    let from_obj = biscale::commands::cylindrical_uv(&d.join("m.obj"), &d.join("uv_obj.obj"), false).unwrap();
    assert_eq!(from_ply, from_obj);
}
