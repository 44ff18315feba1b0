//! Every built-in gather against its memory-bandwidth floor (a gather should
//! sit within 3x of the time it takes to stream its compressed bytes once at copy bandwidth).
//!
//! For the mesh's real transfer matrix (traced with `transfer::build` at the reference
//! settings, as `bicluster_bench` and `gpu_bench --real` do) and a random light, each
//! compressor (sparse, bicluster default, cpca 32 x 8, haar 12) is compressed once and its
//! gather timed. The bytes a gather must move at least once are counted as
//!
//! * the form's arrays at their stored width (`CompressedForm::bytes`; on the GPU the arrays
//!   packed into 32-bit words, `GpuGather::uploaded_bytes`, which only adds padding), plus
//! * the light vector read, N x RGB f32 = 12 N bytes, plus
//! * `L*` written, rows x RGB f32 = 12 rows bytes.
//!
//! Scratch arrays a gather writes and re-reads (bicluster's per-bicluster scalars, cpca's
//! projections) are not counted: the floor is what any gather of this form must touch.
//!
//! Copy bandwidth is measured the way STREAM's "Copy" counts it: `2 x bytes` (one read, one
//! write) per copy of a buffer much larger than the last-level cache, median of `--runs`
//! copies after one warm-up: single-threaded `copy_from_slice` and the same split over rayon's
//! threads (the CPU gathers are rayon-parallel). On wgpu, `copy_buffer_to_buffer` of a
//! buffer of the same size, timed by the wall clock from submit until the device is idle (wgpu
//! cannot put timestamps around a copy without `TIMESTAMP_QUERY_INSIDE_ENCODERS`); the gather
//! is timed both by `GpuGather::time_gather` (per-pass GPU timestamps where the adapter has
//! them) and by the same submit-and-wait wall clock as the copy. The floor is
//! `bytes / bandwidth`; the ratio is `gather time / floor` (3 or less meets the goal).
//!
//! ```text
//! cargo run --release -p biscale-gpu --example gather_floor -- \
//!     [--mesh assets/meshes/bunny.obj] [--runs 10] [--local-grid 8] [--copy-mib 1024] [--no-gpu]
//!     [--sh-order 5 [--sh-rays 1024]]
//! ```
//!
//! With `--sh-order n` the matrix is the low-frequency method's `M` instead (one
//! n^2 x n^2 block per vertex, traced with `transfer::sh::build_sh` at `--sh-rays` rays per
//! vertex, its build timed over `--runs` builds), the light the SH projection of the random
//! cubemap light, and the forms the raw `sparse` one (the method's default) and CPCA of whole
//! vertex blocks (32 x 8, `unit = "vertex"`). The goal there is 2x of the floor on the CPU.

use biscale_compressors::bicluster::Bicluster;
use biscale_compressors::cpca::{Cpca, CpcaUnit};
use biscale_compressors::haar::Haar;
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::random_light;
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::LightVector;
use biscale_core::sh::light::LIGHT_SUBTEXELS;
use biscale_core::sh::{ShOrder, ShProjection};
use biscale_core::transfer::sh::{build_sh, ShTransferSettings};
use biscale_core::transfer::{self, TransferMatrix, TransferScene, TransferSettings};
use biscale_gpu::timing::median;
use biscale_gpu::{GpuContext, GpuGather};
use rayon::prelude::*;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

/// The floor under the GPU gather: copy bandwidth, and the gather on the GPU and the CPU.
#[derive(clap::Parser)]
struct Args {
    /// The mesh T is built for (also relative to the repository root).
    #[arg(long, default_value = "assets/meshes/bunny.obj")]
    mesh: PathBuf,
    /// Timed runs of each measurement.
    #[arg(long, default_value_t = 10)]
    runs: usize,
    /// Local bins per side, m.
    #[arg(long, default_value_t = 8)]
    local_grid: u32,
    /// Size of the copy-bandwidth buffer in MiB.
    #[arg(long, default_value_t = 1024)]
    copy_mib: usize,
    /// Measure the CPU only.
    #[arg(long)]
    no_gpu: bool,
    /// Measure the SH method's `M` of this order (2..8) instead of `T`.
    #[arg(long)]
    sh_order: Option<u32>,
    /// Rays per vertex of the SH transfer build.
    #[arg(long, default_value_t = 1024)]
    sh_rays: u32,
}

