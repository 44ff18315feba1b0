//! The GPU shader against analytic scenes and against the CPU reference shader
//! (`shading::cpu::shade`).

use super::gpu_or_skip;
use crate::{GpuCamera, GpuContext, GpuGather, GpuShader, ShadeInputs, ShadedImage};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::random_transfer;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::{shapes, vertex_frames, Mesh, SceneBvh, VertexFrame};
use biscale_core::sampling::{HemisphereGrid, LightVector};
use biscale_shading::btf::Btf;
use biscale_shading::camera::Camera;
use biscale_shading::cpu::{shade, Background, ShadeScene};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

const U: f64 = f32::EPSILON as f64 / 2.0; // unit roundoff of f32, 2^-24

fn camera(position: Vec3, width: u32, height: u32) -> GpuCamera {
    GpuCamera { position, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0, width, height }
}

fn cpu_camera(c: &GpuCamera) -> Camera {
    Camera {
        position: c.position,
        target: c.target,
        up: c.up,
        fov_y_degrees: c.fov_y_degrees,
        width: c.width,
        height: c.height,
    }
}

/// Shade `mesh` with `frames`, a BTF table and host L* on the GPU.
#[allow(clippy::too_many_arguments)]
fn gpu_shade(
    ctx: &GpuContext,
    mesh: &Mesh,
    frames: &[VertexFrame],
    btf: &Btf,
    lstar: &LocalRadiance,
    cam: GpuCamera,
) -> ShadedImage {
    let normals: Vec<[f32; 3]> = frames.iter().map(|f| f.normal.to_array()).collect();
    let tangents: Vec<[f32; 3]> = frames.iter().map(|f| f.tangent.to_array()).collect();
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let uvs: Option<Vec<[f32; 2]>> = mesh.uvs.as_ref().map(|u| u.iter().map(|p| p.to_array()).collect());
    let inputs = ShadeInputs {
        positions: &positions,
        normals: &normals,
        tangents: &tangents,
        uvs: uvs.as_deref(),
        triangles: &mesh.triangles,
        btf_data: &btf.data,
        btf_spatial: btf.spatial,
        light_m: btf.light_grid.m,
        view_m: btf.view_grid.map(|g| g.m),
        camera: cam,
    };
    let mut shader = GpuShader::new(ctx, &inputs).unwrap();
    shader.shade_lstar(lstar).unwrap()
}

/// The plane `grid_plane(4, 2.0)` ([-1, 1]^2 in XZ, facing +Y) with frame t = +X, n = +Y.
fn plane() -> (Mesh, Vec<VertexFrame>) {
    let mesh = shapes::grid_plane(4, 2.0);
    let frames = vec![VertexFrame::from_normal_tangent(Vec3::Y, Vec3::X); mesh.positions.len()];
    (mesh, frames)
}

/// Where the pixel centre's ray hits the plane y = 0 (CPU, through the CPU camera).
fn plane_hit(cam: &GpuCamera, x: u32, y: u32) -> (Vec3, Vec3) {
    let (o, d) = cpu_camera(cam).ray(x as f32 + 0.5, y as f32 + 0.5);
    let t = -o.y as f64 / d.y as f64;
    ((o.as_dvec3() + d.as_dvec3() * t).as_vec3(), d)
}

/// A BTF table `albedo_texel / pi * cosbar_j * g(view col, view row)` (one texel per albedo).
fn table_btf(
    albedos: &[f32],
    spatial: [u32; 2],
    light_m: u32,
    view_m: Option<u32>,
    g: impl Fn(u32, u32) -> f64,
) -> Btf {
    let lg = HemisphereGrid::new(light_m);
    let vg = view_m.map(HemisphereGrid::new);
    let views = vg.map_or(1, |g| g.len() as u32);
    let mut data = vec![];
    for &a in albedos {
        for v in 0..views {
            let (col, row) = vg.map_or((0, 0), |g| (v % g.m, v / g.m));
            for j in 0..lg.len() as u32 {
                let b = a as f64 / PI * lg.bin_mean_cosine(j) * g(col, row);
                data.push([b as f32; 3]);
            }
        }
    }
    Btf { spatial, light_grid: lg, view_grid: vg, data, name: "test table".into() }
}

