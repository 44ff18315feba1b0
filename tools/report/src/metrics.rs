//! The `metrics.json` schema (one file per run). Field names are stable: later issues add
//! fields, never rename them. See the README's "Output folder" section.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

#[derive(Debug, Serialize, Deserialize)]
pub struct Metrics {
    /// [`SCHEMA_VERSION`].
    pub schema_version: u32,
    pub experiment: String,
    pub config: String,
    pub backend: biscale_shading::runtime::Backend,
    pub scene: SceneMetrics,
    pub lighting: LightingMetrics,
    pub transfer: TransferMetrics,
    /// Gather and shade of the uncompressed `T` (the image every compressor is compared with).
    pub uncompressed: UncompressedMetrics,
    /// Present when the reference image was traced.
    pub reference: Option<ReferenceMetrics>,
    pub compressors: Vec<CompressorRecord>,
    /// One record per `[[methods]]` setting (the low-frequency method, ...).
    pub methods: Vec<MethodRecord>,
    /// Error target of the equal-quality comparison (`report.target_error`).
    pub target_error: f64,
    /// The run's memory: the estimate it was admitted with and the peak it measured.
    pub memory: Option<MemoryMetrics>,
    /// Present when `T` came from a sharded precompute (`biscale shard merge`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sharded: Option<ShardedMetrics>,
    /// How the run was made (the pipeline's `provenance`).
    pub run: Option<RunRecord>,
    /// The report's comparison figures: the inset region and each row's thumbnail, inset and
    /// error against the ground truth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub figures: Option<ComparisonFigures>,
    /// The machine's load around the timed steps (absent in older records and off Linux).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load: Option<LoadRecord>,
    /// The animated comparisons (`[runtime.animation]`), one per path; absent without.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub animations: Vec<AnimationRecord>,
    /// The tone map every PNG of the run was written with (absent in older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tone_map: Option<ToneMapRecord>,
    /// Each form's frame-time model: its stages' bytes and flops, their floors on this machine
    /// beside the measured times, and their projected floors on a named GPU class (absent in
    /// older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_model: Option<FrameModelRecord>,
}

/// The frame-time model of a run (`biscale_shading::frame_model`): per form, its light change
/// (`gather`) and view change (`shade`) counted, floored on this machine (`machine`, measured
/// by the run's probe) and projected on `projection` (published figures). A projection is a
/// floor, a lower bound on that processor's time: the frame rate it implies is a ceiling.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameModelRecord {
    /// The run's image and samples per pixel (the shading grid the counts are for).
    pub width: u32,
    pub height: u32,
    pub samples_per_pixel: u32,
    /// Where the light moments are resolved (`vertex` without them).
    pub resolve: biscale_shading::runtime::MomentsResolve,
    pub machine: biscale_shading::frame_model::Processor,
    pub projection: biscale_shading::frame_model::Processor,
    pub forms: Vec<FormFrameModel>,
}

/// One form's stages in the frame-time model.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FormFrameModel {
    pub name: String,
    /// A light change's gather (with light moments, the three moment gathers and the vertex
    /// resolve).
    pub gather: StageModel,
    /// A view change: the shading pass.
    pub shade: StageModel,
    /// The shade's projected floor at 1920x1080, one sample per pixel.
    pub shade_1080p_projected_ms: f64,
}

/// One stage of a frame: what it moves and computes, the times measured (the CPU runtime's,
/// and the GPU backend's when it ran), its floor on this machine and its projected floor.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StageModel {
    pub stage: String,
    pub bytes: f64,
    pub flops: f64,
    pub cpu_ms: Option<f64>,
    pub gpu_ms: Option<f64>,
    pub floor_ms: f64,
    pub projected_ms: f64,
}

/// The PNGs' tone map (`value x 2^exposure`, clamped to [0, 1], sRGB), one for the whole run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ToneMapRecord {
    /// The exposure in stops.
    pub exposure: f32,
    /// `[report] exposure = "auto"`: chosen from the uncompressed render so that at most 1% of
    /// the mesh's pixels clip.
    pub auto: bool,
    /// The share of the uncompressed render's mesh pixels the tone map clips (a channel
    /// above 1).
    pub clipped: f64,
}

/// One animated comparison (`[runtime.animation]`): a path, the light turned about +Y or the
/// camera orbited about its target through one full turn, rendered per frame for the
/// uncompressed `T` and every animated setting.
#[derive(Debug, Serialize, Deserialize)]
pub struct AnimationRecord {
    /// `light` or `camera`.
    pub path: String,
    pub frames: u32,
    /// Degrees turned from one frame to the next.
    pub step_degrees: f64,
    /// The animated PNGs' playback rate.
    pub fps: u32,
    /// The per-frame plot (`*.png`, with `*.svg` beside it), relative to the output folder.
    pub plot: String,
    pub series: Vec<AnimationSeries>,
}

