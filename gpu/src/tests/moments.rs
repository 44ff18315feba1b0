//! The GPU light-moments resolve (`moments/resolve.wgsl`) against the CPU's
//! [`biscale_core::gather::moments::resolve`], alone on the same inputs and end to end after
//! the GPU gathers of real compressed forms ([`gather_with_moments`] on the CPU).
//!
//! # Tolerance
//!
//! Every element of `L*'` is checked against a bound [`resolve_bound`] computes in f64 from the
//! inputs: the sum of each side's bound on its distance from the *exact* resolve of the same
//! f32 moments (so it holds whether the CPU resolves in f64 or, as a faster `resolve` may, in
//! f32 with the same operations). Per side, with `u = 2^-24` and Vulkan's precisions (`+ - *`
//! correctly rounded, division 2.5 ulp, `sqrt` 4.5 ulp as `1 / inversesqrt`; an ulp is `2u`
//! relative), per vertex and bin `j`, with the exact `D_c` and `p_c = n . D_c`:
//!
//! * **power**: a 3-term f32 dot is within `gamma_3 < 4u` of `P_c = sum_a |n_a D_ca|`.
//! * **direction**: `G = sum_c Y_c D_c` in f32 is within `5u |H|` (`H = sum_c Y_c |D_c|`; an
//!   f64 `G` rounded to f32, `u |G|`), and its frame coordinates in f32 add `3u |G|` each,
//!   `5.2u |G|` for the vector: the local direction is off by at most `11u |H|`, an angle
//!   `theta = 11u |H| / |G|`.
//! * **map**: the square point `(a, b)` of a direction moves by at most `L theta`: above the
//!   horizon `dr/dtheta <= 1/sqrt 2` and `db/dphi = 4r/pi` with `r / sin(theta) <= 1`, so
//!   `L = 2`; below it `r = 1` and the azimuth moves by `theta / rho` (`rho` the sine of the
//!   polar angle), `L = 2 + (4/pi) / rho`. Evaluating `(a, b)` in f32 costs at most `40u` (the
//!   radius `24u` through two square roots and a division; the polynomial `atan` `2.5u`, `1.7u`
//!   from its reduction's division, `5u` from the ratio's; `4/pi` and two products). The grid
//!   coordinate `x = m (a + 1) / 2 - 0.5` then moves by `dx = (m / 2)(L theta + 40u) + 4 m u`
//!   (its own roundings, or an f64 side's cast to f32).
//! * **weights**: bilinear weights are continuous (a coordinate that rounds across a bin
//!   boundary moves a weight that is within `dx` of 0), so each moves by at most `2 dx + 3u`
//!   (`1 - f` and the product), and only bins within `1 + dx` of the exact coordinates get any
//!   weight. Where `dx` is not small (a cancelling or tiny luminance direction), every bin may
//!   get up to all of the power.
//! * **sum**: bin `i`'s `n_i` terms are summed in f32 (`(n_i + 1) u` of the sum of their
//!   magnitudes), then multiplied by the f32 `1 / cosbar_i` and rounded to f32: `3u |L*'_i|`.
//!
//! End to end, the gathered moments the two sides resolve differ too: each side's f32 gather
//! is within the bound of the gather tests (`tests/gather.rs`, with `|L|` for the signed moment
//! lights) of the exact product, so the GPU's inputs are within twice that, `delta`, of the
//! CPU's; on the GPU's side it adds `|n| . delta_c` to the power's error and
//! `|sum_c Y_c delta_c|` to the direction's.

use super::gather::{cpca_bound, haar_bound, upload};
use super::gpu_or_skip;
use crate::{GpuError, GpuGather, GpuMoments, TimingMethod};
use biscale_compressors::bicluster::{Bicluster, BiclusterView};
use biscale_compressors::cpca::Cpca;
use biscale_compressors::haar::{Haar, HaarWeighting};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{bins, cubemap, random_light, random_transfer};
use biscale_core::basis::LocalBasis;
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::gather::moments::{gather_with_moments, resolve, LightMoments, Lobe, LUMINANCE};
use biscale_core::gather::{reference_product, LocalRadiance};
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::hemisphere::hemisphere_to_square;
use biscale_core::sampling::{HemisphereGrid, LightVector};
use biscale_core::transfer::TransferMatrix;
use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const U: f64 = f32::EPSILON as f64 / 2.0;

