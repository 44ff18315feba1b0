//! The script of a run: wires the stages from an [`Experiment`] and writes the run's output folder
//! (`plan.txt`, `metrics.json`, `report.md`, `report.html`, plots, `images/`).
//!
//! [`run`] reads as the data flow of the README: geometry, lighting, transfer, materials (on
//! `T`'s local basis), the uncompressed baseline, the reference, then every compressor
//! setting, then the report. Each step is a function in [`crate::stages`] that takes plain
//! data and returns a plain record; stages never reach into each other.

use crate::error::{io_err, PipelineError, Result};
use crate::experiment::config::{Backend, CompressorSetting, Experiment};
use crate::metrics::*;
use crate::plan::Plan;
use crate::provenance::StageClock;
use crate::stages::evaluate::{
    cpus_online, errors, load_average_1min, no_gpu_feature, targets, Evaluation, GpuBackend, Targets,
};
use crate::stages::figures::{comparison_figures, inset_region, share_error_scale};
use crate::stages::materials::SceneMaterials;
use crate::stages::scene::{load_geometry, load_lighting, shade_scene, Geometry, Lighting};
use crate::stages::transfer::{
    build_compressor, compressed_form, precomputed_transfer, sky_warning, transfer_matrix, Precomputed, Transfer,
    TransferRows,
};
use crate::stages::view::View;
use crate::store::cache::{form_key, StageCache};
use crate::store::staging::{fault_point, StagedDir};
use crate::store::RunOptions;
use biscale_core::compress::{CompressedForm, Compressor};
use biscale_core::io::write_atomic_bytes;
use biscale_core::scene::Render;
use biscale_shading::image::compare_exposed;
use std::path::{Path, PathBuf};

/// What `run`, `eval` and `shard merge` (through [`run_with`]) share around their stages: the
/// output folder being written (a staging folder that replaces the target whole on
/// [`RunContext::commit`], [`crate::store::staging`]), the stage cache, and the clock that
/// records each stage's time in `metrics.json`.
pub struct RunContext {
    pub clock: StageClock,
    pub cache: Option<StageCache>,
    staged: StagedDir,
}

impl RunContext {
    /// Begin writing `biscale <command> <inputs>`'s output: `--out`, else `default_target`.
    /// Refuses a cache folder inside the output folder (each command replaces it whole).
    pub fn begin(
        opts: &RunOptions,
        default_target: PathBuf,
        command: &str,
        inputs: &str,
        clock: StageClock,
    ) -> Result<Self> {
        let target = opts.out_dir.clone().unwrap_or(default_target);
        let cache = StageCache::new(opts, &target);
        if let Some(c) = &cache {
            let inside = |d: &Path| std::path::absolute(d).unwrap_or_else(|_| d.to_path_buf());
            if inside(c.dir()).starts_with(inside(&target)) {
                return Err(PipelineError::Mismatch {
                    path: c.dir().to_path_buf(),
                    what: format!(
                        "the cache folder lies inside the output folder {}, which each {command} replaces whole; put it elsewhere",
                        target.display()
                    ),
                });
            }
        }
        let staged = StagedDir::begin(&target, &format!("biscale {command} {inputs}"))?;
        let images = staged.path().join("images");
        std::fs::create_dir_all(&images).map_err(io_err(&images))?;
        Ok(Self { clock, cache, staged })
    }

    /// The folder being written (the staging folder until [`Self::commit`]).
    pub fn out_dir(&self) -> &Path {
        self.staged.path()
    }

    pub fn images_dir(&self) -> PathBuf {
        self.out_dir().join("images")
    }

    /// Swap the finished folder in; returns its final path.
    pub fn commit(self) -> Result<PathBuf> {
        let out_dir = self.staged.commit()?;
        log::info!("wrote {}", out_dir.display());
        Ok(out_dir)
    }
}

/// Run the whole experiment; returns the metrics that were written.
pub fn run(exp: &Experiment, opts: &RunOptions) -> Result<(PathBuf, Metrics)> {
    run_with(exp, opts, None)
}

