//! Several materials per scene, synthesized BTFs through a config, and the temple example:
//! end to end through `biscale run`, checked against closed-form radiance where there is one.

use super::run_in;
use biscale::experiment::config::Experiment;
use biscale::run::run;
use biscale::store::RunOptions;
use biscale_core::geometry::{shapes, MaterialIds, Mesh};
use biscale_core::scene::HdrImage;
use biscale_tests::{workspace_root, write_config, write_obj};

/// An 8 x 8 cell plane of side 2 whose triangles left of x = 0 use `left`, the others `right`.
fn split_plane(left: &str, right: &str) -> Mesh {
    let mut mesh = shapes::grid_plane(8, 2.0);
    let per_triangle = mesh
        .triangles
        .iter()
        .map(|t| u16::from(t.iter().map(|&i| mesh.positions[i as usize].x).sum::<f32>() > 0.0))
        .collect();
    mesh.materials = Some(MaterialIds { names: vec![left.into(), right.into()], per_triangle });
    mesh
}

const TOP_VIEW: &str = "[runtime.camera]\nposition = [0.0, 3.0, 0.001]\ntarget = [0.0, 0.0, 0.0]\nfov_y_degrees = 30.0";

#[test]
fn each_half_of_a_plane_shows_its_own_material_under_a_constant_sky() {
    // An open plane under a constant sky of radiance 1: a Lambertian patch of albedo a shows
    // radiance a (see end_to_end.rs for the 1% bound). The right half is a *synthesized* flat
    // patch, which the generator must tabulate analytically and equal exactly the Lambertian
    // table; a third entry no triangle uses is left out.
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("m.obj"), &split_plane("dark", "light"));
    // One sample per pixel: every covered pixel is read as a surface value (a pixel on the
    // plane's edge averaged with the black background is not one).
    let cfg = write_config(
        dir.path(),
        "two",
        &format!(
            "name = \"two\"\n[scene]\nmesh = \"m.obj\"\n\
             [[scene.materials]]\nname = \"dark\"\nkind = \"lambertian\"\nalbedo = [0.3, 0.3, 0.3]\n\
             [[scene.materials]]\nname = \"unused\"\nkind = \"phong\"\nkd = [0.1, 0.1, 0.1]\nks = [0.5, 0.5, 0.5]\nexponent = 10.0\n\
             [[scene.materials]]\nname = \"light\"\nkind = \"synthesized\"\npattern = \"bumps\"\namplitude = 0.0\nview_grid = 0\n\
             brdf = {{ kind = \"lambertian\", albedo = [0.9, 0.9, 0.9] }}\n\
             [lighting]\nconstant = [1, 1, 1]\n[transfer]\ncubemap_resolution = 16\nvisibility_resolution = 32\nlocal_grid = 8\n\
             [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 64\nheight = 64\nrepeats = 1\nsamples_per_pixel = 1\n{TOP_VIEW}\n[report]\nbackground = false\n"
        ),
    );
    let out = dir.path().join("out");
    let m = run_in(&cfg, &out);
    let notes = m.scene.material_notes.join("\n");
    assert!(notes.contains("unused: left out, no triangle uses it"), "{notes}");
    assert!(notes.contains("light: flat patch, tabulated analytically"), "{notes}");
    assert!(!notes.contains("material ids: left out"), "two materials need ids: {notes}");
    let img = HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    let exp = Experiment::load(&cfg).unwrap();
    let camera = biscale::stages::scene::camera(&exp, &split_plane("dark", "light"), 1);
    let (mut dark, mut light) = (0, 0);
    for y in 0..64 {
        for x in 0..64 {
            let v = img.get(x, y)[1];
            // Where the pixel's ray meets the plane y = 0 (pixels within 0.02 of the seam
            // x = 0 may go either way).
            let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = o + d * (-o.y / d.y);
            if v == 0.0 || hit.x.abs() < 0.02 {
                continue;
            }
            let expect = if hit.x < 0.0 { 0.3 } else { 0.9 };
            assert!((v - expect).abs() < 0.01 * expect, "({x},{y}) at x = {}: {v} vs {expect}", hit.x);
            if hit.x < 0.0 {
                dark += 1
            } else {
                light += 1
            }
        }
    }
    assert!(dark > 500 && light > 500, "{dark} {light}");
}

