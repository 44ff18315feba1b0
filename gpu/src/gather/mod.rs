//! The generic gather host: runs any compressed form's WGSL gather program, leaving
//! `L* = T L` (rows x RGB, f32) in a GPU buffer that the shader reads directly.
//!
//! The host knows nothing of any compressor. Given a form and its program (a
//! [`KernelDesc`], from the compressor's `Compressor::kernels`: built-ins and plugins alike),
//! it runs the program's declared checks on the form, reflects the WGSL
//! ([`biscale_kernels::reflect`]) to find which global binds which array (by name), uploads
//! every array as a storage buffer (narrow integers packed into 32-bit words,
//! [`biscale_kernels::ArrayData::pack_words`]), creates the scratch buffers the program
//! declares, and dispatches its passes in one submission. Everything that could exceed the
//! adapter's limits is checked before the buffer or dispatch is created, and wgpu's
//! validation errors come back as [`GpuError`]s.
//!
//! ```no_run
//! # use biscale_gpu::{GpuContext, GpuGather};
//! # use biscale_core::compress::Compressor;
//! # let form: biscale_core::compress::CompressedForm = unimplemented!();
//! # let light: biscale_core::sampling::LightVector = unimplemented!();
//! # let compressor: biscale_compressors::sparse::Sparse = unimplemented!();
//! let ctx = GpuContext::new()?;
//! let mut gather = GpuGather::new(&ctx, &form, &compressor.kernels(&form)?)?;
//! gather.gather(&light)?;
//! let lstar = gather.read_lstar()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::context::{bytes_to_f32, GpuContext};
use crate::error::{GpuError, Result};
use crate::timing::{measure, Timing};
use biscale_core::basis::TransferShape;
use biscale_core::compress::{CompressError, CompressedForm};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_kernels::reflect::{reflect, Role};
use biscale_kernels::{GatherParams, KernelDesc};
use std::collections::BTreeMap;
use std::num::NonZeroU64;

struct Pass {
    name: String,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    workgroups: [u32; 2],
}

/// A compressed form resident on the GPU with its gather program ready to run.
pub struct GpuGather {
    ctx: GpuContext,
    kind: String,
    shape: TransferShape,
    light: wgpu::Buffer,
    lstar: wgpu::Buffer,
    passes: Vec<Pass>,
    uploaded_bytes: u64,
}

