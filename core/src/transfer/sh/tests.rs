//! The SH transfer against exact hemisphere integrals, a closed box, and the transfer matrix
//! `T` it must agree with.

use super::*;
use crate::geometry::shapes::{closed_box, grid_plane, merged, uv_sphere};
use crate::sh::quadrature::sphere_rule;
use crate::transfer::{self, TransferSettings};
use glam::Vec3;

/// Dense `M_p` of vertex `v` from a stacked `M`.
fn block(m: &TransferMatrix, v: usize) -> Vec<f64> {
    let n = m.local_dirs();
    let mut out = vec![0.0; n * n];
    for i in 0..n {
        if let Some(row) = m.csr().outer_view(v * n + i) {
            for (j, &x) in row.iter() {
                out[i * n + j] = x as f64;
            }
        }
    }
    out
}

/// The exact `M_p` of an unoccluded vertex with frame `frame`: `int_H y_i(l) y_j(F l) dl` over
/// the local upper hemisphere, a polynomial of degree `< 16` in `l`, which the 8-node
/// hemisphere product rule integrates exactly.
fn unoccluded(frame: &VertexFrame, order: ShOrder) -> Vec<f64> {
    let n = order.len();
    let mut out = vec![0.0; n * n];
    for (l, w) in sphere_rule(8, true) {
        let (yl, yw) = (eval(order, l), eval(order, to_world(frame, l)));
        for i in 0..n {
            for j in 0..n {
                out[i * n + j] += w * yl[i] * yw[j];
            }
        }
    }
    out
}

fn frobenius(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
}

