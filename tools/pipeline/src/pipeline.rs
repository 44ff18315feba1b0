//! The pipeline: wires the stages from an [`Experiment`] and writes the run's output folder
//! (`plan.txt`, `metrics.json`, `report.md`, `report.html`, plots, `images/`).
//!
//! [`run`] reads as the data flow of the README: geometry, lighting, transfer, materials (on
//! `T`'s local basis), the uncompressed baseline, the reference, then every compressor
//! setting, then the report. Each step is a function below that takes plain data and returns
//! a plain record; stages never reach into each other.

use crate::cache::{CacheKey, StageCache};
use crate::config::{Backend, CompressorSetting, Experiment};
use crate::materials::{load_materials, SceneMaterials};
use crate::metrics::*;
use crate::plan::Plan;
use crate::staging::{fault_point, StagedDir};
use crate::util::progress_bar;
use biscale_compressors::registry::{self, BuildError};
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::gather::moments::{exact_moments_product, gather_with_moments, LightMoments, Lobe};
use biscale_core::gather::{reference_product, relative_l2_error, LocalRadiance};
use biscale_core::geometry::{Mesh, Placement, VertexFrame};
use biscale_core::io::write_atomic_bytes;
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::scene::{Background, Camera, HdrImage, Render, ShadeScene};
use biscale_core::transfer::{self, TransferMatrix, TransferScene, TransferSettings, VisibilitySampler};
use biscale_shading::cpu::shade;
use biscale_shading::error::ShadingError;
use biscale_shading::image::{compare_exposed, ImageMetrics};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Errors of a pipeline run; each says which stage and input it concerns.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Core(#[from] biscale_core::CoreError),
    #[error("compressor {name}: {source}")]
    Build { name: String, source: BuildError },
    #[error("compressor {name}: {source}")]
    Compress { name: String, source: biscale_core::compress::CompressError },
    #[cfg(feature = "gpu")]
    #[error("gpu backend: {0}")]
    Gpu(#[from] biscale_gpu::GpuError),
    #[error(transparent)]
    Shading(#[from] ShadingError),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A material entry whose BTF could not be made (`label` names the entry).
    #[error("material {label}: {source}")]
    Material { label: String, source: ShadingError },
    /// Inputs that do not fit together, named by the file they come from (an OBJ whose
    /// materials the config does not name, a material the config does not have).
    #[error("{}: {what}", path.display())]
    Mismatch { path: PathBuf, what: String },
    #[error(transparent)]
    Viz(#[from] crate::viz::VizError),
    #[error(transparent)]
    Staging(#[from] crate::staging::StagingError),
    /// The config asks for something this build was compiled without.
    #[error("{what} needs biscale built with the `{feature}` cargo feature")]
    Feature { what: String, feature: &'static str },
}

pub type Result<T, E = PipelineError> = std::result::Result<T, E>;

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io { path: path.to_path_buf(), source }
}

/// Options of `biscale run`.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Output folder (default `out/<name>/`).
    pub out_dir: Option<PathBuf>,
    /// Cache folder for stage outputs (default [`crate::cache::default_dir`]); `None` with
    /// `no_cache` disables caching.
    pub cache_dir: Option<PathBuf>,
    pub no_cache: bool,
}

/// The loaded mesh and the geometry every visibility query shares.
pub struct Geometry {
    pub mesh: Mesh,
    /// What the loader repaired, and vertices whose normal fell back (one line each).
    pub repairs: Vec<String>,
    pub transfer: TransferScene,
    /// How the mesh was moved and scaled from its file's coordinates
    /// ([`biscale_core::geometry::placement`]); config values in world units go through it.
    pub placement: Placement,
}

impl Geometry {
    /// The experiment's camera for this geometry at `downscale` ([`camera_placed`]).
    pub fn camera(&self, exp: &Experiment, downscale: u32) -> Camera {
        camera_placed(exp, &self.mesh, &self.placement, downscale)
    }
}

/// Load the mesh, condition its coordinates for f32 (one similarity for every stage) and
/// build its transfer scene (frames and the normalised BVH), once.
pub fn load_geometry(exp: &Experiment) -> Result<Geometry> {
    let mut load = Mesh::load(&exp.mesh_path)?;
    let placement = biscale_core::geometry::placement::condition(&mut load.mesh);
    if !placement.is_identity() {
        load.repairs.push(format!(
            "coordinates out of f32's comfortable range: the mesh (and any camera position or target) \
             is moved by -({:.3e}, {:.3e}, {:.3e}) and scaled by 2^{}; images and transfer are unchanged by this similarity",
            placement.centre.x,
            placement.centre.y,
            placement.centre.z,
            placement.scale.log2().round()
        ));
    }
    let transfer = TransferScene::new(&load.mesh)?;
    let mut repairs = load.repairs;
    if transfer.frame_fallbacks() > 0 {
        repairs
            .push(format!("{} vertices had no usable normal (cancelling faces); used +Y", transfer.frame_fallbacks()));
    }
    Ok(Geometry { mesh: load.mesh, repairs, transfer, placement })
}

/// The lighting: `L` and the map it came from (for backgrounds).
pub struct Lighting {
    pub light: LightVector,
    pub env: EnvMap,
    pub rotation: f64,
    pub warnings: Vec<String>,
}

impl Lighting {
    /// What a primary ray that misses the mesh sees (per `report.background`).
    pub fn background(&self, exp: &Experiment) -> Background<'_> {
        if exp.file.report.background {
            Background::Env { env: &self.env, rotation: self.rotation }
        } else {
            Background::Black
        }
    }
}

/// `L` in the experiment's light basis, from its env map or constant sky (and `sun_boost`).
pub fn load_lighting(exp: &Experiment) -> Result<Lighting> {
    let l = &exp.file.lighting;
    let rotation = l.rotation_degrees.to_radians();
    let (env, mut warnings) = match (&exp.env_path, l.constant) {
        (Some(p), _) => EnvMap::load(p)?,
        (None, Some(c)) => (EnvMap::constant(64, 32, c), vec![]),
        (None, None) => unreachable!("validated by the config"),
    };
    let mut light = LightVector::from_env(&env, exp.transfer_settings().cubemap(), rotation);
    if let Some(boost) = &l.sun_boost {
        if let Some(k) = light.boost_brightest(*boost.get_ref()) {
            warnings.push(format!("sun_boost: texel {k} multiplied by {}", boost.get_ref()));
        }
    }
    Ok(Lighting { light, env, rotation, warnings })
}

/// `T` with its record and its cache key (which keys every output built from it).
pub struct Transfer {
    pub matrix: TransferMatrix,
    pub metrics: TransferMetrics,
    pub key: CacheKey,
}

/// Build (or load from the cache) the transfer matrix with a progress bar.
pub fn transfer_matrix(exp: &Experiment, geometry: &Geometry, cache: Option<&StageCache>) -> Result<Transfer> {
    let settings = exp.transfer_settings();
    let key = crate::cache::transfer_key(&geometry.mesh, &settings);
    let shape = settings.shape(geometry.mesh.vertex_count());
    if let Some(c) = cache {
        let path = c.transfer_path(&key);
        let accept = |t: &TransferMatrix| match t.shape() == shape {
            true => Ok(()),
            false => Err(format!("{}: holds {}, this run needs {shape}", path.display(), t.shape())),
        };
        if let Some(matrix) = c.get(&path, &key, TransferMatrix::from_artifact, accept) {
            crate::note!("transfer: loaded from cache {}", path.display());
            let metrics = transfer_metrics(&matrix, 0.0, 0, 0.0, true, &settings);
            return Ok(Transfer { matrix, metrics, key });
        }
    }
    let vertices = geometry.mesh.vertex_count();
    let pb = progress_bar(vertices as u64, "transfer");
    let tick = |done: usize| pb.set_position(done as u64);
    let start = Instant::now();
    let mut build = transfer::build_range(&geometry.transfer, &settings, 0..vertices, Some(&tick))?;
    // The scene was built with the geometry; count its time here too, as a whole build would.
    build.stats.seconds = start.elapsed().as_secs_f64();
    build.stats.rays_per_second = build.stats.rays_traced as f64 / build.stats.seconds.max(1e-12);
    pb.finish_and_clear();
    crate::note!("transfer: {build}");
    if let Some(c) = cache {
        c.put_with(&c.transfer_path(&key), &key, || build.matrix.to_artifact());
    }
    let s = &build.stats;
    let metrics = transfer_metrics(&build.matrix, s.seconds, s.rays_traced, s.rays_per_second, false, &settings);
    Ok(Transfer { matrix: build.matrix, metrics, key })
}

/// One setting's compressed form of `t` (whose cache key is `t_key`), built or loaded from the
/// cache (`true` when loaded). A form from the cache keeps the build time it was measured with.
pub fn compressed_form(
    setting: &CompressorSetting,
    compressor: &dyn Compressor,
    t: &TransferMatrix,
    t_key: &CacheKey,
    seed: u64,
    cache: Option<&StageCache>,
) -> Result<(CompressedForm, bool)> {
    let name = &setting.label;
    let cached =
        cache.zip(crate::cache::form_key(t_key, compressor, seed)).map(|(c, key)| (c, c.form_path(&key, name), key));
    if let Some((c, path, key)) = &cached {
        let accept = |f: &CompressedForm| match f.kind == compressor.kind() && f.shape() == t.shape() {
            true => Ok(()),
            false => Err(format!(
                "{}: holds a {} form of {}, this run needs {}",
                path.display(),
                f.kind,
                f.shape(),
                t.shape()
            )),
        };
        if let Some(form) = c.get(path, key, CompressedForm::from_artifact, accept) {
            crate::note!("{name}: loaded from cache {}", path.display());
            return Ok((form, true));
        }
    }
    let pb = progress_bar(1000, name);
    let progress = |f: f64| pb.set_position((f.clamp(0.0, 1.0) * 1000.0) as u64);
    let ctx = CompressContext { seed, progress: Some(&progress) };
    let form = compressor.compress(t, &ctx).map_err(|source| PipelineError::Compress { name: name.clone(), source })?;
    pb.finish_and_clear();
    if let Some((c, path, key)) = &cached {
        c.put(path, key, &form.to_artifact());
    }
    Ok((form, false))
}

fn transfer_metrics(
    t: &TransferMatrix,
    seconds: f64,
    rays: u64,
    rays_per_second: f64,
    cached: bool,
    settings: &TransferSettings,
) -> TransferMetrics {
    let mut hist = std::collections::BTreeMap::<u32, u64>::new();
    for v in t.csr().data() {
        *hist.entry(v.to_bits()).or_default() += 1;
    }
    let mut value_histogram: Vec<ValueCount> =
        hist.into_iter().map(|(b, count)| ValueCount { value: f32::from_bits(b), count }).collect();
    value_histogram.sort_by(|a, b| a.value.total_cmp(&b.value));
    TransferMetrics {
        rows: t.rows(),
        cols: t.cols(),
        nnz: t.nnz(),
        local_dirs: t.local_dirs(),
        visibility_resolution: settings.visibility_resolution(),
        value_histogram,
        build_seconds: seconds,
        rays_traced: rays,
        rays_per_second,
        cached,
        vertices_without_sky: vertices_without_sky(t),
    }
}

/// Vertices whose M rows of `t` are all zero.
pub fn vertices_without_sky(t: &TransferMatrix) -> usize {
    let ip = t.csr().indptr();
    let ip = ip.raw_storage();
    let m = t.local_dirs().max(1);
    (0..t.vertices()).filter(|&v| ip[v * m] == ip[(v + 1) * m]).count()
}

/// A warning when at least half of the vertices see no sky: the likely causes, so a black
/// image with exit 0 does not go unexplained.
pub fn sky_warning(t: &TransferMetrics, vertices: usize) -> Option<String> {
    let n = t.vertices_without_sky;
    (vertices > 0 && 2 * n >= vertices).then(|| {
        format!(
            "{:.0}% of the vertices ({n} of {vertices}) see no sky: every row of T is zero there, so they render \
             black. Is the mesh inside out (faces wound clockwise, normals pointing into the solid) or closed \
             around the camera?",
            100.0 * n as f64 / vertices as f64
        )
    })
}

/// The shade scene: the mesh, the transfer scene's frames and the materials, whose BTFs are
/// built on `T`'s local basis (synthesized ones cached when there is a cache).
pub fn shade_scene(
    exp: &Experiment,
    geometry: &Geometry,
    t: &TransferMatrix,
    cache: Option<&StageCache>,
) -> Result<(ShadeScene, SceneMaterials)> {
    let materials = load_materials(exp, &geometry.mesh, t.local_basis(), cache)?;
    let scene = ShadeScene::new(
        geometry.mesh.clone(),
        geometry.transfer.frames().to_vec(),
        materials.materials.clone(),
        materials.triangle_materials.clone(),
    )?;
    Ok((scene, materials))
}

/// The camera of the experiment at `downscale`, for a mesh in its file's coordinates.
pub fn camera(exp: &Experiment, mesh: &Mesh, downscale: u32) -> Camera {
    camera_placed(exp, mesh, &Placement::IDENTITY, downscale)
}

/// The camera of the experiment at `downscale` for `mesh` placed by `placement`: the
/// config's position and target (file coordinates) go through the same similarity.
pub fn camera_placed(exp: &Experiment, mesh: &Mesh, placement: &Placement, downscale: u32) -> Camera {
    let rt = &exp.file.runtime;
    let (w, h) = ((rt.width.get_ref() / downscale).max(1), (rt.height.get_ref() / downscale).max(1));
    let c = &rt.camera;
    let (min, max) = mesh.bounds();
    let mut cam = Camera::frame_bounds(min, max, w, h, c.azimuth_degrees, c.elevation_degrees, c.fov_y_degrees);
    if let Some(p) = c.position {
        cam.position = placement.apply(p.into());
    }
    if let Some(t) = c.target {
        cam.target = placement.apply(t.into());
    }
    cam.samples_per_pixel = rt.samples_per_pixel();
    cam
}

pub(crate) fn errors(m: &ImageMetrics) -> ImageErrors {
    ImageErrors::from(m)
}

/// The uncompressed baseline: the f64 product `T L` (the reference for `L*` errors) and,
/// rounded to f32, the image every compressor is compared with. With light moments the
/// product weights every texel by its own cosine and moves the BRDF to each bin's mean light
/// direction ([`exact_moments_product`]), and the paper's
/// bin-mean-cosine `L*` is kept beside it so the report measures both side by side.
pub struct Baseline {
    pub exact: Vec<[f64; 3]>,
    pub lstar: LocalRadiance,
    pub render: Render,
    pub gather_ms: f64,
    pub shade_ms: f64,
    /// With light moments: the paper's `L*` and its image.
    pub paper: Option<(LocalRadiance, Render)>,
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

/// What every compressor setting is scored against, made the same way for `run` and `eval`.
pub(crate) struct Targets {
    /// The light's direction moments, with `runtime.light_moments`.
    pub moments: Option<LightMoments>,
    pub base: Baseline,
    /// The ground-truth reference, when the plan traces one.
    pub reference: Option<Reference>,
}

/// The [`Targets`] of `t` in `view`, their images written into `images_dir` (`uncompressed`,
/// with moments also `uncompressed_paper`, `mask`, and with `trace_reference` `reference` and
/// `reference_mask`). Refuses a camera that sees none of the mesh: every score would be empty.
#[allow(clippy::too_many_arguments)]
pub(crate) fn targets(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    t: &TransferMatrix,
    view: &View<'_>,
    images_dir: &Path,
    trace_reference: bool,
    clock: &mut crate::provenance::StageClock,
) -> Result<Targets> {
    let moments = match exp.file.runtime.light_moments {
        true => Some(LightMoments::new(&lighting.light)?),
        false => None,
    };
    let frames = geometry.transfer.frames();
    let base = baseline(t, lighting, moments.as_ref().map(|_| frames), view, exp.file.runtime.repeats)?;
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
    let exposure = exp.file.report.exposure;
    save_images(&base.render.image, images_dir, "uncompressed", exposure)?;
    if let Some((_, paper)) = &base.paper {
        save_images(&paper.image, images_dir, "uncompressed_paper", exposure)?;
    }
    base.render.write_mask_png(&images_dir.join("mask.png"))?;
    clock.mark("uncompressed baseline");
    fault_point("images");
    let reference = match trace_reference {
        true => {
            let r = reference(exp, geometry, view, lighting, &base)?;
            save_images(&r.render.image, images_dir, "reference", exposure)?;
            r.render.write_mask_png(&images_dir.join("reference_mask.png"))?;
            clock.mark("reference");
            Some(r)
        }
        false => None,
    };
    Ok(Targets { moments, base, reference })
}

pub(crate) fn baseline(
    t: &TransferMatrix,
    lighting: &Lighting,
    moments: Option<&[VertexFrame]>,
    view: &View<'_>,
    repeats: usize,
) -> Result<Baseline> {
    let (exact, gather_ms) = timed(repeats, || uncompressed_product(t, &lighting.light, moments))?;
    let lstar = LocalRadiance::from_f64(t.local_basis(), t.vertices(), &exact)?;
    let (render, shade_ms) = view.timed_render(&lstar, repeats)?;
    let paper = match moments {
        None => None,
        Some(_) => {
            let lstar = LocalRadiance::from_f64(t.local_basis(), t.vertices(), &reference_product(t, &lighting.light))?;
            let render = view.render(&lstar, &view.camera)?;
            Some((lstar, render))
        }
    };
    Ok(Baseline { exact, lstar, render, gather_ms, shade_ms, paper })
}

/// What every render of the run shares: the scene, the camera and the background.
pub(crate) struct View<'a> {
    pub scene: &'a ShadeScene,
    pub camera: Camera,
    pub background: Background<'a>,
}

impl View<'_> {
    /// The image of `lstar` with the background behind it.
    fn render(&self, lstar: &LocalRadiance, camera: &Camera) -> Result<Render> {
        Ok(shade(self.scene, lstar, camera)?.with_background(camera, &self.background))
    }

    /// [`Self::render`] at the run's camera, `repeats` times: the image and the median ms.
    fn timed_render(&self, lstar: &LocalRadiance, repeats: usize) -> Result<(Render, f64)> {
        timed(repeats, || self.render(lstar, &self.camera))
    }
}

/// Run `f` `repeats` times (at least once): its last result and the median wall time (ms).
pub(crate) fn timed<T>(repeats: usize, mut f: impl FnMut() -> Result<T>) -> Result<(T, f64)> {
    let mut samples = vec![];
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        last = Some(f()?);
        samples.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok((last.expect("at least one run"), biscale_core::stats::median(&samples)))
}

/// The ground truth (direct light), ray-traced per pixel at the reference resolution
/// ([`biscale_shading::reference::ReferenceRule::GroundTruth`]), and the baseline's error against it.
pub struct Reference {
    pub render: Render,
    pub camera: Camera,
    pub seconds: f64,
    pub baseline_error: ImageMetrics,
    /// With light moments: the paper-mode baseline's error against the same reference.
    pub paper_baseline_error: Option<ImageMetrics>,
    /// Every setting's render at the reference's camera, by name, kept as it is scored
    /// ([`Evaluation::score`]) for its error figure against the reference, which
    /// [`comparison_figures`] draws once every setting is in, at one scale for all.
    pub(crate) scored: std::sync::Mutex<Vec<(String, HdrImage)>>,
}

pub(crate) fn reference(
    exp: &Experiment,
    geometry: &Geometry,
    view: &View<'_>,
    lighting: &Lighting,
    baseline: &Baseline,
) -> Result<Reference> {
    let camera = geometry.camera(exp, *exp.file.report.reference_downscale.get_ref());
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
        biscale_shading::reference::ReferenceRule::GroundTruth,
        Some(&tick),
    )?
    .with_background(&camera, &view.background);
    let seconds = start.elapsed().as_secs_f64();
    pb.finish_and_clear();
    let small = view.render(&baseline.lstar, &camera)?;
    let exposure = exp.file.report.exposure;
    let baseline_error = compare_exposed(&small.image, &render.image, Some(&render.mask), exposure)?;
    let paper_baseline_error = match &baseline.paper {
        Some((lstar, _)) => {
            let small = view.render(lstar, &camera)?;
            Some(compare_exposed(&small.image, &render.image, Some(&render.mask), exposure)?)
        }
        None => None,
    };
    crate::note!("reference: traced {}x{} in {seconds:.1} s", camera.width, camera.height);
    Ok(Reference { render, camera, seconds, baseline_error, paper_baseline_error, scored: Default::default() })
}