#[test]
fn a_synthesized_btf_is_generated_once_then_read_from_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("m.obj"), &shapes::cylindrical_uvs(&shapes::uv_sphere(glam::Vec3::ZERO, 1.0, 8, 16)));
    let cfg = write_config(
        dir.path(),
        "bumpy",
        "name = \"bumpy\"\n[scene]\nmesh = \"m.obj\"\n[scene.material]\nkind = \"synthesized\"\npattern = \"bumps\"\n\
         amplitude = 0.1\nfrequency = 2\nresolution = 8\nview_grid = 3\ntiling = 2.0\n\
         brdf = { kind = \"phong\", kd = [0.5, 0.4, 0.3], ks = [0.3, 0.3, 0.3], exponent = 20.0 }\n\
         [lighting]\nconstant = [1, 1, 1]\n[transfer]\ncubemap_resolution = 4\nvisibility_resolution = 8\nlocal_grid = 3\n\
         [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 24\nheight = 24\nrepeats = 1\n",
    );
    let out = dir.path().join("out");
    run_in(&cfg, &out);
    let cached: Vec<_> = std::fs::read_dir(biscale_tests::cache_beside(&out))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("btf-"))
        .collect();
    assert_eq!(cached.len(), 1, "one BTF cache file");
    let first = HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    let stamp = cached[0].metadata().unwrap().modified().unwrap();
    run_in(&cfg, &out);
    assert_eq!(cached[0].metadata().unwrap().modified().unwrap(), stamp, "not rewritten");
    let second = HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    // The first run already used the table as its encoding (f16) stores it: bit-identical.
    assert_eq!(first.pixels, second.pixels);
    // The bumps are visible: the image is not one flat shade of the sphere's lighting.
    let lit: Vec<f32> = first.pixels.iter().map(|p| p[1]).filter(|&v| v > 0.0).collect();
    assert!(lit.len() > 100);
}

#[test]
fn the_bundled_temple_is_the_generators_and_names_every_configured_material() {
    let root = workspace_root();
    let bundled = Mesh::load_obj(&root.join("assets/meshes/temple.obj")).unwrap();
    assert!(bundled.repairs.is_empty(), "{:?}", bundled.repairs);
    let generated = biscale::temple::build(&biscale::temple::TempleOptions::default());
    assert_eq!(bundled.mesh.positions.len(), generated.positions.len(), "regenerate assets/meshes/temple.obj");
    assert_eq!(bundled.mesh.materials, generated.materials);
    let exp = Experiment::load(&root.join("configs/temple.toml")).unwrap();
    let map = biscale::stages::materials::assign(&bundled.mesh, &exp.mesh_path, &exp.materials())
        .unwrap()
        .expect("per-name map");
    assert_eq!(map.len(), 5);
    let plan = biscale::plan::Plan::new(&exp).to_string();
    assert!(plan.contains("marble: ray tracing of a flat patch"), "{plan}");
    assert!(plan.contains("ground: synthesize 16x16 texels x no view axis"), "{plan}");
    assert!(plan.contains("material ids per triangle (5 materials)"), "{plan}");
}

