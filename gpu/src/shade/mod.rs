//! Bi-scale shading on the GPU with a visibility buffer (the per-pixel meso-scale integral of
//! Sun et al., eq. 2: `B(x, e) = sum_j b(u, e, d_j) L*(x, d_j)`).
//!
//! Two passes per frame (see `shade.wgsl`): a render pass with a depth test writes the id of
//! the nearest triangle at each pixel centre; a compute pass per pixel intersects the pixel
//! ray with that triangle for exact barycentrics, interpolates the three vertices' `L*` (read
//! straight from the gather's buffer) and frames, expresses the view direction in the local
//! frame (tangent = interpolated tangent made orthogonal to the interpolated normal,
//! bitangent = n x t, as `VertexFrame::from_normal_tangent`), looks the BTF up bilinearly
//! between the four nearest view samples of its Shirley-Chiu view grid, and takes the dot
//! product over the M light directions. Output: linear HDR RGB (rgba32float) and a coverage
//! mask, row 0 at the top, pixel centres at +0.5.
//!
//! Anti-aliasing: with `n x n` samples per pixel both passes run on the camera's sample grid
//! ([`Camera::supersampled`], `n` times the width and height: a supersampled visibility buffer),
//! and the read-back box-filters it to the camera's pixels ([`Render::box_filtered`]), the same
//! sample positions and arithmetic as the CPU shaders.
//!
//! Several materials per scene (as `biscale_core::scene::ShadeScene`): every material's BTF
//! floats (a dense table, or an LPCA BTF's means, eigen-BRDFs and weights) are appended to one
//! storage buffer and the LPCA cluster ids to another; a small storage buffer holds one
//! [`GpuMaterialHeader`] per material (its representation, where its data start, its patch
//! size, its view grid, its tiling), and a per-triangle buffer holds material ids. Per pixel:
//! the triangle's material, its header, the nearest texel of `uv * tiling` (wrapping, as
//! `biscale_core::scene::btf::texel_of`), that material's own view weights (none for a
//! view-independent one), each view sample resolved once (`btf_sample`) and evaluated per
//! light bin (`btf_value`: the table entry, or the LPCA mean plus weighted eigen-BRDFs), dot
//! with `L*`. LPCA values are uploaded dequantized (f32) whatever their stored quantization. All
//! materials share the light grid (`L*` has one set of bins). A one-material scene may pass no
//! ids: the id binding then holds a 4-byte placeholder and `ShadeParams::has_material_ids = 0`,
//! so the shader never reads it and uses material 0.
//!
//! Inputs are core's shading vocabulary, as for the CPU shader
//! (`biscale_shading::cpu::shade`): the [`ShadeScene`] (validated when it was built, so only
//! the adapter's limits are checked here), `L*` and the [`Camera`]; the output is a
//! [`Render`].

mod brdf;

pub use brdf::{brdf_constants_wgsl, GpuBrdf, BRDF_NONE};

use crate::context::{bytes_to_f32, GpuContext, RasterPipeline};
use crate::error::{GpuError, Result};
use crate::gather::GpuLstar;
use crate::moments::{GpuMoments, BINS_WGSL};
use crate::timing::{measure, PassTimer, Timing};
use biscale_core::gather::moments::Lobe;
use biscale_core::gather::LocalRadiance;
use biscale_core::scene::{BtfRepresentation, Camera, HdrImage, Render, ShadeScene};
use biscale_shading::runtime::MomentsResolve;
use biscale_shading::synth::Brdf;
use glam::{DMat4, DVec3, DVec4, Vec3};
use wgpu::util::DeviceExt;

/// The WGSL declaration of [`ShadeParams`], shared by the shading passes and the tone-mapping
/// pass (`present.wgsl`), which both bind it.
pub const SHADE_PARAMS_WGSL: &str = include_str!("shade_params.wgsl");

/// `ShadeParams::resolve`: [`MomentsResolve`]'s code in WGSL (`RESOLVE_VERTEX`,
/// `RESOLVE_PIXEL`, `RESOLVE_PIXEL_ANALYTIC`, generated from the enum by [`shade_wgsl`]).
pub fn resolve_code(resolve: MomentsResolve) -> u32 {
    match resolve {
        MomentsResolve::Vertex => 0,
        MomentsResolve::Pixel => 1,
        MomentsResolve::PixelAnalytic => 2,
    }
}

