//! # biscale-shading
//!
//! biscale's meso-scale side (paper section 3, `B(x, e) = sum_j b(u, e, d_j) L*(x, d_j)`):
//!
//! * [`btf`]: BTF tables `b(u, e, d_j)` of analytic materials and their lookup.
//! * [`camera`]: the pinhole camera and its primary rays.
//! * [`cpu`]: the CPU per-pixel shader from per-vertex `L*`: the reference the GPU shader is
//!   checked against.
//! * [`reference`](mod@reference): the ray-traced reference image (`L*` from exact per-pixel visibility).
//! * [`synth`]: BTFs synthesized by ray tracing tileable height-field patches, their files and
//!   contact sheets.
//! * [`image`]: HDR images, atomic OpenEXR/PNG writes, error metrics, false colour errors.
//!
//! Shortest use, from per-vertex `L*` to an image file:
//!
//! ```no_run
//! use biscale_core::geometry::{shapes, vertex_frames, SceneBvh};
//! use biscale_core::gather::LocalRadiance;
//! use biscale_shading::{btf::Btf, camera::Camera, cpu::{shade, Background, Material, ShadeScene}};
//! let mesh = shapes::uv_sphere(glam::Vec3::ZERO, 1.0, 16, 32);
//! let (frames, _) = vertex_frames(&mesh);
//! let bvh = SceneBvh::build(&mesh.positions, &mesh.triangles);
//! let btf = Btf::lambertian([0.8; 3], 8).unwrap();
//! let lstar = LocalRadiance::zeros(mesh.positions.len(), 64); // from the gather stage
//! let scene = ShadeScene { mesh: &mesh, frames: &frames, bvh: &bvh, materials: &[Material::new(btf)], triangle_materials: None, background: Background::Black };
//! let camera = Camera::frame_bounds(glam::Vec3::splat(-1.0), glam::Vec3::ONE, 640, 480, 30.0, 20.0, 40.0);
//! let render = shade(&scene, &lstar, &camera).unwrap();
//! render.image.write_exr("out.exr".as_ref()).unwrap();
//! ```

pub mod btf;
pub mod camera;
pub mod cpu;
pub mod error;
pub mod image;
pub mod reference;
pub mod synth;

pub use error::{Result, ShadingError};
