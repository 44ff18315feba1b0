//! The interactive viewer (cargo feature `viewer`): a window showing the bi-scale
//! rendering of one scene, in which the user orbits the camera, rotates the environment (a
//! *light change*: `L` is recomputed from the map with the new rotation on a worker thread,
//! then the current compressed form's gather runs again on the GPU), and switches between
//! compressed forms, with the frame time and the GPU split between gather and shade drawn
//! over the image.
//!
//! Per frame: [`GpuGather`] (only after a light change, a switch to a form whose `L*` is
//! stale, or every frame in continuous mode; with light moments, [`GpuMoments`]: the rotated
//! light's three direction moments gathered and resolved into `L*'` on the GPU, as the
//! pipeline's `[runtime] light_moments`), [`GpuShader`]'s visibility and shade passes into
//! its HDR image, [`ToneMap`] into the window's surface texture, the text overlay on top; all
//! in one submission, with GPU timestamps around every pass where the adapter has them.
//!
//! Controls: left drag orbits, wheel zooms, right drag or Left/Right turn the environment
//! (15 degrees a key press), Tab / Shift+Tab / 1-9 pick the compressed form, +/- change the
//! exposure, Space toggles continuous redraw (which re-runs the gather every frame, to time
//! the full light-change path), B toggles the background, C cycles how many components LPCA
//! BTFs keep while the light moves (1, 2, all: Müller et al. drop components during rotation),
//! R resets the camera, Esc or Q quit.
//!
//! Runtime libraries (X11 client libraries or libwayland, Vulkan loader + driver):
//! `scripts/setup-viewer.sh`. winit allows one event loop per process, so [`run_viewer`] can
//! be called once per process.

pub mod orbit;
pub(crate) mod overlay;

use crate::context::GpuContext;
use crate::error::{GpuError, Result};
use crate::gather::GpuGather;
use crate::moments::GpuMoments;
use crate::present::{read_texture_rgba8, Rgba8Image, ToneMap, ToneMapSettings};
use crate::shade::GpuShader;
use crate::timing::{median, PassTimer};
use biscale_core::basis::LightBasis;
use biscale_core::compress::CompressedForm;
use biscale_core::gather::moments::LightMoments;
use biscale_core::sampling::{Cubemap, EnvMap, LightVector};
use biscale_core::scene::{Camera, ShadeScene};
use biscale_core::sh::light::LIGHT_SUBTEXELS;
use biscale_core::sh::{ShProjection, ShRotation};
use biscale_shading::runtime::MomentsResolve;
use biscale_shading::synth::Brdf;
use orbit::Orbit;
use overlay::Overlay;
use std::path::PathBuf;
use std::sync::{mpsc, Arc};
use std::time::Instant;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// One compressed form the viewer can show, with the label shown on screen.
#[derive(Clone, Debug)]
pub struct ViewerForm {
    /// e.g. the compressor's label in the config (`cpca-k32-c8`).
    pub label: String,
    pub form: CompressedForm,
    /// The form's GPU gather program (its compressor's `Compressor::kernels`).
    pub kernels: biscale_kernels::KernelDesc,
}

/// Write a PNG of the window's content after `frames` frames, then close (for scripted
/// checks and headless screenshots).
#[derive(Clone, Debug, PartialEq)]
pub struct Screenshot {
    pub path: PathBuf,
    /// Frames to render before the capture (at least 1; the capture is of the last one).
    pub frames: u32,
}

/// Everything the viewer shows: the scene (as every shader takes it), the forms and the
/// lighting.
#[derive(Clone, Debug)]
pub struct ViewerSetup {
    /// Window title (e.g. the experiment's name).
    pub title: String,
    /// The scene, exactly as the pipeline shades it.
    pub scene: ShadeScene,
    /// The compressed forms (at least one); Tab cycles through them in this order.
    pub forms: Vec<ViewerForm>,
    /// Index into `forms` shown first.
    pub initial_form: usize,
    /// The environment map `L` is computed from (`LightVector::from_env`).
    pub env: EnvMap,
    /// The basis `L` is computed in (the forms' columns).
    pub light_basis: LightBasis,
    /// Initial rotation of the environment about +Y, radians (the config's rotation).
    pub env_rotation: f64,
    /// The config's `lighting.sun_boost`: the brightest texel of every recomputed `L` is
    /// multiplied by it ([`LightVector::boost_brightest`], as the pipeline does).
    pub sun_boost: Option<f32>,
    /// Initial camera; its `width x height` is the initial window size (pixels).
    pub camera: Camera,
    /// Exposure in stops (the config's `report.exposure`).
    pub exposure: f32,
    /// Draw the environment behind the mesh.
    pub background: bool,
    /// Capture the window after some frames and exit.
    pub screenshot: Option<Screenshot>,
    /// Start in continuous mode (redraw and re-gather every frame; Space toggles it).
    pub continuous: bool,
    /// Light moments (the config's `runtime.light_moments`): every light change gathers the
    /// light's three direction moments (`LightMoments::new`) through the form and resolves
    /// them into `L*'` on the GPU ([`GpuMoments`]), each texel weighted by its own cosine and
    /// each bin's BRDF taken at its mean light direction. Needs a cubemap light basis and a
    /// local basis of bins (the SH methods have neither: leave it off for them); the moments
    /// are resolved in the scene's frames, which must be those `T` was traced with.
    pub light_moments: bool,
    /// With light moments, where they are resolved first (the config's
    /// `runtime.moments_resolve`; key M cycles through the resolves): per vertex into `L*'`, or
    /// at every pixel ([`GpuShader::shade_moments`]).
    pub moments_resolve: MomentsResolve,
    /// Each material's analytic BRDF, or `None` (the config's flat analytic materials): what
    /// [`MomentsResolve::PixelAnalytic`] shades them with. Empty: no material has one.
    pub analytic: Vec<Option<Brdf>>,
}

