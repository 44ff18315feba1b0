//! The low-frequency method (`[[methods]] kind = "sh"`) end to end: an analytic scene with a
//! derived tolerance, the records beside the compressors, and the wgpu backend against the
//! CPU.

use super::run_in;
use biscale::experiment::config::Experiment;
use biscale_core::geometry::shapes;
use biscale_core::sampling::hemisphere::square_to_hemisphere;
use biscale_core::scene::HdrImage;
use biscale_tests::{write_config, write_obj};
use glam::Vec3;

/// A white Lambertian convex sphere under a constant sky of radiance 1, by shadowed diffuse
/// PRT (every material is Lambertian, so the method keeps one transfer vector per vertex).
///
/// Exact: every vertex sees its whole upper hemisphere; the order-5 irradiance of that light
/// is exactly `pi` (only bands 0 and 1 of the hemisphere and the clamped cosine overlap, see
/// `biscale_core::transfer::sh`'s tests), so the radiance is the albedo. Errors, bounded:
/// * `M_p` is a jittered stratified estimate over `S = g^2` equal-area strata of the upper
///   hemisphere; the irradiance it gives is the estimate of `int_H (P_n c)` (`P_n c` the
///   truncated clamped cosine). Its standard deviation is at most `(2 pi / S) sqrt(S) L d / 2`
///   with `L` the Lipschitz constant of `P_n c` on the sphere and `d` the largest stratum
///   diameter; `L <= sum_l |c_l| sqrt(l (l + 1) (2l + 1) / (4 pi))` (the addition theorem for
///   gradients) and `d` is measured on the grid. We allow 5 standard deviations.
/// * The light is the projection of the run's cubemap light of the constant sky: its bands
///   above 0 (the splatting of the map onto the cubemap, and the projection's midpoint error)
///   add at most `|c| |L_sh[1..]|` to the irradiance (`|M_p| <= 1`: it restricts and rotates).
#[test]
fn a_white_lambertian_sphere_under_a_constant_sky_shades_to_its_albedo() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("m.obj"), &shapes::uv_sphere(Vec3::ZERO, 1.0, 16, 32));
    let albedo = 0.8f64;
    // One sample per pixel: every covered pixel is read as a surface value (a silhouette
    // pixel averaged with the black background is not one).
    let cfg = write_config(
        dir.path(),
        "diffuse",
        &format!(
            "name = \"diffuse\"\n[scene]\nmesh = \"m.obj\"\n[scene.material]\nkind = \"lambertian\"\nalbedo = [{albedo}, {albedo}, {albedo}]\n\
             [lighting]\nconstant = [1, 1, 1]\n[transfer]\ncubemap_resolution = 16\nvisibility_resolution = 32\nlocal_grid = 8\n\
             [[compressors]]\nkind = \"sparse\"\n[[methods]]\nkind = \"sh\"\norder = 5\n\
             [runtime]\nwidth = 64\nheight = 64\nrepeats = 1\nsamples_per_pixel = 1\n[runtime.camera]\nazimuth_degrees = 10.0\nelevation_degrees = 35.0\n\
             [report]\nbackground = false\n"
        ),
    );
    let out = dir.path().join("out");
    let m = run_in(&cfg, &out);
    let sh = m.methods[0].sh.as_ref().unwrap();
    assert!(sh.diffuse, "every material is Lambertian: the diffuse special case");
    assert_eq!((m.methods[0].record.name.as_str(), sh.order, sh.rays), ("sh-n5", 5, 1024));
    // The bound.
    let order = biscale_core::sh::ShOrder::new(5).unwrap();
    let c = biscale_core::sh::clamped_cosine(order);
    let lipschitz: f64 = (0..5)
        .map(|l| {
            let cl = c[biscale_core::sh::index(l, 0)].abs();
            cl * ((l * (l + 1) * (2 * l + 1)) as f64 / (4.0 * std::f64::consts::PI)).sqrt()
        })
        .sum();
    let g = 32u32;
    let corner = |i: u32, j: u32| square_to_hemisphere(i as f64 / g as f64, j as f64 / g as f64);
    let mut diam = 0.0f64;
    for i in 0..g {
        for j in 0..g {
            let pts = [corner(i, j), corner(i + 1, j), corner(i, j + 1), corner(i + 1, j + 1)];
            for a in &pts {
                for b in &pts {
                    diam = diam.max(a.dot(*b).clamp(-1.0, 1.0).acos());
                }
            }
        }
    }
    let s = (g * g) as f64;
    let sigma = 2.0 * std::f64::consts::PI / s * s.sqrt() * lipschitz * diam / 2.0;
    // The run's own light (a constant map integrated over the cubemap: each texel gathers whole
    // sub-pixels of the map, so its power is the texel's solid angle up to that splatting).
    let exp = Experiment::load(&cfg).unwrap();
    let light = biscale::stages::scene::load_lighting(&exp).unwrap().light;
    let cubemap = biscale_core::sampling::Cubemap::new(16);
    let sh_light = biscale_core::sh::ShProjection::new(cubemap, order, biscale_core::sh::light::LIGHT_SUBTEXELS)
        .project(&light)
        .unwrap();
    let residual = sh_light.power[1..].iter().map(|p| (p[0] as f64).powi(2)).sum::<f64>().sqrt();
    let c_norm = c.iter().map(|x| x * x).sum::<f64>().sqrt();
    let tol = albedo / std::f64::consts::PI * (5.0 * sigma + c_norm * residual) + 1e-5;
    assert!(tol < 0.05 * albedo, "the bound must be meaningful: {tol}");
    let img = HdrImage::read_exr(&out.join("images/sh-n5.exr")).unwrap().0;
    let covered: Vec<f32> = img.pixels.iter().filter(|p| p[0] > 0.0).map(|p| p[1]).collect();
    assert!(covered.len() > 500);
    for v in covered {
        assert!((v as f64 - albedo).abs() <= tol, "{v} vs {albedo} (tolerance {tol:e})");
    }
    // The agreement with T and the other records are reported, and finite.
    assert!(
        sh.transfer.from_t_difference.is_finite() && sh.transfer.from_t_difference < 0.1,
        "{}",
        sh.transfer.from_t_difference
    );
    // The constant sky reaches the cubemap with the splatting's texel-scale noise, which order 5
    // cannot hold: a few percent.
    assert!(sh.light_projection_error < 0.1, "{}", sh.light_projection_error);
    assert_eq!(sh.negative_pixels, 0.0);
}