/// [`run`], with `T` and the separable forms taken from a sharded precompute when given.
pub fn run_with(exp: &Experiment, opts: &RunOptions, pre: Option<Precomputed>) -> Result<(PathBuf, Metrics)> {
    let (mut ctx, plan) = begin(exp, opts, pre.as_ref())?;
    let out_dir = ctx.out_dir().to_path_buf();

    // Compressors are constructed first so a bad setting fails before any heavy work.
    let compressors: Vec<(CompressorSetting, Box<dyn Compressor>)> =
        plan.compressors.iter().map(|s| build_compressor(s).map(|c| (s.clone(), c))).collect::<Result<_>>()?;
    let animated_labels = animated_settings(exp, &plan)?;

    ctx.clock.mark("setup");
    let (geometry, lighting) = geometry_and_lighting(exp, &mut ctx.clock)?;
    let streamed = pre.as_ref().and_then(|p| p.streamed_part_vertices());
    let (memory, available) = crate::estimate::check_run(exp, &geometry, &lighting, ctx.cache.is_some(), streamed)?;
    ctx.clock.mark("memory estimate");
    // This machine's bandwidth and fp32 peak for the frame-time model's floors, measured
    // before T is built (its buffers then cost no more than T will) and before any timed step.
    let here = crate::stages::frame_model::probe();
    ctx.clock.mark("frame-time probe");
    let (t, pre_forms, sharded) = transfer_of(exp, &geometry, &mut ctx, pre)?;
    fault_point("transfer");
    crate::estimate::check_peak(&memory, &available, "the transfer stage")?;
    if let Some(w) = sky_warning(&t.metrics, t.view().vertices()) {
        crate::util::warn(w);
    }
    let (scene, mut materials) = materials_of(exp, &geometry, &t, &mut ctx)?;
    crate::estimate::check_peak(&memory, &available, "the materials")?;
    let analytic = materials.analytic.clone();
    let view = View::of(exp, &geometry, &lighting, &scene, &analytic);
    // The machine's load around the timed steps: from the uncompressed gather to the last method.
    let load_before = load_average_1min();
    let (images, cache) = (ctx.images_dir(), ctx.cache.as_ref());
    let targets = targets(exp, &geometry, &lighting, t.view(), &view, &images, plan.reference, cache, &mut ctx.clock)?;
    let (base, reference) = (&targets.base, targets.reference.as_ref());

    let study = crate::stages::btf_study::StudyInputs {
        view: &view,
        lstar: &base.lstar,
        reference,
        repeats: exp.file.runtime.repeats,
        exposure: targets.tone.exposure,
        out_dir: &out_dir,
    };
    materials.btfs = crate::stages::btf_study::run(&materials, &study)?;
    ctx.clock.mark("btf study");
    crate::estimate::check_peak(&memory, &available, "the BTF study")?;

    let mut gpu = match exp.file.runtime.backend {
        Backend::Gpu => Some(GpuBackend::new(&scene, &view.camera, view.analytic)?),
        Backend::Cpu => None,
    };
    if gpu.is_some() {
        ctx.clock.mark("gpu setup");
    }
    let eval = Evaluation::new(exp, t.view(), &lighting, &geometry, &targets, &view, &out_dir, true);
    let forms = Forms { exp, t: &t, cache: ctx.cache.as_ref(), precomputed: pre_forms };
    let (mut records, renders, kept) =
        forms.evaluate(&compressors, &eval, gpu.as_mut(), &mut ctx.clock, &animated_labels)?;
    crate::estimate::check_peak(&memory, &available, "the compressors")?;
    share_error_scale(records.iter_mut().collect(), &renders, &base.render, exp.file.report.error_scale, &out_dir)?;
    let region = inset_region(exp, &records, &renders, base, targets.tone.exposure);
    drop(renders);
    let inputs = crate::stages::sh::MethodInputs {
        exp,
        geometry: &geometry,
        lighting: &lighting,
        t: &t,
        scene: &scene,
        baseline: &base.render,
        view: &view,
        reference,
        cache: ctx.cache.as_ref(),
        repeats: exp.file.runtime.repeats,
        exposure: targets.tone.exposure,
        out_dir: &out_dir,
    };
    let mut animated: Vec<crate::stages::animation::Animated<'_>> = kept
        .into_iter()
        .map(|(i, form)| crate::stages::animation::Animated {
            name: compressors[i].0.label.clone(),
            source: crate::stages::animation::Source::Form { compressor: compressors[i].1.as_ref(), form },
        })
        .collect();
    let methods = evaluate_methods(exp, &inputs, gpu.as_ref(), &animated_labels, &mut animated)?;
    if !methods.is_empty() {
        ctx.clock.mark("methods");
    }
    let load_after = load_average_1min();
    crate::estimate::check_peak(&memory, &available, "the methods")?;
    let animations = animations_of(exp, &lighting, &t, &geometry, &view, targets.tone.exposure, &out_dir, &animated)?;
    if exp.file.runtime.animation.any() {
        ctx.clock.mark("animation");
    }
    drop(animated);

    let fixed = exp.file.report.reference_error_scale;
    let figures = comparison_figures(region, &records, &methods, base, &view, reference, fixed, &out_dir)?;
    let mut metrics = metrics_of_run(exp, &geometry, &lighting, &materials, t.metrics, &targets, records, methods);
    metrics.figures = Some(figures);
    metrics.animations = animations;
    metrics.memory = Some(memory.metrics(&available));
    // The merge's own time, up to its record (metrics.json is written next).
    metrics.sharded =
        sharded.map(|(s, started)| ShardedMetrics { merge_seconds: started.elapsed().as_secs_f64(), ..s });
    metrics.run = Some(ctx.clock.finish());
    metrics.load = load_record(load_before, load_after);
    metrics.frame_model = Some(crate::stages::frame_model::record(&metrics, view.analytic, &view.camera, here));
    if let Some(w) = crate::report::timing_warning(&metrics) {
        log::warn!("{w}");
    }
    write_report(&metrics, &plan, &out_dir)?;
    fault_point("report");
    Ok((ctx.commit()?, metrics))
}