impl GpuGather {
    /// Check `form` against `kernels` (its compressor's GPU program, `Compressor::kernels`),
    /// upload it and build the program. The kernels' declared checks run first, so a corrupt
    /// form is a [`GpuError::Compress`] and never a GPU loop of billions of steps; then the
    /// WGSL is reflected ([`biscale_kernels::reflect`]) and every global bound by name.
    pub fn new(ctx: &GpuContext, form: &CompressedForm, kernels: &KernelDesc) -> Result<Self> {
        for (what, n) in [("rows", form.rows()), ("cols", form.cols())] {
            if n > u32::MAX as usize / 3 {
                return Err(GpuError::Form(format!("{what} = {n} does not fit 32-bit GPU indices")));
            }
        }
        kernels.check_form(form).map_err(CompressError::from)?;
        let reflected = reflect(kernels).map_err(|e| GpuError::Wgsl { program: e.kind, message: e.message })?;
        reflected.check_arrays(form).map_err(CompressError::from)?;
        let limits = ctx.limits();
        let storage_count = reflected.globals.iter().filter(|g| g.uniform_size.is_none()).count();
        if storage_count as u64 > limits.max_storage_buffers_per_shader_stage as u64 {
            return Err(GpuError::Limit {
                what: format!("gather program '{}' ({storage_count} storage buffers)", kernels.kind),
                limit: "max_storage_buffers_per_shader_stage",
                needed: storage_count as u64,
                max: limits.max_storage_buffers_per_shader_stage as u64,
            });
        }

        // Buffers for every global but `params` (per pass).
        let mut buffers: BTreeMap<String, wgpu::Buffer> = BTreeMap::new();
        let mut uploaded_bytes = 0u64;
        let (mut light, mut lstar) = (None, None);
        for g in &reflected.globals {
            let name = g.name.as_str();
            let buffer = match g.role {
                Role::Params => continue,
                Role::Light | Role::Lstar => {
                    let rw = g.role == Role::Lstar;
                    let n = if rw { form.rows() } else { form.cols() };
                    let bytes = (n * 3 * 4) as u64;
                    let what = if rw { "L* (rows x RGB f32)" } else { "light vector (N x RGB f32)" };
                    ctx.check_storage_size(what, bytes)?;
                    let usage = wgpu::BufferUsages::STORAGE
                        | wgpu::BufferUsages::COPY_DST
                        | if rw { wgpu::BufferUsages::COPY_SRC } else { wgpu::BufferUsages::empty() };
                    let b = ctx.scoped(&format!("creating the {name} buffer"), || {
                        ctx.device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some(name),
                            size: bytes.max(4).next_multiple_of(4),
                            usage,
                            mapped_at_creation: false,
                        })
                    })?;
                    if rw {
                        lstar = Some(b.clone());
                    } else {
                        light = Some(b.clone());
                    }
                    b
                }
                Role::Meta => {
                    let mut words = Vec::with_capacity(kernels.meta_keys.len());
                    for k in &kernels.meta_keys {
                        let v = form.meta(k)?;
                        words.push(
                            u32::try_from(v)
                                .map_err(|_| GpuError::Form(format!("meta '{k}' = {v} does not fit u32")))?,
                        );
                    }
                    ctx.storage_buffer("meta_values", bytemuck::cast_slice(&words), wgpu::BufferUsages::empty())?
                }
                Role::Scratch => {
                    let desc = kernels.scratch.iter().find(|s| s.name == name).expect("reflect checked it");
                    let words = desc.words.eval(form).map_err(CompressError::from)?;
                    let bytes =
                        words.checked_mul(4).ok_or_else(|| GpuError::Form(format!("scratch '{name}' overflows")))?;
                    let what = format!("scratch buffer '{name}' ({words} words)");
                    ctx.check_storage_size(&what, bytes)?;
                    ctx.scoped(&format!("creating {what}"), || {
                        ctx.device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some(name),
                            size: bytes.max(4),
                            usage: wgpu::BufferUsages::STORAGE,
                            mapped_at_creation: false,
                        })
                    })?
                }
                Role::FormArray => {
                    let data = form.array(name)?;
                    let words = data.pack_words();
                    let what = format!(
                        "form array '{name}' ({} x {}, {} bytes packed)",
                        data.len(),
                        data.element_type(),
                        words.len() * 4
                    );
                    uploaded_bytes += (words.len() * 4) as u64;
                    ctx.storage_buffer(&what, bytemuck::cast_slice(&words), wgpu::BufferUsages::empty())?
                }
            };
            buffers.insert(name.to_string(), buffer);
        }
        let (Some(light), Some(lstar)) = (light, lstar) else {
            unreachable!("reflect checked that the program binds light and lstar");
        };

        // One layout for all passes: every global, visible to compute.
        let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = reflected
            .globals
            .iter()
            .map(|g| wgpu::BindGroupLayoutEntry {
                binding: g.binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: match g.uniform_size {
                        Some(_) => wgpu::BufferBindingType::Uniform,
                        None => wgpu::BufferBindingType::Storage { read_only: g.read_only },
                    },
                    has_dynamic_offset: false,
                    min_binding_size: g.uniform_size.and_then(NonZeroU64::new),
                },
                count: None,
            })
            .collect();
        let label = format!("gather '{}'", kernels.kind);
        let max_groups = limits.max_compute_workgroups_per_dimension as u64;
        let mut passes = Vec::with_capacity(kernels.passes.len());
        let (module, pipeline_layout) = ctx.scoped(&format!("compiling {label}"), || {
            let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(&label),
                source: wgpu::ShaderSource::Wgsl(reflected.source.as_str().into()),
            });
            let bgl = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(&label),
                entries: &layout_entries,
            });
            let pl = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(&label),
                bind_group_layouts: &[Some(&bgl)],
                immediate_size: 0,
            });
            (module, (pl, bgl))
        })?;
        let (pipeline_layout, bgl) = pipeline_layout;
        for (index, pass) in kernels.passes.iter().enumerate() {
            let group_size = reflected.workgroup_size(&pass.entry_point).expect("reflect checked it").max(1);
            let threads = pass.threads.eval(form).map_err(CompressError::from)?;
            let threads32 = u32::try_from(threads).map_err(|_| {
                GpuError::Form(format!("pass '{}' needs {threads} invocations (> u32)", pass.entry_point))
            })?;
            let groups = threads.div_ceil(group_size);
            let x = groups.min(max_groups);
            let y = if x == 0 { 0 } else { groups.div_ceil(x) };
            if y > max_groups {
                return Err(GpuError::Limit {
                    what: format!("pass '{}' ({groups} workgroups of {group_size})", pass.entry_point),
                    limit: "max_compute_workgroups_per_dimension (squared)",
                    needed: groups,
                    max: max_groups * max_groups,
                });
            }
            let params = GatherParams {
                rows: form.rows() as u32,
                cols: form.cols() as u32,
                local_dirs: form.local_dirs() as u32,
                vertices: form.vertices() as u32,
                threads: threads32,
                pass_index: index as u32,
                light_resolution: form.light_basis().cubemap_layout().map_or(0, |c| c.resolution),
                _pad: 0,
            };
            let pass_label = format!("{label} pass {index} '{}'", pass.entry_point);
            let (pipeline, bind_group) = ctx.scoped(&format!("building {pass_label}"), || {
                use wgpu::util::DeviceExt;
                let params_buf = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("gather params"),
                    contents: bytemuck::bytes_of(&params),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
                let pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(&pass_label),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some(&pass.entry_point),
                    compilation_options: Default::default(),
                    cache: None,
                });
                let entries: Vec<wgpu::BindGroupEntry<'_>> = reflected
                    .globals
                    .iter()
                    .map(|g| wgpu::BindGroupEntry {
                        binding: g.binding,
                        resource: if g.name == "params" {
                            params_buf.as_entire_binding()
                        } else {
                            buffers[&g.name].as_entire_binding()
                        },
                    })
                    .collect();
                let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(&pass_label),
                    layout: &bgl,
                    entries: &entries,
                });
                (pipeline, bind_group)
            })?;
            passes.push(Pass {
                name: pass.entry_point.clone(),
                pipeline,
                bind_group,
                workgroups: [x as u32, y as u32],
            });
        }
        Ok(Self {
            ctx: ctx.clone(),
            kind: form.kind.clone(),
            shape: form.shape(),
            light,
            lstar,
            passes,
            uploaded_bytes,
        })
    }

    /// Upload `light` and run the gather; `L*` is then in [`Self::lstar_buffer`] (queue order
    /// makes it visible to anything submitted later; [`Self::read_lstar`] waits for it).
    pub fn gather(&mut self, light: &LightVector) -> Result<()> {
        self.upload_light(light)?;
        self.ctx.scoped(&format!("running the '{}' gather", self.kind), || {
            let mut enc = self.ctx.device.create_command_encoder(&Default::default());
            self.record(&mut enc, None);
            self.ctx.queue.submit([enc.finish()]);
        })
    }

    /// Read `L*` back: `values[v * M + j]`.
    pub fn read_lstar(&self) -> Result<LocalRadiance> {
        let rows = self.shape.rows();
        let bytes = self.ctx.read_buffer("L*", &self.lstar, 0, (rows * 12).max(4) as u64)?;
        let mut f = bytes_to_f32(&bytes);
        f.truncate(rows * 3);
        let values = f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(LocalRadiance::new(self.shape.local, self.shape.vertices, values)?)
    }

    /// Median gather time over `repetitions` runs with `light` (GPU timestamps per pass where
    /// the adapter has them, else wall clock). The light is uploaded once, outside the timing.
    pub fn time_gather(&mut self, light: &LightVector, repetitions: usize) -> Result<Timing> {
        self.upload_light(light)?;
        let names = self.pass_names();
        measure(&self.ctx, &names, repetitions, |enc, timer| self.record(enc, timer))
    }

    /// Overwrite every element of `L*` with `value` (tests poison it with NaN to prove every
    /// element is written).
    pub fn fill_lstar(&self, value: f32) -> Result<()> {
        let data = vec![value; self.shape.rows() * 3];
        self.ctx.scoped("filling L*", || {
            if !data.is_empty() {
                self.ctx.queue.write_buffer(&self.lstar, 0, bytemuck::cast_slice(&data));
            }
        })
    }

    /// The GPU buffer holding `L*`: `rows * 3` f32, row `v * M + j`, RGB interleaved.
    pub fn lstar_buffer(&self) -> &wgpu::Buffer {
        &self.lstar
    }

    pub fn kind(&self) -> &str {
        &self.kind
    }
    /// The shape of the form (and of the `L*` the gather leaves).
    pub fn shape(&self) -> TransferShape {
        self.shape
    }
    pub fn rows(&self) -> usize {
        self.shape.rows()
    }
    pub fn local_dirs(&self) -> usize {
        self.shape.local_dirs()
    }
    pub fn vertices(&self) -> usize {
        self.shape.vertices
    }
    /// Bytes of form arrays uploaded (after packing to 32-bit words).
    pub fn uploaded_bytes(&self) -> u64 {
        self.uploaded_bytes
    }

    pub(crate) fn upload_light(&self, light: &LightVector) -> Result<()> {
        self.check_light(light)?;
        self.ctx.scoped("uploading the light vector", || {
            if !light.power.is_empty() {
                self.ctx.queue.write_buffer(&self.light, 0, bytemuck::cast_slice(&light.power));
            }
        })
    }

    /// An error unless `light` is in the form's light basis and finite.
    pub(crate) fn check_light(&self, light: &LightVector) -> Result<()> {
        if light.basis() != self.shape.light {
            return Err(GpuError::Input(format!(
                "the light vector is in {}, the form's columns are {}",
                light.basis(),
                self.shape.light
            )));
        }
        if let Some(k) = light.power.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(GpuError::Input(format!("light texel {k} is not finite: {:?}", light.power[k])));
        }
        Ok(())
    }

    /// The context the form lives in.
    pub(crate) fn ctx(&self) -> &GpuContext {
        &self.ctx
    }

    /// The GPU buffer the gather reads the light from (`cols * 3` f32).
    pub(crate) fn light_buffer(&self) -> &wgpu::Buffer {
        &self.light
    }

    /// The entry points of the program's passes, in order.
    pub(crate) fn pass_names(&self) -> Vec<String> {
        self.passes.iter().map(|p| p.name.clone()).collect()
    }

    /// Number of kernel passes of the program (one timestamp pair each).
    pub(crate) fn pass_count(&self) -> usize {
        self.passes.len()
    }

    /// Record every pass into `enc` (pass `i` writes timestamps `2i`, `2i + 1` of `timer`).
    pub(crate) fn record(&self, enc: &mut wgpu::CommandEncoder, timer: Option<&crate::timing::PassTimer>) {
        self.record_from(enc, timer, 0);
    }

    /// [`Self::record`] with pass `i` writing timestamp pair `first + i` of `timer` (several
    /// gathers timed in one submission: the light moments).
    pub(crate) fn record_from(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timer: Option<&crate::timing::PassTimer>,
        first: u32,
    ) {
        for (i, p) in self.passes.iter().enumerate() {
            let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(&p.name),
                timestamp_writes: timer.map(|t| t.compute_writes(first + i as u32)),
            });
            if p.workgroups[0] > 0 {
                cp.set_pipeline(&p.pipeline);
                cp.set_bind_group(0, &p.bind_group, &[]);
                cp.dispatch_workgroups(p.workgroups[0], p.workgroups[1], 1);
            }
        }
    }
}

/// An `L*` resident on the GPU that the shader can read straight from its buffer: a
/// [`GpuGather`]'s `T L`, or a [`crate::GpuMoments`]' resolved `L*'`.
pub trait GpuLstar {
    /// The shape of the form the `L*` belongs to (its rows are `vertices x M`).
    fn lstar_shape(&self) -> TransferShape;
    /// `rows * 3` f32, row `v * M + j`, RGB interleaved.
    fn lstar_buffer(&self) -> &wgpu::Buffer;
}

impl GpuLstar for GpuGather {
    fn lstar_shape(&self) -> TransferShape {
        self.shape
    }
    fn lstar_buffer(&self) -> &wgpu::Buffer {
        &self.lstar
    }
}