fn parse() -> Result<Args, String> {
    let mut a = <Args as clap::Parser>::parse();
    (a.runs, a.copy_mib) = (a.runs.max(1), a.copy_mib.max(1));
    if !a.mesh.exists() {
        // Also accept paths relative to the repository root (cargo runs examples from the cwd).
        let rooted = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join(&a.mesh);
        if rooted.exists() {
            a.mesh = rooted;
        } else {
            return Err(format!("mesh {} not found", a.mesh.display()));
        }
    }
    Ok(a)
}

/// Median milliseconds of `runs` calls of `f`, after one untimed warm-up call.
fn time_ms<E>(runs: usize, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    f()?;
    let mut ms = Vec::with_capacity(runs);
    for _ in 0..runs {
        let s = Instant::now();
        f()?;
        ms.push(s.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(&ms))
}

/// STREAM-Copy bandwidths in bytes/s (2 x size per copy): (single-threaded, rayon).
fn cpu_copy_bandwidth(bytes: usize, runs: usize) -> (f64, f64) {
    // Both buffers written before timing, so no copy reads the shared zero page.
    let src: Vec<u64> = (0..bytes / 8).map(|i| i as u64).collect();
    let mut dst: Vec<u64> = vec![1; bytes / 8];
    let moved = 2.0 * (src.len() * 8) as f64;
    let single = time_ms(runs, || {
        dst.copy_from_slice(black_box(&src));
        black_box(&mut dst);
        Ok::<(), ()>(())
    })
    .unwrap();
    // One contiguous piece per thread, as STREAM's OpenMP static schedule does.
    let chunk = src.len().div_ceil(rayon::current_num_threads().max(1)).max(1);
    let parallel = time_ms(runs, || {
        dst.par_chunks_mut(chunk).zip(black_box(&src).par_chunks(chunk)).for_each(|(d, s)| d.copy_from_slice(s));
        black_box(&mut dst);
        Ok::<(), ()>(())
    })
    .unwrap();
    (moved / (single * 1e-3), moved / (parallel * 1e-3))
}

/// wgpu `copy_buffer_to_buffer` bandwidth in bytes/s (2 x size per copy), submit-and-wait
/// wall clock; returns the bandwidth and the size actually copied (clamped to the limits).
fn gpu_copy_bandwidth(ctx: &GpuContext, bytes: u64, runs: usize) -> Result<(f64, u64), Box<dyn std::error::Error>> {
    let size = bytes.min(ctx.limits().max_buffer_size) / 4 * 4;
    let device = ctx.device();
    let make = |label, usage| {
        device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size, usage, mapped_at_creation: false })
    };
    let src = make("copy src", wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST);
    let dst = make("copy dst", wgpu::BufferUsages::COPY_DST);
    // Write the source with non-zero data (in 64 MiB pieces to bound the staging memory).
    let piece: Vec<u32> = (0..(64u64 << 20).min(size) / 4).map(|i| i as u32 | 1).collect();
    let mut off = 0;
    while off < size {
        let n = (size - off).min(piece.len() as u64 * 4);
        ctx.queue().write_buffer(&src, off, bytemuck::cast_slice(&piece[..(n / 4) as usize]));
        off += n;
    }
    let wait = || device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ());
    wait()?;
    let ms = time_ms(runs, || {
        let mut enc = device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&src, 0, &dst, 0, size);
        ctx.queue().submit([enc.finish()]);
        wait()
    })?;
    Ok((2.0 * size as f64 / (ms * 1e-3), size))
}

struct Row {
    kind: String,
    form_bytes: u64,
    io_bytes: u64,
    cpu_ms: f64,
    cpu_err: f64,
    gpu: Option<GpuRow>,
}

struct GpuRow {
    uploaded: u64,
    stamp_ms: f64,
    wall_ms: f64,
    err: f64,
}