/// What the worker thread sends back: a light vector for a rotation (and its moments, with
/// light moments).
struct LightReady {
    rotation: f64,
    light: LightVector,
    moments: Option<LightMoments>,
    ms: f64,
}

/// Cubemap resolution an SH light is projected from in the viewer (the reference cubemap).
const SH_SOURCE_RESOLUTION: u32 = 32;

/// `L` for any sky rotation, in the forms' light basis. A cubemap light is integrated from the
/// environment for every rotation, exactly as the pipeline's lighting stage makes it; an SH
/// light is projected once (from the reference cubemap, sun boost applied there) and then
/// rotated by the SH rotation matrix, which costs microseconds instead of a re-integration.
enum LightSource {
    Cubemap { env: Arc<EnvMap>, cubemap: Cubemap, sun_boost: Option<f32> },
    Sh { base: LightVector },
}

impl LightSource {
    fn new(env: &Arc<EnvMap>, basis: LightBasis, sun_boost: Option<f32>) -> Result<Self> {
        match basis {
            LightBasis::Cubemap(cubemap) => Ok(Self::Cubemap { env: env.clone(), cubemap, sun_boost }),
            LightBasis::Sh(order) => {
                let cubemap = Cubemap::new(SH_SOURCE_RESOLUTION);
                let mut l = LightVector::from_env(env, cubemap, 0.0);
                if let Some(b) = sun_boost {
                    l.boost_brightest(b);
                }
                let base = ShProjection::new(cubemap, order, LIGHT_SUBTEXELS).project(&l)?;
                Ok(Self::Sh { base })
            }
        }
    }

    fn at(&self, rotation: f64) -> LightVector {
        match self {
            Self::Cubemap { env, cubemap, sun_boost } => {
                let mut light = LightVector::from_env(env, *cubemap, rotation);
                if let Some(boost) = sun_boost {
                    light.boost_brightest(*boost);
                }
                light
            }
            Self::Sh { base } => {
                let order = base.basis().sh_order().expect("an SH light");
                base.rotated_sh(&ShRotation::about_y(order, rotation)).expect("the rotation has the light's order")
            }
        }
    }
}

impl ViewerSetup {
    /// Check sizes before anything is opened (the GPU stages check the rest).
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(GpuError::Input(m));
        if self.forms.is_empty() {
            return bad("the viewer needs at least one compressed form".into());
        }
        if self.initial_form >= self.forms.len() {
            return bad(format!("initial form {} of {} forms", self.initial_form, self.forms.len()));
        }
        let shape = biscale_core::basis::TransferShape::new(
            self.scene.mesh().vertex_count(),
            self.scene.local_basis(),
            self.light_basis,
        );
        for f in &self.forms {
            if f.form.shape() != shape {
                return bad(format!("form '{}' is {}; the scene needs {shape}", f.label, f.form.shape()));
            }
        }
        if self.env.width == 0 || self.env.height == 0 || self.env.pixels.len() != self.env.width * self.env.height {
            return bad("empty or inconsistent environment map".into());
        }
        if !self.env_rotation.is_finite() || !self.exposure.is_finite() {
            return bad("environment rotation and exposure must be finite".into());
        }
        if self.sun_boost.is_some_and(|b| !b.is_finite() || b < 0.0) {
            return bad("sun_boost must be finite and non-negative".into());
        }
        if self.screenshot.as_ref().is_some_and(|s| s.frames == 0) {
            return bad("a screenshot needs at least one frame".into());
        }
        if self.moments_resolve.per_pixel() && !self.light_moments {
            return bad(format!("the resolve \"{}\" needs light moments", self.moments_resolve.name()));
        }
        if !self.analytic.is_empty() && self.analytic.len() != self.scene.materials().len() {
            return bad(format!(
                "{} analytic BRDFs for {} materials",
                self.analytic.len(),
                self.scene.materials().len()
            ));
        }
        if self.light_moments {
            if self.light_basis.cubemap_layout().is_none() {
                return bad(format!(
                    "light moments need a cubemap light basis, the forms' is the {}",
                    self.light_basis
                ));
            }
            if self.scene.local_basis().grid().is_none() {
                return bad(format!(
                    "light moments need a local basis of bins, the scene's is {}",
                    self.scene.local_basis()
                ));
            }
        }
        Ok(())
    }

    /// Whether any material is an LPCA BTF (then key C picks its components while the light
    /// moves).
    fn has_lpca(&self) -> bool {
        self.scene.materials().iter().any(|m| matches!(m.btf, biscale_core::scene::BtfRepresentation::Lpca(_)))
    }

    /// A shader for this scene seen by `camera` (whose size is the image's), with the
    /// materials' analytic BRDFs.
    fn shader(&self, ctx: &GpuContext, camera: Camera) -> Result<GpuShader> {
        let mut shader = GpuShader::new(ctx, &self.scene, &camera)?;
        if !self.analytic.is_empty() {
            shader.set_brdfs(&self.analytic)?;
        }
        Ok(shader)
    }

    /// The resolves key M cycles through: per vertex and with the tables at every pixel with
    /// light moments, the analytic one too when a material has a BRDF; none without moments.
    fn resolves(&self) -> Vec<MomentsResolve> {
        match self.light_moments {
            false => vec![],
            true => MomentsResolve::ALL
                .into_iter()
                .filter(|r| *r != MomentsResolve::PixelAnalytic || self.analytic.iter().any(Option::is_some))
                .collect(),
        }
    }
}

