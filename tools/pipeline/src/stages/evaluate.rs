//! The evaluation stage: what every form is measured against (the f64 product `T L`, the
//! uncompressed baseline image, the reference) and the measurement of one form.

use crate::error::{PipelineError, Result};
use crate::experiment::config::{CompressorSetting, Experiment, MomentsResolve};
use crate::metrics::*;
use crate::stages::figures::{error_extent, save_images, write_error_figure};
use crate::stages::scene::{Geometry, Lighting};
use crate::stages::view::{timed, Baseline, Reference, Shaded, View};
use crate::store::cache::{reference_key, CacheKey, StageCache};
use crate::store::staging::fault_point;
use crate::util::progress_bar;
use biscale_core::artifact::{Artifact, ArtifactError, Field};
use biscale_core::compress::{ArrayData, CompressedForm, Compressor};
use biscale_core::gather::moments::{exact_moments_product, gather_keeping_moments, LightMoments, Lobe};
use biscale_core::gather::{reference_product, relative_l2_error, LocalRadiance};
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::LightVector;
use biscale_core::scene::{Camera, HdrImage, Render, ShadeScene};
use biscale_core::transfer::{TransferMatrix, TransferView, VisibilitySampler};
use biscale_shading::image::{compare_exposed, ImageMetrics};
use biscale_shading::reference::ReferenceRule;
use biscale_shading::synth::Brdf;
use std::path::Path;
use std::time::Instant;

pub(crate) fn errors(m: &ImageMetrics) -> ImageErrors {
    ImageErrors::from(m)
}

/// The uncompressed product in f64: `T L`, or with light moments (`moments`: the frames `T`
/// was traced with) the moments' product ([`exact_moments_product`]). Rounded to f32 it is the
/// uncompressed `L*` a run renders (`biscale export` writes it as `lstar.npz`).
pub(crate) fn uncompressed_product(
    t: &TransferMatrix,
    light: &LightVector,
    moments: Option<&[VertexFrame]>,
) -> Result<Vec<[f64; 3]>> {
    match moments {
        None => Ok(reference_product(t, light)),
        // LightMoments::new's lobe: the BRDF at each bin's mean direction.
        Some(frames) => Ok(exact_moments_product(t, light, frames, Lobe::MeanDirection)?),
    }
}

/// [`uncompressed_product`] part by part over `T` (a streamed merge's shard files, or `T`
/// whole as one part), with the seconds spent in the products alone (not in reading parts).
/// Every row is computed on its own, so the rows are those of the product of `T` whole.
pub(crate) fn uncompressed_rows(
    t: TransferView<'_>,
    light: &LightVector,
    moments: Option<&[VertexFrame]>,
) -> Result<(Vec<[f64; 3]>, f64)> {
    let mut seconds = 0.0;
    let rows = t.map_rows(|first, part| -> Result<Vec<[f64; 3]>> {
        let frames = match moments {
            Some(f) => Some(f.get(first..first + part.vertices()).ok_or_else(|| {
                PipelineError::Core(biscale_core::CoreError::Invalid(format!(
                    "light moments need one vertex frame per vertex: {} frames for {} vertices",
                    f.len(),
                    t.vertices()
                )))
            })?),
            None => None,
        };
        let start = Instant::now();
        let rows = uncompressed_product(part, light, frames)?;
        seconds += start.elapsed().as_secs_f64();
        Ok(rows)
    })?;
    Ok((rows, seconds))
}

/// What every compressor setting is scored against, made the same way for `run` and `eval`.
pub(crate) struct Targets {
    /// The light's direction moments, with `runtime.light_moments`.
    pub moments: Option<LightMoments>,
    pub base: Baseline,
    /// The ground-truth reference, when the plan traces one.
    pub reference: Option<Reference>,
    /// The tone map of every PNG of the run ([`crate::experiment::config::Exposure::resolve`]).
    pub tone: crate::metrics::ToneMapRecord,
}

