//! Animated comparisons (`[runtime.animation]`): the light turned about +Y, or the camera
//! orbited about its target, through one full turn in `frames` steps; every frame rendered
//! on the CPU for the uncompressed `T` and for each animated setting (a compressor's form, or
//! an SH method setting, whose light is projected again each frame), and scored against the
//! uncompressed render of the same frame.
//!
//! Each sequence is streamed into an animated PNG (`animation/<path>/<name>.png`, tone mapped
//! at the report's exposure), so a long animation never holds its frames; each frame's error
//! and wall times go into the run's record ([`AnimationRecord`]) and a per-frame plot
//! (`animation_<path>.png`: error and frame time against the frame index, every setting on
//! one axis). Timings are one repeat per frame, on the CPU, whatever the run's backend.

use crate::error::{io_err, PipelineError, Result};
use crate::experiment::config::Experiment;
use crate::metrics::{AnimationRecord, AnimationSeries};
use crate::stages::evaluate::uncompressed_product;
use crate::stages::scene::Lighting;
use crate::stages::view::{Shaded, View};
use biscale_core::compress::{CompressedForm, Compressor};
use biscale_core::gather::moments::{gather_keeping_moments, LightMoments};
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::LightVector;
use biscale_core::scene::{Background, Camera, ShadeScene};
use biscale_core::sh::ShProjection;
use biscale_core::transfer::TransferMatrix;
use biscale_shading::image::compare_exposed;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What an animated setting gathers from.
pub(crate) enum Source<'a> {
    /// A compressor setting's form of `T`, shaded with the run's scene.
    Form { compressor: &'a dyn Compressor, form: CompressedForm },
    /// An SH method setting: the light projected onto its order each frame, its compressed
    /// transfer, and the scene with its radiance transfer textures.
    Sh(Box<ShSource>),
}

/// What an animated SH setting keeps (boxed: it holds a whole shade scene).
pub(crate) struct ShSource {
    pub projection: ShProjection,
    pub compressor: Box<dyn Compressor>,
    pub form: CompressedForm,
    pub scene: ShadeScene,
}

/// One setting to animate.
pub(crate) struct Animated<'a> {
    pub name: String,
    pub source: Source<'a>,
}

/// What every frame shares.
pub(crate) struct Inputs<'a> {
    pub exp: &'a Experiment,
    pub lighting: &'a Lighting,
    pub t: &'a TransferMatrix,
    /// The vertex frames `T` was traced with (light moments resolve against them).
    pub frames: &'a [VertexFrame],
    pub view: &'a View<'a>,
    /// The run's tone map, in stops ([`crate::stages::evaluate::Targets::tone`]).
    pub exposure: f32,
    pub out_dir: &'a Path,
}

/// The path of one animation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Turn {
    Light,
    Camera,
}

impl Turn {
    fn name(self) -> &'static str {
        match self {
            Turn::Light => "light",
            Turn::Camera => "camera",
        }
    }
}

/// Every animation the config asks for, over `entries`.
pub(crate) fn animate(inp: &Inputs<'_>, entries: &[Animated<'_>]) -> Result<Vec<AnimationRecord>> {
    let a = &inp.exp.file.runtime.animation;
    let mut records = vec![];
    for (path, frames) in [(Turn::Light, a.light_frames), (Turn::Camera, a.camera_frames)] {
        if frames > 0 {
            records.push(one(inp, entries, path, frames)?);
        }
    }
    Ok(records)
}

/// The light of frame `angle` radians past the run's rotation, with the run's sun boost.
fn light_at(inp: &Inputs<'_>, angle: f64) -> LightVector {
    crate::stages::scene::light_of(inp.exp, &inp.lighting.env, inp.lighting.rotation + angle).0
}

/// The camera turned `angle` radians about +Y around its target (frame 0 is the run's camera
/// exactly, not one rounded through the turn).
fn orbit(camera: &Camera, angle: f64) -> Camera {
    if angle == 0.0 {
        return *camera;
    }
    let q = glam::Quat::from_rotation_y(angle as f32);
    Camera { position: camera.target + q * (camera.position - camera.target), ..*camera }
}

/// An animated PNG being written frame by frame.
struct Apng {
    path: PathBuf,
    writer: png::Writer<BufWriter<std::fs::File>>,
}

