//! The headless wgpu device every GPU stage shares, plus the small helpers they all need:
//! error scopes that turn wgpu validation errors into [`GpuError`]s, limit checks made before
//! a buffer is created, and buffer read-back.
//!
//! On a machine without a GPU the only adapter is Mesa's software Vulkan driver (lavapipe,
//! installed by `scripts/setup-vulkan.sh`); it supports compute, rendering and timestamp
//! queries, so everything here runs unchanged on it.

use crate::error::{GpuError, Result};
use std::sync::{Arc, Mutex};
use wgpu::util::DeviceExt;

/// What the runtime records about the adapter it runs on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdapterSummary {
    /// Adapter name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)` for lavapipe.
    pub name: String,
    /// Backend, e.g. `Vulkan`.
    pub backend: String,
    /// `Cpu` for software drivers, `DiscreteGpu`, `IntegratedGpu`, ...
    pub device_type: String,
    /// Driver name and version string as the driver reports them.
    pub driver: String,
    /// Whether the adapter advertises timestamp queries (whether they are used is
    /// [`GpuContext::has_timestamps`]).
    pub timestamp_queries: bool,
}

/// Whether stage timings use GPU timestamp queries ([`GpuContext::with_timestamps`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimestampPolicy {
    /// Where the adapter has them, except on a CPU adapter such as lavapipe, whose
    /// timestamps were measured to be unusable: the default.
    #[default]
    Auto,
    /// Wherever the adapter advertises them, CPU adapters included. For exercising the
    /// timestamp path on lavapipe (the tests do); the values there mean little.
    Always,
    /// Never: every stage is timed by the wall clock from submit until idle.
    Never,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}, {})", self.name, self.backend, self.device_type, self.driver)
    }
}

/// A headless wgpu device and queue. Cheap to clone (wgpu handles are reference counted).
#[derive(Clone)]
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    adapter: AdapterSummary,
    limits: wgpu::Limits,
    timestamps: bool,
    /// Errors no scope caught (wgpu's default handler would panic on them).
    uncaptured: Arc<Mutex<Vec<String>>>,
}

impl GpuContext {
    /// Open the default adapter headlessly. Requests the adapter's own limits (not WebGPU's
    /// defaults: the transfer matrix needs large storage buffers) and timestamp queries when
    /// the adapter has them. Fails with [`GpuError::NoAdapter`] when there is no adapter.
    pub fn new() -> Result<Self> {
        Self::with_timestamps(TimestampPolicy::Auto)
    }