/// The [`Targets`] of `t` in `view`, their images written into `images_dir` (`uncompressed`,
/// with moments also `uncompressed_paper`, `mask`, and with `trace_reference` `reference` and
/// `reference_mask`). The reference comes from `cache` when it holds one of the same inputs
/// ([`reference`]). Refuses a camera that sees none of the mesh: every score would be empty.
#[allow(clippy::too_many_arguments)]
pub(crate) fn targets(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    t: TransferView<'_>,
    view: &View<'_>,
    images_dir: &Path,
    trace_reference: bool,
    cache: Option<&StageCache>,
    clock: &mut crate::provenance::StageClock,
) -> Result<Targets> {
    let moments = match exp.file.runtime.light_moments {
        true => Some(LightMoments::new(&lighting.light)?),
        false => None,
    };
    let frames = geometry.transfer.frames();
    let per_pixel = moments.as_ref().filter(|_| exp.file.runtime.resolve_per_pixel());
    let base = baseline(t, lighting, moments.as_ref().map(|_| frames), per_pixel, view, exp.file.runtime.repeats)?;
    if !base.render.mask.iter().any(|&hit| hit) {
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!(
                "the camera sees none of the mesh (no pixel of the {}x{} image hits it): check [runtime.camera] \
                 (position, target, azimuth, elevation, fov) against the mesh's bounds {:?}",
                view.camera.width,
                view.camera.height,
                geometry.mesh.bounds()
            ),
        });
    }
    let tone = tone_map(exp, &base.render);
    let exposure = tone.exposure;
    save_images(&base.render.image, images_dir, "uncompressed", exposure)?;
    if let Some((_, paper)) = &base.paper {
        save_images(&paper.image, images_dir, "uncompressed_paper", exposure)?;
    }
    base.render.write_mask_png(&images_dir.join("mask.png"))?;
    clock.mark("uncompressed baseline");
    fault_point("images");
    let reference = match trace_reference {
        true => {
            let r = reference(exp, geometry, view, lighting, &base, exposure, cache)?;
            save_images(&r.render.image, images_dir, "reference", exposure)?;
            r.render.write_mask_png(&images_dir.join("reference_mask.png"))?;
            clock.mark("reference");
            Some(r)
        }
        false => None,
    };
    Ok(Targets { moments, base, reference, tone })
}

/// The run's tone map: `[report] exposure` resolved on the uncompressed render's mesh pixels,
/// with the share it clips (logged; a fixed exposure that clips over a tenth of the mesh is
/// warned about).
pub(crate) fn tone_map(exp: &Experiment, render: &Render) -> crate::metrics::ToneMapRecord {
    use crate::experiment::config::Exposure;
    let setting = exp.file.report.exposure;
    let exposure = setting.resolve(&render.image, &render.mask);
    let clipped = render.image.clipped_fraction(Some(&render.mask), exposure);
    let auto = setting == Exposure::Auto;
    match auto {
        true => log::info!(
            "report: exposure \"auto\": {exposure:+.1} stops ({:.2}% of the mesh's pixels clip)",
            100.0 * clipped
        ),
        false if clipped > 0.1 => log::warn!(
            "report: the PNGs' tone map at {exposure:+.1} stops clips {:.0}% of the mesh's pixels; \
             `[report] exposure = \"auto\"` picks one that clips at most {:.0}%",
            100.0 * clipped,
            100.0 * Exposure::AUTO_CLIPS
        ),
        false => {}
    }
    crate::metrics::ToneMapRecord { exposure, auto, clipped }
}

/// The uncompressed baseline; with `per_pixel` (the light's moments, `moments_resolve =
/// "pixel"`) its image resolves the three exact moment gathers at every pixel. Of `T` in parts
/// (a streamed merge) the gather is timed once, its products alone (reading the parts is not
/// part of a gather).
pub(crate) fn baseline(
    t: TransferView<'_>,
    lighting: &Lighting,
    moments: Option<&[VertexFrame]>,
    per_pixel: Option<&LightMoments>,
    view: &View<'_>,
    repeats: usize,
) -> Result<Baseline> {
    let (exact, gather_timing) = match t {
        TransferView::Whole(t) => timed(repeats, || uncompressed_product(t, &lighting.light, moments))?,
        TransferView::Parts(_) => {
            let (exact, seconds) = uncompressed_rows(t, &lighting.light, moments)?;
            (exact, Timing::from_samples(&[seconds * 1e3]))
        }
    };
    let lstar = LocalRadiance::from_f64(t.local_basis(), t.vertices(), &exact)?;
    let pixel_moments = per_pixel.map(|m| moment_gathers(t, m)).transpose()?;
    let (render, shade_timing) = view.timed_render_shaded(Shaded::of(&lstar, pixel_moments.as_ref()), repeats)?;
    let paper = match moments {
        None => None,
        Some(_) => {
            let lstar = exact_lstar(t, &lighting.light)?;
            let render = view.render(&lstar, &view.camera)?;
            Some((lstar, render))
        }
    };
    Ok(Baseline { exact, lstar, render, gather_timing, shade_timing, paper, moments: pixel_moments })
}