/// Open the window and run until it is closed (or the screenshot is written). Errors: bad
/// setup, no display ([`GpuError::Window`]), no adapter, and anything the GPU stages report.
pub fn run_viewer(setup: ViewerSetup) -> Result<()> {
    setup.validate()?;
    let mut builder = EventLoop::<LightReady>::with_user_event();
    // Allow a call from any thread (tests, a CLI that does work on the main thread first).
    #[cfg(all(unix, not(target_os = "macos")))]
    {
        use winit::platform::wayland::EventLoopBuilderExtWayland;
        use winit::platform::x11::EventLoopBuilderExtX11;
        EventLoopBuilderExtX11::with_any_thread(&mut builder, true);
        EventLoopBuilderExtWayland::with_any_thread(&mut builder, true);
    }
    let event_loop = builder
        .build()
        .map_err(|e| GpuError::Window(format!("{e} (is DISPLAY or WAYLAND_DISPLAY set? try xvfb-run)")))?;
    let start = Instant::now();
    let source = Arc::new(LightSource::new(&Arc::new(setup.env.clone()), setup.light_basis, setup.sun_boost)?);
    let light = source.at(setup.env_rotation);
    let moments = moments_of(&light, setup.light_moments)?;
    let light_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut app = App {
        source,
        proxy: event_loop.create_proxy(),
        state: State::new(&setup, light, moments, light_ms),
        setup,
        gpu: None,
        error: None,
        worker: None,
        shift: false,
    };
    event_loop.run_app(&mut app).map_err(|e| GpuError::Window(e.to_string()))?;
    let s = &app.state;
    if s.frames > 0 {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2} ms"));
        eprintln!(
            "biscale view: {} frames; frame median {:.1} ms; last gather {} GPU / {} wall; last shade {} GPU",
            s.frames,
            median(&s.frame_ms),
            ms(s.last_gather_ms),
            ms(s.last_gather_wall_ms),
            ms(s.last_passes.map(|p| p[0] + p[1])),
        );
    }
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// Interaction state (no GPU objects).
struct State {
    orbit: Orbit,
    home: Orbit,
    min_distance: f64,
    form: usize,
    exposure: f32,
    background: bool,
    /// Rotation last asked of the worker, and the one the current `L` was computed with.
    requested_rotation: f64,
    light_rotation: f64,
    light: LightVector,
    /// The light's direction moments, with light moments.
    moments: Option<LightMoments>,
    /// Where the moments are resolved (key M).
    resolve: MomentsResolve,
    light_ms: f64,
    /// Per form: its `L*` on the GPU is from an older light.
    stale: Vec<bool>,
    continuous: bool,
    /// Components per cluster of LPCA BTFs while the light moves (a rotation pending or
    /// continuous mode; Müller et al. 2004); `None`: always all. Key C cycles 1, 2, all.
    moving_components: Option<u32>,
    left: bool,
    right: bool,
    cursor: Option<(f64, f64)>,
    frames: u32,
    /// Wall-clock frame times (ms), newest last, and the last GPU figures.
    frame_ms: Vec<f64>,
    /// GPU-timestamp and wall-clock (submit to idle) times of the last gather.
    last_gather_ms: Option<f64>,
    last_gather_wall_ms: Option<f64>,
    gather_this_frame: bool,
    last_passes: Option<[f64; 4]>,
    last_frame_start: Option<Instant>,
    fps_intervals: Vec<f64>,
}

