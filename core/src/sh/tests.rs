//! SH basis, quadrature and rotation against closed forms and exact quadrature.

use super::quadrature::{gauss_legendre, sphere_rule};
use super::*;
use glam::DMat3;
use rand::{Rng, SeedableRng};

fn order(n: u32) -> ShOrder {
    ShOrder::new(n).unwrap()
}

/// Every tolerance below is f64 rounding: sums of at most a few thousand terms of size O(1),
/// each with relative error 2^-53, and recurrences of at most 8 steps: 1e-12 absolute leaves
/// a factor of ten to spare.
const EPS: f64 = 1e-12;

#[test]
fn gauss_legendre_integrates_polynomials_exactly() {
    for n in [1usize, 2, 5, 9] {
        let (x, w) = gauss_legendre(n, -1.0, 1.0);
        for p in 0..2 * n {
            let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(p as i32)).sum();
            let want = if p % 2 == 1 { 0.0 } else { 2.0 / (p as f64 + 1.0) };
            assert!((got - want).abs() < EPS, "n {n} p {p}: {got} vs {want}");
        }
        let (x, w) = gauss_legendre(n, 0.0, 1.0);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < EPS);
        assert!(x.iter().all(|&v| (0.0..=1.0).contains(&v)));
    }
}

#[test]
fn orders_are_validated() {
    assert!(ShOrder::new(0).is_err() && ShOrder::new(MAX_SH_ORDER + 1).is_err());
    assert_eq!((order(5).n(), order(5).len()), (5, 25));
}

#[test]
fn the_basis_is_orthonormal_over_the_sphere() {
    let n = order(MAX_SH_ORDER);
    // Products of two band-7 functions are polynomials of degree <= 14 in (x, y, z): a rule
    // exact to degree 15 integrates them exactly.
    let rule = sphere_rule(8, false);
    let mut gram = vec![0.0; n.len() * n.len()];
    let mut y = vec![0.0; n.len()];
    for &(d, w) in &rule {
        eval_into(n, d, &mut y);
        for i in 0..n.len() {
            for j in 0..n.len() {
                gram[i * n.len() + j] += w * y[i] * y[j];
            }
        }
    }
    for i in 0..n.len() {
        for j in 0..n.len() {
            let want = (i == j) as i32 as f64;
            assert!((gram[i * n.len() + j] - want).abs() < EPS, "<y{i}, y{j}> = {}", gram[i * n.len() + j]);
        }
    }
}

#[test]
fn bands_zero_one_and_two_match_their_closed_forms() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let pi = std::f64::consts::PI;
    for _ in 0..50 {
        let d = DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)).normalize();
        let y = eval(order(3), d);
        let (x, yy, z) = (d.x, d.y, d.z);
        let c1 = (3.0 / (4.0 * pi)).sqrt();
        let want = [
            0.5 / pi.sqrt(),
            c1 * yy,
            c1 * z,
            c1 * x,
            0.5 * (15.0 / pi).sqrt() * x * yy,
            0.5 * (15.0 / pi).sqrt() * yy * z,
            0.25 * (5.0 / pi).sqrt() * (3.0 * z * z - 1.0),
            0.5 * (15.0 / pi).sqrt() * x * z,
            0.25 * (15.0 / pi).sqrt() * (x * x - yy * yy),
        ];
        for (i, (a, b)) in y.iter().zip(want).enumerate() {
            assert!((a - b).abs() < EPS, "y{i}({d}) = {a}, closed form {b}");
        }
    }
}

#[test]
fn projection_then_reconstruction_of_a_band_limited_function_is_exact() {
    let n = order(6);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let coeffs: Vec<f64> = (0..n.len()).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let f = |d: DVec3| eval(n, d).iter().zip(&coeffs).map(|(y, c)| y * c).sum::<f64>();
    let rule = sphere_rule(7, false);
    let mut back = vec![0.0; n.len()];
    for &(d, w) in &rule {
        let v = f(d);
        for (b, y) in back.iter_mut().zip(eval(n, d)) {
            *b += w * v * y;
        }
    }
    for (i, (a, b)) in back.iter().zip(&coeffs).enumerate() {
        assert!((a - b).abs() < EPS, "coefficient {i}: {a} vs {b}");
    }
}