/// `T l` in f64, part by part, rounded to an `L*`: the paper's rule's uncompressed `L*`.
fn exact_lstar(t: TransferView<'_>, l: &LightVector) -> Result<LocalRadiance> {
    let rows = t.map_rows(|_, part| -> Result<_> { Ok(reference_product(part, l)) })?;
    Ok(LocalRadiance::from_f64(t.local_basis(), t.vertices(), &rows)?)
}

/// The three exact moment gathers of `m` ([`exact_lstar`] along each axis): what a per-pixel
/// resolve (`moments_resolve = "pixel"`) shades for the uncompressed `T`.
pub(crate) fn moment_gathers(t: TransferView<'_>, m: &LightMoments) -> Result<[LocalRadiance; 3]> {
    let [x, y, z] = &m.along;
    Ok([exact_lstar(t, x)?, exact_lstar(t, y)?, exact_lstar(t, z)?])
}

/// The machine's 1-minute load average (`/proc/loadavg`), `None` where it cannot be read (off
/// Linux): taken before and after the run's timed steps ([`LoadRecord`]).
pub(crate) fn load_average_1min() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg").ok()?.split_whitespace().next()?.parse().ok()
}

/// The CPUs online on the machine, what its load average is spread over (at least 1).
pub(crate) fn cpus_online() -> usize {
    // SAFETY: sysconf only reads a system constant.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    match usize::try_from(n) {
        Ok(n) if n > 0 => n,
        _ => std::thread::available_parallelism().map_or(1, |n| n.get()),
    }
}

/// How the pipeline's reference weights each traced texel (whatever `light_moments` says).
/// Changing it, or anything of how [`reference`] renders, needs a bump of
/// [`crate::store::cache::REFERENCE_VERSION`], so no cached reference of the old code is reused.
pub(crate) const REFERENCE_RULE: ReferenceRule = ReferenceRule::GroundTruth;

/// The artifact kind of a cached reference (`reference-<key>.bsf`): fields `width`, `height`,
/// `seconds` (the trace's), `samples_per_pixel`; arrays `image` (f32 RGB, row-major, row 0 at
/// the top, without the background), `mask` (u8, 1 where the mesh is hit) and, with several
/// samples per pixel, `coverage` (f32).
pub(crate) const REFERENCE_ARTIFACT: &str = "reference";

/// The reference's camera (the run's at `report.reference_downscale`) and the cache key of its
/// image in `scene` ([`reference_key`]), as [`reference`] computes them; `biscale plan` asks too.
pub(crate) fn reference_key_of(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    scene: &ShadeScene,
    analytic: &[Option<Brdf>],
) -> (Camera, CacheKey) {
    let camera = geometry.camera(exp, *exp.file.report.reference_downscale.get_ref());
    let key = reference_key(scene, &lighting.light, &exp.transfer_settings(), &camera, REFERENCE_RULE, analytic);
    (camera, key)
}

/// A traced reference (before its background) as a cache artifact ([`REFERENCE_ARTIFACT`]).
fn reference_artifact(render: &Render, camera: &Camera, seconds: f64) -> Artifact {
    let image = render.image.pixels.iter().flatten().copied().collect();
    let mask = render.mask.iter().map(|&m| m as u8).collect();
    let a = Artifact::new(REFERENCE_ARTIFACT)
        .with("width", Field::U64(render.image.width as u64))
        .with("height", Field::U64(render.image.height as u64))
        .with("samples_per_pixel", Field::U64(camera.samples_per_pixel as u64))
        .with("seconds", Field::F64(seconds))
        .with_array("image", ArrayData::F32(image))
        .with_array("mask", ArrayData::U8(mask));
    match &render.coverage {
        Some(c) => a.with_array("coverage", ArrayData::F32(c.clone())),
        None => a,
    }
}

