//! The low-frequency method on the GPU: the gather of a ray-traced SH transfer and the
//! shading of radiance transfer textures, against the f64 product and the CPU shader.
//!
//! Tolerances. The gather sums a row's `n` signed products `M_ij L_j` in f32: by the standard
//! recursive-summation bound each result is within `gamma_{n+1} sum_j |M_ij L_j|` of the exact
//! value whatever the order (`gamma_k = k u / (1 - k u)`, `u = 2^-24`), which we assert per
//! element. The shading of an RTT is the binned shading's dot product over `n^2` signed
//! coefficients: against the CPU (f64 accumulation) each channel is within
//! `gamma_{n^2+1} sum_i |RTT_i l_i|` plus the f32 barycentric and view-interpolation effects
//! the BTF-shading tests bound at 5e-5 of the pixel's largest value; with signed terms that
//! scale is `sum |RTT_i l_i|`, so we compare relative to it.

use super::gpu_or_skip;
use crate::{GpuGather, GpuShader};
use biscale_compressors::sparse::Sparse;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::reference_product;
use biscale_core::geometry::shapes;
use biscale_core::sampling::{Cubemap, LightVector};
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_core::sh::{light::LIGHT_SUBTEXELS, rtt::radiance_transfer_texture, ShOrder, ShProjection};
use biscale_core::transfer::sh::{build_sh, ShTransferSettings};
use biscale_core::transfer::TransferScene;
use biscale_shading::cpu::shade;
use glam::Vec3;
use rand::{Rng, SeedableRng};

#[test]
fn the_sh_gather_and_rtt_shading_match_the_cpu() {
    let ctx = gpu_or_skip!();
    let mesh = shapes::merged(&[shapes::grid_plane(6, 6.0), shapes::uv_sphere(Vec3::Y, 1.0, 10, 20)]);
    let scene = TransferScene::new(&mesh).unwrap();
    let order = ShOrder::new(5).unwrap();
    let m =
        build_sh(&scene, &ShTransferSettings::new(5, 256, 2).unwrap(), 0..mesh.vertex_count(), None).unwrap().matrix;
    // A sky with a sun: signed SH coefficients of very different sizes.
    let cubemap = Cubemap::new(16);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut l = LightVector::constant(biscale_core::basis::LightBasis::Cubemap(cubemap), [0.3, 0.4, 0.5]);
    for p in l.power.iter_mut() {
        *p = p.map(|x| x * rng.gen_range(0.5..1.5f32));
    }
    l.power[200] = [1e3, 9e2, 8e2];
    let light = ShProjection::new(cubemap, order, LIGHT_SUBTEXELS).project(&l).unwrap();

    // Gather.
    let form = Sparse.compress(&m, &CompressContext::default()).unwrap();
    let mut g = GpuGather::new(ctx, &form, &Sparse.kernels(&form).unwrap()).unwrap();
    g.fill_lstar(f32::NAN).unwrap();
    g.gather(&light).unwrap();
    let got = g.read_lstar().unwrap();
    let exact = reference_product(&m, &light);
    let u = f32::EPSILON as f64 / 2.0;
    for (r, (gv, e)) in got.values().iter().zip(&exact).enumerate() {
        let row = m.csr().outer_view(r).unwrap();
        let gamma = (row.nnz() + 1) as f64 * u / (1.0 - (row.nnz() + 1) as f64 * u);
        for c in 0..3 {
            let abs: f64 = row.iter().map(|(j, &x)| (x as f64 * light.power[j][c] as f64).abs()).sum();
            assert!(
                gv[c].is_finite() && (gv[c] as f64 - e[c]).abs() <= gamma * abs + 1e-30,
                "row {r} channel {c}: {} vs {}",
                gv[c],
                e[c]
            );
        }
    }

    // Shading of the RTT of a glossy table (the view axis interpolates as for bins).
    let bins = biscale_core::basis::LocalBasis::bins(8).unwrap();
    let btf = Btf::phong([0.4, 0.35, 0.3], [0.3, 0.3, 0.3], 16.0, bins, 6).unwrap();
    let (rtt, _) = radiance_transfer_texture(&btf, order).unwrap();
    let sh_scene =
        ShadeScene::new(mesh.clone(), scene.frames().to_vec(), vec![Material::new(rtt.clone())], None).unwrap();
    let cam = Camera::frame_bounds(mesh.bounds().0, mesh.bounds().1, 64, 48, 20.0, 25.0, 40.0);
    let mut shader = GpuShader::new(ctx, &sh_scene, &cam).unwrap();
    let gpu = shader.shade(&g).unwrap();
    let cpu = shade(&sh_scene, &got, &cam).unwrap();
    let n = gpu.image.pixels.len();
    let mismatched = (0..n).filter(|&i| gpu.mask[i] != cpu.mask[i]).count();
    let covered = cpu.mask.iter().filter(|&&c| c).count();
    assert!(covered > 500 && mismatched * 200 <= covered.max(200), "{mismatched} of {covered}");
    // Scale per pixel: sum_i |RTT_i l_i| over the pixel's texel and views is at most, per
    // channel, sum_i max|RTT_i| |l_i| taken at the worst of the hit triangle's vertices.
    let k = order.len();
    let rtt_max: Vec<[f64; 3]> = (0..k)
        .map(|i| {
            let mut mx = [0.0f64; 3];
            for e in rtt.data().chunks(k) {
                for c in 0..3 {
                    mx[c] = mx[c].max(e[i][c].abs() as f64);
                }
            }
            mx
        })
        .collect();
    let vertex_scale: Vec<[f64; 3]> = got
        .values()
        .chunks(k)
        .map(|l| std::array::from_fn(|c| (0..k).map(|i| rtt_max[i][c] * l[i][c].abs() as f64).sum()))
        .collect();
    let gamma = (k + 1) as f64 * u / (1.0 - (k + 1) as f64 * u);
    let (mut worst, mut checked) = (0.0f64, 0usize);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let i = (y * cam.width + x) as usize;
            if !(gpu.mask[i] && cpu.mask[i]) {
                continue;
            }
            let (origin, dir) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let Some(hit) = biscale_shading::cpu::primary_hit(&sh_scene, origin, dir) else { continue };
            for c in 0..3 {
                let scale = hit.vertices.iter().map(|&v| vertex_scale[v as usize][c]).fold(0.0, f64::max);
                let err = (gpu.image.pixels[i][c] as f64 - cpu.image.pixels[i][c] as f64).abs();
                worst = worst.max(err / scale.max(1e-30));
                assert!(
                    err <= (gamma + 5e-5) * scale,
                    "pixel ({x}, {y}) channel {c}: GPU {} vs CPU {} (scale {scale:e})",
                    gpu.image.pixels[i][c],
                    cpu.image.pixels[i][c]
                );
            }
            checked += 1;
        }
    }
    assert!(checked > 500);
    eprintln!("SH on the GPU: {mismatched} coverage mismatches, worst difference {worst:e} of the pixel's scale");
}