#[test]
fn clamped_cosine_matches_ramamoorthi_hanrahan() {
    // A_l of the clamped cosine's convolution (Ramamoorthi and Hanrahan 2001): pi, 2 pi / 3,
    // then 0 for odd l and 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) * l! / (2^l ((l/2)!)^2) for even
    // l; the coefficient of y_l^0 is A_l / sqrt(4 pi / (2l + 1)).
    let pi = std::f64::consts::PI;
    let fact = |k: u32| (1..=k).map(|v| v as f64).product::<f64>();
    let c = clamped_cosine(order(MAX_SH_ORDER));
    for l in 0..MAX_SH_ORDER as i32 {
        let a = match l {
            0 => pi,
            1 => 2.0 * pi / 3.0,
            l if l % 2 == 1 => 0.0,
            l => {
                let lu = l as u32;
                let sign = if (l / 2 - 1) % 2 == 0 { 1.0 } else { -1.0 };
                2.0 * pi * sign / (((l + 2) * (l - 1)) as f64) * fact(lu) / (2f64.powi(l) * fact(lu / 2).powi(2))
            }
        };
        let want = a / (4.0 * pi / (2 * l + 1) as f64).sqrt();
        assert!((c[index(l, 0)] - want).abs() < EPS, "band {l}: {} vs {want}", c[index(l, 0)]);
        for m in (-l..=l).filter(|&m| m != 0) {
            assert_eq!(c[index(l, m)], 0.0);
        }
    }
}

fn random_rotation(rng: &mut impl Rng) -> DMat3 {
    let axis = DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)).normalize();
    DMat3::from_axis_angle(axis, rng.gen_range(-3.0..3.0))
}

fn full(r: &ShRotation) -> Vec<f64> {
    let n = r.order().len();
    (0..n * n).map(|k| r.entry(k / n, k % n)).collect()
}

#[test]
fn rotations_are_orthogonal_and_compose() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let o = order(MAX_SH_ORDER);
    let n = o.len();
    for _ in 0..5 {
        let (a, b) = (random_rotation(&mut rng), random_rotation(&mut rng));
        let (ra, rb, rab) =
            (full(&ShRotation::new(o, a)), full(&ShRotation::new(o, b)), full(&ShRotation::new(o, a * b)));
        for i in 0..n {
            for j in 0..n {
                let rtr: f64 = (0..n).map(|k| ra[k * n + i] * ra[k * n + j]).sum();
                assert!((rtr - (i == j) as i32 as f64).abs() < 1e-11, "R^T R ({i}, {j}) = {rtr}");
                let prod: f64 = (0..n).map(|k| ra[i * n + k] * rb[k * n + j]).sum();
                assert!((prod - rab[i * n + j]).abs() < 1e-11, "R(a) R(b) vs R(ab) at ({i}, {j})");
            }
        }
    }
    // The identity, and a quarter turn about +Y read off band 1: x -> -z, z -> x.
    let id = ShRotation::new(o, DMat3::IDENTITY);
    for i in 0..n {
        assert!((id.entry(i, i) - 1.0).abs() < EPS);
    }
}