/// Every method beside the all-frequency one (`[[methods]]`: SH orders) measured on the run's
/// inputs, each kept for the animation when it asks for one (into `animated`); their error
/// images share a colour scale of their own, as their errors against the uncompressed render
/// are of another size than the compressors'.
fn evaluate_methods(
    exp: &Experiment,
    inputs: &crate::stages::sh::MethodInputs<'_>,
    gpu: Option<&GpuBackend>,
    animated_labels: &[String],
    animated: &mut Vec<crate::stages::animation::Animated<'_>>,
) -> Result<Vec<MethodRecord>> {
    let (mut methods, mut renders) = (vec![], vec![]);
    for m in exp.method_settings() {
        let keep = animated_labels.contains(&m.label);
        let (record, render, a) = crate::stages::evaluate_method(m, inputs, gpu, keep)?;
        methods.push(record);
        renders.push(render);
        animated.extend(a);
    }
    share_error_scale(
        methods.iter_mut().map(|m| &mut m.record).collect(),
        &renders,
        inputs.baseline,
        None,
        inputs.out_dir,
    )?;
    Ok(methods)
}

/// The separable forms a sharded precompute built, by label.
type SeparableForms = std::collections::BTreeMap<String, CompressedForm>;

/// The shards' record and when their merge began.
type ShardRecord = (ShardedMetrics, std::time::Instant);

/// A run's start: its plan (saying where `T` comes from when a sharded precompute made it)
/// printed, the GPU backend refused when this build has none, the output folder staged and
/// `plan.txt` written into it.
fn begin(exp: &Experiment, opts: &RunOptions, pre: Option<&Precomputed>) -> Result<(RunContext, Plan)> {
    // The text as it runs (with any `--set` applied), not the file's.
    let clock = StageClock::start(&exp.source, exp.file.seed);
    let mut plan = Plan::new(exp);
    if let Some(p) = pre {
        // A merge traces nothing and caches no T: its plan says where T comes from.
        plan.transfer_from(format!(
            "T from {} shards' outputs ({}), traced by the shards, not cached",
            p.sharded.shards,
            match &p.rows {
                TransferRows::Whole(_) => "stacked into one matrix",
                TransferRows::Parts(_) => "streamed part by part, never whole",
            }
        ));
    }
    // Standard error from the CLI; a `biscale` logging record from Python, as every note is.
    crate::util::note(plan.to_string().trim_end());
    if exp.file.runtime.backend == Backend::Gpu && !cfg!(feature = "gpu") {
        return Err(no_gpu_feature());
    }
    let default_target = Path::new("out").join(exp.name());
    let ctx = RunContext::begin(opts, default_target, "run", &exp.config_path.display().to_string(), clock)?;
    write_atomic_bytes(&ctx.out_dir().join("plan.txt"), plan.to_string().as_bytes())?;
    Ok((ctx, plan))
}

/// The mesh and the light, each one's repairs and warnings said.
fn geometry_and_lighting(exp: &Experiment, clock: &mut StageClock) -> Result<(Geometry, Lighting)> {
    let geometry = load_geometry(exp)?;
    clock.mark("geometry");
    for r in &geometry.repairs {
        crate::util::warn(format_args!("{}: {r}", exp.mesh_path.display()));
    }
    let lighting = load_lighting(exp)?;
    for w in &lighting.warnings {
        crate::util::warn(w);
    }
    clock.mark("lighting");
    Ok((geometry, lighting))
}

