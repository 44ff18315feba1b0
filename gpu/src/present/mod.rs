//! Display of the shaded HDR image on the GPU: a small render pass ([`ToneMap`]) that reads
//! [`GpuShader`]'s rgba32float image, puts the environment map behind uncovered pixels, and
//! applies the report's tone map (`HdrImage::to_srgb8`: `value * 2^exposure`, clamped, sRGB)
//! into any colour target: a window's surface texture (the viewer) or an offscreen 8-bit
//! texture read back as RGBA ([`ToneMap::render_rgba8`], used by tests and screenshots).
//!
//! Nothing here changes [`GpuShader::shade`]: the image stays linear HDR, and the pass only
//! reads it, so the same frame can be both read back and displayed.

use crate::context::{GpuContext, RasterPipeline};

use crate::error::{GpuError, Result};
use crate::gather::GpuLstar;
use crate::shade::GpuShader;
use crate::timing::PassTimer;
use biscale_core::sampling::EnvMap;
use wgpu::util::DeviceExt;

/// The WGSL of the tone-mapping pass.
/// The tone-mapping pass's WGSL ([`crate::shade::SHADE_PARAMS_WGSL`] prepended).
pub fn present_wgsl() -> String {
    format!("{}\n{}", crate::shade::SHADE_PARAMS_WGSL, include_str!("present.wgsl"))
}

/// Uniform block of the pass; mirrored by `ToneParams` in `present.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct ToneParams {
    scale: f32,
    env_rotation: f32,
    encode_srgb: u32,
    has_env: u32,
    target_width: f32,
    target_height: f32,
    _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<ToneParams>() == 32);

/// Display settings of one tone-mapped frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToneMapSettings {
    /// Exposure in stops (0 = unchanged), as the report's PNGs.
    pub exposure: f32,
    /// Rotation of the background environment about +Y in radians (the rotation the light
    /// vector was computed with, so background and lighting agree).
    pub env_rotation: f32,
    /// Draw the environment (if one is set) behind uncovered pixels; black otherwise.
    pub background: bool,
}

impl Default for ToneMapSettings {
    fn default() -> Self {
        Self { exposure: 0.0, env_rotation: 0.0, background: true }
    }
}

/// An RGBA8 image read back from the GPU: `pixels[(row * width + col) * 4 + channel]`, row 0
/// at the top, sRGB-encoded, alpha 255.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rgba8Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// The tone-mapping pass for one target format.
pub struct ToneMap {
    ctx: GpuContext,
    format: wgpu::TextureFormat,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    /// The environment (rgba32float lat-long), or a 1x1 placeholder when there is none.
    env_view: wgpu::TextureView,
    has_env: bool,
}