/// Random unit normals, half of the frames with a random tangent (`from_normal_tangent`).
fn random_frames(n: usize, rng: &mut ChaCha8Rng) -> Vec<VertexFrame> {
    let mut unit = || loop {
        let d = Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
        if d.length() > 0.1 {
            return d.normalize();
        }
    };
    (0..n)
        .map(|i| {
            if i % 2 == 0 {
                VertexFrame::from_normal(unit())
            } else {
                VertexFrame::from_normal_tangent(unit(), unit())
            }
        })
        .collect()
}

/// World vector of channel `c` of row `r`'s three moments.
fn moment(along: [&LocalRadiance; 3], r: usize, c: usize) -> DVec3 {
    DVec3::new(along[0].values()[r][c] as f64, along[1].values()[r][c] as f64, along[2].values()[r][c] as f64)
}

/// The bound on `|GPU - CPU|` of every element of `L*'` (module doc): each side's bound on its
/// distance from the exact resolve of `along` (the moments the CPU resolved into `cpu`), the
/// GPU's with its inputs up to `delta[a][r][c]` away from them.
fn resolve_bound(
    along: [&LocalRadiance; 3],
    delta: Option<&[Vec<[f64; 3]>; 3]>,
    frames: &[VertexFrame],
    lobe: Lobe,
    cpu: &LocalRadiance,
) -> Vec<[f64; 3]> {
    let gpu = side_bound(along, delta, frames, lobe, cpu);
    let cpu = side_bound(along, None, frames, lobe, cpu);
    gpu.iter().zip(&cpu).map(|(g, c)| std::array::from_fn(|k| g[k] + c[k])).collect()
}