/// A cached reference read back: the render (without background) and the trace's seconds.
/// Every size is checked against the header's, every value against what a trace can give.
fn reference_from_artifact(mut a: Artifact) -> std::result::Result<(Render, f64), ArtifactError> {
    a.expect_kind(REFERENCE_ARTIFACT)?;
    let (width, height) = (a.u64("width")?, a.u64("height")?);
    let pixels = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if (w as u64) * (h as u64) <= biscale_core::scene::image::MAX_IMAGE_PIXELS => {
            w as usize * h as usize
        }
        _ => return Err(a.corrupt(format!("a {width}x{height} image"))),
    };
    let seconds = a.f64("seconds")?;
    let image = match a.take_array("image")? {
        ArrayData::F32(v) if v.len() == 3 * pixels && v.iter().all(|x| x.is_finite()) => v,
        _ => return Err(a.corrupt(format!("'image' is not {pixels} finite f32 RGB pixels"))),
    };
    let mask = match a.take_array("mask")? {
        ArrayData::U8(v) if v.len() == pixels && v.iter().all(|&m| m <= 1) => v,
        _ => return Err(a.corrupt(format!("'mask' is not {pixels} values of 0 or 1"))),
    };
    let coverage = match a.arrays.iter().any(|x| x.name == "coverage") {
        false => None,
        true => match a.take_array("coverage")? {
            ArrayData::F32(v) if v.len() == pixels && v.iter().all(|x| (0.0..=1.0).contains(x)) => Some(v),
            _ => return Err(a.corrupt(format!("'coverage' is not {pixels} fractions"))),
        },
    };
    let image = HdrImage {
        width: width as u32,
        height: height as u32,
        pixels: image.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
    };
    Ok((Render { image, mask: mask.into_iter().map(|m| m == 1).collect(), coverage }, seconds))
}

/// The ground-truth reference of the run's view at `report.reference_downscale` with the
/// baseline's errors against it ([`reference_render`]).
pub(crate) fn reference(
    exp: &Experiment,
    geometry: &Geometry,
    view: &View<'_>,
    lighting: &Lighting,
    baseline: &Baseline,
    exposure: f32,
    cache: Option<&StageCache>,
) -> Result<Reference> {
    let traced = reference_render(exp, geometry, view, lighting, cache)?;
    let (render, camera) = (traced.render, traced.camera);
    let small = view.render_shaded(baseline.shaded(), &camera)?;
    let baseline_error = compare_exposed(&small.image, &render.image, Some(&render.mask), exposure)?;
    let paper_baseline_error = match &baseline.paper {
        Some((lstar, _)) => {
            let small = view.render(lstar, &camera)?;
            Some(compare_exposed(&small.image, &render.image, Some(&render.mask), exposure)?)
        }
        None => None,
    };
    Ok(Reference {
        render,
        camera,
        seconds: traced.seconds,
        cached: traced.cached,
        baseline_error,
        paper_baseline_error,
        scored: Default::default(),
    })
}

/// A traced (or cached) reference image, with the background.
pub(crate) struct TracedReference {
    pub render: Render,
    /// The camera at `report.reference_downscale`.
    pub camera: Camera,
    /// The trace's seconds (the cached file's, when loaded).
    pub seconds: f64,
    pub cached: bool,
}