#[test]
fn rotating_coefficients_equals_reprojecting_the_rotated_function() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let o = order(MAX_SH_ORDER);
    let rule = sphere_rule(8, false);
    for trial in 0..4 {
        let r = if trial == 0 { DMat3::from_rotation_y(0.7) } else { random_rotation(&mut rng) };
        let f: Vec<f64> = (0..o.len()).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let eval_f = |d: DVec3| eval(o, d).iter().zip(&f).map(|(y, c)| y * c).sum::<f64>();
        // g(w) = f(R^T w), projected exactly (g is band-limited to the same order).
        let mut g = vec![0.0; o.len()];
        for &(d, w) in &rule {
            let v = eval_f(r.transpose() * d);
            for (gi, y) in g.iter_mut().zip(eval(o, d)) {
                *gi += w * v * y;
            }
        }
        let mut rotated = vec![0.0; o.len()];
        ShRotation::new(o, r).apply(&f, &mut rotated);
        for (i, (a, b)) in rotated.iter().zip(&g).enumerate() {
            assert!((a - b).abs() < 1e-11, "trial {trial} coefficient {i}: rotated {a}, re-projected {b}");
        }
    }
    // about_y is the rotation about +Y.
    let a = ShRotation::about_y(o, 0.3);
    assert_eq!(a, ShRotation::new(o, DMat3::from_rotation_y(0.3)));
}

/// A cubemap light is a radiance that is constant over each texel; its exact SH coefficients
/// are the texel integrals of `y_i`, which the projection takes with the midpoint rule on
/// `s x s` sub-texels. The error against a 32 x 32 sub-texel reference must fall at second
/// order (doubling `s` divides it by about 4; we require 3), for a constant sky (whose exact
/// coefficients are known: only the constant one, `sqrt(4 pi)`) and for a random light with a
/// sun, and be within the midpoint rule's error estimate.
#[test]
fn the_light_projection_converges_at_second_order_in_the_sub_texels() {
    use crate::basis::LightBasis;
    use crate::sampling::{Cubemap, LightVector};
    let cubemap = Cubemap::new(8);
    let o = order(5);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let mut random = LightVector::constant(LightBasis::Cubemap(cubemap), [0.0; 3]);
    for p in random.power.iter_mut() {
        *p = [rng.gen_range(0.0..1.0f32); 3];
    }
    random.power[17] = [1e4; 3];
    let constant = LightVector::constant(LightBasis::Cubemap(cubemap), [1.0; 3]);
    let exact_constant = LightVector::constant(LightBasis::Sh(o), [1.0; 3]);
    let reference = ShProjection::new(cubemap, o, 32);
    for (light, exact) in [(&constant, exact_constant), (&random, reference.project(&random).unwrap())] {
        let err = |s: u32| {
            let sh = ShProjection::new(cubemap, o, s).project(light).unwrap();
            sh.power.iter().zip(&exact.power).map(|(a, b)| (a[0] as f64 - b[0] as f64).powi(2)).sum::<f64>().sqrt()
        };
        let scale = exact.power.iter().map(|p| (p[0] as f64).powi(2)).sum::<f64>().sqrt();
        let (e2, e4, e8) = (err(2), err(4), err(8));
        assert!(e4 < e2 / 3.0 && e8 < e4 / 3.0, "errors {e2:e} {e4:e} {e8:e}");
        // Midpoint rule on a sub-texel of angular width h: relative error about h^2 / 24 times
        // the second derivatives, which for band l are at most l (l + 1) times the function
        // (the sphere Laplacian's eigenvalue). The widest sub-texel, at a face centre, spans
        // h = 2 / (R s) radians; l = 4.
        let h = 2.0 / (8.0 * 4.0);
        assert!(e4 < h * h / 24.0 * 20.0 * scale, "{e4:e} against {scale}");
    }
    // The constant coefficient of a constant sky is exact to f32 rounding at any s.
    let sh = ShProjection::new(cubemap, o, 1).project(&constant).unwrap();
    let c0 = (4.0 * std::f64::consts::PI).sqrt();
    assert!((sh.power[0][0] as f64 - c0).abs() < 1e-5 * c0);
    // Reconstruction inverts projection on band-limited lights: a light built as the texel
    // integrals of a band-limited radiance projects back to nearly its coefficients (the only
    // loss is treating it as constant per texel, second order in the texel size), and its
    // projection error is correspondingly small; a sun is not band-limited.
    let p = ShProjection::new(Cubemap::new(32), o, light::LIGHT_SUBTEXELS);
    let c: Vec<[f32; 3]> = (0..o.len()).map(|_| [rng.gen_range(-1.0..1.0f32); 3]).collect();
    let band = p.reconstruct(&LightVector::new(LightBasis::Sh(o), c).unwrap()).unwrap();
    // Same estimate as above with the texel itself as the cell: h = 2 / 32, l = 4.
    let h = 2.0 / 32.0;
    let e = p.projection_error(&band).unwrap();
    assert!(e < h * h / 24.0 * 20.0, "{e:e}");
    let mut sun = band.clone();
    sun.power[100] = [1e3; 3];
    assert!(p.projection_error(&sun).unwrap() > 0.5);
    // Bases are checked.
    assert!(p.project(&p.project(&band).unwrap()).is_err());
    assert!(p.reconstruct(&band).is_err());
}

