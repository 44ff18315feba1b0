//! GPU gather and shade timings at bunny size.
//!
//! The bunny mesh (1839 vertices, `assets/meshes/bunny.obj`) with its real transfer matrix
//! (`--real`: traced with `transfer::build` at the reference settings, 6x64x64 visibility
//! box-filtered to 6x32x32, 8x8 local bins) or, by default, a random matrix of the same shape
//! and density (1839 x 64 rows, N = 6 x 32^2 = 6144 columns, ~1.4 % non-zeros, ~10 million,
//! values in {1/4, 1/2, 3/4, 1}); a random HDR light (a 10^6 sun), and a
//! view-dependent Phong BTF (8x8 lights, 12x12 views) on a 32x32-texel patch, shaded at
//! 640x480. Prints medians over `--reps` repetitions, per pass, and the CPU gather for
//! comparison (its error against the f64 reference too); `--all-kinds` adds the Haar (12 terms),
//! CPCA (32 x 8) and bicluster forms.
//!
//! ```text
//! cargo run --release -p biscale-gpu --example gpu_bench -- [--real] [--reps 10] [--density 0.0138]
//!     [--local 8] [--texels 32] [--width 640 --height 480] [--all-kinds]
//! ```

use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{random_light, random_transfer};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::geometry::{vertex_frames, Mesh};
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_gpu::{GpuContext, GpuGather, GpuShader, Timing};
use std::time::Instant;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(|v| v.parse().unwrap_or_else(|_| panic!("bad value for {name}: {v}")))
        .unwrap_or(default)
}

