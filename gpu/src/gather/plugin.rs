//! Plugin forms on the GPU (issue 7): a compressor loaded from a shared library hands its
//! gather kernels over as plain data ([`KernelDesc`], from
//! `biscale_compressors::plugin::PluginCompressor::gpu_kernels`); this turns them into a
//! [`GatherProgram`], so the generic host runs a plugin form exactly like a built-in one.
//!
//! A [`GatherProgram`]'s `validate` is a plain function pointer and cannot carry a plugin's
//! declared checks, so [`GpuGather::with_kernels`] runs them ([`KernelDesc::check_form`])
//! before calling [`GpuGather::with_program`]: a bad pointer array is a [`GpuError::Form`],
//! never a GPU loop of billions of steps. Calling `with_program(ctx, form, &program(k))`
//! directly skips those checks; do that only for forms already checked on the host (every form
//! `PluginCompressor::compress` returns is).
//!
//! ```no_run
//! # let plugin: biscale_compressors::plugin::PluginCompressor = unimplemented!();
//! # let form: biscale_core::compress::CompressedForm = unimplemented!();
//! # let light: biscale_core::sampling::LightVector = unimplemented!();
//! let ctx = biscale_gpu::GpuContext::new()?;
//! let mut gather = biscale_gpu::GpuGather::with_kernels(&ctx, &form, plugin.gpu_kernels())?;
//! gather.gather(&light)?;
//! # Ok::<(), biscale_gpu::GpuError>(())
//! ```

use super::program::{GatherProgram, KernelPass, ScratchBuffer};
use super::GpuGather;
use crate::context::GpuContext;
use crate::error::Result;
use biscale_core::compress::CompressedForm;
use biscale_core::kernels::KernelDesc;

/// The gather program of a kernel description (no `validate`: see the module docs).
pub fn program(k: &KernelDesc) -> GatherProgram {
    GatherProgram {
        kind: k.kind.clone(),
        wgsl: k.wgsl.clone(),
        passes: k
            .passes
            .iter()
            .map(|p| KernelPass { entry_point: p.entry_point.clone(), threads: p.threads.clone() })
            .collect(),
        scratch: k.scratch.iter().map(|s| ScratchBuffer { name: s.name.clone(), words: s.words.clone() }).collect(),
        meta_keys: k.meta_keys.clone(),
        validate: None,
    }
}

impl GpuGather {
    /// Upload `form` and build the gather described by `kernels` (a plugin's), after running
    /// the kernels' declared structural checks on the form.
    pub fn with_kernels(ctx: &GpuContext, form: &CompressedForm, kernels: &KernelDesc) -> Result<Self> {
        kernels.check_form(form)?;
        Self::with_program(ctx, form, &program(kernels))
    }
}
