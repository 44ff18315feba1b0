//! The planner (docs/DESIGN.md section 5): from the experiment, decide which stages and data
//! dimensions are needed, and say what is left out and why. Printed before every run;
//! `biscale plan` adds the run's estimated peak memory and, stage by stage, what the cache
//! already holds and how big each output it would write is ([`Plan::with_estimates`]).

use crate::estimate::human;
use crate::experiment::config::{CompressorSetting, Experiment, MaterialConfig};
use crate::store::cache::StageCache;
use crate::store::RunOptions;
use biscale_shading::synth::BtfEncoding;
use std::fmt;
use std::path::PathBuf;

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Action {
    Run,
    LeftOut(String),
}

#[derive(Clone, Debug)]
pub struct Step {
    pub stage: &'static str,
    pub what: String,
    pub action: Action,
}

#[derive(Clone, Debug)]
pub struct Plan {
    pub steps: Vec<Step>,
    pub compressors: Vec<CompressorSetting>,
    pub reference: bool,
    /// The estimated memory of the run and the memory available, when asked for.
    pub memory: Option<(crate::estimate::RunMemory, crate::estimate::Available)>,
    /// What the stage cache holds of this run's outputs, when asked for.
    pub cache: CacheReport,
}

/// The stage cache as a run with given options would find it.
#[derive(Clone, Debug, Default)]
pub enum CacheReport {
    /// Not looked at (the plan printed before a run).
    #[default]
    NotChecked,
    /// `--no-cache`: every stage is built and nothing is written.
    Off,
    /// The cache folder and each cacheable output of the run, in run order.
    Dir { dir: PathBuf, outputs: Vec<CachedOutput> },
}

/// One output the stage cache can hold.
#[derive(Clone, Debug)]
pub struct CachedOutput {
    pub stage: &'static str,
    pub what: String,
    pub state: CacheState,
}

/// Whether a run would load an output or build it, and its size.
#[derive(Clone, Debug, PartialEq)]
pub enum CacheState {
    /// In the cache: the run loads it (after checking the key the file carries).
    Cached { path: PathBuf, bytes: u64 },
    /// Not in the cache: the run builds it and writes a file of about `estimate` bytes
    /// (`None`: no estimate, e.g. a plugin's form).
    Build { path: PathBuf, estimate: Option<u64> },
    /// Its key is the content of an earlier stage's output, known only once that is built.
    KeyLater(String),
}

impl CacheState {
    /// `path`'s state: cached with its size on disk if it is a file, else built.
    fn of(path: PathBuf, estimate: Option<u64>) -> Self {
        match std::fs::metadata(&path) {
            Ok(m) if m.is_file() => CacheState::Cached { path, bytes: m.len() },
            _ => CacheState::Build { path, estimate },
        }
    }
}