impl Apng {
    fn create(path: PathBuf, width: u32, height: u32, frames: u32, fps: u32) -> Result<Self> {
        let file = std::fs::File::create(&path).map_err(io_err(&path))?;
        let bad = |e: png::EncodingError| PipelineError::Mismatch { path: path.clone(), what: format!("APNG: {e}") };
        let mut enc = png::Encoder::new(BufWriter::new(file), width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_animated(frames, 0).map_err(bad)?;
        enc.set_frame_delay(1, fps as u16).map_err(bad)?;
        let writer = enc.write_header().map_err(bad)?;
        Ok(Self { path, writer })
    }

    fn frame(&mut self, rgb: &image::RgbImage) -> Result<()> {
        let path = &self.path;
        self.writer
            .write_image_data(rgb.as_raw())
            .map_err(|e| PipelineError::Mismatch { path: path.clone(), what: format!("APNG frame: {e}") })
    }

    fn finish(self) -> Result<()> {
        let path = self.path.clone();
        self.writer.finish().map_err(|e| PipelineError::Mismatch { path, what: format!("APNG: {e}") })
    }
}

/// What one frame of one setting shades.
enum Gathered {
    Lstar(LocalRadiance),
    Moments(LocalRadiance, [LocalRadiance; 3]),
}

impl Gathered {
    fn shaded(&self) -> Shaded<'_> {
        match self {
            Gathered::Lstar(l) => Shaded::Lstar(l),
            Gathered::Moments(l, m) => Shaded::of(l, Some(m)),
        }
    }
}

/// The uncompressed frame: the f64 product rounded to f32 (with light moments, the moments'
/// product; per pixel, the three moment products), as the run's baseline.
fn uncompressed(inp: &Inputs<'_>, light: &LightVector) -> Result<Gathered> {
    let rt = &inp.exp.file.runtime;
    let t = inp.t;
    let moments = rt.light_moments.then_some(inp.frames);
    let lstar = LocalRadiance::from_f64(t.local_basis(), t.vertices(), &uncompressed_product(t, light, moments)?)?;
    if !rt.resolve_per_pixel() {
        return Ok(Gathered::Lstar(lstar));
    }
    let m = LightMoments::new(light)?;
    Ok(Gathered::Moments(lstar, crate::stages::evaluate::moment_gathers(t.into(), &m)?))
}

/// A setting's frame under `light`, gathered as the run gathers it.
fn gathered(inp: &Inputs<'_>, e: &Animated<'_>, light: &LightVector) -> Result<Gathered> {
    let cerr = |source| PipelineError::Compress { name: e.name.clone(), source };
    let rt = &inp.exp.file.runtime;
    match &e.source {
        Source::Form { compressor, form } => match rt.light_moments {
            false => Ok(Gathered::Lstar(compressor.gather(form, light).map_err(cerr)?)),
            true => {
                let m = LightMoments::new(light)?;
                let (lstar, g) = gather_keeping_moments(*compressor, form, &m, inp.frames).map_err(cerr)?;
                Ok(match rt.resolve_per_pixel() {
                    true => Gathered::Moments(lstar, g),
                    false => Gathered::Lstar(lstar),
                })
            }
        },
        Source::Sh(sh) => {
            Ok(Gathered::Lstar(sh.compressor.gather(&sh.form, &sh.projection.project(light)?).map_err(cerr)?))
        }
    }
}