/// The WGSL of the shading passes: the `L*` pass (`shade_pixels`) and the per-pixel resolves
/// of light moments (`shade_moment_pixels`), with [`SHADE_PARAMS_WGSL`], the constants of
/// [`MomentsResolve`] and of the BRDF kinds, the bins ([`BINS_WGSL`]) and the analytic BRDFs
/// (`brdf.wgsl`).
pub fn shade_wgsl() -> String {
    let mut resolves = String::new();
    for r in MomentsResolve::ALL {
        resolves += &format!("const RESOLVE_{}: u32 = {}u;\n", r.name().to_uppercase(), resolve_code(r));
    }
    format!(
        "{SHADE_PARAMS_WGSL}\n{resolves}\n{BINS_WGSL}\n{}\n{}\n{}\n{}",
        include_str!("shade.wgsl"),
        brdf_constants_wgsl(),
        include_str!("brdf.wgsl"),
        include_str!("moments.wgsl")
    )
}

/// What a shading pass reads, bound: an `L*` (a gather's, or the `L*'` of the vertex resolve)
/// for `shade_pixels`, or the three moment gathers for a per-pixel resolve.
#[derive(Clone, Debug)]
pub struct ShadeBinding {
    bind_group: wgpu::BindGroup,
    /// `None` for an `L*`; the per-pixel resolve and the moments' lobe otherwise.
    per_pixel: Option<(MomentsResolve, Lobe)>,
}

/// Uniform block of both shading passes. Mirrored by `ShadeParams` in `shade/shade.wgsl`
/// (size and member offsets checked by the layout test; every `[f32; 3]` is followed by a
/// 4-byte scalar, matching WGSL's 16-byte `vec3` alignment).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadeParams {
    /// World to clip (column-major, reversed Z: depth 1 at the near plane, 0 at the far one).
    pub view_proj: [[f32; 4]; 4],
    /// Camera right, scaled by `tan(fov_y / 2) * aspect`.
    pub cam_right: [f32; 3],
    pub width: u32,
    /// Camera up, scaled by `tan(fov_y / 2)`.
    pub cam_up: [f32; 3],
    pub height: u32,
    /// Unit viewing direction.
    pub cam_forward: [f32; 3],
    pub local_dirs: u32,
    pub camera_pos: [f32; 3],
    pub _pad0: u32,
    /// Number of materials (headers in the material buffer).
    pub material_count: u32,
    /// 1: the per-triangle material id buffer is real; 0: a placeholder, every triangle uses
    /// material 0 (one-material scenes).
    pub has_material_ids: u32,
    pub vertex_count: u32,
    pub triangle_count: u32,
    /// LPCA BTFs use at most this many components per cluster (their leading ones, the
    /// evaluation of `LpcaBtf::truncated`); `u32::MAX`: all. The viewer lowers it while the
    /// light moves.
    pub max_components: u32,
    /// [`resolve_code`] of the per-pixel resolve the moments pass runs (unused by the `L*` pass).
    pub resolve: u32,
    /// The local grid's side `m` (`M = m^2` bins), 0 when the scene's local basis has no bins.
    pub moment_grid: u32,
    /// The moments' lobe: 0 [`Lobe::MeanDirection`], 1 [`Lobe::BinCentre`].
    pub lobe: u32,
}
const _: () = assert!(std::mem::size_of::<ShadeParams>() == 160);

/// Fill the camera fields of `p` from `camera` (its basis, [`Camera::basis`]); `near` and
/// `far` (view distances) bound the scene.
fn write_camera(camera: &Camera, p: &mut ShadeParams, near: f64, far: f64) {
    let (r, u, f) = camera.basis();
    let t = (camera.fov_y_degrees.to_radians() * 0.5).tan();
    let aspect = camera.width as f32 / camera.height as f32;
    p.cam_right = (r * (t * aspect)).to_array();
    p.cam_up = (u * t).to_array();
    p.cam_forward = f.to_array();
    p.camera_pos = camera.position.to_array();
    // View matrix from the same basis (rows r, u, -f), then a reversed-Z perspective
    // (depth = near / distance-ish, 1 at near, 0 at far), all in f64.
    let (r, u, f, e) = (r.as_dvec3(), u.as_dvec3(), f.as_dvec3(), camera.position.as_dvec3());
    let view = DMat4::from_cols(
        DVec4::new(r.x, u.x, -f.x, 0.0),
        DVec4::new(r.y, u.y, -f.y, 0.0),
        DVec4::new(r.z, u.z, -f.z, 0.0),
        DVec4::new(-r.dot(e), -u.dot(e), f.dot(e), 1.0),
    );
    let (t, aspect) = (t as f64, aspect as f64);
    let (a, b) = (near / (far - near), near * far / (far - near));
    let proj = DMat4::from_cols(
        DVec4::new(1.0 / (t * aspect), 0.0, 0.0, 0.0),
        DVec4::new(0.0, 1.0 / t, 0.0, 0.0),
        DVec4::new(0.0, 0.0, a, -1.0),
        DVec4::new(0.0, 0.0, b, 0.0),
    );
    p.view_proj = (proj * view).as_mat4().to_cols_array_2d();
}