impl Plan {
    pub fn new(exp: &Experiment) -> Plan {
        let f = &exp.file;
        let mut steps = vec![];
        let t = exp.transfer_settings();
        push(
            &mut steps,
            "sampling",
            match &exp.env_path {
                Some(p) => format!("light vector L from {} (6x{r}x{r})", p.display(), r = t.cubemap().resolution),
                None => format!("light vector L from a constant sky (6x{r}x{r})", r = t.cubemap().resolution),
            },
            Action::Run,
        );
        push(
            &mut steps,
            "transfer",
            format!(
                "T: visibility 6x{v}x{v} by {how}, box-filtered to 6x{r}x{r}, local grid {m}x{m} (cached by content)",
                v = t.visibility_resolution(),
                how = t.visibility().name(),
                r = t.cubemap().resolution,
                m = t.local_grid().m
            ),
            Action::Run,
        );
        let materials = exp.materials();
        for m in &materials {
            material_steps(m, &t, f.runtime.resolve_analytic(), &mut steps);
        }
        if materials.len() == 1 {
            push(&mut steps, "btf", "material-id buffer".into(), Action::LeftOut("the scene has one material".into()));
        } else {
            push(&mut steps, "btf", format!("material ids per triangle ({} materials)", materials.len()), Action::Run);
        }
        let compressors: Vec<CompressorSetting> = exp.compressor_settings().to_vec();
        for c in &compressors {
            push(&mut steps, "compress", c.label.clone(), Action::Run);
        }
        for kind in biscale_compressors::registry::KINDS
            .iter()
            .filter(|k| k.role != biscale_compressors::registry::Role::External)
            .map(|k| k.name)
        {
            if !compressors.iter().any(|c| c.kind == kind) {
                push(&mut steps, "compress", kind.into(), Action::LeftOut("not named in the config".into()));
            }
        }
        // The diffuse special case, as far as the config tells (the run checks the tables).
        let diffuse = materials.iter().all(lambertian_config);
        for m in exp.method_settings() {
            method_steps(m, diffuse, &mut steps);
        }
        push(
            &mut steps,
            "gather",
            format!(
                "{} gather(s) on the {:?} backend",
                compressors.len() + 1 + exp.method_settings().len(),
                f.runtime.backend
            )
            .to_lowercase(),
            Action::Run,
        );
        let a = &f.runtime.animation;
        match a.any() {
            false => push(
                &mut steps,
                "gather",
                "re-gathers for changing light".into(),
                Action::LeftOut("the light does not change ([runtime.animation] turns it)".into()),
            ),
            true => {
                let settings = match a.settings.is_empty() {
                    true => "every compressor setting".to_string(),
                    false => a.settings.join(", "),
                };
                push(
                    &mut steps,
                    "animate",
                    format!(
                        "{} frames of the light turned about +Y, {} of the camera orbited: the uncompressed T and \
                         {settings}, on the cpu, into animated PNGs",
                        a.light_frames, a.camera_frames
                    ),
                    Action::Run,
                )
            }
        }
        push(
            &mut steps,
            "shade",
            format!(
                "{}x{} image per compressor plus the uncompressed T",
                f.runtime.width.get_ref(),
                f.runtime.height.get_ref()
            ),
            Action::Run,
        );
        let reference = f.report.reference;
        push(
            &mut steps,
            "reference",
            "ray-traced per-pixel visibility image (cached by content)".into(),
            if reference { Action::Run } else { Action::LeftOut("report.reference = false".into()) },
        );
        push(&mut steps, "report", "metrics.json, report.md, images".into(), Action::Run);
        Plan { steps, compressors, reference, memory: None, cache: CacheReport::NotChecked }
    }

    /// This plan with the run's memory estimate (`crate::estimate`) and what the stage cache
    /// of `opts` holds of its outputs: loads the mesh and the light and traces the sample of
    /// vertices, as `biscale run` does before it starts.
    pub fn with_estimates(mut self, exp: &Experiment, opts: &RunOptions) -> crate::error::Result<Plan> {
        let geometry = crate::stages::scene::load_geometry(exp)?;
        let lighting = crate::stages::scene::load_lighting(exp)?;
        let cache = StageCache::new(opts, std::path::Path::new("."));
        let memory = crate::estimate::estimate(exp, &geometry, &lighting, cache.is_some());
        self.cache = match &cache {
            None => CacheReport::Off,
            Some(c) => CacheReport::Dir {
                dir: c.dir().to_path_buf(),
                outputs: cached_outputs(exp, &geometry, &lighting, &self.compressors, self.reference, &memory, c)?,
            },
        };
        self.memory = Some((memory, crate::estimate::available()?));
        Ok(self)
    }
}

fn push(steps: &mut Vec<Step>, stage: &'static str, what: String, action: Action) {
    steps.push(Step { stage, what, action });
}

