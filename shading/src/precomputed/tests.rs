//! The two LPCA shading paths (direct evaluation, precomputed dot products) against an f64
//! evaluation of the LPCA arrays written out here, on random BTFs and random `L*`, with and
//! without stiff (sun-like) `L*`; full rank against the dense table; the memory refusal.

use super::*;
use crate::cpu::{interpolate_lstar, primary_hit, shade};
use biscale_core::basis::LocalBasis;
use biscale_core::geometry::{shapes, vertex_frames, Mesh};
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::btf::{texel_of, view_weights};
use biscale_core::scene::{Btf, LpcaSettings, Material};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const U: f64 = f32::EPSILON as f64 / 2.0;

/// A `w x h` BTF of random non-negative values (4x4 lights, `view_m^2` views).
fn random_btf(w: u32, h: u32, view_m: u32, seed: u64) -> Btf {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let grid = HemisphereGrid::new(view_m);
    let n = (w * h) as usize * grid.len() * 16;
    let data = (0..n).map(|_| std::array::from_fn(|_| rng.gen_range(0.0..1.0f32))).collect();
    Btf::new([w, h], LocalBasis::bins(4).unwrap(), Some(grid), data, "random").unwrap()
}

/// Random positive `L*`; `stiff` puts a sun 1e5 times the sky into one bin at every vertex.
fn random_lstar(vertices: usize, stiff: bool, seed: u64) -> LocalRadiance {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let values = (0..vertices * 16)
        .map(|i| {
            let sun = if stiff && i % 16 == 5 { 1e5 } else { 1.0 };
            std::array::from_fn(|_| sun * rng.gen_range(0.0..1.0f32))
        })
        .collect();
    LocalRadiance::new(LocalBasis::bins(4).unwrap(), vertices, values).unwrap()
}

fn sphere_scene(materials: Vec<Material>, ids: Option<Vec<u32>>) -> (ShadeScene, Mesh) {
    let mesh = shapes::cylindrical_uvs(&shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 24));
    let (frames, _) = vertex_frames(&mesh);
    (ShadeScene::new(mesh.clone(), frames, materials, ids).unwrap(), mesh)
}

fn camera() -> Camera {
    Camera::frame_bounds(Vec3::splat(-1.0), Vec3::ONE, 48, 40, 30.0, 20.0, 40.0)
}

/// `B` at `p` in f64 straight from the LPCA arrays, and the sum of the absolute values of its
/// terms (the scale of every rounding error).
fn reference(l: &LpcaBtf, tiling: f32, p: &SurfacePoint, lstar: &LocalRadiance) -> ([f64; 3], [f64; 3]) {
    let texel = texel_of(l.spatial(), p.uv * tiling);
    let (mut b, mut abs) = ([0.0f64; 3], [0.0f64; 3]);
    for (view, wv) in view_weights(l.view_grid(), p.view_local) {
        let (unit, seg) = l.unit_of(texel, view);
        let Some(k) = l.cluster_of(unit) else { continue };
        for c in 0..=l.components() {
            let a = if c == 0 { 1.0 } else { l.unit_weights(unit)[c - 1] as f64 };
            for (&v, &beta) in p.vertices.iter().zip(&p.weights) {
                for (e, lj) in l.segment(k, c, seg).chunks_exact(3).zip(lstar.vertex(v as usize)) {
                    for ch in 0..3 {
                        let t = wv as f64 * a * beta as f64 * e[ch] as f64 * lj[ch] as f64;
                        b[ch] += t;
                        abs[ch] += t.abs();
                    }
                }
            }
        }
    }
    (b, abs)
}