#[test]
fn lambertian_plane_under_constant_sky_is_albedo_times_radiance() {
    // Constant sky of radiance Ls, unoccluded: every bin receives L*_j = Ls * 2 pi / M, and
    // B = sum_j (a / pi) cosbar_j Ls 2 pi / M = a Ls (the bin-mean cosines integrate to pi to
    // 1e-12). f32 error: storage of b_j and L*_j, the barycentric and view weights (which sum
    // to 1 within a few ulp) and the M-term sum: about (M + 10) u relative; we allow twice that.
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let radiance = [1.0f32, 2.0, 0.5];
    let albedo = 0.7f32;
    for (light_m, view_m, (w, h)) in [(8, None, (64, 48)), (16, Some(6), (48, 36)), (32, None, (24, 18))] {
        let m = (light_m * light_m) as usize;
        let btf = table_btf(&[albedo], [1, 1], light_m, view_m, |_, _| 1.0);
        let bin = (2.0 * PI / m as f64) as f32;
        let lstar = LocalRadiance {
            vertices: mesh.positions.len(),
            local_dirs: m,
            values: vec![radiance.map(|r| r * bin); mesh.positions.len() * m],
        };
        let cam = camera(Vec3::new(0.3, 1.6, 2.0), w, h);
        let img = gpu_shade(ctx, &mesh, &frames, &btf, &lstar, cam);
        let tol = 2.0 * (m as f64 + 10.0) * U;
        let (mut inside, mut outside) = (0, 0);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let (p, _) = plane_hit(&cam, x, y);
                let edge = p.x.abs().max(p.z.abs());
                if edge < 1.0 - 1e-3 {
                    inside += 1;
                    assert!(img.coverage[i], "M={m}: pixel ({x},{y}) hits the plane at {p} but is not covered");
                    for c in 0..3 {
                        let expect = albedo as f64 * radiance[c] as f64;
                        let got = img.pixels[i][c] as f64;
                        assert!(
                            (got - expect).abs() <= tol * expect,
                            "M={m} ({x},{y}) c{c}: {got} vs {expect} (tol {tol})"
                        );
                    }
                } else if edge > 1.0 + 1e-3 {
                    outside += 1;
                    assert!(!img.coverage[i], "M={m}: pixel ({x},{y}) misses the plane but is covered");
                    assert_eq!(img.pixels[i], [0.0; 3]);
                }
            }
        }
        assert!(inside > 100 && outside > 50, "camera does not frame the plane: {inside} in, {outside} out");
    }
}

#[test]
fn plane_with_linear_lstar_texels_and_view_dependence_matches_the_analytic_model() {
    // L*_v = (1 + x_v / 2) * rgb * 2 pi / M is linear in position, so barycentric interpolation
    // reproduces (1 + P.x / 2) at the pixel's hit point P exactly. The BTF is
    // a_texel / pi * cosbar_j * (1 + col + 2 row) over the 6x6 view grid, linear in the view
    // sample's (col, row), so bilinear view interpolation gives (1 + x + 2 y) at the
    // continuous coordinates (x, y) of the local view direction (core's continuous_coords).
    // Expected: a_texel * rgb * (1 + P.x / 2) * (1 + x + 2 y), texel from P's UV on a 2x2 patch.
    // Tolerance: f32 coordinates (x, y) carry ~m * 10 ulp of the trigonometry (~1e-5 absolute
    // for m = 6), so g = 1 + x + 2y is within ~3e-5 relative (g >= 1); sums and weights add
    // ~(M + 10) u. We allow 5e-5 (measured on lavapipe: 2.5e-6).
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let rgb = [1.0f32, 0.5, 0.25];
    let albedos = [0.2f32, 0.4, 0.6, 0.8];
    let (light_m, view_m) = (8u32, 6u32);
    let m = (light_m * light_m) as usize;
    let btf = table_btf(&albedos, [2, 2], light_m, Some(view_m), |c, r| 1.0 + c as f64 + 2.0 * r as f64);
    let bin = (2.0 * PI / m as f64) as f32;
    let mut values = vec![];
    for p in &mesh.positions {
        values.extend(std::iter::repeat_n(rgb.map(|c| c * (1.0 + 0.5 * p.x) * bin), m));
    }
    let lstar = LocalRadiance { vertices: mesh.positions.len(), local_dirs: m, values };
    let grid = HemisphereGrid::new(view_m);
    let (w, h) = (64, 48);
    for eye in [Vec3::new(0.3, 1.6, 2.0), Vec3::new(-2.0, 0.7, -0.4)] {
        let cam = camera(eye, w, h);
        let img = gpu_shade(ctx, &mesh, &frames, &btf, &lstar, cam);
        let mut checked = 0;
        let mut worst = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                let (p, d) = plane_hit(&cam, x, y);
                // Away from the plane's border and the texel boundaries x = 0, z = 0.
                if p.x.abs().max(p.z.abs()) > 0.99 || p.x.abs() < 0.01 || p.z.abs() < 0.01 {
                    continue;
                }
                let (u, v) = ((p.x + 1.0) / 2.0, (p.z + 1.0) / 2.0);
                let texel = (v * 2.0).floor() as usize * 2 + (u * 2.0).floor() as usize;
                let (cx, cy) = grid.continuous_coords(frames[0].to_local(-d));
                let g = 1.0 + cx as f64 + 2.0 * cy as f64;
                let i = (y * w + x) as usize;
                assert!(img.coverage[i]);
                for c in 0..3 {
                    let expect = albedos[texel] as f64 * rgb[c] as f64 * (1.0 + 0.5 * p.x as f64) * g;
                    let err = (img.pixels[i][c] as f64 - expect).abs() / expect;
                    worst = worst.max(err);
                    assert!(
                        err <= 5e-5,
                        "eye {eye} pixel ({x},{y}) c{c}: {} vs {expect} (rel {err:e})",
                        img.pixels[i][c]
                    );
                }
                checked += 1;
            }
        }
        eprintln!("analytic plane from {eye}: {checked} pixels, worst relative error {worst:e}");
        assert!(checked > 300, "only {checked} pixels checked");
    }
}

