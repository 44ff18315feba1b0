//! The "ours" figures: each one read off a run's `metrics.json` record ([`Metrics`]) by one
//! definition, the one the tables' captions state. Nothing here is measured or assumed: a
//! figure the record cannot give is an error saying why, which the tables print instead.

use crate::metrics::{CompressorRecord, Metrics};
use biscale_compressors::registry::{self, Role};

/// A figure of Tables I and II.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Figure {
    Width,
    Height,
    Vertices,
    Btfs,
    BtfMb,
    NnzM,
    NnzPerVertex,
    Mflops,
    ReducedMflops,
    ComputationPct,
    DataMb,
    ReducedMb,
    DataPct,
    PrecomputeMin,
    FpsFixedLight,
    FpsMovingLight,
    /// The frame-time model's projected floors of the paper's form on the named GPU class
    /// (`metrics.json`'s `frame_model`), as frame rates: ceilings, not measurements.
    ProjectedFpsFixedLight,
    ProjectedFpsMovingLight,
}

impl Figure {
    /// `numbers.csv`'s row key, the tables' label, unit and decimals.
    pub fn describe(self) -> (&'static str, &'static str, &'static str, usize) {
        use Figure::*;
        match self {
            Width => ("width", "image width", "px", 0),
            Height => ("height", "image height", "px", 0),
            Vertices => ("vertices", "vertices", "", 0),
            Btfs => ("btfs", "BTFs", "", 0),
            BtfMb => ("btf_size", "BTF size", "MB", 1),
            NnzM => ("nnz", "nnz(T)", "M", 2),
            NnzPerVertex => ("nnz_per_vertex", "nnz(T) per vertex", "", 0),
            Mflops => ("mflops", "MFLOPs", "M", 2),
            ReducedMflops => ("reduced_mflops", "reduced to", "M", 2),
            ComputationPct => ("computation", "computation", "%", 1),
            DataMb => ("data_size", "data size", "MB", 0),
            ReducedMb => ("reduced_size", "reduced to", "MB", 2),
            DataPct => ("data_size_pct", "data size", "%", 2),
            PrecomputeMin => ("precompute", "precomputation", "min", 2),
            FpsFixedLight => ("fps_fixed_light", "fps, fixed light, moving view", "fps", 1),
            FpsMovingLight => ("fps_moving_light", "fps, moving light and view", "fps", 1),
            ProjectedFpsFixedLight => {
                ("projected_fps_fixed_light", "fps ceiling, fixed light (projected H100-class floor)", "fps", 0)
            }
            ProjectedFpsMovingLight => {
                ("projected_fps_moving_light", "fps ceiling, moving light (projected H100-class floor)", "fps", 0)
            }
        }
    }
}

/// Where a run's precomputation time comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum TransferTime {
    /// This run traced `T` in this many seconds.
    Measured(f64),
    /// `T` came from the stage cache; an earlier `biscale reproduce` into the same folder
    /// traced it in this many seconds, at `measured_at` (`precompute.json`).
    Earlier { seconds: f64, measured_at: String },
    /// `T` came from the stage cache and no earlier trace of it is known.
    Unknown,
}

impl TransferTime {
    pub fn seconds(&self) -> Option<f64> {
        match self {
            Self::Measured(s) | Self::Earlier { seconds: s, .. } => Some(*s),
            Self::Unknown => None,
        }
    }
}

/// The lossless setting of the paper's compressor (lossless biclustering) in `m`.
pub fn paper_form(m: &Metrics) -> Option<&CompressorRecord> {
    m.compressors.iter().find(|c| registry::role_of(&c.kind) == Role::Paper && c.lossless)
}

/// A run's record and how long its `T` took to trace.
pub struct RunFacts<'a> {
    pub metrics: &'a Metrics,
    pub transfer: TransferTime,
}

