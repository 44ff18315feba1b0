//! Light moments through every built-in compressor's CPU gather: the three gathers resolved
//! with the vertex normals equal the per-texel f64 product `sum_k T L_k (n . d_k) / cosbar_j`
//! (lossless forms), or the same product over the form's own decoded matrix (lossy ones,
//! whose gather is still linear in the light).

use biscale_compressors::registry;
use biscale_compressors::testing::{random_light, random_transfer};
use biscale_core::compress::CompressContext;
use biscale_core::gather::moments::{exact_moments_product, gather_with_moments, LightMoments};
use biscale_core::gather::relative_l2_error;
use biscale_core::geometry::VertexFrame;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn every_lossless_compressor_gathers_the_moments_of_the_per_texel_cosine() {
    let vertices = 24;
    let t = random_transfer(vertices, 4, 8, 0.25, 11);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let frames: Vec<VertexFrame> = (0..vertices)
        .map(|_| {
            let d = Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            VertexFrame::from_normal(if d.length() > 0.1 { d.normalize() } else { Vec3::Z })
        })
        .collect();
    let mut checked = vec![];
    // Kinds from outside (plugins, hosted compressors) are checked in their own tests: they
    // need a library or a host.
    let builtin = registry::KINDS.iter().filter(|k| k.role != registry::Role::External).map(|k| k.name);
    for name in builtin {
        let compressor = registry::build(name, &serde_json::json!({})).expect("default parameters build");
        let form = compressor.compress(&t, &CompressContext::default()).expect("compress");
        if !form.lossless {
            continue;
        }
        // Random light, then a sun 1e6 above it (seed parity picks the stiff case).
        for seed in [2, 3] {
            let light = random_light(8, seed);
            let moments = LightMoments::new(&light).unwrap();
            let got = gather_with_moments(compressor.as_ref(), &form, &moments, &frames).expect("gather");
            let exact = exact_moments_product(&t, &light, &frames, moments.lobe).unwrap();
            // Three f32 gathers of rows of up to ~100 terms of either sign (the random T has
            // texels below each horizon), summed in f64: a few hundred ulps of the row's
            // absolute sum at worst; the L2 over all rows is far inside 1e-5.
            let err = relative_l2_error(got.values(), &exact);
            assert!(err < 1e-5, "{name}, light seed {seed}: relative L2 {err:e}");
        }
        checked.push(name);
    }
    for must in ["sparse", "bicluster"] {
        assert!(checked.contains(&must), "{must} was not checked: {checked:?}");
    }
}

/// A fused `gather_three` (biclustering's nine-lane pass) is the three plain gathers bit for
/// bit, on random and stiff light, with one block and with many, lossless and lossy.
#[test]
fn gather_three_is_three_gathers_bit_for_bit() {
    let t = random_transfer(40, 4, 8, 0.3, 21);
    let lights = [random_light(8, 4), random_light(8, 5), random_light(8, 7)];
    for (name, params) in [
        ("bicluster", serde_json::json!({ "block_vertices": 8 })),
        ("bicluster", serde_json::json!({ "block_vertices": 0 })),
        ("bicluster", serde_json::json!({ "error_budget": 0.1 })),
        ("sparse", serde_json::json!({})),
        ("haar", serde_json::json!({ "terms": 6 })),
        ("cpca", serde_json::json!({ "clusters": 4, "components": 3 })),
        ("cpca", serde_json::json!({ "clusters": 3, "components": 2, "unit": "vertex" })),
    ] {
        let c = registry::build(name, &params).unwrap();
        let form = c.compress(&t, &CompressContext::default()).unwrap();
        let fused = c.gather_three(&form, [&lights[0], &lights[1], &lights[2]]).unwrap();
        for (i, l) in lights.iter().enumerate() {
            let one = c.gather(&form, l).unwrap();
            let same =
                one.values().iter().zip(fused[i].values()).all(|(a, b)| a.map(f32::to_bits) == b.map(f32::to_bits));
            assert!(same, "{name} {params}: light {i} differs");
        }
    }
}