#[test]
fn direct_and_precomputed_lpca_shading_match_an_f64_evaluation() {
    let btf = random_btf(4, 3, 3, 1);
    for settings in [LpcaSettings::new(3, 2), LpcaSettings::new(4, 3).per_view()] {
        let (l, _) = LpcaBtf::compress(&btf, &settings, 2).unwrap();
        let material = Material { btf: l.clone().into(), tiling: 2.0 };
        let (scene, mesh) = sphere_scene(vec![material], None);
        for stiff in [false, true] {
            let lstar = random_lstar(mesh.vertex_count(), stiff, 3);
            let dots = LightDots::new(&scene, &lstar, u64::MAX).unwrap();
            assert_eq!(dots.bytes(), LightDots::bytes_needed(&scene));
            let cam = camera();
            let (mut acc, mut scratch) = (vec![[0.0f64; 3]; 16], vec![[0.0f32; 3]; 16]);
            // Direct: each b_j is a sum of 4 (C + 1) f32 products, rounded at every step
            // ((4 (C + 1) + 1) u of its absolute terms), then dotted with L* in f64. Precomputed:
            // each stored dot product is rounded once to f32 (u of its absolute terms). Both
            // bounds are below (4 (C + 1) + 4) u of the sum of absolute terms.
            let gamma = (4 * (l.components() + 1) + 4) as f64 * U;
            let mut checked = 0;
            for y in 0..cam.height {
                for x in 0..cam.width {
                    let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
                    let Some(p) = primary_hit(&scene, o, d) else { continue };
                    let (want, abs) = reference(&l, 2.0, &p, &lstar);
                    interpolate_lstar(&p, &lstar, &mut acc);
                    let direct = shade_point(&scene.materials()[0], p.uv, p.view_local, &acc, &mut scratch);
                    let pre = dots.shade_point(&scene, 0, &p).unwrap();
                    for ch in 0..3 {
                        let tol = gamma * abs[ch] + 1e-30;
                        assert!((direct[ch] as f64 - want[ch]).abs() <= tol, "direct {direct:?} vs {want:?}");
                        assert!((pre[ch] as f64 - want[ch]).abs() <= tol, "precomputed {pre:?} vs {want:?}");
                    }
                    checked += 1;
                }
            }
            assert!(checked > 300, "{checked}");
            // And the images: the same coverage, each pixel as above.
            let a = shade(&scene, &lstar, &cam).unwrap();
            let b = shade_precomputed(&scene, &dots, &lstar, &cam).unwrap();
            assert_eq!(a.mask, b.mask);
        }
    }
}

#[test]
fn full_rank_lpca_shades_the_dense_image_and_mixed_scenes_keep_dense_materials() {
    // 12 texels: per view a unit has 48 values; 48 components keep everything, so the LPCA
    // image is the dense one up to f32 rounding of the reconstruction (relative ~1e-6).
    let btf = random_btf(4, 3, 3, 4);
    let (l, report) = LpcaBtf::compress(&btf, &LpcaSettings::new(2, 48).per_view(), 5).unwrap();
    assert!(report.relative_rms_error < 1e-5, "{report:?}");
    let lam = Btf::lambertian([0.6, 0.5, 0.4], LocalBasis::bins(4).unwrap()).unwrap();
    let mesh = shapes::cylindrical_uvs(&shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 24));
    let ids: Vec<u32> = (0..mesh.triangle_count() as u32).map(|t| t % 2).collect();
    let dense = vec![Material::new(btf.clone()), Material::new(lam.clone())];
    let lpca = vec![Material::new(l), Material::new(lam)];
    let (dense_scene, _) = sphere_scene(dense, Some(ids.clone()));
    let (lpca_scene, _) = sphere_scene(lpca, Some(ids));
    let lstar = random_lstar(mesh.vertex_count(), true, 6);
    let cam = camera();
    let want = shade(&dense_scene, &lstar, &cam).unwrap();
    let direct = shade(&lpca_scene, &lstar, &cam).unwrap();
    let dots = LightDots::new(&lpca_scene, &lstar, u64::MAX).unwrap();
    let pre = shade_precomputed(&lpca_scene, &dots, &lstar, &cam).unwrap();
    let covered = want.mask.iter().filter(|&&m| m).count();
    assert!(covered > 300, "{covered}");
    for (img, what) in [(&direct, "direct"), (&pre, "precomputed")] {
        assert_eq!(img.mask, want.mask, "{what}");
        let err = crate::image::compare(&img.image, &want.image, Some(&want.mask)).unwrap().rel_l2;
        // The reconstruction's own error (< 1e-5, above) bounds the image's.
        assert!(err < 1e-5, "{what}: {err:e}");
    }
}

#[test]
fn precomputed_tables_over_the_limit_are_refused_with_the_estimate() {
    let btf = random_btf(4, 3, 3, 7);
    let (l, _) = LpcaBtf::compress(&btf, &LpcaSettings::new(3, 2), 8).unwrap();
    let (scene, mesh) = sphere_scene(vec![Material::new(l)], None);
    let need = LightDots::bytes_needed(&scene);
    // Every vertex: 3 clusters x 3 vectors x 9 views x 12 bytes, plus the row index.
    assert_eq!(need, (mesh.vertex_count() * (3 * 3 * 9 * 12 + 4)) as u64);
    let e = LightDots::new(&scene, &random_lstar(mesh.vertex_count(), false, 1), need - 1).unwrap_err().to_string();
    assert!(e.contains("MB") && e.contains("3 clusters x 3 vectors x 9 segment(s)"), "{e}");
}
