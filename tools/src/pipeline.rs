//! The pipeline: wires the stages from an [`Experiment`] and writes the run's output folder
//! (`plan.txt`, `metrics.json`, `report.md`, `images/`). Stages exchange plain data only.

use crate::config::{Backend, Experiment};
use crate::materials::{load_materials, SceneMaterials};
use crate::metrics::*;
use crate::plan::{CompressorSetting, Plan};
use crate::registry;
use crate::util::{progress_bar, write_atomic};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error, LocalRadiance};
use biscale_core::geometry::{vertex_frames, Mesh, SceneBvh, VertexFrame};
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::transfer::{self, TransferMatrix, VisibilitySampler};
use biscale_shading::camera::Camera;
use biscale_shading::cpu::{shade, Background, Render, ShadeScene};
use biscale_shading::error::ShadingError;
use biscale_shading::image::{compare, HdrImage, ImageMetrics};
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
    Compress { name: String, source: biscale_core::compress::CompressError },
    #[error(transparent)]
    Shading(#[from] ShadingError),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{0}")]
    Other(String),
}

pub type Result<T, E = PipelineError> = std::result::Result<T, E>;

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io { path: path.to_path_buf(), source }
}

/// Options of `biscale run`.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Output folder (default `out/<name>/`).
    pub out_dir: Option<PathBuf>,
    /// Cache folder for stage outputs (default `<out parent>/.cache`); `None` with
    /// `no_cache` disables caching.
    pub cache_dir: Option<PathBuf>,
    pub no_cache: bool,
}

/// The loaded scene: mesh, frames, BVH, materials.
pub struct Scene {
    pub mesh: Mesh,
    pub repairs: Vec<String>,
    pub frames: Vec<VertexFrame>,
    pub bvh: SceneBvh,
    pub materials: SceneMaterials,
}

impl Scene {
    /// The CPU shader's view of the scene.
    pub fn shade_scene<'a>(&'a self, background: Background<'a>) -> ShadeScene<'a> {
        ShadeScene {
            mesh: &self.mesh,
            frames: &self.frames,
            bvh: &self.bvh,
            materials: &self.materials.materials,
            triangle_materials: self.materials.triangle_materials.as_deref(),
            background,
        }
    }
}

/// The lighting: `L` and the map it came from (for backgrounds).
pub struct Lighting {
    pub light: LightVector,
    pub env: EnvMap,
    pub warnings: Vec<String>,
}

/// Load the mesh and build its frames, BVH and materials; synthesized BTFs are cached in
/// `cache_dir` when given.
pub fn load_scene(exp: &Experiment, cache_dir: Option<&Path>) -> Result<Scene> {
    let load = Mesh::load_obj(&exp.mesh_path)?;
    let (frames, fallbacks) = vertex_frames(&load.mesh);
    let mut repairs = load.repairs;
    if fallbacks > 0 {
        repairs.push(format!("{fallbacks} vertices had no usable normal (cancelling faces); used +Y"));
    }
    let bvh = SceneBvh::build(&load.mesh.positions, &load.mesh.triangles);
    let materials = load_materials(exp, &load.mesh, cache_dir)?;
    Ok(Scene { mesh: load.mesh, repairs, frames, bvh, materials })
}

pub fn load_lighting(exp: &Experiment) -> Result<Lighting> {
    let l = &exp.file.lighting;
    let r = *exp.file.transfer.cubemap_resolution.get_ref();
    let rotation = l.rotation_degrees.to_radians();
    let (env, mut warnings) = match (&exp.env_path, l.constant) {
        (Some(p), _) => EnvMap::load(p)?,
        (None, Some(c)) => (EnvMap::constant(64, 32, c), vec![]),
        (None, None) => unreachable!("validated by the config"),
    };
    let mut light = LightVector::from_env(&env, r, rotation);
    if let Some(boost) = &l.sun_boost {
        let lum = |p: &[f32; 3]| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
        if let Some(k) = (0..light.len()).max_by(|&a, &b| lum(&light.power[a]).total_cmp(&lum(&light.power[b]))) {
            light.power[k] = light.power[k].map(|v| v * boost.get_ref());
            warnings.push(format!("sun_boost: texel {k} multiplied by {}", boost.get_ref()));
        }
    }
    Ok(Lighting { light, env, warnings })
}