/// Near and far view distances that enclose the bounding sphere of `positions` seen from
/// `eye` (near never below 1e-5 of far; geometry closer than that is clipped).
fn depth_range(positions: &[Vec3], eye: Vec3) -> (f64, f64) {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for p in positions {
        let p = p.as_dvec3();
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if positions.is_empty() {
        return (0.01, 1.0);
    }
    let (c, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
    let d = (c - eye.as_dvec3()).length();
    let far = (d + radius) * 1.01 + 1e-6;
    let near = ((d - radius) * 0.99).max(far * 1e-5);
    (near, far)
}

/// One mesh vertex as the shader reads it (mirrors WGSL `Vertex`, 48 bytes: each vec3 is
/// followed by a scalar so that WGSL's 16-byte vec3 alignment adds no hidden padding).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuVertex {
    pub position: [f32; 3],
    pub u: f32,
    pub normal: [f32; 3],
    pub v: f32,
    pub tangent: [f32; 3],
    pub _pad: f32,
}
const _: () = assert!(std::mem::size_of::<GpuVertex>() == 48);

/// Where one material's BTF lies in the concatenated buffers and how to evaluate it (mirrors
/// WGSL `MaterialHeader`, 48 bytes; checked by the layout test). The representation
/// (`kind`) selects the WGSL evaluation: a dense table, or a local-PCA form (means and
/// eigen-BRDFs, per-unit weights and cluster ids).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuMaterialHeader {
    /// First float of the material's table (dense) or basis (LPCA) in the `btf` buffer.
    pub data_offset: u32,
    /// Patch width in texels.
    pub width: u32,
    /// Patch height in texels.
    pub height: u32,
    /// View grid m; 0 for a view-independent BTF.
    pub view_m: u32,
    /// Patch repetitions per unit of uv.
    pub tiling: f32,
    /// [`KIND_DENSE`] or [`KIND_LPCA`].
    pub kind: u32,
    /// LPCA: clusters `K` (an id `>= K` marks an all-zero unit).
    pub clusters: u32,
    /// LPCA: components `C` besides the mean.
    pub components: u32,
    /// LPCA: 1 when a unit is one (texel, view), 0 when it is a whole texel.
    pub per_view: u32,
    /// LPCA: first float of the weights (`C` per unit) in the `btf` buffer.
    pub weights_offset: u32,
    /// LPCA: first cluster id of the material in the `btf_ids` buffer.
    pub ids_offset: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<GpuMaterialHeader>() == 48);

/// `GpuMaterialHeader::kind` of a dense table.
pub const KIND_DENSE: u32 = 0;
/// `GpuMaterialHeader::kind` of a local-PCA BTF.
pub const KIND_LPCA: u32 = 1;

/// Every material's BTF as the shader reads it: the headers (in scene order), the floats of
/// all tables and LPCA bases and weights back to back, and the LPCA cluster ids back to back.
pub(crate) struct MaterialBuffers {
    pub headers: Vec<GpuMaterialHeader>,
    /// Floats the concatenation holds (it is built only after the size is checked).
    pub floats: u64,
    pub ids: u64,
}

/// The headers and sizes of the concatenated buffers ([`MaterialBuffers`]).
pub(crate) fn material_headers(scene: &ShadeScene) -> MaterialBuffers {
    let mut headers = Vec::with_capacity(scene.materials().len());
    let (mut floats, mut ids) = (0u64, 0u64);
    // Offsets past 32 bits are refused by the caller with the total size; saturate until then.
    let at = |x: u64| x.min(u32::MAX as u64) as u32;
    for mat in scene.materials() {
        let btf = &mat.btf;
        let [width, height] = btf.spatial();
        let mut h = GpuMaterialHeader {
            data_offset: at(floats),
            width,
            height,
            view_m: btf.view_grid().map_or(0, |g| g.m),
            tiling: mat.tiling,
            ..Default::default()
        };
        match btf {
            BtfRepresentation::Dense(b) => floats += b.data().len() as u64 * 3,
            BtfRepresentation::Lpca(l) => {
                floats += l.basis_values().len() as u64;
                h.kind = KIND_LPCA;
                h.clusters = l.clusters() as u32;
                h.components = l.components() as u32;
                h.per_view = u32::from(l.unit() == biscale_core::scene::LpcaUnit::View);
                h.weights_offset = at(floats);
                floats += l.weight_values().len() as u64;
                h.ids_offset = at(ids);
                ids += l.cluster_ids().len() as u64;
            }
        }
        headers.push(h);
    }
    MaterialBuffers { headers, floats, ids }
}