/// Compare a GPU image with the CPU reference: coverage may differ only on silhouette pixels;
/// where both cover, the relative error must stay within `tol`.
fn compare_with_cpu(gpu: &ShadedImage, cpu: &biscale_shading::cpu::Render, tol: f64) -> (usize, f64) {
    let n = gpu.pixels.len();
    let mismatched = (0..n).filter(|&i| gpu.coverage[i] != cpu.mask[i]).count();
    let covered = cpu.mask.iter().filter(|&&m| m).count();
    // Pixel centres within rounding of a silhouette edge: a handful at most.
    assert!(mismatched * 200 <= covered.max(200), "{mismatched} coverage mismatches over {covered} covered pixels");
    let mut worst = 0.0f64;
    for i in (0..n).filter(|&i| gpu.coverage[i] && cpu.mask[i]) {
        let (g, c) = (gpu.pixels[i], cpu.image.pixels[i]);
        let scale = c.iter().fold(0.0f32, |a, &b| a.max(b.abs())) as f64;
        for k in 0..3 {
            let err = (g[k] as f64 - c[k] as f64).abs() / scale.max(1e-30);
            worst = worst.max(err);
            assert!(err <= tol, "pixel {i} channel {k}: GPU {} vs CPU {} (rel {err:e})", g[k], c[k]);
        }
    }
    (mismatched, worst)
}

#[test]
fn sphere_with_phong_btf_matches_cpu_shade() {
    // Random positive per-vertex L* on a UV sphere, a view-dependent Phong BTF (8x8 lights,
    // 12x12 views). Differences: f32 against f64 sums (~M u = 4e-6 for M = 64), f32
    // barycentrics and view coordinates (~1e-5 of a view cell; the bilinear table changes by
    // at most about its own magnitude per cell). Relative to the pixel's largest channel we
    // allow 5e-5 (measured on lavapipe: 4.7e-6).
    let ctx = gpu_or_skip!();
    let mesh = shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 24);
    let (frames, _) = vertex_frames(&mesh);
    let btf = Btf::phong([0.3, 0.25, 0.2], [0.4, 0.5, 0.6], 20.0, 8, 12).unwrap();
    let m = btf.light_count();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let values = (0..mesh.positions.len() * m)
        .map(|_| [rng.gen_range(0.0..1.0f32), rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0)])
        .collect();
    let lstar = LocalRadiance { vertices: mesh.positions.len(), local_dirs: m, values };
    let cam = camera(Vec3::new(0.5, 0.8, 3.2), 64, 48);
    let gpu = gpu_shade(ctx, &mesh, &frames, &btf, &lstar, cam);
    let bvh = SceneBvh::build(&mesh.positions, &mesh.triangles);
    let scene = ShadeScene { mesh: &mesh, frames: &frames, bvh: &bvh, btf: &btf, background: Background::Black };
    let cpu = shade(&scene, &lstar, &cpu_camera(&cam)).unwrap();
    let (mismatched, worst) = compare_with_cpu(&gpu, &cpu, 5e-5);
    eprintln!("sphere vs CPU: {mismatched} coverage mismatches, worst relative error {worst:e}");
}

