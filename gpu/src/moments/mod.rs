//! Light moments on the GPU (`[runtime] light_moments`, docs/DESIGN.md "Known limit of the bin
//! convention, and light moments"): the three direction moments `L d_x, L d_y, L d_z`
//! ([`LightMoments`]) gathered through a form's own program, then resolved into `L*'` by a
//! compute pass (`resolve.wgsl`), so that gather, resolve and shade run with no round trip
//! through the host.
//!
//! Why a GPU pass: `L*'` is not linear in the moments (each bin's power moves to the bins
//! around its mean direction), so it cannot be folded into the gather; without it every light
//! change read three `L*` back, resolved them on the CPU
//! ([`biscale_core::gather::moments::resolve`]) and uploaded the result: three read-backs of
//! `rows x 12` bytes and a CPU pass per frame in the viewer. The kernel is that function in
//! f32 (one invocation per vertex, the same special cases; the tests hold it to a bound
//! derived from f32 rounding, `tests/moments.rs`).
//!
//! The three gathers reuse one [`GpuGather`]: the three moment lights are uploaded once into
//! one buffer, and one command buffer copies each into the gather's light buffer, runs the
//! program and copies `L*` aside (the last one is read in place), then runs the resolve:
//!
//! ```no_run
//! # use biscale_gpu::{GpuContext, GpuGather, GpuMoments};
//! # use biscale_core::gather::moments::LightMoments;
//! # let form: biscale_core::compress::CompressedForm = unimplemented!();
//! # let kernels: biscale_kernels::KernelDesc = unimplemented!();
//! # let light: biscale_core::sampling::LightVector = unimplemented!();
//! # let frames: Vec<biscale_core::geometry::VertexFrame> = unimplemented!();
//! let ctx = GpuContext::new()?;
//! let mut moments = GpuMoments::new(GpuGather::new(&ctx, &form, &kernels)?, &frames)?;
//! moments.gather(&LightMoments::new(&light)?)?;
//! let lstar = moments.read_lstar()?; // or shade straight from it: GpuShader::shade(&moments)
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::context::{bytes_to_f32, GpuContext};
use crate::error::{GpuError, Result};
use crate::gather::{GpuGather, GpuLstar};
use crate::timing::{measure, PassTimer, Timing};
use biscale_core::basis::TransferShape;
use biscale_core::gather::moments::{LightMoments, Lobe};
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::VertexFrame;
use wgpu::util::DeviceExt;

/// The bins of a hemisphere grid located in f32 (`bins.wgsl`: where a bin's light goes), shared
/// by the resolve kernel and the shader's per-pixel resolves.
pub const BINS_WGSL: &str = include_str!("bins.wgsl");

/// The resolve kernel's WGSL ([`BINS_WGSL`] prepended).
pub fn resolve_wgsl() -> String {
    format!("{BINS_WGSL}\n{}", include_str!("resolve.wgsl"))
}

/// Invocations per workgroup of the resolve kernel (`@workgroup_size` in `resolve.wgsl`).
const WORKGROUP: u64 = 64;

/// The resolve kernel's uniform (mirrors WGSL `ResolveParams`; checked by the layout test).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ResolveParams {
    pub vertices: u32,
    /// The local grid's side `m`.
    pub grid: u32,
    /// 0: [`Lobe::MeanDirection`], 1: [`Lobe::BinCentre`].
    pub lobe: u32,
    /// Workgroups along x of the dispatch.
    pub groups_x: u32,
}

/// A form's gather with light moments: the three moment gathers and the resolve into `L*'`,
/// all on the GPU. Owns the [`GpuGather`] it runs three times.
pub struct GpuMoments {
    gather: GpuGather,
    ctx: GpuContext,
    /// The three moment lights, one after another (`3 x cols x RGB` f32).
    lights: wgpu::Buffer,
    /// Copies of the first two moments' `L*` (the third stays in the gather's buffer).
    along: [wgpu::Buffer; 2],
    /// `L*'` (`rows x RGB` f32).
    resolved: wgpu::Buffer,
    /// `1 / cosbar_i` per bin of the local grid (f32), which the resolve and the shader's
    /// per-pixel resolves read.
    inverse_mean_cosine: wgpu::Buffer,
    params: ResolveParams,
    params_buf: wgpu::Buffer,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    workgroups: [u32; 2],
}

