//! # biscale-gpu
//!
//! biscale's wgpu runtime (docs/DESIGN.md sections 2 and 4): the per-frame stages that run on the
//! GPU, kept in their own crate so that `biscale-core` knows nothing of wgpu and the rest of
//! the workspace builds without it.
//!
//! * [`GpuContext`]: a headless device (on machines without a GPU, Mesa's lavapipe software
//!   Vulkan driver; install it with `scripts/setup-vulkan.sh`).
//! * [`GpuGather`]: the generic gather host. Any [`biscale_core::compress::CompressedForm`]
//!   with its compressor's program (a `biscale_kernels::KernelDesc`, built-in or plugin) is
//!   uploaded as plain arrays and its WGSL kernels leave `L* = T L` in a GPU buffer.
//! * [`GpuMoments`]: light moments (`[runtime] light_moments`) on the GPU: a form's three
//!   moment gathers and a compute pass resolving them into `L*'`, which the shader reads as it
//!   reads `L*` (no read-back in between).
//! * [`GpuShader`]: visibility-buffer shading: triangles rasterized to (id, barycentrics),
//!   then one compute invocation per pixel interpolates `L*` and the vertex frame and takes
//!   the dot product with the BTF of the triangle's material (bilinear in the view direction).
//! * [`Timing`]: per-pass GPU timestamps (or wall-clock) medians over repetitions.
//! * [`ToneMap`]: the HDR image tone-mapped on the GPU into a display target.
//! * `viewer` (cargo feature `viewer`): `viewer::run_viewer`, an interactive
//!   window (orbit camera, environment rotation, compressor switching, timings on screen).
//!
//! Shortest use:
//!
//! ```no_run
//! # let form: biscale_core::compress::CompressedForm = unimplemented!();
//! # let kernels: biscale_kernels::KernelDesc = unimplemented!(); // compressor.kernels(&form)
//! # let light: biscale_core::sampling::LightVector = unimplemented!();
//! let ctx = biscale_gpu::GpuContext::new()?;
//! let mut gather = biscale_gpu::GpuGather::new(&ctx, &form, &kernels)?;
//! gather.gather(&light)?;
//! let lstar = gather.read_lstar()?; // or shade straight from gather.lstar_buffer()
//! # Ok::<(), biscale_gpu::GpuError>(())
//! ```

pub mod context;
pub mod error;
pub mod gather;
pub mod moments;
pub mod present;
pub mod shade;
pub mod timing;
#[cfg(feature = "viewer")]
pub mod viewer;

pub use context::{AdapterSummary, GpuContext, TimestampPolicy};
pub use error::{GpuError, Result};
pub use gather::{GpuGather, GpuLstar};
pub use moments::GpuMoments;
pub use present::{Rgba8Image, ToneMap, ToneMapSettings};
pub use shade::{GpuBrdf, GpuMaterialHeader, GpuShader, GpuVertex, ShadeBinding, ShadeParams};
pub use timing::{PassTiming, Timing, TimingMethod};
#[cfg(feature = "viewer")]
pub use viewer::{run_viewer, Screenshot, ViewerForm, ViewerSetup};

#[cfg(test)]
mod tests;