fn norm(a: &[f64]) -> f64 {
    a.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// A vertex that sees the whole upper hemisphere (the centre of an open plane, and a point
/// on a convex sphere) converges to the exact matrix. Two checks with derived bounds:
/// * the error is within three standard errors of *plain* Monte Carlo on the same samples
///   (`sqrt(Var(f) / S)` per entry, estimated from them); jittered stratification only lowers
///   the variance, so this holds with room to spare;
/// * the integrand is smooth on the hemisphere, so stratified sampling converges faster than
///   `S^-1/2`: quadrupling the rays must more than halve the error.
#[test]
fn an_unoccluded_vertex_converges_to_the_exact_hemisphere_projection() {
    let order = ShOrder::new(5).unwrap();
    let n = order.len();
    for (mesh, v) in [(grid_plane(4, 2.0), 12usize), (uv_sphere(Vec3::ZERO, 1.0, 8, 16), 40)] {
        let scene = TransferScene::new(&mesh).unwrap();
        let frame = scene.frames()[v];
        let exact = unoccluded(&frame, order);
        let err = |rays: u32| {
            let s = ShTransferSettings::new(5, rays, 7).unwrap();
            let m = build_sh(&scene, &s, 0..mesh.vertex_count(), None).unwrap().matrix;
            let e = frobenius(&block(&m, v), &exact);
            // Plain Monte Carlo's standard error on the same strata (no ray hits anything).
            let (mut sum, mut sq) = (vec![0.0; n * n], vec![0.0; n * n]);
            let w = 2.0 * std::f64::consts::PI;
            for st in 0..s.rays() {
                let l = stratum_direction(&s, v, st);
                let (yl, yw) = (eval(order, l), eval(order, to_world(&frame, l)));
                for i in 0..n {
                    for j in 0..n {
                        let f = w * yl[i] * yw[j];
                        sum[i * n + j] += f;
                        sq[i * n + j] += f * f;
                    }
                }
            }
            let k = s.rays() as f64;
            let se2: f64 = sum.iter().zip(&sq).map(|(s1, s2)| (s2 / k - (s1 / k).powi(2)) / k).sum();
            (e, se2.sqrt())
        };
        let ((e256, _), (e1024, se1024), (e4096, _)) = (err(256), err(1024), err(4096));
        assert!(e1024 < e256 / 2.0 && e4096 < e1024 / 2.0, "errors {e256:e} {e1024:e} {e4096:e}");
        assert!(e1024 < 3.0 * se1024, "error {e1024:e} against plain MC's standard error {se1024:e}");
    }
}

#[test]
fn inside_a_closed_box_the_transfer_is_zero_and_bad_ranges_are_errors() {
    let mut mesh = closed_box(Vec3::splat(-1.0), Vec3::splat(1.0));
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
    let scene = TransferScene::new(&mesh).unwrap();
    let s = ShTransferSettings::new(4, 64, 1).unwrap();
    let b = build_sh(&scene, &s, 0..8, None).unwrap();
    assert_eq!((b.matrix.nnz(), b.matrix.rows(), b.matrix.cols(), b.rays_traced), (0, 8 * 16, 16, 8 * 64));
    assert_eq!(b.matrix.local_basis(), LocalBasis::Sh(s.order()));
    assert!(build_sh(&scene, &s, 0..9, None).is_err());
    assert!(ShTransferSettings::new(0, 64, 0).is_err() && ShTransferSettings::new(5, 0, 0).is_err());
    assert!(ShTransferSettings::new(5, 70_000, 0).is_err());
    assert_eq!(ShTransferSettings::new(5, 1000, 0).unwrap().rays(), 32 * 32);
}

#[test]
fn the_transfer_is_deterministic_for_a_seed_and_thread_count() {
    let mesh = merged(&[grid_plane(6, 6.0), uv_sphere(Vec3::Y, 1.0, 8, 16)]);
    let scene = TransferScene::new(&mesh).unwrap();
    let s = ShTransferSettings::new(3, 100, 5).unwrap();
    let a = build_sh(&scene, &s, 0..mesh.vertex_count(), None).unwrap().matrix;
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let b = one.install(|| build_sh(&scene, &s, 0..mesh.vertex_count(), None).unwrap().matrix);
    assert_eq!(a, b);
    let c = build_sh(&scene, &ShTransferSettings::new(3, 100, 6).unwrap(), 0..mesh.vertex_count(), None).unwrap();
    assert_ne!(a, c.matrix, "another seed jitters differently");
}

/// The bridge between the methods: `M` projected from `T` and `M` ray traced are quadratures
/// of the same integral. On a sphere resting on a plane (shadows near the contact), the
/// difference must be the quadrature error of `T`'s side, which falls as its cubemap refines
/// (texel midpoint rule and 2 x 2 box-filtered visibility: first order at the visibility
/// edges): halving the texel size must cut it by a third, and at the reference resolution it
/// must be below 5% of the matrix; the traced side uses 16,384 rays, whose error is an order
/// of magnitude below (see the convergence test above).
#[test]
fn the_transfer_projected_from_t_agrees_with_the_traced_one() {
    let mesh = merged(&[grid_plane(8, 8.0), uv_sphere(Vec3::Y, 1.0, 16, 32)]);
    let scene = TransferScene::new(&mesh).unwrap();
    let order = ShOrder::new(4).unwrap();
    // Plane vertices around the contact point, and sphere vertices near the plane.
    let near: Vec<usize> =
        (0..mesh.vertex_count()).filter(|&v| mesh.positions[v].length() < 2.2 && mesh.positions[v].y < 0.6).collect();
    assert!(near.len() > 10);
    let traced =
        build_sh(&scene, &ShTransferSettings::new(4, 16_384, 3).unwrap(), 0..mesh.vertex_count(), None).unwrap().matrix;
    let diff = |r: u32| {
        let settings = TransferSettings::new(r, 2 * r, 8).unwrap();
        let t = transfer::build(&mesh, &settings, None).unwrap().matrix;
        let from_t = sh_from_transfer(&t, scene.frames(), order).unwrap();
        let (mut num, mut den) = (0.0, 0.0);
        for &v in &near {
            let (a, b) = (block(&from_t, v), block(&traced, v));
            num += frobenius(&a, &b).powi(2);
            den += norm(&b).powi(2);
        }
        (num / den).sqrt()
    };
    let (d16, d32) = (diff(16), diff(32));
    assert!(d32 < d16 * 2.0 / 3.0, "{d16:e} -> {d32:e}");
    assert!(d32 < 0.05, "{d32:e}");
    // Bases are checked.
    assert!(sh_from_transfer(&traced, scene.frames(), order).is_err());
    let t = transfer::build(&mesh, &TransferSettings::new(8, 16, 4).unwrap(), None).unwrap().matrix;
    assert!(sh_from_transfer(&t, &scene.frames()[1..], order).is_err());
}

/// The diffuse reduction `t_p = c^T M_p`: for an unoccluded vertex under a constant sky of
/// radiance 1 (`L_sh = sqrt(4 pi) e_0`) it gives the irradiance of the truncated hemisphere,
/// `E_n = sum_l h_l c_l` with `h` the zonal coefficients of the hemisphere's indicator; here
/// `M_p` is the exact matrix, so the match is to f32 rounding (1e-5 relative).
#[test]
fn the_irradiance_transfer_of_an_open_vertex_is_the_truncated_hemisphere_irradiance() {
    let order = ShOrder::new(5).unwrap();
    let mesh = grid_plane(2, 2.0);
    let scene = TransferScene::new(&mesh).unwrap();
    let blocks: Vec<Vec<f64>> = scene.frames().iter().map(|f| unoccluded(f, order)).collect();
    let m = assemble(order, &blocks).unwrap();
    let t = irradiance_transfer(&m).unwrap();
    assert_eq!((t.local_basis(), t.rows(), t.cols()), (LocalBasis::Irradiance(order), mesh.vertex_count(), 25));
    // E_n by Gauss-Legendre on the zonal profiles: h_l = 2 pi K_l int_0^1 P_l, c_l likewise with mu.
    let (nodes, weights) = crate::sh::quadrature::gauss_legendre(8, 0.0, 1.0);
    let e_n: f64 = (0..5)
        .map(|l| {
            let y = |mu: f64| eval(order, DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu))[crate::sh::index(l, 0)];
            let h: f64 = nodes.iter().zip(&weights).map(|(&mu, w)| 2.0 * std::f64::consts::PI * w * y(mu)).sum();
            let c: f64 = nodes.iter().zip(&weights).map(|(&mu, w)| 2.0 * std::f64::consts::PI * w * mu * y(mu)).sum();
            h * c
        })
        .sum();
    let sqrt4pi = (4.0 * std::f64::consts::PI).sqrt();
    for v in 0..mesh.vertex_count() {
        let e = t.csr().get(v, 0).copied().unwrap_or(0.0) as f64 * sqrt4pi;
        assert!((e - e_n).abs() < 1e-5 * e_n, "vertex {v}: {e} vs {e_n}");
    }
    // In closed form E_n = pi for every n >= 2: h_l = 0 for even l >= 2 (int_0^1 P_l = 0) and
    // c_l = 0 for odd l >= 3, so only bands 0 and 1 contribute, pi / 2 each. The clamped
    // cosine's truncation does not show on an open vertex under a constant sky.
    assert!((e_n - std::f64::consts::PI).abs() < 1e-12, "{e_n}");
    assert!(irradiance_transfer(&t).is_err(), "only an SH transfer reduces");
}

