//! How much memory a run will need, estimated before it traces anything, against how much the
//! machine has: `biscale plan` prints it, `biscale run` refuses up front a run that will not fit
//! (instead of being killed an hour in), and `metrics.json` `memory` records the estimate beside
//! the peak the run measured.
//!
//! * **What is counted.** Every large buffer: the process itself (measured), the mesh and both
//!   BVHs, the environment map, `T` in each form it takes ([`TransferMemory`]: the build's
//!   staging, the CSR, the cache file's arrays and encoded bytes), the BTFs, the images, the
//!   per-row vectors (`T L` in f64, `L*`), each compressor's working set and form (and their
//!   cache write: the form's arrays copied, then encoded whole), each SH method's matrices, the
//!   wgpu instance's buffers, and every BTF representation a material lists
//!   ([`RepresentationMemory`]: each local-PCA table, its build, and the BTF study's scene,
//!   dot products and images per setting).
//! * **Phases.** Buffers that are never alive together are not added: the estimate is the
//!   largest of the run's phases (transfer build, cache write, the local-PCA builds, baseline,
//!   BTF study, each compressor, each method), each the sum of what is alive in it.
//! * **Non-zeros.** `T`'s size is not known before tracing; [`estimate`] traces a sample of
//!   vertices first ([`sample_nnz`]: drawn by the experiment's seed in strata of every
//!   connected component, so no part of a mesh can hide from it) and uses its upper bound (the
//!   stratified total plus [`biscale_core::transfer::NNZ_MARGIN_SIGMAS`] standard errors); the
//!   worst case (`N / 2` per vertex) is reported beside it.
//! * **As it goes.** `biscale run` checks its own peak (VmHWM) between its heavy stages
//!   ([`check_peak`]) and stops with the estimate and the limit when the peak has passed the
//!   available memory, instead of growing on until it is killed.
//! * **Constants.** The per-triangle, per-pixel and baseline figures below were measured as
//!   peak resident memory (VmHWM) of runs on the 2-core Linux test machine (dev profile):
//!   BENCHMARKS.md "Memory estimate" has the runs and the estimate against the measurement.

use crate::error::PipelineError;
use crate::experiment::config::{Backend, Experiment, MaterialConfig, RepresentationSetting, Setting};
use crate::stages::scene::{Geometry, Lighting};
use biscale_core::transfer::{sample_nnz, NnzEstimate, TransferMemory, TransferSettings, NNZ_SAMPLE_VERTICES};
use biscale_core::CoreError;

/// Resident memory of the `biscale` process before any stage's data: code, libraries, thread
/// stacks, allocator arenas. Measured: 16 MiB at the peak of a run of the bunny at a 6x4x4
/// cubemap (everything else tiny); 4 MiB of headroom for other builds and machines.
pub const PROCESS_BASELINE_BYTES: u64 = 20 << 20;

/// The frame-time model's probe (run before `T` is built, beside the geometry and the light):
/// its two copy buffers, as the probe defines them.
pub use crate::stages::frame_model::PROBE_BYTES as FRAME_PROBE_BYTES;

/// What `runtime.backend = "gpu"` adds besides the buffers: the wgpu instance and, on a CPU
/// adapter (lavapipe), its compiler. Measured: 100 MiB (lavapipe, the bunny at a 6x4x4 cubemap).
pub const GPU_BASELINE_BYTES: u64 = 112 << 20;

/// Mesh, frames and both BVHs (the transfer scene's and the shader's) per triangle and per
/// vertex, with the transients of loading and building them. Measured: 540 MiB at the peak of
/// a run of the bunny subdivided four times (940,544 triangles, 470,274 vertices) at a 6x1x1
/// cubemap, about 445 MiB of it the geometry (the rest the process and `T`'s per-vertex
/// staging).
pub const GEOMETRY_BYTES_PER_TRIANGLE: u64 = 500;
pub const GEOMETRY_BYTES_PER_VERTEX: u64 = 64;

/// Images per pixel of the run's size: the renders alive at once (baseline, a compressor's,
/// its error image) and their PNG and EXR encodings. Measured: 44 MiB at 1280 x 960.
pub const IMAGE_BYTES_PER_PIXEL: u64 = 40;
/// The reference adds per pixel of its size: 20 MiB measured at 1280 x 960.
pub const REFERENCE_BYTES_PER_PIXEL: u64 = 20;
/// Every compressor's render stays alive until the run's shared error scale is known (its
/// f32 RGB image, its coverage and mask): per pixel and setting.
pub const KEPT_RENDER_BYTES_PER_PIXEL: u64 = 17;

/// Per row of `T`: `T L` in f64 (24), the baseline's `L*` (12), one gather's `L*` (12).
pub const VECTOR_BYTES_PER_ROW: u64 = 48;
/// With light moments, per row besides: the baseline's three exact moment gathers (36, which the
/// per-pixel resolves keep) and one form's three gathers (36, alive while they are resolved).
pub const MOMENT_BYTES_PER_ROW: u64 = 72;
/// With `runtime.moments_resolve = "pixel_analytic"`, per row besides: a render's lit bins
/// (`biscale_shading::analytic::LitBins`: a unit direction and three direction sums, f32).
pub const LIT_BIN_BYTES_PER_ROW: u64 = 48;
/// With a per-pixel resolve (`"pixel"`, or `"pixel_analytic"` beside a material with tables),
/// per row besides: the moments laid out for the table resolve
/// (`biscale_core::gather::moments::PointMoments`, twelve f32 lanes).
pub const POINT_MOMENT_BYTES_PER_ROW: u64 = biscale_core::gather::moments::PointMoments::BYTES_PER_ROW;
/// Per row on the GPU backend: the `L*` buffer and its read-back.
pub const GPU_BYTES_PER_ROW: u64 = 32;

/// Bytes per stored BTF value (RGB f32).
const BTF_BYTES_PER_VALUE: u64 = 12;

/// What each scene of the BTF study copies per vertex and per triangle (`ShadeScene::
/// with_materials`): the position (12), the UV (8) and the frame (36); the triangle (12), its
/// material id (2) and its compact material index (4).
pub const SCENE_BYTES_PER_VERTEX: u64 = 56;
pub const SCENE_BYTES_PER_TRIANGLE: u64 = 18;

/// Per unit (texel, or texel and view) of a local-PCA build besides its model
/// ([`biscale_core::linalg::cpca::build_bytes`]): the clustered PCA's row list, squared norms,
/// assignments and errors (old and new), seeding distances and member lists (about 60 bytes),
/// each unit's coefficient vector while it is accumulated (a `Vec` with its allocation, 56),
/// the stored cluster ids (u32, then u16); and per component its f32 coefficient (twice:
/// accumulated and stored) and the refit's f64 projection (`LPCA_BYTES_PER_UNIT_COMPONENT`,
/// plus 4 oversampling columns counted in the 144).
const LPCA_BYTES_PER_UNIT: u64 = 144;
const LPCA_BYTES_PER_UNIT_COMPONENT: u64 = 16;

/// Where the available memory comes from when `/proc/meminfo` cannot be read: the fixed limit
/// the transfer build has always had.
pub const FALLBACK_AVAILABLE_BYTES: u64 = biscale_core::transfer::MAX_TRANSFER_BYTES;

pub use biscale_report::metrics::Part;

/// A compressor setting's memory: its working set while it compresses (the form included)
/// and its form alone (what the cache write copies and encodes).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CompressorMemory {
    pub label: String,
    pub working: u64,
    pub form: u64,
}