impl State {
    fn new(setup: &ViewerSetup, light: LightVector, moments: Option<LightMoments>, light_ms: f64) -> Self {
        let orbit = Orbit::from_camera(&setup.camera);
        Self {
            orbit,
            home: orbit,
            min_distance: orbit.distance * 0.02,
            form: setup.initial_form,
            exposure: setup.exposure,
            background: setup.background,
            requested_rotation: setup.env_rotation,
            light_rotation: setup.env_rotation,
            light,
            moments,
            resolve: setup.moments_resolve,
            light_ms,
            stale: vec![true; setup.forms.len()],
            continuous: setup.continuous,
            moving_components: None,
            left: false,
            right: false,
            cursor: None,
            frames: 0,
            frame_ms: vec![],
            last_gather_ms: None,
            last_gather_wall_ms: None,
            gather_this_frame: false,
            last_passes: None,
            last_frame_start: None,
            fps_intervals: vec![],
        }
    }
}

/// GPU objects of the open window.
struct Gpu {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    ctx: GpuContext,
    shader: GpuShader,
    gathers: Vec<FormGather>,
    /// Per form, what the current shader reads of it for the current resolve.
    bind_groups: Vec<Option<crate::ShadeBinding>>,
    tonemap: ToneMap,
    overlay: Overlay,
    /// Timestamps of visibility, shade, tone map, overlay.
    frame_timer: Option<PassTimer>,
    gather_timers: Vec<Option<PassTimer>>,
    /// The surface texture can be copied (screenshots read the real frame).
    surface_copy: bool,
}

/// One form's gather on the GPU: `L* = T L`, or with light moments the three moment gathers
/// and the resolve into `L*'`.
enum FormGather {
    Plain(Box<GpuGather>),
    Moments(Box<GpuMoments>),
}

impl FormGather {
    /// What the shader reads, bound: `L*`, or with moments `L*'` or the three gathers
    /// (`resolve`).
    fn binding(&self, shader: &mut GpuShader, resolve: MomentsResolve) -> Result<crate::ShadeBinding> {
        match self {
            Self::Plain(g) => shader.shade_bind_group(g.lstar_buffer()),
            Self::Moments(m) => shader.moments_bind_group(m, resolve),
        }
    }

    /// Timestamp pairs one gather writes.
    fn pass_count(&self) -> usize {
        match self {
            Self::Plain(g) => g.pass_count(),
            Self::Moments(m) => m.pass_count(),
        }
    }

    /// Upload the light (or, with light moments, its three moments, which `validate` made sure
    /// the state has).
    fn upload(&mut self, light: &LightVector, moments: Option<&LightMoments>) -> Result<()> {
        match (self, moments) {
            (Self::Plain(g), _) => g.upload_light(light),
            (Self::Moments(m), Some(moments)) => m.upload(moments),
            (Self::Moments(_), None) => Err(GpuError::Input("light moments without the light's moments".into())),
        }
    }

    /// Record the gather (and resolve) with the light last uploaded.
    fn record(&self, enc: &mut wgpu::CommandEncoder, timer: Option<&PassTimer>) {
        match self {
            Self::Plain(g) => g.record(enc, timer),
            Self::Moments(m) => m.record(enc, timer),
        }
    }
}

/// The direction moments of `light` when `enabled` (the light is then in a cubemap basis,
/// which `ViewerSetup::validate` checked).
fn moments_of(light: &LightVector, enabled: bool) -> Result<Option<LightMoments>> {
    Ok(if enabled { Some(LightMoments::new(light)?) } else { None })
}

