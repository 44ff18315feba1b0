//! The BTF study of a run: every BTF setting of every material shaded with the uncompressed
//! `L*`, against the same scene with every BTF dense (the part of the error the BTF
//! representation adds) and against the ray-traced reference, with its CPU shade time and,
//! for compressed settings, the fixed-light fast path of precomputed per-vertex dot products
//! (`biscale_shading::precomputed`). It runs when any material lists a compressed setting;
//! each setting changes one material and leaves the others dense, so a row is that material's
//! own effect.

use crate::error::Result;
use crate::metrics::{BtfRecord, BtfStudyRecord, PrecomputedRecord};
use crate::stages::evaluate::errors;
use crate::stages::materials::SceneMaterials;
use crate::stages::view::{timed, Reference, View};
use biscale_core::gather::LocalRadiance;
use biscale_core::scene::{BtfRepresentation, Render, ShadeScene};
use biscale_shading::image::{compare, compare_exposed};
use biscale_shading::precomputed::{shade_precomputed, LightDots};
use std::path::Path;

/// Largest precomputed dot-product table the study builds (1 GiB); a larger one is recorded
/// as not measured, with its size.
pub const MAX_PRECOMPUTED_BYTES: u64 = 1 << 30;

/// What the study shades with: the run's view (camera, background), the uncompressed `L*`,
/// the reference, where images go.
pub(crate) struct StudyInputs<'a> {
    pub view: &'a View<'a>,
    pub lstar: &'a LocalRadiance,
    pub reference: Option<&'a Reference>,
    pub repeats: usize,
    pub exposure: f32,
    pub out_dir: &'a Path,
}

/// Fill in the `study` of every record of `materials.btfs` (none when every setting is dense).
pub(crate) fn run(materials: &SceneMaterials, inp: &StudyInputs<'_>) -> Result<Vec<BtfRecord>> {
    let mut records = materials.btfs.clone();
    if !materials.has_compressed() {
        return Ok(records);
    }
    let scene_of = |m| inp.view.scene.with_materials(m);
    let background = |r: Render, camera| r.with_background(camera, &inp.view.background);
    let shade = |scene: &ShadeScene, camera| -> Result<Render> {
        Ok(background(biscale_shading::cpu::shade(scene, inp.lstar, camera)?, camera))
    };
    let camera = &inp.view.camera;
    let dense_scene = scene_of(materials.all_dense())?;
    let scenes: Vec<ShadeScene> = materials
        .variants
        .iter()
        .map(|v| scene_of(materials.with_variant(v)))
        .collect::<std::result::Result<_, _>>()?;
    let (dots, mut notes) = precomputed_dots(&scenes, materials, inp.lstar)?;
    // Every image of the study, timed in interleaved rounds (so that load changes during the
    // run touch every setting alike): the primary rays and background alone, the all-dense
    // scene, each setting directly, and each precomputed setting.
    let mut jobs: Vec<Box<dyn Fn() -> Result<Render> + '_>> = vec![
        Box::new(|| Ok(background(biscale_shading::cpu::trace_only(&dense_scene, camera)?, camera))),
        Box::new(|| shade(&dense_scene, camera)),
    ];
    for scene in &scenes {
        jobs.push(Box::new(move || shade(scene, camera)));
    }
    for (scene, d) in scenes.iter().zip(&dots) {
        if let Some((d, _)) = d {
            jobs.push(Box::new(move || Ok(background(shade_precomputed(scene, d, inp.lstar, camera)?, camera))));
        }
    }
    let rounds = inp.repeats.max(1);
    let (ms, renders) = interleaved(&jobs, rounds)?;
    let mut renders = renders.into_iter();
    let (_, dense) = (renders.next(), renders.next().expect("the dense job"));
    let (rays_ms, dense_ms) = (ms[0], ms[1]);
    log::info!(
        "btf study ({rounds} interleaved rounds): all-dense image {dense_ms:.1} ms, of which {rays_ms:.1} ms primary rays and background"
    );
    let direct: Vec<Render> = renders.by_ref().take(scenes.len()).collect();
    let mut pre_ms = ms[2 + scenes.len()..].iter();
    let mut pre_renders = renders;
    let images = inp.out_dir.join("images");
    let shared_scale = shared_study_scale(&direct, &dense)?;
    for (i, record) in records.iter_mut().enumerate() {
        let (scene, render, shade_ms) = (&scenes[i], &direct[i], ms[2 + i]);
        let vs_dense = errors(&compare_exposed(&render.image, &dense.image, Some(&dense.mask), inp.exposure)?);
        let vs_reference = match inp.reference {
            Some(r) => {
                let small = shade(scene, &r.camera)?;
                Some(errors(&compare_exposed(&small.image, &r.render.image, Some(&r.render.mask), inp.exposure)?))
            }
            None => None,
        };
        let precomputed = match &dots[i] {
            Some((d, precompute_ms)) => {
                let img = pre_renders.next().expect("a precomputed render per table");
                let vs_direct = compare(&img.image, &render.image, Some(&render.mask))?.rel_l2;
                let shade_ms = *pre_ms.next().expect("a time per precomputed render");
                Some(PrecomputedRecord { bytes: d.bytes(), precompute_ms: *precompute_ms, shade_ms, vs_direct })
            }
            None => None,
        };
        let stem = format!("btf-{}-{}", record.material, record.representation).replace([':', ' ', '/'], "-");
        let png = format!("images/{stem}.png");
        render.image.write_png(&images.join(format!("{stem}.png")), inp.exposure)?;
        let error_png = format!("images/{stem}_error.png");
        let (error_scale, _) = crate::stages::figures::write_error_figure(
            &render.image,
            &dense.image,
            "all-dense BTFs",
            Some(shared_scale),
            &inp.out_dir.join(&error_png),
        )?;
        log::info!(
            "btf study: {} {}: image vs dense rel. L2 {:.2e}{}, shade {shade_ms:.1} ms (dense {dense_ms:.1} ms){}",
            record.material,
            record.representation,
            vs_dense.rel_l2,
            vs_reference.as_ref().map_or(String::new(), |e| format!(", vs reference {:.2e}", e.rel_l2)),
            precomputed.as_ref().map_or(String::new(), |p| format!(
                ", precomputed {:.1} ms per frame after {:.0} ms ({:.1} MB)",
                p.shade_ms,
                p.precompute_ms,
                p.bytes as f64 * 1e-6
            )),
        );
        record.study = Some(BtfStudyRecord {
            vs_dense,
            vs_reference,
            shade_ms,
            dense_shade_ms: dense_ms,
            rays_ms,
            precomputed,
            precomputed_note: notes[i].take(),
            png,
            error_png,
            error_scale,
        });
    }
    Ok(records)
}

