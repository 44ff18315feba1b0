//! The viewer's text overlay: lines of text rasterized on the CPU with `ab_glyph` from the
//! bundled DejaVu Sans (`assets/fonts/DejaVuSans.ttf`) into a premultiplied RGBA8 image
//! (white text on a translucent black box), uploaded to a texture and blended over the frame
//! at 1:1 pixel size in the top-left corner. A few hundred glyphs per frame cost well under a
//! millisecond, so the text is simply redrawn every frame.

use crate::context::{GpuContext, RasterPipeline};

use crate::error::{GpuError, Result};
use crate::timing::PassTimer;
use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
use wgpu::util::DeviceExt;

/// The bundled font (Bitstream Vera derivative, free licence: assets/fonts/LICENSE_DejaVu.txt).
const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

/// The overlay texture's size: text beyond it is cut off.
const MAX_W: u32 = 2048;
const MAX_H: u32 = 512;
/// Box padding and distance from the window corner, pixels.
const PAD: u32 = 6;
const MARGIN: f32 = 8.0;
/// Opacity of the box behind the text.
const BOX_ALPHA: f32 = 0.6;

const OVERLAY_WGSL: &str = r#"
struct Rect { origin: vec2<f32>, size: vec2<f32>, target_size: vec2<f32>, pad: vec2<f32> }
@group(0) @binding(0) var<uniform> rect: Rect;
@group(0) @binding(1) var text: texture_2d<f32>;

@vertex
fn overlay_vs(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), vec2<f32>(0.0, 1.0),
        vec2<f32>(0.0, 1.0), vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0));
    let p = rect.origin + corners[vi] * rect.size;
    return vec4<f32>(2.0 * p.x / rect.target_size.x - 1.0, 1.0 - 2.0 * p.y / rect.target_size.y, 0.0, 1.0);
}

@fragment
fn overlay_fs(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let p = vec2<i32>(floor(frag.xy - rect.origin));
    // Premultiplied alpha.
    return textureLoad(text, p, 0);
}
"#;

/// Text rasterized to a premultiplied RGBA8 image, `pixels[(y * width + x) * 4 + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct TextImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// Rasterize `lines` at `px` pixels per em: white glyphs on a box of opacity [`BOX_ALPHA`],
/// padded by [`PAD`] pixels, at most `max_w x max_h` (longer lines are cut).
pub fn rasterize(font: &FontRef<'_>, lines: &[String], px: f32, max_w: u32, max_h: u32) -> TextImage {
    let scaled = font.as_scaled(PxScale::from(px));
    let line_h = (scaled.height() + scaled.line_gap()).ceil();
    let mut widths = Vec::with_capacity(lines.len());
    for line in lines {
        let mut x = 0.0f32;
        let mut prev = None;
        for c in line.chars() {
            let id = scaled.glyph_id(c);
            if let Some(p) = prev {
                x += scaled.kern(p, id);
            }
            x += scaled.h_advance(id);
            prev = Some(id);
        }
        widths.push(x);
    }
    let text_w = widths.iter().copied().fold(0.0f32, f32::max).ceil() as u32;
    let width = (text_w + 2 * PAD).min(max_w).max(1);
    let height = ((line_h * lines.len() as f32).ceil() as u32 + 2 * PAD).min(max_h).max(1);
    let mut coverage = vec![0.0f32; (width * height) as usize];
    for (row, line) in lines.iter().enumerate() {
        let baseline = PAD as f32 + row as f32 * line_h + scaled.ascent();
        let mut x = PAD as f32;
        let mut prev = None;
        for c in line.chars() {
            let id = scaled.glyph_id(c);
            if let Some(p) = prev {
                x += scaled.kern(p, id);
            }
            let glyph = id.with_scale_and_position(px, ab_glyph::point(x, baseline));
            x += scaled.h_advance(id);
            prev = Some(id);
            if let Some(outlined) = font.outline_glyph(glyph) {
                let b = outlined.px_bounds();
                outlined.draw(|gx, gy, cov| {
                    let (x, y) = (b.min.x as i64 + gx as i64, b.min.y as i64 + gy as i64);
                    if x >= 0 && y >= 0 && (x as u32) < width && (y as u32) < height {
                        let k = (y as u32 * width + x as u32) as usize;
                        coverage[k] = (coverage[k] + cov).min(1.0);
                    }
                });
            }
        }
    }
    let mut pixels = Vec::with_capacity(coverage.len() * 4);
    for cov in coverage {
        // White over the translucent black box, premultiplied: rgb = cov, a = cov + (1-cov) box.
        let a = cov + (1.0 - cov) * BOX_ALPHA;
        let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        pixels.extend_from_slice(&[to8(cov), to8(cov), to8(cov), to8(a)]);
    }
    TextImage { width, height, pixels }
}