/// A glossy scene with shadows: the SH settings (an order sweep and CPCA of whole vertex
/// matrices) get records beside the compressors, the report its low- vs all-frequency section
/// and the image-error plot, and a second run takes every SH transfer from the cache.
#[test]
fn sh_settings_are_recorded_reported_and_cached() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(
        &dir.path().join("m.obj"),
        &shapes::merged(&[shapes::grid_plane(8, 6.0), shapes::uv_sphere(Vec3::Y, 1.0, 12, 24)]),
    );
    let cfg = write_config(
        dir.path(),
        "glossy",
        "name = \"glossy\"\n[scene]\nmesh = \"m.obj\"\n[scene.material]\nkind = \"phong\"\nkd = [0.4, 0.35, 0.3]\nks = [0.3, 0.3, 0.3]\nexponent = 30.0\nview_grid = 4\n\
         [lighting]\nconstant = [0.3, 0.35, 0.4]\nsun_boost = 1000.0\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\nlocal_grid = 4\n\
         [[compressors]]\nkind = \"sparse\"\n[[compressors]]\nkind = \"bicluster\"\n\
         [[methods]]\nkind = \"sh\"\norder = [2, 4]\nrays = 256\n\
         [[methods]]\nkind = \"sh\"\norder = 3\nrays = 256\ncompressor = { kind = \"cpca\", clusters = 4, components = 2, unit = \"vertex\" }\n\
         [[methods]]\nkind = \"sh\"\norder = 2\nrays = 256\nbounces = 1\n\
         [runtime]\nwidth = 48\nheight = 36\nrepeats = 1\n[report]\nreference = true\nreference_downscale = 2\n",
    );
    let out = dir.path().join("out");
    let m = run_in(&cfg, &out);
    let names: Vec<&str> = m.methods.iter().map(|r| r.record.name.as_str()).collect();
    assert_eq!(names, ["sh-n2-r256", "sh-n4-r256", "sh-n3-r256-cpca-k4-c2-vertex", "sh-n2-b1-r256"]);
    let n2 = m.methods[0].sh.as_ref().unwrap();
    let n4 = m.methods[1].sh.as_ref().unwrap();
    let cpca = &m.methods[2];
    assert!(
        !n2.diffuse && n2.rays == 256 && n2.compressor == "sparse" && cpca.sh.as_ref().unwrap().compressor == "cpca"
    );
    // Storage and the BTF's projection error follow the order; every record is complete.
    assert!(m.methods[1].record.bytes > m.methods[0].record.bytes);
    assert!(n4.rtt.projection_error < n2.rtt.projection_error && n2.rtt.projection_error < 1.0);
    for r in &m.methods {
        let c = &r.record;
        assert_eq!(c.kind, "sh");
        assert!(c.bytes > 0 && c.gather_ms >= 0.0 && c.shade_ms > 0.0 && c.image.vs_reference.is_some(), "{}", c.name);
        assert!(c.image.vs_uncompressed.rel_l2.is_finite() && c.image.vs_uncompressed.rel_l2 > 0.0);
        let sh = r.sh.as_ref().unwrap();
        assert!(sh.transfer.nnz > 0 && !sh.transfer.cached && sh.light_projection_error > 0.0);
        assert!((0.0..=1.0).contains(&sh.negative_pixels));
        assert!(out.join(&c.image.png).is_file() && out.join(c.image.exr.as_str()).is_file());
    }
    // A bounce off the plane and the sphere adds light: the image's mean grows.
    let mean = |name: &str| {
        let img = HdrImage::read_exr(&out.join(format!("images/{name}.exr"))).unwrap().0;
        img.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>()
    };
    assert_eq!(m.methods[3].sh.as_ref().unwrap().bounces, 1);
    assert!(mean("sh-n2-b1-r256") > mean("sh-n2-r256") * 1.001, "the bounce must add light");
    // CPCA of the vertex matrices is lossy but close to its raw matrices.
    assert!(!cpca.record.lossless && cpca.record.rel_error_lstar > 0.0 && cpca.record.rel_error_lstar < 0.5);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Low- vs all-frequency") && report.contains("low-frequency, sh-n4-r256"));
    assert!(std::fs::read_to_string(out.join("report.html")).unwrap().contains("Low- vs all-frequency"));
    assert!(out.join("image_error_vs_storage.png").is_file());
    let plan = std::fs::read_to_string(out.join("plan.txt")).unwrap();
    assert!(plan.contains("sh-n2-r256: light in order-2 SH") && plan.contains("radiance transfer texture"), "{plan}");
    // The second run reuses every SH transfer and reproduces the records.
    let again = run_in(&cfg, &out);
    for (a, b) in m.methods.iter().zip(&again.methods) {
        assert!(b.sh.as_ref().unwrap().transfer.cached, "{}", b.record.name);
        assert_eq!((a.record.bytes, a.record.rel_error_lstar), (b.record.bytes, b.record.rel_error_lstar));
    }
}

