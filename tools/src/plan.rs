//! The planner (DESIGN.md section 5): from the experiment, decide which stages and data
//! dimensions are needed, and say what is left out and why. Printed before every run.

use crate::config::{CompressorConfig, Experiment, MaterialConfig, Sweep};
use std::fmt;

/// One compressor setting after sweep expansion.
#[derive(Clone, Debug, PartialEq)]
pub struct CompressorSetting {
    /// Label used for file names and report rows, e.g. `cpca-k32-c8`.
    pub label: String,
    pub config: CompressorConfig,
}

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
}

fn values<T: Clone>(s: &Option<Sweep<T>>, default: T) -> Vec<T> {
    s.as_ref().map(|s| s.0.clone()).unwrap_or_else(|| vec![default])
}

/// Expand every swept parameter into one setting per combination.
pub fn expand(c: &CompressorConfig) -> Vec<CompressorSetting> {
    match c {
        CompressorConfig::Sparse {} => vec![CompressorSetting { label: "sparse".into(), config: c.clone() }],
        CompressorConfig::Bicluster { block_vertices } => {
            let blocks: Vec<Option<usize>> = match block_vertices {
                Some(s) => s.0.iter().map(|&b| Some(b)).collect(),
                None => vec![None],
            };
            blocks
                .into_iter()
                .map(|b| CompressorSetting {
                    label: match b {
                        Some(b) => format!("bicluster-b{b}"),
                        None => "bicluster".into(),
                    },
                    config: CompressorConfig::Bicluster { block_vertices: b.map(|b| Sweep(vec![b])) },
                })
                .collect()
        }
        CompressorConfig::Cpca { clusters, components, iterations } => {
            let mut out = vec![];
            for k in values(clusters, 32) {
                for c in values(components, 8) {
                    out.push(CompressorSetting {
                        label: format!("cpca-k{k}-c{c}"),
                        config: CompressorConfig::Cpca {
                            clusters: Some(Sweep(vec![k])),
                            components: Some(Sweep(vec![c])),
                            iterations: *iterations,
                        },
                    });
                }
            }
            out
        }
        CompressorConfig::Plugin { path, .. } => vec![CompressorSetting {
            label: format!(
                "plugin-{}",
                path.file_stem().map(|s| s.to_string_lossy().trim_start_matches("lib").to_string()).unwrap_or_default()
            ),
            config: c.clone(),
        }],
        CompressorConfig::Haar { terms } => values(terms, 12)
            .into_iter()
            .map(|t| CompressorSetting {
                label: format!("haar-t{t}"),
                config: CompressorConfig::Haar { terms: Some(Sweep(vec![t])) },
            })
            .collect(),
    }
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
        }
        if materials.len() == 1 {
            step("btf", "material-id buffer".into(), Action::LeftOut("the scene has one material".into()));
        } else {
            step("btf", format!("material ids per triangle ({} materials)", materials.len()), Action::Run);
        }
        let mut compressors: Vec<CompressorSetting> = vec![];
        for c in &f.compressors {
            compressors.extend(expand(c.get_ref()));
        }
        for c in &compressors {
            step("compress", c.label.clone(), Action::Run);
        }
        for kind in ["sparse", "bicluster", "cpca", "haar"] {
            if !compressors.iter().any(|c| c.config.kind() == kind) {
                step("compress", kind.into(), Action::LeftOut("not named in the config".into()));
            }
        }
        step(
            "gather",
            format!("{} gather(s) on the {:?} backend", compressors.len() + 1, f.runtime.backend).to_lowercase(),
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
        Plan { steps, compressors, reference }
    }
}

impl fmt::Display for Plan {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        writeln!(f, "plan:")?;
        for s in &self.steps {
            match &s.action {
                Action::Run => writeln!(f, "  run   {:<10} {}", s.stage, s.what)?,
                Action::LeftOut(why) => writeln!(f, "  skip  {:<10} {} ({why})", s.stage, s.what)?,
            }
        }
        Ok(())
    }
}
