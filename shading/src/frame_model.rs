//! The frame-time model of the runtime (docs/DESIGN.md, "Frame-time model"): for each stage
//! of a frame, the bytes it must move through memory at least once and the floating-point
//! operations it must do, and from them its **floor** on a processor of a given memory
//! bandwidth and fp32 peak, `max(bytes / bandwidth, flops / peak)`: no implementation of the
//! stage runs faster there. On the machine of the run (bandwidth and peak measured by the run's
//! probe) the floor says how far a measured time is from what the hardware allows; on a named
//! GPU class (its published bandwidth and peak, [`Processor::h100_sxm`]) it is a
//! **projection**: a lower bound on that GPU's time, so the frame rate it implies is a ceiling,
//! and it is labelled so wherever it is printed, never mixed with a measured figure.
//!
//! What is counted, per frame of `samples = width x height x samples per pixel`:
//!
//! * **gather** (a light change): the form's stored bytes, the light read (`12 N` bytes, RGB
//!   f32) and `L*` written (`12 rows`); `3 flops_per_gather` (the form's count is monochrome).
//!   With light moments the three moments share one pass over the form (the CPU's fused
//!   gather): the form once, three lights and three `L*`, `9 flops_per_gather`; then the
//!   **vertex resolve**: the three moment `L*` read and `L*'` written, [`RESOLVE_ROW_FLOPS`]
//!   per row (the pipeline runs it under every resolve: the `L*` error is the vertex one).
//! * **shade** (a view change; a light change too): compulsory traffic only (the `L*`, or the
//!   three moment gathers, read once; every material's BTF bytes once; per sample the
//!   visibility id written and read and the rgba32f sample written, 24 bytes); flops per
//!   sample: [`HIT_FLOPS`] (ray, barycentrics, frame, view) plus, per bin `M`,
//!   [`LSTAR_BIN_FLOPS`] (`"vertex"`), `3 x` [`TABLE_BIN_FLOPS`] `+` [`LSTAR_BIN_FLOPS`]
//!   (`"pixel"`: three vertices resolved at the sample, their rows blended and dotted with the
//!   BTF once) or `3 x (`[`ANALYTIC_BIN_FLOPS`]` + `[`brdf_flops`]`)` (`"pixel_analytic"`,
//!   the scene's dearest analytic material).
//!
//! Flops are counted from the kernels (`gpu/src/shade/*.wgsl`, `gpu/src/moments/*.wgsl`, the
//! CPU's lanes): a multiply, an add, a compare-and-select, a square root or a division one
//! each; rounded, good to about 20%. Where two algorithms do the same work, the cheaper one
//! is counted (the table resolve: the WGSL dots each of a bin's four shares with the BTF as it
//! spreads them, four times the BTF work of accumulating the rows and dotting them once, as the
//! CPU does), so a floor is one for every implementation. Caches are assumed perfect (each byte once), which is what makes it a
//! floor.

use crate::runtime::MomentsResolve;
use serde::{Deserialize, Serialize};

/// Flops of the vertex resolve per row (bin of a vertex): the power (three dots), the
/// luminance direction and its frame coordinates, the grid map (polynomial arctangent) and
/// the four bilinear shares (`moments/bins.wgsl`'s `spread`, `resolve.wgsl`).
pub const RESOLVE_ROW_FLOPS: f64 = 130.0;
/// Flops per shading sample before the bins: the pixel ray, Moller-Trumbore barycentrics, the
/// interpolated frame and the view in it, the view grid's bilinear weights.
pub const HIT_FLOPS: f64 = 200.0;
/// Flops per bin of the `L*` pass: three vertices' `L*` blended (RGB), four view samples of
/// the BTF weighted, the product accumulated.
pub const LSTAR_BIN_FLOPS: f64 = 45.0;
/// Flops per bin and vertex of the table resolve at a sample: `spread` (about 110) and its four
/// shares accumulated into the vertex's resolved row (16); the blend of the three rows and the
/// BTF dot are [`LSTAR_BIN_FLOPS`] per bin.
pub const TABLE_BIN_FLOPS: f64 = 126.0;
/// Flops per bin and vertex of the analytic resolve besides the BRDF: the power, the
/// luminance direction in the sample's frame, its normalisation, the product accumulated.
pub const ANALYTIC_BIN_FLOPS: f64 = 66.0;