/// One side's bound on its distance from the exact resolve of `along`, with its inputs up to
/// `delta` away from them (module doc).
fn side_bound(
    along: [&LocalRadiance; 3],
    delta: Option<&[Vec<[f64; 3]>; 3]>,
    frames: &[VertexFrame],
    lobe: Lobe,
    cpu: &LocalRadiance,
) -> Vec<[f64; 3]> {
    let grid = along[0].basis().grid().unwrap();
    let (m, bins) = (grid.m as usize, grid.len());
    let inv: Vec<f64> = grid.mean_cosines().iter().map(|c| 1.0 / c).collect();
    let mut out = vec![[0.0f64; 3]; cpu.values().len()];
    for (v, frame) in frames.iter().enumerate() {
        let [t, b, n] = [frame.tangent, frame.bitangent, frame.normal].map(|x| x.as_dvec3());
        let (mut err, mut mag, mut count) = (vec![[0.0f64; 3]; bins], vec![[0.0f64; 3]; bins], vec![0usize; bins]);
        for j in 0..bins {
            let r = v * bins + j;
            let d: [DVec3; 3] = std::array::from_fn(|c| moment(along, r, c));
            let dd: [DVec3; 3] = std::array::from_fn(|c| match delta {
                Some(delta) => DVec3::new(delta[0][r][c], delta[1][r][c], delta[2][r][c]),
                None => DVec3::ZERO,
            });
            let p = d.map(|d| n.dot(d));
            let e_p: [f64; 3] = std::array::from_fn(|c| 4.0 * U * n.abs().dot(d[c].abs()) + n.abs().dot(dd[c]));
            let (targets, e_w): (Vec<usize>, f64) = if lobe == Lobe::BinCentre {
                (vec![j], 0.0)
            } else if m == 1 {
                (vec![0], 0.0)
            } else {
                // The exact local luminance direction and its grid coordinates.
                let g: DVec3 = (0..3).map(|c| LUMINANCE[c] * d[c]).sum();
                let h: DVec3 = (0..3).map(|c| LUMINANCE[c] * d[c].abs()).sum();
                let dg: DVec3 = (0..3).map(|c| LUMINANCE[c] * dd[c]).sum();
                let l = DVec3::new(t.dot(g), b.dot(g), n.dot(g));
                let theta = (11.0 * U * h.length() + dg.length()) / g.length();
                let rho = l.truncate().length() / l.length();
                let lip = 2.0 + if l.z <= 0.0 { 4.0 * std::f64::consts::FRAC_1_PI / rho } else { 0.0 };
                let dx = m as f64 / 2.0 * (lip * theta + 40.0 * U) + 4.0 * m as f64 * U;
                // Not small (or not finite): the weights are not controlled.
                if dx.is_nan() || dx >= 0.25 {
                    ((0..bins).collect(), 1.0)
                } else {
                    let (su, sv) = hemisphere_to_square(l);
                    let coord = |s: f64| (s * m as f64 - 0.5).clamp(0.0, m as f64 - 1.0);
                    let (cx, cy) = (coord(su), coord(sv));
                    let near = |i: usize, c: f64| (i as f64 - c).abs() <= 1.0 + dx;
                    ((0..bins).filter(|&i| near(i % m, cx) && near(i / m, cy)).collect(), 2.0 * dx + 3.0 * U)
                }
            };
            for i in targets {
                count[i] += 1;
                for c in 0..3 {
                    err[i][c] += e_w * p[c].abs() + e_p[c];
                    mag[i][c] += p[c].abs() + e_p[c];
                }
            }
        }
        for i in 0..bins {
            let r = v * bins + i;
            for c in 0..3 {
                out[r][c] = (err[i][c] + (count[i] + 1) as f64 * U * mag[i][c]) * inv[i]
                    + 3.0 * U * (cpu.values()[r][c] as f64).abs();
            }
        }
    }
    out
}

/// Every element of `gpu` is finite and within `bound` of `cpu`; returns the largest
/// `error / bound`.
fn assert_within(what: &str, gpu: &LocalRadiance, cpu: &LocalRadiance, bound: &[[f64; 3]]) -> f64 {
    assert_eq!(gpu.values().len(), cpu.values().len(), "{what}: rows");
    let mut worst = 0.0f64;
    for (r, ((g, e), b)) in gpu.values().iter().zip(cpu.values()).zip(bound).enumerate() {
        for c in 0..3 {
            assert!(g[c].is_finite(), "{what}: row {r} channel {c} not written (or not finite): {}", g[c]);
            let err = (g[c] as f64 - e[c] as f64).abs();
            assert!(
                err <= b[c],
                "{what}: row {r} channel {c}: GPU {} vs CPU {} (error {err:e}, bound {:e})",
                g[c],
                e[c],
                b[c]
            );
            if b[c] > 0.0 {
                worst = worst.max(err / b[c]);
            }
        }
    }
    worst
}

/// `form` resident on the GPU with its compressor's program, ready for light moments with `frames`.
fn moments_on_gpu(
    ctx: &crate::GpuContext,
    c: &dyn Compressor,
    form: &CompressedForm,
    frames: &[VertexFrame],
) -> GpuMoments {
    GpuMoments::new(upload(ctx, c, form), frames).unwrap()
}

/// Resolve `along` on the GPU (after poisoning `L*'` with NaN) and on the CPU, with both lobes,
/// and compare every element.
fn check_resolve(moments: &mut GpuMoments, along: [&LocalRadiance; 3], frames: &[VertexFrame], what: &str) {
    for lobe in [Lobe::MeanDirection, Lobe::BinCentre] {
        moments.fill_lstar(f32::NAN).unwrap();
        moments.resolve(along, lobe).unwrap();
        let gpu = moments.read_lstar().unwrap();
        let cpu = resolve(along, frames, lobe).unwrap();
        let bound = resolve_bound(along, None, frames, lobe, &cpu);
        let worst = assert_within(&format!("{what}, {lobe:?}"), &gpu, &cpu, &bound);
        eprintln!("{what}, {lobe:?}: largest error / bound {worst:.3e}");
    }
}