/// The estimated memory of a run, part by part and phase by phase (module docs).
#[derive(Clone, Debug)]
pub struct RunMemory {
    /// The non-zeros of `T` the estimate assumes (`nnz.upper`) and how they were found.
    pub nnz: NnzEstimate,
    /// `T`'s buffers at `nnz.upper` non-zeros.
    pub transfer: TransferMemory,
    /// A merge that streams `T` ([`RunShape::streamed_part`]): the largest part as loaded,
    /// held twice (one in use, the next being read): all of `T` it holds at once (then
    /// `transfer` is what it never builds).
    pub streamed_part: Option<u64>,
    pub baseline: u64,
    pub geometry: u64,
    /// The environment map as loaded (with its decoding) and `L`.
    pub lighting: u64,
    /// The BTF tables: the materials' and the shade scene's copy, synthesis and local-PCA
    /// decoding.
    pub btfs: u64,
    pub images: u64,
    pub vectors: u64,
    /// The wgpu instance (0 on the CPU backend); each compressor's upload is in its phase.
    pub gpu: u64,
    pub compressors: Vec<CompressorMemory>,
    pub methods: Vec<Part>,
    /// The materials' BTF representations: local-PCA tables, builds and the BTF study.
    pub representations: RepresentationMemory,
    /// What is alive at once in each phase of the run, in run order.
    pub phases: Vec<Part>,
    /// The peak with every vertex at the worst case of `N / 2` non-zeros.
    pub worst_case_peak: u64,
}

/// What a run estimate needs to know of the experiment besides the config.
#[derive(Clone, Copy, Debug)]
pub struct RunShape {
    pub vertices: usize,
    pub triangles: usize,
    /// Pixels of the environment map (0 for a constant sky's small map).
    pub env_pixels: usize,
    /// Whether the stage cache is on (`T` and each form are written to it).
    pub cache: bool,
    /// Threads tracing `T` and building compressors.
    pub threads: usize,
    /// A sharded merge that streams `T` from the shards' files: the vertices of the largest
    /// part (it holds two at once, one in use and the next being read, and builds no `T` and
    /// no separable form); `None`: a run that holds `T` whole.
    pub streamed_part: Option<usize>,
}

impl RunMemory {
    /// The estimate for `exp` on a mesh and light of `shape`, with `nnz` non-zeros of `T`.
    pub fn new(exp: &Experiment, shape: &RunShape, nnz: NnzEstimate) -> Self {
        let settings = exp.transfer_settings();
        let mut m = Self::at(exp, shape, &settings, nnz.upper, nnz);
        m.worst_case_peak = Self::at(exp, shape, &settings, nnz.worst_case, nnz).peak().bytes;
        m
    }

    fn at(exp: &Experiment, shape: &RunShape, settings: &TransferSettings, nnz: u64, estimate: NnzEstimate) -> Self {
        let f = &exp.file;
        let transfer = TransferMemory::new(settings, shape.vertices, nnz, shape.threads);
        let rows = transfer.rows;
        let n = settings.light_basis().len() as u64;
        let m = settings.local_basis().len() as u64;
        let geometry =
            shape.triangles as u64 * GEOMETRY_BYTES_PER_TRIANGLE + shape.vertices as u64 * GEOMETRY_BYTES_PER_VERTEX;
        // Decoding holds the file's channels beside the map; L is N RGB f32 values.
        let lighting = shape.env_pixels.max(64 * 32) as u64 * 12 * 3 + n * 12;
        let pixels = *f.runtime.width.get_ref() as u64 * *f.runtime.height.get_ref() as u64;
        let ds = (*f.report.reference_downscale.get_ref()).max(1) as u64;
        let reference_pixels = match f.report.reference {
            true => (*f.runtime.width.get_ref() as u64 / ds).max(1) * (*f.runtime.height.get_ref() as u64 / ds).max(1),
            false => 0,
        };
        let kept = pixels * KEPT_RENDER_BYTES_PER_PIXEL * exp.compressor_settings().len() as u64;
        let images = pixels * IMAGE_BYTES_PER_PIXEL + reference_pixels * REFERENCE_BYTES_PER_PIXEL + kept;
        let btfs: u64 = exp.materials().iter().map(|c| btf_bytes(c, m)).sum();
        let representations = RepresentationMemory::new(exp, shape, m, pixels);
        let per_row = VECTOR_BYTES_PER_ROW
            + if f.runtime.light_moments { MOMENT_BYTES_PER_ROW } else { 0 }
            + if f.runtime.resolve_analytic() { LIT_BIN_BYTES_PER_ROW } else { 0 }
            + if f.runtime.moments_resolve().is_some_and(|r| r.per_pixel()) { POINT_MOMENT_BYTES_PER_ROW } else { 0 };
        let vectors = rows * per_row + n * 16;
        let gpu_on = f.runtime.backend == Backend::Gpu;
        let gpu = if gpu_on { GPU_BASELINE_BYTES } else { 0 };
        let threads = shape.threads.max(1) as u64;
        let compressors: Vec<CompressorMemory> = exp
            .compressor_settings()
            .iter()
            .map(|s| compressor_memory(s, settings, shape.vertices, nnz, threads))
            .collect();
        let methods: Vec<Part> = exp
            .method_settings()
            .iter()
            .map(|s| Part::new(&s.label, method_bytes(s, shape.vertices, shape.cache)))
            .collect();

        let common = PROCESS_BASELINE_BYTES + geometry + lighting;
        // What of T is alive after the transfer stage: all of it, or (streamed) nothing but
        // the two parts a pass holds (one in use, one read ahead), during the baseline's passes.
        let (held, part) = match shape.streamed_part {
            None => (transfer.csr, 0),
            Some(v) => {
                let part_nnz = (nnz as f64 * v as f64 / shape.vertices.max(1) as f64).ceil() as u64;
                (0, 2 * TransferMemory::new(settings, v, part_nnz, shape.threads).load_peak())
            }
        };
        let mut phases = vec![Part::new("frame-time probe", common + FRAME_PROBE_BYTES)];
        phases.push(match shape.streamed_part {
            None => Part::new("transfer build", common + transfer.build_peak()),
            Some(_) => Part::new("transfer: two shards' parts at a time (one read ahead)", common + part),
        });
        if shape.cache && shape.streamed_part.is_none() {
            phases.push(Part::new("transfer cache write", common + transfer.save_peak()));
        }
        let materials = (common + held + btfs).saturating_add(representations.tables);
        if let Some(b) = &representations.largest_build {
            phases.push(Part::new(format!("materials: local-PCA build {}", b.name), materials.saturating_add(b.bytes)));
        }
        let after = materials.saturating_add(images + vectors);
        phases.push(Part::new("materials, baseline and reference", after + part));
        if representations.study > 0 {
            phases.push(Part::new("btf study", after.saturating_add(representations.study)));
        }
        for c in &compressors {
            // A streamed merge builds no form: it holds the shards' parts and the merged form.
            let working = if shape.streamed_part.is_some() { c.form.saturating_mul(2) } else { c.working };
            let cache_write = if shape.cache { c.form.saturating_mul(2) } else { 0 };
            let upload =
                if gpu_on { c.form.saturating_mul(2).saturating_add(gpu + rows * GPU_BYTES_PER_ROW) } else { 0 };
            let bytes = after.saturating_add(working).saturating_add(cache_write).saturating_add(upload);
            phases.push(Part::new(format!("compress {}", c.label), bytes));
        }
        for p in &methods {
            phases.push(Part::new(format!("method {}", p.name), after + gpu + p.bytes));
        }
        Self {
            nnz: estimate,
            transfer,
            streamed_part: shape.streamed_part.map(|_| part),
            baseline: PROCESS_BASELINE_BYTES,
            geometry,
            lighting,
            btfs,
            images,
            vectors,
            gpu,
            compressors,
            methods,
            representations,
            phases,
            worst_case_peak: 0,
        }
    }

    /// The largest phase: the estimated peak of the run.
    pub fn peak(&self) -> &Part {
        self.phases.iter().max_by_key(|p| p.bytes).expect("a run has a transfer phase")
    }