#[test]
fn rotating_a_projected_light_matches_projecting_the_rotated_environment() {
    use crate::sampling::{Cubemap, EnvMap, LightVector};
    // A smooth sky (a broad lobe), so the cubemap discretisation error is small against the
    // difference a wrong rotation would make.
    let (w, h) = (256usize, 128usize);
    let mut env = EnvMap::constant(w, h, [0.0; 3]);
    for y in 0..h {
        for x in 0..w {
            let d =
                crate::sampling::envmap::latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            let v = (1.0 + d.dot(DVec3::new(0.6, 0.5, 0.2).normalize())).powi(2) as f32;
            env.pixels[y * w + x] = [v, 0.5 * v, 0.25 * v];
        }
    }
    let cubemap = Cubemap::new(16);
    let o = order(4);
    let p = ShProjection::new(cubemap, o, light::LIGHT_SUBTEXELS);
    let angle = 1.1;
    let rotated_env = p.project(&LightVector::from_env(&env, cubemap, angle)).unwrap();
    let rotated_sh = p
        .project(&LightVector::from_env(&env, cubemap, 0.0))
        .unwrap()
        .rotated_sh(&ShRotation::about_y(o, angle))
        .unwrap();
    let unrotated = p.project(&LightVector::from_env(&env, cubemap, 0.0)).unwrap();
    let diff = |a: &LightVector, b: &LightVector| {
        a.power.iter().zip(&b.power).map(|(x, y)| (x[0] as f64 - y[0] as f64).powi(2)).sum::<f64>().sqrt()
    };
    let scale = diff(&unrotated, &LightVector::constant(crate::basis::LightBasis::Sh(o), [0.0; 3]));
    assert!(diff(&rotated_env, &rotated_sh) < 1e-3 * scale, "{} vs scale {scale}", diff(&rotated_env, &rotated_sh));
    assert!(diff(&rotated_env, &unrotated) > 0.1 * scale, "the rotation must matter for the test to mean anything");
}

#[test]
fn bin_integrals_sum_to_the_hemisphere_integral_and_converge() {
    use crate::sampling::HemisphereGrid;
    let o = order(5);
    let grid = HemisphereGrid::new(8);
    let mut exact = vec![0.0; o.len()];
    for (d, w) in sphere_rule(8, true) {
        for (e, y) in exact.iter_mut().zip(eval(o, d)) {
            *e += w * y;
        }
    }
    let sums = |s: u32| {
        let y = rtt::bin_integrals(grid, o, s);
        (0..o.len()).map(|i| (0..grid.len()).map(|j| y[j * o.len() + i]).sum::<f64>()).collect::<Vec<f64>>()
    };
    let err = |s: u32| sums(s).iter().zip(&exact).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
    let (e2, e4, e8) = (err(2), err(4), err(8));
    // Midpoint rule: second order, but the concentric map is only piecewise smooth (its
    // diagonals), which can cost a little of the order: require a factor 2.5 per doubling.
    assert!(e4 < e2 / 2.5 && e8 < e4 / 2.5, "{e2:e} {e4:e} {e8:e}");
    // The constant band is exact: every cell has the same solid angle.
    let y = rtt::bin_integrals(grid, o, 3);
    let y0 = 0.5 / std::f64::consts::PI.sqrt();
    for j in 0..grid.len() {
        assert!((y[j * o.len()] - y0 * grid.bin_solid_angle()).abs() < EPS);
    }
}