/// A hemispherical bowl of radius 1 (the lower half of the unit sphere, open at y = 0),
/// facing inward: `rings` latitude bands from the rim to the bottom pole, `segments` around.
fn bowl(rings: u32, segments: u32) -> crate::geometry::Mesh {
    use std::f32::consts::PI;
    let mut positions = vec![];
    for r in 0..rings {
        let theta = PI / 2.0 + PI / 2.0 * r as f32 / rings as f32; // from the rim (y = 0) down
        for s in 0..segments {
            let phi = 2.0 * PI * s as f32 / segments as f32;
            positions.push(Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()));
        }
    }
    positions.push(Vec3::new(0.0, -1.0, 0.0));
    let bottom = positions.len() as u32 - 1;
    let at = |r: u32, s: u32| r * segments + s % segments;
    let mut triangles = vec![];
    for r in 0..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (at(r, s), at(r, s + 1), at(r + 1, s), at(r + 1, s + 1));
            // Counter-clockwise seen from inside (from the centre).
            triangles.push([a, d, b]);
            triangles.push([a, c, d]);
        }
    }
    for s in 0..segments {
        triangles.push([at(rings - 1, s), bottom, at(rings - 1, s + 1)]);
    }
    crate::geometry::Mesh { positions, uvs: None, triangles, materials: None }
}

