//! The GPU shader against analytic scenes and against the CPU reference shader
//! (`shading::cpu::shade`), with one material and with several per scene.

use super::gpu_or_skip;
use crate::{GpuContext, GpuError, GpuGather, GpuShader};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::random_transfer;
use biscale_core::basis::LocalBasis;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::{shapes, vertex_frames, Mesh, VertexFrame};
use biscale_core::sampling::{HemisphereGrid, LightVector};
use biscale_core::scene::{Btf, Camera, Material, Render, ShadeScene};
use biscale_shading::cpu::{primary_hit, shade};
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

const U: f64 = f32::EPSILON as f64 / 2.0; // unit roundoff of f32, 2^-24

fn camera(position: Vec3, width: u32, height: u32) -> Camera {
    Camera { position, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0, width, height, samples_per_pixel: 1 }
}

fn bins(m: u32) -> LocalBasis {
    LocalBasis::bins(m).unwrap()
}

/// `L*` from row values.
fn lstar_of(basis: LocalBasis, vertices: usize, values: Vec<[f32; 3]>) -> LocalRadiance {
    LocalRadiance::new(basis, vertices, values).unwrap()
}

/// The scene of `mesh` with `frames`, materials and per-triangle `ids`.
fn scene(mesh: &Mesh, frames: &[VertexFrame], materials: &[Material], ids: Option<&[u32]>) -> ShadeScene {
    ShadeScene::new(mesh.clone(), frames.to_vec(), materials.to_vec(), ids.map(<[u32]>::to_vec)).unwrap()
}

/// Shade `mesh` with `frames`, materials (per-triangle `ids`) and host L* on the GPU; the
/// shader is returned too, to move its camera.
fn gpu_shader(
    ctx: &GpuContext,
    mesh: &Mesh,
    frames: &[VertexFrame],
    materials: &[Material],
    ids: Option<&[u32]>,
    cam: Camera,
) -> Result<GpuShader, GpuError> {
    GpuShader::new(ctx, &scene(mesh, frames, materials, ids), &cam)
}

/// Shade `mesh` with `frames`, one BTF and host L* on the GPU.
fn gpu_shade(
    ctx: &GpuContext,
    mesh: &Mesh,
    frames: &[VertexFrame],
    btf: &Btf,
    lstar: &LocalRadiance,
    cam: Camera,
) -> Render {
    let mut shader = gpu_shader(ctx, mesh, frames, &[Material::new(btf.clone())], None, cam).unwrap();
    shader.shade_lstar(lstar).unwrap()
}

/// The plane `grid_plane(4, 2.0)` ([-1, 1]^2 in XZ, facing +Y) with frame t = +X, n = +Y.
fn plane() -> (Mesh, Vec<VertexFrame>) {
    let mesh = shapes::grid_plane(4, 2.0);
    let frames = vec![VertexFrame::from_normal_tangent(Vec3::Y, Vec3::X); mesh.positions.len()];
    (mesh, frames)
}