    /// Every part by name (the transfer's buffers, each compressor's and method's), for
    /// printing and `metrics.json`.
    pub fn parts(&self) -> Vec<Part> {
        let t = &self.transfer;
        let mut parts = vec![
            Part::new("process baseline", self.baseline),
            Part::new("mesh, frames and BVHs", self.geometry),
            Part::new("environment map and L", self.lighting),
        ];
        match self.streamed_part {
            None => parts.extend([
                Part::new("T: build staging (u16 columns and counts)", t.staging),
                Part::new("T: CSR (f32 values, usize columns and row pointers)", t.csr),
                Part::new("T: tracing scratch", t.scratch),
                Part::new("T: cache file arrays (u32, u16, f32)", t.file_arrays),
                Part::new("T: cache file encode buffer", t.file_bytes),
            ]),
            Some(b) => parts.push(Part::new("T: the largest shard's part in use and one read ahead (streamed)", b)),
        }
        parts.extend([
            Part::new("BTFs", self.btfs),
            Part::new("images", self.images),
            Part::new("per-row vectors (T L in f64, L*)", self.vectors),
        ]);
        if self.gpu > 0 {
            parts.push(Part::new("wgpu instance", self.gpu));
        }
        for c in &self.compressors {
            match self.streamed_part {
                None => parts.push(Part::new(format!("compressor {} working set", c.label), c.working)),
                Some(_) => parts.push(Part::new(format!("compressor {} shards' parts", c.label), c.form)),
            }
            parts.push(Part::new(format!("compressor {} form", c.label), c.form));
        }
        for p in &self.methods {
            parts.push(Part::new(format!("method {}", p.name), p.bytes));
        }
        let r = &self.representations;
        if r.lpca_settings > 0 {
            parts.push(Part::new(format!("BTF local-PCA tables ({} settings)", r.lpca_settings), r.tables));
        }
        if let Some(b) = &r.largest_build {
            parts.push(Part::new(format!("local-PCA build {} (the largest)", b.name), b.bytes));
        }
        if r.study > 0 {
            parts.push(Part::new("BTF study: scenes, dot products and images", r.study));
        }
        parts
    }

    /// What to change when the run does not fit: the setting behind the largest part of the
    /// peak phase.
    pub fn advice(&self) -> String {
        let peak = self.peak();
        let transfer =
            "lower [transfer] cubemap_resolution or visibility_resolution, or use a mesh with fewer vertices";
        if peak.name == "btf study" || peak.name.starts_with("materials: local-PCA build") {
            let most = self.representations.longest_list.as_ref();
            let which = most.map_or(String::new(), |(label, n)| format!(" (material {label} lists {n})"));
            return format!(
                "list fewer BTF representations{which} or smaller local-PCA settings (clusters, components, \
                 unit = \"view\"), or {transfer}"
            );
        }
        if let Some(label) = peak.name.strip_prefix("compress ") {
            let c = self.compressors.iter().find(|c| c.label == label);
            if c.is_some_and(|c| c.working > self.transfer.csr) {
                return format!("use smaller settings of the compressor {label} (or leave it out), or {transfer}");
            }
        }
        if let Some(label) = peak.name.strip_prefix("method ") {
            if self.methods.iter().any(|p| p.name == label && p.bytes > self.transfer.csr) {
                return format!("lower the order of the [[methods]] setting {label}, or {transfer}");
            }
        }
        let largest = [
            (self.geometry, "use a mesh with fewer triangles"),
            (self.btfs, "lower the materials' BTF resolution or view_grid"),
            (self.images, "lower [runtime] width and height (or report.reference_downscale)"),
        ]
        .into_iter()
        .max_by_key(|p| p.0)
        .expect("three candidates");
        if largest.0 > self.transfer.csr {
            return largest.1.to_string();
        }
        transfer.to_string()
    }

    /// The lines `biscale plan` prints: the peak, its phase, the non-zeros it assumes, each
    /// phase and the available memory.
    pub fn summary(&self, available: &Available) -> String {
        use std::fmt::Write;
        let peak = self.peak();
        let e = &self.nnz;
        let mut s = String::new();
        let _ = writeln!(s, "memory:");
        let _ = writeln!(
            s,
            "  estimated peak {} (in: {}); {} worst case; {} available ({})",
            human(peak.bytes),
            peak.name,
            human(self.worst_case_peak),
            human(available.bytes),
            available.source
        );
        let how = match e.sampled == e.vertices {
            true => format!("every one of the {} vertices traced", e.vertices),
            false => format!(
                "{} of {} vertices traced in {:.2} s: {:.0} +- {:.0} per vertex",
                e.sampled, e.vertices, e.seconds, e.mean_per_vertex, e.std_dev_per_vertex
            ),
        };
        let _ = writeln!(
            s,
            "  non-zeros of T: {} estimated, {} with a {}-sigma margin, {} worst case ({how})",
            e.expected,
            e.upper,
            biscale_core::transfer::NNZ_MARGIN_SIGMAS,
            e.worst_case
        );
        for p in &self.phases {
            let _ = writeln!(s, "  phase {:<40} {:>11}", p.name, human(p.bytes));
        }
        for p in self.parts().iter().filter(|p| p.bytes > 0) {
            let _ = writeln!(s, "  part  {:<52} {:>11}", p.name, human(p.bytes));
        }
        s
    }

    /// The record of `metrics.json` (`peak_rss_bytes` read now: the process's VmHWM).
    pub fn metrics(&self, available: &Available) -> crate::metrics::MemoryMetrics {
        let e = &self.nnz;
        crate::metrics::MemoryMetrics {
            estimate_bytes: self.peak().bytes,
            estimate_phase: self.peak().name.clone(),
            worst_case_bytes: self.worst_case_peak,
            available_bytes: available.bytes,
            available_source: available.source.to_string(),
            peak_rss_bytes: peak_rss(),
            nnz_sampled_vertices: e.sampled,
            nnz_expected: e.expected,
            nnz_upper: e.upper,
            nnz_worst_case: e.worst_case,
            sample_seconds: e.seconds,
            phases: self.phases.clone(),
            parts: self.parts(),
        }
    }
}

/// The BTF memory of one material entry on `m` light directions: the table held twice (the
/// materials' and the shade scene's), a synthesized one half as much again for its synthesis
/// and cache write (measured: 2.3 tables at the peak of a run with the bunny's 32 x 32-texel,
/// 12 x 12-view synthesized BTF), and one dense decoding for the local-PCA settings.
fn btf_bytes(c: &MaterialConfig, m: u64) -> u64 {
    // Copies of the table, in halves.
    let (values, halves) = match c {
        MaterialConfig::Lambertian { .. } => (m, 4),
        MaterialConfig::Phong { view_grid, .. } => (*view_grid as u64 * *view_grid as u64 * m, 4),
        MaterialConfig::Synthesized(s) => {
            let views = (s.view_grid as u64 * s.view_grid as u64).max(1);
            (synthesized_texels(s) * views * m, 5)
        }
        // The table and the shade scene's copy, plus one view's f64 sums while importing.
        MaterialConfig::Bonn(b) => {
            let views = (b.view_grid as u64 * b.view_grid as u64).max(1);
            (b.resolution as u64 * b.resolution as u64 * views * m, 5)
        }
    };
    let lpca = c.representations().all().iter().any(|r| *r != crate::experiment::config::RepresentationSetting::Dense);
    values * BTF_BYTES_PER_VALUE * (halves + 2 * lpca as u64) / 2
}

/// Texels of a synthesized entry's table: one for a flat patch without an albedo map (no height
/// map and zero amplitude: tabulated analytically as one texel, as `stages::materials` builds
/// it), else `resolution^2`. A flat analytic GGX material was charged 8 GB of tables it never
/// builds (its table is 3 MB).
fn synthesized_texels(s: &crate::experiment::config::SynthesizedConfig) -> u64 {
    match s.height_map.is_none() && s.amplitude == 0.0 && s.albedo_map.is_none() {
        true => 1,
        false => s.resolution as u64 * s.resolution as u64,
    }
}

/// Texels and views of a material entry's BTF (an upper bound: a flat synthesized patch is
/// tabulated as one texel).
fn btf_shape(c: &MaterialConfig) -> (u64, u64) {
    let grid = |g: u32| (g as u64 * g as u64).max(1);
    match c {
        MaterialConfig::Lambertian { .. } => (1, 1),
        MaterialConfig::Phong { view_grid, .. } => (1, grid(*view_grid)),
        MaterialConfig::Synthesized(s) => (synthesized_texels(s), grid(s.view_grid)),
        MaterialConfig::Bonn(b) => (b.resolution as u64 * b.resolution as u64, grid(b.view_grid)),
    }
}

