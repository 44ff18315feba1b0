//! The stages of a run, each a function from plain records to a plain record; [`crate::run`]
//! calls them in order, and `eval` and `shard merge` call the same ones.
//!
//! | module | stage |
//! |---|---|
//! | [`scene`] | the mesh and its visibility geometry, the light, the camera, the shade scene |
//! | [`transfer`] | `T` (traced, cached or stacked from shards) and each compressor's form |
//! | [`materials`] | the scene's BTFs: analytic, synthesized, measured, local PCA |
//! | [`view`] | what every render is made with and measured against: the view, the baseline, the reference |
//! | [`evaluate`] | the baseline and the reference computed, and the measurement of one form |
//! | [`figures`] | error images on a shared scale, insets, the side-by-side comparison |
//! | [`btf_study`] | every BTF representation of the scene measured against the dense tables |
//! | [`sh`] | the low-frequency (SH) method's run |
//! | [`animation`] | the light turned and the camera orbited, per frame, into animated PNGs |
//! | [`frame_model`] | each form's stages counted, floored on this machine (its probe) and projected on a GPU class |
//! | `gpu_backend` | the wgpu backend (with the `gpu` feature) |

pub mod animation;
pub mod btf_study;
pub mod evaluate;
pub mod figures;
pub mod frame_model;
#[cfg(feature = "gpu")]
pub mod gpu_backend;
pub mod materials;
pub mod scene;
pub mod sh;
pub mod transfer;
pub mod view;

use crate::error::{PipelineError, Result};
use crate::experiment::config::MethodSetting;
use crate::experiment::methods;
use crate::metrics::MethodRecord;
use biscale_core::scene::Render;
use evaluate::GpuBackend;

/// Run one method setting against the all-frequency run's inputs (dispatch on its kind); with
/// `animate`, also what [`animation`] needs to render it again under other lights.
pub(crate) fn evaluate_method(
    setting: &MethodSetting,
    inputs: &sh::MethodInputs<'_>,
    gpu: Option<&GpuBackend>,
    animate: bool,
) -> Result<(MethodRecord, Render, Option<animation::Animated<'static>>)> {
    match setting.kind.as_str() {
        k if k == methods::sh::KIND.name => sh::evaluate(setting, inputs, gpu, animate),
        other => Err(PipelineError::Mismatch {
            path: inputs.exp.config_path.clone(),
            what: format!("method kind {other} has no evaluation in this build"),
        }),
    }
}
