//! The shader's per-pixel resolves of light moments (`shade/moments.wgsl`,
//! `runtime.moments_resolve = "pixel"` and `"pixel_analytic"`) against the CPU's
//! `shade_moments` and `shade_moments_analytic`, and its analytic BRDFs (`shade/brdf.wgsl`)
//! against `Brdf::eval`, kind by kind.
//!
//! # Tolerances
//!
//! **BRDFs.** The GPU evaluates the formula in f32 on the same f32 directions the CPU evaluates
//! in f64. Its error has two parts. The directions it forms inside (the half-vector, the
//! mirrored light, their normalisations) are within a few `u` (`u = 2^-24`) of the exact ones:
//! we bound that part by the BRDF's own change when the light or the view moves by `32 u` (the
//! largest change over six perturbation directions, evaluated in f64), which covers a GGX lobe
//! whose relative slope is `2 / alpha` per radian. The arithmetic on the values adds at most
//! about 30 roundings of up to Vulkan's 2.5 ulp each (`128 u` relative), and `pow(x, e) =
//! exp2(e log2 x)` adds `e 2^-21 ln 2` relative (the absolute error `2^-21` of `log2` scaled by
//! `e`) plus `(3 + 2 |e log2 x|)` ulp of `exp2`.
//!
//! **Images.** Against the CPU's image (f64 sums of the same f32 moments), relative to a
//! pixel's largest channel as the other shading tests: a pixel is a sum of `3 M` terms (three
//! vertices, `M` bins) in f32, `3 M u` of the sum of their magnitudes (all non-negative here but
//! near the hit's horizon); the hit's frame and view are f32 on both sides, within about `10 u`
//! of each other, which moves each bin's direction by as much (`20 u / alpha` relative through a
//! GGX lobe; the table resolve's bilinear weights by `70 m u`, the bound of the vertex resolve's
//! test, times the ratio of neighbouring bins' BTF values, below 4 for these materials); and the
//! BRDF's own error above. For `M = 64`, `m = 8`, `alpha >= 0.15`: `(192 + 133 + 2240 + 128) u`,
//! about `1.6e-4`; we allow `2e-4`. Near the terminator a pixel's terms cancel (the hit's
//! normal sees a vertex's light from just below its horizon), and the error is relative to
//! their magnitudes, each at most a lit pixel's value: there the bound is `2e-4` of 5% of the
//! image's largest value (`1e-5` of it, still well above the `(3 M + 10) u` of such terms).

/// The GPU and CPU images where both cover a pixel, within `tol` of the pixel's largest
/// channel or of 5% of the image's largest value, whichever is larger (module docs); the
/// number of coverage mismatches (silhouette samples within rounding, a handful at most) and
/// the largest error relative to that scale.
fn compare(gpu: &Render, cpu: &Render, tol: f64) -> (usize, f64) {
    let n = gpu.image.pixels.len();
    let mismatched = (0..n).filter(|&i| gpu.mask[i] != cpu.mask[i]).count();
    let covered = cpu.mask.iter().filter(|&&m| m).count();
    assert!(mismatched * 200 <= covered.max(200), "{mismatched} coverage mismatches over {covered} covered pixels");
    let largest = |p: &[f32; 3]| p.iter().fold(0.0f64, |a, &b| a.max(b.abs() as f64));
    let floor = 0.05 * cpu.image.pixels.iter().map(largest).fold(0.0, f64::max);
    let mut worst = 0.0f64;
    for i in (0..n).filter(|&i| gpu.mask[i] && cpu.mask[i]) {
        let (g, c) = (gpu.image.pixels[i], cpu.image.pixels[i]);
        let scale = largest(&c).max(floor).max(1e-30);
        for k in 0..3 {
            let err = (g[k] as f64 - c[k] as f64).abs() / scale;
            worst = worst.max(err);
            assert!(err <= tol, "pixel {i} channel {k}: GPU {} vs CPU {} (error {err:e} of {scale:e})", g[k], c[k]);
        }
    }
    (mismatched, worst)
}

use super::gather::upload;
use super::gpu_or_skip;
use super::shading::random_btf;
use crate::{GpuContext, GpuMoments, GpuShader};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{bins, random_transfer};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::moments::Lobe;
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::{shapes, vertex_frames, VertexFrame};
use biscale_core::scene::{Btf, Camera, LpcaBtf, LpcaSettings, Material, Render, ShadeScene};
use biscale_shading::cpu::{shade_moments, shade_moments_analytic};
use biscale_shading::runtime::MomentsResolve;
use biscale_shading::synth::Brdf;
use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const U: f64 = f32::EPSILON as f64 / 2.0;