#[test]
fn the_rtt_shades_band_limited_light_exactly_as_the_bins_do() {
    use crate::basis::LocalBasis;
    use crate::scene::Btf;
    let o = order(4);
    let bins = LocalBasis::bins(8).unwrap();
    let btf = Btf::phong([0.4, 0.3, 0.2], [0.3, 0.3, 0.3], 20.0, bins, 4).unwrap();
    let (rtt, report) = rtt::radiance_transfer_texture(&btf, o).unwrap();
    assert_eq!(
        (rtt.local_basis(), rtt.view_grid(), rtt.spatial()),
        (LocalBasis::Sh(o), btf.view_grid(), btf.spatial())
    );
    // Local light l (SH), its bin powers L*_j = sum_i l_i Y_ji: the two shadings agree to f32
    // rounding of the tables (each entry 2^-24 relative; sums of 64 or 16 terms).
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let l: Vec<f64> = (0..o.len()).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let y = rtt::bin_integrals(bins.grid().unwrap(), o, rtt::BIN_CELLS);
    let lstar: Vec<f64> = (0..64).map(|j| (0..o.len()).map(|i| l[i] * y[j * o.len() + i]).sum()).collect();
    for v in 0..btf.view_count() {
        let b = &btf.data()[v * 64..(v + 1) * 64];
        let r = &rtt.data()[v * o.len()..(v + 1) * o.len()];
        for c in 0..3 {
            let binned: f64 = b.iter().zip(&lstar).map(|(b, l)| b[c] as f64 * l).sum();
            let sh: f64 = r.iter().zip(&l).map(|(r, l)| r[c] as f64 * l).sum();
            let scale: f64 = b.iter().zip(&lstar).map(|(b, l)| (b[c] as f64 * l).abs()).sum();
            assert!((binned - sh).abs() <= 1e-6 * scale, "view {v} channel {c}: {binned} vs {sh}");
        }
    }
    assert!(report.quadrature_error < 1e-2, "{report:?}");
    // A Lambertian table keeps nearly all of its light dependence (the cosine is smooth); a
    // glossy lobe loses much of it at low order, less as the order grows.
    let lam = Btf::lambertian([0.5; 3], bins).unwrap();
    let e_lam = rtt::radiance_transfer_texture(&lam, order(4)).unwrap().1.projection_error;
    let e = |n: u32| rtt::radiance_transfer_texture(&btf, order(n)).unwrap().1.projection_error;
    assert!(e_lam < 0.2 && e(2) > e(4) && e(4) > e(8) && e(2) > e_lam, "{e_lam} {} {} {}", e(2), e(4), e(8));
    // The constant band of a Lambertian RTT is exact: albedo * y_0 (sum_j cosbar_j omega = pi).
    let lam_rtt = rtt::radiance_transfer_texture(&lam, o).unwrap().0;
    assert!((lam_rtt.data()[0][0] as f64 - 0.5 * 0.5 / std::f64::consts::PI.sqrt()).abs() < 1e-6);
    assert!(rtt::radiance_transfer_texture(&lam_rtt, o).is_err(), "an RTT is not projected again");
}