/// Interreflection against a closed form: inside a spherical cavity the form factor from a
/// point to any part of the sphere is that part's area over `4 pi R^2`, whatever the point.
/// A hemispherical bowl of albedo `a` under a constant sky of radiance 1 therefore has a
/// uniform exit radiance: each point sees the sky through the opening with form factor 1/2 and
/// the bowl with 1/2, so `B = (a / 2)(1 + B)` and after `k` bounces `B_k = (a/2) sum_{i<=k} (a/2)^i`.
///
/// Errors, bounded (order n = 6, 1024 rays, the mean over interior vertices):
/// * truncation: the method's irradiance is `<l, P_n c>` instead of `<l, c>`; with the bowl's
///   light `l = B 1_H + (1 - B) 1_S` (`S` the sky directions) and `<1_H, c - P_n c> = 0` it is
///   off by `(1 - B) <1_S - 1_H / 2, d>`, `d = c - P_n c`, at most `(1 - B) sqrt(pi / 2) |d 1_H|`
///   (Cauchy-Schwarz; `|d 1_H|` by exact Gauss-Legendre). Bounces propagate an error `e` of
///   the bowl's radiance as at most `a e int_H |P_n c| / pi`: a geometric series.
/// * Monte Carlo: each vertex's estimate has a standard deviation at most `a 2 pi max|P_n c| / (pi sqrt(S))`
///   (plain Monte Carlo of a function bounded by `max |P_n c|`; stratification only helps); the
///   vertices' jitters are independent, so the mean's is that over `sqrt(vertices)`; 5 of them.
/// * tessellation: the polyhedral bowl's area falls short of the sphere's by about
///   `h^2 / 12` relatively (`h` the angular step), on the form factors alike: 1% of `B` covers it.
#[test]
fn interreflection_in_a_spherical_bowl_matches_the_closed_form() {
    let (rings, segments) = (12u32, 24u32);
    let mesh = bowl(rings, segments);
    let scene = TransferScene::new(&mesh).unwrap();
    let order = ShOrder::new(6).unwrap();
    let settings = ShTransferSettings::new(6, 1024, 9).unwrap();
    let direct = build_sh(&scene, &settings, 0..mesh.vertex_count(), None).unwrap().matrix;
    let a = 0.5f64;
    let albedo = vec![a as f32; mesh.triangles.len()];
    // Interior vertices: not on the rim ring (whose normals and sky view are the mesh's edge).
    let interior: Vec<usize> = (segments as usize..mesh.vertex_count()).collect();
    let c = crate::sh::clamped_cosine(order);
    let exit = |m: &TransferMatrix| -> f64 {
        let t = irradiance_transfer(m).unwrap();
        // L_sh of a constant sky of radiance 1 is sqrt(4 pi) e_0.
        let e = |v: usize| t.csr().get(v, 0).copied().unwrap_or(0.0) as f64 * (4.0 * std::f64::consts::PI).sqrt();
        interior.iter().map(|&v| a / std::f64::consts::PI * e(v)).sum::<f64>() / interior.len() as f64
    };
    // The bound's pieces.
    let (nodes, weights) = crate::sh::quadrature::gauss_legendre(16, 0.0, 1.0);
    let pnc = |mu: f64| -> f64 {
        let y = eval(order, DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu));
        (0..6).map(|l| c[crate::sh::index(l, 0)] * y[crate::sh::index(l, 0)]).sum()
    };
    let d_h = (nodes
        .iter()
        .zip(&weights)
        .map(|(&mu, w)| 2.0 * std::f64::consts::PI * w * (mu - pnc(mu)).powi(2))
        .sum::<f64>())
    .sqrt();
    let abs_pnc =
        nodes.iter().zip(&weights).map(|(&mu, w)| 2.0 * std::f64::consts::PI * w * pnc(mu).abs()).sum::<f64>();
    let max_pnc = (0..=1000).map(|i| pnc(i as f64 / 1000.0).abs()).fold(0.0, f64::max);
    let gain = a * abs_pnc / std::f64::consts::PI;
    assert!(gain < 1.0);
    let mc = 5.0 * a * 2.0 * max_pnc / (settings.rays() as f64).sqrt() / (interior.len() as f64).sqrt();
    let mut previous = 0.0;
    for k in 0..=3u32 {
        let m = add_bounces(&scene, &mesh.triangles, &settings, &direct, &albedo, k).unwrap();
        let want: f64 = (0..=k).map(|i| (a / 2.0).powi(i as i32 + 1)).sum();
        let truncation = a / std::f64::consts::PI * (1.0 - want) * (std::f64::consts::PI / 2.0).sqrt() * d_h;
        let tol = truncation * (1.0 - gain.powi(k as i32 + 1)) / (1.0 - gain) + mc + 0.01 * want;
        let got = exit(&m);
        eprintln!("bowl, {k} bounces: exit radiance {got:.5}, closed form {want:.5}, tolerance {tol:.2e}");
        assert!((got - want).abs() <= tol, "{k} bounces: exit radiance {got}, closed form {want} (tolerance {tol:e})");
        assert!(got > previous, "every bounce adds light");
        previous = got;
    }
    // Zero bounces is the direct transfer itself; sizes and albedos are checked.
    assert_eq!(add_bounces(&scene, &mesh.triangles, &settings, &direct, &albedo, 0).unwrap(), direct);
    assert!(add_bounces(&scene, &mesh.triangles, &settings, &direct, &albedo[1..], 1).is_err());
    assert!(add_bounces(&scene, &mesh.triangles, &settings, &direct, &vec![1.5; mesh.triangles.len()], 1).is_err());
}

/// A convex mesh never sees itself: bounces add nothing.
#[test]
fn a_convex_mesh_gains_nothing_from_bounces() {
    let mesh = uv_sphere(Vec3::ZERO, 1.0, 8, 16);
    let scene = TransferScene::new(&mesh).unwrap();
    let settings = ShTransferSettings::new(4, 256, 1).unwrap();
    let direct = build_sh(&scene, &settings, 0..mesh.vertex_count(), None).unwrap().matrix;
    let albedo = vec![0.9; mesh.triangles.len()];
    assert_eq!(add_bounces(&scene, &mesh.triangles, &settings, &direct, &albedo, 2).unwrap(), direct);
}