/// `brdf_eval(brdfs[0], l, v)` on the GPU for each `(l, v)`.
fn probe(ctx: &GpuContext, brdf: &Brdf, dirs: &[(Vec3, Vec3)]) -> Vec<[f32; 3]> {
    let (records, coating) = crate::GpuBrdf::records(&[Some(*brdf)]);
    let input: Vec<f32> = dirs.iter().flat_map(|(l, v)| [l.x, l.y, l.z, v.x, v.y, v.z]).collect();
    let source = format!(
        "{}\n{}\n@group(0) @binding(0) var<storage, read> dirs: array<f32>;\n\
         @group(0) @binding(1) var<storage, read_write> out: array<f32>;\n\
         @compute @workgroup_size(64)\nfn probe(@builtin(global_invocation_id) id: vec3<u32>) {{\n    \
         let i = id.x;\n    if i >= arrayLength(&out) / 3u {{ return; }}\n    \
         let l = vec3<f32>(dirs[6u * i], dirs[6u * i + 1u], dirs[6u * i + 2u]);\n    \
         let v = vec3<f32>(dirs[6u * i + 3u], dirs[6u * i + 4u], dirs[6u * i + 5u]);\n    \
         let f = brdf_eval(brdfs[0], l, v);\n    out[3u * i] = f.x;\n    out[3u * i + 1u] = f.y;\n    \
         out[3u * i + 2u] = f.z;\n}}\n",
        crate::shade::brdf_constants_wgsl(),
        include_str!("../shade/brdf.wgsl"),
    );
    let buf = |label: &str, data: &[u8], usage| ctx.storage_buffer(label, data, usage).unwrap();
    let dirs_buf = buf("probe directions", bytemuck::cast_slice(&input), wgpu::BufferUsages::empty());
    let brdf_buf = buf("probe BRDF", bytemuck::cast_slice(&records), wgpu::BufferUsages::empty());
    let coating_buf = buf("probe coating", bytemuck::cast_slice(&coating), wgpu::BufferUsages::empty());
    let out = buf("probe output", bytemuck::cast_slice(&vec![f32::NAN; 3 * dirs.len()]), wgpu::BufferUsages::COPY_SRC);
    ctx.scoped("probing brdf_eval", || {
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("brdf probe"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("brdf probe"),
            layout: None,
            module: &module,
            entry_point: Some("probe"),
            compilation_options: Default::default(),
            cache: None,
        });
        let entries = [
            wgpu::BindGroupEntry { binding: 0, resource: dirs_buf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 13, resource: brdf_buf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 14, resource: coating_buf.as_entire_binding() },
        ];
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brdf probe"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        {
            let mut cp = enc.begin_compute_pass(&Default::default());
            cp.set_pipeline(&pipeline);
            cp.set_bind_group(0, &bind_group, &[]);
            cp.dispatch_workgroups((dirs.len() as u32).div_ceil(64), 1, 1);
        }
        ctx.queue.submit([enc.finish()]);
    })
    .unwrap();
    let got =
        crate::context::bytes_to_f32(&ctx.read_buffer("probe output", &out, 0, (12 * dirs.len()) as u64).unwrap());
    got.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// A unit direction of the upper hemisphere at polar cosine `z` and azimuth `phi`, in f32.
fn dir(z: f64, phi: f64) -> Vec3 {
    let s = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z).normalize().as_vec3()
}

/// Light and view pairs: random ones over the hemisphere, and stiff ones: grazing (cosines
/// down to 1e-3), the mirror configuration (the specular peak), light equal to view, normal
/// incidence.
fn directions(rng: &mut ChaCha8Rng) -> Vec<(Vec3, Vec3)> {
    let mut d = vec![];
    let mut r = || (rng.gen_range(0.0..1.0f64), rng.gen_range(0.0..std::f64::consts::TAU));
    for _ in 0..3000 {
        let ((z1, p1), (z2, p2)) = (r(), r());
        d.push((dir(z1.max(1e-3), p1), dir(z2.max(1e-3), p2)));
    }
    for _ in 0..1000 {
        let ((z, p), (dz, dp)) = (r(), r());
        // Near the mirror direction: within 0.05 in cosine and azimuth.
        let view = dir((z + 0.05 * (dz - 0.5)).clamp(1e-3, 1.0), p + std::f64::consts::PI + 0.05 * (dp - 3.0));
        d.push((dir(z.max(1e-3), p), view));
    }
    for z in [1e-3, 1e-2, 0.1, 0.5, 0.9, 1.0] {
        d.push((dir(z, 0.3), dir(z, 0.3 + std::f64::consts::PI)));
        d.push((dir(z, 1.1), dir(z, 1.1)));
        d.push((dir(1.0, 0.0), dir(z, 2.0)));
    }
    d
}