/// One path: every frame of every setting.
fn one(inp: &Inputs<'_>, entries: &[Animated<'_>], path: Turn, frames: u32) -> Result<AnimationRecord> {
    let a = &inp.exp.file.runtime.animation;
    let exposure = inp.exposure;
    let dir = inp.out_dir.join("animation").join(path.name());
    std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    let cam = inp.view.camera;
    let mut names = vec!["uncompressed".to_string()];
    names.extend(entries.iter().map(|e| e.name.clone()));
    let file = |name: &str| format!("animation/{}/{}.png", path.name(), name.replace([':', '/'], "-"));
    let mut apngs = names
        .iter()
        .map(|n| Apng::create(inp.out_dir.join(file(n)), cam.width, cam.height, frames, a.fps))
        .collect::<Result<Vec<_>>>()?;
    let mut series: Vec<AnimationSeries> = names
        .iter()
        .map(|n| AnimationSeries {
            name: n.clone(),
            apng: file(n),
            rel_l2: vec![],
            gather_ms: vec![],
            shade_ms: vec![],
        })
        .collect();
    let step = std::f64::consts::TAU / frames as f64;
    // On the camera path the light, and so every L*, is the run's: gathered once.
    let fixed: Option<(Gathered, Vec<Gathered>)> = match path {
        Turn::Camera => {
            let light = &inp.lighting.light;
            Some((uncompressed(inp, light)?, entries.iter().map(|e| gathered(inp, e, light)).collect::<Result<_>>()?))
        }
        Turn::Light => None,
    };
    let progress = crate::util::progress_bar(frames as u64, &format!("animation ({})", path.name()));
    for f in 0..frames {
        let angle = step * f as f64;
        let (camera, background) = match path {
            Turn::Light => {
                let background = match inp.view.background {
                    Background::Env { env, rotation } => Background::Env { env, rotation: rotation + angle },
                    Background::Black => Background::Black,
                };
                (cam, background)
            }
            Turn::Camera => (orbit(&cam, angle), inp.view.background),
        };
        let view = inp.view.with(inp.view.scene, camera, background);
        // This frame's gathers, the uncompressed one first (the target of every other's
        // error), and each one's time: the fixed light's, gathered once (no time per frame),
        // or the turned light's, gathered now.
        let turned;
        let (target_g, gs, gather_ms): (&Gathered, &[Gathered], Vec<f64>) = match &fixed {
            Some((u, gs)) => (u, gs, vec![0.0; entries.len() + 1]),
            None => {
                let light = light_at(inp, angle);
                let mut ms = vec![];
                let mut timed = |f: &dyn Fn() -> Result<Gathered>| -> Result<Gathered> {
                    let start = Instant::now();
                    let g = f()?;
                    ms.push(start.elapsed().as_secs_f64() * 1e3);
                    Ok(g)
                };
                let u = timed(&|| uncompressed(inp, &light))?;
                let gs = entries.iter().map(|e| timed(&|| gathered(inp, e, &light))).collect::<Result<Vec<_>>>()?;
                turned = (u, gs);
                (&turned.0, &turned.1, ms)
            }
        };
        let start = Instant::now();
        let target = view.render_shaded(target_g.shaded(), &camera)?;
        let shade_ms = start.elapsed().as_secs_f64() * 1e3;
        record(&mut series[0], &mut apngs[0], &target, &target, gather_ms[0], shade_ms, exposure)?;
        for (i, e) in entries.iter().enumerate() {
            let g = &gs[i];
            let start = Instant::now();
            let render = match &e.source {
                Source::Form { .. } => view.render_shaded(g.shaded(), &camera)?,
                Source::Sh(sh) => {
                    let sh_view = inp.view.with(&sh.scene, camera, background);
                    sh_view.render_shaded(g.shaded(), &camera)?
                }
            };
            let shade_ms = start.elapsed().as_secs_f64() * 1e3;
            record(&mut series[i + 1], &mut apngs[i + 1], &render, &target, gather_ms[i + 1], shade_ms, exposure)?;
        }
        progress.set_position(f as u64 + 1);
    }
    progress.finish_and_clear();
    for a in apngs {
        a.finish()?;
    }
    let plot = format!("animation_{}.png", path.name());
    let curves: Vec<crate::plots::FrameCurve> = series
        .iter()
        .map(|s| crate::plots::FrameCurve {
            name: s.name.clone(),
            error: s.rel_l2.clone(),
            ms: s.gather_ms.iter().zip(&s.shade_ms).map(|(g, s)| g + s).collect(),
        })
        .collect();
    let title = match path {
        Turn::Light => format!("light turned about +Y, {frames} frames"),
        Turn::Camera => format!("camera orbited, {frames} frames"),
    };
    crate::plots::frame_plot(&inp.out_dir.join(&plot), &title, &curves)
        .map_err(|what| PipelineError::Mismatch { path: inp.out_dir.join(&plot), what })?;
    let worst = series.iter().skip(1).map(|s| (s.name.as_str(), s.rel_l2.iter().fold(0f64, |a, &b| a.max(b))));
    for (name, e) in worst {
        log::info!("animation {}: {name}: largest per-frame rel. L2 {e:.2e}", path.name());
    }
    Ok(AnimationRecord {
        path: path.name().into(),
        frames,
        step_degrees: 360.0 / frames as f64,
        fps: a.fps,
        plot,
        series,
    })
}

/// Score `render` against the frame's `target`, stream it into its APNG and note its times.
fn record(
    s: &mut AnimationSeries,
    apng: &mut Apng,
    render: &biscale_core::scene::Render,
    target: &biscale_core::scene::Render,
    gather_ms: f64,
    shade_ms: f64,
    exposure: f32,
) -> Result<()> {
    let m = compare_exposed(&render.image, &target.image, Some(&target.mask), exposure)?;
    s.rel_l2.push(m.rel_l2);
    s.gather_ms.push(gather_ms);
    s.shade_ms.push(shade_ms);
    apng.frame(&render.image.to_srgb8(exposure))
}