#[test]
fn gather_to_shade_on_the_gpu_with_32x32_directions_matches_cpu() {
    // The no-read-back path (shade straight from the gather's buffer) with M = 1024 bins,
    // against shade_lstar of the read-back L* (bit-identical: same data, same kernel) and the
    // CPU shader (tolerance as above, plus the M = 1024-term f32 sum: M u = 6e-5; we allow
    // 1.5e-4; measured on lavapipe: 1.5e-6).
    let ctx = gpu_or_skip!();
    let mesh = shapes::grid_plane(2, 2.0);
    let (frames, _) = vertex_frames(&mesh);
    let btf = Btf::phong([0.5, 0.4, 0.3], [0.3, 0.3, 0.3], 8.0, 32, 4).unwrap();
    let t = random_transfer(mesh.positions.len(), 1024, 2, 0.3, 8);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut gather = GpuGather::new(ctx, &form).unwrap();
    let light = LightVector::constant(2, [1.0, 0.8, 0.6]);
    gather.gather(&light).unwrap();
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = frames.iter().map(|f| f.normal.to_array()).collect();
    let tangents: Vec<[f32; 3]> = frames.iter().map(|f| f.tangent.to_array()).collect();
    let uvs: Vec<[f32; 2]> = mesh.uvs.as_ref().unwrap().iter().map(|p| p.to_array()).collect();
    let cam = camera(Vec3::new(0.4, 1.5, 1.8), 40, 30);
    let inputs = ShadeInputs {
        positions: &positions,
        normals: &normals,
        tangents: &tangents,
        uvs: Some(&uvs),
        triangles: &mesh.triangles,
        btf_data: &btf.data,
        btf_spatial: btf.spatial,
        light_m: 32,
        view_m: Some(4),
        camera: cam,
    };
    let mut shader = GpuShader::new(ctx, &inputs).unwrap();
    let direct = shader.shade(&gather).unwrap();
    let lstar = gather.read_lstar().unwrap();
    let via_host = shader.shade_lstar(&lstar).unwrap();
    assert_eq!(direct, via_host);
    let bvh = SceneBvh::build(&mesh.positions, &mesh.triangles);
    let scene = ShadeScene { mesh: &mesh, frames: &frames, bvh: &bvh, btf: &btf, background: Background::Black };
    let cpu = shade(&scene, &lstar, &cpu_camera(&cam)).unwrap();
    let (mismatched, worst) = compare_with_cpu(&direct, &cpu, 1.5e-4);
    eprintln!("plane M=1024 vs CPU: {mismatched} coverage mismatches, worst relative error {worst:e}");

    // Moving the camera re-renders without rebuilding.
    let cam2 = camera(Vec3::new(-1.0, 1.2, 1.0), 40, 30);
    shader.set_camera(&cam2).unwrap();
    let moved = shader.shade(&gather).unwrap();
    let cpu2 = shade(&scene, &lstar, &cpu_camera(&cam2)).unwrap();
    compare_with_cpu(&moved, &cpu2, 1.5e-4);
    assert!(shader.set_camera(&camera(Vec3::ONE, 41, 30)).is_err());

    let timing = shader.time_shade(&gather, 2).unwrap();
    assert!(timing.median_ms.is_finite() && timing.median_ms >= 0.0, "{timing:?}");
}

#[test]
fn bad_shading_inputs_are_errors() {
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let btf = table_btf(&[0.5], [1, 1], 4, None, |_, _| 1.0);
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = frames.iter().map(|f| f.normal.to_array()).collect();
    let tangents = normals.clone();
    let good = ShadeInputs {
        positions: &positions,
        normals: &normals,
        tangents: &tangents,
        uvs: None,
        triangles: &mesh.triangles,
        btf_data: &btf.data,
        btf_spatial: [1, 1],
        light_m: 4,
        view_m: None,
        camera: camera(Vec3::new(0.0, 2.0, 2.0), 8, 8),
    };
    let mut shader = GpuShader::new(ctx, &good).unwrap();
    // L* with the wrong number of bins.
    assert!(shader.shade_lstar(&LocalRadiance::zeros(positions.len(), 64)).is_err());
    let bad_tri = [[0, 1, 999]];
    assert!(GpuShader::new(ctx, &ShadeInputs { triangles: &bad_tri, ..good }).is_err());
    assert!(GpuShader::new(ctx, &ShadeInputs { light_m: 5, ..good }).is_err());
    assert!(GpuShader::new(ctx, &ShadeInputs { view_m: Some(3), ..good }).is_err());
    let mut nan = positions.clone();
    nan[2][1] = f32::NAN;
    let e = GpuShader::new(ctx, &ShadeInputs { positions: &nan, ..good }).err().unwrap();
    assert!(e.to_string().contains("vertex 2"), "{e}");
    let mut cam = good.camera;
    cam.target = cam.position;
    assert!(GpuShader::new(ctx, &ShadeInputs { camera: cam, ..good }).is_err());
}