/// Flops of one evaluation of a BRDF kind (`Brdf::kind`'s name) in `gpu/src/shade/brdf.wgsl`;
/// `None` for a name it does not know.
pub fn brdf_flops(kind: &str) -> Option<f64> {
    Some(match kind {
        "lambertian" => 3.0,
        "phong" => 20.0,
        "ashikhmin-shirley" => 70.0,
        "rough-conductor" => 140.0,
        "rough-plastic" => 115.0,
        _ => return None,
    })
}

/// A processor the model is evaluated on: its memory bandwidth and fp32 peak, and where the
/// two numbers come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Processor {
    pub name: String,
    pub bandwidth_gb_s: f64,
    pub peak_gflop_s: f64,
    /// `measured` (the run's probe) or the publication the numbers are from.
    pub source: String,
}

impl Processor {
    /// The GPU class the projections name: NVIDIA H100 SXM5, 3.35 TB/s of HBM3 and 66.9
    /// TFLOP/s of fp32 (non-tensor), as NVIDIA's H100 datasheet gives them.
    pub fn h100_sxm() -> Self {
        Processor {
            name: "NVIDIA H100 SXM5 (H100-class)".into(),
            bandwidth_gb_s: 3350.0,
            peak_gflop_s: 66_900.0,
            source: "published: NVIDIA H100 datasheet, 3.35 TB/s HBM3, 66.9 TFLOP/s fp32 non-tensor".into(),
        }
    }

    /// The floor of `cost` here, in milliseconds.
    pub fn floor_ms(&self, cost: &StageCost) -> f64 {
        let memory = cost.bytes / (self.bandwidth_gb_s * 1e9);
        let compute = cost.flops / (self.peak_gflop_s * 1e9);
        memory.max(compute) * 1e3
    }
}

/// What one stage of a frame must move and compute.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageCost {
    /// `gather`, `moment gathers + vertex resolve` or `shade (<resolve>)`.
    pub stage: String,
    pub bytes: f64,
    pub flops: f64,
}

impl StageCost {
    fn plus(self, other: StageCost, stage: &str) -> StageCost {
        StageCost { stage: stage.into(), bytes: self.bytes + other.bytes, flops: self.flops + other.flops }
    }
}

/// What the model needs of a run and a form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameShape {
    /// Vertices and bins per vertex (`rows = vertices x bins`), light texels (columns).
    pub vertices: u64,
    pub bins: u64,
    pub cols: u64,
    /// Shading samples per frame (`width x height x samples per pixel`).
    pub samples: u64,
    /// The form's stored bytes and monochrome gather flops.
    pub form_bytes: u64,
    pub flops_per_gather: u64,
    /// Every material's BTF bytes.
    pub material_bytes: u64,
    /// Light moments, and where they are resolved (`Vertex` without them).
    pub moments: bool,
    pub resolve: MomentsResolve,
    /// [`brdf_flops`] of the dearest analytic material (`"pixel_analytic"`; 0 otherwise).
    pub brdf_flops: f64,
}

impl FrameShape {
    fn rows(&self) -> f64 {
        (self.vertices * self.bins) as f64
    }

    /// A light change's gather: the form's gather, or with light moments the three fused
    /// moment gathers and the vertex resolve.
    pub fn gather(&self) -> StageCost {
        let (rows, cols) = (self.rows(), self.cols as f64);
        let (form, flops) = (self.form_bytes as f64, self.flops_per_gather as f64);
        match self.moments {
            false => StageCost { stage: "gather".into(), bytes: form + 12.0 * (cols + rows), flops: 3.0 * flops },
            true => {
                let gathers =
                    StageCost { stage: String::new(), bytes: form + 36.0 * (cols + rows), flops: 9.0 * flops };
                let resolve = StageCost { stage: String::new(), bytes: 48.0 * rows, flops: RESOLVE_ROW_FLOPS * rows };
                gathers.plus(resolve, "moment gathers + vertex resolve")
            }
        }
    }