struct App {
    setup: ViewerSetup,
    /// Where every rotation's light comes from (shared with the light worker).
    source: Arc<LightSource>,
    proxy: EventLoopProxy<LightReady>,
    state: State,
    gpu: Option<Gpu>,
    error: Option<GpuError>,
    worker: Option<mpsc::Sender<f64>>,
    shift: bool,
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: GpuError) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        event_loop.exit();
    }

    fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let cam = self.setup.camera;
        let attrs = Window::default_attributes()
            .with_title(format!("biscale view: {}", self.setup.title))
            .with_inner_size(PhysicalSize::new(cam.width.max(1), cam.height.max(1)));
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| GpuError::Window(e.to_string()))?);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| GpuError::Window(format!("creating the surface: {e}")))?;
        let (ctx, adapter) = GpuContext::open(&instance, Some(&surface), crate::TimestampPolicy::Auto)?;
        let caps = surface.get_capabilities(&adapter);
        // An 8-bit format (the tone map's output is display-referred sRGB), preferring the
        // surface's own order; else whatever it offers first.
        let eight_bit = |f: &wgpu::TextureFormat| {
            matches!(
                f,
                wgpu::TextureFormat::Rgba8Unorm
                    | wgpu::TextureFormat::Rgba8UnormSrgb
                    | wgpu::TextureFormat::Bgra8Unorm
                    | wgpu::TextureFormat::Bgra8UnormSrgb
            )
        };
        let format =
            *caps.formats.iter().find(|f| eight_bit(f)).or(caps.formats.first()).ok_or_else(|| {
                GpuError::Window(format!("adapter {} cannot present to this window", ctx.adapter().name))
            })?;
        let surface_copy = caps.usages.contains(wgpu::TextureUsages::COPY_SRC) && eight_bit(&format);
        let size = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | if surface_copy { wgpu::TextureUsages::COPY_SRC } else { wgpu::TextureUsages::empty() },
            format,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps.alpha_modes.first().copied().unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        ctx.scoped("configuring the surface", || surface.configure(&ctx.device, &config))?;
        let shader = self.setup.shader(&ctx, self.state.orbit.camera(config.width, config.height))?;
        let moments = self.setup.light_moments;
        let gathers = self
            .setup
            .forms
            .iter()
            .map(|f| {
                let form = || -> Result<FormGather> {
                    let gather = GpuGather::new(&ctx, &f.form, &f.kernels)?;
                    Ok(match moments {
                        true => FormGather::Moments(Box::new(GpuMoments::new(gather, self.setup.scene.frames())?)),
                        false => FormGather::Plain(Box::new(gather)),
                    })
                };
                form().map_err(|e| GpuError::Form(format!("'{}': {e}", f.label)))
            })
            .collect::<Result<Vec<_>>>()?;
        let gather_timers =
            gathers.iter().map(|g| PassTimer::new(&ctx, g.pass_count() as u32)).collect::<Result<Vec<_>>>()?;
        let mut tonemap = ToneMap::new(&ctx, format)?;
        tonemap.set_environment(Some(&self.setup.env))?;
        let scale = window.scale_factor() as f32;
        let overlay = Overlay::new(&ctx, format, (15.0 * scale).round())?;
        let frame_timer = PassTimer::new(&ctx, 4)?;

        // The light worker: coalesces requests to the newest rotation.
        let (tx, rx) = mpsc::channel::<f64>();
        let proxy = self.proxy.clone();
        let source = self.source.clone();
        let with_moments = self.setup.light_moments;
        std::thread::Builder::new()
            .name("biscale-view-light".into())
            .spawn(move || {
                while let Ok(mut rotation) = rx.recv() {
                    while let Ok(r) = rx.try_recv() {
                        rotation = r;
                    }
                    let start = Instant::now();
                    let light = source.at(rotation);
                    // `validate` checked that the light basis is a cubemap: this cannot fail.
                    let moments = moments_of(&light, with_moments).expect("a cubemap light has moments");
                    let ms = start.elapsed().as_secs_f64() * 1e3;
                    if proxy.send_event(LightReady { rotation, light, moments, ms }).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| GpuError::Window(format!("starting the light worker: {e}")))?;
        self.worker = Some(tx);
        let n = gathers.len();
        self.gpu = Some(Gpu {
            window,
            surface,
            config,
            ctx,
            shader,
            gathers,
            bind_groups: vec![None; n],
            tonemap,
            overlay,
            frame_timer,
            gather_timers,
            surface_copy,
        });
        Ok(())
    }

    fn request_rotation(&mut self, rotation: f64) {
        self.state.requested_rotation = rotation.rem_euclid(std::f64::consts::TAU);
        if let Some(tx) = &self.worker {
            let _ = tx.send(self.state.requested_rotation);
        }
        self.redraw();
    }

    fn redraw(&self) {
        if let Some(g) = &self.gpu {
            g.window.request_redraw();
        }
    }
}

impl State {
    /// A light change is under way: a rotation is being recomputed, or every frame re-gathers.
    fn light_moving(&self) -> bool {
        self.continuous || (self.requested_rotation - self.light_rotation).abs() > 1e-12
    }
}