/// One local-PCA setting of a BTF on `m` light directions: the table it keeps, the peak of its
/// build and its precomputed dot products in the BTF study.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LpcaMemory {
    /// The table as held (the values dequantized to f32 whatever the storage): `K (C + 1) D`
    /// basis values, `C` weights and a u16 cluster per unit.
    pub table: u64,
    /// Its build: the clustered PCA's model ([`biscale_core::linalg::cpca::build_bytes`]), its
    /// per-unit state ([`LPCA_BYTES_PER_UNIT`]), each thread's subspace iteration, the table,
    /// and its quantized copy and cache encoding where they are made.
    pub build: u64,
    /// The BTF study's dot products for one `L*` (`LightDots`): `K (C + 1) S` RGB f32 per
    /// vertex (`S` the views for texel units, 1 for view units) and a u32 row per vertex, at
    /// most the study's limit (a larger table is not built).
    pub dots: u64,
}

impl LpcaMemory {
    pub fn new(s: &biscale_core::scene::LpcaSettings, texels: u64, views: u64, m: u64, shape: &RunShape) -> Self {
        use biscale_core::scene::{LpcaQuantize, LpcaUnit};
        let (units, d, segments) = match s.unit {
            LpcaUnit::Texel => (texels, views.saturating_mul(3 * m), views),
            LpcaUnit::View => (texels.saturating_mul(views), 3 * m, 1),
        };
        let k = (s.clusters as u64).min(units).min(u16::MAX as u64 - 1).max(1);
        let c = (s.components as u64).min(d);
        let basis = k.saturating_mul(c + 1).saturating_mul(d);
        let table = basis.saturating_mul(4).saturating_add(units.saturating_mul(c * 4 + 2));
        let model = basis.saturating_mul(biscale_core::linalg::cpca::BUILD_BYTES_PER_BASIS_VALUE);
        let per_unit = units.saturating_mul(LPCA_BYTES_PER_UNIT + LPCA_BYTES_PER_UNIT_COMPONENT * c);
        // Per thread: the subspace and its product (d x (C + 4) f64 each) and a block of 8 rows'
        // dot products with every model.
        let per_thread = d.saturating_mul(16 * (c + 4)).saturating_add(k.saturating_mul(c + 1) * 32);
        let copies = 1 + (s.quantize != LpcaQuantize::F32) as u64 + if shape.cache { 2 } else { 0 };
        let build = model
            .saturating_add(per_unit)
            .saturating_add(per_thread.saturating_mul(shape.threads.max(1) as u64))
            .saturating_add(table.saturating_mul(copies));
        let vertices = shape.vertices as u64;
        let dots = vertices
            .saturating_mul(k.saturating_mul(c + 1).saturating_mul(segments))
            .saturating_mul(12)
            .saturating_add(4 * vertices)
            .min(crate::stages::btf_study::MAX_PRECOMPUTED_BYTES);
        Self { table, build, dots }
    }
}

/// The memory of the materials' BTF representations (`representation = [...]`): every
/// local-PCA table is kept for the whole run (a material's own one twice: the materials' and
/// the shade scene's), each is built in turn, and when any is listed the BTF study holds at
/// once, per setting, a copy of the scene (mesh, frames, every other material's dense table,
/// the setting's table), its dot products and its images.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RepresentationMemory {
    /// Local-PCA settings over every material.
    pub lpca_settings: usize,
    /// The local-PCA tables held.
    pub tables: u64,
    /// The largest build, by its setting's label.
    pub largest_build: Option<Part>,
    /// The BTF study (0 when every setting is dense: there is none).
    pub study: u64,
    /// The material with the longest list, and its length.
    pub longest_list: Option<(String, usize)>,
}

impl RepresentationMemory {
    /// The representations of `exp`'s materials on `m` light directions, for a mesh of `shape`
    /// and images of `pixels`.
    pub fn new(exp: &Experiment, shape: &RunShape, m: u64, pixels: u64) -> Self {
        let materials = exp.materials();
        let dense: Vec<u64> = materials
            .iter()
            .map(|c| {
                let (texels, views) = btf_shape(c);
                texels.saturating_mul(views).saturating_mul(m).saturating_mul(BTF_BYTES_PER_VALUE)
            })
            .collect();
        let all_dense = dense.iter().fold(0u64, |a, &b| a.saturating_add(b));
        let mut out = Self::default();
        let (mut variants, mut scene_tables, mut dots) = (0u64, 0u64, 0u64);
        for (c, own_dense) in materials.iter().zip(&dense) {
            let (texels, views) = btf_shape(c);
            let list = c.representations().all();
            if out.longest_list.as_ref().is_none_or(|(_, n)| list.len() > *n) {
                out.longest_list = Some((c.label(), list.len()));
            }
            for (i, r) in list.iter().enumerate() {
                variants += 1;
                let table = match r {
                    RepresentationSetting::Dense => *own_dense,
                    RepresentationSetting::Lpca(s) => {
                        let l = LpcaMemory::new(s, texels, views, m, shape);
                        out.lpca_settings += 1;
                        let copies = if i == 0 { 2 } else { 1 };
                        out.tables = out.tables.saturating_add(l.table.saturating_mul(copies));
                        if out.largest_build.as_ref().is_none_or(|b| l.build > b.bytes) {
                            out.largest_build = Some(Part::new(r.label(), l.build));
                        }
                        dots = dots.saturating_add(l.dots);
                        l.table
                    }
                };
                scene_tables = scene_tables.saturating_add(all_dense - own_dense).saturating_add(table);
            }
        }
        if out.lpca_settings > 0 {
            let scene =
                shape.vertices as u64 * SCENE_BYTES_PER_VERTEX + shape.triangles as u64 * SCENE_BYTES_PER_TRIANGLE;
            // The all-dense scene and one per setting; every job's last image (the primary rays,
            // the all-dense image, each setting's, each precomputed one).
            let renders =
                (2 + variants + out.lpca_settings as u64).saturating_mul(pixels * KEPT_RENDER_BYTES_PER_PIXEL);
            out.study = (variants + 1)
                .saturating_mul(scene)
                .saturating_add(all_dense)
                .saturating_add(scene_tables)
                .saturating_add(dots)
                .saturating_add(renders);
        }
        out
    }
}

/// A compressor setting's working set and form on `T` with `nnz` non-zeros: its kind's own
/// memory model (`registry::Kind::memory`), so a new kind is estimated by what its folder
/// says; a kind the registry does not know is counted as a u32 CSR copy of `T` plus a form of
/// that size (`registry::csr_copy_memory`).
pub fn compressor_memory(
    s: &Setting,
    settings: &TransferSettings,
    vertices: usize,
    nnz: u64,
    threads: u64,
) -> CompressorMemory {
    memory_of(biscale_compressors::registry::find(&s.kind), s, settings, vertices, nnz, threads)
}

/// [`compressor_memory`] with the kind given.
pub(crate) fn memory_of(
    kind: Option<&biscale_compressors::registry::Kind>,
    s: &Setting,
    settings: &TransferSettings,
    vertices: usize,
    nnz: u64,
    threads: u64,
) -> CompressorMemory {
    use biscale_compressors::registry;
    let facts = registry::MemoryFacts {
        light_dirs: settings.light_basis().len() as u64,
        local_dirs: settings.local_basis().len() as u64,
        vertices: vertices as u64,
        nnz,
        threads,
    };
    let model = kind.map_or(registry::csr_copy_memory as fn(&_, &_) -> _, |k| k.memory);
    let m = model(&s.params, &facts);
    CompressorMemory { label: s.label.clone(), working: m.working, form: m.form }
}

/// An SH method setting's matrices: per vertex an `n^2 x n^2` block, dense in f64 while it is
/// traced and assembled into a CSR (8 + 12 bytes per value), then the CSR and its raw form
/// (12 + 8), with the cache on the form's copy and encoding as well (+ 16); one more CSR with
/// bounces (+ 12).
fn method_bytes(s: &Setting, vertices: usize, cache: bool) -> u64 {
    let Ok(p) = crate::experiment::methods::sh::ShParams::parse(&s.params) else { return 0 };
    let n2 = p.order as u64 * p.order as u64;
    let values = vertices as u64 * n2 * n2;
    let per_value = 20 + if cache { 16 } else { 0 } + if p.bounces > 0 { 12 } else { 0 };
    values * per_value + vertices as u64 * n2 * VECTOR_BYTES_PER_ROW
}