/// The ground-truth reference image of the run's view at `report.reference_downscale`: loaded
/// from `cache` when it holds one under the same [`reference_key`] (the image as traced, before
/// its background, which is added here either way), else traced and stored there.
pub(crate) fn reference_render(
    exp: &Experiment,
    geometry: &Geometry,
    view: &View<'_>,
    lighting: &Lighting,
    cache: Option<&StageCache>,
) -> Result<TracedReference> {
    let (camera, key) = reference_key_of(exp, geometry, lighting, view.scene, view.analytic);
    let cached = cache.map(|c| (c, c.reference_path(&key), key));
    let loaded = cached.as_ref().and_then(|(c, path, key)| {
        let accept = |(r, _): &(Render, f64)| {
            let (w, h) = (r.image.width, r.image.height);
            let several = camera.samples_per_pixel > 1;
            match (w, h, r.coverage.is_some()) == (camera.width, camera.height, several) {
                true => Ok(()),
                false => Err(format!(
                    "{}: holds a {w}x{h} reference{}, this run needs {}x{}{}",
                    path.display(),
                    if r.coverage.is_some() { " with coverage" } else { "" },
                    camera.width,
                    camera.height,
                    if several { " with coverage" } else { "" }
                )),
            }
        };
        c.get(path, key, reference_from_artifact, accept)
    });
    let (render, seconds, from_cache) = match loaded {
        Some((render, seconds)) => {
            let path = &cached.as_ref().expect("loaded from a cache").1;
            log::info!("reference: loaded from cache {}", path.display());
            (render, seconds, true)
        }
        None => {
            let sampler = VisibilitySampler::new(&exp.transfer_settings());
            let pb = progress_bar(camera.height as u64, "reference");
            let tick = |rows: usize| pb.set_position(rows as u64);
            let start = Instant::now();
            let render = biscale_shading::reference::render_reference(
                view.scene,
                &lighting.light,
                &geometry.transfer,
                &sampler,
                &camera,
                REFERENCE_RULE,
                view.analytic,
                Some(&tick),
            )?;
            let seconds = start.elapsed().as_secs_f64();
            pb.finish_and_clear();
            log::info!("reference: traced {}x{} in {seconds:.1} s", camera.width, camera.height);
            if let Some((c, path, key)) = &cached {
                c.put(path, key, &reference_artifact(&render, &camera, seconds));
            }
            (render, seconds, false)
        }
    };
    let render = render.with_background(&camera, &view.background);
    Ok(TracedReference { render, camera, seconds, cached: from_cache })
}

#[cfg(feature = "gpu")]
pub(crate) use crate::stages::gpu_backend::GpuBackend;

/// Without the `gpu` feature there is no wgpu backend: this type has no values, so the
/// pipeline's code is the same with and without it.
#[cfg(not(feature = "gpu"))]
pub(crate) enum GpuBackend {}

#[cfg(not(feature = "gpu"))]
impl GpuBackend {
    pub(crate) fn new(_: &ShadeScene, _: &Camera, _: &[Option<Brdf>]) -> Result<Self> {
        Err(no_gpu_feature())
    }

    pub(crate) fn for_scene(&self, _: &ShadeScene, _: &Camera) -> Result<Self> {
        match *self {}
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &mut self,
        _: &CompressedForm,
        _: &biscale_kernels::KernelDesc,
        _: &LightVector,
        _: Option<(&LightMoments, &[VertexFrame])>,
        _: MomentsResolve,
        _: &[[f64; 3]],
        _: &Render,
        _: &biscale_core::scene::Background<'_>,
        _: usize,
    ) -> Result<GpuRecord> {
        match *self {}
    }
}

pub(crate) fn no_gpu_feature() -> PipelineError {
    PipelineError::Feature { what: "runtime.backend = \"gpu\"".into(), feature: "gpu" }
}

/// What every compressed form is measured against: the matrix it compresses and the light it
/// is gathered with, the f64 product `T L` (the reference for `L*`), the uncompressed
/// all-frequency image (the baseline), the reference and the view it is shaded in.
pub(crate) struct Evaluation<'a> {
    pub t: TransferView<'a>,
    pub light: &'a LightVector,
    /// With light moments: the light's moments and the vertex frames `T` was traced with;
    /// every form is then gathered three times and resolved ([`gather_keeping_moments`]).
    pub moments: Option<(&'a LightMoments, &'a [VertexFrame])>,
    /// `runtime.moments_resolve`, `Vertex` without light moments; per pixel, every form's image
    /// resolves its three moment gathers at each pixel (its `L*`, for the `L*` error, is still
    /// resolved per vertex).
    pub resolve: MomentsResolve,
    pub exact: &'a [[f64; 3]],
    pub baseline: &'a Render,
    pub view: &'a View<'a>,
    pub reference: Option<&'a Reference>,
    pub repeats: usize,
    pub exposure: f32,
    pub out_dir: &'a Path,
    /// The error figure waits for the run's shared scale ([`share_error_scale`] draws it once
    /// every compressor is measured); otherwise it is drawn at its own scale right away.
    pub shared_error_scale: bool,
}