/// Build (or load from the cache) the transfer matrix with a progress bar.
pub fn transfer_matrix(
    exp: &Experiment,
    scene: &Scene,
    opts: &RunOptions,
    out_dir: &Path,
) -> Result<(TransferMatrix, TransferMetrics)> {
    let settings = exp.transfer_settings();
    let cache = crate::cache::TransferCache::new(opts, out_dir);
    let key = crate::cache::transfer_key(&scene.mesh, &settings);
    if let Some(cache) = &cache {
        match cache.load(key, &settings) {
            Ok(Some(t)) => {
                eprintln!("transfer: loaded from cache {}", cache.path(key).display());
                let metrics = transfer_metrics(&t, 0.0, 0, 0.0, true, &settings);
                return Ok((t, metrics));
            }
            Ok(None) => {}
            Err(e) => eprintln!("warning: ignoring unusable cache file: {e}"),
        }
    }
    let pb = progress_bar(scene.mesh.positions.len() as u64, "transfer");
    let tick = |done: usize| pb.set_position(done as u64);
    let build = transfer::build(&scene.mesh, &settings, Some(&tick))?;
    pb.finish_and_clear();
    eprintln!(
        "transfer: {} x {} with {} non-zeros in {:.2} s ({:.1} M rays/s)",
        build.matrix.rows(),
        build.matrix.cols(),
        build.matrix.nnz(),
        build.stats.seconds,
        build.stats.rays_per_second / 1e6
    );
    if let Some(cache) = &cache {
        if let Err(e) = cache.store(key, &build.matrix) {
            eprintln!("warning: could not write the transfer cache: {e}");
        }
    }
    let m = transfer_metrics(
        &build.matrix,
        build.stats.seconds,
        build.stats.rays_traced,
        build.stats.rays_per_second,
        false,
        &settings,
    );
    Ok((build.matrix, m))
}

fn transfer_metrics(
    t: &TransferMatrix,
    seconds: f64,
    rays: u64,
    rays_per_second: f64,
    cached: bool,
    settings: &transfer::TransferSettings,
) -> TransferMetrics {
    let mut hist = std::collections::BTreeMap::<u32, u64>::new();
    for v in t.csr.data() {
        *hist.entry(v.to_bits()).or_default() += 1;
    }
    let mut value_histogram: Vec<ValueCount> =
        hist.into_iter().map(|(b, count)| ValueCount { value: f32::from_bits(b), count }).collect();
    value_histogram.sort_by(|a, b| a.value.total_cmp(&b.value));
    TransferMetrics {
        rows: t.rows(),
        cols: t.cols(),
        nnz: t.nnz(),
        local_dirs: t.local_dirs,
        visibility_resolution: settings.visibility_resolution,
        value_histogram,
        build_seconds: seconds,
        rays_traced: rays,
        rays_per_second,
        cached,
    }
}

/// The camera of the experiment at `downscale`.
pub fn camera(exp: &Experiment, mesh: &Mesh, downscale: u32) -> Camera {
    let rt = &exp.file.runtime;
    let (w, h) = ((rt.width.get_ref() / downscale).max(1), (rt.height.get_ref() / downscale).max(1));
    let c = &rt.camera;
    let (min, max) = mesh.bounds();
    let mut cam = Camera::frame_bounds(min, max, w, h, c.azimuth_degrees, c.elevation_degrees, c.fov_y_degrees);
    if let Some(p) = c.position {
        cam.position = p.into();
    }
    if let Some(t) = c.target {
        cam.target = t.into();
    }
    cam
}

fn median_ms(samples: &mut [f64]) -> f64 {
    samples.sort_by(f64::total_cmp);
    samples[samples.len() / 2] * 1e3
}

