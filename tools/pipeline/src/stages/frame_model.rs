//! The run's frame-time model (`metrics.json`'s `frame_model`, docs/DESIGN.md "Frame-time
//! model"): each form's gather and shade counted by `biscale_shading::frame_model`, their
//! floors on this machine (its memory bandwidth and fp32 peak measured by [`probe`] before the
//! transfer stage) beside the measured CPU and GPU times, and their floors on the named GPU class
//! (a projection, labelled as one), at the run's resolution and at 1920x1080.

use crate::metrics::{FormFrameModel, FrameModelRecord, Metrics, StageModel};
use biscale_core::scene::Camera;
use biscale_shading::frame_model::{brdf_flops, FrameShape, Processor, StageCost};
use biscale_shading::runtime::MomentsResolve;
use biscale_shading::synth::Brdf;
use rayon::prelude::*;
use std::hint::black_box;
use std::time::Instant;

/// The probe's two copy buffers, 32 MiB each (a copy touches both: twice the 32 MiB
/// last-level cache of the machine it was written on); the run's memory estimate charges them.
/// Part of them may stay in that cache: on that machine it measured 35-59 GB/s where a 256 MiB
/// copy measured 28, so the floors it gives are low (the side on which a ratio to them is never
/// flattering), not high.
pub const PROBE_BYTES: u64 = 2 * (32 << 20);
/// Bytes of each of the copy probe's two buffers.
const COPY_BYTES: usize = (PROBE_BYTES / 2) as usize;
/// Flops one iteration of [`peak_kernel`] does: 12 independent chains of 8 lanes, a fused
/// multiply-add (two flops) each (or, without FMA, a multiply and an add on 4 lanes, twice).
const PEAK_FLOPS_PER_ITERATION: u64 = 12 * 8 * 2;

/// `iterations` of [`PEAK_FLOPS_PER_ITERATION`] flops in independent chains, with the widest
/// vector instructions this CPU has (AVX2 with FMA where detected, else SSE2's multiply and
/// add, which every x86-64 has), so the peak is the hardware's whatever the build's
/// optimisation level; the kernel's name.
fn peak_kernel(iterations: u64) -> (u64, &'static str) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the features the function enables were detected just above.
            return (unsafe { peak_avx2_fma(iterations) }, "AVX2 FMA, 8 lanes");
        }
        (peak_sse2(iterations), "SSE2 multiply and add, 4 lanes")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut acc = [1.0f32; 96];
        let (m, c) = (black_box(0.999_999f32), black_box(1e-7f32));
        for _ in 0..iterations {
            for a in &mut acc {
                *a = *a * m + c;
            }
        }
        black_box(acc);
        (iterations, "scalar multiply and add")
    }
}

/// Twelve chains of eight-lane fused multiply-adds.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn peak_avx2_fma(iterations: u64) -> u64 {
    use std::arch::x86_64::*;
    let m = _mm256_set1_ps(black_box(0.999_999));
    let c = _mm256_set1_ps(black_box(1e-7));
    let mut a = [_mm256_set1_ps(1.0); 12];
    for _ in 0..iterations {
        a[0] = _mm256_fmadd_ps(a[0], m, c);
        a[1] = _mm256_fmadd_ps(a[1], m, c);
        a[2] = _mm256_fmadd_ps(a[2], m, c);
        a[3] = _mm256_fmadd_ps(a[3], m, c);
        a[4] = _mm256_fmadd_ps(a[4], m, c);
        a[5] = _mm256_fmadd_ps(a[5], m, c);
        a[6] = _mm256_fmadd_ps(a[6], m, c);
        a[7] = _mm256_fmadd_ps(a[7], m, c);
        a[8] = _mm256_fmadd_ps(a[8], m, c);
        a[9] = _mm256_fmadd_ps(a[9], m, c);
        a[10] = _mm256_fmadd_ps(a[10], m, c);
        a[11] = _mm256_fmadd_ps(a[11], m, c);
    }
    black_box(a);
    iterations
}

/// Twelve chains of a four-lane multiply and add, twice per iteration (the same flops as
/// [`peak_avx2_fma`]).
#[cfg(target_arch = "x86_64")]
fn peak_sse2(iterations: u64) -> u64 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of x86-64, always available.
    unsafe {
        let m = _mm_set1_ps(black_box(0.999_999));
        let c = _mm_set1_ps(black_box(1e-7));
        let mut a = [_mm_set1_ps(1.0); 12];
        for _ in 0..2 * iterations {
            for x in &mut a {
                *x = _mm_add_ps(_mm_mul_ps(*x, m), c);
            }
        }
        black_box(a);
    }
    iterations
}