/// The concatenated floats and cluster ids of every material ([`MaterialBuffers`]); a
/// placeholder id when no material is compressed (wgpu cannot bind an empty buffer).
fn material_data(scene: &ShadeScene, sizes: &MaterialBuffers) -> (Vec<f32>, Vec<u32>) {
    let mut floats = Vec::with_capacity(sizes.floats as usize);
    let mut ids = Vec::with_capacity(sizes.ids.max(1) as usize);
    for mat in scene.materials() {
        match &mat.btf {
            BtfRepresentation::Dense(b) => floats.extend_from_slice(bytemuck::cast_slice(b.data())),
            BtfRepresentation::Lpca(l) => {
                floats.extend_from_slice(l.basis_values());
                floats.extend_from_slice(l.weight_values());
                ids.extend(l.cluster_ids().iter().map(|&k| k as u32));
            }
        }
    }
    if ids.is_empty() {
        ids.push(0);
    }
    (floats, ids)
}

/// The GPU shader for one mesh, its materials and an image size.
pub struct GpuShader {
    ctx: GpuContext,
    params: ShadeParams,
    params_buf: wgpu::Buffer,
    vertex_buf: wgpu::Buffer,
    index_buf: wgpu::Buffer,
    btf_buf: wgpu::Buffer,
    btf_id_buf: wgpu::Buffer,
    material_buf: wgpu::Buffer,
    material_id_buf: wgpu::Buffer,
    vis_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    image: wgpu::Texture,
    image_view: wgpu::TextureView,
    vis_pipeline: wgpu::RenderPipeline,
    vis_bind_group: wgpu::BindGroup,
    shade_pipeline: wgpu::ComputePipeline,
    /// The per-pixel resolves' pass, built on first use.
    moments_pipeline: Option<wgpu::ComputePipeline>,
    /// The shader module both passes come from.
    module: wgpu::ShaderModule,
    /// One [`GpuBrdf`] per material (all `BRDF_NONE` until [`Self::set_brdfs`]) and the
    /// coating tables they index.
    brdf_buf: wgpu::Buffer,
    coating_buf: wgpu::Buffer,
    readback: wgpu::Buffer,
    padded_row: u32,
    vertex_count: usize,
    triangle_count: u32,
    /// Kept for the depth range when the camera moves.
    positions: Vec<Vec3>,
    /// What the scene's BTFs are dotted with, for [`Self::check_lstar`].
    scene_basis: biscale_core::basis::LocalBasis,
    /// The camera's sample grid side `n`: the passes run at `n` times its width and height.
    samples_per_axis: u32,
}