/// Estimate the run of `exp` on its loaded geometry and lighting: traces the sample of
/// vertices (well under a second), then counts every buffer.
pub fn estimate(exp: &Experiment, geometry: &Geometry, lighting: &Lighting, cache: bool) -> RunMemory {
    estimate_streamed(exp, geometry, lighting, cache, None)
}

/// [`estimate`] of a sharded merge that streams `T` from parts of at most `streamed_part`
/// vertices (`None`: the run holds `T` whole).
pub fn estimate_streamed(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    cache: bool,
    streamed_part: Option<usize>,
) -> RunMemory {
    let settings = exp.transfer_settings();
    let nnz = sample_nnz(&geometry.transfer, &geometry.mesh.triangles, &settings, NNZ_SAMPLE_VERTICES, exp.file.seed);
    RunMemory::new(exp, &RunShape { streamed_part, ..run_shape(geometry, lighting, cache) }, nnz)
}

/// The [`RunShape`] of a run on its loaded geometry and lighting, holding `T` whole.
pub fn run_shape(geometry: &Geometry, lighting: &Lighting, cache: bool) -> RunShape {
    RunShape {
        vertices: geometry.mesh.vertex_count(),
        triangles: geometry.mesh.triangle_count(),
        env_pixels: lighting.env.width * lighting.env.height,
        cache,
        threads: rayon::current_num_threads(),
        streamed_part: None,
    }
}

/// Estimate the run of `exp` and refuse it when the estimate exceeds the available memory:
/// the one check `biscale run` makes before tracing. Prints the estimate's one-line summary.
pub fn check_run(
    exp: &Experiment,
    geometry: &Geometry,
    lighting: &Lighting,
    cache: bool,
    streamed_part: Option<usize>,
) -> Result<(RunMemory, Available), PipelineError> {
    let memory = estimate_streamed(exp, geometry, lighting, cache, streamed_part);
    let available = available()?;
    let peak = memory.peak();
    crate::util::note(format_args!(
        "memory: estimated peak {} (in: {}; T {} non-zeros from {} sampled vertices), {} available ({})",
        human(peak.bytes),
        peak.name,
        memory.nnz.upper,
        memory.nnz.sampled,
        human(available.bytes),
        available.source
    ));
    refuse_over(&format!("{}: this run", exp.config_path.display()), &memory, &available)?;
    Ok((memory, available))
}

/// The process's baseline and the mesh with its frames and BVHs: what every command that
/// traces holds beside `T` (a shard too: its rays may hit any triangle of the whole mesh).
pub fn process_and_geometry_bytes(mesh: &biscale_core::geometry::Mesh) -> u64 {
    PROCESS_BASELINE_BYTES
        + mesh.triangle_count() as u64 * GEOMETRY_BYTES_PER_TRIANGLE
        + mesh.vertex_count() as u64 * GEOMETRY_BYTES_PER_VERTEX
}

/// Refuse tracing `T` for a command that does not estimate a whole run (`export`,
/// `export-matrix`, `viz`, the Python module's images), as `run` refuses: the process, the
/// geometry and `T`'s build (and its cache write with `cache`) at the sampled non-zeros'
/// upper bound, against the available memory. `what` names the command in the refusal.
pub fn check_transfer(exp: &Experiment, geometry: &Geometry, cache: bool, what: &str) -> Result<(), PipelineError> {
    let settings = exp.transfer_settings();
    let nnz = sample_nnz(&geometry.transfer, &geometry.mesh.triangles, &settings, NNZ_SAMPLE_VERTICES, exp.file.seed);
    let t = TransferMemory::new(&settings, geometry.mesh.vertex_count(), nnz.upper, rayon::current_num_threads());
    let peak = process_and_geometry_bytes(&geometry.mesh) + t.build_peak().max(if cache { t.save_peak() } else { 0 });
    refuse(
        &format!("{}: {what}", exp.config_path.display()),
        peak,
        &format!(" (tracing T: {} non-zeros from {} sampled vertices)", nnz.upper, nnz.sampled),
        &available()?,
        "use a smaller transfer.cubemap_resolution or mesh, or split the precompute with `biscale shard plan`",
    )
}

/// Check this run's own peak so far (VmHWM) against the memory that was available when it
/// started: `biscale run` calls it after each heavy stage (`after` names the stage), so a run
/// the estimate let through but that grew past the limit stops there with the peak, the
/// limit, the estimate and the setting to change, instead of growing on until it is killed.
/// A peak more than a quarter over the estimate (but within the limit) is a warning, once per
/// process: the estimate is off. Nothing is checked where `/proc/self/status` cannot be read.
pub fn check_peak(memory: &RunMemory, available: &Available, after: &str) -> Result<(), PipelineError> {
    check_peak_at(peak_rss(), memory, available, after)
}

/// [`check_peak`] with the peak given.
fn check_peak_at(
    peak: Option<u64>,
    memory: &RunMemory,
    available: &Available,
    after: &str,
) -> Result<(), PipelineError> {
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let Some(peak) = peak else { return Ok(()) };
    let estimate = memory.peak();
    if peak > available.bytes {
        return Err(PipelineError::Core(CoreError::TooLarge(format!(
            "this run's resident memory reached {} by the end of {after}, more than the {} available ({}); \
             it was estimated at {} (peak in: {}), so it was stopped here rather than left to be killed; {}",
            human(peak),
            human(available.bytes),
            available.source,
            human(estimate.bytes),
            estimate.name,
            memory.advice()
        ))));
    }
    let over = estimate.bytes.saturating_add(estimate.bytes / 4);
    if peak > over && !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        log::warn!(
            "memory: this run's peak reached {} by the end of {after}, over its estimate of {} (peak in: {})",
            human(peak),
            human(estimate.bytes),
            estimate.name
        );
    }
    Ok(())
}

/// Err when `memory`'s peak is over `available`: the estimate, its phase, the available
/// memory and the setting to change.
pub fn refuse_over(what: &str, memory: &RunMemory, available: &Available) -> Result<(), PipelineError> {
    let peak = memory.peak();
    refuse(what, peak.bytes, &format!(" (peak in: {})", peak.name), available, &memory.advice())
}

/// Err when `estimate` is over `available`, saying `what` needs how much, what is available and
/// `advice`.
pub fn refuse(
    what: &str,
    estimate: u64,
    detail: &str,
    available: &Available,
    advice: &str,
) -> Result<(), PipelineError> {
    if estimate <= available.bytes {
        return Ok(());
    }
    Err(PipelineError::Core(CoreError::TooLarge(format!(
        "{what} needs about {} of memory at its peak{detail}, more than the {} available ({}); {advice}",
        human(estimate),
        human(available.bytes),
        available.source
    ))))
}

/// Memory the machine can give a new allocation without swapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Available {
    pub bytes: u64,
    /// Where the figure comes from.
    pub source: &'static str,
}

/// The environment variable that caps the memory biscale plans for (bytes, or a number with
/// `K`, `M`, `G` or `T` for powers of 1024): for a machine shared with other work, and for
/// tests that need a small machine.
pub const LIMIT_VAR: &str = "BISCALE_MEMORY_LIMIT";

/// `MemAvailable` from `/proc/meminfo`, or [`FALLBACK_AVAILABLE_BYTES`] where it cannot be
/// read (not Linux, no /proc); at most [`LIMIT_VAR`] when that is set. A value of
/// [`LIMIT_VAR`] that is not a size is an error naming it.
pub fn available() -> Result<Available, PipelineError> {
    let machine = match std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| kib_field(&s, "MemAvailable")) {
        Some(bytes) => Available { bytes, source: "MemAvailable in /proc/meminfo" },
        None => Available {
            bytes: FALLBACK_AVAILABLE_BYTES,
            source: "the fixed limit: MemAvailable could not be read from /proc/meminfo",
        },
    };
    let Some(value) = std::env::var_os(LIMIT_VAR) else { return Ok(machine) };
    let limit = value.to_str().and_then(parse_size).filter(|&b| b > 0).ok_or_else(|| {
        PipelineError::Core(CoreError::Invalid(format!(
            "{LIMIT_VAR}={}: not a size above zero (bytes, or a number with K, M, G or T, powers of 1024)",
            value.to_string_lossy()
        )))
    })?;
    Ok(match limit < machine.bytes {
        true => Available { bytes: limit, source: LIMIT_VAR },
        false => machine,
    })
}