/// The steps that build material `m`'s BTF (and its local-PCA forms and study); `analytic`:
/// the run resolves light moments with the analytic BRDF (`moments_resolve =
/// "pixel_analytic"`).
fn material_steps(
    m: &MaterialConfig,
    t: &biscale_core::transfer::TransferSettings,
    analytic: bool,
    steps: &mut Vec<Step>,
) {
    let label = m.label();
    match m {
        MaterialConfig::Lambertian { .. } => push(
            steps,
            "btf",
            format!("{label}: view axis of the lambertian BTF"),
            Action::LeftOut("a diffuse BTF is view-independent".into()),
        ),
        MaterialConfig::Phong { view_grid, .. } => {
            push(steps, "btf", format!("{label}: phong BTF with {view_grid}x{view_grid} view directions"), Action::Run)
        }
        MaterialConfig::Bonn(b) => {
            let views = match b.view_grid {
                0 => "the view nearest the normal (no view axis)".to_string(),
                v => format!("{v}x{v} views"),
            };
            push(
                steps,
                "btf",
                format!(
                    "{label}: resample the measured BTF in {} to {r}x{r} texels x {views} x {m}x{m} lights",
                    b.path.display(),
                    r = b.resolution,
                    m = t.local_grid().m
                ),
                Action::Run,
            )
        }
        MaterialConfig::Synthesized(s) if s.amplitude == 0.0 && s.albedo_map.is_none() => {
            push(
                steps,
                "btf",
                format!("{label}: ray tracing of a flat patch"),
                Action::LeftOut("tabulated analytically from the BRDF".into()),
            );
            if analytic && s.view_grid > 0 {
                // What the tables still serve, so a reader does not raise view_grid for it.
                push(
                    steps,
                    "btf",
                    format!("{label}: the {v}x{v}-view tables in the analytic resolve", v = s.view_grid),
                    Action::LeftOut(
                        "it evaluates the BRDF at the pixel's exact view, on the CPU and the GPU; the tables \
                         serve only the paper's bin-mean image, so view_grid does not change the moments' images"
                            .into(),
                    ),
                );
            }
        }
        MaterialConfig::Synthesized(s) => {
            let views = match s.view_grid {
                0 => "no view axis (diffuse special case)".to_string(),
                v => format!("{v}x{v} views"),
            };
            push(
                steps,
                "btf",
                format!(
                    "{label}: synthesize {r}x{r} texels x {views} x {m}x{m} lights (cached by content)",
                    r = s.resolution,
                    m = t.local_grid().m
                ),
                Action::Run,
            )
        }
    }
    let all = m.representations().all();
    for (i, r) in all.iter().enumerate() {
        if let crate::experiment::config::RepresentationSetting::Lpca(biscale_core::scene::LpcaSettings {
            clusters,
            components,
            ..
        }) = *r
        {
            let role = if i == 0 { "evaluated directly by every shader" } else { "compared in the BTF study" };
            push(
                steps,
                "btf",
                format!(
                    "{label}: local-PCA compression {} ({clusters} clusters x {components} eigen-BRDFs, cached by content); {role}",
                    r.label()
                ),
                Action::Run,
            );
        }
    }
    if all.iter().any(|r| *r != crate::experiment::config::RepresentationSetting::Dense) {
        push(
            steps,
            "btf",
            format!(
                "{label}: BTF study of {} setting(s): image error against dense BTFs and the reference, shade time, precomputed dot products",
                all.len()
            ),
            Action::Run,
        );
    }
}

/// The steps of one `[[methods]]` setting; `diffuse` when every material is Lambertian.
fn method_steps(m: &crate::experiment::config::Setting, diffuse: bool, steps: &mut Vec<Step>) {
    let Ok(p) = crate::experiment::methods::sh::ShParams::parse(&m.params) else { return };
    let n2 = p.order * p.order;
    let bounces = match p.bounces {
        0 => String::new(),
        b => format!(", {b} interreflection bounce(s)"),
    };
    push(
        steps,
        "method",
        format!(
            "{}: light in order-{} SH, M_p {n2}x{n2} per vertex by {} rays{bounces} (cached by content)",
            m.label, p.order, p.rays
        ),
        Action::Run,
    );
    if diffuse {
        push(
            steps,
            "method",
            format!("{}: {n2}x{n2} transfer matrices and per-pixel RTT lookups", m.label),
            Action::LeftOut(format!("every material is Lambertian: shadowed diffuse PRT, a {n2}-vector per vertex")),
        );
    } else {
        push(
            steps,
            "method",
            format!("{}: radiance transfer texture per material (the BTFs on order-{} SH)", m.label, p.order),
            Action::Run,
        );
    }
}