/// The overlay's text for the current state.
fn overlay_lines(setup: &ViewerSetup, s: &State, gpu: &Gpu) -> Vec<String> {
    let f = &setup.forms[s.form];
    let n = setup.forms.len();
    let a = gpu.ctx.adapter();
    let recent = |v: &[f64]| median(&v[v.len().saturating_sub(15)..]);
    let frame = recent(&s.frame_ms);
    let interval = recent(&s.fps_intervals);
    let mut lines = vec![
        format!("{} | {} ({}) | {}x{}", setup.title, a.name, a.backend, gpu.config.width, gpu.config.height),
        format!("[Tab] form {}/{n}: {} ({}, {:.2} MB)", s.form + 1, f.label, f.form.kind, f.form.bytes() as f64 / 1e6),
    ];
    let frame_text = if frame.is_finite() { format!("{frame:.1} ms") } else { "-".into() };
    let fps_text =
        if interval.is_finite() && s.continuous { format!(", {:.1} fps", 1e3 / interval) } else { String::new() };
    lines.push(format!(
        "frame {frame_text} (CPU+GPU, median of last {}{fps_text}){}",
        s.frame_ms.len().min(15),
        if s.continuous { "  [continuous: gather every frame]" } else { "" }
    ));
    let when = if s.gather_this_frame { "" } else { " (at the last light change)" };
    let what = if setup.light_moments { "gather (3 light moments + vertex resolve)" } else { "gather" };
    lines.push(match (s.last_gather_ms, s.last_gather_wall_ms) {
        (Some(g), Some(w)) => format!("{what} {g:.2} ms GPU, {w:.2} ms wall{when}"),
        (None, Some(w)) => format!("{what} {w:.2} ms wall{when}"),
        _ => format!("{what} -"),
    });
    match s.last_passes {
        Some([vis, shade, tone, text]) => lines.push(format!(
            "shade {:.2} ms GPU (visibility {vis:.2} + shade {shade:.2}), tone map {tone:.2} + text {text:.2} ms",
            vis + shade
        )),
        None if gpu.frame_timer.is_none() => lines.push("shade: no timestamp queries, no per-pass split".into()),
        None => lines.push("shade -".into()),
    }
    if setup.light_moments {
        let how = match s.resolve {
            MomentsResolve::Vertex => "per vertex, L*' blended",
            MomentsResolve::Pixel => "at every pixel, with the BTF tables",
            MomentsResolve::PixelAnalytic => "at every pixel, analytic BRDFs (tables where none)",
        };
        lines.push(format!("[M] resolve: {} ({how})", s.resolve.name()));
    }
    let pending = if (s.requested_rotation - s.light_rotation).abs() > 1e-12 { "  (recomputing...)" } else { "" };
    if setup.has_lpca() {
        lines.push(match (s.moving_components, s.light_moving()) {
            (None, _) => "LPCA BTFs: every component (C: fewer while the light moves)".into(),
            (Some(n), true) => format!("LPCA BTFs: {n} component(s) per cluster while the light moves"),
            (Some(n), false) => format!("LPCA BTFs: every component, {n} while the light moves"),
        });
    }
    let source = match s.light.basis() {
        LightBasis::Sh(_) => format!("L ({} SH coefficients) rotated in SH", s.light.len()),
        LightBasis::Cubemap(_) => format!("L ({} texels) from the map", s.light.len()),
    };
    lines.push(format!(
        "light: env rotation {:.0} deg, {source} in {:.1} ms{pending}, exposure {:+.1}",
        s.light_rotation.to_degrees(),
        s.light_ms,
        s.exposure
    ));
    lines.push("drag: orbit  wheel: zoom  right-drag, Left/Right: rotate env  Tab, 1-9: form".into());
    lines.push(
        "+/-: exposure  Space: continuous  B: background  C: LPCA components  M: resolve  R: reset  Esc, Q: quit"
            .into(),
    );
    lines
}