/// The bound of the module docs for `brdf` at `(l, v)` around the f64 value `f`.
fn brdf_bound(brdf: &Brdf, l: DVec3, v: DVec3, f: [f64; 3]) -> [f64; 3] {
    let exponent = match *brdf {
        Brdf::Phong { exponent, .. } => exponent as f64,
        Brdf::AshikhminShirley { nu, nv, .. } => nu.max(nv) as f64,
        _ => 0.0,
    };
    // pow: log2's 2^-21 scaled by e (through exp2, ln 2 relative), exp2's (3 + 2 |y|) ulp with
    // |y| <= e * 24 for the cosines here (>= 2^-24).
    let pow = exponent * 2f64.powi(-21) * std::f64::consts::LN_2 + (3.0 + 48.0 * exponent) * 2.0 * U;
    let rel = 128.0 * U + pow;
    let step = 32.0 * U;
    let mut moved = [0.0f64; 3];
    for axis in [DVec3::X, DVec3::Y, DVec3::Z, -DVec3::X, -DVec3::Y, -DVec3::Z] {
        for (l2, v2) in [((l + axis * step).normalize(), v), (l, (v + axis * step).normalize())] {
            let g = brdf.eval(l2, v2);
            (0..3).for_each(|c| moved[c] = moved[c].max((g[c] - f[c]).abs()));
        }
    }
    std::array::from_fn(|c| rel * f[c].abs() + moved[c])
}

#[test]
fn brdf_matches_the_cpu() {
    let ctx = gpu_or_skip!();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let dirs = directions(&mut rng);
    for brdf in Brdf::one_of_each() {
        let got = probe(ctx, &brdf, &dirs);
        let (mut worst, mut worst_rel) = (0.0f64, 0.0f64);
        for ((l, v), g) in dirs.iter().zip(&got) {
            let (l, v) = (l.as_dvec3(), v.as_dvec3());
            let f = brdf.eval(l, v);
            let bound = brdf_bound(&brdf, l, v, f);
            for c in 0..3 {
                let err = (g[c] as f64 - f[c]).abs();
                assert!(
                    err <= bound[c],
                    "{brdf:?} at light {l}, view {v}, channel {c}: GPU {} vs CPU {} (error {err:e}, bound {:e})",
                    g[c],
                    f[c],
                    bound[c]
                );
                worst = worst.max(err / bound[c].max(1e-300));
                if f[c].abs() > 1e-6 {
                    worst_rel = worst_rel.max(err / f[c].abs());
                }
            }
        }
        eprintln!("{}: largest error / bound {worst:.3e}, largest relative error {worst_rel:.3e}", brdf.kind());
    }
}

/// A UV sphere with two materials (alternate triangles): Phong BTF tables on `m x m` bins with
/// 4x4 views, and the three moment gathers of a light made of `texels` directions per bin
/// (random radiance, directions random within each vertex's upper hemisphere, so the powers
/// are non-negative at the vertex and nearly so between), or of one sun for `texels = 0`.
struct Case {
    scene: ShadeScene,
    frames: Vec<VertexFrame>,
    moments: [LocalRadiance; 3],
}

fn case(m: u32, texels: usize, seed: u64) -> Case {
    case_with(m, texels, seed, None)
}