/// Each output of the run that the stage cache keys, in run order: `T`, the synthesized
/// BTFs and their local-PCA fits, the reference (with `reference`), each compressed form,
/// each SH method's direct transfer. Keys are computed exactly as the run computes them, so
/// "cached" means the run loads it.
#[allow(clippy::too_many_arguments)]
fn cached_outputs(
    exp: &Experiment,
    geometry: &crate::stages::scene::Geometry,
    lighting: &crate::stages::scene::Lighting,
    compressors: &[CompressorSetting],
    reference: bool,
    memory: &crate::estimate::RunMemory,
    cache: &StageCache,
) -> crate::error::Result<Vec<CachedOutput>> {
    let mesh = &geometry.mesh;
    let mut out = vec![];
    let settings = exp.transfer_settings();
    let t_key = crate::store::cache::transfer_key(mesh, &settings);
    out.push(CachedOutput {
        stage: "transfer",
        what: format!("T (about {} non-zeros)", memory.nnz.expected),
        state: CacheState::of(cache.transfer_path(&t_key), Some(memory.transfer.file_bytes)),
    });
    let local = settings.local_basis();
    for m in exp.materials() {
        let label = m.label();
        if let MaterialConfig::Synthesized(s) = &m {
            let key = crate::stages::materials::synth_key(s, local)?;
            let bytes = BtfEncoding::from_name(&s.encoding).map_or(4, BtfEncoding::value_bytes);
            let views = (s.view_grid as u64 * s.view_grid as u64).max(1);
            let values = s.resolution as u64 * s.resolution as u64 * views * local.len() as u64;
            out.push(CachedOutput {
                stage: "btf",
                what: format!("{label}: synthesized table"),
                state: CacheState::of(cache.btf_path(&key, &s.encoding), Some(values * 3 * bytes)),
            });
        }
        for r in m.representations().all() {
            if let crate::experiment::config::RepresentationSetting::Lpca(_) = r {
                out.push(CachedOutput {
                    stage: "btf",
                    what: format!("{label}: local-PCA fit {}", r.label()),
                    state: CacheState::KeyLater("keyed by the BTF's values".into()),
                });
            }
        }
    }
    if reference {
        out.push(reference_output(exp, geometry, lighting, cache)?);
    }
    for (setting, mem) in compressors.iter().zip(&memory.compressors) {
        let compressor = crate::stages::transfer::build_compressor(setting)?;
        let state = match crate::store::cache::form_key(&t_key, compressor.as_ref(), exp.file.seed) {
            Some(key) => CacheState::of(cache.form_path(&key, &setting.label), Some(mem.form)),
            None => CacheState::KeyLater("this build cannot identify itself, so forms are not cached".into()),
        };
        out.push(CachedOutput { stage: "compress", what: setting.label.clone(), state });
    }
    for m in exp.method_settings() {
        let Ok(p) = crate::experiment::methods::sh::ShParams::parse(&m.params) else { continue };
        let Ok(sh) = biscale_core::transfer::sh::ShTransferSettings::new(p.order, p.rays, exp.file.seed) else {
            continue;
        };
        let key = crate::store::cache::sh_transfer_key(mesh, &sh, 0, 0);
        // The file holds the CSR of the dense n^2 x n^2 blocks, laid out as T's file.
        let n2 = (p.order * p.order) as u64;
        let rows = mesh.vertex_count() as u64 * n2;
        let estimate = biscale_core::transfer::TransferMemory::file_bytes_of(rows, rows * n2);
        out.push(CachedOutput {
            stage: "method",
            what: format!("{}: direct SH transfer M", m.label),
            state: CacheState::of(cache.sh_transfer_path(&key, sh.order().n()), Some(estimate)),
        });
    }
    Ok(out)
}