    /// A view change: the shading pass over every sample.
    pub fn shade(&self) -> StageCost {
        let (rows, bins, samples) = (self.rows(), self.bins as f64, self.samples as f64);
        let per_bin = match self.resolve {
            MomentsResolve::Vertex => LSTAR_BIN_FLOPS,
            MomentsResolve::Pixel => 3.0 * TABLE_BIN_FLOPS + LSTAR_BIN_FLOPS,
            MomentsResolve::PixelAnalytic => 3.0 * (ANALYTIC_BIN_FLOPS + self.brdf_flops),
        };
        let read = match self.resolve.per_pixel() {
            true => 36.0 * rows,
            false => 12.0 * rows,
        };
        StageCost {
            stage: format!("shade ({})", self.resolve.name()),
            bytes: read + self.material_bytes as f64 + 24.0 * samples,
            flops: samples * (HIT_FLOPS + bins * per_bin),
        }
    }

    /// The same frame at `samples` shading samples (another resolution).
    pub fn at_samples(self, samples: u64) -> Self {
        FrameShape { samples, ..self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(resolve: MomentsResolve) -> FrameShape {
        FrameShape {
            vertices: 1000,
            bins: 64,
            cols: 6144,
            samples: 320 * 240 * 4,
            form_bytes: 5_000_000,
            flops_per_gather: 2_000_000,
            material_bytes: 100_000,
            moments: resolve.per_pixel(),
            resolve,
            brdf_flops: if resolve == MomentsResolve::PixelAnalytic {
                brdf_flops("rough-conductor").unwrap()
            } else {
                0.0
            },
        }
    }

    #[test]
    fn counts_follow_the_module_docs() {
        let s = shape(MomentsResolve::Vertex);
        let g = s.gather();
        assert_eq!(g.bytes, 5e6 + 12.0 * (6144.0 + 64_000.0));
        assert_eq!(g.flops, 6e6);
        let sh = s.shade();
        assert_eq!(sh.bytes, 12.0 * 64_000.0 + 1e5 + 24.0 * 307_200.0);
        assert_eq!(sh.flops, 307_200.0 * (200.0 + 64.0 * 45.0));
        let a = shape(MomentsResolve::PixelAnalytic);
        assert_eq!(a.gather().flops, 18e6 + 130.0 * 64_000.0);
        assert_eq!(a.shade().flops, 307_200.0 * (200.0 + 64.0 * 3.0 * (66.0 + 140.0)));
        assert_eq!(a.shade().stage, "shade (pixel_analytic)");
        let p = shape(MomentsResolve::Pixel);
        assert_eq!(p.shade().flops, 307_200.0 * (200.0 + 64.0 * (3.0 * 126.0 + 45.0)));
    }

    #[test]
    fn the_floor_is_the_slower_of_memory_and_compute() {
        let p = Processor { name: "p".into(), bandwidth_gb_s: 10.0, peak_gflop_s: 100.0, source: "test".into() };
        let memory_bound = StageCost { stage: "s".into(), bytes: 1e9, flops: 1e9 };
        assert!((p.floor_ms(&memory_bound) - 100.0).abs() < 1e-9);
        let compute_bound = StageCost { stage: "s".into(), bytes: 1e6, flops: 1e11 };
        assert!((p.floor_ms(&compute_bound) - 1000.0).abs() < 1e-9);
        // Four times the samples: four times a sample-bound shade.
        let s = shape(MomentsResolve::Pixel);
        let h = Processor::h100_sxm();
        let ratio = h.floor_ms(&s.at_samples(4 * s.samples).shade()) / h.floor_ms(&s.shade());
        assert!((ratio - 4.0).abs() < 1e-9, "{ratio}");
    }

    #[test]
    fn every_brdf_kind_has_a_count() {
        for k in ["lambertian", "phong", "ashikhmin-shirley", "rough-conductor", "rough-plastic"] {
            assert!(brdf_flops(k).is_some(), "{k}");
        }
        assert_eq!(brdf_flops("velvet"), None);
    }
}