fn errors(m: &ImageMetrics) -> ImageErrors {
    ImageErrors { rmse: m.rmse, psnr: m.psnr, rel_l2: m.rel_l2 }
}

/// Run the whole experiment; returns the metrics that were written.
pub fn run(exp: &Experiment, opts: &RunOptions) -> Result<(PathBuf, Metrics)> {
    let plan = Plan::new(exp);
    eprint!("{plan}");
    #[cfg(not(feature = "gpu"))]
    if exp.file.runtime.backend == Backend::Gpu {
        return Err(PipelineError::Other(
            "runtime.backend = \"gpu\" needs biscale built with the `gpu` cargo feature".into(),
        ));
    }
    let out_dir = opts.out_dir.clone().unwrap_or_else(|| Path::new("out").join(exp.name()));
    let images_dir = out_dir.join("images");
    std::fs::create_dir_all(&images_dir).map_err(io_err(&images_dir))?;
    write_atomic(&out_dir.join("plan.txt"), plan.to_string().as_bytes())?;

    // Compressors are constructed first so a bad setting fails before any heavy work.
    let compressors: Vec<(CompressorSetting, Box<dyn Compressor>)> =
        plan.compressors.iter().map(|s| registry::build(s).map(|c| (s.clone(), c))).collect::<Result<_>>()?;

    let scene = load_scene(exp, crate::cache::cache_dir(opts, &out_dir).as_deref())?;
    for r in &scene.repairs {
        eprintln!("warning: {}: {r}", exp.mesh_path.display());
    }
    for n in &scene.materials.notes {
        eprintln!("materials: {n}");
    }
    let lighting = load_lighting(exp)?;
    for w in &lighting.warnings {
        eprintln!("warning: {w}");
    }
    let (t, transfer_metrics) = transfer_matrix(exp, &scene, opts, &out_dir)?;
    let repeats = exp.file.runtime.repeats;

    // The uncompressed product, in f64: the reference for L* errors, and (cast to f32) the
    // image every compressor is compared with.
    let mut samples = vec![];
    let mut exact = vec![];
    for _ in 0..repeats {
        let start = Instant::now();
        exact = reference_product(&t, &lighting.light);
        samples.push(start.elapsed().as_secs_f64());
    }
    let uncompressed_gather_ms = median_ms(&mut samples);
    let exact_lstar = LocalRadiance {
        vertices: t.vertices,
        local_dirs: t.local_dirs,
        values: exact.iter().map(|v| [v[0] as f32, v[1] as f32, v[2] as f32]).collect(),
    };
    let background = if exp.file.report.background {
        Background::Env { env: &lighting.env, rotation: exp.file.lighting.rotation_degrees.to_radians() }
    } else {
        Background::Black
    };
    let shade_scene = scene.shade_scene(background);
    let cam = camera(exp, &scene.mesh, 1);
    let (base, uncompressed_shade_ms) = timed_shade(&shade_scene, &exact_lstar, &cam, repeats)?;
    let exposure = exp.file.report.exposure;
    save_images(&base.image, &images_dir, "uncompressed", exposure)?;

    // The reference (only when asked for), at the reference resolution.
    let ds = *exp.file.report.reference_downscale.get_ref();
    let reference = if plan.reference {
        let cam_ref = camera(exp, &scene.mesh, ds);
        let sampler = VisibilitySampler::new(&exp.transfer_settings())?;
        let pb = progress_bar(cam_ref.height as u64, "reference");
        let tick = |rows: usize| pb.set_position(rows as u64);
        let start = Instant::now();
        let r = biscale_shading::reference::render_reference(
            &shade_scene,
            &lighting.light,
            &sampler,
            &cam_ref,
            Some(&tick),
        )?;
        let seconds = start.elapsed().as_secs_f64();
        pb.finish_and_clear();
        save_images(&r.image, &images_dir, "reference", exposure)?;
        let base_small = shade(&shade_scene, &exact_lstar, &cam_ref)?;
        let m = compare(&base_small.image, &r.image, Some(&r.mask))?;
        eprintln!("reference: traced {}x{} in {seconds:.1} s", cam_ref.width, cam_ref.height);
        Some((r, cam_ref, seconds, m))
    } else {
        None
    };

    #[cfg(feature = "gpu")]
    let mut gpu = match exp.file.runtime.backend {
        Backend::Gpu => {
            let g = crate::gpu_backend::GpuBackend::new(&scene, &cam)?;
            eprintln!("gpu: {}", g.adapter);
            Some(g)
        }
        Backend::Cpu => None,
    };
    let mut records = vec![];
    for (setting, compressor) in &compressors {
        let name = &setting.label;
        let pb = progress_bar(1000, name);
        let progress = |f: f64| pb.set_position((f.clamp(0.0, 1.0) * 1000.0) as u64);
        let ctx = CompressContext { seed: exp.file.seed, progress: Some(&progress) };
        let cerr = |source| PipelineError::Compress { name: name.clone(), source };
        let form = compressor.compress(&t, &ctx).map_err(cerr)?;
        pb.finish_and_clear();
        let mut samples = vec![];
        let mut lstar = None;
        for _ in 0..repeats {
            let start = Instant::now();
            lstar = Some(compressor.gather(&form, &lighting.light).map_err(cerr)?);
            samples.push(start.elapsed().as_secs_f64());
        }
        let lstar = lstar.expect("repeats >= 1");
        let gather_ms = median_ms(&mut samples);
        let rel_error_lstar = relative_l2_error(&lstar.values, &exact);
        let (render, shade_ms) = timed_shade(&shade_scene, &lstar, &cam, repeats)?;
        let vs_uncompressed = errors(&compare(&render.image, &base.image, Some(&base.mask))?);
        let vs_reference = match &reference {
            Some((r, cam_ref, _, _)) => {
                let small = shade(&shade_scene, &lstar, cam_ref)?;
                Some(errors(&compare(&small.image, &r.image, Some(&r.mask))?))
            }
            None => None,
        };
        #[cfg(feature = "gpu")]
        let gpu_record = match gpu.as_mut() {
            Some(g) => {
                let kernels = registry::plugin_kernels(setting)?;
                Some(g.run(&form, &lighting.light, &exact, &render, repeats, kernels.as_ref())?)
            }
            None => None,
        };
        #[cfg(not(feature = "gpu"))]
        let gpu_record: Option<crate::metrics::GpuRecord> = None;
        if let Some(g) = &gpu_record {
            eprintln!(
                "{name} on the gpu: gather {:.2} ms, shade {:.2} ms ({}), rel. error of L* {:.2e}, image vs cpu rel. L2 {:.2e} ({} of {} pixels differ by > 1e-3)",
                g.gather_ms, g.shade_ms, g.timing, g.rel_error_lstar, g.image_vs_cpu.rel_l2, g.differing_pixels, g.covered_pixels
            );
        }
        let name = &name.replace(':', "-");
        let (png, exr) = save_images(&render.image, &images_dir, name, exposure)?;
        let error_rel = format!("images/{name}_error.png");
        let error_scale =
            biscale_shading::image::write_error_image(&render.image, &base.image, None, &out_dir.join(&error_rel))?;
        eprintln!(
            "{name}: {:.2} MB, {:.2} Mflop/gather, built in {:.2} s, gather {gather_ms:.2} ms, rel. error of L* {rel_error_lstar:.2e}",
            form.bytes() as f64 / 1e6,
            form.flops_per_gather as f64 / 1e6,
            form.build_seconds
        );
        records.push(CompressorRecord {
            name: name.clone(),
            kind: compressor.kind().to_string(),
            params: compressor.params(),
            lossless: form.lossless,
            bytes: form.bytes(),
            bytes_by_array: form.bytes_by_array(),
            bytes_per_nnz: form.bytes() as f64 / t.nnz().max(1) as f64,
            flops_per_gather: form.flops_per_gather,
            build_seconds: form.build_seconds,
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
            },
            stats: registry::stats(compressor.kind(), &form, &t),
            gpu: gpu_record,
        });
    }

    let metrics = Metrics {
        experiment: exp.name().to_string(),
        config: exp.config_path.display().to_string(),
        backend: format!("{:?}", exp.file.runtime.backend).to_lowercase(),
        scene: SceneMetrics {
            mesh: exp.mesh_path.display().to_string(),
            vertices: scene.mesh.positions.len(),
            triangles: scene.mesh.triangles.len(),
            repairs: scene.repairs.clone(),
            material: scene.materials.summary(),
            material_notes: scene.materials.notes.clone(),
        },
        lighting: LightingMetrics {
            source: exp.env_path.as_ref().map_or("constant".into(), |p| p.display().to_string()),
            cubemap_resolution: lighting.light.cubemap.resolution,
            rotation_degrees: exp.file.lighting.rotation_degrees,
            total_power: lighting.light.total(),
            warnings: lighting.warnings.clone(),
        },
        transfer: transfer_metrics,
        uncompressed: UncompressedMetrics { gather_ms: uncompressed_gather_ms, shade_ms: uncompressed_shade_ms },
        reference: reference.as_ref().map(|(r, _, seconds, m)| ReferenceMetrics {
            width: r.image.width,
            height: r.image.height,
            seconds: *seconds,
            uncompressed_vs_reference: errors(m),
        }),
        compressors: records,
        target_error: exp.file.report.target_error,
    };
    let json = serde_json::to_string_pretty(&metrics).expect("metrics serialize");
    let metrics_path = out_dir.join("metrics.json");
    write_atomic(&metrics_path, json.as_bytes())?;
    let plots = write_plots(&metrics, &out_dir);
    let html_path = out_dir.join("report.html");
    write_atomic(&html_path, crate::html::html(&metrics, &plan.to_string(), &out_dir, &plots).as_bytes())?;
    let report_path = out_dir.join("report.md");
    write_atomic(&report_path, crate::report::markdown(&metrics, &plan).as_bytes())?;
    eprintln!("wrote {}", out_dir.display());
    Ok((out_dir, metrics))
}

