//! An experiment's images without a run, for a program that holds the pipeline as a library
//! (the Python module's `Experiment.shade` and `Experiment.reference`): the image of an `L*`
//! at the run's camera, and the ground-truth reference, each exactly as `biscale run` renders
//! it (same scene, materials, camera, background and reference cache).

use crate::error::{PipelineError, Result};
use crate::experiment::config::{Experiment, MomentsResolve};
use crate::stages::evaluate::reference_render;
use crate::stages::scene::{load_geometry, load_lighting, shade_scene, Geometry, Lighting};
use crate::stages::transfer::transfer_matrix;
use crate::stages::view::View;
use crate::store::cache::StageCache;
use crate::store::RunOptions;
use biscale_core::gather::LocalRadiance;
use biscale_core::scene::Render;
use biscale_core::transfer::TransferMatrix;
use std::path::Path;

/// The image `biscale run` renders of `lstar` (rows `v*M + j` of the config's transfer shape),
/// at the run's camera with its background; refused with `runtime.moments_resolve = "pixel"`,
/// whose images shade the three moment gathers, not an `L*`. `T` comes from the stage cache (or is traced): its
/// local basis builds the materials' BTFs.
pub fn shade_image(exp: &Experiment, lstar: &[[f32; 3]], opts: &RunOptions) -> Result<Render> {
    if let Some(what) = exp.file.runtime.moments_resolve().and_then(MomentsResolve::refuses_lstar) {
        return Err(PipelineError::Mismatch { path: exp.config_path.clone(), what });
    }
    let geometry = load_geometry(exp)?;
    let want = exp.transfer_settings().shape(geometry.mesh.vertex_count());
    if lstar.len() != want.rows() {
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!(
                "the L* has {} rows, this config's has {} ({} vertices x {} local directions)",
                lstar.len(),
                want.rows(),
                want.vertices,
                want.local_dirs()
            ),
        });
    }
    if let Some(i) = lstar.as_flattened().iter().position(|x| !x.is_finite()) {
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!("L*[{}, {}] is {}: every value must be finite", i / 3, i % 3, lstar.as_flattened()[i]),
        });
    }
    with_view(exp, geometry, opts, |_, v, t, _| {
        let lstar = LocalRadiance::new(t.local_basis(), t.vertices(), lstar.to_vec())?;
        v.render(&lstar, &v.camera)
    })
}

/// The reference image of a run of `exp` (at `report.reference_downscale`, with the
/// background): from the stage cache when it holds one of the same inputs, else traced (and
/// stored there).
pub fn reference_image(exp: &Experiment, opts: &RunOptions) -> Result<Render> {
    with_view(exp, load_geometry(exp)?, opts, |g, v, _, l| {
        let cache = StageCache::new(opts, Path::new("."));
        Ok(reference_render(exp, g, v, l, cache.as_ref())?.render)
    })
}

/// `f` of the run's view of `exp` (`T` from the cache or traced, the materials on its basis).
fn with_view<R>(
    exp: &Experiment,
    geometry: Geometry,
    opts: &RunOptions,
    f: impl FnOnce(&Geometry, &View<'_>, &TransferMatrix, &Lighting) -> Result<R>,
) -> Result<R> {
    let lighting = load_lighting(exp)?;
    let cache = StageCache::new(opts, Path::new("."));
    crate::estimate::check_transfer(exp, &geometry, cache.is_some(), "rendering images")?;
    let t = transfer_matrix(exp, &geometry, cache.as_ref())?.into_whole("rendering")?;
    let (scene, materials) = shade_scene(exp, &geometry, t.local_basis(), cache.as_ref())?;
    let view = View::of(exp, &geometry, &lighting, &scene, &materials.analytic);
    f(&geometry, &view, &t, &lighting)
}