/// One error scale for every setting of the study, so their figures against the all-dense
/// image compare at a glance: the largest of the settings' own 99th percentiles
/// ([`crate::stages::figures::error_extent`]). A dense setting, identical to the all-dense
/// image, is then drawn dark on the others' scale instead of on a scale of its own. Where
/// every setting differs in fewer than 1% of the pixels the largest error is the scale; where
/// none differs at all, 0 leaves [`biscale_shading::image::error_image`]'s fallback.
fn shared_study_scale(direct: &[Render], dense: &Render) -> Result<f32> {
    let (mut scale, mut largest) = (0.0f32, 0.0f32);
    for r in direct {
        let (own, max) = crate::stages::figures::error_extent(&r.image, &dense.image)?;
        (scale, largest) = (scale.max(own), largest.max(max));
    }
    Ok(if scale > 0.0 { scale } else { largest })
}

/// The precomputed dot products of every compressed setting whose table fits (with the time
/// each took), and a note for each setting that has none.
#[allow(clippy::type_complexity)]
fn precomputed_dots(
    scenes: &[ShadeScene],
    materials: &SceneMaterials,
    lstar: &LocalRadiance,
) -> Result<(Vec<Option<(LightDots, f64)>>, Vec<Option<String>>)> {
    let mut dots = vec![];
    let mut notes = vec![];
    for (scene, variant) in scenes.iter().zip(&materials.variants) {
        let compressed = !matches!(scene.materials()[variant.material].btf, BtfRepresentation::Dense(_));
        let need = LightDots::bytes_needed(scene);
        let (d, note) = match (compressed, need <= MAX_PRECOMPUTED_BYTES) {
            (false, _) => (None, Some("dense: nothing to precompute".to_string())),
            (true, false) => (
                None,
                Some(format!(
                    "not measured: the dot products would take {:.0} MB (limit {:.0} MB); per-view units need V times less",
                    need as f64 * 1e-6,
                    MAX_PRECOMPUTED_BYTES as f64 * 1e-6
                )),
            ),
            (true, true) => {
                let (d, once) = timed(1, || Ok(LightDots::new(scene, lstar, MAX_PRECOMPUTED_BYTES)?))?;
                (Some((d, once.median_ms)), None)
            }
        };
        dots.push(d);
        notes.push(note);
    }
    Ok((dots, notes))
}

/// Run every job `rounds` times in interleaved rounds: the median time of each (ms) and its
/// last render.
fn interleaved(jobs: &[Box<dyn Fn() -> Result<Render> + '_>], rounds: usize) -> Result<(Vec<f64>, Vec<Render>)> {
    let mut samples = vec![vec![]; jobs.len()];
    let mut last: Vec<Option<Render>> = (0..jobs.len()).map(|_| None).collect();
    for _ in 0..rounds {
        for (i, job) in jobs.iter().enumerate() {
            let start = std::time::Instant::now();
            last[i] = Some(job()?);
            samples[i].push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    let ms: Vec<f64> = samples.iter().map(|s| biscale_core::stats::median(s)).collect();
    Ok((ms, last.into_iter().map(|r| r.expect("every job ran")).collect()))
}