/// Müller et al.'s system: an LPCA BTF lit by SH. Its radiance transfer texture is the LPCA
/// with projected eigen-BRDFs (`biscale_core::sh::rtt::radiance_transfer`), so at full rank
/// (16 units of one cluster span 15 centred directions) the SH image is the dense BTF's to
/// f32 rounding (1e-5: the reconstruction's own error, see the all-frequency LPCA test). The
/// run also shades from per-vertex dot products (the same image to rounding) and with fewer
/// components, whose error vanishes at all of them and grows as they are dropped.
#[test]
fn an_lpca_btf_lit_by_sh_matches_the_dense_one_at_full_rank() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(
        &dir.path().join("m.obj"),
        &shapes::merged(&[shapes::grid_plane(6, 6.0), shapes::uv_sphere(Vec3::Y, 1.0, 10, 20)]),
    );
    let cfg = |name: &str, repr: &str| {
        write_config(
            dir.path(),
            name,
            &format!(
                "name = \"{name}\"\n[scene]\nmesh = \"m.obj\"\n[scene.material]\nkind = \"phong\"\nkd = [0.4, 0.35, 0.3]\nks = [0.3, 0.3, 0.3]\nexponent = 30.0\nview_grid = 4\n{repr}\n\
                 [lighting]\nconstant = [0.3, 0.35, 0.4]\nsun_boost = 1000.0\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\nlocal_grid = 4\n\
                 [[compressors]]\nkind = \"sparse\"\n[[methods]]\nkind = \"sh\"\norder = 3\nrays = 256\n\
                 [[methods]]\nkind = \"sh\"\norder = 3\nrays = 256\ncompressor = {{ kind = \"cpca\", clusters = 4, components = 2, unit = \"vertex\" }}\n\
                 [runtime]\nwidth = 48\nheight = 36\nrepeats = 1\n[report]\nbackground = false\n"
            ),
        )
    };
    let dense_out = dir.path().join("dense");
    let dense = run_in(&cfg("dense", ""), &dense_out);
    assert!(dense.methods[0].sh.as_ref().unwrap().lpca.is_none(), "no LPCA material, no LPCA runtime");
    let lpca_out = dir.path().join("lpca");
    let repr = "representation = { kind = \"lpca\", clusters = 1, components = 15, unit = \"view\" }";
    let m = run_in(&cfg("lpca", repr), &lpca_out);
    let image = |out: &std::path::Path| HdrImage::read_exr(&out.join("images/sh-n3-r256.exr")).unwrap().0;
    let (a, b) = (image(&lpca_out), image(&dense_out));
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.pixels.iter().flatten().zip(b.pixels.iter().flatten()) {
        num += (*x as f64 - *y as f64).powi(2);
        den += (*y as f64).powi(2);
    }
    assert!(den > 0.0 && (num / den).sqrt() < 1e-5, "SH with full-rank LPCA vs dense: {:e}", (num / den).sqrt());
    let sh = m.methods[0].sh.as_ref().unwrap();
    let l = sh.lpca.as_ref().expect("an LPCA material gets the LPCA runtime");
    assert!(l.precomputed.vs_direct < 1e-5 && l.relight_ms >= 0.0, "{:?}", l.precomputed);
    let counts: Vec<usize> = l.adaptive.iter().map(|a| a.components).collect();
    assert_eq!(counts, (1..=15).collect::<Vec<_>>());
    assert_eq!(l.adaptive[14].vs_all_components, 0.0);
    assert!(l.adaptive[0].vs_all_components > 1e-3, "one of 15 components must lose something: {:?}", l.adaptive[0]);
    // Müller's full system: CPCA-compressed SH transfer matrices (the gather of the clustered
    // M_p l) and LPCA BTFs; the dot products are taken with what that gather gives.
    let cpca = m.methods[1].sh.as_ref().unwrap();
    assert_eq!(cpca.compressor, "cpca");
    let l = cpca.lpca.as_ref().expect("the CPCA setting gets the LPCA runtime too");
    assert!(l.precomputed.vs_direct < 1e-5 && l.adaptive.len() == 15, "{:?}", l.precomputed);
}