/// Random moments (every component uniform in [-1, 1], so directions point everywhere, below
/// the horizon too) on grids of side 1 to 16, and a few bins made special: all three moments
/// zero, and powers exactly zero with a non-zero direction (moments in the tangent plane of a
/// +Z normal).
#[test]
fn resolve_matches_the_cpu_on_random_moments_for_grids_1_to_16() {
    let ctx = gpu_or_skip!();
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    for m in [1u32, 2, 5, 8, 16] {
        let vertices = 40;
        let mut frames = random_frames(vertices, &mut rng);
        frames[0] = VertexFrame::from_normal(Vec3::Z);
        let basis = bins(m);
        let rows = vertices * basis.len();
        let mut along: [Vec<[f32; 3]>; 3] =
            std::array::from_fn(|_| (0..rows).map(|_| std::array::from_fn(|_| rng.gen_range(-1.0..1.0))).collect());
        for a in &mut along {
            a[rows - 1] = [0.0; 3];
        }
        // Vertex 0 (normal +Z): bin 0 has no z components, so all three powers are exactly 0.
        along[2][0] = [0.0; 3];
        let along = along.map(|v| LocalRadiance::new(basis, vertices, v).unwrap());
        let t = random_transfer(vertices, m, 2, 0.5, 1);
        let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
        let mut g = moments_on_gpu(ctx, &Sparse, &form, &frames);
        check_resolve(&mut g, [&along[0], &along[1], &along[2]], &frames, &format!("random moments, m = {m}"));
    }
}

/// The moments of a stiff light (one texel 10^6 times the rest, and in the second light one
/// such texel per face) through a random `T`, gathered in f64: the sun's bins carry 10^6
/// times the power of the others, which must still be resolved to f32 accuracy.
#[test]
fn resolve_matches_the_cpu_under_a_stiff_light() {
    let ctx = gpu_or_skip!();
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for m in [4u32, 8, 16] {
        let (vertices, r) = (24, 8);
        let frames = random_frames(vertices, &mut rng);
        let t = random_transfer(vertices, m, r, 0.1, m as u64);
        let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
        let mut g = moments_on_gpu(ctx, &Sparse, &form, &frames);
        let mut light = random_light(r, 2);
        let sun = rng.gen_range(0..light.len());
        light.power[sun] = light.power[sun].map(|x| x * 1e6);
        let mut suns = light.clone();
        for face in 0..6 {
            let k = face * (r * r) as usize + rng.gen_range(0..(r * r) as usize);
            suns.power[k] = [1e6, 8e5, 5e5];
        }
        for (name, light) in [("one sun", &light), ("a sun per face", &suns)] {
            let moments = LightMoments::new(light).unwrap();
            let along = moments.along.clone().map(|l| {
                LocalRadiance::from_f64(LocalBasis::Bins(HemisphereGrid::new(m)), vertices, &reference_product(&t, &l))
                    .unwrap()
            });
            check_resolve(&mut g, [&along[0], &along[1], &along[2]], &frames, &format!("{name}, m = {m}"));
        }
    }
}

/// `|light|`: bounds the magnitudes of a signed moment light's products.
fn abs_light(light: &LightVector) -> LightVector {
    LightVector::new(light.basis(), light.power.iter().map(|p| p.map(f32::abs)).collect()).unwrap()
}