fn run_gpu(
    ctx: &GpuContext,
    form: &CompressedForm,
    kernels: &biscale_kernels::KernelDesc,
    light: &LightVector,
    runs: usize,
    reference: &[[f64; 3]],
) -> Result<GpuRow, Box<dyn std::error::Error>> {
    let mut g = GpuGather::new(ctx, form, kernels)?;
    let stamp_ms = g.time_gather(light, runs)?.median_ms;
    let device = ctx.device();
    let wall_ms = time_ms(runs, || -> Result<(), Box<dyn std::error::Error>> {
        g.gather(light)?;
        device.poll(wgpu::PollType::wait_indefinitely())?;
        Ok(())
    })?;
    let err = relative_l2_error(g.read_lstar()?.values(), reference);
    Ok(GpuRow { uploaded: g.uploaded_bytes(), stamp_ms, wall_ms, err })
}

/// The SH transfer matrix of `mesh` and the median seconds of `runs` builds.
fn sh_matrix(
    mesh: &Mesh,
    order: u32,
    rays: u32,
    runs: usize,
) -> Result<(TransferMatrix, f64), Box<dyn std::error::Error>> {
    let scene = TransferScene::new(mesh)?;
    let settings = ShTransferSettings::new(order, rays, 1)?;
    let mut secs = vec![];
    let mut last = None;
    for _ in 0..runs {
        let b = build_sh(&scene, &settings, 0..scene.vertex_count(), None)?;
        secs.push(b.seconds);
        last = Some(b.matrix);
    }
    Ok((last.expect("runs >= 1"), median(&secs)))
}