/// Where the pixel centre's ray hits the plane y = 0 (CPU, through the CPU camera).
fn plane_hit(cam: &Camera, x: u32, y: u32) -> (Vec3, Vec3) {
    let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
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
    Btf::new(spatial, bins(light_m), vg, data, "test table").unwrap()
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
        let lstar = lstar_of(
            btf.local_basis(),
            mesh.positions.len(),
            vec![radiance.map(|r| r * bin); mesh.positions.len() * m],
        );
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
                    assert!(img.mask[i], "M={m}: pixel ({x},{y}) hits the plane at {p} but is not covered");
                    for c in 0..3 {
                        let expect = albedo as f64 * radiance[c] as f64;
                        let got = img.image.pixels[i][c] as f64;
                        assert!(
                            (got - expect).abs() <= tol * expect,
                            "M={m} ({x},{y}) c{c}: {got} vs {expect} (tol {tol})"
                        );
                    }
                } else if edge > 1.0 + 1e-3 {
                    outside += 1;
                    assert!(!img.mask[i], "M={m}: pixel ({x},{y}) misses the plane but is covered");
                    assert_eq!(img.image.pixels[i], [0.0; 3]);
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
    let lstar = lstar_of(btf.local_basis(), mesh.positions.len(), values);
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
                assert!(img.mask[i]);
                for c in 0..3 {
                    let expect = albedos[texel] as f64 * rgb[c] as f64 * (1.0 + 0.5 * p.x as f64) * g;
                    let err = (img.image.pixels[i][c] as f64 - expect).abs() / expect;
                    worst = worst.max(err);
                    assert!(
                        err <= 5e-5,
                        "eye {eye} pixel ({x},{y}) c{c}: {} vs {expect} (rel {err:e})",
                        img.image.pixels[i][c]
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
fn compare_with_cpu(gpu: &Render, cpu: &Render, tol: f64) -> (usize, f64) {
    let n = gpu.image.pixels.len();
    let mismatched = (0..n).filter(|&i| gpu.mask[i] != cpu.mask[i]).count();
    let covered = cpu.mask.iter().filter(|&&m| m).count();
    // Pixel centres within rounding of a silhouette edge: a handful at most.
    assert!(mismatched * 200 <= covered.max(200), "{mismatched} coverage mismatches over {covered} covered pixels");
    let mut worst = 0.0f64;
    for i in (0..n).filter(|&i| gpu.mask[i] && cpu.mask[i]) {
        let (g, c) = (gpu.image.pixels[i], cpu.image.pixels[i]);
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
    let btf = Btf::phong([0.3, 0.25, 0.2], [0.4, 0.5, 0.6], 20.0, bins(8), 12).unwrap();
    let m = btf.light_count();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let values = (0..mesh.positions.len() * m)
        .map(|_| [rng.gen_range(0.0..1.0f32), rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0)])
        .collect();
    let lstar = lstar_of(btf.local_basis(), mesh.positions.len(), values);
    let cam = camera(Vec3::new(0.5, 0.8, 3.2), 64, 48);
    let gpu = gpu_shade(ctx, &mesh, &frames, &btf, &lstar, cam);
    let cpu = shade(&scene(&mesh, &frames, &[Material::new(btf.clone())], None), &lstar, &cam).unwrap();
    let (mismatched, worst) = compare_with_cpu(&gpu, &cpu, 5e-5);
    eprintln!("sphere vs CPU: {mismatched} coverage mismatches, worst relative error {worst:e}");
}

/// Anti-aliasing: the GPU shades the sample grid and box-filters it, the CPU averages the
/// same sample positions per pixel. Where both saw the same samples hit (equal coverage) the
/// pixel is the mean of the same samples, within the one-sample tolerance above (5e-5); a
/// sample within rounding of the silhouette may fall on either side, so a handful of pixels
/// differ by one sample in coverage and nothing else.
#[test]
fn anti_aliased_shading_matches_the_cpu_samples() {
    let ctx = gpu_or_skip!();
    let mesh = shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 24);
    let (frames, _) = vertex_frames(&mesh);
    let btf = Btf::phong([0.3, 0.25, 0.2], [0.4, 0.5, 0.6], 20.0, bins(8), 12).unwrap();
    let m = btf.light_count();
    // L* a smooth function of position: the sphere's seam vertices are duplicated, and random
    // values there would make a sample within rounding of the seam jump between two L*.
    let values = (0..mesh.positions.len() * m)
        .map(|r| {
            let (p, j) = (mesh.positions[r / m], (r % m) as f32);
            [0, 1, 2].map(|c| 1.0 + 0.5 * (3.0 * p.x + 0.1 * j).sin() * (2.0 * p.y + c as f32).cos())
        })
        .collect();
    let lstar = lstar_of(btf.local_basis(), mesh.positions.len(), values);
    for spp in [4u32, 9] {
        let cam = Camera { samples_per_pixel: spp, ..camera(Vec3::new(0.5, 0.8, 3.2), 40, 30) };
        let mut shader = gpu_shader(ctx, &mesh, &frames, &[Material::new(btf.clone())], None, cam).unwrap();
        let n = (spp as f64).sqrt() as u32;
        assert_eq!(shader.size(), (40 * n, 30 * n), "the passes run on the sample grid");
        let gpu = shader.shade_lstar(&lstar).unwrap();
        let cpu = shade(&scene(&mesh, &frames, &[Material::new(btf.clone())], None), &lstar, &cam).unwrap();
        let (gc, cc) = (gpu.coverage.as_ref().unwrap(), cpu.coverage.as_ref().unwrap());
        assert_eq!((gpu.image.width, gpu.image.height), (40, 30));
        let (mut same, mut partial, mut off_by_one) = (0, 0, 0);
        for i in 0..gpu.image.pixels.len() {
            let samples_apart = ((gc[i] - cc[i]) * spp as f32).abs().round() as u32;
            assert!(samples_apart <= 1, "spp {spp} pixel {i}: coverage {} vs {}", gc[i], cc[i]);
            if samples_apart == 1 {
                off_by_one += 1;
                continue;
            }
            assert_eq!(gpu.mask[i], cpu.mask[i]);
            if !cpu.mask[i] {
                continue;
            }
            same += 1;
            partial += usize::from(cc[i] < 1.0);
            let (g, c) = (gpu.image.pixels[i], cpu.image.pixels[i]);
            let scale = c.iter().fold(0.0f32, |a, &b| a.max(b.abs())) as f64;
            for k in 0..3 {
                let err = (g[k] as f64 - c[k] as f64).abs() / scale;
                assert!(err <= 5e-5, "spp {spp} pixel {i} channel {k}: GPU {} vs CPU {} (rel {err:e})", g[k], c[k]);
            }
        }
        eprintln!("spp {spp}: {same} pixels agree ({partial} partly covered), {off_by_one} one sample apart");
        assert!(partial > 20 && same > 300, "the view has an anti-aliased silhouette: {partial} partial of {same}");
        assert!(off_by_one * 100 <= same, "{off_by_one} pixels one sample apart of {same}");
        // Moving the camera keeps the sample grid; another sample count is refused.
        assert!(shader.set_camera(&Camera { position: Vec3::new(0.4, 0.9, 3.0), ..cam }).is_ok());
        assert!(shader.set_camera(&Camera { samples_per_pixel: 1, ..cam }).is_err());
    }
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
    let btf = Btf::phong([0.5, 0.4, 0.3], [0.3, 0.3, 0.3], 8.0, bins(32), 4).unwrap();
    let t = random_transfer(mesh.positions.len(), 32, 2, 0.3, 8);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut gather = GpuGather::new(ctx, &form, &Sparse.kernels(&form).unwrap()).unwrap();
    let light = LightVector::constant(t.light_basis(), [1.0, 0.8, 0.6]);
    gather.gather(&light).unwrap();
    let cam = camera(Vec3::new(0.4, 1.5, 1.8), 40, 30);
    let scene = scene(&mesh, &frames, &[Material::new(btf.clone())], None);
    let mut shader = GpuShader::new(ctx, &scene, &cam).unwrap();
    let direct = shader.shade(&gather).unwrap();
    let lstar = gather.read_lstar().unwrap();
    let via_host = shader.shade_lstar(&lstar).unwrap();
    assert_eq!(direct, via_host);
    let cpu = shade(&scene, &lstar, &cam).unwrap();
    let (mismatched, worst) = compare_with_cpu(&direct, &cpu, 1.5e-4);
    eprintln!("plane M=1024 vs CPU: {mismatched} coverage mismatches, worst relative error {worst:e}");

    // Moving the camera re-renders without rebuilding.
    let cam2 = camera(Vec3::new(-1.0, 1.2, 1.0), 40, 30);
    shader.set_camera(&cam2).unwrap();
    let moved = shader.shade(&gather).unwrap();
    let cpu2 = shade(&scene, &lstar, &cam2).unwrap();
    compare_with_cpu(&moved, &cpu2, 1.5e-4);
    assert!(shader.set_camera(&camera(Vec3::ONE, 41, 30)).is_err());

    let timing = shader.time_shade(&gather, 2).unwrap();
    assert!(timing.median_ms.is_finite() && timing.median_ms >= 0.0, "{timing:?}");
}

#[test]
fn bad_shading_inputs_are_errors() {
    // The scene itself is checked when it is built (ShadeScene::new, core's tests); here what
    // the GPU shader checks: L* against the scene, and the camera.
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let btf = table_btf(&[0.5], [1, 1], 4, None, |_, _| 1.0);
    let scene = scene(&mesh, &frames, &[Material::new(btf)], None);
    let cam = camera(Vec3::new(0.0, 2.0, 2.0), 8, 8);
    let mut shader = GpuShader::new(ctx, &scene, &cam).unwrap();
    // L* with the wrong number of bins, or of vertices.
    let n = mesh.positions.len();
    let e = shader.shade_lstar(&LocalRadiance::zeros(bins(8), n)).unwrap_err();
    assert!(matches!(e, GpuError::Core(_)) && e.to_string().contains("8x8 bins"), "{e}");
    assert!(shader.shade_lstar(&LocalRadiance::zeros(bins(4), n - 1)).is_err());
    assert!(shader.shade_lstar(&LocalRadiance::zeros(bins(4), n)).is_ok());
    let mut bad_cam = cam;
    bad_cam.target = bad_cam.position;
    assert!(matches!(GpuShader::new(ctx, &scene, &bad_cam), Err(GpuError::Input(_))));
    assert!(shader.set_camera(&bad_cam).is_err());
}

/// A plane (`grid_plane(8, 2.0)`) with a UV sphere above it, in one mesh (plane triangles
/// first). Frames from each part alone; the sphere's uvs are its vertices' (x, z), so uv
/// interpolation is exercised there too.
fn plane_and_sphere() -> (Mesh, Vec<VertexFrame>, usize) {
    let plane = shapes::grid_plane(8, 2.0);
    let (mut frames, _) = vertex_frames(&plane);
    let sphere = shapes::uv_sphere(Vec3::new(0.25, 0.4, -0.2), 0.35, 12, 24);
    let (sphere_frames, _) = vertex_frames(&sphere);
    frames.extend(sphere_frames);
    let base = plane.positions.len() as u32;
    let plane_triangles = plane.triangles.len();
    let mut mesh = plane;
    mesh.uvs.as_mut().unwrap().extend(sphere.positions.iter().map(|p| Vec2::new(p.x, p.z)));
    mesh.positions.extend(&sphere.positions);
    mesh.triangles.extend(sphere.triangles.iter().map(|t| t.map(|i| i + base)));
    (mesh, frames, plane_triangles)
}

/// Four materials on one light grid (8 x 8): a view-independent Lambertian, a 3 x 2 texel
/// Phong patch (view grid 4, texels scaled differently) tiled 2.5 times, a Phong with a 6 x 6
/// view grid and a glossier one with 12 x 12.
fn four_materials() -> Vec<Material> {
    let lambert = Btf::lambertian([0.7, 0.6, 0.5], bins(8)).unwrap();
    let base = Btf::phong([0.5, 0.4, 0.3], [0.4, 0.4, 0.4], 10.0, bins(8), 4).unwrap();
    let texels = [1.0f32, 0.55, 0.8, 0.3, 0.65, 0.9]
        .iter()
        .flat_map(|&s| base.data().iter().map(move |v| v.map(|x| x * s)))
        .collect();
    let patch = Btf::new([3, 2], bins(8), base.view_grid(), texels, "patch").unwrap();
    let phong6 = Btf::phong([0.2, 0.3, 0.4], [0.5, 0.4, 0.3], 15.0, bins(8), 6).unwrap();
    let phong12 = Btf::phong([0.5, 0.3, 0.2], [0.3, 0.3, 0.3], 30.0, bins(8), 12).unwrap();
    vec![
        Material::new(lambert),
        Material { btf: patch.into(), tiling: 2.5 },
        Material::new(phong6),
        Material::new(phong12),
    ]
}

#[test]
fn several_materials_match_cpu_shade() {
    // Plane quadrants x < 0, z < 0: Lambertian (view-independent); x >= 0: the tiled 3 x 2
    // patch (view grid 4); x < 0, z >= 0: Phong with a 6 x 6 view grid; the sphere above:
    // Phong with 12 x 12. Random positive L* per vertex, two eyes (the second through
    // set_camera). Each pixel covered on both sides is compared with shading::cpu::shade on
    // the same scene, relative to the pixel's largest channel.
    //
    // Pixels are classed by CPU rays cast 1/16 pixel left, right, above and below the centre.
    // The rasterizer snaps vertices to sub-pixel bits (at least 4 in Vulkan), so that close to
    // an edge it may pick the neighbouring triangle, and the GPU then shades that triangle's
    // nearest point (clamped barycentrics):
    // * interior (all five rays hit the same triangle): the GPU and CPU shade the same point.
    //   Tolerance as in sphere_with_phong_btf_matches_cpu_shade (same M = 64, view grids up to
    //   12): 5e-5.
    // * edge (same material and texel, different triangles): the GPU's point may sit on the
    //   shared edge, a barycentric distance dw from the CPU's, and random per-vertex L* changes
    //   by up to its whole range across a triangle, so the error is up to ~dw. With 8
    //   sub-pixel bits (lavapipe, NVIDIA) dw <= (1/512 pixel) / (the triangle's smallest
    //   altitude, >= 1 pixel here): we allow 2e-3.
    // * material, texel or occlusion boundary: skipped (either side is right).
    let ctx = gpu_or_skip!();
    let (mesh, frames, plane_triangles) = plane_and_sphere();
    let materials = four_materials();
    let ids: Vec<u32> = mesh
        .triangles
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            if t >= plane_triangles {
                return 3;
            }
            let c = tri.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / 3.0;
            if c.x >= 0.0 {
                1
            } else if c.z < 0.0 {
                0
            } else {
                2
            }
        })
        .collect();
    let m = 64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let values = (0..mesh.positions.len() * m)
        .map(|_| [rng.gen_range(0.0..1.0f32), rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0)])
        .collect();
    let lstar = lstar_of(bins(8), mesh.positions.len(), values);
    let scene = scene(&mesh, &frames, &materials, Some(&ids));
    let (w, h) = (96, 72);
    let eyes = [Vec3::new(0.5, 1.7, 2.0), Vec3::new(-1.9, 1.1, -0.8)];
    let mut shader = gpu_shader(ctx, &mesh, &frames, &materials, Some(&ids), camera(eyes[0], w, h)).unwrap();
    // (material, texel of uv * tiling, triangle) of the CPU hit at sub-pixel position (x, y).
    let key = |cam: &Camera, x: f32, y: f32| {
        let (o, d) = cam.ray(x, y);
        primary_hit(&scene, o, d).map(|p| {
            let id = ids[p.triangle as usize] as usize;
            (id, materials[id].btf.texel_of(p.uv * materials[id].tiling), p.triangle)
        })
    };
    let (interior_tol, edge_tol) = (5e-5, 2e-3);
    let mut per_material = [0usize; 4];
    let mut per_texel = [0usize; 6];
    for (e, &eye) in eyes.iter().enumerate() {
        let cam = camera(eye, w, h);
        shader.set_camera(&cam).unwrap();
        let gpu = shader.shade_lstar(&lstar).unwrap();
        let cpu_cam = cam;
        let cpu = shade(&scene, &lstar, &cpu_cam).unwrap();
        let covered = cpu.mask.iter().filter(|&&c| c).count();
        let mismatched = (0..gpu.image.pixels.len()).filter(|&i| gpu.mask[i] != cpu.mask[i]).count();
        assert!(mismatched * 200 <= covered.max(200), "eye {e}: {mismatched} coverage mismatches of {covered}");
        let (mut interior, mut edge, mut boundary) = (0usize, 0usize, 0usize);
        let (mut worst_interior, mut worst_edge) = (0.0f64, 0.0f64);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                if !(gpu.mask[i] && cpu.mask[i]) {
                    continue;
                }
                let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                let Some(centre) = key(&cpu_cam, cx, cy) else {
                    boundary += 1;
                    continue;
                };
                let d = 1.0 / 16.0;
                let probes =
                    [(cx - d, cy), (cx + d, cy), (cx, cy - d), (cx, cy + d)].map(|(px, py)| key(&cpu_cam, px, py));
                if probes.iter().any(|p| p.is_none_or(|p| (p.0, p.1) != (centre.0, centre.1))) {
                    boundary += 1;
                    continue;
                }
                let on_edge = probes.iter().any(|p| p.is_some_and(|p| p.2 != centre.2));
                let (id, texel, _) = centre;
                let (g, c) = (gpu.image.pixels[i], cpu.image.pixels[i]);
                let scale = c.iter().fold(0.0f32, |a, &b| a.max(b.abs())) as f64;
                assert!(scale > 0.0, "eye {e} ({x},{y}): random positive L* must light every pixel");
                let err = (0..3).map(|k| (g[k] as f64 - c[k] as f64).abs() / scale).fold(0.0, f64::max);
                let (tol, worst, count) = if on_edge {
                    (edge_tol, &mut worst_edge, &mut edge)
                } else {
                    (interior_tol, &mut worst_interior, &mut interior)
                };
                assert!(
                    err <= tol,
                    "eye {e} ({x},{y}) material {id} texel {texel} (edge: {on_edge}): GPU {g:?} vs CPU {c:?} (rel {err:e})"
                );
                *worst = worst.max(err);
                *count += 1;
                per_material[id] += 1;
                if id == 1 {
                    per_texel[texel] += 1;
                }
            }
        }
        eprintln!(
            "materials, eye {e}: {interior} interior pixels (worst relative error {worst_interior:e}), {edge} on \
             triangle edges (worst {worst_edge:e}), {boundary} on material/texel/occlusion boundaries skipped, \
             {mismatched} coverage mismatches"
        );
        // Boundaries are thin (a band 1/8 pixel wide around each), edges too.
        assert!(interior + edge >= covered * 9 / 10, "eye {e}: only {} of {covered} compared", interior + edge);
        assert!(interior * 10 >= covered * 7, "eye {e}: only {interior} interior pixels of {covered}");
    }
    eprintln!("pixels per material {per_material:?}, per patch texel {per_texel:?}");
    assert!(per_material.iter().all(|&n| n > 200), "every material is seen: {per_material:?}");
    assert!(per_texel.iter().all(|&n| n > 20), "every texel of the patch is seen: {per_texel:?}");
}