#[cfg(feature = "gpu")]
pub(crate) use crate::gpu_backend::GpuBackend;

/// Without the `gpu` feature there is no wgpu backend: this type has no values, so the
/// pipeline's code is the same with and without it.
#[cfg(not(feature = "gpu"))]
pub(crate) enum GpuBackend {}

#[cfg(not(feature = "gpu"))]
impl GpuBackend {
    fn new(_: &ShadeScene, _: &Camera) -> Result<Self> {
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
        _: &[[f64; 3]],
        _: &Render,
        _: &Background<'_>,
        _: usize,
    ) -> Result<GpuRecord> {
        match *self {}
    }
}

fn no_gpu_feature() -> PipelineError {
    PipelineError::Feature { what: "runtime.backend = \"gpu\"".into(), feature: "gpu" }
}

/// What every compressed form is measured against: the matrix it compresses and the light it
/// is gathered with, the f64 product `T L` (the reference for `L*`), the uncompressed
/// all-frequency image (the baseline), the reference and the view it is shaded in.
pub(crate) struct Evaluation<'a> {
    pub t: &'a TransferMatrix,
    pub light: &'a LightVector,
    /// With light moments: the light's moments and the vertex frames `T` was traced with;
    /// every form is then gathered three times and resolved ([`gather_with_moments`]).
    pub moments: Option<(&'a LightMoments, &'a [VertexFrame])>,
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
        let (lstar, gather_ms) = timed(repeats, || {
            match self.moments {
                None => compressor.gather(form, self.light),
                Some((moments, frames)) => gather_with_moments(compressor, form, moments, frames),
            }
            .map_err(cerr)
        })?;
        let (mut record, render) = self.score(&setting.label, &lstar, gather_ms)?;
        let gpu = match gpu {
            Some(g) => {
                let kernels = compressor.kernels(form).map_err(cerr)?;
                Some(g.run(form, &kernels, self.light, self.moments, self.exact, &render, &view.background, repeats)?)
            }
            None => None,
        };
        let name = &setting.label;
        if let Some(g) = &gpu {
            crate::note!(
                "{name} on the gpu: gather {:.2} ms, shade {:.2} ms ({}), rel. error of L* {:.2e}, image vs cpu rel. L2 {:.2e} ({} of {} pixels differ by > 1e-3)",
                g.gather_ms, g.shade_ms, g.timing, g.rel_error_lstar, g.image_vs_cpu.rel_l2, g.differing_pixels, g.covered_pixels
            );
        }
        let name = &name.replace(':', "-");
        let rel_error_lstar = record.rel_error_lstar;
        crate::note!(
            "{name}: {:.2} MB, {:.2} Mflop/gather, built in {:.2} s{}, gather {gather_ms:.2} ms, rel. error of L* {rel_error_lstar:.2e}",
            form.bytes() as f64 / 1e6,
            form.flops_per_gather as f64 / 1e6,
            form.build_seconds,
            if cached { " (cached)" } else { "" },
        );
        // The host checks a lossless claim (a plugin's, or our own) against its f64 product.
        let lossless = form.lossless && rel_error_lstar <= LOSSLESS_CLAIM_TOLERANCE;
        if form.lossless && !lossless {
            eprintln!(
                "warning: {name}: the form claims to be lossless, but its L* is {rel_error_lstar:.2e} from the f64 \
                 product T L (more than f32 rounding explains, {LOSSLESS_CLAIM_TOLERANCE:.0e}); reported as lossy"
            );
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

    /// Shade `lstar` (gathered in `gather_ms`), compare it with the baseline and the reference
    /// and write its images as `images/<name>.*`: a record whose form fields (kind, params,
    /// storage, flops, build, stats, GPU) are empty for the caller to fill in ([`Self::record`]
    /// for a compressed form, `crate::interop::eval` for an external `L*`).
    pub(crate) fn score(
        &self,
        name: &str,
        lstar: &LocalRadiance,
        gather_ms: f64,
    ) -> Result<(CompressorRecord, Render)> {
        let (view, repeats) = (self.view, self.repeats);
        let rel_error_lstar = relative_l2_error(lstar.values(), self.exact);
        let (render, shade_ms) = view.timed_render(lstar, repeats)?;
        let vs_uncompressed =
            errors(&compare_exposed(&render.image, &self.baseline.image, Some(&self.baseline.mask), self.exposure)?);
        let vs_reference = match self.reference {
            Some(r) => {
                let small = view.render(lstar, &r.camera)?;
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
            gather_ms,
            shade_ms,
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

/// The largest finite per-pixel error `luminance(|a - b|)`.
fn largest_error(a: &HdrImage, b: &HdrImage) -> f32 {
    (a.pixels.iter().zip(&b.pixels))
        .map(|(p, q)| biscale_core::scene::image::luminance(std::array::from_fn(|c| (p[c] - q[c]).abs())))
        .filter(|e| e.is_finite())
        .fold(0.0f32, f32::max)
}

/// The scale an error figure of `|a - b|` would have on its own (its 99th percentile,
/// [`biscale_shading::image::error_image`]) and the largest error, without drawing it.
fn error_extent(a: &HdrImage, b: &HdrImage) -> Result<(f32, f32)> {
    let (_, scale) = biscale_shading::image::error_image(a, b, None)?;
    Ok((scale, largest_error(a, b)))
}

/// The false-colour `|a - b|` of [`biscale_shading::image::error_image`] at `scale` (its own
/// 99th percentile when `None`) with a colour bar below that says what it measures (`b` is
/// the image named `against`) and the largest error, written as a PNG: the scale used and
/// the largest per-pixel error.
pub(crate) fn write_error_figure(
    a: &HdrImage,
    b: &HdrImage,
    against: &str,
    scale: Option<f32>,
    path: &Path,
) -> Result<(f32, f32)> {
    let (picture, scale) = biscale_shading::image::error_image(a, b, scale)?;
    // A picture narrower than the colour bar is magnified (nearest) to fill it.
    let picture = crate::inset::magnify(&picture, crate::inset::thumbnail_factor(picture.width()));
    let max = largest_error(a, b);
    let label = format!(
        "luminance of |error| vs {against} (linear radiance)\nlargest {}",
        crate::plots::tick_label(max as f64)
    );
    let figure = crate::plots::with_colour_bar(&picture, scale, &label)
        .map_err(|what| PipelineError::Mismatch { path: path.to_path_buf(), what: format!("colour bar: {what}") })?;
    biscale_core::scene::image::write_rgb8_png(&figure, path)?;
    Ok((scale, max))
}

/// A setting's error figure against the reference, relative to the output folder.
pub(crate) fn reference_error_png(name: &str) -> String {
    format!("images/{}_error_reference.png", name.replace(':', "-"))
}

/// The region of the report's insets, once per run, and where it comes from: `[report]
/// inset`, else the default window ([`crate::inset::default_side`]) with the largest error of
/// the worst lossy setting (largest RMSE) against the uncompressed render as the PNGs show it
/// ([`crate::inset::error_map`]), else of the worst setting, else the window with the most of
/// the mesh.
fn inset_region(
    exp: &Experiment,
    records: &[CompressorRecord],
    renders: &[Render],
    base: &Baseline,
) -> (crate::inset::Region, String) {
    use crate::inset::{self, Region};
    let (width, height) = (base.render.image.width, base.render.image.height);
    match &exp.file.report.inset {
        Some(r) => {
            let [x, y, w, h] = *r.get_ref();
            (Region { x, y, width: w, height: h }, "`[report] inset`".to_string())
        }
        None => {
            let side = inset::default_side(width, height);
            let worst = |lossy: bool| {
                (records.iter().zip(renders))
                    .filter(|(r, _)| !lossy || !r.lossless)
                    .max_by(|a, b| a.0.image.vs_uncompressed.rmse.total_cmp(&b.0.image.vs_uncompressed.rmse))
            };
            let errors = worst(true)
                .or_else(|| worst(false))
                .map(|(r, render)| {
                    (r.name.clone(), inset::error_map(&render.image, &base.render.image, exp.file.report.exposure))
                })
                .filter(|(_, e)| e.iter().any(|&v| v > 0.0));
            let (values, from) = match errors {
                Some((name, e)) => {
                    (e, format!("the {side}x{side} window where {name} differs most from the uncompressed render"))
                }
                None => (
                    base.render.mask.iter().map(|&hit| hit as u8 as f32).collect(),
                    format!("the {side}x{side} window with the most of the mesh"),
                ),
            };
            let (x, y) = inset::largest_sum_window(&values, width, height, side, side);
            (Region { x, y, width: side, height: side }, from)
        }
    }
}

/// The report's comparison figures ([`ComparisonFigures`]) at the inset `region`
/// ([`inset_region`]): per row (uncompressed, each compressor and method setting, the ground
/// truth) its thumbnail with the region marked and its inset, from the PNGs written, and its
/// error figure against the ground truth (the uncompressed render's is drawn here).
#[allow(clippy::too_many_arguments)]
fn comparison_figures(
    (region, from): (crate::inset::Region, String),
    records: &[CompressorRecord],
    methods: &[MethodRecord],
    base: &Baseline,
    view: &View<'_>,
    reference: Option<&Reference>,
    out_dir: &Path,
) -> Result<ComparisonFigures> {
    use crate::inset;
    let width = base.render.image.width;
    let mismatch = |what: String| PipelineError::Mismatch { path: out_dir.to_path_buf(), what };
    let row = |name: &str, png: &str, error_vs_reference_png: Option<String>| -> Result<FigureRow> {
        let (thumbnail, zoom) = inset::write_row(out_dir, png, name, &region, width).map_err(mismatch)?;
        Ok(FigureRow { name: name.to_string(), thumbnail, inset: zoom, error_vs_reference_png })
    };
    // Every error figure against the reference at one scale: the largest of their own 99th
    // percentiles (the uncompressed render's included), so each fits and they compare.
    let mut against_reference: Vec<String> = vec![];
    let mut reference_error_scale = None;
    if let Some(r) = reference {
        let mut scored = std::mem::take(&mut *r.scored.lock().unwrap_or_else(|p| p.into_inner()));
        scored.insert(0, ("uncompressed".into(), view.render(&base.lstar, &r.camera)?.image));
        let mut scale = 0.0f32;
        for (_, small) in &scored {
            scale = scale.max(error_extent(small, &r.render.image)?.0);
        }
        for (name, small) in &scored {
            let png = reference_error_png(name);
            write_error_figure(small, &r.render.image, "ground truth", Some(scale), &out_dir.join(&png))?;
            against_reference.push(name.clone());
        }
        reference_error_scale = Some(scale);
    }
    let error = |name: &str| against_reference.iter().any(|n| n == name).then(|| reference_error_png(name));
    let mut rows = vec![row("uncompressed", "images/uncompressed.png", error("uncompressed"))?];
    if base.paper.is_some() {
        rows.push(row("uncompressed_paper", "images/uncompressed_paper.png", None)?);
    }
    for r in records.iter().chain(methods.iter().map(|m| &m.record)) {
        rows.push(row(&r.name, &r.image.png, error(&r.name))?);
    }
    if reference.is_some() {
        rows.push(row("reference", "images/reference.png", None)?);
    }
    Ok(ComparisonFigures {
        inset: [region.x, region.y, region.width, region.height],
        inset_from: from,
        inset_magnification: inset::magnification(&region),
        reference_error_scale,
        rows,
    })
}

/// One error scale for every compressor of the run, so their error figures compare at a
/// glance: `[report] error_scale` when set, else the largest of the lossy settings' own 99th
/// percentiles (every lossy figure then fits; a lossless one, far below, shows dark), else of
/// all. Each figure is drawn here, once, at that scale.
fn share_error_scale(
    records: &mut [CompressorRecord],
    renders: &[Render],
    baseline: &Render,
    fixed: Option<f32>,
    out_dir: &Path,
) -> Result<()> {
    let own = |lossy: bool| {
        records.iter().filter(|r| lossy <= !r.lossless).filter_map(|r| r.image.error_scale).fold(0.0f32, f32::max)
    };
    let shared = fixed.unwrap_or_else(|| match own(true) {
        s if s > 0.0 => s,
        _ => own(false),
    });
    for (r, render) in records.iter_mut().zip(renders) {
        if let Some(png) = &r.image.error_png {
            let (scale, _) =
                write_error_figure(&render.image, &baseline.image, "uncompressed", Some(shared), &out_dir.join(png))?;
            r.image.error_scale = Some(scale);
        }
    }
    Ok(())
}

/// The compressor of one setting (a plugin loads its library here).
pub fn build_compressor(setting: &CompressorSetting) -> Result<Box<dyn Compressor>> {
    registry::build(&setting.kind, &setting.params)
        .map_err(|source| PipelineError::Build { name: setting.label.clone(), source })
}

/// What a sharded precompute hands the pipeline (`crate::shard::merge`): `T` stacked from the
/// shards, the merged forms of the separable compressors by label, and the shards' record.
pub struct Precomputed {
    pub matrix: TransferMatrix,
    /// Rays and seconds summed over the shards.
    pub rays_traced: u64,
    pub transfer_seconds: f64,
    pub forms: std::collections::BTreeMap<String, CompressedForm>,
    pub sharded: ShardedMetrics,
}

/// `T` from a sharded precompute, checked against the geometry and put in the cache as a
/// single build would have (so a later `biscale run` of the config finds it).
fn precomputed_transfer(
    matrix: TransferMatrix,
    rays: u64,
    seconds: f64,
    exp: &Experiment,
    geometry: &Geometry,
    cache: Option<&StageCache>,
) -> Result<Transfer> {
    let settings = exp.transfer_settings();
    let shape = settings.shape(geometry.mesh.vertex_count());
    if matrix.shape() != shape {
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!("the shards' T is {}, this config's mesh and settings need {shape}", matrix.shape()),
        });
    }
    let key = crate::cache::transfer_key(&geometry.mesh, &settings);
    if let Some(c) = cache {
        c.put_with(&c.transfer_path(&key), &key, || matrix.to_artifact());
    }
    let metrics = transfer_metrics(&matrix, seconds, rays, rays as f64 / seconds.max(1e-12), false, &settings);
    crate::note!("transfer: {} x {} from the shards, {} non-zeros", matrix.rows(), matrix.cols(), matrix.nnz());
    Ok(Transfer { matrix, metrics, key })
}

/// Run the whole experiment; returns the metrics that were written.
pub fn run(exp: &Experiment, opts: &RunOptions) -> Result<(PathBuf, Metrics)> {
    run_with(exp, opts, None)
}

/// [`run`], with `T` and the separable forms taken from a sharded precompute when given.
pub fn run_with(exp: &Experiment, opts: &RunOptions, pre: Option<Precomputed>) -> Result<(PathBuf, Metrics)> {
    // The text as it runs (with any `--set` applied), not the file's.
    let mut clock = crate::provenance::StageClock::start(&exp.source, exp.file.seed);
    let plan = Plan::new(exp);
    eprint!("{plan}");
    if exp.file.runtime.backend == Backend::Gpu && !cfg!(feature = "gpu") {
        return Err(no_gpu_feature());
    }

    let target = opts.out_dir.clone().unwrap_or_else(|| Path::new("out").join(exp.name()));
    let cache = StageCache::new(opts, &target);
    if let Some(c) = &cache {
        let inside = |d: &Path| std::path::absolute(d).unwrap_or_else(|_| d.to_path_buf());
        if inside(c.dir()).starts_with(inside(&target)) {
            return Err(PipelineError::Mismatch {
                path: c.dir().to_path_buf(),
                what: format!(
                    "the cache folder lies inside the output folder {}, which each run replaces whole; put it elsewhere",
                    target.display()
                ),
            });
        }
    }
    // Everything is written into a staging folder that replaces the output folder whole
    // when the run is complete (crate::staging).
    let staged = StagedDir::begin(&target, &format!("biscale run {}", exp.config_path.display()))?;
    let out_dir = staged.path().to_path_buf();
    let images_dir = out_dir.join("images");
    std::fs::create_dir_all(&images_dir).map_err(io_err(&images_dir))?;
    write_atomic_bytes(&out_dir.join("plan.txt"), plan.to_string().as_bytes())?;

    // Compressors are constructed first so a bad setting fails before any heavy work.
    let compressors: Vec<(CompressorSetting, Box<dyn Compressor>)> =
        plan.compressors.iter().map(|s| build_compressor(s).map(|c| (s.clone(), c))).collect::<Result<_>>()?;

    clock.mark("setup");
    let geometry = load_geometry(exp)?;
    clock.mark("geometry");
    for r in &geometry.repairs {
        eprintln!("warning: {}: {r}", exp.mesh_path.display());
    }
    let lighting = load_lighting(exp)?;
    for w in &lighting.warnings {
        eprintln!("warning: {w}");
    }
    clock.mark("lighting");
    let (memory, available) = crate::memory::check_run(exp, &geometry, &lighting, cache.is_some())?;
    clock.mark("memory estimate");
    let (t, mut pre_forms, sharded) = match pre {
        Some(p) => {
            let t = precomputed_transfer(p.matrix, p.rays_traced, p.transfer_seconds, exp, &geometry, cache.as_ref())?;
            (t, p.forms, Some(p.sharded))
        }
        None => (transfer_matrix(exp, &geometry, cache.as_ref())?, Default::default(), None),
    };
    clock.mark(if sharded.is_some() { "transfer (stacked from the shards)" } else { "transfer" });
    fault_point("transfer");
    if let Some(w) = sky_warning(&t.metrics, t.matrix.vertices()) {
        eprintln!("warning: {w}");
    }
    let (scene, mut materials) = shade_scene(exp, &geometry, &t.matrix, cache.as_ref())?;
    for n in &materials.notes {
        crate::note!("materials: {n}");
    }
    clock.mark("materials");
    let repeats = exp.file.runtime.repeats;
    let view = View { scene: &scene, camera: geometry.camera(exp, 1), background: lighting.background(exp) };
    let Targets { moments, base, reference } =
        targets(exp, &geometry, &lighting, &t.matrix, &view, &images_dir, plan.reference, &mut clock)?;
    let frames = geometry.transfer.frames();
    let exposure = exp.file.report.exposure;

    let study = crate::btf_study::StudyInputs {
        view: &view,
        lstar: &base.lstar,
        reference: reference.as_ref(),
        repeats,
        exposure,
        out_dir: &out_dir,
    };
    materials.btfs = crate::btf_study::run(&materials, &study)?;
    clock.mark("btf study");

    let mut gpu = match exp.file.runtime.backend {
        Backend::Gpu => Some(GpuBackend::new(&scene, &view.camera)?),
        Backend::Cpu => None,
    };
    if gpu.is_some() {
        clock.mark("gpu setup");
    }
    let eval = Evaluation {
        t: &t.matrix,
        light: &lighting.light,
        moments: moments.as_ref().map(|m| (m, frames)),
        exact: &base.exact,
        baseline: &base.render,
        view: &view,
        reference: reference.as_ref(),
        repeats,
        exposure,
        out_dir: &out_dir,
        shared_error_scale: true,
    };
    let (mut records, mut renders) = (vec![], vec![]);
    for (setting, compressor) in &compressors {
        let (form, cached) = match pre_forms.remove(&setting.label) {
            Some(form) => {
                if let Some((c, key)) =
                    cache.as_ref().zip(crate::cache::form_key(&t.key, compressor.as_ref(), exp.file.seed))
                {
                    c.put(&c.form_path(&key, &setting.label), &key, &form.to_artifact());
                }
                (form, false)
            }
            None => compressed_form(setting, compressor.as_ref(), &t.matrix, &t.key, exp.file.seed, cache.as_ref())?,
        };
        let (record, render) = eval.record(setting, compressor.as_ref(), &form, cached, gpu.as_mut())?;
        records.push(record);
        renders.push(render);
        clock.mark(format!("compressor {}", setting.label));
        fault_point("compression");
    }
    share_error_scale(&mut records, &renders, &base.render, exp.file.report.error_scale, &out_dir)?;
    let region = inset_region(exp, &records, &renders, &base);
    drop(renders);
    let inputs = crate::methods::sh::MethodInputs {
        exp,
        geometry: &geometry,
        lighting: &lighting,
        t: &t,
        scene: &scene,
        baseline: &base.render,
        view: &view,
        reference: reference.as_ref(),
        cache: cache.as_ref(),
        repeats,
        exposure,
        out_dir: &out_dir,
    };
    let methods = exp
        .method_settings()
        .iter()
        .map(|m| crate::methods::evaluate(m, &inputs, gpu.as_ref()))
        .collect::<Result<Vec<_>>>()?;
    if !methods.is_empty() {
        clock.mark("methods");
    }

    let figures = comparison_figures(region, &records, &methods, &base, &view, reference.as_ref(), &out_dir)?;
    let mut metrics =
        metrics_of_run(exp, &geometry, &lighting, &materials, t.metrics, &base, reference.as_ref(), records, methods);
    metrics.figures = Some(figures);
    metrics.memory = Some(memory.metrics(&available));
    metrics.sharded = sharded;
    metrics.run = Some(clock.finish());
    write_report(&metrics, &plan, &out_dir)?;
    fault_point("report");
    let out_dir = staged.commit()?;
    crate::note!("wrote {}", out_dir.display());
    Ok((out_dir, metrics))
}

/// The run's record from its stages' records.
#[allow(clippy::too_many_arguments)]
pub(crate) fn metrics_of_run(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    materials: &SceneMaterials,
    transfer: TransferMetrics,
    base: &Baseline,
    reference: Option<&Reference>,
    compressors: Vec<CompressorRecord>,
    methods: Vec<MethodRecord>,
) -> Metrics {
    Metrics {
        schema_version: crate::provenance::SCHEMA_VERSION,
        experiment: exp.name().to_string(),
        config: exp.config_path.display().to_string(),
        backend: format!("{:?}", exp.file.runtime.backend).to_lowercase(),
        scene: SceneMetrics {
            mesh: exp.mesh_path.display().to_string(),
            vertices: geometry.mesh.vertex_count(),
            triangles: geometry.mesh.triangle_count(),
            repairs: geometry.repairs.clone(),
            material: materials.summary(),
            material_notes: materials.notes.clone(),
            btf_bytes: materials.btfs.iter().filter(|b| b.primary).map(|b| b.dense_bytes).sum(),
            btfs: materials.btfs.clone(),
        },
        lighting: LightingMetrics {
            source: exp.env_path.as_ref().map_or("constant".into(), |p| p.display().to_string()),
            cubemap_resolution: exp.transfer_settings().cubemap().resolution,
            rotation_degrees: exp.file.lighting.rotation_degrees,
            total_power: lighting.light.total(),
            warnings: lighting.warnings.clone(),
        },
        transfer,
        uncompressed: UncompressedMetrics {
            gather_ms: base.gather_ms,
            shade_ms: base.shade_ms,
            light_moments: exp.file.runtime.light_moments,
            // Same camera, same size: compare cannot fail here.
            paper_vs_moments: base.paper.as_ref().and_then(|(_, paper)| {
                let exposure = exp.file.report.exposure;
                compare_exposed(&paper.image, &base.render.image, Some(&base.render.mask), exposure)
                    .ok()
                    .map(|m| errors(&m))
            }),
        },
        reference: reference.map(|r| ReferenceMetrics {
            kind: "ground truth (direct light)".into(),
            width: r.render.image.width,
            height: r.render.image.height,
            seconds: r.seconds,
            uncompressed_vs_reference: errors(&r.baseline_error),
            uncompressed_paper_vs_reference: r.paper_baseline_error.as_ref().map(errors),
        }),
        compressors,
        methods,
        target_error: exp.file.report.target_error,
        memory: None,
        sharded: None,
        run: None,
        figures: None,
    }
}

/// `metrics.json`, `metrics.csv`, then the plots, `report.html` and `report.md`
/// ([`crate::report::write_documents`], which `biscale report` calls alone).
fn write_report(metrics: &Metrics, plan: &Plan, out_dir: &Path) -> Result<()> {
    let json = serde_json::to_string_pretty(metrics).expect("metrics serialize");
    write_atomic_bytes(&out_dir.join("metrics.json"), json.as_bytes())?;
    write_atomic_bytes(&out_dir.join("metrics.csv"), metrics.to_csv().as_bytes())?;
    fault_point("metrics");
    crate::report::write_documents(metrics, &plan.to_string(), out_dir)?;
    Ok(())
}

/// Write `<name>.png` and `<name>.exr`; returns their paths relative to the output folder.
pub(crate) fn save_images(img: &HdrImage, dir: &Path, name: &str, exposure: f32) -> Result<(String, String)> {
    let png = dir.join(format!("{name}.png"));
    let exr = dir.join(format!("{name}.exr"));
    img.write_png(&png, exposure)?;
    img.write_exr(&exr)?;
    Ok((format!("images/{name}.png"), format!("images/{name}.exr")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use biscale_core::geometry::shapes::uv_sphere;

    fn transfer_of(mesh: &biscale_core::geometry::Mesh) -> TransferMetrics {
        let settings = TransferSettings::new(8, 16, 4).unwrap();
        let t = transfer::build(mesh, &settings, None).unwrap().matrix;
        transfer_metrics(&t, 0.0, 0, 0.0, false, &settings)
    }

    #[test]
    fn an_inside_out_mesh_is_warned_about() {
        // Regression (hostile input): a closed sphere with every face flipped traced T with
        // no non-zeros and rendered black with exit 0 and no word.
        let sphere = uv_sphere(glam::Vec3::ZERO, 1.0, 8, 12);
        let vertices = sphere.vertex_count();
        let ok = transfer_of(&sphere);
        assert_eq!(ok.vertices_without_sky, 0);
        assert!(sky_warning(&ok, vertices).is_none());
        let mut flipped = sphere.clone();
        for t in &mut flipped.triangles {
            t.swap(1, 2);
        }
        let bad = transfer_of(&flipped);
        assert_eq!((bad.nnz, bad.vertices_without_sky), (0, vertices));
        let w = sky_warning(&bad, vertices).expect("a warning");
        assert!(w.starts_with("100% of the vertices") && w.contains("inside out"), "{w}");
    }
}