fn main() {
    if let Err(e) = run() {
        eprintln!("gather_floor: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse()?;
    let mib = |b: f64| b / (1u64 << 20) as f64;
    let gbs = |b: f64| b / 1e9;

    let mesh = Mesh::load_obj(&args.mesh)?.mesh;
    let settings = TransferSettings::default().with_local_grid(args.local_grid)?;
    let cube_light = random_light(settings.cubemap().resolution, 3);
    let (t, light) = match args.sh_order {
        None => {
            let build = transfer::build(&mesh, &settings, None)?;
            println!("T ({}): {build}", args.mesh.display());
            (build.matrix, cube_light)
        }
        Some(order) => {
            let (m, secs) = sh_matrix(&mesh, order, args.sh_rays, args.runs)?;
            println!(
                "M ({}): order {order}, {} x {}, {} rays per vertex, built in {secs:.2} s (median of {} builds, {} rayon threads)",
                args.mesh.display(),
                m.rows(),
                m.cols(),
                args.sh_rays,
                args.runs,
                rayon::current_num_threads()
            );
            let projection = ShProjection::new(settings.cubemap(), ShOrder::new(order)?, LIGHT_SUBTEXELS);
            (m, projection.project(&cube_light)?)
        }
    };
    if light.len() != t.cols() {
        return Err(format!("light has {} texels, T has {} columns", light.len(), t.cols()).into());
    }
    let reference = reference_product(&t, &light);

    let copy_bytes = args.copy_mib << 20;
    let (bw1, bwp) = cpu_copy_bandwidth(copy_bytes, args.runs);
    println!(
        "CPU copy ({} MiB, STREAM Copy count 2 x size): single-threaded {:.2} GB/s, rayon {:.2} GB/s",
        args.copy_mib,
        gbs(bw1),
        gbs(bwp)
    );

    let gpu = if !args.no_gpu {
        match GpuContext::new() {
            Ok(ctx) => {
                println!("adapter: {} (timestamps: {})", ctx.adapter(), ctx.has_timestamps());
                match gpu_copy_bandwidth(&ctx, copy_bytes as u64, args.runs) {
                    Ok((bw, size)) => {
                        println!(
                            "GPU copy_buffer_to_buffer ({:.0} MiB, 2 x size, submit-and-wait): {:.2} GB/s",
                            mib(size as f64),
                            gbs(bw)
                        );
                        Some((ctx, bw))
                    }
                    Err(e) => {
                        println!("GPU part skipped: the copy benchmark failed: {e}");
                        None
                    }
                }
            }
            Err(e) => {
                println!("GPU part skipped: {e}");
                None
            }
        }
    } else {
        println!("GPU part skipped (--no-gpu)");
        None
    };

    let compressors: Vec<Box<dyn Compressor>> = match args.sh_order {
        None => vec![
            Box::new(Sparse),
            Box::new(Bicluster::default()),
            Box::new(Cpca::new(32, 8)),
            Box::new(Haar::with_terms(12)),
        ],
        Some(_) => vec![Box::new(Sparse), Box::new(Cpca { unit: CpcaUnit::Vertex, ..Cpca::new(32, 8) })],
    };
    let io_bytes = 12 * (t.cols() + t.rows()) as u64;
    let mut rows = vec![];
    for c in &compressors {
        let form = c.compress(&t, &CompressContext::default())?;
        let mut out = None;
        let cpu_ms = time_ms(args.runs, || {
            out = Some(c.gather(&form, &light)?);
            Ok::<(), biscale_core::compress::CompressError>(())
        })?;
        let cpu_err = relative_l2_error(out.expect("timed at least once").values(), &reference);
        let gpu = match &gpu {
            Some((ctx, _)) => match run_gpu(ctx, &form, &c.kernels(&form)?, &light, args.runs, &reference) {
                Ok(r) => Some(r),
                Err(e) => {
                    println!("{}: GPU gather skipped: {e}", form.kind);
                    None
                }
            },
            None => None,
        };
        println!(
            "{}: form {:.2} MiB, built in {:.1} s, CPU gather median {cpu_ms:.2} ms (rel. L2 err {cpu_err:.1e}){}",
            form.kind,
            mib(form.bytes() as f64),
            form.build_seconds,
            gpu.as_ref()
                .map(|g| format!(
                    ", GPU gather median {:.2} ms timestamps / {:.2} ms wall (rel. L2 err {:.1e})",
                    g.stamp_ms, g.wall_ms, g.err
                ))
                .unwrap_or_default()
        );
        rows.push(Row { kind: form.kind.clone(), form_bytes: form.bytes(), io_bytes, cpu_ms, cpu_err, gpu });
    }

    println!();
    println!(
        "Bytes = form arrays + light (12 N) + L* written (12 rows = {:.2} MiB incl. light). Floor = bytes / copy bandwidth.",
        mib(io_bytes as f64)
    );
    println!(
        "CPU copy: {:.2} GB/s single-threaded, {:.2} GB/s rayon. Ratio = gather / floor (goal: <= {}).",
        gbs(bw1),
        gbs(bwp),
        if args.sh_order.is_some() { 2 } else { 3 }
    );
    println!();
    println!("| form | bytes MiB | CPU gather ms | floor ms (1 thread / rayon) | ratio (1 thread / rayon) |");
    println!("|---|---|---|---|---|");
    for r in &rows {
        let b = (r.form_bytes + r.io_bytes) as f64;
        let (f1, fp) = (b / bw1 * 1e3, b / bwp * 1e3);
        println!(
            "| {} | {:.2} | {:.2} | {:.2} / {:.2} | {:.1} / {:.1} |",
            r.kind,
            mib(b),
            r.cpu_ms,
            f1,
            fp,
            r.cpu_ms / f1,
            r.cpu_ms / fp
        );
    }
    if let Some((ctx, gbw)) = &gpu {
        println!();
        println!(
            "wgpu on {} ({}): copy_buffer_to_buffer {:.2} GB/s; bytes use the packed upload size.",
            ctx.adapter().name,
            ctx.adapter().device_type,
            gbs(*gbw)
        );
        println!();
        println!("| form | bytes MiB | GPU gather ms (timestamps / wall) | floor ms | ratio (timestamps / wall) |");
        println!("|---|---|---|---|---|");
        for r in &rows {
            if let Some(g) = &r.gpu {
                let b = (g.uploaded + r.io_bytes) as f64;
                let floor = b / gbw * 1e3;
                println!(
                    "| {} | {:.2} | {:.2} / {:.2} | {:.2} | {:.1} / {:.1} |",
                    r.kind,
                    mib(b),
                    g.stamp_ms,
                    g.wall_ms,
                    floor,
                    g.stamp_ms / floor,
                    g.wall_ms / floor
                );
            }
        }
    }
    let worst = rows.iter().map(|r| r.cpu_err).fold(0.0, f64::max);
    println!("\n(largest CPU rel. L2 error vs the f64 reference: {worst:.2e}; lossy forms are expected to be large)");
    Ok(())
}