impl<'a> Evaluation<'a> {
    /// The evaluation of forms of `t` against the [`Targets`] made for it in `view`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        exp: &Experiment,
        t: TransferView<'a>,
        lighting: &'a Lighting,
        geometry: &'a Geometry,
        targets: &'a Targets,
        view: &'a View<'a>,
        out_dir: &'a Path,
        shared_error_scale: bool,
    ) -> Self {
        Evaluation {
            t,
            light: &lighting.light,
            moments: targets.moments.as_ref().map(|m| (m, geometry.transfer.frames())),
            resolve: match targets.base.moments.is_some() {
                true => exp.file.runtime.moments_resolve().unwrap_or(MomentsResolve::Pixel),
                false => MomentsResolve::Vertex,
            },
            exact: &targets.base.exact,
            baseline: &targets.base.render,
            view,
            reference: targets.reference.as_ref(),
            repeats: exp.file.runtime.repeats,
            exposure: targets.tone.exposure,
            out_dir,
            shared_error_scale,
        }
    }
}

/// Relative L* error above which a form's `lossless` claim is refused. f32 gathers of lossless
/// forms measure at most 2e-7 on the bundled scenes; the worst-case f32 bound for a row of
/// N = 6144 non-negative terms is (N + 2) 2^-24 = 3.7e-4. Anything past 1e-3 is not rounding.
pub const LOSSLESS_CLAIM_TOLERANCE: f64 = 1e-3;