/// The comparison plots (only when there is something to compare); returns (path, caption).
fn write_plots(m: &Metrics, out_dir: &Path) -> Vec<(String, String)> {
    if m.compressors.len() < 2 {
        return vec![];
    }
    let mut out = vec![];
    let plots: [(&str, &str, &str, fn(&CompressorRecord) -> f64); 2] = [
        ("error_vs_time", "relative error of L* against gather time", "gather time (ms, CPU)", |r| r.gather_ms),
        ("error_vs_storage", "relative error of L* against storage", "storage (MB)", |r| r.bytes as f64 / 1e6),
    ];
    for (file, title, x_label, x) in plots {
        let series = crate::plots::series_by_kind(&m.compressors, x, |r| r.rel_error_lstar);
        let rel = format!("{file}.png");
        match crate::plots::log_log_plot(&out_dir.join(&rel), title, x_label, "relative L2 error of L*", &series) {
            Ok(()) => out.push((rel, title.to_string())),
            Err(e) => eprintln!("warning: plot {file}: {e}"),
        }
    }
    out
}

fn timed_shade(scene: &ShadeScene, lstar: &LocalRadiance, cam: &Camera, repeats: usize) -> Result<(Render, f64)> {
    let mut samples = vec![];
    let mut render = None;
    for _ in 0..repeats.min(3) {
        let start = Instant::now();
        render = Some(shade(scene, lstar, cam)?);
        samples.push(start.elapsed().as_secs_f64());
    }
    Ok((render.expect("at least one shade"), median_ms(&mut samples)))
}

/// Write `<name>.png` and `<name>.exr`; returns their paths relative to the output folder.
fn save_images(img: &HdrImage, dir: &Path, name: &str, exposure: f32) -> Result<(String, String)> {
    let png = dir.join(format!("{name}.png"));
    let exr = dir.join(format!("{name}.exr"));
    img.write_png(&png, exposure)?;
    img.write_exr(&exr)?;
    Ok((format!("images/{name}.png"), format!("images/{name}.exr")))
}