impl App {
    /// Render one frame; returns the captured image when this frame is the screenshot.
    fn render(&mut self) -> Result<Option<Rgba8Image>> {
        let capture = self.setup.screenshot.as_ref().is_some_and(|sh| self.state.frames + 1 >= sh.frames);
        let setup = &self.setup;
        let s = &mut self.state;
        let Some(gpu) = self.gpu.as_mut() else { return Ok(None) };
        let (w, h) = (gpu.config.width, gpu.config.height);
        // Resized: a shader for the new size (the camera's aspect follows the window).
        if gpu.shader.size() != (w, h) {
            gpu.shader = setup.shader(&gpu.ctx, s.orbit.camera(w, h))?;
            gpu.bind_groups.iter_mut().for_each(|b| *b = None);
        }
        let frame = match gpu.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => return Ok(None),
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                gpu.ctx.scoped("reconfiguring the surface", || gpu.surface.configure(&gpu.ctx.device, &gpu.config))?;
                gpu.window.request_redraw();
                return Ok(None);
            }
            other => return Err(GpuError::Window(format!("acquiring the next frame: {other:?}"))),
        };
        // Frame time: from after the acquire (which may wait for vsync) until the GPU is idle.
        let start = Instant::now();
        if let Some(prev) = s.last_frame_start.replace(start) {
            s.fps_intervals.push(prev.elapsed().as_secs_f64() * 1e3);
        }
        let i = s.form;
        gpu.shader.set_camera(&s.orbit.camera(w, h))?;
        gpu.shader.set_max_components(if s.light_moving() { s.moving_components } else { None })?;
        let gather = s.stale[i] || s.continuous;
        // The gather goes alone and is waited for, so that its wall-clock time is known too
        // (lavapipe's timestamps around short compute passes are unreliable).
        if gather {
            let t0 = Instant::now();
            let gather_timer = gpu.gather_timers[i].as_ref();
            gpu.gathers[i].upload(&s.light, s.moments.as_ref())?;
            gpu.ctx.scoped("running the gather", || {
                let mut genc = gpu.ctx.device.create_command_encoder(&Default::default());
                gpu.gathers[i].record(&mut genc, gather_timer);
                if let Some(t) = gather_timer {
                    t.resolve(&mut genc);
                }
                gpu.ctx.queue.submit([genc.finish()]);
            })?;
            gpu.ctx.wait("the gather")?;
            s.last_gather_wall_ms = Some(t0.elapsed().as_secs_f64() * 1e3);
            s.last_gather_ms = match gather_timer {
                Some(t) => Some(t.read_ms(&gpu.ctx)?.iter().sum()),
                None => None,
            };
            s.stale[i] = false;
        }
        s.gather_this_frame = gather;
        if gpu.bind_groups[i].is_none() {
            gpu.bind_groups[i] = Some(gpu.gathers[i].binding(&mut gpu.shader, s.resolve)?);
        }
        let lines = overlay_lines(setup, s, gpu);
        gpu.overlay.set_text(&lines);
        let view = frame.texture.create_view(&Default::default());
        let settings =
            ToneMapSettings { exposure: s.exposure, env_rotation: s.light_rotation as f32, background: s.background };
        let mut enc = gpu.ctx.device.create_command_encoder(&Default::default());
        let frame_timer = gpu.frame_timer.as_ref();
        let bind_group = gpu.bind_groups[i].as_ref().expect("built above");
        gpu.shader.set_resolve(bind_group)?;
        gpu.ctx.scoped("recording a frame", || gpu.shader.record(&mut enc, bind_group, frame_timer))?;
        gpu.tonemap.encode_timed(&mut enc, &gpu.shader, &view, (w, h), &settings, frame_timer.map(|t| (t, 2)))?;
        gpu.overlay.encode(&mut enc, &view, (w, h), frame_timer.map(|t| (t, 3)));
        if let Some(t) = frame_timer {
            t.resolve(&mut enc);
        }
        let shot = if capture && gpu.surface_copy {
            // The frame itself, copied from the surface texture before it is presented.
            Some(read_texture_rgba8(&gpu.ctx, enc, &frame.texture)?)
        } else {
            gpu.ctx.scoped("submitting a frame", || gpu.ctx.queue.submit([enc.finish()]))?;
            None
        };
        gpu.window.pre_present_notify();
        gpu.ctx.queue.present(frame);
        gpu.ctx.wait("a frame")?;
        s.frame_ms.push(start.elapsed().as_secs_f64() * 1e3);
        if let Some(t) = frame_timer {
            let ms = t.read_ms(&gpu.ctx)?;
            s.last_passes = Some([ms[0], ms[1], ms[2], ms[3]]);
        }
        for v in [&mut s.frame_ms, &mut s.fps_intervals] {
            if v.len() > 240 {
                v.drain(..120);
            }
        }
        s.frames += 1;
        if capture && shot.is_none() {
            // The surface cannot be copied: draw the same frame again into an 8-bit texture.
            let format = wgpu::TextureFormat::Rgba8UnormSrgb;
            let mut tonemap = ToneMap::new(&gpu.ctx, format)?;
            tonemap.set_environment(Some(&setup.env))?;
            let mut overlay = Overlay::new(&gpu.ctx, format, gpu.overlay.px())?;
            overlay.set_text(&lines);
            let texture = gpu.ctx.scoped("creating the screenshot target", || {
                gpu.ctx.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("screenshot"),
                    size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                    view_formats: &[],
                })
            })?;
            let view = texture.create_view(&Default::default());
            let mut enc = gpu.ctx.device.create_command_encoder(&Default::default());
            tonemap.encode(&mut enc, &gpu.shader, &view, (w, h), &settings)?;
            overlay.encode(&mut enc, &view, (w, h), None);
            return Ok(Some(read_texture_rgba8(&gpu.ctx, enc, &texture)?));
        }
        Ok(shot)
    }

    fn select_form(&mut self, i: usize) {
        if i < self.setup.forms.len() && i != self.state.form {
            self.state.form = i;
            self.redraw();
        }
    }

    fn key(&mut self, event_loop: &ActiveEventLoop, key: &Key, shift: bool) {
        let step = 15f64.to_radians();
        let n = self.setup.forms.len();
        match key {
            Key::Named(NamedKey::Escape) => event_loop.exit(),
            Key::Named(NamedKey::Tab) => {
                let next = if shift { (self.state.form + n - 1) % n } else { (self.state.form + 1) % n };
                self.select_form(next);
            }
            Key::Named(NamedKey::ArrowLeft) => self.request_rotation(self.state.requested_rotation - step),
            Key::Named(NamedKey::ArrowRight) => self.request_rotation(self.state.requested_rotation + step),
            Key::Named(NamedKey::Space) => {
                self.state.continuous = !self.state.continuous;
                self.redraw();
            }
            Key::Character(c) => match c.as_str() {
                "q" | "Q" => event_loop.exit(),
                "+" | "=" => {
                    self.state.exposure += 0.5;
                    self.redraw();
                }
                "-" | "_" => {
                    self.state.exposure -= 0.5;
                    self.redraw();
                }
                "b" | "B" => {
                    self.state.background = !self.state.background;
                    self.redraw();
                }
                "c" | "C" => {
                    self.state.moving_components = match self.state.moving_components {
                        None => Some(1),
                        Some(1) => Some(2),
                        Some(_) => None,
                    };
                    self.redraw();
                }
                "r" | "R" => {
                    self.state.orbit = self.state.home;
                    self.redraw();
                }
                "m" | "M" => {
                    let all = self.setup.resolves();
                    if let Some(k) = all.iter().position(|r| *r == self.state.resolve) {
                        self.state.resolve = all[(k + 1) % all.len()];
                        if let Some(gpu) = self.gpu.as_mut() {
                            gpu.bind_groups.iter_mut().for_each(|b| *b = None);
                        }
                        self.redraw();
                    }
                }
                d => {
                    if let Some(k) = d.parse::<usize>().ok().filter(|&k| k >= 1) {
                        self.select_form(k - 1);
                    }
                }
            },
            _ => {}
        }
    }
}

