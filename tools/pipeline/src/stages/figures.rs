//! The run's figures: error images on a shared scale, insets and the side-by-side comparison.

use crate::error::{PipelineError, Result};
use crate::experiment::config::Experiment;
use crate::metrics::*;
use crate::stages::view::{Baseline, Reference, View};
use biscale_core::scene::{HdrImage, Render};
use std::path::Path;

/// The largest finite per-pixel error `luminance(|a - b|)`.
fn largest_error(a: &HdrImage, b: &HdrImage) -> f32 {
    (a.pixels.iter().zip(&b.pixels))
        .map(|(p, q)| biscale_core::scene::image::luminance(std::array::from_fn(|c| (p[c] - q[c]).abs())))
        .filter(|e| e.is_finite())
        .fold(0.0f32, f32::max)
}

/// The scale an error figure of `|a - b|` would have on its own (its 99th percentile,
/// [`biscale_shading::image::error_image`]) and the largest error, without drawing it.
pub(crate) fn error_extent(a: &HdrImage, b: &HdrImage) -> Result<(f32, f32)> {
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
pub(crate) fn inset_region(
    exp: &Experiment,
    records: &[CompressorRecord],
    renders: &[Render],
    base: &Baseline,
    exposure: f32,
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
                .map(|(r, render)| (r.name.clone(), inset::error_map(&render.image, &base.render.image, exposure)))
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
pub(crate) fn comparison_figures(
    (region, from): (crate::inset::Region, String),
    records: &[CompressorRecord],
    methods: &[MethodRecord],
    base: &Baseline,
    view: &View<'_>,
    reference: Option<&Reference>,
    fixed_scale: Option<f32>,
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
        scored.insert(0, ("uncompressed".into(), view.render_shaded(base.shaded(), &r.camera)?.image));
        let mut scale = 0.0f32;
        for (_, small) in &scored {
            scale = scale.max(error_extent(small, &r.render.image)?.0);
        }
        // `[report] reference_error_scale` puts them on another run's colour bar.
        let scale = fixed_scale.unwrap_or(scale);
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

/// One error scale for every setting of `records` (the run's compressors; apart from them,
/// its methods), so their error figures compare at a glance: `fixed` (`[report] error_scale`
/// for the compressors) when set, else the largest of the lossy settings' own 99th
/// percentiles (every lossy figure then fits; a lossless one, far below, shows dark), else of
/// all. Each figure is drawn here, once, at that scale.
pub(crate) fn share_error_scale(
    mut records: Vec<&mut CompressorRecord>,
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

/// Write `<name>.png` and `<name>.exr`; returns their paths relative to the output folder.
pub(crate) fn save_images(img: &HdrImage, dir: &Path, name: &str, exposure: f32) -> Result<(String, String)> {
    let png = dir.join(format!("{name}.png"));
    let exr = dir.join(format!("{name}.exr"));
    img.write_png(&png, exposure)?;
    img.write_exr(&exr)?;
    Ok((format!("images/{name}.png"), format!("images/{name}.exr")))
}