/// [`case`], with material 1 an LPCA of a random 4x3-texel BTF (`m = 4`) on a sphere with
/// cylindrical UVs when `lpca` is given.
fn case_with(m: u32, texels: usize, seed: u64, lpca: Option<LpcaSettings>) -> Case {
    let sphere = shapes::uv_sphere(Vec3::ZERO, 1.0, 10, 20);
    let mesh = if lpca.is_some() { shapes::cylindrical_uvs(&sphere) } else { sphere };
    let (frames, _) = vertex_frames(&mesh);
    let basis = bins(m);
    let second = match &lpca {
        None => Material::new(Btf::phong([0.5, 0.5, 0.5], [0.2, 0.2, 0.2], 6.0, basis, 4).unwrap()),
        Some(settings) => {
            assert_eq!(m, 4, "the random BTF has 4x4 light bins");
            let (l, _) = LpcaBtf::compress(&random_btf(4, 3, 3, seed), settings, 11).unwrap();
            Material { btf: l.into(), tiling: 2.0 }
        }
    };
    let materials = vec![Material::new(Btf::phong([0.3, 0.25, 0.2], [0.4, 0.5, 0.6], 16.0, basis, 4).unwrap()), second];
    let ids = (0..mesh.triangle_count() as u32).map(|t| t % 2).collect();
    let nv = mesh.positions.len();
    let bins_per_vertex = basis.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sun = Vec3::new(0.4, 0.8, 0.45).normalize();
    let mut along = [
        vec![[0.0f32; 3]; nv * bins_per_vertex],
        vec![[0.0; 3]; nv * bins_per_vertex],
        vec![[0.0; 3]; nv * bins_per_vertex],
    ];
    for (v, frame) in frames.iter().enumerate() {
        for j in 0..bins_per_vertex {
            let mut d = [DVec3::ZERO; 3];
            if texels == 0 {
                if j == 0 && frame.normal.dot(sun) > 0.0 {
                    d = [3.0, 2.5, 2.0].map(|e| sun.as_dvec3() * e);
                }
            } else {
                for _ in 0..texels {
                    let local = dir(rng.gen_range(0.02..1.0), rng.gen_range(0.0..std::f64::consts::TAU)).as_dvec3();
                    let w = frame.tangent.as_dvec3() * local.x
                        + frame.bitangent.as_dvec3() * local.y
                        + frame.normal.as_dvec3() * local.z;
                    for (c, dc) in d.iter_mut().enumerate() {
                        *dc += w * rng.gen_range(0.0..1.0) * [1.0, 0.8, 0.6][c];
                    }
                }
            }
            for a in 0..3 {
                along[a][v * bins_per_vertex + j] = std::array::from_fn(|c| d[c][a] as f32);
            }
        }
    }
    let moments = along.map(|values| LocalRadiance::new(basis, nv, values).unwrap());
    Case { scene: ShadeScene::new(mesh, frames.clone(), materials, Some(ids)).unwrap(), frames, moments }
}

/// A camera at `position` looking at the sphere's centre, one sample per pixel.
fn camera_at(position: Vec3, width: u32, height: u32) -> Camera {
    Camera { position, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 45.0, width, height, samples_per_pixel: 1 }
}

/// `case`'s moments resident on the GPU, as the gathers leave them.
fn moments_on_gpu(ctx: &GpuContext, case: &Case, m: u32) -> GpuMoments {
    let nv = case.frames.len();
    let t = random_transfer(nv, m, 2, 0.05, 3);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut g = GpuMoments::new(upload(ctx, &Sparse, &form), &case.frames).unwrap();
    let [x, y, z] = &case.moments;
    g.resolve([x, y, z], Lobe::MeanDirection).unwrap();
    g
}

#[test]
fn per_pixel_resolves_match_the_cpu_for_every_material_kind() {
    let ctx = gpu_or_skip!();
    let camera = camera_at(Vec3::new(0.6, 0.9, 3.0), 48, 36);
    for (m, texels, seed) in [(4u32, 0usize, 1u64), (8, 3, 2), (4, 2, 3)] {
        let case = case(m, texels, seed);
        let g = moments_on_gpu(ctx, &case, m);
        let mut shader = GpuShader::new(ctx, &case.scene, &camera).unwrap();
        let [x, y, z] = &case.moments;
        let what = format!(
            "m = {m}, {} per bin",
            if texels == 0 { "one sun".to_string() } else { format!("{texels} texels") }
        );
        // The tables' resolve.
        let gpu = shader.shade_moments(&g, MomentsResolve::Pixel).unwrap();
        let cpu = shade_moments(&case.scene, [x, y, z], Lobe::MeanDirection, &camera).unwrap();
        let (mismatched, worst) = compare(&gpu, &cpu, 2e-4);
        eprintln!("pixel, {what}: {mismatched} coverage mismatches, worst relative error {worst:.3e}");
        // Each analytic kind on material 0, the tables on material 1.
        for brdf in Brdf::one_of_each() {
            let brdfs = [Some(brdf), None];
            shader.set_brdfs(&brdfs).unwrap();
            let gpu = shader.shade_moments(&g, MomentsResolve::PixelAnalytic).unwrap();
            let cpu = shade_moments_analytic(&case.scene, [x, y, z], &brdfs, &camera).unwrap();
            let (mismatched, worst) = compare(&gpu, &cpu, 2e-4);
            eprintln!(
                "pixel_analytic {}, {what}: {mismatched} coverage mismatches, worst relative error {worst:.3e}",
                brdf.kind()
            );
        }
        // The vertex resolve through the same entry point is the L*' pass.
        let vertex = shader.shade_moments(&g, MomentsResolve::Vertex).unwrap();
        assert_eq!(vertex.image.pixels, shader.shade(&g).unwrap().image.pixels);
    }
}

