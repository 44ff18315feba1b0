//! The script of a run: wires the stages from an [`Experiment`] and writes the run's output folder
//! (`plan.txt`, `metrics.json`, `report.md`, `report.html`, plots, `images/`).
//!
//! [`run`] reads as the data flow of the README: geometry, lighting, transfer, materials (on
//! `T`'s local basis), the uncompressed baseline, the reference, then every compressor
//! setting, then the report. Each step is a function in [`crate::stages`] that takes plain
//! data and returns a plain record; stages never reach into each other.

use crate::error::{io_err, PipelineError, Result};
use crate::experiment::config::{Backend, CompressorSetting, Experiment};
use crate::experiment::plan::Plan;
use crate::metrics::*;
use crate::stages::evaluate::{
    errors, no_gpu_feature, targets, Baseline, Evaluation, GpuBackend, Reference, Targets, View,
};
use crate::stages::figures::{comparison_figures, inset_region, share_error_scale};
use crate::stages::materials::SceneMaterials;
use crate::stages::scene::{load_geometry, load_lighting, shade_scene, Geometry, Lighting};
use crate::stages::transfer::{
    build_compressor, compressed_form, precomputed_transfer, sky_warning, transfer_matrix, Precomputed,
};
use crate::store::cache::StageCache;
use crate::store::staging::{fault_point, StagedDir};
use crate::store::RunOptions;
use biscale_core::compress::Compressor;
use biscale_core::io::write_atomic_bytes;
use biscale_shading::image::compare_exposed;
use std::path::{Path, PathBuf};

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
    // when the run is complete (crate::store::staging).
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
    let (memory, available) = crate::estimate::check_run(exp, &geometry, &lighting, cache.is_some())?;
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

    let study = crate::stages::btf_study::StudyInputs {
        view: &view,
        lstar: &base.lstar,
        reference: reference.as_ref(),
        repeats,
        exposure,
        out_dir: &out_dir,
    };
    materials.btfs = crate::stages::btf_study::run(&materials, &study)?;
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
                    cache.as_ref().zip(crate::store::cache::form_key(&t.key, compressor.as_ref(), exp.file.seed))
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
    let inputs = crate::stages::sh::MethodInputs {
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
        .map(|m| crate::stages::evaluate_method(m, &inputs, gpu.as_ref()))
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