/// How far one side's f32 gather of `light` can be from the exact product, per row and
/// channel (`tests/gather.rs`, with `|L|` for the signed light): sparse `(n + 2) u sum |T L|`;
/// bicluster `u (r_i sum_b |a_b| + sum_b (l_b + 3) A_b)`. The lossy forms (CPCA, Haar) are
/// held to the CPU's gather of the same form, not to `T L`: their whole GPU-to-CPU bound
/// (`tests/gather.rs`) stands for each side's (twice what is needed).
fn gather_error(c: &dyn Compressor, form: &CompressedForm, t: &TransferMatrix, light: &LightVector) -> Vec<[f64; 3]> {
    match form.kind.as_str() {
        "haar" => return haar_bound(form, light, &c.gather(form, light).unwrap()),
        "cpca" => return cpca_bound(form, light, &c.gather(form, light).unwrap()),
        _ => {}
    }
    if form.kind == "sparse" {
        let a = reference_product(t, &abs_light(light));
        return (0..t.rows())
            .map(|r| {
                let n = t.csr().outer_view(r).unwrap().nnz() as f64;
                a[r].map(|x| (n + 2.0) * U * x)
            })
            .collect();
    }
    assert_eq!(form.kind, "bicluster");
    let view = BiclusterView::new(form).unwrap();
    let q = view.value_scale as f64;
    let per_bicluster: Vec<([f64; 3], [f64; 3], f64)> = (0..view.biclusters())
        .map(|b| {
            let (ks, ts) = view.bicluster(b);
            let (mut a, mut abs) = ([0.0f64; 3], [0.0f64; 3]);
            for (&k, &code) in ks.iter().zip(ts) {
                for c in 0..3 {
                    let l = light.power[k as usize][c] as f64 / q;
                    a[c] += code as f64 * l;
                    abs[c] += (code as f64 * l).abs();
                }
            }
            (a, abs, ks.len() as f64)
        })
        .collect();
    (0..form.rows())
        .map(|i| {
            let ids: Vec<usize> = view.row_biclusters(i).collect();
            std::array::from_fn(|c| {
                let sum_a: f64 = ids.iter().map(|&b| per_bicluster[b].0[c].abs()).sum();
                let sum_p: f64 = ids.iter().map(|&b| (per_bicluster[b].2 + 3.0) * per_bicluster[b].1[c]).sum();
                U * (ids.len() as f64 * sum_a + sum_p)
            })
        })
        .collect()
}

/// End to end: the three moments gathered on the GPU through every built-in form (sparse and
/// lossless bicluster; CPCA and Haar, lossy, held to the CPU's gather of the same form) and
/// resolved there, against the CPU's `gather_with_moments` of the same
/// form (its own gathers and resolve), with both lobes, a plain and a stiff light (odd seeds
/// of `random_light` put a sun 10^6 times the sky in one texel), grids 4 and 8.
#[test]
fn gather_and_resolve_match_the_cpu_end_to_end() {
    let ctx = gpu_or_skip!();
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let bicluster = Bicluster { block_vertices: 8, ..Bicluster::default() };
    let cpca = Cpca::new(3, 2);
    let haar = Haar { terms: 10, weighting: HaarWeighting::Area, f16_values: true };
    for (m, seed) in [(4u32, 1u64), (8, 2)] {
        let (vertices, r) = (24, 4);
        let t = random_transfer(vertices, m, r, 0.2, seed);
        let frames = random_frames(vertices, &mut rng);
        for c in [&Sparse as &dyn Compressor, &bicluster, &cpca, &haar] {
            let form = c.compress(&t, &CompressContext { seed, progress: None, sweep: None }).unwrap();
            assert_eq!(form.lossless, ["sparse", "bicluster"].contains(&form.kind.as_str()), "{}", form.kind);
            let mut g = moments_on_gpu(ctx, c, &form, &frames);
            for light_seed in [10 + seed, 11 + seed * 2] {
                let light = random_light(r, light_seed);
                for lobe in [Lobe::MeanDirection, Lobe::BinCentre] {
                    let moments = LightMoments::new(&light).unwrap().with_lobe(lobe);
                    g.fill_lstar(f32::NAN).unwrap();
                    g.gather(&moments).unwrap();
                    let gpu = g.read_lstar().unwrap();
                    let cpu = gather_with_moments(c, &form, &moments, &frames).unwrap();
                    let [x, y, z] = &moments.along;
                    let along = c.gather_three(&form, [x, y, z]).unwrap();
                    let delta = moments.along.clone().map(|l| {
                        gather_error(c, &form, &t, &l).into_iter().map(|e| e.map(|x| 2.0 * x)).collect::<Vec<_>>()
                    });
                    let bound = resolve_bound([&along[0], &along[1], &along[2]], Some(&delta), &frames, lobe, &cpu);
                    let what = format!("{} m = {m}, light {light_seed}, {lobe:?}", form.kind);
                    let worst = assert_within(&what, &gpu, &cpu, &bound);
                    eprintln!("{what}: largest error / bound {worst:.3e}");
                }
            }
        }
    }
}