    /// [`Self::new`] with a choice of how stages are timed.
    pub fn with_timestamps(policy: TimestampPolicy) -> Result<Self> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        Self::open(&instance, None, policy).map(|(ctx, _)| ctx)
    }

    /// Open the default adapter of `instance` that can present to `surface` (the viewer's
    /// window; `None` for headless use), as [`Self::new`] does; also returns the adapter
    /// (the window needs its surface capabilities).
    pub(crate) fn open(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
        policy: TimestampPolicy,
    ) -> Result<(Self, wgpu::Adapter)> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let timestamp_queries = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
            timestamp_queries,
        };
        // A CPU adapter (lavapipe) advertises timestamp queries, but its values were measured
        // to be unusable for multi-pass gathers (bicluster's two passes read 0.09 ms by
        // timestamps against 40 ms submit-to-idle on the bunny): time it by the wall clock
        // unless the caller insists.
        let timestamps = timestamp_queries
            && match policy {
                TimestampPolicy::Auto => info.device_type != wgpu::DeviceType::Cpu,
                TimestampPolicy::Always => true,
                TimestampPolicy::Never => false,
            };
        let required_features = if timestamps { wgpu::Features::TIMESTAMP_QUERY } else { wgpu::Features::empty() };
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("biscale"),
            required_features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice { adapter: summary.name.clone(), message: e.to_string() })?;
        let uncaptured: Arc<Mutex<Vec<String>>> = Arc::default();
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        Ok((Self { device, queue, adapter: summary, limits, timestamps, uncaptured }, adapter))
    }

    /// The adapter this context runs on.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// The device limits (the adapter's own).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// True when passes are timed with GPU timestamps (otherwise timings are wall-clock
    /// medians from submit to idle): by default only on a GPU that has them, never on a CPU
    /// adapter such as lavapipe, whose timestamps are not meaningful (`TimestampPolicy`).
    pub fn has_timestamps(&self) -> bool {
        self.timestamps
    }

    /// The wgpu device (for callers that add their own passes).
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The wgpu queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// Run `f` inside validation and out-of-memory error scopes and turn anything wgpu
    /// reports into [`GpuError::Validation`] naming `during`.
    pub(crate) fn scoped<T>(&self, during: &str, f: impl FnOnce() -> T) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let v = pollster::block_on(validation.pop());
        let o = pollster::block_on(oom.pop());
        if let Some(e) = v.or(o) {
            return Err(GpuError::Validation { during: during.to_string(), message: e.to_string() });
        }
        let stray: Vec<String> = self.uncaptured.lock().map(|mut v| std::mem::take(&mut *v)).unwrap_or_default();
        if !stray.is_empty() {
            return Err(GpuError::Validation { during: during.to_string(), message: stray.join("; ") });
        }
        Ok(out)
    }

    /// Check a storage binding of `bytes` against the binding and buffer size limits.
    pub(crate) fn check_storage_size(&self, what: &str, bytes: u64) -> Result<()> {
        let l = &self.limits;
        within(what, bytes, "max_storage_buffer_binding_size", l.max_storage_buffer_binding_size)?;
        self.check_buffer_size(what, bytes)
    }

    /// Check a buffer of `bytes` against `max_buffer_size`.
    pub(crate) fn check_buffer_size(&self, what: &str, bytes: u64) -> Result<()> {
        within(what, bytes, "max_buffer_size", self.limits.max_buffer_size)
    }

    /// A render pipeline without vertex buffers (its vertex shader makes the geometry from
    /// indices) drawing into one colour target: the visibility pass, the tone-mapping pass and
    /// the viewer's overlay.
    pub(crate) fn render_pipeline(&self, p: RasterPipeline<'_>) -> wgpu::RenderPipeline {
        self.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(p.label),
            layout: p.layout,
            vertex: wgpu::VertexState {
                module: p.module,
                entry_point: Some(p.vertex),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: p.primitive,
            depth_stencil: p.depth,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: p.module,
                entry_point: Some(p.fragment),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: p.format,
                    blend: p.blend,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        })
    }

    /// A storage buffer holding `contents` (at least 4 bytes: wgpu cannot bind empty buffers),
    /// after checking its size against the limits.
    pub(crate) fn storage_buffer(
        &self,
        label: &str,
        contents: &[u8],
        extra: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer> {
        self.check_storage_size(label, contents.len() as u64)?;
        let padded;
        let contents = if contents.len() < 4 || !contents.len().is_multiple_of(4) {
            let mut v = contents.to_vec();
            v.resize(contents.len().next_multiple_of(4).max(4), 0);
            padded = v;
            &padded[..]
        } else {
            contents
        };
        self.scoped(&format!("creating buffer '{label}'"), || {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE | extra,
            })
        })
    }

    /// Copy `size` bytes of `src` from `offset` to the host (submits and waits).
    pub(crate) fn read_buffer(&self, what: &str, src: &wgpu::Buffer, offset: u64, size: u64) -> Result<Vec<u8>> {
        let staging = self.scoped(&format!("reading back {what}"), || {
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut enc = self.device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(src, offset, &staging, 0, size);
            self.queue.submit([enc.finish()]);
            staging
        })?;
        self.map_read(what, &staging)
    }

    /// Map a MAP_READ buffer, wait, and copy its contents out.
    pub(crate) fn map_read(&self, what: &str, staging: &wgpu::Buffer) -> Result<Vec<u8>> {
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait(what)?;
        let err = |message: String| GpuError::Readback { what: what.to_string(), message };
        rx.recv().map_err(|e| err(e.to_string()))?.map_err(|e| err(e.to_string()))?;
        let bytes = staging.get_mapped_range(..).map_err(|e| err(e.to_string()))?.to_vec();
        staging.unmap();
        Ok(bytes)
    }

    /// Block until all submitted work is done.
    pub(crate) fn wait(&self, what: &str) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Validation { during: format!("waiting for {what}"), message: e.to_string() })
    }
}

/// Reinterpret little-endian bytes read back from the GPU as f32s.
pub(crate) fn bytes_to_f32(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

/// An error unless `bytes` is within the adapter limit `limit` (= `max`).
fn within(what: &str, bytes: u64, limit: &'static str, max: u64) -> Result<()> {
    if bytes > max {
        return Err(GpuError::Limit { what: what.to_string(), limit, needed: bytes, max });
    }
    Ok(())
}

/// What differs between biscale's render pipelines ([`GpuContext::render_pipeline`]).
pub(crate) struct RasterPipeline<'a> {
    pub label: &'a str,
    /// `None`: derived from the shader.
    pub layout: Option<&'a wgpu::PipelineLayout>,
    pub module: &'a wgpu::ShaderModule,
    pub vertex: &'a str,
    pub fragment: &'a str,
    pub primitive: wgpu::PrimitiveState,
    pub depth: Option<wgpu::DepthStencilState>,
    pub format: wgpu::TextureFormat,
    pub blend: Option<wgpu::BlendState>,
}