#[test]
fn btf_command_writes_tables_and_contact_sheets() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("m.obj"), &split_plane("a", "b"));
    let cfg = write_config(
        dir.path(),
        "btfs",
        "name = \"btfs\"\n[scene]\nmesh = \"m.obj\"\n\
         [[scene.materials]]\nname = \"a\"\nkind = \"synthesized\"\npattern = \"weave\"\namplitude = 0.05\nfrequency = 2\nresolution = 8\nview_grid = 3\n\
         brdf = { kind = \"phong\", kd = [0.5, 0.4, 0.3], ks = [0.3, 0.3, 0.3], exponent = 20.0 }\n\
         [[scene.materials]]\nname = \"b\"\nkind = \"lambertian\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [lighting]\nconstant = [1, 1, 1]\n[transfer]\nlocal_grid = 4\n",
    );
    let exp = Experiment::load(&cfg).unwrap();
    let out = dir.path().join("btf");
    let opts = RunOptions { out_dir: Some(out.clone()), cache_dir: None, no_cache: true };
    let written = biscale::commands::btf(&exp, &out, None, true, &opts).unwrap();
    assert_eq!(written.len(), 2);
    let a = biscale_shading::synth::load_btf(&written[0].path).unwrap();
    assert_eq!((a.spatial(), a.light_count(), a.view_count()), ([8, 8], 16, 9));
    for w in &written {
        let png = image::open(w.preview.as_ref().unwrap()).unwrap();
        assert!(png.width() >= 32 && png.height() >= 32);
    }
    // Only one, by name; an unknown name is an error listing the names.
    assert_eq!(biscale::commands::btf(&exp, &out, Some("b"), false, &opts).unwrap().len(), 1);
    let e = biscale::commands::btf(&exp, &out, Some("c"), false, &opts).err().unwrap();
    let biscale::error::PipelineError::Mismatch { path, what } = &e else { panic!("{e}") };
    assert!(path == &exp.config_path && what.contains("no material named \"c\"") && what.contains("a, b"), "{e}");
}