/// The GPU `L*'` shades as the same values uploaded from the host do (the shader reads the
/// resolve's buffer in place), and timing runs all three gathers and the resolve, leaving the
/// same `L*'` behind; with forced timestamps every pass is named.
#[test]
fn resolved_moments_shade_in_place_and_time_every_pass() {
    use crate::{GpuContext, GpuShader, TimestampPolicy};
    use biscale_core::scene::Camera;
    let _ = gpu_or_skip!();
    let always = GpuContext::with_timestamps(TimestampPolicy::Always).unwrap();
    let (scene, nv) = crate::tests::phong_plane();
    let camera = Camera {
        position: Vec3::new(0.3, 1.5, 2.2),
        target: Vec3::ZERO,
        up: Vec3::Y,
        fov_y_degrees: 50.0,
        width: 48,
        height: 40,
        samples_per_pixel: 1,
    };
    let t = random_transfer(nv, 4, 4, 0.3, 8);
    let bicluster = Bicluster { block_vertices: 8, ..Bicluster::default() };
    let form = bicluster.compress(&t, &CompressContext::default()).unwrap();
    let mut g =
        GpuMoments::new(GpuGather::new(&always, &form, &bicluster.kernels(&form).unwrap()).unwrap(), scene.frames())
            .unwrap();
    let moments = LightMoments::new(&random_light(4, 3)).unwrap();
    g.gather(&moments).unwrap();
    let lstar = g.read_lstar().unwrap();
    let mut shader = GpuShader::new(&always, &scene, &camera).unwrap();
    let in_place = shader.shade(&g).unwrap();
    let uploaded = shader.shade_lstar(&lstar).unwrap();
    assert_eq!(in_place.image.pixels, uploaded.image.pixels);
    assert!(in_place.mask.iter().any(|&m| m), "the camera sees the plane");

    let timing = g.time_gather(&moments, 2).unwrap();
    assert_eq!(timing.repetitions, 2);
    assert!(timing.median_ms.is_finite() && timing.median_ms >= 0.0, "{timing:?}");
    if always.has_timestamps() {
        assert_eq!(timing.method, TimingMethod::GpuTimestamps);
        let names: Vec<&str> = timing.passes.iter().map(|p| p.name.as_str()).collect();
        let row = biscale_kernels::ROW_ENTRY;
        let want: Vec<String> = ["x", "y", "z"]
            .iter()
            .flat_map(|a| [format!("{a}: bicluster_sums"), format!("{a}: {row}")])
            .chain(["resolve".to_string()])
            .collect();
        assert_eq!(names, want);
    }
    assert_eq!(g.read_lstar().unwrap(), lstar, "timing leaves the same L*' behind");
}