impl RunFacts<'_> {
    /// The lossless setting of the paper's compressor (lossless biclustering).
    pub fn paper_form(&self) -> Option<&CompressorRecord> {
        paper_form(self.metrics)
    }

    fn stat(&self, key: &str) -> Result<f64, String> {
        let form = self.paper_form().ok_or("no lossless biclustering ran")?;
        form.stats
            .as_ref()
            .and_then(|s| s.get(key))
            .and_then(serde_json::Value::as_f64)
            .ok_or_else(|| format!("{}'s record has no stats.{key}", form.name))
    }

    /// A setting of the config the run ran (`run.config_text`), when it sets it.
    fn config_u64(&self, table: &str, key: &str) -> Option<u64> {
        let text = &self.metrics.run.as_ref()?.config_text;
        let v: toml::Value = toml::from_str(text).ok()?;
        v.get(table)?.get(key)?.as_integer().and_then(|i| u64::try_from(i).ok())
    }

    /// The figure, by the definition the captions state.
    pub fn value(&self, f: Figure) -> Result<f64, String> {
        use Figure::*;
        let m = self.metrics;
        let form = || self.paper_form().ok_or_else(|| "no lossless biclustering ran".to_string());
        Ok(match f {
            // The config's [runtime] size (biscale's defaults, 640x480, when it does not set it).
            Width => self.config_u64("runtime", "width").unwrap_or(640) as f64,
            Height => self.config_u64("runtime", "height").unwrap_or(480) as f64,
            Vertices => m.scene.vertices as f64,
            Btfs => m.scene.btfs.iter().filter(|b| b.primary).count() as f64,
            BtfMb => m.scene.btf_bytes as f64 / 1e6,
            NnzM => m.transfer.nnz as f64 / 1e6,
            NnzPerVertex => m.transfer.nnz as f64 / (m.scene.vertices.max(1)) as f64,
            Mflops => self.stat("mflops_raw")?,
            ReducedMflops => self.stat("mflops_biclustered")?,
            ComputationPct => 100.0 * self.stat("flops_ratio")?,
            DataMb => self.stat("dense_bytes")? / 1e6,
            ReducedMb => form()?.bytes as f64 / 1e6,
            DataPct => 100.0 * form()?.bytes as f64 / self.stat("dense_bytes")?,
            PrecomputeMin => {
                let t = self.transfer.seconds().ok_or(
                    "T came from the stage cache and its trace time is not recorded (run with a fresh --cache-dir)",
                )?;
                (t + form()?.build_seconds) / 60.0
            }
            FpsFixedLight => 1000.0 / form()?.shade_ms,
            FpsMovingLight => {
                let b = form()?;
                1000.0 / (b.gather_ms + b.shade_ms)
            }
            ProjectedFpsFixedLight | ProjectedFpsMovingLight => {
                let name = form()?.name.clone();
                let model =
                    m.frame_model.as_ref().ok_or("the run's record has no frame-time model (made before it)")?;
                let f_model = model.forms.iter().find(|f| f.name == name).ok_or("no frame-time model of the form")?;
                let ms = match f {
                    ProjectedFpsFixedLight => f_model.shade.projected_ms,
                    _ => f_model.gather.projected_ms + f_model.shade.projected_ms,
                };
                1000.0 / ms
            }
        })
    }

    /// What a reader must know of a figure beside its value (the precomputation of a run
    /// whose `T` or form came from the cache).
    /// The load a timed figure was taken under: the runtime's steps' (`metrics.json` `load`)
    /// for the frame rates, the whole run's (`run.load_average_start`/`_end`) for the
    /// precomputation; `(peak 1-minute load, CPUs)`, `None` for a figure that is not a time or
    /// a record without the reading.
    pub fn load_of(&self, f: Figure) -> Option<(f64, usize)> {
        let m = self.metrics;
        match f {
            Figure::FpsFixedLight | Figure::FpsMovingLight => m.load.and_then(|l| l.peak().map(|p| (p, l.cpus_online))),
            Figure::PrecomputeMin => m.run.as_ref().and_then(|r| {
                let peak =
                    [r.load_average_start, r.load_average_end].into_iter().flatten().map(|l| l[0]).reduce(f64::max)?;
                Some((peak, r.cores))
            }),
            _ => None,
        }
    }

    /// Whether figure `f` is a time taken while the load exceeded the machine's CPUs: then
    /// every table marks it and `numbers.csv` says so ([`super::tables::Cell::busy`]).
    pub fn busy(&self, f: Figure) -> bool {
        self.load_of(f).is_some_and(|(load, cpus)| load > cpus as f64)
    }

    pub fn note(&self, f: Figure) -> Option<String> {
        let mut notes = vec![];
        if let Some((load, cpus)) = self.load_of(f) {
            notes.push(format!("timed at load {load:.1} on {cpus} CPUs"));
        }
        if f != Figure::PrecomputeMin {
            return (!notes.is_empty()).then(|| notes.join("; "));
        }
        if let TransferTime::Earlier { measured_at, .. } = &self.transfer {
            notes.push(format!("T from the stage cache; traced by the earlier reproduce of {measured_at}"));
        }
        if let Some(b) = self.paper_form().filter(|b| b.cached) {
            notes.push(format!("{} from the stage cache; its build time as measured when it was built", b.name));
        }
        (!notes.is_empty()).then(|| notes.join("; "))
    }
}