/// A size: a whole number of bytes, or one followed by `K`, `M`, `G` or `T` (optionally
/// `KiB` ...), powers of 1024.
pub fn parse_size(s: &str) -> Option<u64> {
    let s = s.trim();
    let digits = s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    let (number, unit) = s.split_at(digits);
    let shift = match unit.trim().to_ascii_uppercase().trim_end_matches("IB").trim_end_matches('B') {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => return None,
    };
    number.parse::<u64>().ok()?.checked_mul(1 << shift)
}

/// This process's peak resident memory so far (`VmHWM` in `/proc/self/status`), if readable.
pub fn peak_rss() -> Option<u64> {
    kib_field(&std::fs::read_to_string("/proc/self/status").ok()?, "VmHWM")
}

/// The value in bytes of a `Name:   1234 kB` line of `/proc/meminfo` or `/proc/*/status`.
pub fn kib_field(text: &str, name: &str) -> Option<u64> {
    text.lines().find_map(|l| {
        let rest = l.strip_prefix(name)?.strip_prefix(':')?;
        let mut it = rest.split_whitespace();
        let value: u64 = it.next()?.parse().ok()?;
        match it.next() {
            Some("kB") => value.checked_mul(1024),
            _ => None,
        }
    })
}

/// What unwelding `triangles` into a polygon soup adds to [`subdivide_bytes`]: three
/// vertices with a uv each per triangle (20 bytes each), and their `v` and `vt` lines of OBJ
/// text (at most 43 and 30 characters).
pub fn unweld_bytes(triangles: u64) -> u64 {
    triangles.saturating_mul(3).saturating_mul(20 + 43 + 30)
}

/// Peak bytes of `generate subdivide` writing `levels` levels of a mesh of `triangles`
/// triangles and `vertices` vertices (`uvs`: with texture coordinates): the larger of the
/// last level (its input and output meshes and the midpoint map) and the write (the output
/// mesh and its whole OBJ text), plus the process.
pub fn subdivide_bytes(triangles: u64, vertices: u64, uvs: bool, levels: u32) -> u64 {
    if levels == 0 {
        return PROCESS_BASELINE_BYTES + triangles * 12 + vertices * 20;
    }
    let scale = 1u64.checked_shl(2 * levels).unwrap_or(u64::MAX);
    let t_out = triangles.saturating_mul(scale);
    let t_in = t_out / 4;
    // Each level adds a vertex per edge of its input, about 3/2 per triangle (a closed mesh;
    // an open one has a few more), so `n` levels add `T (4^n - 1) / 2` vertices.
    let added = |t: u64| t.saturating_sub(triangles) / 2;
    let v_in = vertices.saturating_add(added(t_in));
    let v_out = vertices.saturating_add(added(t_out));
    let per_vertex = if uvs { 12 + 8 } else { 12 };
    let mesh = |t: u64, v: u64| t.saturating_mul(12 + 4).saturating_add(v.saturating_mul(per_vertex));
    // The midpoint map: a (u32, u32) -> u32 entry and a control byte per edge, at most 8/7
    // full rounded up to a power of two (up to 2.3 slots per edge), old and new table while it
    // grows (1.5 x).
    let edges = t_in.saturating_mul(3) / 2;
    let map = edges.saturating_mul(13 * 35 / 10);
    let level = mesh(t_in, v_in).saturating_add(mesh(t_out, v_out)).saturating_add(map);
    // The OBJ text: `v x y z` lines (a float is at most 13 characters), `vt u v`, and faces
    // `f a b c` (or `f a/a b/b c/c`) with indices of the output's digit count.
    let digits = (v_out.max(1) as f64).log10().floor() as u64 + 2;
    let v_line = 3 + 3 * 13 + 1;
    let vt_line = if uvs { 3 + 2 * 13 + 1 } else { 0 };
    let f_line = if uvs { 2 + 3 * (2 * digits + 1) } else { 2 + 3 * digits };
    let text = v_out.saturating_mul(v_line + vt_line).saturating_add(t_out.saturating_mul(f_line));
    let write = mesh(t_out, v_out).saturating_add(text);
    PROCESS_BASELINE_BYTES.saturating_add(level.max(write))
}