/// The table resolve reads an LPCA BTF (beside a dense one) as the CPU does, per texel and per
/// view, under a sun and under texels spread over the hemisphere. Bound: the images' `2e-4`;
/// the LPCA's own f32 sums add `(M + 4 (C + 1)) u`, `4e-6` for `M = 16`, `C <= 3`
/// (`tests/shading.rs`). A wrong cluster, segment or weight is an O(1) error.
#[test]
fn the_table_resolve_reads_lpca_btfs_like_the_cpu() {
    let ctx = gpu_or_skip!();
    let camera = camera_at(Vec3::new(0.6, 0.9, 3.0), 48, 36);
    for (settings, texels, seed) in
        [(LpcaSettings::new(3, 2), 0usize, 4u64), (LpcaSettings::new(4, 3).per_view(), 2, 5)]
    {
        let case = case_with(4, texels, seed, Some(settings));
        let g = moments_on_gpu(ctx, &case, 4);
        let mut shader = GpuShader::new(ctx, &case.scene, &camera).unwrap();
        let [x, y, z] = &case.moments;
        let gpu = shader.shade_moments(&g, MomentsResolve::Pixel).unwrap();
        let cpu = shade_moments(&case.scene, [x, y, z], Lobe::MeanDirection, &camera).unwrap();
        let (mismatched, worst) = compare(&gpu, &cpu, 2e-4);
        eprintln!("pixel, LPCA {settings:?}, {texels} texels: {mismatched} coverage mismatches, worst {worst:.3e}");
        // Material 1 (the LPCA) is where the analytic resolve falls back to the tables.
        let brdfs = [Some(Brdf::one_of_each()[0]), None];
        shader.set_brdfs(&brdfs).unwrap();
        let gpu = shader.shade_moments(&g, MomentsResolve::PixelAnalytic).unwrap();
        let cpu = shade_moments_analytic(&case.scene, [x, y, z], &brdfs, &camera).unwrap();
        let (mismatched, worst) = compare(&gpu, &cpu, 2e-4);
        eprintln!("pixel_analytic + LPCA tables: {mismatched} coverage mismatches, worst {worst:.3e}");
    }
}

#[test]
fn per_pixel_resolves_refuse_what_they_cannot_shade() {
    let ctx = gpu_or_skip!();
    let case = case(4, 1, 5);
    let camera = camera_at(Vec3::new(0.0, 0.0, 3.0), 8, 8);
    let mut shader = GpuShader::new(ctx, &case.scene, &camera).unwrap();
    let e = shader.set_brdfs(&[None]).unwrap_err().to_string();
    assert!(e.contains("1 analytic BRDFs for 2 materials"), "{e}");
    let bad = Brdf::Phong { kd: [0.1; 3], ks: [0.1; 3], exponent: -1.0 };
    let e = shader.set_brdfs(&[Some(bad), None]).unwrap_err().to_string();
    assert!(e.contains("exponent"), "{e}");
    // Moments of another size than the scene's L*.
    let other = case_with_vertices(ctx, 4);
    let e = shader.shade_moments(&other, MomentsResolve::Pixel).unwrap_err().to_string();
    assert!(e.contains("vertices") || e.contains("L*"), "{e}");
}

/// Moments on the GPU for a form of `vertices` vertices on 4x4 bins.
fn case_with_vertices(ctx: &GpuContext, vertices: usize) -> GpuMoments {
    let t = random_transfer(vertices, 4, 2, 0.2, 9);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let frames = vec![VertexFrame::from_normal(Vec3::Z); vertices];
    GpuMoments::new(upload(ctx, &Sparse, &form), &frames).unwrap()
}