impl Evaluation<'_> {
    /// Gather and shade `form` (and on the GPU backend when given), compare it with the
    /// baseline and the reference, write its images: its record.
    pub(crate) fn record(
        &self,
        setting: &CompressorSetting,
        compressor: &dyn Compressor,
        form: &CompressedForm,
        cached: bool,
        gpu: Option<&mut GpuBackend>,
    ) -> Result<(CompressorRecord, Render)> {
        let (view, repeats) = (self.view, self.repeats);
        let cerr = |source| PipelineError::Compress { name: setting.label.clone(), source };
        let ((lstar, gathered), gather_timing) = timed(repeats, || {
            match self.moments {
                None => compressor.gather(form, self.light).map(|l| (l, None)),
                // The same gathers and resolve either way; per pixel the image shades the three.
                Some((moments, frames)) => gather_keeping_moments(compressor, form, moments, frames)
                    .map(|(l, g)| (l, self.resolve.per_pixel().then_some(g))),
            }
            .map_err(cerr)
        })?;
        let (mut record, render) = self.score_timed(&setting.label, &lstar, gathered.as_ref(), Some(gather_timing))?;
        // A compressor without a GPU gather (a hosted one) is gathered on the CPU only.
        let gpu = match gpu.filter(|_| compressor.has_kernels()) {
            Some(g) => {
                let kernels = compressor.kernels(form).map_err(cerr)?;
                Some(g.run(
                    form,
                    &kernels,
                    self.light,
                    self.moments,
                    self.resolve,
                    self.exact,
                    &render,
                    &view.background,
                    repeats,
                )?)
            }
            None => None,
        };
        let name = &setting.label;
        if let Some(g) = &gpu {
            log::info!(
                "{name} on the gpu: gather {} ms, shade {} ms ({}), rel. error of L* {:.2e}, image vs cpu rel. L2 {:.2e} ({} of {} pixels differ by > 1e-3)",
                g.gather_timing.map_or(format!("{:.2}", g.gather_ms), |t| t.median_range(2)),
                g.shade_timing.map_or(format!("{:.2}", g.shade_ms), |t| t.median_range(2)),
                g.timing, g.rel_error_lstar, g.image_vs_cpu.rel_l2, g.differing_pixels, g.covered_pixels
            );
        }
        let name = &name.replace(':', "-");
        let rel_error_lstar = record.rel_error_lstar;
        log::info!(
            "{name}: {:.2} MB, {:.2} Mflop/gather, built in {:.2} s{}, gather {} ms, rel. error of L* {rel_error_lstar:.2e}",
            form.bytes() as f64 / 1e6,
            form.flops_per_gather as f64 / 1e6,
            form.build_seconds,
            if cached { " (cached)" } else { "" },
            gather_timing.median_range(2),
        );
        // The host checks a lossless claim (a plugin's, or our own) against its f64 product.
        let lossless = form.lossless && rel_error_lstar <= LOSSLESS_CLAIM_TOLERANCE;
        if form.lossless && !lossless {
            crate::util::warn(format_args!(
                "{name}: the form claims to be lossless, but its L* is {rel_error_lstar:.2e} from the f64 \
                 product T L (more than f32 rounding explains, {LOSSLESS_CLAIM_TOLERANCE:.0e}); reported as lossy"
            ));
        }
        record.kind = compressor.kind().to_string();
        record.params = compressor.params();
        record.lossless = lossless;
        record.bytes = form.bytes();
        record.bytes_by_array = form.bytes_by_array();
        record.bytes_per_nnz = form.bytes() as f64 / self.t.nnz().max(1) as f64;
        record.flops_per_gather = form.flops_per_gather;
        record.build_seconds = form.build_seconds;
        record.cached = cached;
        record.stats = compressor.stats(form, self.t);
        record.gpu = gpu;
        Ok((record, render))
    }

    /// Shade `lstar` (gathered in `gather_ms`, not timed here: no `gather_timing`), compare it
    /// with the baseline and the reference and write its images as `images/<name>.*`: a record
    /// whose form fields (kind, params, storage, flops, build, stats, GPU) are empty for the
    /// caller to fill in (`crate::interop::eval` for an external `L*`).
    pub(crate) fn score(
        &self,
        name: &str,
        lstar: &LocalRadiance,
        gather_ms: f64,
    ) -> Result<(CompressorRecord, Render)> {
        if let Some(what) = self.resolve.refuses_lstar() {
            return Err(PipelineError::Mismatch { path: self.out_dir.to_path_buf(), what: format!("{name}: {what}") });
        }
        let (mut record, render) = self.score_timed(name, lstar, None, None)?;
        record.gather_ms = gather_ms;
        Ok((record, render))
    }

    /// [`Self::score`] of an `L*` whose gather was timed (`gather_timing`, [`Self::record`]).
    /// `moments`: the three gathers the image resolves per pixel (`per_pixel`), else `lstar`'s.
    fn score_timed(
        &self,
        name: &str,
        lstar: &LocalRadiance,
        moments: Option<&[LocalRadiance; 3]>,
        gather_timing: Option<Timing>,
    ) -> Result<(CompressorRecord, Render)> {
        let (view, repeats) = (self.view, self.repeats);
        let rel_error_lstar = relative_l2_error(lstar.values(), self.exact);
        let shaded = Shaded::of(lstar, moments);
        let (render, shade_timing) = view.timed_render_shaded(shaded, repeats)?;
        let vs_uncompressed =
            errors(&compare_exposed(&render.image, &self.baseline.image, Some(&self.baseline.mask), self.exposure)?);
        let vs_reference = match self.reference {
            Some(r) => {
                let small = view.render_shaded(shaded, &r.camera)?;
                let e = errors(&compare_exposed(&small.image, &r.render.image, Some(&r.render.mask), self.exposure)?);
                r.scored.lock().unwrap_or_else(|p| p.into_inner()).push((name.replace(':', "-"), small.image));
                Some(e)
            }
            None => None,
        };
        let name = &name.replace(':', "-");
        let images_dir = self.out_dir.join("images");
        let (png, exr) = save_images(&render.image, &images_dir, name, self.exposure)?;
        let error_rel = format!("images/{name}_error.png");
        let (error_scale, error_max) = match self.shared_error_scale {
            true => error_extent(&render.image, &self.baseline.image)?,
            false => write_error_figure(
                &render.image,
                &self.baseline.image,
                "uncompressed",
                None,
                &self.out_dir.join(&error_rel),
            )?,
        };
        let record = CompressorRecord {
            name: name.clone(),
            kind: String::new(),
            params: serde_json::Value::Null,
            lossless: false,
            bytes: 0,
            bytes_by_array: Default::default(),
            bytes_per_nnz: 0.0,
            flops_per_gather: 0,
            build_seconds: 0.0,
            cached: false,
            gather_ms: gather_timing.map_or(0.0, |t| t.median_ms),
            shade_ms: shade_timing.median_ms,
            gather_timing,
            shade_timing: Some(shade_timing),
            rel_error_lstar,
            image: ImageRecord {
                vs_uncompressed,
                vs_reference,
                png,
                exr,
                error_png: Some(error_rel),
                error_scale: Some(error_scale),
                error_max: Some(error_max),
            },
            stats: None,
            gpu: None,
        };
        Ok((record, render))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timed_keeps_every_repeat_and_the_last_result() {
        let mut calls = 0;
        let (last, t) = timed(4, || {
            calls += 1;
            Ok(calls)
        })
        .unwrap();
        assert_eq!((last, calls, t.repeats), (4, 4, 4));
        assert!(t.min_ms <= t.median_ms && t.median_ms <= t.max_ms && t.spread >= 0.0, "{t:?}");
        // Zero repeats still run once.
        let (_, t) = timed(0, || Ok(())).unwrap();
        assert_eq!((t.repeats, t.spread), (1, 0.0));
    }

    #[test]
    fn the_load_is_read_on_linux_and_the_cpus_are_counted() {
        assert!(cpus_online() >= 1);
        if cfg!(target_os = "linux") {
            assert!(load_average_1min().is_some_and(|l| l >= 0.0));
        }
    }
}