#[test]
fn one_material_with_or_without_ids_is_the_same_image() {
    // Without ids the id binding is a placeholder the shader must not read; with all-zero ids
    // it is read. Same data, same kernel otherwise: bit-identical images.
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let materials =
        [Material { btf: Btf::phong([0.4, 0.5, 0.6], [0.3; 3], 12.0, bins(4), 5).unwrap().into(), tiling: 1.5 }];
    let m = 16;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let values = (0..mesh.positions.len() * m).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect();
    let lstar = lstar_of(bins(4), mesh.positions.len(), values);
    let cam = camera(Vec3::new(0.3, 1.6, 2.0), 32, 24);
    let zeros = vec![0u32; mesh.triangles.len()];
    let without = gpu_shader(ctx, &mesh, &frames, &materials, None, cam).unwrap().shade_lstar(&lstar).unwrap();
    let with = gpu_shader(ctx, &mesh, &frames, &materials, Some(&zeros), cam).unwrap().shade_lstar(&lstar).unwrap();
    assert!(without.mask.iter().filter(|&&c| c).count() > 200);
    assert_eq!(without, with);
}

#[test]
fn concatenated_tables_over_the_binding_limit_are_refused() {
    // Concatenated tables over the binding limit, while each table alone fits: the same
    // 3 MiB table (64 x 64 texels x 64 lights) used by enough materials. Refused before
    // anything is concatenated or uploaded. (Ids, tilings and table shapes are the scene's
    // checks: ShadeScene::new and Btf::new, tested in core.)
    let ctx = gpu_or_skip!();
    let (mesh, frames) = plane();
    let n = mesh.triangles.len();
    let cam = camera(Vec3::new(0.0, 2.0, 2.0), 8, 8);
    let max = ctx.limits().max_storage_buffer_binding_size;
    let big = Btf::new([64, 64], bins(8), None, vec![[0.0f32; 3]; 64 * 64 * 64], "big").unwrap();
    let table_bytes = (big.data().len() * 12) as u64;
    let count = max / table_bytes + 1;
    if count > 100 {
        eprintln!("skipped the binding-size check: the limit {max} needs {count} materials");
        return;
    }
    let many = vec![Material::new(big); count as usize];
    let zero_ids = vec![0u32; n];
    match gpu_shader(ctx, &mesh, &frames, &many, Some(&zero_ids), cam) {
        Err(GpuError::Limit { limit, needed, max: m, .. }) => {
            assert_eq!((limit, needed, m), ("max_storage_buffer_binding_size", count * table_bytes, max));
        }
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("accepted {} bytes of tables over a {max}-byte limit", count * table_bytes),
    }
    assert!(gpu_shader(ctx, &mesh, &frames, &many[..1], None, cam).is_ok(), "one table of {table_bytes} bytes fits");
}