/// One rendered sequence of an [`AnimationRecord`].
#[derive(Debug, Serialize, Deserialize)]
pub struct AnimationSeries {
    /// `uncompressed` or the setting's label.
    pub name: String,
    /// The animated PNG (APNG: every frame, tone mapped at the report's exposure), relative to
    /// the output folder.
    pub apng: String,
    /// Each frame's image error against the uncompressed render of the same frame: relative
    /// L2 over the covered pixels at the report's exposure (0 for `uncompressed` itself).
    pub rel_l2: Vec<f64>,
    /// Each frame's gather wall time (the light path's; 0 on the camera path, where the light
    /// and so `L*` do not change) and shade wall time, one repeat each.
    pub gather_ms: Vec<f64>,
    pub shade_ms: Vec<f64>,
}

/// The machine's load while a run timed its steps (`metrics.json`'s `load`): the 1-minute
/// load average of `/proc/loadavg` just before the first timed step (the uncompressed gather)
/// and just after the last (the last method setting), and the CPUs it is spread over.
///
/// The load average counts runnable threads of the whole machine, this run's own included,
/// so it is compared with the machine's online CPUs (`cpus_online`), not with the CPUs this
/// process may use (`run.cores`, smaller under an affinity mask or a batch allocation). A run
/// cannot push it past `cpus_online` on its own (its rayon threads are at most one per CPU):
/// a load above it means other work competed for the CPUs while the steps were timed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoadRecord {
    /// 1-minute load average before the timed steps; `None` where `/proc/loadavg` cannot be read.
    pub load_before: Option<f64>,
    /// 1-minute load average after the timed steps.
    pub load_after: Option<f64>,
    /// CPUs online on the machine.
    pub cpus_online: usize,
}

impl LoadRecord {
    /// The larger of the two readings, when either was made.
    pub fn peak(&self) -> Option<f64> {
        match (self.load_before, self.load_after) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        }
    }

    /// True when the load average exceeded the online CPUs before or after the timed steps:
    /// some repeats then waited for a CPU, and their times measure the queue as well as the
    /// step.
    pub fn overloaded(&self) -> bool {
        self.peak().is_some_and(|l| l > self.cpus_online as f64)
    }
}

/// One timed step (a gather or a shade) over its `repeats` (`runtime.repeats`): the fastest,
/// the median and the slowest wall-clock time, and how much the repeats disagree (`spread`).
/// `median_ms` is the figure the step's `*_ms` field reports (`gather_ms`, `shade_ms`).
///
/// `spread` is the interquartile range over the median, `(q3 - q1) / median_ms`, with the
/// quartiles interpolated linearly between the sorted samples (NumPy's default percentile);
/// 0 for a single repeat. It is robust on purpose: one slow repeat (a first-touch page fault,
/// a cold cache, a context switch) moves neither the median nor the quartiles, so the spread
/// only grows when the repeats as a body disagree, which is when the median itself is in
/// doubt. The single slow repeat still shows in `max_ms`. See [`Timing::noisy`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub min_ms: f64,
    pub median_ms: f64,
    pub max_ms: f64,
    pub repeats: usize,
    /// `(q3 - q1) / median_ms` (0 for one repeat or a zero median).
    pub spread: f64,
}

/// [`Timing::spread`] above which a step's timing is called noisy in the report and the log.
///
/// An interquartile range of a quarter of the median means the middle half of the repeats
/// disagree by 25%: with the usual 5 repeats the median is then uncertain by about 10% (the
/// standard error of a median of n samples is about `1.25 sigma / sqrt(n)`, with `sigma` about
/// `IQR / 1.35`), so two settings within 1.3x of each other cannot be ranked by speed. On a
/// quiet machine the repeats of a gather agree within a few percent.
pub const NOISY_SPREAD: f64 = 0.25;

impl Timing {
    /// The timing of `samples` (ms, one per repeat); every figure NaN when there are none.
    pub fn from_samples(samples: &[f64]) -> Self {
        let mut s = samples.to_vec();
        s.sort_by(f64::total_cmp);
        let n = s.len();
        // The median exactly as every `*_ms` field has always been computed.
        let median_ms = biscale_core::stats::median(&s);
        let quantile = |p: f64| {
            let x = p * (n - 1) as f64;
            let (i, f) = (x.floor() as usize, x.fract());
            match s.get(i + 1) {
                Some(&next) => s[i] + f * (next - s[i]),
                None => s[i],
            }
        };
        let spread = match n {
            0 => f64::NAN,
            _ if median_ms > 0.0 => (quantile(0.75) - quantile(0.25)) / median_ms,
            _ => 0.0,
        };
        Timing {
            min_ms: s.first().copied().unwrap_or(f64::NAN),
            median_ms,
            max_ms: s.last().copied().unwrap_or(f64::NAN),
            repeats: n,
            spread,
        }
    }

    /// True when the repeats disagree by more than [`NOISY_SPREAD`].
    pub fn noisy(&self) -> bool {
        self.spread > NOISY_SPREAD
    }

    /// `median (min-max)` at `decimals` decimals, as the report's tables print a timing; the
    /// median alone for a single repeat (its range is itself).
    pub fn median_range(&self, decimals: usize) -> String {
        match self.repeats > 1 {
            true => format!("{:.decimals$} ({:.decimals$}-{:.decimals$})", self.median_ms, self.min_ms, self.max_ms),
            false => format!("{:.decimals$}", self.median_ms),
        }
    }
}