/// `T`, traced (or from the cache), or stacked or streamed from a sharded precompute with the
/// forms the shards built and the record of the shards.
fn transfer_of(
    exp: &Experiment,
    geometry: &Geometry,
    ctx: &mut RunContext,
    pre: Option<Precomputed>,
) -> Result<(Transfer, SeparableForms, Option<ShardRecord>)> {
    let (t, pre_forms, sharded) = match pre {
        Some(p) => {
            let t = precomputed_transfer(p.rows, p.rays_traced, p.transfer_seconds, exp, geometry, ctx.cache.as_ref())?;
            (t, p.forms, Some((p.sharded, p.started)))
        }
        None => (transfer_matrix(exp, geometry, ctx.cache.as_ref())?, Default::default(), None),
    };
    ctx.clock.mark(match (&sharded, &t.rows) {
        (None, _) => "transfer",
        (Some(_), TransferRows::Whole(_)) => "transfer (stacked from the shards)",
        (Some(_), TransferRows::Parts(_)) => "transfer (streamed from the shards)",
    });
    Ok((t, pre_forms, sharded))
}

/// The scene to shade and its materials on `T`'s local basis, their notes said, and a warning
/// when the analytic resolve has no analytic material to shade.
fn materials_of(
    exp: &Experiment,
    geometry: &Geometry,
    t: &Transfer,
    ctx: &mut RunContext,
) -> Result<(biscale_core::scene::ShadeScene, SceneMaterials)> {
    let (scene, materials) = shade_scene(exp, geometry, t.view().local_basis(), ctx.cache.as_ref())?;
    for n in &materials.notes {
        log::info!("materials: {n}");
    }
    ctx.clock.mark("materials");
    if exp.file.runtime.resolve_analytic() && materials.analytic.iter().all(Option::is_none) {
        crate::util::warn(format!(
            "runtime.moments_resolve = \"pixel_analytic\": no material is a flat analytic BRDF ({}), so every \
             pixel is resolved from the BTF's tables, as with \"pixel\"",
            materials.reference_shading()
        ));
    }
    Ok((scene, materials))
}

/// The turning-light animation of the kept forms and methods (`[runtime.animation]`), or
/// nothing when none is asked for.
#[allow(clippy::too_many_arguments)]
fn animations_of(
    exp: &Experiment,
    lighting: &Lighting,
    t: &Transfer,
    geometry: &Geometry,
    view: &View<'_>,
    exposure: f32,
    out_dir: &Path,
    animated: &[crate::stages::animation::Animated<'_>],
) -> Result<Vec<AnimationRecord>> {
    if !exp.file.runtime.animation.any() {
        return Ok(vec![]);
    }
    let inputs = crate::stages::animation::Inputs {
        exp,
        lighting,
        t: t.whole("[runtime.animation]")?,
        frames: geometry.transfer.frames(),
        view,
        exposure,
        out_dir,
    };
    crate::stages::animation::animate(&inputs, animated)
}

/// `metrics.json`'s `load`: the 1-minute load before and after the timed steps, with the CPUs.
fn load_record(load_before: Option<f64>, load_after: Option<f64>) -> Option<LoadRecord> {
    (load_before.is_some() || load_after.is_some()).then(|| LoadRecord {
        load_before,
        load_after,
        cpus_online: cpus_online(),
    })
}

/// Each compressor setting's form of `T` (from the shards when a sharded precompute made it,
/// else from the cache or built) measured by the run's [`Evaluation`].
struct Forms<'a> {
    exp: &'a Experiment,
    t: &'a Transfer,
    cache: Option<&'a StageCache>,
    precomputed: std::collections::BTreeMap<String, CompressedForm>,
}

/// The labels `[runtime.animation]` animates (every compressor setting when it names none;
/// none without an animation), each checked against the plan's settings before any work.
fn animated_settings(exp: &Experiment, plan: &Plan) -> Result<Vec<String>> {
    let a = &exp.file.runtime.animation;
    if !a.any() {
        return Ok(vec![]);
    }
    let mut known: Vec<String> = plan.compressors.iter().map(|s| s.label.clone()).collect();
    known.extend(exp.method_settings().iter().map(|m| m.label.clone()));
    if a.settings.is_empty() {
        return Ok(plan.compressors.iter().map(|s| s.label.clone()).collect());
    }
    for name in &a.settings {
        if !known.contains(name) {
            return Err(PipelineError::Mismatch {
                path: exp.config_path.clone(),
                what: format!(
                    "runtime.animation.settings names `{name}`, which is no compressor or method setting of this \
                     run; the settings are {}",
                    known.join(", ")
                ),
            });
        }
    }
    Ok(a.settings.clone())
}