fn gpu_size(gpu: &Option<Gpu>) -> (u32, u32) {
    gpu.as_ref().map_or((1, 1), |g| (g.config.width.max(1), g.config.height.max(1)))
}

impl ApplicationHandler<LightReady> for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gpu.is_some() || self.error.is_some() {
            return;
        }
        if let Err(e) = self.init(event_loop) {
            self.fail(event_loop, e);
            return;
        }
        self.redraw();
    }

    fn user_event(&mut self, _event_loop: &ActiveEventLoop, ev: LightReady) {
        let s = &mut self.state;
        s.light = ev.light;
        s.moments = ev.moments;
        s.light_rotation = ev.rotation;
        s.light_ms = ev.ms;
        s.stale.iter_mut().for_each(|x| *x = true);
        self.redraw();
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(gpu) = self.gpu.as_mut() {
                    if size.width > 0 && size.height > 0 {
                        gpu.config.width = size.width;
                        gpu.config.height = size.height;
                        let r = gpu
                            .ctx
                            .scoped("resizing the surface", || gpu.surface.configure(&gpu.ctx.device, &gpu.config));
                        if let Err(e) = r {
                            self.fail(event_loop, e);
                            return;
                        }
                    }
                }
                self.redraw();
            }
            WindowEvent::ModifiersChanged(m) => self.shift = m.state().shift_key(),
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                let shift = self.shift;
                self.key(event_loop, &event.logical_key, shift);
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let down = state == ElementState::Pressed;
                match button {
                    MouseButton::Left => self.state.left = down,
                    MouseButton::Right => self.state.right = down,
                    _ => {}
                }
            }
            WindowEvent::CursorLeft { .. } => self.state.cursor = None,
            WindowEvent::CursorMoved { position, .. } => {
                let (x, y) = (position.x, position.y);
                if let Some((px, py)) = self.state.cursor.replace((x, y)) {
                    let (dx, dy) = (x - px, y - py);
                    let (w, h) = gpu_size(&self.gpu);
                    if self.state.left {
                        self.state.orbit.drag(dx, dy, h);
                        self.redraw();
                    }
                    if self.state.right && dx != 0.0 {
                        // A drag across the full width turns the environment once around.
                        self.request_rotation(self.state.requested_rotation + dx / w as f64 * std::f64::consts::TAU);
                    }
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                let min = self.state.min_distance;
                self.state.orbit.zoom(steps, min);
                self.redraw();
            }
            WindowEvent::RedrawRequested => match self.render() {
                Ok(shot) => {
                    if let Some(img) = shot {
                        let path =
                            self.setup.screenshot.as_ref().map(|s| s.path.clone()).expect("capture implies a path");
                        match write_png(&path, &img) {
                            Ok(()) => eprintln!("biscale view: wrote {}", path.display()),
                            Err(e) => return self.fail(event_loop, e),
                        }
                        event_loop.exit();
                    } else if self.state.continuous || self.setup.screenshot.is_some() {
                        self.redraw();
                    }
                }
                Err(e) => self.fail(event_loop, e),
            },
            _ => {}
        }
    }
}

/// Write `img` as an 8-bit RGB PNG.
fn write_png(path: &std::path::Path, img: &Rgba8Image) -> Result<()> {
    let rgb: Vec<u8> = img.pixels.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    let out = image::RgbImage::from_raw(img.width, img.height, rgb)
        .ok_or_else(|| GpuError::Input("screenshot buffer has the wrong size".into()))?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| GpuError::Window(format!("creating {}: {e}", dir.display())))?;
    }
    out.save(path).map_err(|e| GpuError::Window(format!("writing {}: {e}", path.display())))
}