/// `representation = { kind = "lpca", ... }` end to end: with every component its clusters can
/// hold, the render equals the dense one to f32 rounding (the reconstruction is exact; 1e-5 is
/// a few hundred f32 ulps of the summed BTF-times-light terms); with one component it costs
/// less and loses something, and the record says how much. A setting the patch cannot hold is
/// an error naming the material.
#[test]
fn lpca_btfs_render_like_the_dense_table_at_full_rank_and_report_their_cost() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("m.obj"), &shapes::grid_plane(8, 2.0));
    let config = |name: &str, repr: &str| {
        write_config(
            dir.path(),
            name,
            &format!(
                "name = \"{name}\"\n[scene]\nmesh = \"m.obj\"\n\
                 [scene.material]\nkind = \"synthesized\"\npattern = \"bumps\"\namplitude = 0.08\nfrequency = 2\n\
                 resolution = 4\nview_grid = 3\ntiling = 3.0\n\
                 brdf = {{ kind = \"phong\", kd = [0.5, 0.4, 0.3], ks = [0.3, 0.3, 0.3], exponent = 12.0 }}\n{repr}\n\
                 [lighting]\nenv_map = \"{}\"\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\nlocal_grid = 4\n\
                 [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 48\nheight = 48\nrepeats = 1\n{TOP_VIEW}\n\
                 [report]\nbackground = false\n",
                workspace_root().join("assets/envmaps/pmndrs_apartment.exr").display()
            ),
        )
    };
    let image = |out: &std::path::Path| HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    let rel = |a: &HdrImage, b: &HdrImage| {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (x, y) in a.pixels.iter().flatten().zip(b.pixels.iter().flatten()) {
            num += (*x as f64 - *y as f64).powi(2);
            den += (*y as f64).powi(2);
        }
        (num / den).sqrt()
    };
    let dense_out = dir.path().join("dense");
    let m = run_in(&config("dense", ""), &dense_out);
    assert_eq!(m.scene.btfs[0].representation, "dense");
    let dense = image(&dense_out);

    // 16 texels in 2 clusters: at most 15 centred directions each.
    let full_out = dir.path().join("full");
    let m = run_in(&config("full", "representation = { kind = \"lpca\", clusters = 2, components = 15 }"), &full_out);
    let r = &m.scene.btfs[0];
    assert_eq!(r.representation, "lpca-k2-c15");
    assert!(r.relative_rms_error < 1e-5, "{r:?}");
    let e = rel(&image(&full_out), &dense);
    assert!(e < 1e-5, "full-rank LPCA image differs from dense by {e:e}");

    let low_out = dir.path().join("low");
    let m = run_in(&config("low", "representation = { kind = \"lpca\", clusters = 1, components = 1 }"), &low_out);
    let r = &m.scene.btfs[0];
    assert!(r.compression_ratio > 5.0 && r.bytes < r.dense_bytes, "{r:?}");
    assert!(r.relative_rms_error > 1e-3, "one component of a bumpy Phong patch must lose something: {r:?}");
    let e = rel(&image(&low_out), &dense);
    assert!(e > 1e-4, "{e:e}");
    // Both reports list the BTF's storage.
    let md = std::fs::read_to_string(low_out.join("report.md")).unwrap();
    let html = std::fs::read_to_string(low_out.join("report.html")).unwrap();
    assert!(md.contains("| synthesized | lpca-k1-c1 | yes |") && md.contains("The materials' own BTFs:"), "{md}");
    assert!(
        html.contains("<h3>BTFs</h3>") && html.contains("<td>lpca-k1-c1</td>"),
        "BTF table missing from report.html"
    );

    // A list sweeps: the first setting is the material's own (its images are those of the
    // `low` run above), every setting gets a study row. The study compares each setting's
    // image with the all-dense one: the same numbers as the separate runs above.
    let sweep_out = dir.path().join("sweep");
    let sweep = "representation = [{ kind = \"lpca\", clusters = 1, components = 1 }, \
                 { kind = \"lpca\", clusters = 2, components = 15 }, { kind = \"dense\" }]";
    let m = run_in(&config("sweep", sweep), &sweep_out);
    let labels: Vec<(&str, bool)> = m.scene.btfs.iter().map(|b| (b.representation.as_str(), b.primary)).collect();
    assert_eq!(labels, [("lpca-k1-c1", true), ("lpca-k2-c15", false), ("dense", false)]);
    let e_sweep = rel(&image(&sweep_out), &dense);
    assert!((e_sweep - e).abs() <= 1e-9 + 1e-6 * e, "the own setting shades every image: {e_sweep} vs {e}");
    let study: Vec<_> = m.scene.btfs.iter().map(|b| b.study.clone().unwrap()).collect();
    // Masked (covered pixels) against all pixels of a black background: the same sums.
    assert!((study[0].vs_dense.rel_l2 - e).abs() <= 1e-6 * e, "{} vs {e}", study[0].vs_dense.rel_l2);
    assert!(study[1].vs_dense.rel_l2 < 1e-5 && study[2].vs_dense.rel_l2 == 0.0, "{study:?}");
    // The fixed-light fast path gives the direct image up to f32 rounding of its dot products.
    for st in &study[..2] {
        let p = st.precomputed.as_ref().expect("a small table is measured");
        assert!(p.vs_direct < 1e-5 && p.bytes > 0, "{p:?}");
    }
    assert!(study[2].precomputed.is_none() && study[2].precomputed_note.is_some());
    assert!(sweep_out.join("btf_error_vs_storage.png").exists() && sweep_out.join(&study[1].error_png).exists());
    let md = std::fs::read_to_string(sweep_out.join("report.md")).unwrap();
    assert!(md.contains("| synthesized | lpca-k2-c15 | study |"), "{md}");
    // Total bytes count the material's own setting only.
    assert_eq!(m.scene.btf_bytes, m.scene.btfs[0].dense_bytes);
    // `biscale btf --preview` writes a dense | compressed | error sheet per compressed setting.
    let exp = Experiment::load(&sweep_out.parent().unwrap().join("sweep.toml")).unwrap();
    let opts = RunOptions { out_dir: None, cache_dir: Some(biscale_tests::cache_beside(&sweep_out)), no_cache: false };
    let written = biscale::commands::btf(&exp, &dir.path().join("btf"), None, true, &opts).unwrap();
    let sheets: Vec<&str> = written[0].comparisons.iter().map(|c| c.representation.as_str()).collect();
    assert_eq!(sheets, ["lpca-k1-c1", "lpca-k2-c15"]);
    for c in &written[0].comparisons {
        assert!(c.path.is_file() && c.error_gain > 0.0, "{}", c.path.display());
    }
    assert!((written[0].comparisons[0].relative_rms_error - m.scene.btfs[0].relative_rms_error).abs() < 1e-12);

    let bad = config("bad", "representation = { kind = \"lpca\", clusters = 20, components = 2 }");
    let exp = Experiment::load(&bad).unwrap();
    let opts = RunOptions { out_dir: Some(dir.path().join("bad")), cache_dir: None, no_cache: true };
    let msg = run(&exp, &opts).unwrap_err().to_string();
    assert!(msg.contains("clusters = 20") && msg.contains("16 texels"), "{msg}");
}