impl GpuShader {
    /// Upload the scene's mesh, the materials' BTF tables and ids, and build both passes for
    /// images of `camera`'s size. The scene was checked when it was built; here only the
    /// adapter's limits are: [`GpuError::Limit`] when the concatenated BTF tables exceed the
    /// adapter's `max_storage_buffer_binding_size` or the image its texture size,
    /// [`GpuError::Input`] for an unusable camera or counts past 32-bit indices.
    pub fn new(ctx: &GpuContext, scene: &ShadeScene, camera: &Camera) -> Result<Self> {
        let mesh = scene.mesh();
        let nv = mesh.vertex_count();
        let tri_count = mesh.triangle_count();
        let local_dirs = scene.local_basis().len() as u64;
        let sizes = material_headers(scene);
        let materials = scene.materials();
        // The concatenated tables are one binding: refuse before building it.
        let btf_bytes = sizes.floats.saturating_mul(4);
        let btf_label = format!("BTF data of {} material(s), concatenated", materials.len());
        ctx.check_storage_size(&btf_label, btf_bytes)?;
        ctx.check_storage_size("LPCA cluster ids, concatenated", sizes.ids.saturating_mul(4))?;
        if sizes.floats > u32::MAX as u64 || sizes.ids > u32::MAX as u64 {
            return Err(GpuError::Input(format!(
                "the concatenated BTF data hold {} floats and {} cluster ids; the shader indexes them with 32 bits",
                sizes.floats, sizes.ids
            )));
        }
        camera.validate().map_err(|e| GpuError::Input(e.to_string()))?;
        // Several samples per pixel: the passes run on the grid of samples (a supersampled
        // visibility buffer), box-filtered to the camera's pixels on read-back.
        let samples_per_axis = camera.samples_per_axis();
        let camera = &camera.supersampled();
        let (w, h) = (camera.width, camera.height);
        let max_dim = ctx.limits().max_texture_dimension_2d;
        if w > max_dim || h > max_dim {
            return Err(GpuError::Limit {
                what: format!("a {w}x{h} image"),
                limit: "max_texture_dimension_2d",
                needed: w.max(h) as u64,
                max: max_dim as u64,
            });
        }
        if tri_count as u64 * 3 >= u32::MAX as u64 || nv as u64 >= u32::MAX as u64 {
            return Err(GpuError::Input(format!("{tri_count} triangles / {nv} vertices do not fit 32-bit ids")));
        }

        let mut params = ShadeParams {
            view_proj: [[0.0; 4]; 4],
            cam_right: [0.0; 3],
            width: w,
            cam_up: [0.0; 3],
            height: h,
            cam_forward: [0.0; 3],
            local_dirs: local_dirs as u32,
            camera_pos: [0.0; 3],
            _pad0: 0,
            material_count: materials.len() as u32,
            has_material_ids: u32::from(scene.triangle_materials().is_some()),
            vertex_count: nv as u32,
            triangle_count: tri_count as u32,
            max_components: u32::MAX,
            resolve: resolve_code(MomentsResolve::Vertex),
            moment_grid: scene.local_basis().grid().map_or(0, |g| g.m),
            lobe: 0,
        };
        let (near, far) = depth_range(&mesh.positions, camera.position);
        write_camera(camera, &mut params, near, far);
        let frames = scene.frames();
        let verts: Vec<GpuVertex> = (0..nv)
            .map(|i| {
                let uv = mesh.uvs.as_ref().map_or([0.0; 2], |u| u[i].to_array());
                GpuVertex {
                    position: mesh.positions[i].to_array(),
                    u: uv[0],
                    normal: frames[i].normal.to_array(),
                    v: uv[1],
                    tangent: frames[i].tangent.to_array(),
                    _pad: 0.0,
                }
            })
            .collect();
        let vertex_buf = ctx.storage_buffer(
            "mesh vertices (48 bytes each)",
            bytemuck::cast_slice(&verts),
            wgpu::BufferUsages::empty(),
        )?;
        let index_buf =
            ctx.storage_buffer("triangle indices", bytemuck::cast_slice(&mesh.triangles), wgpu::BufferUsages::empty())?;
        let (floats, ids) = material_data(scene, &sizes);
        let btf_buf = ctx.storage_buffer(&btf_label, bytemuck::cast_slice(&floats), wgpu::BufferUsages::empty())?;
        let btf_id_buf = ctx.storage_buffer(
            "LPCA cluster ids, concatenated",
            bytemuck::cast_slice(&ids),
            wgpu::BufferUsages::empty(),
        )?;
        drop((floats, ids));
        let headers = sizes.headers;
        let material_buf = ctx.storage_buffer(
            "material headers (48 bytes each)",
            bytemuck::cast_slice(&headers),
            wgpu::BufferUsages::empty(),
        )?;
        // Without ids: a 4-byte placeholder (wgpu cannot bind an empty buffer) that the shader
        // never reads (`has_material_ids = 0`).
        let material_id_buf = ctx.storage_buffer(
            "per-triangle material ids",
            bytemuck::cast_slice(scene.triangle_materials().unwrap_or(&[0])),
            wgpu::BufferUsages::empty(),
        )?;
        let padded_row = (w * 16).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        ctx.check_buffer_size("image read-back", padded_row as u64 * h as u64)?;

        let built = ctx.scoped("building the shading passes", || {
            let params_buf = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("shade params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
            let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("shade.wgsl"),
                source: wgpu::ShaderSource::Wgsl(shade_wgsl().into()),
            });
            let size = wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
            let tex = |label, format, usage| {
                ctx.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
            };
            let vis = tex(
                "visibility",
                wgpu::TextureFormat::R32Uint,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            );
            let depth = tex("depth", wgpu::TextureFormat::Depth32Float, wgpu::TextureUsages::RENDER_ATTACHMENT);
            let image = tex(
                "hdr image",
                wgpu::TextureFormat::Rgba32Float,
                // TEXTURE_BINDING: the tone-mapping pass (`present`) reads it.
                wgpu::TextureUsages::STORAGE_BINDING
                    | wgpu::TextureUsages::COPY_SRC
                    | wgpu::TextureUsages::TEXTURE_BINDING,
            );
            let vis_pipeline = ctx.render_pipeline(RasterPipeline {
                label: "visibility",
                layout: None,
                module: &module,
                vertex: "vis_vs",
                fragment: "vis_fs",
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    cull_mode: None,
                    ..Default::default()
                },
                depth: Some(wgpu::DepthStencilState {
                    format: wgpu::TextureFormat::Depth32Float,
                    depth_write_enabled: Some(true),
                    // Reversed Z: nearer is larger.
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                format: wgpu::TextureFormat::R32Uint,
                blend: None,
            });
            let vis_bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("visibility"),
                layout: &vis_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: params_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: vertex_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: index_buf.as_entire_binding() },
                ],
            });
            let shade_pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("shade"),
                layout: None,
                module: &module,
                entry_point: Some("shade_pixels"),
                compilation_options: Default::default(),
                cache: None,
            });
            let readback = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("image read-back"),
                size: padded_row as u64 * h as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let view = |t: &wgpu::Texture| t.create_view(&Default::default());
            (
                params_buf,
                view(&vis),
                view(&depth),
                view(&image),
                image,
                vis_pipeline,
                vis_bind_group,
                shade_pipeline,
                readback,
                module,
            )
        })?;
        let (
            params_buf,
            vis_view,
            depth_view,
            image_view,
            image,
            vis_pipeline,
            vis_bind_group,
            shade_pipeline,
            readback,
            module,
        ) = built;
        let (brdfs, coating) = GpuBrdf::records(&vec![None; materials.len()]);
        let brdf_buf = ctx.storage_buffer(
            "analytic BRDFs (80 bytes each)",
            bytemuck::cast_slice(&brdfs),
            wgpu::BufferUsages::COPY_DST,
        )?;
        let coating_buf =
            ctx.storage_buffer("coating tables", bytemuck::cast_slice(&coating), wgpu::BufferUsages::empty())?;
        Ok(Self {
            ctx: ctx.clone(),
            params,
            params_buf,
            vertex_buf,
            index_buf,
            btf_buf,
            btf_id_buf,
            material_buf,
            material_id_buf,
            vis_view,
            depth_view,
            image,
            image_view,
            vis_pipeline,
            vis_bind_group,
            shade_pipeline,
            moments_pipeline: None,
            module,
            brdf_buf,
            coating_buf,
            readback,
            padded_row,
            vertex_count: nv,
            triangle_count: tri_count as u32,
            positions: mesh.positions.clone(),
            scene_basis: scene.local_basis(),
            samples_per_axis,
        })
    }

    /// Move the camera (the image size and samples per pixel must stay the same).
    pub fn set_camera(&mut self, camera: &Camera) -> Result<()> {
        camera.validate().map_err(|e| GpuError::Input(e.to_string()))?;
        let n = self.samples_per_axis;
        if (camera.width * n, camera.height * n, camera.samples_per_axis())
            != (self.params.width, self.params.height, n)
        {
            return Err(GpuError::Input(format!(
                "camera is {}x{} at {} samples per pixel, the shader was built for {}x{} at {}",
                camera.width,
                camera.height,
                camera.samples_per_pixel,
                self.params.width / n,
                self.params.height / n,
                n * n
            )));
        }
        let camera = &camera.supersampled();
        let (near, far) = depth_range(&self.positions, camera.position);
        write_camera(camera, &mut self.params, near, far);
        self.ctx.scoped("updating the camera", || {
            self.ctx.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        })
    }

    /// Evaluate LPCA BTFs with at most `n` components per cluster (their leading ones: what
    /// `LpcaBtf::truncated(n)` evaluates), or all of them with `None`; dense BTFs are unchanged.
    /// Müller et al. drop components while the light rotates.
    pub fn set_max_components(&mut self, n: Option<u32>) -> Result<()> {
        let n = n.unwrap_or(u32::MAX);
        if n == self.params.max_components {
            return Ok(());
        }
        self.params.max_components = n;
        self.ctx.scoped("updating the component cap", || {
            self.ctx.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        })
    }

    /// Shade with the `L*` a [`crate::GpuGather`] (or the `L*'` a [`crate::GpuMoments`]) left on the
    /// GPU (no read-back in between).
    pub fn shade(&mut self, gather: &impl GpuLstar) -> Result<Render> {
        self.check_lstar(gather)?;
        let binding = self.shade_bind_group(gather.lstar_buffer())?;
        self.run(&binding)?;
        self.read_image()
    }

    /// Shade with `L*` from the host (e.g. a CPU gather).
    pub fn shade_lstar(&mut self, lstar: &LocalRadiance) -> Result<Render> {
        self.check_lstar_shape(lstar.basis(), lstar.vertices())?;
        let buf = self.ctx.storage_buffer(
            "L* (from host)",
            bytemuck::cast_slice(lstar.values()),
            wgpu::BufferUsages::empty(),
        )?;
        let binding = self.shade_bind_group(&buf)?;
        self.run(&binding)?;
        self.read_image()
    }

    /// Give the materials analytic BRDFs for [`MomentsResolve::PixelAnalytic`]: `brdfs[i]` for
    /// material `i` (`None`: shaded from its BTF's tables, as the CPU's
    /// `biscale_shading::cpu::shade_moments_analytic` does), one entry per material.
    pub fn set_brdfs(&mut self, brdfs: &[Option<Brdf>]) -> Result<()> {
        let count = self.params.material_count as usize;
        if brdfs.len() != count {
            return Err(GpuError::Input(format!("{} analytic BRDFs for {count} materials", brdfs.len())));
        }
        for b in brdfs.iter().flatten() {
            b.validate().map_err(|e| GpuError::Input(e.to_string()))?;
        }
        let (records, coating) = GpuBrdf::records(brdfs);
        let coating_buf =
            self.ctx.storage_buffer("coating tables", bytemuck::cast_slice(&coating), wgpu::BufferUsages::empty())?;
        self.ctx.scoped("uploading the analytic BRDFs", || {
            self.ctx.queue.write_buffer(&self.brdf_buf, 0, bytemuck::cast_slice(&records));
        })?;
        self.coating_buf = coating_buf;
        Ok(())
    }

    /// Shade from the three moment gathers `moments` left on the GPU with `resolve`:
    /// [`MomentsResolve::Vertex`] reads their vertex-resolved `L*'` ([`Self::shade`]); the
    /// per-pixel resolves read the three gathers in place and resolve them at every sample,
    /// `Pixel` with the BTFs' tables (`biscale_shading::cpu::shade_moments`), `PixelAnalytic`
    /// with each material's BRDF given by [`Self::set_brdfs`], the others with their tables
    /// (`shade_moments_analytic`).
    pub fn shade_moments(&mut self, moments: &GpuMoments, resolve: MomentsResolve) -> Result<Render> {
        let binding = self.moments_bind_group(moments, resolve)?;
        self.run(&binding)?;
        self.read_image()
    }

    /// Median time of the two shading passes (`visibility`, `shade`) over `repetitions` frames.
    pub fn time_shade(&mut self, gather: &impl GpuLstar, repetitions: usize) -> Result<Timing> {
        self.check_lstar(gather)?;
        let binding = self.shade_bind_group(gather.lstar_buffer())?;
        self.time_binding(&binding, repetitions)
    }

    /// [`Self::time_shade`] of [`Self::shade_moments`].
    pub fn time_shade_moments(
        &mut self,
        moments: &GpuMoments,
        resolve: MomentsResolve,
        repetitions: usize,
    ) -> Result<Timing> {
        let binding = self.moments_bind_group(moments, resolve)?;
        self.time_binding(&binding, repetitions)
    }

    fn time_binding(&mut self, binding: &ShadeBinding, repetitions: usize) -> Result<Timing> {
        self.set_resolve(binding)?;
        let names = ["visibility".to_string(), "shade".to_string()];
        measure(&self.ctx, &names, repetitions, |enc, timer| self.record(enc, binding, timer))
    }

    /// An error unless `gather`'s `L*` fits the scene.
    pub(crate) fn check_lstar(&self, gather: &impl GpuLstar) -> Result<()> {
        let shape = gather.lstar_shape();
        self.check_lstar_shape(shape.local, shape.vertices)
    }

    fn check_lstar_shape(&self, basis: biscale_core::basis::LocalBasis, vertices: usize) -> Result<()> {
        Ok(biscale_core::scene::check_lstar_shape(self.scene_basis, self.vertex_count, basis, vertices)?)
    }

    /// `lstar` bound for the `L*` pass.
    pub(crate) fn shade_bind_group(&self, lstar: &wgpu::Buffer) -> Result<ShadeBinding> {
        let bind_group = self.ctx.scoped("binding L* for shading", || {
            self.ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("shade"),
                layout: &self.shade_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: self.params_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: self.vertex_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: self.index_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: lstar.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: self.btf_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: wgpu::BindingResource::TextureView(&self.vis_view) },
                    wgpu::BindGroupEntry { binding: 6, resource: wgpu::BindingResource::TextureView(&self.image_view) },
                    wgpu::BindGroupEntry { binding: 7, resource: self.material_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 8, resource: self.material_id_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 9, resource: self.btf_id_buf.as_entire_binding() },
                ],
            })
        })?;
        Ok(ShadeBinding { bind_group, per_pixel: None })
    }

    /// `moments` bound for `resolve`: its vertex-resolved `L*'` for the `L*` pass
    /// ([`MomentsResolve::Vertex`]), else its three gathers for the per-pixel pass (built on
    /// first use). An error unless the moments fit the scene and the scene's local basis has
    /// bins.
    pub fn moments_bind_group(&mut self, moments: &GpuMoments, resolve: MomentsResolve) -> Result<ShadeBinding> {
        let shape = moments.shape();
        self.check_lstar_shape(shape.local, shape.vertices)?;
        if !resolve.per_pixel() {
            return self.shade_bind_group(moments.lstar_buffer());
        }
        if self.params.moment_grid == 0 {
            return Err(GpuError::Input(format!(
                "the per-pixel resolve \"{}\" needs a local basis of bins, the scene's is {}",
                resolve.name(),
                self.scene_basis
            )));
        }
        let pipeline = match &self.moments_pipeline {
            Some(p) => p.clone(),
            None => {
                let p = self.ctx.scoped("building the per-pixel resolve pass", || {
                    self.ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some("shade (per-pixel resolve)"),
                        layout: None,
                        module: &self.module,
                        entry_point: Some("shade_moment_pixels"),
                        compilation_options: Default::default(),
                        cache: None,
                    })
                })?;
                self.moments_pipeline = Some(p.clone());
                p
            }
        };
        let [x, y, z] = moments.moment_buffers();
        let bind_group = self.ctx.scoped("binding the light moments for shading", || {
            let entries = [
                (0, self.params_buf.as_entire_binding()),
                (1, self.vertex_buf.as_entire_binding()),
                (2, self.index_buf.as_entire_binding()),
                (4, self.btf_buf.as_entire_binding()),
                (5, wgpu::BindingResource::TextureView(&self.vis_view)),
                (6, wgpu::BindingResource::TextureView(&self.image_view)),
                (7, self.material_buf.as_entire_binding()),
                (8, self.material_id_buf.as_entire_binding()),
                (9, self.btf_id_buf.as_entire_binding()),
                (10, x.as_entire_binding()),
                (11, y.as_entire_binding()),
                (12, z.as_entire_binding()),
                (13, self.brdf_buf.as_entire_binding()),
                (14, self.coating_buf.as_entire_binding()),
                (15, moments.inverse_mean_cosine_buffer().as_entire_binding()),
            ]
            .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource });
            self.ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("shade (per-pixel resolve)"),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        })?;
        Ok(ShadeBinding { bind_group, per_pixel: Some((resolve, moments.lobe())) })
    }

    /// Write the resolve and lobe `binding` shades with into the uniform (queued before the
    /// next submission).
    pub(crate) fn set_resolve(&mut self, binding: &ShadeBinding) -> Result<()> {
        let (resolve, lobe) = binding.per_pixel.unwrap_or((MomentsResolve::Vertex, Lobe::MeanDirection));
        let (resolve, lobe) = (resolve_code(resolve), u32::from(lobe == Lobe::BinCentre));
        if (resolve, lobe) == (self.params.resolve, self.params.lobe) {
            return Ok(());
        }
        (self.params.resolve, self.params.lobe) = (resolve, lobe);
        self.ctx.scoped("updating the resolve", || {
            self.ctx.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        })
    }

    /// The HDR image (rgba32float, alpha = coverage) the shading pass writes.
    pub(crate) fn image_view(&self) -> &wgpu::TextureView {
        &self.image_view
    }

    /// The uniform buffer holding [`ShadeParams`] (camera rays for the background).
    pub(crate) fn params_buffer(&self) -> &wgpu::Buffer {
        &self.params_buf
    }

    /// Size `(width, height)` of the shaded grid: the camera's image times its samples per
    /// axis (the image itself with one sample per pixel).
    pub fn size(&self) -> (u32, u32) {
        (self.params.width, self.params.height)
    }

    /// Record both passes (timestamps 0..4 of `timer`: visibility, then shade), the second the
    /// pass `binding` was bound for. [`Self::set_resolve`] must have written its resolve.
    pub(crate) fn record(&self, enc: &mut wgpu::CommandEncoder, binding: &ShadeBinding, timer: Option<&PassTimer>) {
        {
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("visibility"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.vis_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth_view,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: timer.map(|t| t.render_writes(0)),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if self.triangle_count > 0 {
                rp.set_pipeline(&self.vis_pipeline);
                rp.set_bind_group(0, &self.vis_bind_group, &[]);
                rp.draw(0..3 * self.triangle_count, 0..1);
            }
        }
        let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("shade"),
            timestamp_writes: timer.map(|t| t.compute_writes(1)),
        });
        let pipeline = match binding.per_pixel {
            None => &self.shade_pipeline,
            Some(_) => self.moments_pipeline.as_ref().expect("built with the binding"),
        };
        cp.set_pipeline(pipeline);
        cp.set_bind_group(0, &binding.bind_group, &[]);
        cp.dispatch_workgroups(self.params.width.div_ceil(8), self.params.height.div_ceil(8), 1);
    }

    fn run(&mut self, binding: &ShadeBinding) -> Result<()> {
        self.set_resolve(binding)?;
        self.ctx.scoped("shading", || {
            let mut enc = self.ctx.device.create_command_encoder(&Default::default());
            self.record(&mut enc, binding, None);
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.image,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(self.padded_row),
                        rows_per_image: Some(self.params.height),
                    },
                },
                wgpu::Extent3d { width: self.params.width, height: self.params.height, depth_or_array_layers: 1 },
            );
            self.ctx.queue.submit([enc.finish()]);
        })
    }

    fn read_image(&self) -> Result<Render> {
        let bytes = self.ctx.map_read("the shaded image", &self.readback)?;
        let (w, h) = (self.params.width as usize, self.params.height as usize);
        let mut pixels = Vec::with_capacity(w * h);
        let mut mask = Vec::with_capacity(w * h);
        for row in 0..h {
            let start = row * self.padded_row as usize;
            let f = bytes_to_f32(&bytes[start..start + w * 16]);
            for px in f.chunks_exact(4) {
                pixels.push([px[0], px[1], px[2]]);
                mask.push(px[3] > 0.5);
            }
        }
        let render = Render { image: HdrImage { width: w as u32, height: h as u32, pixels }, mask, coverage: None };
        Ok(render.box_filtered(self.samples_per_axis)?)
    }
}