#[test]
fn lambertian_tables_reduce_to_one_value_per_texel_and_others_do_not() {
    use crate::basis::LocalBasis;
    use crate::scene::Btf;
    let bins = LocalBasis::bins(8).unwrap();
    let lam = Btf::lambertian([0.8, 0.5, 0.2], bins).unwrap();
    let albedo = rtt::lambertian_albedo(&lam).unwrap();
    // sum_j cosbar_j omega = pi exactly, so the albedo comes back to f32 rounding.
    for (a, b) in albedo[0].iter().zip([0.8f32, 0.5, 0.2]) {
        assert!((a - b).abs() < 1e-5, "{albedo:?}");
    }
    let irr = rtt::irradiance_btf(&lam, order(5)).unwrap().unwrap();
    assert_eq!((irr.local_basis(), irr.light_count(), irr.view_grid()), (LocalBasis::Irradiance(order(5)), 1, None));
    assert!((irr.data()[0][0] - 0.8 / std::f32::consts::PI).abs() < 1e-6);
    // A textured Lambertian table (two texels of different albedo) is Lambertian too.
    let mut data = lam.data().to_vec();
    data.extend(lam.data().iter().map(|v| v.map(|x| x * 0.5)));
    let textured = Btf::new([2, 1], bins, None, data, "textured").unwrap();
    assert_eq!(rtt::lambertian_albedo(&textured).unwrap().len(), 2);
    // A glossy or a view-dependent table is not; neither is an RTT.
    let phong = Btf::phong([0.4; 3], [0.3; 3], 20.0, bins, 3).unwrap();
    assert!(rtt::lambertian_albedo(&phong).is_none() && rtt::irradiance_btf(&phong, order(5)).unwrap().is_none());
    let mut bent = lam.data().to_vec();
    bent[5][1] *= 1.5;
    assert!(rtt::lambertian_albedo(&Btf::new([1, 1], bins, None, bent, "bent").unwrap()).is_none());
}

#[test]
fn the_rtt_of_an_lpca_btf_is_the_rtt_of_its_table() {
    use crate::basis::LocalBasis;
    use crate::scene::{Btf, BtfRepresentation, LpcaBtf, LpcaSettings};
    // A textured Phong patch: 6 texels, each the Phong table times a random factor plus
    // random noise, so the LPCA below is lossy and has signed eigen-BRDFs.
    let bins = LocalBasis::bins(4).unwrap();
    let base = Btf::phong([0.4, 0.3, 0.2], [0.3, 0.3, 0.3], 20.0, bins, 3).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let data = (0..6)
        .flat_map(|_| {
            let s: f32 = rng.gen_range(0.3..1.0);
            base.data().iter().map(|v| v.map(|x| x * s + 0.05 * rng.gen_range(0.0..1.0f32))).collect::<Vec<_>>()
        })
        .collect();
    let btf = Btf::new([3, 2], bins, base.view_grid(), data, "patch").unwrap();
    let o = order(4);
    for settings in [LpcaSettings::new(2, 2), LpcaSettings::new(3, 2).per_view()] {
        let (l, _) = LpcaBtf::compress(&btf, &settings, 1).unwrap();
        let (rtt, report) = rtt::radiance_transfer(&BtfRepresentation::Lpca(l.clone()), o).unwrap();
        let BtfRepresentation::Lpca(rl) = &rtt else { panic!("the RTT of an LPCA BTF is an LPCA BTF") };
        assert_eq!(
            (rl.clusters(), rl.components(), rl.local_basis()),
            (l.clusters(), l.components(), LocalBasis::Sh(o))
        );
        // Projection is linear: projecting the eigen-BRDFs and reconstructing equals
        // reconstructing and projecting, up to f32 rounding of both orders (each value a sum of
        // C + 1 reconstructed terms and 16 projected ones: ~20 u of the absolute terms, which
        // are within a few times the value here).
        let (want, want_report) = rtt::radiance_transfer_texture(&l.decode().unwrap(), o).unwrap();
        let got = rtt.to_dense().unwrap();
        let scale = want.data().iter().flatten().fold(0.0f32, |a, &b| a.max(b.abs())) as f64;
        for (a, b) in got.data().iter().flatten().zip(want.data().iter().flatten()) {
            assert!((*a as f64 - *b as f64).abs() <= 1e-5 * scale, "{a} vs {b}");
        }
        assert!((report.projection_error - want_report.projection_error).abs() < 1e-6, "{report:?} {want_report:?}");
    }
}