/// The reference image as the cache holds it. Its key hashes the materials' tables as the run
/// shades them, so it is computed here only where they are analytic (Lambertian and Phong,
/// held dense: tabulated in no time, nothing built or written); otherwise it is known once the
/// run has built them.
fn reference_output(
    exp: &Experiment,
    geometry: &crate::stages::scene::Geometry,
    lighting: &crate::stages::scene::Lighting,
    cache: &StageCache,
) -> crate::error::Result<CachedOutput> {
    use crate::experiment::config::RepresentationSetting;
    let (w, h) = {
        let camera = geometry.camera(exp, *exp.file.report.reference_downscale.get_ref());
        (camera.width, camera.height)
    };
    let what = format!("ground truth {w}x{h}");
    let analytic = exp.materials().iter().all(|m| {
        matches!(m, MaterialConfig::Lambertian { .. } | MaterialConfig::Phong { .. })
            && m.representations().all().iter().all(|r| *r == RepresentationSetting::Dense)
    });
    if !analytic {
        let why = "keyed by the materials' tables, known once they are built";
        return Ok(CachedOutput { stage: "reference", what, state: CacheState::KeyLater(why.into()) });
    }
    let local = exp.transfer_settings().local_basis();
    let materials = crate::stages::materials::load_materials(exp, &geometry.mesh, local, None)?;
    let scene = biscale_core::scene::ShadeScene::new(
        geometry.mesh.clone(),
        geometry.transfer.frames().to_vec(),
        materials.materials,
        materials.triangle_materials,
    )?;
    let analytic = materials.analytic;
    let (camera, key) = crate::stages::evaluate::reference_key_of(exp, geometry, lighting, &scene, &analytic);
    // f32 RGB, a byte of mask and with several samples an f32 of coverage per pixel.
    let pixels = camera.width as u64 * camera.height as u64;
    let estimate = pixels * (12 + 1 + if camera.samples_per_pixel > 1 { 4 } else { 0 }) + 512;
    Ok(CachedOutput { stage: "reference", what, state: CacheState::of(cache.reference_path(&key), Some(estimate)) })
}

impl Plan {
    /// The transfer step, when `T` is not traced here (a shard merge): `what` says where it
    /// comes from.
    pub fn transfer_from(&mut self, what: String) {
        if let Some(s) = self.steps.iter_mut().find(|s| s.stage == "transfer") {
            s.what = what;
        }
    }
}

impl fmt::Display for Plan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "plan:")?;
        for s in &self.steps {
            match &s.action {
                Action::Run => writeln!(f, "  run   {:<10} {}", s.stage, s.what)?,
                Action::LeftOut(why) => writeln!(f, "  skip  {:<10} {} ({why})", s.stage, s.what)?,
            }
        }
        match &self.cache {
            CacheReport::NotChecked => {}
            CacheReport::Off => writeln!(f, "cache: off (--no-cache): every stage is built, nothing is written")?,
            CacheReport::Dir { dir, outputs } => {
                let (hit, bytes) = outputs.iter().fold((0, 0), |(n, b), o| match o.state {
                    CacheState::Cached { bytes, .. } => (n + 1, b + bytes),
                    _ => (n, b),
                });
                writeln!(f, "cache {} ({hit} of {} outputs cached, {}):", dir.display(), outputs.len(), human(bytes))?;
                for o in outputs {
                    let what = format!("{:<10} {}", o.stage, o.what);
                    match &o.state {
                        CacheState::Cached { path, bytes } => {
                            writeln!(f, "  load  {what:<56} {:>10}  {}", human(*bytes), file_name(path))?
                        }
                        CacheState::Build { path, estimate } => {
                            let size = estimate.map_or("?".to_string(), |b| format!("~{}", human(b)));
                            writeln!(f, "  build {what:<56} {size:>10}  {}", file_name(path))?
                        }
                        CacheState::KeyLater(why) => writeln!(f, "  ?     {what:<56} {:>10}  ({why})", "")?,
                    }
                }
            }
        }
        if let Some((memory, available)) = &self.memory {
            write!(f, "{}", memory.summary(available))?;
            if memory.peak().bytes > available.bytes {
                writeln!(f, "  biscale run refuses this run: {}", memory.advice())?;
            }
        }
        Ok(())
    }
}

fn file_name(path: &std::path::Path) -> String {
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// True when a material entry is Lambertian in shape for certain: analytic Lambertian, or a
/// flat synthesized patch with a Lambertian BRDF (with or without an albedo map).
fn lambertian_config(m: &MaterialConfig) -> bool {
    match m {
        MaterialConfig::Lambertian { .. } => true,
        MaterialConfig::Phong { .. } | MaterialConfig::Bonn(_) => false,
        MaterialConfig::Synthesized(s) => {
            s.amplitude == 0.0 && matches!(s.brdf, biscale_shading::synth::Brdf::Lambertian { .. })
        }
    }
}