/// The overlay pass for one target format.
pub struct Overlay {
    ctx: GpuContext,
    font: FontRef<'static>,
    px: f32,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    pipeline: wgpu::RenderPipeline,
    /// Size of the text currently in the texture.
    used: (u32, u32),
}

impl Overlay {
    pub fn new(ctx: &GpuContext, format: wgpu::TextureFormat, px: f32) -> Result<Self> {
        let font = FontRef::try_from_slice(FONT).map_err(|e| GpuError::Input(format!("bundled font: {e}")))?;
        let max = ctx.limits().max_texture_dimension_2d;
        let (tw, th) = (MAX_W.min(max), MAX_H.min(max));
        let (texture, pipeline) = ctx.scoped("building the text overlay", || {
            let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("overlay text"),
                size: wgpu::Extent3d { width: tw, height: th, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("overlay"),
                source: wgpu::ShaderSource::Wgsl(OVERLAY_WGSL.into()),
            });
            let blend = wgpu::BlendComponent {
                src_factor: wgpu::BlendFactor::One,
                dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
                operation: wgpu::BlendOperation::Add,
            };
            let pipeline = ctx.render_pipeline(RasterPipeline {
                label: "overlay",
                layout: None,
                module: &module,
                vertex: "overlay_vs",
                fragment: "overlay_fs",
                primitive: Default::default(),
                depth: None,
                format,
                blend: Some(wgpu::BlendState { color: blend, alpha: blend }),
            });
            (texture, pipeline)
        })?;
        let view = texture.create_view(&Default::default());
        Ok(Self { ctx: ctx.clone(), font, px, texture, view, pipeline, used: (0, 0) })
    }

    /// Font size in pixels per em.
    pub fn px(&self) -> f32 {
        self.px
    }

    /// Rasterize `lines` and upload them (shown by the next [`Self::encode`]).
    pub fn set_text(&mut self, lines: &[String]) {
        let img = rasterize(&self.font, lines, self.px, self.texture.width(), self.texture.height());
        self.ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            &img.pixels,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(img.width * 4), rows_per_image: None },
            wgpu::Extent3d { width: img.width, height: img.height, depth_or_array_layers: 1 },
        );
        self.used = (img.width, img.height);
    }

    /// Blend the text over `target` (a `target_size` view), writing timestamps `2 * index`,
    /// `2 * index + 1` of `timer`.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        target_size: (u32, u32),
        timer: Option<(&PassTimer, u32)>,
    ) {
        let (w, h) = (self.used.0.min(target_size.0) as f32, self.used.1.min(target_size.1) as f32);
        let rect = [MARGIN, MARGIN, w, h, target_size.0 as f32, target_size.1 as f32, 0.0, 0.0];
        let buf = self.ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("overlay rect"),
            contents: bytemuck::cast_slice(&rect),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind_group = self.ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("overlay"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&self.view) },
            ],
        });
        let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("overlay"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: timer.map(|(t, i)| t.render_writes(i)),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        if w >= 1.0 && h >= 1.0 {
            rp.set_pipeline(&self.pipeline);
            rp.set_bind_group(0, &bind_group, &[]);
            rp.draw(0..6, 0..1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_inside_its_box() {
        let font = FontRef::try_from_slice(FONT).unwrap();
        let lines = vec!["frame 12.3 ms".to_string(), "Tab: sparse".to_string()];
        let img = rasterize(&font, &lines, 16.0, 1024, 256);
        assert_eq!(img.pixels.len(), (img.width * img.height * 4) as usize);
        // Two 16 px lines plus padding; "frame 12.3 ms" is ~13 glyphs of ~8-10 px.
        assert!(img.height >= 2 * 16 && img.height < 2 * 24 + 2 * PAD, "height {}", img.height);
        assert!(img.width > 80 && img.width < 200, "width {}", img.width);
        // Some pixels are fully inked text, the padding rows are box only (alpha 0.6 -> 153).
        let lit = img.pixels.chunks_exact(4).filter(|p| p[0] > 200).count();
        assert!(lit > 50, "{lit} text pixels");
        for x in 0..img.width as usize {
            assert_eq!(&img.pixels[x * 4..x * 4 + 4], &[0, 0, 0, 153], "top padding row");
        }
        // Premultiplied: colour never exceeds alpha.
        assert!(img.pixels.chunks_exact(4).all(|p| p[0] <= p[3]));
    }

    #[test]
    fn long_text_is_cut_to_the_maximum_size() {
        let font = FontRef::try_from_slice(FONT).unwrap();
        let lines = vec!["x".repeat(500); 40];
        let img = rasterize(&font, &lines, 16.0, 300, 100);
        assert_eq!((img.width, img.height), (300, 100));
    }
}