/// The figures of the report's comparison section (`crate::inset`), one row per image: the
/// uncompressed render, every compressor and method setting, the ground truth.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ComparisonFigures {
    /// The inset region `[x, y, width, height]` in pixels of the render.
    pub inset: [u32; 4],
    /// Where it comes from: `[report] inset`, or the window of the largest error of a setting.
    pub inset_from: String,
    /// Each inset's nearest-neighbour magnification (a reference's is this times its downscale).
    pub inset_magnification: u32,
    /// The full scale shared by every error figure against the ground truth, when traced.
    pub reference_error_scale: Option<f32>,
    pub rows: Vec<FigureRow>,
}

/// One row of [`ComparisonFigures`]; paths relative to the output folder.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FigureRow {
    /// `uncompressed`, a setting's label, or `reference` (the ground truth).
    pub name: String,
    /// The image, magnified to at least 300 pixels wide, with the inset region marked.
    pub thumbnail: String,
    pub inset: String,
    /// The error against the ground truth at [`ComparisonFigures::reference_error_scale`],
    /// its largest per-pixel error on its colour bar.
    pub error_vs_reference_png: Option<String>,
}

/// How a sharded precompute went (the pipeline's `shard`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardedMetrics {
    pub shards: usize,
    /// Wall seconds of the shards, summed and the slowest (the array's critical path).
    pub shard_seconds_sum: f64,
    pub shard_seconds_max: f64,
    /// CPU seconds of the shards' processes, summed (when every shard could read its own).
    pub shard_cpu_seconds_sum: Option<f64>,
    /// The largest peak resident memory of a shard.
    pub shard_peak_rss_max: Option<u64>,
    /// Seconds the merge took to check, load and stack the shards' outputs.
    pub merge_load_seconds: f64,
    /// Seconds of the whole merge, pipeline included.
    pub merge_seconds: f64,
    /// `T` was left in the shards' files and every pass over it read them part by part
    /// (false: stacked into one matrix; and in older records).
    #[serde(default)]
    pub streamed: bool,
}

/// The memory record of a run (the pipeline's `memory`): the estimate made before tracing, beside
/// the peak resident memory the run measured at its end.
#[derive(Debug, Serialize, Deserialize)]
pub struct MemoryMetrics {
    /// Estimated peak bytes: the largest phase (`phases`), made before tracing.
    pub estimate_bytes: u64,
    /// The phase the estimate peaks in.
    pub estimate_phase: String,
    /// The estimate with every vertex at its worst case (`N / 2` non-zeros).
    pub worst_case_bytes: u64,
    /// Memory available when the run started, and where the figure came from.
    pub available_bytes: u64,
    pub available_source: String,
    /// Measured: the process's peak resident memory (VmHWM) when `metrics.json` was written;
    /// null where /proc cannot be read.
    pub peak_rss_bytes: Option<u64>,
    /// Non-zeros of `T`: vertices traced for the estimate, the sampled total, its upper bound
    /// (what the estimate uses), the worst case, and the sampling's seconds.
    pub nnz_sampled_vertices: usize,
    pub nnz_expected: u64,
    pub nnz_upper: u64,
    pub nnz_worst_case: u64,
    pub sample_seconds: f64,
    /// What is alive at once in each phase of the run.
    pub phases: Vec<Part>,
    /// Every buffer the estimate counts.
    pub parts: Vec<Part>,
}

/// One method setting: the fields of a compressor record (its `kind` and `params` are the
/// method's; storage, flops and build time are those of its transfer's compressed form;
/// `image.vs_uncompressed` is against the all-frequency uncompressed image) plus the method's
/// own record.
#[derive(Debug, Serialize, Deserialize)]
pub struct MethodRecord {
    #[serde(flatten)]
    pub record: CompressorRecord,
    /// The SH method's own numbers (present for `kind = "sh"`).
    pub sh: Option<ShRecord>,
}

/// What the SH method measured beyond a compressor record.
#[derive(Debug, Serialize, Deserialize)]
pub struct ShRecord {
    pub order: u32,
    pub rays: u32,
    pub bounces: u32,
    /// The compressor of the `M_p` set (`sparse`: the raw matrices).
    pub compressor: String,
    /// How much of the cubemap light lies above the order: relative L2 of the light against
    /// the reconstruction of its projection.
    pub light_projection_error: f64,
    /// The SH transfer `M`: build, storage and agreement with `T`.
    pub transfer: ShTransferRecord,
    /// The radiance transfer textures (every material's BTF on local SH).
    pub rtt: RttRecord,
    /// Fraction of covered pixels with a negative channel: SH ringing under a sharp light.
    /// Not clamped (the EXR keeps them; the PNG shows them as black).
    pub negative_pixels: f64,
    /// True when every material is Lambertian, so the method ran as shadowed diffuse PRT (a
    /// transfer vector per vertex instead of a matrix, no per-pixel BTF lookup).
    pub diffuse: bool,
    /// With LPCA materials (Müller et al. 2004): the runtime of precomputed dot products and
    /// of fewer components while the light moves.
    pub lpca: Option<ShLpcaRecord>,
}