/// A measured BTF in the Bonn database's layout (a folder per view, an image per light)
/// whose photographs are those of a Lambertian patch, `albedo / pi * cos theta_l`: the
/// importer divides the cosine out, interpolates a constant ABRDF (exact) and multiplies the
/// bins' mean cosines back in, which is `Btf::lambertian`'s table. So a plane of the measured
/// material renders as the same plane with the analytic Lambertian, up to f32 rounding.
#[test]
fn a_measured_btf_in_the_bonn_layout_renders_as_the_material_it_measured() {
    let dir = tempfile::tempdir().unwrap();
    let albedo = [0.3f32, 0.5, 0.7];
    let sample = dir.path().join("sample");
    let views = [(0, 0), (30, 0), (30, 180)];
    let mut lights = vec![(0u32, 0u32)];
    for theta in [30, 60] {
        for phi in [0, 90, 180, 270] {
            lights.push((theta, phi));
        }
    }
    for (tv, pv) in views {
        let folder = sample.join(format!("tv{tv:03}_pv{pv:03}"));
        std::fs::create_dir_all(&folder).unwrap();
        for (i, (tl, pl)) in lights.iter().enumerate() {
            let cos = (*tl as f64).to_radians().cos();
            let mut img = HdrImage::new(4, 4);
            for p in &mut img.pixels {
                *p = albedo.map(|a| (a as f64 / std::f64::consts::PI * cos) as f32);
            }
            img.write_exr(&folder.join(format!("{i:05} tl{tl:03} pl{pl:03} tv{tv:03} pv{pv:03}.exr"))).unwrap();
        }
    }
    write_obj(&dir.path().join("m.obj"), &shapes::grid_plane(4, 2.0));
    let config = |name: &str, material: &str| {
        write_config(
            dir.path(),
            name,
            &format!(
                "name = \"{name}\"\n[scene]\nmesh = \"m.obj\"\n[scene.material]\n{material}\n\
                 [lighting]\nconstant = [1, 0.8, 0.6]\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\nlocal_grid = 4\n\
                 [[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 32\nheight = 32\nrepeats = 1\n{TOP_VIEW}\n[report]\nreference = false\n"
            ),
        )
    };
    let measured = config("measured", "kind = \"bonn\"\npath = \"sample\"\nresolution = 2\nview_grid = 2");
    let analytic = config("analytic", &format!("kind = \"lambertian\"\nalbedo = {albedo:?}"));
    let exp = Experiment::load(&measured).unwrap();
    let plan = biscale::plan::Plan::new(&exp).to_string();
    assert!(
        plan.contains("resample the measured BTF in") && plan.contains("2x2 texels x 2x2 views x 4x4 lights"),
        "{plan}"
    );
    let (out_m, out_a) = (dir.path().join("out-m"), dir.path().join("out-a"));
    run_in(&measured, &out_m);
    run_in(&analytic, &out_a);
    let read = |out: &std::path::Path| HdrImage::read_exr(&out.join("images/uncompressed.exr")).unwrap().0;
    let (m, a) = (read(&out_m), read(&out_a));
    let mut lit = 0;
    for (pm, pa) in m.pixels.iter().zip(&a.pixels) {
        for c in 0..3 {
            // f32 rounding of the table (a few ulps) through a dot of 16 bins.
            assert!((pm[c] - pa[c]).abs() <= 1e-5 * pa[c].abs() + 1e-7, "{pm:?} vs {pa:?}");
        }
        lit += usize::from(pa[0] > 0.0);
    }
    assert!(lit > 100, "the plane covers {lit} pixels");

    // A sample folder that is not there is a config error naming it.
    let missing = config("missing", "kind = \"bonn\"\npath = \"nowhere\"");
    let e = Experiment::load(&missing).unwrap_err().to_string();
    assert!(e.contains("bonn sample folder not found") && e.contains("nowhere"), "{e}");
}
