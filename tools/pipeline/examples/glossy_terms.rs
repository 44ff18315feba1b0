//! Where the error of a flat analytic material comes from (issue 33's decomposition): five
//! images of one config at its reference camera, each differing from the next by one
//! approximation, and their relative L2 errors over the covered pixels.
//!
//! | image | `L*` | BRDF |
//! |---|---|---|
//! | `exact` | per pixel, every texel at its own direction and cosine | the analytic BRDF at each texel's direction and the pixel's view (the pipeline's reference) |
//! | `table` | same | the BTF's tables: light grid interpolated at each texel's direction, view grid looked up (the reference before `REFERENCE_VERSION` 2) |
//! | `binned` | per pixel, the paper's bins (bin-mean cosine) | the BTF at the bin centres |
//! | `vertex` | per vertex with light moments, interpolated | the BTF as every run shades it |
//! | `vertex_paper` | per vertex, the paper's bins, interpolated | same |
//! | `pixel_resolve` | the moments' three gathers per vertex, each vertex's resolved at the pixel's own frame, blended (`runtime.moments_resolve = "pixel"`) | same |
//! | `pixel_analytic` | the moments' three gathers per vertex | the analytic BRDF at each of a vertex's bins' mean light direction and the pixel's view, the three vertices blended (`runtime.moments_resolve = "pixel_analytic"`) |
//!
//! The terms: `table` vs `exact` is the tabulation of the BRDF on the light and view grids;
//! `binned` vs `table` the bin rule (each texel by its bin's mean cosine, the BRDF at the bin
//! centre) per pixel; `vertex` vs `table` the vertex interpolation of the moments' `L*` (with
//! the resolve's own mean-direction rule); `vertex_paper` vs `binned` the vertex interpolation
//! of the paper's `L*`; `pixel_resolve` vs `table` what is left of it when the moments (world
//! space directions) are resolved per pixel, so a sharp light falling in different bins of
//! neighbouring vertices' frames is not split between two local directions;
//! `pixel_analytic` vs `exact` what is left without the tables (each bin's light at its mean
//! direction, the interpolation of the moments); and each vertex image against `exact` the
//! whole. They need not add up
//! (errors of opposite sign cancel). All share `T`'s visibility (cubemap texels, 2x2 box
//! filter), which only a finer `[transfer]` changes; rerun with `--set` to see those terms.
//! Prints one JSON object.
//!
//! ```text
//! cargo run --release -p biscale --example glossy_terms -- configs/glossy_ggx_bunny.toml [--set KEY=VALUE ...]
//! ```

use anyhow::{bail, Result};
use biscale::experiment::config::Experiment;
use biscale::stages::scene::{load_geometry, load_lighting, shade_scene};
use biscale::stages::transfer::transfer_matrix;
use biscale::store::cache::StageCache;
use biscale::store::RunOptions;
use biscale_core::gather::moments::{exact_moments_product, LightMoments, Lobe};
use biscale_core::gather::{reference_product, LocalRadiance};
use biscale_core::transfer::VisibilitySampler;
use biscale_shading::cpu::{shade, shade_moments, shade_moments_analytic};
use biscale_shading::image::compare;
use biscale_shading::reference::{render_reference, ReferenceRule};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Parser)]
struct Args {
    /// The experiment config (a flat analytic material: Lambertian, Phong or a flat synthesized patch).
    config: PathBuf,
    /// `KEY=VALUE` overrides, as `biscale run --set`.
    #[arg(long = "set")]
    sets: Vec<String>,
    /// Stage cache folder (default: the pipeline's).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
}