/// An SH setting with LPCA BTFs: `B = sum_v w_v sum_c a_c (E_kc(e_v) . M_p l)`, the dot
/// products recomputed per vertex whenever the light changes.
#[derive(Debug, Serialize, Deserialize)]
pub struct ShLpcaRecord {
    /// What a light change costs: the gather `M_p l` and the dot products (median ms).
    pub relight_ms: f64,
    /// Per frame from the dot products, and how far that is from the direct evaluation.
    pub precomputed: PrecomputedRecord,
    /// Each number of components per cluster from 1 up: relight and shade time, and the image
    /// error against all components (what dropping components during rotation costs).
    pub adaptive: Vec<AdaptiveRecord>,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct AdaptiveRecord {
    pub components: usize,
    pub relight_ms: f64,
    pub shade_ms: f64,
    /// Relative L2 against the image with every component.
    pub vs_all_components: f64,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct ShTransferRecord {
    /// Seconds to build `M` (0 when it came from the cache).
    pub seconds: f64,
    pub rays_traced: u64,
    pub cached: bool,
    pub nnz: usize,
    /// Relative Frobenius difference between `M` projected from `T` and the ray-traced `M`,
    /// over every `from_t_stride`-th vertex (the bridge between the methods).
    pub from_t_difference: f64,
    pub from_t_stride: usize,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct RttRecord {
    /// Stored bytes of all RTT tables at f32 (the SH analogue of the BTF tables).
    pub bytes: u64,
    /// Largest relative L2 error of a material's BTF light dependence lost to the order.
    pub projection_error: f64,
    /// Largest relative error of the bin integrals of the projection.
    pub quadrature_error: f64,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct SceneMetrics {
    pub mesh: String,
    pub vertices: usize,
    pub triangles: usize,
    pub repairs: Vec<String>,
    /// The materials used: `label (BTF name)`, comma separated.
    pub material: String,
    /// What the material stage left out or repaired (one line each).
    pub material_notes: Vec<String>,
    /// Bytes of the materials' dense BTF tables at f32 (the all-frequency method's meso-scale
    /// data before any BTF compression).
    pub btf_bytes: u64,
    /// Every representation of every material: its storage and error (and its BTF study).
    pub btfs: Vec<BtfRecord>,
}

/// One representation of one material's BTF (`representation` in its config entry): what it
/// stores and loses, and (in the BTF study, when any setting is compressed) what it changes in
/// the image and costs to shade.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BtfRecord {
    pub material: String,
    /// `dense` or `lpca-k<clusters>-c<components>[-view][-f16|-u8]`.
    pub representation: String,
    /// The material's own representation (the first listed; every compressor and method is
    /// shaded with it), else another setting compared in the BTF study.
    pub primary: bool,
    /// The dense table at f32.
    pub dense_bytes: u64,
    /// What the representation stores.
    pub bytes: u64,
    /// `dense_bytes / bytes`.
    pub compression_ratio: f64,
    /// `||B - B~||_F / ||B||_F` of the table (0 for dense).
    pub relative_rms_error: f64,
    pub build_seconds: f64,
    /// The BTF study (absent when every setting of the run is dense).
    pub study: Option<BtfStudyRecord>,
}

/// One BTF setting shaded with the uncompressed `L*` (every other material dense).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BtfStudyRecord {
    /// Against the same scene with every BTF dense: the BTF part of the error.
    pub vs_dense: ImageErrors,
    /// Against the ray-traced reference, when it was traced.
    pub vs_reference: Option<ImageErrors>,
    /// Median CPU shade time (ms) of the image, and of the all-dense image in the same run.
    pub shade_ms: f64,
    pub dense_shade_ms: f64,
    /// Median time of the primary rays and the background alone (the floor of every CPU shade
    /// of the view): the BTF evaluation costs `shade_ms - rays_ms`.
    pub rays_ms: f64,
    /// Precomputed per-vertex dot products for the fixed light, when the setting is
    /// compressed and the table fits ([`biscale_shading::precomputed`]).
    pub precomputed: Option<PrecomputedRecord>,
    /// Why the precomputed path was not measured, if it was not.
    pub precomputed_note: Option<String>,
    pub png: String,
    /// False-colour error against the all-dense image, and its full scale.
    pub error_png: String,
    pub error_scale: f32,
}

/// The fixed-light fast path of an LPCA setting.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PrecomputedRecord {
    /// The dot-product tables.
    pub bytes: u64,
    /// Computing them once for the light (ms).
    pub precompute_ms: f64,
    /// Median shade time from them (ms), per frame while the light stays.
    pub shade_ms: f64,
    /// Relative L2 difference from the direct evaluation's image (rounding only).
    pub vs_direct: f64,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct LightingMetrics {
    pub source: String,
    pub cubemap_resolution: u32,
    pub rotation_degrees: f64,
    /// Sum of `L` per channel (power over the sphere).
    pub total_power: [f64; 3],
    pub warnings: Vec<String>,
    /// With light moments, where each texel's light came from (`lighting.texel_directions`:
    /// `mean` or `centre`); absent without light moments and in older records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texel_directions: Option<biscale_core::sampling::TexelDirections>,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct ValueCount {
    pub value: f32,
    pub count: u64,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct TransferMetrics {
    pub rows: usize,
    pub cols: usize,
    pub nnz: usize,
    pub local_dirs: usize,
    pub visibility_resolution: u32,
    /// How the visibility rays were decided (`transfer.visibility`: "coverage" or "rays";
    /// absent in older records, which traced every ray).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub visibility: Option<biscale_core::transfer::Visibility>,
    pub value_histogram: Vec<ValueCount>,
    /// Seconds to build T (0 when it came from the cache; see `cached`).
    pub build_seconds: f64,
    /// Visibility rays decided (traced, or answered by the coverage test).
    pub rays_traced: u64,
    pub rays_per_second: f64,
    pub cached: bool,
    /// Vertices all of whose rows of T are zero: they see no sky at all (closed rooms, or an
    /// inside-out mesh whose normals point into the solid).
    pub vertices_without_sky: usize,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct UncompressedMetrics {
    pub gather_ms: f64,
    pub shade_ms: f64,
    /// The repeats behind `gather_ms` and `shade_ms` (absent in older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gather_timing: Option<Timing>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shade_timing: Option<Timing>,
    /// `[runtime] light_moments`: every `L*` of the run weights texels by their own cosine.
    pub light_moments: bool,
    /// With light moments, `[runtime] moments_resolve`: `vertex` (each vertex's three moment
    /// gathers resolved into its `L*`, interpolated), `pixel` (each vertex's moment gathers
    /// resolved at every pixel's frame, then blended) or `pixel_analytic` (resolved per pixel with a flat
    /// analytic material's own BRDF). Absent without moments, and in older records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moments_resolve: Option<biscale_shading::runtime::MomentsResolve>,
    /// With light moments: the paper's (bin-mean-cosine) uncompressed image against the
    /// moments' one, over the covered pixels: how much the moments change the picture.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paper_vs_moments: Option<ImageErrors>,
}

/// The per-pixel reference image: always "ground truth (direct light)"
/// (`biscale_shading::reference::ReferenceRule::GroundTruth`), whatever `light_moments` says.
#[derive(Debug, Serialize, Deserialize)]
pub struct ReferenceMetrics {
    /// What the reference is: `"ground truth (direct light)"`.
    pub kind: String,
    /// How it shades each material, `; `-separated: `<label>: <kind> BRDF, exact` where the
    /// material is an analytic BRDF (evaluated at each texel's direction and the pixel's
    /// view), `<label>: BTF table` where its table is all there is (interpolated at each
    /// texel's direction). Empty in records written before it was recorded.
    #[serde(default)]
    pub shading: String,
    pub width: u32,
    pub height: u32,
    /// The trace's wall time (of a `cached` reference: measured by the earlier run that traced it).
    pub seconds: f64,
    /// Whether the reference image came from the stage cache (`reference-<key>.bsf`) instead of
    /// a trace; absent (false) in records written before the reference was cached.
    #[serde(default)]
    pub cached: bool,
    /// Error of the per-vertex (uncompressed) render against the reference: the
    /// "per-vertex sampling" part of the error.
    pub uncompressed_vs_reference: ImageErrors,
    /// With light moments: the paper-mode uncompressed image against the same (exact-cosine)
    /// reference, the side-by-side figure of what the moments gain.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncompressed_paper_vs_reference: Option<ImageErrors>,
}

/// An image's error against another (`biscale_shading::image::ImageMetrics`, which documents
/// each figure): HDR `rmse`, `psnr` (peak: the reference's largest value) and `rel_l2`; then
/// after the report's tone map (`[report] exposure`, clamp, sRGB) `ldr_psnr` (peak 1), `ssim`
/// (mean over R, G, B and the masked pixels) and `flip` (mean LDR FLIP).
///
/// JSON has no infinities: a PSNR of identical images (infinite) is written `null` and read
/// back as infinite; any other `null` figure is read back as NaN.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ImageErrors {
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse: f64,
    #[serde(deserialize_with = "infinite_if_null")]
    pub psnr: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rel_l2: f64,
    #[serde(deserialize_with = "infinite_if_null")]
    pub ldr_psnr: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub ssim: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub flip: f64,
}

fn infinite_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

impl From<&biscale_shading::image::ImageMetrics> for ImageErrors {
    fn from(m: &biscale_shading::image::ImageMetrics) -> Self {
        Self { rmse: m.rmse, psnr: m.psnr, rel_l2: m.rel_l2, ldr_psnr: m.ldr_psnr, ssim: m.ssim, flip: m.flip }
    }
}

#[derive(Debug, Serialize, Deserialize)]
pub struct ImageRecord {
    /// Against the render from the uncompressed `T` (the "compression" part of the error).
    pub vs_uncompressed: ImageErrors,
    /// Against the ray-traced reference, when it was traced.
    pub vs_reference: Option<ImageErrors>,
    pub png: String,
    pub exr: String,
    /// False-colour |error| against the uncompressed render, with its colour bar; its full
    /// scale (shared by every compressor of the run) and the largest per-pixel error.
    pub error_png: Option<String>,
    pub error_scale: Option<f32>,
    pub error_max: Option<f32>,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct CompressorRecord {
    /// Setting label (`sparse`, `bicluster`, `cpca-k32-c8`, `haar-t12`, ...).
    pub name: String,
    pub kind: String,
    pub params: serde_json::Value,
    pub lossless: bool,
    /// Stored bytes over every array the gather reads.
    pub bytes: u64,
    pub bytes_by_array: BTreeMap<String, u64>,
    pub bytes_per_nnz: f64,
    /// Monochrome gather flops (an RGB gather does three times the multiply-adds).
    pub flops_per_gather: u64,
    /// Seconds the compressor took (for a form from the cache: when it was built, by an
    /// earlier run whose machine and load the cache does not record).
    pub build_seconds: f64,
    /// True when the form was loaded from the stage cache.
    pub cached: bool,
    /// Median wall-clock of the RGB gather over `runtime.repeats` runs.
    pub gather_ms: f64,
    /// Median wall-clock of the CPU shade over `runtime.repeats` runs.
    pub shade_ms: f64,
    /// The repeats behind `gather_ms` (absent in older records, and for an `L*` the run did
    /// not gather: `biscale eval --lstar`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gather_timing: Option<Timing>,
    /// The repeats behind `shade_ms` (absent in older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shade_timing: Option<Timing>,
    /// Relative L2 error of `L*` against the f64 product `T L`.
    pub rel_error_lstar: f64,
    pub image: ImageRecord,
    /// Compressor-specific statistics (e.g. biclustering's Table I numbers).
    pub stats: Option<serde_json::Value>,
    /// The same form on the wgpu backend (when `runtime.backend = "gpu"`).
    pub gpu: Option<GpuRecord>,
}

/// The columns of `metrics.csv`, one row per compressor and method setting: what a plot of
/// error against storage or time needs, in plain units, without parsing JSON. New columns
/// are appended (the LDR figures last), so a reader by position keeps working.
pub const CSV_COLUMNS: [&str; 24] = [
    "setting",
    "kind",
    "method",
    "lossless",
    "bytes",
    "bytes_per_nnz",
    "flops_per_gather",
    "build_seconds",
    "gather_ms",
    "shade_ms",
    "rel_error_lstar",
    "image_rel_l2_vs_uncompressed",
    "image_psnr_vs_uncompressed",
    "image_rel_l2_vs_reference",
    "image_psnr_vs_reference",
    "image_error_max",
    "gpu_gather_ms",
    "gpu_shade_ms",
    "image_ldr_psnr_vs_uncompressed",
    "image_ssim_vs_uncompressed",
    "image_flip_vs_uncompressed",
    "image_ldr_psnr_vs_reference",
    "image_ssim_vs_reference",
    "image_flip_vs_reference",
];

/// Keys whose string values name a file of the run folder (an image, a plot): `png`, `exr`,
/// `apng`, `svg`, `plot`, `thumbnail`, `inset`, and any key ending in `_png`, `_exr`, `_svg`
/// or `_apng`. [`named_files`] finds them; a record may name files inside its own folder only.
fn names_a_file(key: &str) -> bool {
    matches!(key, "png" | "exr" | "apng" | "svg" | "plot" | "thumbnail" | "inset")
        || ["_png", "_exr", "_svg", "_apng"].iter().any(|s| key.ends_with(s))
}

/// Every file a record (a parsed `metrics.json`) names, as (field, path): the field in
/// JSON-path form (`compressors[2].image.png`). The report reads and embeds these, so each
/// must stay inside the run folder ([`biscale_core::io::inside_folder`]).
pub fn named_files(record: &serde_json::Value) -> Vec<(String, String)> {
    fn walk(v: &serde_json::Value, at: &str, key: &str, out: &mut Vec<(String, String)>) {
        match v {
            serde_json::Value::String(s) if names_a_file(key) => out.push((at.to_string(), s.clone())),
            serde_json::Value::Array(items) => {
                for (i, item) in items.iter().enumerate() {
                    walk(item, &format!("{at}[{i}]"), key, out);
                }
            }
            serde_json::Value::Object(map) => {
                for (k, item) in map {
                    let field = if at.is_empty() { k.clone() } else { format!("{at}.{k}") };
                    walk(item, &field, k, out);
                }
            }
            _ => {}
        }
    }
    let mut out = vec![];
    walk(record, "", "", &mut out);
    out
}

impl Metrics {
    /// `metrics.csv`: a header of [`CSV_COLUMNS`], then one row per compressor setting
    /// (`method` false) and per method setting (`method` true); absent values are empty.
    pub fn to_csv(&self) -> String {
        let field = |s: &str| match s.contains([',', '"', '\n']) {
            true => format!("\"{}\"", s.replace('"', "\"\"")),
            false => s.to_string(),
        };
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:e}"));
        let mut out = CSV_COLUMNS.join(",") + "\n";
        let rows = (self.compressors.iter().map(|r| (r, false))).chain(self.methods.iter().map(|m| (&m.record, true)));
        for (r, method) in rows {
            let cells = [
                field(&r.name),
                field(&r.kind),
                method.to_string(),
                r.lossless.to_string(),
                r.bytes.to_string(),
                format!("{:e}", r.bytes_per_nnz),
                r.flops_per_gather.to_string(),
                format!("{:e}", r.build_seconds),
                format!("{:e}", r.gather_ms),
                format!("{:e}", r.shade_ms),
                format!("{:e}", r.rel_error_lstar),
                format!("{:e}", r.image.vs_uncompressed.rel_l2),
                format!("{:e}", r.image.vs_uncompressed.psnr),
                opt(r.image.vs_reference.map(|e| e.rel_l2)),
                opt(r.image.vs_reference.map(|e| e.psnr)),
                opt(r.image.error_max.map(f64::from)),
                opt(r.gpu.as_ref().map(|g| g.gather_ms)),
                opt(r.gpu.as_ref().map(|g| g.shade_ms)),
                format!("{:e}", r.image.vs_uncompressed.ldr_psnr),
                format!("{:e}", r.image.vs_uncompressed.ssim),
                format!("{:e}", r.image.vs_uncompressed.flip),
                opt(r.image.vs_reference.map(|e| e.ldr_psnr)),
                opt(r.image.vs_reference.map(|e| e.ssim)),
                opt(r.image.vs_reference.map(|e| e.flip)),
            ];
            out += &cells.join(",");
            out.push('\n');
        }
        out
    }
}

/// Gather and shade of one compressed form on the GPU, checked against the CPU.
#[derive(Debug, Serialize, Deserialize)]
pub struct GpuRecord {
    pub adapter: String,
    /// `GpuTimestamps` or `WallClock`.
    pub timing: String,
    /// Median GPU time of the gather (RGB); with light moments, of the three moment gathers
    /// plus the GPU resolve into `L*'` (`GpuMoments::time_gather`).
    pub gather_ms: f64,
    /// Median GPU time of the shade (visibility buffer + compute pass).
    pub shade_ms: f64,
    /// The repeats behind `gather_ms` and `shade_ms` (absent in older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gather_timing: Option<Timing>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shade_timing: Option<Timing>,
    /// Relative L2 error of the GPU's `L*` against the f64 product.
    pub rel_error_lstar: f64,
    /// The GPU image against the CPU image of the same form, over the pixels the CPU covers
    /// with the same samples as the GPU (its LDR figures at exposure 0).
    pub image_vs_cpu: ImageErrors,
    /// Pixels whose coverage differs between the GPU rasterizer and the CPU ray cast (with
    /// anti-aliasing: by a sample near a silhouette); they are left out of `image_vs_cpu`.
    pub coverage_mismatch: usize,
    /// Compared pixels where GPU and CPU differ by more than 1e-3 of the pixel's value
    /// (nearest-texel lookups flipping at texel and material boundaries).
    pub differing_pixels: usize,
    /// Pixels the CPU render covers.
    pub covered_pixels: usize,
}

/// Version of the `metrics.json` schema: 2 added `schema_version` and `run`.
pub const SCHEMA_VERSION: u32 = 2;

/// The provenance of one run.
/// (Made by the pipeline's `provenance::StageClock`.)
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunRecord {
    pub biscale_version: String,
    /// The commit of the checkout biscale was built from (absent outside a git checkout).
    pub git_commit: Option<String>,
    /// Whether tracked files differed from that commit when biscale was built.
    pub git_dirty: Option<bool>,
    pub rustc: String,
    /// The command line.
    pub command: Vec<String>,
    pub config_text: String,
    /// XXH3-128 of `config_text`.
    pub config_hash: String,
    pub seed: u64,
    /// UTC, RFC 3339.
    pub started_at: String,
    pub host: String,
    pub cpu_model: String,
    /// Logical CPUs the process may use.
    pub cores: usize,
    /// Rayon threads (`--threads`, `RAYON_NUM_THREADS`, or one per core).
    pub threads: usize,
    /// `/proc/loadavg`'s 1, 5 and 15 minute averages at the start and the end of the run.
    pub load_average_start: Option<[f64; 3]>,
    pub load_average_end: Option<[f64; 3]>,
    /// Each stage's wall and CPU (user + system, all threads) seconds, in order.
    pub stages: Vec<StageTime>,
    pub wall_seconds: f64,
    pub cpu_seconds: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    pub stage: String,
    pub wall_seconds: f64,
    pub cpu_seconds: Option<f64>,
}

impl RunRecord {
    /// One line for the report's header.
    pub fn summary(&self) -> String {
        let git = match (&self.git_commit, self.git_dirty) {
            (Some(c), Some(true)) => format!(", git {} (dirty)", &c[..c.len().min(12)]),
            (Some(c), _) => format!(", git {}", &c[..c.len().min(12)]),
            _ => String::new(),
        };
        let load = |l: Option<[f64; 3]>| l.map_or("?".into(), |l| format!("{:.2}", l[0]));
        format!(
            "biscale {}{git}, {}; started {} on {} ({}, {} cores, threads {}), load {} at start and {} at end; \
             {:.1} s wall, {} CPU; config hash {}",
            self.biscale_version,
            self.rustc,
            self.started_at,
            self.host,
            self.cpu_model,
            self.cores,
            self.threads,
            load(self.load_average_start),
            load(self.load_average_end),
            self.wall_seconds,
            self.cpu_seconds.map_or("?".into(), |c| format!("{c:.1} s")),
            self.config_hash
        )
    }
}

/// One named amount of memory.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Part {
    pub name: String,
    pub bytes: u64,
}

impl Part {
    pub fn new(name: impl Into<String>, bytes: u64) -> Self {
        Self { name: name.into(), bytes }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_timing_keeps_the_fastest_the_median_and_the_slowest_repeat() {
        let t = Timing::from_samples(&[5.0, 1.0, 3.0, 2.0, 4.0]);
        assert_eq!((t.min_ms, t.median_ms, t.max_ms, t.repeats), (1.0, 3.0, 5.0, 5));
        // Quartiles 2 and 4 (linear interpolation between the sorted samples): (4 - 2) / 3.
        assert_eq!(t.spread, 2.0 / 3.0);
        // An even count: median 2.5, quartiles at 0.75 and 2.25 of the way, 1.75 and 3.25.
        let t = Timing::from_samples(&[4.0, 3.0, 2.0, 1.0]);
        assert_eq!((t.min_ms, t.median_ms, t.max_ms, t.repeats), (1.0, 2.5, 4.0, 4));
        assert_eq!(t.spread, 1.5 / 2.5);
        // The median is the one every `*_ms` field always held, to the bit.
        let samples = [0.1, 0.7, 0.3, 0.2];
        assert_eq!(Timing::from_samples(&samples).median_ms, biscale_core::stats::median(&samples));
    }

    #[test]
    fn one_repeat_has_no_spread_and_none_has_no_figures() {
        let t = Timing::from_samples(&[7.25]);
        assert_eq!((t.min_ms, t.median_ms, t.max_ms, t.repeats, t.spread), (7.25, 7.25, 7.25, 1, 0.0));
        assert!(!t.noisy());
        assert_eq!(t.median_range(2), "7.25");
        let t = Timing::from_samples(&[]);
        assert_eq!(t.repeats, 0);
        assert!(t.min_ms.is_nan() && t.median_ms.is_nan() && t.max_ms.is_nan() && !t.noisy());
        // A zero median (a step below the clock's resolution) is not called noisy.
        assert_eq!(Timing::from_samples(&[0.0, 0.0, 0.0]).spread, 0.0);
    }

    #[test]
    fn a_timing_is_noisy_past_a_quarter_of_its_median_and_not_for_one_slow_repeat() {
        // Interquartile range 1.125 - 0.875 = 0.25 of a median of 1: at the threshold, quiet.
        let at = Timing::from_samples(&[0.5, 0.875, 1.0, 1.125, 2.0]);
        assert_eq!(at.spread, NOISY_SPREAD);
        assert!(!at.noisy());
        let past = Timing::from_samples(&[0.5, 0.875, 1.0, 1.25, 2.0]);
        assert_eq!(past.spread, 0.375);
        assert!(past.noisy());
        // One slow repeat (a cold first run) moves neither the median nor the quartiles...
        let one_slow = Timing::from_samples(&[36.0, 6.4, 6.5, 6.6, 6.7]);
        assert!(!one_slow.noisy(), "{one_slow:?}");
        assert_eq!(one_slow.median_range(1), "6.6 (6.4-36.0)");
        // ...but repeats that disagree as a body do.
        let body = Timing::from_samples(&[6.4, 6.5, 6.6, 30.0, 36.0]);
        assert!(body.noisy(), "{body:?}");
    }

    #[test]
    fn the_load_is_too_high_only_past_the_online_cpus() {
        let load = |before, after| LoadRecord { load_before: before, load_after: after, cpus_online: 2 };
        assert!(load(Some(1.0), Some(2.5)).overloaded());
        assert!(load(Some(3.1), None).overloaded());
        assert_eq!(load(Some(3.1), None).peak(), Some(3.1));
        // Exactly one runnable thread per CPU (the run's own, at full tilt) is not overload.
        assert!(!load(Some(2.0), Some(2.0)).overloaded());
        assert!(!load(None, None).overloaded());
        assert_eq!(load(None, None).peak(), None);
    }

    #[test]
    fn a_record_without_timings_or_load_still_reads_and_writes_none_back() {
        let old = r#"{"gather_ms": 6.4, "shade_ms": 12.0, "light_moments": false}"#;
        let u: UncompressedMetrics = serde_json::from_str(old).unwrap();
        assert_eq!((u.gather_ms, u.gather_timing, u.shade_timing), (6.4, None, None));
        let back = serde_json::to_value(&u).unwrap();
        assert!(back.get("gather_timing").is_none(), "absent, not null: {back}");
        // A timing round-trips with the keys the README lists.
        let t = Timing::from_samples(&[1.0, 2.0, 4.0]);
        let v = serde_json::to_value(t).unwrap();
        let mut keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
        keys.sort();
        assert_eq!(keys, ["max_ms", "median_ms", "min_ms", "repeats", "spread"]);
        assert_eq!(serde_json::from_value::<Timing>(v).unwrap(), t);
    }
}
