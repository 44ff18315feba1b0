//! What every render of a run is made with and measured against, apart from the measuring
//! ([`super::evaluate`]) and the figures ([`super::figures`]), which both use it: the run's
//! [`View`] (scene, camera, background, the analytic BRDFs and the resolve), what a render
//! shades ([`Shaded`]), the uncompressed [`Baseline`], the ground truth [`Reference`], and the
//! repeated timing of a step ([`timed`]).

use crate::error::Result;
use crate::experiment::config::Experiment;
use crate::metrics::Timing;
use crate::stages::scene::{Geometry, Lighting};
use biscale_core::gather::moments::Lobe;
use biscale_core::gather::LocalRadiance;
use biscale_core::scene::{Background, Camera, HdrImage, Render, ShadeScene};
use biscale_shading::cpu::{shade, shade_moments, shade_moments_analytic};
use biscale_shading::image::ImageMetrics;
use biscale_shading::synth::Brdf;
use std::time::Instant;

/// The uncompressed baseline: the f64 product `T L` (the reference for `L*` errors) and,
/// rounded to f32, the image every compressor is compared with. With light moments the
/// product weights every texel by its own cosine and moves the BRDF to each bin's mean light
/// direction ([`biscale_core::gather::moments::exact_moments_product`]), and the paper's
/// bin-mean-cosine `L*` is kept beside it so the report measures both side by side.
pub struct Baseline {
    pub exact: Vec<[f64; 3]>,
    pub lstar: LocalRadiance,
    pub render: Render,
    /// The uncompressed gather's and shade's repeats (their medians are `metrics.json`'s
    /// `uncompressed.gather_ms` and `shade_ms`).
    pub gather_timing: Timing,
    pub shade_timing: Timing,
    /// With light moments: the paper's `L*` and its image.
    pub paper: Option<(LocalRadiance, Render)>,
    /// With `runtime.moments_resolve = "pixel"`: the exact three moment gathers (f64 products
    /// rounded to f32), which `render` resolves at every pixel.
    pub moments: Option<[LocalRadiance; 3]>,
}

impl Baseline {
    /// What the baseline's image shades: the three moments per pixel, or `L*`.
    pub(crate) fn shaded(&self) -> Shaded<'_> {
        Shaded::of(&self.lstar, self.moments.as_ref())
    }
}

/// What a render of the run shades: an `L*`, or with `runtime.moments_resolve = "pixel"` the
/// three gathered light moments, resolved at every shading point
/// (`biscale_shading::cpu::shade_moments`).
#[derive(Clone, Copy)]
pub(crate) enum Shaded<'a> {
    Lstar(&'a LocalRadiance),
    Moments([&'a LocalRadiance; 3]),
}

impl<'a> Shaded<'a> {
    /// The three moments when there are (`moments_resolve = "pixel"`), else `lstar`.
    pub(crate) fn of(lstar: &'a LocalRadiance, moments: Option<&'a [LocalRadiance; 3]>) -> Self {
        match moments {
            Some([x, y, z]) => Shaded::Moments([x, y, z]),
            None => Shaded::Lstar(lstar),
        }
    }
}

/// What every render of the run shares: the scene, the camera and the background.
pub(crate) struct View<'a> {
    pub scene: &'a ShadeScene,
    pub camera: Camera,
    pub background: Background<'a>,
    /// The BRDF of each material of `scene` that is one (`SceneMaterials::analytic`): the
    /// reference evaluates it exactly.
    pub analytic: &'a [Option<Brdf>],
    /// `runtime.moments_resolve = "pixel_analytic"`: the per-pixel resolve shades the
    /// materials `analytic` names with their own BRDF
    /// (`biscale_shading::cpu::shade_moments_analytic`).
    pub moments_analytic: bool,
}

impl<'a> View<'a> {
    /// The run's view of `scene`: `exp`'s camera of `geometry`, the background of `lighting`,
    /// the materials' analytic BRDFs `analytic` and the config's resolve. The one setup of
    /// `run`, `eval` and the Python module's images.
    pub(crate) fn of(
        exp: &Experiment,
        geometry: &Geometry,
        lighting: &'a Lighting,
        scene: &'a ShadeScene,
        analytic: &'a [Option<Brdf>],
    ) -> Self {
        View {
            scene,
            camera: geometry.camera(exp, 1),
            background: lighting.background(exp),
            analytic,
            moments_analytic: exp.file.runtime.resolve_analytic(),
        }
    }

    /// This view of `scene` from `camera` against `background` (another method's scene, a
    /// frame of an animation), with the same materials' BRDFs and resolve.
    pub(crate) fn with<'b>(&self, scene: &'b ShadeScene, camera: Camera, background: Background<'b>) -> View<'b>
    where
        'a: 'b,
    {
        View { scene, camera, background, analytic: self.analytic, moments_analytic: self.moments_analytic }
    }
}

impl View<'_> {
    /// The image of `lstar` with the background behind it.
    pub(crate) fn render(&self, lstar: &LocalRadiance, camera: &Camera) -> Result<Render> {
        Ok(shade(self.scene, lstar, camera)?.with_background(camera, &self.background))
    }

    /// The image of `shaded` with the background behind it.
    pub(crate) fn render_shaded(&self, shaded: Shaded<'_>, camera: &Camera) -> Result<Render> {
        match shaded {
            Shaded::Lstar(lstar) => self.render(lstar, camera),
            Shaded::Moments(m) => {
                let render = match self.moments_analytic {
                    true => shade_moments_analytic(self.scene, m, self.analytic, camera)?,
                    false => shade_moments(self.scene, m, Lobe::MeanDirection, camera)?,
                };
                Ok(render.with_background(camera, &self.background))
            }
        }
    }

    /// [`Self::render_shaded`] at the run's camera, `repeats` times: the image and its [`Timing`].
    pub(crate) fn timed_render_shaded(&self, shaded: Shaded<'_>, repeats: usize) -> Result<(Render, Timing)> {
        timed(repeats, || self.render_shaded(shaded, &self.camera))
    }
}

/// Run `f` `repeats` times (at least once): its last result and the wall time of the repeats
/// (fastest, median, slowest, spread: [`Timing`]; its `median_ms` is what `*_ms` fields report).
pub(crate) fn timed<T>(repeats: usize, mut f: impl FnMut() -> Result<T>) -> Result<(T, Timing)> {
    let mut samples = vec![];
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        last = Some(f()?);
        samples.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok((last.expect("at least one run"), Timing::from_samples(&samples)))
}

/// The ground truth (direct light), ray-traced per pixel at the reference resolution
/// ([`biscale_shading::reference::ReferenceRule::GroundTruth`]), and the baseline's error against it.
pub struct Reference {
    pub render: Render,
    pub camera: Camera,
    /// The trace's wall time; of a `cached` reference, the time the run that traced it measured.
    pub seconds: f64,
    /// Whether the image came from the stage cache ([`super::evaluate::REFERENCE_ARTIFACT`]) instead of a trace.
    pub cached: bool,
    pub baseline_error: ImageMetrics,
    /// With light moments: the paper-mode baseline's error against the same reference.
    pub paper_baseline_error: Option<ImageMetrics>,
    /// Every setting's render at the reference's camera, by name, kept as it is scored
    /// ([`super::evaluate::Evaluation::score`]) for its error figure against the reference, which
    /// [`super::figures::comparison_figures`] draws once every setting is in, at one scale for all.
    pub(crate) scored: std::sync::Mutex<Vec<(String, HdrImage)>>,
}
