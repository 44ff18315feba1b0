//! # biscale-shading
//!
//! biscale's meso-scale side (paper section 3, `B(x, e) = sum_j b(u, e, d_j) L*(x, d_j)`):
//!
//! * [`cpu`]: the CPU per-pixel shader from per-vertex `L*`: the reference the GPU shader is
//!   checked against. It takes core's shading vocabulary (`biscale_core::scene`: the shade
//!   scene, BTF tables, the camera, the image type), as the wgpu shader does.
//! * [`reference`](mod@reference): the ray-traced reference image (`L*` from exact per-pixel visibility).
//! * [`synth`]: BTFs synthesized by ray tracing tileable height-field patches, their files and
//!   contact sheets.
//! * [`microfacet`]: GGX microfacet BRDFs as Mitsuba 3's `roughconductor` and `roughplastic`
//!   (the synthesized BTFs' `rough_conductor` / `rough_plastic` BRDFs).
//! * [`measured`]: measured BTFs in the Bonn BTF Database layout, resampled onto the bins.
//! * [`precomputed`]: LPCA BTFs under a fixed light from per-vertex dot products, the fast path
//!   of the CPU shader (checked against it).
//! * [`image`]: error metrics of images against a reference, false-colour error images.
//! * [`ldr`]: the LDR metrics after the report's tone map (LDR PSNR, SSIM, FLIP).
//! * [`runtime`]: the runtime's choices as one type each from config key to `metrics.json`
//!   and report: [`runtime::Backend`], [`runtime::MomentsResolve`].
//!
//! Shortest use, from per-vertex `L*` to an image file:
//!
//! ```no_run
//! use biscale_core::basis::LocalBasis;
//! use biscale_core::gather::LocalRadiance;
//! use biscale_core::geometry::{shapes, vertex_frames};
//! use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
//! let mesh = shapes::uv_sphere(glam::Vec3::ZERO, 1.0, 16, 32);
//! let (frames, _) = vertex_frames(&mesh);
//! let bins = LocalBasis::bins(8).unwrap();
//! let btf = Btf::lambertian([0.8; 3], bins).unwrap();
//! let lstar = LocalRadiance::zeros(bins, mesh.vertex_count()); // from the gather stage
//! let scene = ShadeScene::new(mesh, frames, vec![Material::new(btf)], None).unwrap();
//! let camera = Camera::frame_bounds(glam::Vec3::splat(-1.0), glam::Vec3::ONE, 640, 480, 30.0, 20.0, 40.0);
//! let render = biscale_shading::cpu::shade(&scene, &lstar, &camera).unwrap();
//! render.image.write_exr("out.exr".as_ref()).unwrap();
//! ```

pub mod analytic;
pub mod cpu;
pub mod error;
pub mod frame_model;
pub mod image;
pub mod ldr;
pub mod measured;
pub mod microfacet;
pub mod precomputed;
pub mod reference;
pub mod runtime;
pub mod synth;

pub use error::{Result, ShadingError};
