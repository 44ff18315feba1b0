//! The planner (docs/DESIGN.md section 5): from the experiment, decide which stages and data
//! dimensions are needed, and say what is left out and why. Printed before every run;
//! `biscale plan` adds the run's estimated peak memory ([`Plan::with_memory`]).

use crate::config::{CompressorSetting, Experiment, MaterialConfig};
use std::fmt;

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
    pub memory: Option<(crate::memory::RunMemory, crate::memory::Available)>,
}

impl Plan {
    pub fn new(exp: &Experiment) -> Plan {
        let f = &exp.file;
        let mut steps = vec![];
        let mut step = |stage, what: String, action| steps.push(Step { stage, what, action });
        let t = exp.transfer_settings();
        step(
            "sampling",
            match &exp.env_path {
                Some(p) => format!("light vector L from {} (6x{r}x{r})", p.display(), r = t.cubemap().resolution),
                None => format!("light vector L from a constant sky (6x{r}x{r})", r = t.cubemap().resolution),
            },
            Action::Run,
        );
        step(
            "transfer",
            format!(
                "T: visibility 6x{v}x{v} box-filtered to 6x{r}x{r}, local grid {m}x{m} (cached by content)",
                v = t.visibility_resolution(),
                r = t.cubemap().resolution,
                m = t.local_grid().m
            ),
            Action::Run,
        );
        let materials = exp.materials();
        for m in &materials {
            let label = m.label();
            match m {
                MaterialConfig::Lambertian { .. } => step(
                    "btf",
                    format!("{label}: view axis of the lambertian BTF"),
                    Action::LeftOut("a diffuse BTF is view-independent".into()),
                ),
                MaterialConfig::Phong { view_grid, .. } => {
                    step("btf", format!("{label}: phong BTF with {view_grid}x{view_grid} view directions"), Action::Run)
                }
                MaterialConfig::Synthesized(s) if s.amplitude == 0.0 && s.albedo_map.is_none() => step(
                    "btf",
                    format!("{label}: ray tracing of a flat patch"),
                    Action::LeftOut("tabulated analytically from the BRDF".into()),
                ),
                MaterialConfig::Synthesized(s) => {
                    let views = match s.view_grid {
                        0 => "no view axis (diffuse special case)".to_string(),
                        v => format!("{v}x{v} views"),
                    };
                    step(
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
                if let crate::config::BtfRepresentation::Lpca { clusters, components, .. } = *r {
                    let role = if i == 0 { "evaluated directly by every shader" } else { "compared in the BTF study" };
                    step(
                        "btf",
                        format!(
                            "{label}: local-PCA compression {} ({clusters} clusters x {components} eigen-BRDFs, cached by content); {role}",
                            r.label()
                        ),
                        Action::Run,
                    );
                }
            }
            if all.iter().any(|r| *r != crate::config::BtfRepresentation::Dense) {
                step(
                    "btf",
                    format!(
                        "{label}: BTF study of {} setting(s): image error against dense BTFs and the reference, shade time, precomputed dot products",
                        all.len()
                    ),
                    Action::Run,
                );
            }
        }
        if materials.len() == 1 {
            step("btf", "material-id buffer".into(), Action::LeftOut("the scene has one material".into()));
        } else {
            step("btf", format!("material ids per triangle ({} materials)", materials.len()), Action::Run);
        }
        let compressors: Vec<CompressorSetting> = exp.compressor_settings().to_vec();
        for c in &compressors {
            step("compress", c.label.clone(), Action::Run);
        }
        for kind in biscale_compressors::registry::KINDS.iter().map(|k| k.name).filter(|&k| k != "plugin") {
            if !compressors.iter().any(|c| c.kind == kind) {
                step("compress", kind.into(), Action::LeftOut("not named in the config".into()));
            }
        }
        // The diffuse special case, as far as the config tells (the run checks the tables).
        let diffuse = materials.iter().all(lambertian_config);
        for m in exp.method_settings() {
            let Ok(p) = crate::methods::sh::ShParams::parse(&m.params) else { continue };
            let n2 = p.order * p.order;
            let bounces = match p.bounces {
                0 => String::new(),
                b => format!(", {b} interreflection bounce(s)"),
            };
            step(
                "method",
                format!(
                    "{}: light in order-{} SH, M_p {n2}x{n2} per vertex by {} rays{bounces} (cached by content)",
                    m.label, p.order, p.rays
                ),
                Action::Run,
            );
            if diffuse {
                step(
                    "method",
                    format!("{}: {n2}x{n2} transfer matrices and per-pixel RTT lookups", m.label),
                    Action::LeftOut(format!(
                        "every material is Lambertian: shadowed diffuse PRT, a {n2}-vector per vertex"
                    )),
                );
            } else {
                step(
                    "method",
                    format!("{}: radiance transfer texture per material (the BTFs on order-{} SH)", m.label, p.order),
                    Action::Run,
                );
            }
        }
        step(
            "gather",
            format!(
                "{} gather(s) on the {:?} backend",
                compressors.len() + 1 + exp.method_settings().len(),
                f.runtime.backend
            )
            .to_lowercase(),
            Action::Run,
        );
        step("gather", "re-gathers for changing light".into(), Action::LeftOut("the light does not change".into()));
        step(
            "shade",
            format!(
                "{}x{} image per compressor plus the uncompressed T",
                f.runtime.width.get_ref(),
                f.runtime.height.get_ref()
            ),
            Action::Run,
        );
        let reference = f.report.reference;
        step(
            "reference",
            "ray-traced per-pixel visibility image".into(),
            if reference { Action::Run } else { Action::LeftOut("report.reference = false".into()) },
        );
        step("report", "metrics.json, report.md, images".into(), Action::Run);
        Plan { steps, compressors, reference, memory: None }
    }

    /// This plan with the run's memory estimate (`crate::memory`): loads the mesh and the
    /// light and traces the sample of vertices, as `biscale run` does before it starts (with
    /// the stage cache on, its default).
    pub fn with_memory(mut self, exp: &Experiment) -> crate::pipeline::Result<Plan> {
        let geometry = crate::pipeline::load_geometry(exp)?;
        let lighting = crate::pipeline::load_lighting(exp)?;
        let memory = crate::memory::estimate(exp, &geometry, &lighting, true);
        self.memory = Some((memory, crate::memory::available()?));
        Ok(self)
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
        if let Some((memory, available)) = &self.memory {
            write!(f, "{}", memory.summary(available))?;
            if memory.peak().bytes > available.bytes {
                writeln!(f, "  biscale run refuses this run: {}", memory.advice())?;
            }
        }
        Ok(())
    }
}

/// True when a material entry is Lambertian in shape for certain: analytic Lambertian, or a
/// flat synthesized patch with a Lambertian BRDF (with or without an albedo map).
fn lambertian_config(m: &MaterialConfig) -> bool {
    match m {
        MaterialConfig::Lambertian { .. } => true,
        MaterialConfig::Phong { .. } => false,
        MaterialConfig::Synthesized(s) => {
            s.amplitude == 0.0 && matches!(s.brdf, crate::config::BrdfConfig::Lambertian { .. })
        }
    }
}