impl ToneMap {
    /// Build the pass for targets of `format` (any renderable colour format; 8-bit formats
    /// without `Srgb` get the sRGB curve applied in the shader).
    pub fn new(ctx: &GpuContext, format: wgpu::TextureFormat) -> Result<Self> {
        if format.is_depth_stencil_format() || format.is_compressed() {
            return Err(GpuError::Input(format!("cannot tone-map into a {format:?} target")));
        }
        let (pipeline, layout, env_view) = ctx.scoped("building the tone-mapping pass", || {
            let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("present.wgsl"),
                source: wgpu::ShaderSource::Wgsl(present_wgsl().into()),
            });
            let uniform = |binding| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            };
            let texture = |binding| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            };
            let layout = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("present"),
                entries: &[uniform(0), uniform(1), texture(2), texture(3)],
            });
            let pl = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("present"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = ctx.render_pipeline(RasterPipeline {
                label: "present",
                layout: Some(&pl),
                module: &module,
                vertex: "present_vs",
                fragment: "present_fs",
                primitive: Default::default(),
                depth: None,
                format,
                blend: None,
            });
            let env_view = env_texture(ctx, 1, 1, &[0.0; 4]).create_view(&Default::default());
            (pipeline, layout, env_view)
        })?;
        Ok(Self { ctx: ctx.clone(), format, pipeline, layout, env_view, has_env: false })
    }

    /// The target format this pass was built for.
    pub fn format(&self) -> wgpu::TextureFormat {
        self.format
    }

    /// Draw `env` behind uncovered pixels (bilinear between lat-long pixel centres, as
    /// `EnvMap::radiance`; a cube map through its `EnvMap::latlong_view`), or nothing (black)
    /// with `None`. Maps wider or taller than the adapter's texture limit are box-filtered
    /// down by a whole factor first.
    pub fn set_environment(&mut self, env: Option<&EnvMap>) -> Result<()> {
        let Some(env) = env else {
            self.has_env = false;
            return Ok(());
        };
        let env = &*env.latlong_view();
        if env.width == 0 || env.height == 0 || env.pixels.len() != env.width * env.height {
            return Err(GpuError::Input(format!(
                "environment map is {}x{} with {} pixels",
                env.width,
                env.height,
                env.pixels.len()
            )));
        }
        let max = self.ctx.limits().max_texture_dimension_2d as usize;
        let factor = env.width.div_ceil(max).max(env.height.div_ceil(max)).max(1);
        let (w, h) = (env.width / factor, env.height / factor);
        let mut rgba = vec![0.0f32; w * h * 4];
        let norm = 1.0 / (factor * factor) as f32;
        for y in 0..h {
            for x in 0..w {
                let o = &mut rgba[(y * w + x) * 4..][..4];
                for sy in 0..factor {
                    for sx in 0..factor {
                        let p = env.pixels[(y * factor + sy) * env.width + x * factor + sx];
                        for c in 0..3 {
                            o[c] += p[c] * norm;
                        }
                    }
                }
                o[3] = 1.0;
            }
        }
        let ctx = &self.ctx;
        self.ctx.check_buffer_size("environment texture", (w * h * 16) as u64)?;
        self.env_view = ctx.scoped("uploading the environment map", || {
            env_texture(ctx, w as u32, h as u32, &rgba).create_view(&Default::default())
        })?;
        self.has_env = true;
        Ok(())
    }

    /// Record the pass: `shader`'s current image, tone-mapped into `target` (a view of a
    /// `target_size` texture of this pass's format; the image is stretched to it, nearest).
    /// Run after the shading was recorded or submitted.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shader: &GpuShader,
        target: &wgpu::TextureView,
        target_size: (u32, u32),
        settings: &ToneMapSettings,
    ) -> Result<()> {
        self.encode_timed(enc, shader, target, target_size, settings, None)
    }

    /// [`Self::encode`], writing timestamps `2 * index` and `2 * index + 1` of `timer`.
    pub(crate) fn encode_timed(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shader: &GpuShader,
        target: &wgpu::TextureView,
        target_size: (u32, u32),
        settings: &ToneMapSettings,
        timer: Option<(&PassTimer, u32)>,
    ) -> Result<()> {
        if target_size.0 == 0 || target_size.1 == 0 {
            return Err(GpuError::Input("tone-mapping target has zero size".into()));
        }
        if !settings.exposure.is_finite() || !settings.env_rotation.is_finite() {
            return Err(GpuError::Input(format!("tone-map settings are not finite: {settings:?}")));
        }
        let params = ToneParams {
            scale: settings.exposure.exp2(),
            env_rotation: settings.env_rotation,
            encode_srgb: u32::from(!self.format.is_srgb()),
            has_env: u32::from(self.has_env && settings.background),
            target_width: target_size.0 as f32,
            target_height: target_size.1 as f32,
            _pad: [0; 2],
        };
        let ctx = &self.ctx;
        ctx.scoped("recording the tone-mapping pass", || {
            let buf = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("tone params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("present"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: shader.params_buffer().as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: buf.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(shader.image_view()),
                    },
                    wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&self.env_view) },
                ],
            });
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("present"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: timer.map(|(t, i)| t.render_writes(i)),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            rp.set_pipeline(&self.pipeline);
            rp.set_bind_group(0, &bind_group, &[]);
            rp.draw(0..3, 0..1);
        })
    }

    /// Shade `gather`'s `L*` (a [`crate::GpuGather`]'s, or a [`crate::GpuMoments`]' `L*'`) with
    /// `shader`, tone-map into an offscreen texture of this pass's format at the image's size
    /// and read it back (submits and waits). The format must be one of `Rgba8Unorm`,
    /// `Rgba8UnormSrgb`, `Bgra8Unorm`, `Bgra8UnormSrgb`.
    pub fn render_rgba8(
        &self,
        shader: &mut GpuShader,
        gather: &impl GpuLstar,
        settings: &ToneMapSettings,
    ) -> Result<Rgba8Image> {
        shader.check_lstar(gather)?;
        let (w, h) = shader.size();
        let bind_group = shader.shade_bind_group(gather.lstar_buffer())?;
        let ctx = &self.ctx;
        let texture = ctx.scoped("creating the offscreen target", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("offscreen target"),
                size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: self.format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            })
        })?;
        let view = texture.create_view(&Default::default());
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        shader.set_resolve(&bind_group)?;
        shader.record(&mut enc, &bind_group, None);
        self.encode(&mut enc, shader, &view, (w, h), settings)?;
        read_texture_rgba8(ctx, enc, &texture)
    }
}

/// An rgba32float texture holding `rgba` (`w * h * 4` floats).
fn env_texture(ctx: &GpuContext, w: u32, h: u32, rgba: &[f32]) -> wgpu::Texture {
    ctx.device.create_texture_with_data(
        &ctx.queue,
        &wgpu::TextureDescriptor {
            label: Some("environment"),
            size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(rgba),
    )
}

/// Append to `enc` a copy of the whole `texture` (8-bit RGBA or BGRA, COPY_SRC) into a
/// read-back buffer, submit `enc`, wait, and return the pixels as RGBA rows, top first.
pub(crate) fn read_texture_rgba8(
    ctx: &GpuContext,
    mut enc: wgpu::CommandEncoder,
    texture: &wgpu::Texture,
) -> Result<Rgba8Image> {
    use wgpu::TextureFormat as F;
    let format = texture.format();
    let bgra = match format {
        F::Rgba8Unorm | F::Rgba8UnormSrgb => false,
        F::Bgra8Unorm | F::Bgra8UnormSrgb => true,
        other => return Err(GpuError::Input(format!("cannot read a {other:?} texture back as RGBA8"))),
    };
    let (w, h) = (texture.width(), texture.height());
    let padded = (w * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    ctx.check_buffer_size("frame read-back", padded as u64 * h as u64)?;
    let staging = ctx.scoped("reading back a frame", || {
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame read-back"),
            size: padded as u64 * h as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded), rows_per_image: Some(h) },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        ctx.queue.submit([enc.finish()]);
        staging
    })?;
    let bytes = ctx.map_read("a frame", &staging)?;
    let mut pixels = Vec::with_capacity((w * h * 4) as usize);
    for row in 0..h as usize {
        for px in bytes[row * padded as usize..][..w as usize * 4].chunks_exact(4) {
            if bgra {
                pixels.extend_from_slice(&[px[2], px[1], px[0], 255]);
            } else {
                pixels.extend_from_slice(&[px[0], px[1], px[2], 255]);
            }
        }
    }
    Ok(Rgba8Image { width: w, height: h, pixels })
}

#[cfg(test)]
mod tests;