impl GpuMoments {
    /// Ready `gather`'s form for light moments: `frames` are the vertex frames `T` was traced
    /// with (one per vertex). An error unless the form's local basis is a grid of bins and its
    /// light basis a cubemap (the moments need texel directions and bin mean cosines), or when
    /// a buffer exceeds the adapter's limits.
    pub fn new(gather: GpuGather, frames: &[VertexFrame]) -> Result<Self> {
        let shape = gather.shape();
        let grid = shape.local.grid().ok_or_else(|| {
            GpuError::Input(format!("light moments need a local basis of bins, the form's is {}", shape.local))
        })?;
        if shape.light.cubemap_layout().is_none() {
            return Err(GpuError::Input(format!(
                "light moments need a cubemap light basis, the form's is the {}",
                shape.light
            )));
        }
        if frames.len() != shape.vertices {
            return Err(GpuError::Input(format!(
                "light moments need one vertex frame per vertex: {} frames for {} vertices",
                frames.len(),
                shape.vertices
            )));
        }
        if shape.vertices > u32::MAX as usize / 9 {
            return Err(GpuError::Form(format!("{} vertices do not fit 32-bit frame indices", shape.vertices)));
        }
        let ctx = gather.ctx().clone();
        let (rows, cols) = (shape.rows() as u64, shape.cols() as u64);
        let lstar_bytes = (rows * 12).max(4);
        let light_bytes = 3 * cols * 12;
        ctx.check_buffer_size("the three moment lights (3 x N x RGB f32)", light_bytes)?;
        let frame_data: Vec<f32> =
            frames.iter().flat_map(|f| [f.tangent, f.bitangent, f.normal]).flat_map(|v| v.to_array()).collect();
        let inv_cosine: Vec<f32> = grid.mean_cosines().iter().map(|c| (1.0 / c) as f32).collect();
        let frames_buf = ctx.storage_buffer(
            "vertex frames (9 f32 each)",
            bytemuck::cast_slice(&frame_data),
            wgpu::BufferUsages::empty(),
        )?;
        let cosine_buf =
            ctx.storage_buffer("inverse mean cosines", bytemuck::cast_slice(&inv_cosine), wgpu::BufferUsages::empty())?;
        for what in ["a moment's L* (rows x RGB f32)", "L*' (rows x RGB f32)"] {
            ctx.check_storage_size(what, lstar_bytes)?;
        }
        let limits = ctx.limits();
        let max_groups = limits.max_compute_workgroups_per_dimension as u64;
        let groups = (shape.vertices as u64).div_ceil(WORKGROUP);
        let x = groups.min(max_groups);
        let y = if x == 0 { 0 } else { groups.div_ceil(x) };
        if y > max_groups {
            return Err(GpuError::Limit {
                what: format!("the light-moments resolve ({groups} workgroups of {WORKGROUP})"),
                limit: "max_compute_workgroups_per_dimension (squared)",
                needed: groups,
                max: max_groups * max_groups,
            });
        }
        let params = ResolveParams { vertices: shape.vertices as u32, grid: grid.m, lobe: 0, groups_x: x as u32 };
        let (lights, along, resolved, params_buf, pipeline, bind_group) =
            ctx.scoped("building the light-moments resolve", || {
                let buffer = |label: &str, size: u64, usage: wgpu::BufferUsages| {
                    ctx.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some(label),
                        size,
                        usage,
                        mapped_at_creation: false,
                    })
                };
                use wgpu::BufferUsages as U;
                let lights = buffer("moment lights", light_bytes.max(4), U::COPY_SRC | U::COPY_DST);
                let along = ["moment L d_x", "moment L d_y"].map(|l| buffer(l, lstar_bytes, U::STORAGE | U::COPY_DST));
                let resolved = buffer("L*' (light moments)", lstar_bytes, U::STORAGE | U::COPY_SRC | U::COPY_DST);
                let params_buf = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("resolve params"),
                    contents: bytemuck::bytes_of(&params),
                    usage: U::UNIFORM | U::COPY_DST,
                });
                let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("light-moments resolve"),
                    source: wgpu::ShaderSource::Wgsl(resolve_wgsl().into()),
                });
                let pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("light-moments resolve"),
                    layout: None,
                    module: &module,
                    entry_point: Some("resolve"),
                    compilation_options: Default::default(),
                    cache: None,
                });
                let entries = [
                    params_buf.as_entire_binding(),
                    along[0].as_entire_binding(),
                    along[1].as_entire_binding(),
                    gather.lstar_buffer().as_entire_binding(),
                    frames_buf.as_entire_binding(),
                    cosine_buf.as_entire_binding(),
                    resolved.as_entire_binding(),
                ];
                let entries: Vec<wgpu::BindGroupEntry<'_>> = entries
                    .into_iter()
                    .enumerate()
                    .map(|(i, resource)| wgpu::BindGroupEntry { binding: i as u32, resource })
                    .collect();
                let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("light-moments resolve"),
                    layout: &pipeline.get_bind_group_layout(0),
                    entries: &entries,
                });
                (lights, along, resolved, params_buf, pipeline, bind_group)
            })?;
        Ok(Self {
            gather,
            ctx,
            lights,
            along,
            resolved,
            inverse_mean_cosine: cosine_buf,
            params,
            params_buf,
            pipeline,
            bind_group,
            workgroups: [x as u32, y as u32],
        })
    }

    /// Gather the three moments of `moments` and resolve them with its lobe; `L*'` is then in
    /// [`Self::lstar_buffer`] (queue order makes it visible to anything submitted later).
    pub fn gather(&mut self, moments: &LightMoments) -> Result<()> {
        self.upload(moments)?;
        self.ctx.scoped("gathering and resolving the light moments", || {
            let mut enc = self.ctx.device.create_command_encoder(&Default::default());
            self.record(&mut enc, None);
            self.ctx.queue.submit([enc.finish()]);
        })
    }

    /// Median time over `repetitions` runs of the three gathers plus the resolve pass (GPU
    /// timestamps per pass where the context uses them: the gather's passes three times,
    /// named `x: `, `y: `, `z: ` plus the entry point, then `resolve`; the copies between them
    /// fall outside the passes. Otherwise the wall clock from submit to idle, copies
    /// included). The moment lights are uploaded once, outside the timing.
    pub fn time_gather(&mut self, moments: &LightMoments, repetitions: usize) -> Result<Timing> {
        self.upload(moments)?;
        let names = self.pass_names();
        measure(&self.ctx, &names, repetitions, |enc, timer| self.record(enc, timer))
    }

    /// Resolve three `L*` given on the host (`along[a]`: the gathered moment along world axis
    /// `a`) with `lobe`, skipping the gathers: the resolve pass alone, for checking it against
    /// [`biscale_core::gather::moments::resolve`].
    pub fn resolve(&mut self, along: [&LocalRadiance; 3], lobe: Lobe) -> Result<()> {
        let shape = self.gather.shape();
        for (a, l) in along.iter().enumerate() {
            if l.basis() != shape.local || l.vertices() != shape.vertices {
                return Err(GpuError::Input(format!(
                    "moment {a} is {} vertices in {}, the form's L* is {} vertices in {}",
                    l.vertices(),
                    l.basis(),
                    shape.vertices,
                    shape.local
                )));
            }
        }
        self.set_lobe(lobe)?;
        let targets = [&self.along[0], &self.along[1], self.gather.lstar_buffer()];
        self.ctx.scoped("resolving the light moments", || {
            for (buffer, l) in targets.into_iter().zip(along) {
                if !l.values().is_empty() {
                    self.ctx.queue.write_buffer(buffer, 0, bytemuck::cast_slice(l.values()));
                }
            }
            let mut enc = self.ctx.device.create_command_encoder(&Default::default());
            self.record_resolve(&mut enc, None, 0);
            self.ctx.queue.submit([enc.finish()]);
        })
    }

    /// Read `L*'` back: `values[v * M + i]`.
    pub fn read_lstar(&self) -> Result<LocalRadiance> {
        let shape = self.gather.shape();
        let rows = shape.rows();
        let bytes = self.ctx.read_buffer("L*'", &self.resolved, 0, (rows * 12).max(4) as u64)?;
        let mut f = bytes_to_f32(&bytes);
        f.truncate(rows * 3);
        let values = f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(LocalRadiance::new(shape.local, shape.vertices, values)?)
    }

    /// Overwrite every element of `L*'` with `value` (tests poison it with NaN to prove every
    /// element is written).
    pub fn fill_lstar(&self, value: f32) -> Result<()> {
        let data = vec![value; self.gather.shape().rows() * 3];
        self.ctx.scoped("filling L*'", || {
            if !data.is_empty() {
                self.ctx.queue.write_buffer(&self.resolved, 0, bytemuck::cast_slice(&data));
            }
        })
    }

    /// The GPU buffer holding `L*'`: `rows * 3` f32, row `v * M + i`, RGB interleaved.
    pub fn lstar_buffer(&self) -> &wgpu::Buffer {
        &self.resolved
    }

    /// The three gathered moments `L d_x`, `L d_y`, `L d_z` (each `rows * 3` f32, the gather's
    /// `L*` layout) after [`Self::gather`] or [`Self::resolve`]: what the shader's per-pixel
    /// resolves read in place.
    pub fn moment_buffers(&self) -> [&wgpu::Buffer; 3] {
        [&self.along[0], &self.along[1], self.gather.lstar_buffer()]
    }

    /// `1 / cosbar_i` per bin of the form's local grid (f32).
    pub fn inverse_mean_cosine_buffer(&self) -> &wgpu::Buffer {
        &self.inverse_mean_cosine
    }

    /// The lobe of the moments last uploaded or resolved.
    pub fn lobe(&self) -> Lobe {
        match self.params.lobe {
            1 => Lobe::BinCentre,
            _ => Lobe::MeanDirection,
        }
    }

    /// The gather it runs (whose own `L*` holds the last moment, `L d_z`, after a gather).
    pub fn inner(&self) -> &GpuGather {
        &self.gather
    }

    /// The shape of the form (and of `L*'`).
    pub fn shape(&self) -> TransferShape {
        self.gather.shape()
    }

    /// Timestamp pairs one run writes: the gather's passes three times, then the resolve.
    #[cfg_attr(not(feature = "viewer"), allow(dead_code))]
    pub(crate) fn pass_count(&self) -> usize {
        3 * self.gather.pass_count() + 1
    }

    fn pass_names(&self) -> Vec<String> {
        let gather = self.gather.pass_names();
        let mut names: Vec<String> =
            ["x", "y", "z"].iter().flat_map(|a| gather.iter().map(move |n| format!("{a}: {n}"))).collect();
        names.push("resolve".into());
        names
    }

    /// Upload the three moment lights (checked as the gather checks a light) and the lobe.
    pub(crate) fn upload(&mut self, moments: &LightMoments) -> Result<()> {
        let mut data = Vec::with_capacity(3 * self.gather.shape().cols());
        for light in &moments.along {
            self.gather.check_light(light)?;
            data.extend_from_slice(&light.power);
        }
        self.set_lobe(moments.lobe)?;
        self.ctx.scoped("uploading the moment lights", || {
            if !data.is_empty() {
                self.ctx.queue.write_buffer(&self.lights, 0, bytemuck::cast_slice(&data));
            }
        })
    }

    fn set_lobe(&mut self, lobe: Lobe) -> Result<()> {
        let code = match lobe {
            Lobe::MeanDirection => 0,
            Lobe::BinCentre => 1,
        };
        if code == self.params.lobe {
            return Ok(());
        }
        self.params.lobe = code;
        self.ctx.scoped("updating the resolve's lobe", || {
            self.ctx.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        })
    }

    /// Record the three gathers and the resolve (timestamps: pass `i` of the gather for
    /// moment `a` writes pair `a * P + i`, the resolve pair `3 P`), reading the moment lights
    /// last uploaded.
    pub(crate) fn record(&self, enc: &mut wgpu::CommandEncoder, timer: Option<&PassTimer>) {
        let shape = self.gather.shape();
        let (light_bytes, lstar_bytes) = (shape.cols() as u64 * 12, shape.rows() as u64 * 12);
        let passes = self.gather.pass_count() as u32;
        for a in 0..3u32 {
            if light_bytes > 0 {
                enc.copy_buffer_to_buffer(
                    &self.lights,
                    a as u64 * light_bytes,
                    self.gather.light_buffer(),
                    0,
                    light_bytes,
                );
            }
            self.gather.record_from(enc, timer, a * passes);
            if a < 2 && lstar_bytes > 0 {
                enc.copy_buffer_to_buffer(self.gather.lstar_buffer(), 0, &self.along[a as usize], 0, lstar_bytes);
            }
        }
        self.record_resolve(enc, timer, 3 * passes);
    }

    /// Record the resolve pass alone (timestamp pair `index` of `timer`).
    fn record_resolve(&self, enc: &mut wgpu::CommandEncoder, timer: Option<&PassTimer>, index: u32) {
        let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("resolve"),
            timestamp_writes: timer.map(|t| t.compute_writes(index)),
        });
        if self.workgroups[0] > 0 {
            cp.set_pipeline(&self.pipeline);
            cp.set_bind_group(0, &self.bind_group, &[]);
            cp.dispatch_workgroups(self.workgroups[0], self.workgroups[1], 1);
        }
    }
}

impl GpuLstar for GpuMoments {
    fn lstar_shape(&self) -> TransferShape {
        self.gather.shape()
    }
    fn lstar_buffer(&self) -> &wgpu::Buffer {
        &self.resolved
    }
}