fn main() -> Result<()> {
    let args = <Args as clap::Parser>::parse();
    let exp = Experiment::load_with(&args.config, &args.sets)?;
    let opts = RunOptions { out_dir: None, cache_dir: args.cache_dir, no_cache: false };
    let cache = StageCache::new(&opts, std::path::Path::new("."));
    let start = Instant::now();
    let geometry = load_geometry(&exp)?;
    let lighting = load_lighting(&exp)?;
    let t = transfer_matrix(&exp, &geometry, cache.as_ref())?.into_whole("the glossy terms")?;
    let (scene, materials) = shade_scene(&exp, &geometry, t.local_basis(), cache.as_ref())?;
    let brdfs = &materials.analytic;
    if brdfs.iter().any(Option::is_none) {
        bail!("{}: every material must be an analytic BRDF ({})", args.config.display(), materials.reference_shading());
    }
    let camera = geometry.camera(&exp, *exp.file.report.reference_downscale.get_ref());
    let sampler = VisibilitySampler::new(&exp.transfer_settings());
    let light = &lighting.light;
    let trace = |rule, brdfs: &[Option<biscale_shading::synth::Brdf>]| {
        render_reference(&scene, light, &geometry.transfer, &sampler, &camera, rule, brdfs, None)
    };
    let exact = trace(ReferenceRule::GroundTruth, brdfs)?;
    let table = trace(ReferenceRule::GroundTruth, &[])?;
    let binned = trace(ReferenceRule::Binned, &[])?;
    let frames = geometry.transfer.frames();
    let basis = t.local_basis();
    let moments =
        LocalRadiance::from_f64(basis, t.vertices(), &exact_moments_product(&t, light, frames, Lobe::MeanDirection)?)?;
    let paper = LocalRadiance::from_f64(basis, t.vertices(), &reference_product(&t, light))?;
    let vertex = shade(&scene, &moments, &camera)?;
    let vertex_paper = shade(&scene, &paper, &camera)?;
    // The three moments per vertex (f64 products rounded to f32, as an exact gather gives).
    let along = LightMoments::new(light)?.along;
    let gathered: Vec<LocalRadiance> = along
        .iter()
        .map(|l| LocalRadiance::from_f64(basis, t.vertices(), &reference_product(&t, l)))
        .collect::<std::result::Result<_, _>>()?;
    let g = [&gathered[0], &gathered[1], &gathered[2]];
    let pixel_resolve = shade_moments(&scene, g, Lobe::MeanDirection, &camera)?;
    let pixel_analytic = shade_moments_analytic(&scene, g, brdfs, &camera)?;
    let mask = &exact.mask;
    let rel = |a: &biscale_core::scene::Render, b: &biscale_core::scene::Render| -> Result<f64> {
        Ok(compare(&a.image, &b.image, Some(mask))?.rel_l2)
    };
    let out = serde_json::json!({
        "config": args.config.display().to_string(),
        "sets": args.sets,
        "vertices": t.vertices(),
        "local_basis": basis.to_string(),
        "light_basis": t.light_basis().to_string(),
        "camera": [camera.width, camera.height, camera.samples_per_pixel],
        "shading": materials.reference_shading(),
        "terms": {
            "tabulation (table vs exact)": rel(&table, &exact)?,
            "bin rule per pixel (binned vs table)": rel(&binned, &table)?,
            "vertex interpolation, moments (vertex vs table)": rel(&vertex, &table)?,
            "vertex interpolation, paper (vertex_paper vs binned)": rel(&vertex_paper, &binned)?,
            "moments resolved per pixel (pixel_resolve vs table)": rel(&pixel_resolve, &table)?,
            "moments resolved per pixel, analytic BRDF (pixel_analytic vs exact)": rel(&pixel_analytic, &exact)?,
        },
        "against_exact": {
            "table": rel(&table, &exact)?,
            "binned": rel(&binned, &exact)?,
            "vertex": rel(&vertex, &exact)?,
            "vertex_paper": rel(&vertex_paper, &exact)?,
            "pixel_resolve": rel(&pixel_resolve, &exact)?,
            "pixel_analytic": rel(&pixel_analytic, &exact)?,
        },
        "seconds": start.elapsed().as_secs_f64(),
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