/// `bytes` for people: MiB below a GiB, GiB above.
pub fn human(bytes: u64) -> String {
    let mib = bytes as f64 / (1u64 << 20) as f64;
    if mib < 1024.0 {
        format!("{mib:.1} MiB")
    } else {
        format!("{:.2} GiB", mib / 1024.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The application knows no compressor by name: a toy kind declared as a compressor
    /// folder declares its `KIND` is checked against the transfer shape and estimated by
    /// what it says, and a kind the registry does not know is a u32 CSR copy.
    #[test]
    fn a_new_kind_is_validated_and_estimated_by_its_own_entry() {
        use biscale_compressors::registry::{FormMemory, Kind, MemoryFacts};
        const TOY: Kind = Kind {
            name: "toy",
            about: "a kind only this test knows",
            label: |_| Ok("toy".into()),
            check: |_| Ok(()),
            build: |_| Err("a toy builds nothing".to_string().into()),
            fits: |p, t| match p["k"].as_u64() {
                Some(k) if k as usize > t.light_basis().len() => Err(format!("k = {k} is too many")),
                _ => Ok(()),
            },
            memory: |_, t: &MemoryFacts| FormMemory { working: 3 * t.nnz + t.threads, form: t.rows() },
            report: |_| vec![],
            role: biscale_compressors::registry::Role::Other,
            flops: |_| None,
        };
        let settings = TransferSettings::new(4, 8, 2).unwrap();
        let setting =
            |k: u64| Setting { label: format!("toy-{k}"), kind: "toy".into(), params: serde_json::json!({ "k": k }) };
        let e = crate::experiment::config::fits_of(Some(&TOY), &setting(1000), &settings).unwrap_err();
        assert_eq!(e, "toy-1000: k = 1000 is too many");
        crate::experiment::config::fits_of(Some(&TOY), &setting(3), &settings).unwrap();
        let m = memory_of(Some(&TOY), &setting(3), &settings, 10, 1000, 2);
        assert_eq!((m.working, m.form), (3002, 10 * 4));
        let unknown = memory_of(None, &setting(3), &settings, 10, 1000, 2);
        let csr = 1000 * 8 + (10 * 4 + 1) * 4;
        assert_eq!((unknown.working, unknown.form), (2 * csr, csr));
    }

    #[test]
    fn proc_fields_are_read_in_bytes() {
        let meminfo = "MemTotal:       24600000 kB\nMemFree:        20000000 kB\nMemAvailable:   23978264 kB\n";
        assert_eq!(kib_field(meminfo, "MemAvailable"), Some(23_978_264 * 1024));
        assert_eq!(kib_field(meminfo, "MemTotal"), Some(24_600_000 * 1024));
        // A prefix of another name is not that name; a line without its unit is not read.
        assert_eq!(kib_field(meminfo, "Mem"), None);
        assert_eq!(kib_field("VmHWM:\t  123 pages\n", "VmHWM"), None);
        assert_eq!(kib_field("Name:\tbiscale\nVmHWM:\t   16384 kB\n", "VmHWM"), Some(16 << 20));
        // This process has a peak, above its code alone.
        assert!(peak_rss().is_some_and(|b| b > 1 << 20));
    }

    #[test]
    fn sizes_parse_in_powers_of_1024() {
        assert_eq!(parse_size("1234"), Some(1234));
        assert_eq!(parse_size("64M"), Some(64 << 20));
        assert_eq!(parse_size("2GiB"), Some(2 << 30));
        assert_eq!(parse_size(" 3 k "), Some(3 << 10));
        assert_eq!(parse_size("1T"), Some(1 << 40));
        for bad in ["", "M", "1.5G", "-1", "12 apples", "99999999999999999999"] {
            assert_eq!(parse_size(bad), None, "{bad}");
        }
        assert_eq!(parse_size("99999999999T"), None, "overflow");
    }

    #[test]
    fn a_run_over_the_available_memory_is_refused_with_the_setting_to_change() {
        let dir = tempfile::tempdir().unwrap();
        let exp = crate::experiment::config::Experiment::load(&smoke_at(dir.path(), 32)).unwrap();
        let shape =
            RunShape { vertices: 1839, triangles: 3674, env_pixels: 0, cache: true, threads: 2, streamed_part: None };
        let nnz = NnzEstimate::exact(1839, 5_000_000, &exp.transfer_settings());
        let m = RunMemory::new(&exp, &shape, nnz);
        let peak = m.peak().bytes;
        let fits = Available { bytes: peak, source: "test" };
        assert!(refuse_over("x", &m, &fits).is_ok());
        let short = Available { bytes: peak - 1, source: "test" };
        let e = refuse_over("configs/x.toml: this run", &m, &short).unwrap_err().to_string();
        assert!(e.contains("configs/x.toml: this run needs about") && e.contains("available (test)"), "{e}");
        assert!(e.contains("cubemap_resolution or visibility_resolution"), "{e}");
        assert!(e.contains(&human(peak)), "{e}");
    }

    #[test]
    fn phases_add_what_is_alive_together() {
        // The sparse compressor with the cache on: T's CSR (12 bytes per non-zero), its u32
        // form (8), the form's copy and its encoding for the cache (8 + 8): 36 bytes per
        // non-zero over the rest, more than the build (4 + 12) and T's own cache write
        // (12 + 6 + 6).
        let dir = tempfile::tempdir().unwrap();
        let exp = crate::experiment::config::Experiment::load(&smoke_at(dir.path(), 32)).unwrap();
        let shape =
            RunShape { vertices: 1000, triangles: 2000, env_pixels: 0, cache: true, threads: 2, streamed_part: None };
        let settings = exp.transfer_settings();
        let at = |nnz| RunMemory::new(&exp, &shape, NnzEstimate::exact(1000, nnz, &settings));
        let (small, large) = (at(1_000_000), at(2_000_000));
        // The frame-time probe's fixed 64 MiB beside the geometry and the light, before T:
        // the peak of a run this small, whatever T holds.
        let phase = |m: &RunMemory, name: &str| m.phases.iter().find(|p| p.name == name).unwrap().bytes;
        let probe = phase(&small, "frame-time probe");
        assert_eq!(probe, small.baseline + small.geometry + small.lighting + FRAME_PROBE_BYTES);
        assert_eq!(probe, phase(&large, "frame-time probe"));
        assert_eq!(small.peak().name, "frame-time probe");
        assert_eq!(phase(&large, "compress sparse") - phase(&small, "compress sparse"), 36 * 1_000_000);
        assert_eq!(at(5_000_000).peak().name, "compress sparse");
        assert_eq!(phase(&large, "transfer build") - phase(&small, "transfer build"), 16 * 1_000_000);
        let no_cache =
            RunMemory::new(&exp, &RunShape { cache: false, ..shape }, NnzEstimate::exact(1000, 1_000_000, &settings));
        // The cache adds the sparse form's copy and encoding: (8 per non-zero, 4 per row
        // pointer) twice.
        let sparse = |m: &RunMemory| phase(m, "compress sparse");
        assert_eq!(sparse(&small) - sparse(&no_cache), 2 * (8 * 1_000_000 + 4 * (64_000 + 1)));
        // The worst case (N / 2 = 3072 per vertex) is the same count at 3,072,000 non-zeros.
        assert_eq!(small.worst_case_peak, at(3_072_000).peak().bytes);
    }

    #[test]
    fn a_streamed_merge_holds_two_parts_of_t_and_the_forms_not_t() {
        // 1000 vertices at 1,000 non-zeros each in parts of at most 250: the streamed merge
        // holds two parts as they are read (each a quarter of T's file arrays and CSR) instead of T's
        // CSR, and each separable form twice (the shards' parts, the merged form) instead of
        // the compressor's working set; it builds no T.
        let dir = tempfile::tempdir().unwrap();
        let exp = crate::experiment::config::Experiment::load(&smoke_at(dir.path(), 32)).unwrap();
        let settings = exp.transfer_settings();
        let shape =
            RunShape { vertices: 1000, triangles: 2000, env_pixels: 0, cache: false, threads: 2, streamed_part: None };
        let nnz = NnzEstimate::exact(1000, 1_000_000, &settings);
        let whole = RunMemory::new(&exp, &shape, nnz);
        let streamed = RunMemory::new(&exp, &RunShape { streamed_part: Some(250), ..shape }, nnz);
        let part = 2 * TransferMemory::new(&settings, 250, 250_000, 2).load_peak();
        assert_eq!(streamed.streamed_part, Some(part));
        let phase = |m: &RunMemory, name: &str| m.phases.iter().find(|p| p.name == name).map(|p| p.bytes);
        assert_eq!(phase(&streamed, "transfer build"), None);
        let base = |m: &RunMemory| phase(m, "materials, baseline and reference").unwrap();
        assert_eq!(base(&streamed), base(&whole) - whole.transfer.csr + part);
        let sparse = &whole.compressors[0];
        assert_eq!(
            phase(&streamed, "compress sparse").unwrap() - base(&streamed) + part,
            2 * sparse.form,
            "the parts and the merged form"
        );
        // Beyond the frame-time probe's fixed phase, the peak of a run this small.
        let beyond_probe =
            |m: &RunMemory| m.phases.iter().filter(|p| p.name != "frame-time probe").map(|p| p.bytes).max().unwrap();
        assert!(beyond_probe(&streamed) < beyond_probe(&whole));
        let names: Vec<String> = streamed.parts().into_iter().map(|p| p.name).collect();
        assert!(names.iter().any(|n| n.contains("streamed")) && !names.iter().any(|n| n.contains("CSR")), "{names:?}");
    }

    #[test]
    fn an_absurd_compressor_setting_saturates_instead_of_overflowing() {
        // The compressor refuses it with its own message; the estimate must not panic first.
        let settings = TransferSettings::new(104, 104, 64).unwrap();
        let s = Setting {
            label: "cpca-huge".into(),
            kind: "cpca".into(),
            params: serde_json::json!({ "clusters": 65534, "components": 1u64 << 40, "unit": "vertex" }),
        };
        let c = compressor_memory(&s, &settings, 1 << 20, 1 << 40, 16);
        assert_eq!(c.working, u64::MAX);
        // A modest one is the model: 4 clusters x (2 + 1) vectors of N = 6144 values, 16 bytes
        // each twice while it builds, then the f32 basis and per row a cluster and 2 weights.
        let settings = TransferSettings::new(32, 32, 8).unwrap();
        let small = Setting { params: serde_json::json!({ "clusters": 4, "components": 2 }), ..s };
        let c = compressor_memory(&small, &settings, 10, 1000, 2);
        let values = 4 * 3 * 6144;
        assert_eq!(c.form, values * 4 + 640 * 12);
        assert_eq!(c.working, 2 * values * 16 + 640 * 24 + c.form);
    }

    /// A config on the bunny with a Phong material `glossy` (4 x 4 views, on 4 x 4 light bins)
    /// whose `representation` is `list`, written into `dir`.
    fn listing(dir: &std::path::Path, list: &str) -> std::path::PathBuf {
        let bunny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/bunny.obj");
        let cfg = dir.join("x.toml");
        std::fs::write(
            &cfg,
            format!(
                "name = \"x\"\n[scene]\nmesh = \"{}\"\n[scene.material]\nname = \"glossy\"\nkind = \"phong\"\n\
                 kd = [0.5, 0.5, 0.5]\nks = [0.3, 0.3, 0.3]\nexponent = 20.0\nview_grid = 4\nrepresentation = [{list}]\n\
                 [lighting]\nconstant = [1.0, 1.0, 1.0]\n[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 8\n\
                 local_grid = 4\n[[compressors]]\nkind = \"sparse\"\n[runtime]\nwidth = 64\nheight = 48\n",
                bunny.display()
            ),
        )
        .unwrap();
        cfg
    }

    /// Issue 36: a material's `representation` list of 400 local-PCA settings was neither
    /// capped nor estimated (40 MiB estimated, 4.9 GiB used). A list is capped like a sweep,
    /// at the material; and every setting's table, build and BTF-study share (a copy of the
    /// scene, its dot products, its images) is estimated. Against the run's own data: the
    /// tables the materials stage builds and the dot-product tables the study allocates per
    /// setting (`LightDots::bytes_needed` of each study scene). The table model is exact (a
    /// setting keeps `K (C + 1) D` basis values, C weights and a cluster per unit), so within
    /// 1%. The study's estimate is checked against the sum of what the study holds, counted
    /// from the run's own arrays (the dot products, 90% of it here, a copy of the mesh and
    /// frames per scene, the tables, and an f32 RGB image per job): at least that, and within
    /// 5% (the model's images also count their mask and coverage, 17 bytes a pixel, not 12).
    #[test]
    fn lpca_representation_lists_are_capped_and_estimated() {
        let dir = tempfile::tempdir().unwrap();
        let lpca =
            |k: usize, c: usize| format!("{{ kind = \"lpca\", clusters = {k}, components = {c}, unit = \"view\" }}");
        // 16 views of 16 bins: at most 16 clusters of 48 values.
        let settings: Vec<String> = (1..=16).flat_map(|k| (1..=25).map(move |c| lpca(k, c))).collect();
        assert_eq!(settings.len(), 400);

        // The cap is checked at load (the sizes at the build): any 1001 distinct settings.
        let over: Vec<String> = (1..=1001).map(|c| lpca(1, c)).collect();
        let e = Experiment::load(&listing(dir.path(), &over.join(", "))).unwrap_err().to_string();
        assert!(
            e.contains(
                "x.toml:4:1: material: the representation list of glossy has 1001 settings, over the limit of 1000"
            ),
            "located at the material: {e}"
        );
        Experiment::load(&listing(dir.path(), &over[..1000].join(", "))).unwrap();

        let exp = Experiment::load(&listing(dir.path(), &settings.join(", "))).unwrap();
        let geometry = crate::stages::scene::load_geometry(&exp).unwrap();
        let mesh = &geometry.mesh;
        let shape = RunShape {
            vertices: mesh.vertex_count(),
            triangles: mesh.triangle_count(),
            env_pixels: 0,
            cache: false,
            threads: 2,
            streamed_part: None,
        };
        let m = RunMemory::new(&exp, &shape, NnzEstimate::exact(shape.vertices, 100_000, &exp.transfer_settings()));
        let r = &m.representations;
        assert_eq!((r.lpca_settings, r.longest_list.clone()), (400, Some(("glossy".to_string(), 400))));

        // What the run builds and allocates.
        let materials =
            crate::stages::materials::load_materials(&exp, mesh, exp.transfer_settings().local_basis(), None).unwrap();
        let held = |b: &biscale_core::scene::BtfRepresentation| match b {
            biscale_core::scene::BtfRepresentation::Lpca(l) => {
                (l.basis_values().len() * 4 + l.weight_values().len() * 4 + l.cluster_ids().len() * 2) as u64
            }
            biscale_core::scene::BtfRepresentation::Dense(_) => 0,
        };
        let own = held(&materials.materials[0].btf);
        let others: u64 = materials.variants.iter().filter_map(|v| v.representation.as_ref()).map(held).sum();
        let tables = others + 2 * own;
        assert!(r.tables >= tables && (r.tables as f64) < 1.01 * tables as f64, "{} {tables}", r.tables);
        let dots: u64 = materials
            .variants
            .iter()
            .map(|v| {
                let scene = biscale_core::scene::ShadeScene::new(
                    mesh.clone(),
                    geometry.transfer.frames().to_vec(),
                    materials.with_variant(v),
                    materials.triangle_materials.clone(),
                )
                .unwrap();
                biscale_shading::precomputed::LightDots::bytes_needed(&scene)
            })
            .sum();
        assert!(dots > 900 << 20, "the study's dot products alone: {}", human(dots));
        // Besides, the study holds a copy of the scene's mesh and frames for the all-dense
        // image and each setting, each setting's table, and every job's last image (the
        // primary rays, the all-dense image, each setting's direct and precomputed image:
        // 12 bytes of f32 RGB per pixel at least).
        let scene = (mesh.positions.len() * 12
            + mesh.uvs.as_ref().map_or(0, |u| u.len() * 8)
            + mesh.triangles.len() * 12
            + std::mem::size_of_val(geometry.transfer.frames())) as u64;
        let images = (2 + 2 * 400) * 64 * 48 * 12;
        let study = dots + 401 * scene + (others + own) + images;
        assert!(r.study >= study && (r.study as f64) < 1.05 * study as f64, "{} {study}", r.study);

        // Refused up front, in the study, naming the material.
        assert_eq!(m.peak().name, "btf study");
        let e = refuse_over("x", &m, &Available { bytes: 1 << 30, source: "test" }).unwrap_err().to_string();
        assert!(e.contains("(peak in: btf study)") && e.contains("material glossy lists 400"), "{e}");
    }

    /// Issue 36: the run's own peak is checked against the limit between its stages, and a run
    /// past it stops with a clear error (the peak, the limit, the estimate and the advice).
    #[test]
    fn the_runs_own_peak_is_checked_against_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let exp = crate::experiment::config::Experiment::load(&smoke_at(dir.path(), 32)).unwrap();
        let shape =
            RunShape { vertices: 1839, triangles: 3674, env_pixels: 0, cache: true, threads: 2, streamed_part: None };
        let m = RunMemory::new(&exp, &shape, NnzEstimate::exact(1839, 5_000_000, &exp.transfer_settings()));
        let limit = Available { bytes: 1 << 30, source: "BISCALE_MEMORY_LIMIT" };
        check_peak_at(Some(1 << 30), &m, &limit, "the transfer stage").unwrap();
        check_peak_at(None, &m, &limit, "the transfer stage").unwrap();
        let e = check_peak_at(Some((1 << 30) + 1), &m, &limit, "the BTF study").unwrap_err().to_string();
        assert!(
            e.contains(
                "reached 1.00 GiB by the end of the BTF study, more than the 1.00 GiB available (BISCALE_MEMORY_LIMIT)"
            ) && e.contains(&format!("estimated at {} (peak in: {})", human(m.peak().bytes), m.peak().name))
                && e.contains("stopped here"),
            "{e}"
        );
        // This process, now: its own peak is read and is within a generous limit.
        check_peak(&m, &Available { bytes: u64::MAX, source: "test" }, "now").unwrap();
        let tiny = Available { bytes: 1 << 20, source: "test" };
        assert!(check_peak(&m, &tiny, "now").is_err(), "this process is over 1 MiB");
    }

    /// A one-compressor (sparse) config on the bunny at cubemap `r`, written into `dir`.
    fn smoke_at(dir: &std::path::Path, r: u32) -> std::path::PathBuf {
        let bunny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/bunny.obj");
        let cfg = dir.join("x.toml");
        std::fs::write(
            &cfg,
            format!(
                "name = \"x\"\n[scene]\nmesh = \"{}\"\n[lighting]\nconstant = [1.0, 1.0, 1.0]\n[transfer]\n\
                 cubemap_resolution = {r}\nvisibility_resolution = {r}\nlocal_grid = 8\n[[compressors]]\nkind = \"sparse\"\n\
                 [runtime]\nwidth = 64\nheight = 48\n",
                bunny.display()
            ),
        )
        .unwrap();
        cfg
    }

    #[test]
    fn subdivision_estimate_bounds_the_mesh_and_its_text() {
        // The bunny (3,674 triangles, 1,839 vertices), 4 levels: 940,544 triangles; measured
        // 62 MiB peak writing a 36.4 MB OBJ (BENCHMARKS.md).
        let e = subdivide_bytes(3674, 1839, false, 4);
        assert!(e > 62 << 20 && e < 80 << 20, "{}", human(e));
        // Each level about quadruples it.
        let e5 = subdivide_bytes(3674, 1839, false, 5);
        assert!(e5 > 3 * (e - PROCESS_BASELINE_BYTES) && e5 < 5 * e, "{} {}", human(e), human(e5));
        assert!(subdivide_bytes(3674, 1839, true, 4) > e);
        // Absurd requests saturate instead of overflowing.
        assert_eq!(subdivide_bytes(u64::MAX / 2, 1, false, 40), u64::MAX);
    }
}