impl Forms<'_> {
    /// Every setting's record and image, and the forms of the settings in `keep` (by their
    /// index in `compressors`), which the animation renders again.
    #[allow(clippy::type_complexity)]
    fn evaluate(
        mut self,
        compressors: &[(CompressorSetting, Box<dyn Compressor>)],
        eval: &Evaluation<'_>,
        mut gpu: Option<&mut GpuBackend>,
        clock: &mut StageClock,
        keep: &[String],
    ) -> Result<(Vec<CompressorRecord>, Vec<Render>, Vec<(usize, CompressedForm)>)> {
        let (exp, t, cache) = (self.exp, self.t, self.cache);
        let (mut records, mut renders, mut kept) = (vec![], vec![], vec![]);
        // One sweep per kind: its settings share what the kind keeps between them (the
        // bicluster greedy's output, pruned by every error budget); it goes after the kind's last
        // setting.
        let mut sweeps: std::collections::HashMap<&str, biscale_core::compress::Sweep> = Default::default();
        for (i, (setting, compressor)) in compressors.iter().enumerate() {
            let kind = setting.kind.as_str();
            let last_of_kind = compressors.iter().rposition(|(s, _)| s.kind == kind) == Some(i);
            let (form, cached) = match self.precomputed.remove(&setting.label) {
                Some(form) => {
                    if let Some((c, key)) = cache.zip(form_key(&t.key, compressor.as_ref(), exp.file.seed)) {
                        c.put(&c.form_path(&key, &setting.label), &key, &form.to_artifact());
                    }
                    (form, false)
                }
                None => {
                    let whole = t.whole(&format!("the compressor {}", setting.label))?;
                    let sweep = sweeps.entry(kind).or_default();
                    compressed_form(setting, compressor.as_ref(), whole, &t.key, (exp.file.seed, Some(sweep)), cache)?
                }
            };
            let (record, render) = eval.record(setting, compressor.as_ref(), &form, cached, gpu.as_deref_mut())?;
            records.push(record);
            renders.push(render);
            if keep.contains(&setting.label) {
                kept.push((i, form));
            }
            if last_of_kind {
                sweeps.remove(kind);
            }
            clock.mark(format!("compressor {}", setting.label));
            fault_point("compression");
        }
        Ok((records, renders, kept))
    }
}

/// The run's record from its stages' records.
#[allow(clippy::too_many_arguments)]
pub(crate) fn metrics_of_run(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    materials: &SceneMaterials,
    transfer: TransferMetrics,
    targets: &Targets,
    compressors: Vec<CompressorRecord>,
    methods: Vec<MethodRecord>,
) -> Metrics {
    let (base, reference, tone) = (&targets.base, targets.reference.as_ref(), &targets.tone);
    Metrics {
        schema_version: crate::provenance::SCHEMA_VERSION,
        experiment: exp.name().to_string(),
        config: exp.config_path.display().to_string(),
        backend: exp.file.runtime.backend,
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
            // What the light really carries: a constant or cube-map light has no means.
            texel_directions: exp.file.runtime.light_moments.then(|| match lighting.light.has_mean_directions() {
                true => biscale_core::sampling::TexelDirections::Mean,
                false => biscale_core::sampling::TexelDirections::Centre,
            }),
        },
        transfer,
        uncompressed: UncompressedMetrics {
            gather_ms: base.gather_timing.median_ms,
            shade_ms: base.shade_timing.median_ms,
            gather_timing: Some(base.gather_timing),
            shade_timing: Some(base.shade_timing),
            light_moments: exp.file.runtime.light_moments,
            moments_resolve: exp.file.runtime.moments_resolve(),
            // Same camera, same size: compare cannot fail here.
            paper_vs_moments: base.paper.as_ref().and_then(|(_, paper)| {
                let exposure = tone.exposure;
                compare_exposed(&paper.image, &base.render.image, Some(&base.render.mask), exposure)
                    .ok()
                    .map(|m| errors(&m))
            }),
        },
        reference: reference.map(|r| ReferenceMetrics {
            kind: "ground truth (direct light)".into(),
            shading: materials.reference_shading(),
            width: r.render.image.width,
            height: r.render.image.height,
            seconds: r.seconds,
            cached: r.cached,
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
        load: None,
        animations: vec![],
        tone_map: Some(tone.clone()),
        frame_model: None,
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