/// This machine's memory bandwidth (a STREAM-style parallel copy: one read and one write per
/// byte, the best of five after a warm-up, over every rayon thread) and fp32 peak (independent
/// chains of the widest multiply-adds the CPU has in every thread, [`peak_kernel`]: the
/// hardware's peak, which the runtime's compiled code need not reach), in well under a second.
pub fn probe() -> Processor {
    let n = COPY_BYTES / 4;
    let src: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let mut dst = vec![0.0f32; n];
    let chunk = n.div_ceil(rayon::current_num_threads().max(1) * 4);
    let mut best = f64::INFINITY;
    for run in 0..6 {
        let t = Instant::now();
        dst.par_chunks_mut(chunk).zip(src.par_chunks(chunk)).for_each(|(d, s)| d.copy_from_slice(s));
        black_box(&dst);
        if run > 0 {
            best = best.min(t.elapsed().as_secs_f64());
        }
    }
    let bandwidth_gb_s = 2.0 * COPY_BYTES as f64 / best / 1e9;
    let threads = rayon::current_num_threads().max(1);
    let iterations = 4_000_000u64;
    // Every thread starts its chains at one barrier and the rate is all the threads' flops over
    // the time from the first start to the last finish: the peak of the cores working at once.
    // (Summing per-thread rates counted a core twice when its two threads ran one after the
    // other, as on a busy machine or on two vCPUs that share a core: readings 2x apart.) The
    // best of five.
    let mut peak_gflop_s = 0.0f64;
    let mut kernel = "";
    for _ in 0..5 {
        let barrier = std::sync::Barrier::new(threads);
        let spans: Vec<(Instant, Instant, u64, &'static str)> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|_| {
                    s.spawn(|| {
                        barrier.wait();
                        let t = Instant::now();
                        let (n, name) = peak_kernel(iterations);
                        (t, Instant::now(), n, name)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().expect("the probe's kernel does not panic")).collect()
        });
        let first = spans.iter().map(|s| s.0).min().expect("at least one thread");
        let last = spans.iter().map(|s| s.1).max().expect("at least one thread");
        let flops = spans.iter().map(|s| (s.2 * PEAK_FLOPS_PER_ITERATION) as f64).sum::<f64>();
        kernel = spans[0].3;
        peak_gflop_s = peak_gflop_s.max(flops / (last - first).as_secs_f64().max(1e-9) / 1e9);
    }
    Processor {
        name: format!("this machine ({threads} threads)"),
        bandwidth_gb_s,
        peak_gflop_s,
        source: format!("measured by the run's probe: parallel copy, {kernel}"),
    }
}

/// The frame-time model of the run `m` (its forms' records and shape) seen by its `camera`
/// (the image size and samples per pixel), the scene's analytic BRDFs `analytic` and this
/// machine `here` (from [`probe`]).
pub fn record(m: &Metrics, analytic: &[Option<Brdf>], camera: &Camera, here: Processor) -> FrameModelRecord {
    let (width, height, samples_per_pixel) = (camera.width, camera.height, camera.samples_per_pixel);
    let resolve = m.uncompressed.moments_resolve.unwrap_or(MomentsResolve::Vertex);
    let t = &m.transfer;
    let brdf = match resolve {
        MomentsResolve::PixelAnalytic => {
            analytic.iter().flatten().filter_map(|b| brdf_flops(b.kind())).fold(0.0, f64::max)
        }
        _ => 0.0,
    };
    let projection = Processor::h100_sxm();
    let samples = width as u64 * height as u64 * samples_per_pixel as u64;
    let stage = |cost: StageCost, cpu_ms: Option<f64>, gpu_ms: Option<f64>| StageModel {
        floor_ms: here.floor_ms(&cost),
        projected_ms: projection.floor_ms(&cost),
        stage: cost.stage,
        bytes: cost.bytes,
        flops: cost.flops,
        cpu_ms,
        gpu_ms,
    };
    let forms = m
        .compressors
        .iter()
        .map(|c| {
            let shape = FrameShape {
                vertices: m.scene.vertices as u64,
                bins: t.local_dirs as u64,
                cols: t.cols as u64,
                samples,
                form_bytes: c.bytes,
                flops_per_gather: c.flops_per_gather,
                material_bytes: m.scene.btf_bytes,
                moments: m.uncompressed.light_moments,
                resolve,
                brdf_flops: brdf,
            };
            let hd = shape.at_samples(1920 * 1080);
            FormFrameModel {
                name: c.name.clone(),
                gather: stage(shape.gather(), Some(c.gather_ms), c.gpu.as_ref().map(|g| g.gather_ms)),
                shade: stage(shape.shade(), Some(c.shade_ms), c.gpu.as_ref().map(|g| g.shade_ms)),
                shade_1080p_projected_ms: projection.floor_ms(&hd.shade()),
            }
        })
        .collect();
    FrameModelRecord { width, height, samples_per_pixel, resolve, machine: here, projection, forms }
}