#[cfg(test)]
mod reference_cache_tests {
    use super::*;
    use crate::stages::scene::{load_geometry, load_lighting};

    /// The reference's key of the smoke config with `--set` overrides, as a run computes it.
    fn key_of(sets: &[&str]) -> CacheKey {
        let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/smoke.toml");
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let exp = Experiment::load_with(&smoke, &sets).unwrap();
        let (geometry, lighting) = (load_geometry(&exp).unwrap(), load_lighting(&exp).unwrap());
        let local = exp.transfer_settings().local_basis();
        let m = crate::stages::materials::load_materials(&exp, &geometry.mesh, local, None).unwrap();
        let frames = geometry.transfer.frames().to_vec();
        let scene =
            ShadeScene::new(geometry.mesh.clone(), frames, m.materials.clone(), m.triangle_materials.clone()).unwrap();
        reference_key_of(&exp, &geometry, &lighting, &scene, &m.analytic).1
    }

    /// Every config value the reference image depends on misses the cache; the ones it does
    /// not (the compressor list, the name that names the default output folder, the background
    /// and exposure, which are applied after the cache, repeats, light moments) hit it.
    #[test]
    fn the_reference_key_follows_the_config_values_the_image_depends_on() {
        let base = key_of(&[]);
        assert_eq!(base, key_of(&[]), "the same config gives the same key");
        for set in [
            "runtime.camera.azimuth_degrees = 40",
            "runtime.camera.elevation_degrees = 30",
            "runtime.camera.fov_y_degrees = 45",
            "runtime.width = 128",
            "runtime.height = 96",
            "report.reference_downscale = 1",
            "runtime.samples_per_pixel = 1",
            "lighting.rotation_degrees = 90",
            "lighting.sun_boost = 4.0",
            "lighting.env_map = \"../assets/envmaps/blender_forest.exr\"",
            "scene.mesh = \"../assets/meshes/teapot.obj\"",
            "scene.material.albedo = [0.7, 0.8, 0.8]",
            "transfer.visibility_resolution = 32",
        ] {
            assert_ne!(key_of(&[set]).hash, base.hash, "{set} left the reference's key as it was");
        }
        for set in [
            "compressors = [{ kind = \"sparse\" }]",
            "name = \"elsewhere\"",
            "report.background = false",
            "report.exposure = 2.0",
            "runtime.repeats = 3",
            "runtime.light_moments = true",
            "seed = 8",
        ] {
            assert_eq!(key_of(&[set]), base, "{set} changed the reference's key");
        }
    }

    /// A reference goes into the cache and comes back as it was, coverage and all; a file
    /// whose arrays do not fit its header is refused.
    #[test]
    fn a_cached_reference_reads_back_as_it_was_written() {
        let mut render =
            Render { image: HdrImage::new(3, 2), mask: vec![true, false, true, true, false, false], coverage: None };
        render.image.pixels[2] = [0.5, 1.5, 2.5];
        let camera = Camera::frame_bounds(glam::Vec3::ZERO, glam::Vec3::ONE, 3, 2, 0.0, 0.0, 40.0);
        let back = reference_from_artifact(reference_artifact(&render, &camera, 1.25)).unwrap();
        assert_eq!(back, (render.clone(), 1.25));
        render.coverage = Some(vec![1.0, 0.0, 0.25, 0.5, 0.0, 0.0]);
        let back = reference_from_artifact(reference_artifact(&render, &camera, 2.0)).unwrap();
        assert_eq!(back, (render.clone(), 2.0));
        let wrong = reference_artifact(&render, &camera, 2.0).with("width", Field::U64(4));
        assert!(reference_from_artifact(wrong).unwrap_err().to_string().contains("'image'"));
    }
}
