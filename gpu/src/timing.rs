//! Run-time measurement of GPU stages (docs/DESIGN.md section 8: medians over repetitions).
//!
//! Where the context uses timestamp queries ([`crate::GpuContext::has_timestamps`]: a GPU that
//! has them, or any adapter with `TimestampPolicy::Always`), every pass (one compute dispatch
//! or one render pass) is bracketed by GPU timestamps and its duration read back; otherwise
//! (CPU adapters such as lavapipe by default) each repetition is submitted on its own and
//! timed by the wall clock from submit until the queue is idle.

use crate::context::GpuContext;
use crate::error::{GpuError, Result};
use std::time::Instant;

/// How a [`Timing`] was measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimingMethod {
    /// GPU timestamps written at the beginning and end of every pass.
    GpuTimestamps,
    /// Host wall clock from submit to idle (includes submission overhead).
    WallClock,
}

/// The median duration of one pass over the repetitions.
#[derive(Clone, Debug, PartialEq)]
pub struct PassTiming {
    /// Kernel or pass name (the WGSL entry point, or `visibility` / `shade`).
    pub name: String,
    pub median_ms: f64,
}

/// Medians of a stage over `repetitions` runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Timing {
    /// Median over repetitions of the whole stage (sum of its passes for timestamps).
    pub median_ms: f64,
    /// Per-pass medians (empty for wall-clock timings, which cannot separate passes).
    pub passes: Vec<PassTiming>,
    pub method: TimingMethod,
    pub repetitions: usize,
}

/// The one median of biscale's measurements (core's), re-exported for the GPU timings.
pub use biscale_core::stats::median;

/// A timestamp query set with two queries per pass, and the buffers to read it back.
pub(crate) struct PassTimer {
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    staging: wgpu::Buffer,
    passes: u32,
    period_ns: f64,
}

impl PassTimer {
    /// A timer for `passes` passes, or `None` when the context has no timestamp queries.
    pub(crate) fn new(ctx: &GpuContext, passes: u32) -> Result<Option<Self>> {
        if !ctx.has_timestamps() || passes == 0 {
            return Ok(None);
        }
        let count = 2 * passes;
        let bytes = count as u64 * wgpu::QUERY_SIZE as u64;
        ctx.scoped("creating timestamp queries", || {
            let query_set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count,
            });
            let resolve = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            Some(Self { query_set, resolve, staging, passes, period_ns: ctx.queue.get_timestamp_period() as f64 })
        })
    }

    pub(crate) fn compute_writes(&self, pass: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.query_set,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    pub(crate) fn render_writes(&self, pass: u32) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.query_set,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    /// Record the resolve of all queries and their copy to the read-back buffer.
    pub(crate) fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        enc.resolve_query_set(&self.query_set, 0..2 * self.passes, &self.resolve, 0);
        enc.copy_buffer_to_buffer(&self.resolve, 0, &self.staging, 0, self.resolve.size());
    }

    /// Milliseconds of every pass of the last submission that called [`Self::resolve`].
    pub(crate) fn read_ms(&self, ctx: &GpuContext) -> Result<Vec<f64>> {
        let bytes = ctx.map_read("timestamps", &self.staging)?;
        let ticks: Vec<u64> = bytes.chunks_exact(8).map(|c| u64::from_le_bytes(c.try_into().unwrap())).collect();
        let mut out = Vec::with_capacity(self.passes as usize);
        for p in 0..self.passes as usize {
            let (a, b) = (ticks[2 * p], ticks[2 * p + 1]);
            if b < a {
                return Err(GpuError::Readback {
                    what: "timestamps".into(),
                    message: format!("pass {p} ends (tick {b}) before it begins (tick {a})"),
                });
            }
            out.push((b - a) as f64 * self.period_ns * 1e-6);
        }
        Ok(out)
    }
}

/// Time `repetitions` runs of a stage whose passes are named `names`. `record` encodes one
/// run into the encoder, writing pass `i`'s timestamps through the timer when one is given.
pub(crate) fn measure(
    ctx: &GpuContext,
    names: &[String],
    repetitions: usize,
    mut record: impl FnMut(&mut wgpu::CommandEncoder, Option<&PassTimer>),
) -> Result<Timing> {
    let repetitions = repetitions.max(1);
    let timer = PassTimer::new(ctx, names.len() as u32)?;
    let mut totals = Vec::with_capacity(repetitions);
    let mut per_pass: Vec<Vec<f64>> = vec![Vec::with_capacity(repetitions); names.len()];
    for _ in 0..repetitions {
        let start = Instant::now();
        ctx.scoped("timing a stage", || {
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            record(&mut enc, timer.as_ref());
            if let Some(t) = &timer {
                t.resolve(&mut enc);
            }
            ctx.queue.submit([enc.finish()]);
        })?;
        ctx.wait("a timed stage")?;
        let wall = start.elapsed().as_secs_f64() * 1e3;
        match &timer {
            Some(t) => {
                let ms = t.read_ms(ctx)?;
                totals.push(ms.iter().sum());
                for (acc, v) in per_pass.iter_mut().zip(ms) {
                    acc.push(v);
                }
            }
            None => totals.push(wall),
        }
    }
    let passes = if timer.is_some() {
        names.iter().zip(&per_pass).map(|(n, v)| PassTiming { name: n.clone(), median_ms: median(v) }).collect()
    } else {
        vec![]
    };
    Ok(Timing {
        median_ms: median(&totals),
        passes,
        method: if timer.is_some() { TimingMethod::GpuTimestamps } else { TimingMethod::WallClock },
        repetitions,
    })
}