/// Forms and frames light moments cannot use are errors naming what is wrong.
#[test]
fn moments_refuse_what_they_cannot_resolve() {
    let ctx = gpu_or_skip!();
    let t = random_transfer(3, 2, 1, 0.5, 1);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let frame = VertexFrame::from_normal(Vec3::Y);
    let e = GpuMoments::new(upload(ctx, &Sparse, &form), &[frame; 2]).err().expect("2 frames for 3 vertices");
    assert!(matches!(&e, GpuError::Input(m) if m.contains("2 frames for 3 vertices")), "{e}");
    let mut g = GpuMoments::new(upload(ctx, &Sparse, &form), &[frame; 3]).unwrap();
    // A moment light of the wrong basis, and moments of the wrong shape.
    let moments = LightMoments::new(&random_light(2, 0)).unwrap();
    assert!(matches!(g.gather(&moments), Err(GpuError::Input(_))));
    let other = LocalRadiance::new(bins(2), 2, vec![[0.0; 3]; 8]).unwrap();
    let e = g.resolve([&other, &other, &other], Lobe::MeanDirection).unwrap_err();
    assert!(e.to_string().contains("2 vertices"), "{e}");
    // Local SH has no bins.
    let sh = TransferMatrix::new(LocalBasis::sh(2).unwrap(), cubemap(1), sprs::CsMat::zero((3 * 4, 6))).unwrap();
    let form = Sparse.compress(&sh, &CompressContext::default()).unwrap();
    let e = GpuMoments::new(upload(ctx, &Sparse, &form), &[frame; 3]).err().expect("SH local basis");
    assert!(e.to_string().contains("bins"), "{e}");
}

/// The WGSL `atan_unit` (Cephes' atanf) on the adapter, against f64 `atan`, on a dense sweep of
/// `[-1, 1]` and the edges of its reduction: within `5u` (Cephes' peak relative error 1.9e-7
/// is `2.5u` absolute below `pi / 4`; its reduction's division at Vulkan's 2.5 ulp adds `1.7u`).
#[test]
fn atan_unit_matches_f64() {
    let ctx = gpu_or_skip!();
    let mut t: Vec<f32> = (0..=200_000).map(|i| -1.0 + i as f32 / 100_000.0).collect();
    let edge = std::f32::consts::FRAC_PI_8.tan();
    for x in [
        0.0f32,
        1.0,
        -1.0,
        1e-30,
        -1e-30,
        1e-6,
        edge,
        f32::from_bits(edge.to_bits() + 1),
        f32::from_bits(edge.to_bits() - 1),
    ] {
        t.push(x);
    }
    let source = format!(
        "{}\n@compute @workgroup_size(64)\nfn probe(@builtin(global_invocation_id) id: vec3<u32>) {{\n    \
         if id.x < arrayLength(&moment_x) {{ resolved[id.x] = atan_unit(moment_x[id.x]); }}\n}}\n",
        crate::moments::resolve_wgsl()
    );
    let input = ctx.storage_buffer("atan input", bytemuck::cast_slice(&t), wgpu::BufferUsages::empty()).unwrap();
    let output = ctx
        .storage_buffer("atan output", bytemuck::cast_slice(&vec![f32::NAN; t.len()]), wgpu::BufferUsages::COPY_SRC)
        .unwrap();
    ctx.scoped("probing atan_unit", || {
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("atan probe"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("atan probe"),
            layout: None,
            module: &module,
            entry_point: Some("probe"),
            compilation_options: Default::default(),
            cache: None,
        });
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("atan probe"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 1, resource: input.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: output.as_entire_binding() },
            ],
        });
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        {
            let mut cp = enc.begin_compute_pass(&Default::default());
            cp.set_pipeline(&pipeline);
            cp.set_bind_group(0, &bind_group, &[]);
            cp.dispatch_workgroups((t.len() as u32).div_ceil(64), 1, 1);
        }
        ctx.queue.submit([enc.finish()]);
    })
    .unwrap();
    let got = crate::context::bytes_to_f32(&ctx.read_buffer("atan output", &output, 0, (t.len() * 4) as u64).unwrap());
    let mut worst = 0.0f64;
    for (x, g) in t.iter().zip(&got) {
        let err = (*g as f64 - (*x as f64).atan()).abs();
        assert!(err <= 5.0 * U, "atan_unit({x}) = {g}, f64 {} (error {:.2} u)", (*x as f64).atan(), err / U);
        worst = worst.max(err / U);
    }
    eprintln!("atan_unit: largest error {worst:.2} u");
}