/// The render-pass half of the timestamp path (see the gather test of the same name): with
/// timestamps forced on, shading reports both passes by name.
#[test]
fn forced_timestamps_time_both_shading_passes() {
    use crate::{GpuContext, TimestampPolicy, TimingMethod};
    let _ = gpu_or_skip!(); // no adapter at all: skip
    let ctx = GpuContext::with_timestamps(TimestampPolicy::Always).unwrap();
    if !ctx.has_timestamps() {
        eprintln!("SKIPPING: {} has no timestamp queries", ctx.adapter());
        return;
    }
    let mesh = shapes::grid_plane(2, 2.0);
    let (frames, _) = vertex_frames(&mesh);
    let btf = Btf::phong([0.5, 0.4, 0.3], [0.3, 0.3, 0.3], 8.0, bins(8), 4).unwrap();
    let t = random_transfer(mesh.positions.len(), 8, 2, 0.3, 9);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut gather = GpuGather::new(&ctx, &form, &Sparse.kernels(&form).unwrap()).unwrap();
    gather.gather(&LightVector::constant(t.light_basis(), [1.0, 0.8, 0.6])).unwrap();
    let cam = camera(Vec3::new(0.4, 1.5, 1.8), 32, 24);
    let mut shader = gpu_shader(&ctx, &mesh, &frames, &[Material::new(btf)], None, cam).unwrap();
    let timing = shader.time_shade(&gather, 2).unwrap();
    assert_eq!(timing.method, TimingMethod::GpuTimestamps);
    let names: Vec<&str> = timing.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["visibility", "shade"]);
    assert!(timing.passes.iter().all(|p| p.median_ms.is_finite() && p.median_ms >= 0.0), "{timing:?}");
}