fn show(stage: &str, t: &Timing) {
    let passes: Vec<String> = t.passes.iter().map(|p| format!("{} {:.3} ms", p.name, p.median_ms)).collect();
    println!(
        "{stage}: median {:.3} ms over {} reps ({:?}) [{}]",
        t.median_ms,
        t.repetitions,
        t.method,
        passes.join(", ")
    );
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let reps: usize = arg("--reps", 10);
    let density: f64 = arg("--density", 0.0138);
    let local_m: u32 = arg("--local", 8);
    let texels: u32 = arg("--texels", 32);
    let (width, height): (u32, u32) = (arg("--width", 640), arg("--height", 480));

    let ctx = GpuContext::new()?;
    println!("adapter: {} (timestamps: {})", ctx.adapter(), ctx.has_timestamps());
    let l = ctx.limits();
    println!(
        "limits: max_storage_buffer_binding_size {} MiB, max_buffer_size {} MiB, max_compute_workgroups_per_dimension {}",
        l.max_storage_buffer_binding_size >> 20,
        l.max_buffer_size >> 20,
        l.max_compute_workgroups_per_dimension
    );

    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mesh: Mesh = biscale_core::geometry::Mesh::load_obj(&root.join("assets/meshes/bunny.obj"))?.mesh;
    let (frames, _) = vertex_frames(&mesh);
    let m = (local_m * local_m) as usize;

    let start = Instant::now();
    let real = std::env::args().any(|a| a == "--real");
    let t = if real {
        let settings = biscale_core::transfer::TransferSettings::default().with_local_grid(local_m)?;
        biscale_core::transfer::build(&mesh, &settings, None)?.matrix
    } else {
        random_transfer(mesh.positions.len(), local_m, 32, density, 1)
    };
    println!(
        "{} T: {} x {} ({} vertices x {m}), {} non-zeros ({:.2} %), built in {:.1} s",
        if real { "bunny" } else { "random" },
        t.rows(),
        t.cols(),
        t.vertices(),
        t.nnz(),
        100.0 * t.nnz() as f64 / (t.rows() as f64 * t.cols() as f64),
        start.elapsed().as_secs_f64()
    );
    let form = Sparse.compress(&t, &CompressContext::default())?;
    let light = random_light(32, 3);

    // Gather.
    let start = Instant::now();
    let mut gather = GpuGather::new(&ctx, &form, &Sparse.kernels(&form)?)?;
    println!(
        "upload + pipeline: {:.1} ms, {:.1} MB",
        start.elapsed().as_secs_f64() * 1e3,
        gather.uploaded_bytes() as f64 / 1e6
    );
    let timing = gather.time_gather(&light, reps)?;
    show("GPU gather (sparse)", &timing);
    let gpu_lstar = gather.read_lstar()?;
    let reference = reference_product(&t, &light);
    let mut cpu_ms = vec![];
    let mut cpu_lstar = None;
    for _ in 0..reps.clamp(1, 5) {
        let s = Instant::now();
        cpu_lstar = Some(Sparse.gather(&form, &light)?);
        cpu_ms.push(s.elapsed().as_secs_f64() * 1e3);
    }
    let cpu_median = biscale_gpu::timing::median(&cpu_ms);
    println!(
        "CPU gather (sparse, rayon): median {cpu_median:.3} ms over {} reps; GPU/CPU time ratio {:.2}",
        cpu_ms.len(),
        timing.median_ms / cpu_median
    );
    println!(
        "relative L2 error vs f64 reference: GPU {:.2e}, CPU f32 {:.2e}",
        relative_l2_error(gpu_lstar.values(), &reference),
        relative_l2_error(cpu_lstar.unwrap().values(), &reference)
    );

    // The other built-in compressed forms (--all-kinds): build time, GPU and CPU gathers.
    if std::env::args().any(|a| a == "--all-kinds") {
        use biscale_compressors::{bicluster::Bicluster, cpca::Cpca, haar::Haar};
        let compressors: Vec<Box<dyn Compressor>> =
            vec![Box::new(Haar::with_terms(12)), Box::new(Cpca::new(32, 8)), Box::new(Bicluster::default())];
        for c in compressors {
            let f = c.compress(&t, &CompressContext::default())?;
            let mut g = GpuGather::new(&ctx, &f, &c.kernels(&f)?)?;
            let timing = g.time_gather(&light, reps)?;
            let gpu_l = g.read_lstar()?;
            let s = Instant::now();
            let cpu_l = c.gather(&f, &light)?;
            let cpu_ms = s.elapsed().as_secs_f64() * 1e3;
            println!(
                "{}: {:.1} MB, built in {:.1} s; CPU gather {cpu_ms:.1} ms (one run); rel. L2 error GPU {:.2e} CPU {:.2e}",
                f.kind,
                f.bytes() as f64 / 1e6,
                f.build_seconds,
                relative_l2_error(gpu_l.values(), &reference),
                relative_l2_error(cpu_l.values(), &reference)
            );
            show(&format!("GPU gather ({})", f.kind), &timing);
        }
    }

    // Shade.
    let phong = Btf::phong([0.5, 0.45, 0.4], [0.3, 0.3, 0.3], 20.0, t.local_basis(), 12)?;
    let per_texel = phong.data().len();
    let mut data = Vec::with_capacity(per_texel * (texels * texels) as usize);
    for i in 0..texels * texels {
        let s = 0.5 + 0.5 * (i.wrapping_mul(2654435761) as f32 / u32::MAX as f32);
        data.extend(phong.data().iter().map(|b| b.map(|x| x * s)));
    }
    let (lo, hi) = mesh.bounds();
    let camera = Camera::frame_bounds(lo, hi, width, height, 30.0, 20.0, 40.0);
    let btf = Btf::new([texels, texels], t.local_basis(), phong.view_grid(), data, "bench")?;
    let table_bytes = btf.data().len() * 12;
    let scene = ShadeScene::new(mesh.clone(), frames, vec![Material::new(btf)], None)?;
    let mut shader = GpuShader::new(&ctx, &scene, &camera)?;
    let render = shader.shade(&gather)?;
    let covered = render.mask.iter().filter(|&&c| c).count();
    println!(
        "shade {width}x{height}: {covered} covered pixels ({:.1} %), BTF {texels}x{texels} texels x 144 views x {m} lights ({:.1} MB)",
        100.0 * covered as f64 / render.mask.len() as f64,
        table_bytes as f64 / 1e6
    );
    let timing = shader.time_shade(&gather, reps)?;
    show("GPU shade (visibility + shade)", &timing);
    Ok(())
}