/// A `w x h` BTF of random values in [0.2, 1) (16 lights, `view_m^2` views).
pub(super) fn random_btf(w: u32, h: u32, view_m: u32, seed: u64) -> Btf {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let grid = HemisphereGrid::new(view_m);
    let n = (w * h) as usize * grid.len() * 16;
    let data = (0..n).map(|_| std::array::from_fn(|_| rng.gen_range(0.2..1.0f32))).collect();
    Btf::new([w, h], bins(4), Some(grid), data, "random").unwrap()
}

#[test]
fn lpca_btfs_match_the_cpu_lpca_evaluation() {
    // The WGSL LPCA path (btf_sample / btf_value) against the CPU's direct evaluation
    // (LpcaBtf::eval_into, f64 dot), per texel and per view, alone and next to a dense
    // material. Differences: the f32 sums of the GPU, (M + 4 (C + 1)) u = 4e-6 of the absolute
    // terms for M = 16, C <= 3, and f32 view coordinates, ~1e-5 of a view cell, against a
    // random table that changes by up to its own size per cell. The reconstructed values
    // stay near the table's (0.2..1), so the absolute terms are within a few times the pixel:
    // 5e-5 of the pixel's largest channel covers both (measured on lavapipe: 5.1e-6); a wrong
    // cluster, segment or weight is an O(1) error.
    use biscale_core::scene::{LpcaBtf, LpcaSettings};
    let ctx = gpu_or_skip!();
    let mesh = shapes::cylindrical_uvs(&shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 24));
    let (frames, _) = vertex_frames(&mesh);
    let btf = random_btf(4, 3, 3, 9);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(10);
    let values = (0..mesh.positions.len() * 16).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect();
    let lstar = lstar_of(bins(4), mesh.positions.len(), values);
    let cam = camera(Vec3::new(0.5, 0.8, 3.2), 64, 48);
    let phong = Btf::phong([0.3, 0.25, 0.2], [0.4, 0.5, 0.6], 20.0, bins(4), 5).unwrap();
    let ids: Vec<u32> = (0..mesh.triangle_count() as u32).map(|t| (t / 7) % 2).collect();
    for settings in [LpcaSettings::new(3, 2), LpcaSettings::new(4, 3).per_view()] {
        let (l, _) = LpcaBtf::compress(&btf, &settings, 11).unwrap();
        let one = [Material { btf: l.clone().into(), tiling: 2.0 }];
        let mixed = [Material::new(phong.clone()), one[0].clone()];
        for (materials, ids) in [(&one[..], None), (&mixed[..], Some(&ids[..]))] {
            let cpu = shade(&scene(&mesh, &frames, materials, ids), &lstar, &cam).unwrap();
            let gpu = gpu_shader(ctx, &mesh, &frames, materials, ids, cam).unwrap().shade_lstar(&lstar).unwrap();
            let (mismatched, worst) = compare_with_cpu(&gpu, &cpu, 5e-5);
            eprintln!("{settings:?}, {} material(s): {mismatched} mismatches, worst {worst:e}", materials.len());
        }
        // A component cap evaluates the leading components: the CPU image of the truncated
        // BTF, within the same bound; lifting it restores the full image exactly.
        let mut shader = gpu_shader(ctx, &mesh, &frames, &one, None, cam).unwrap();
        let full = shader.shade_lstar(&lstar).unwrap();
        for n in 1..l.components() {
            shader.set_max_components(Some(n as u32)).unwrap();
            let gpu = shader.shade_lstar(&lstar).unwrap();
            let truncated = [Material { btf: l.truncated(n).unwrap().into(), tiling: 2.0 }];
            let cpu = shade(&scene(&mesh, &frames, &truncated, None), &lstar, &cam).unwrap();
            compare_with_cpu(&gpu, &cpu, 5e-5);
            assert_ne!(gpu, full, "{n} of {} components must change the image", l.components());
        }
        shader.set_max_components(None).unwrap();
        assert_eq!(shader.shade_lstar(&lstar).unwrap(), full);
    }
}
