//! The wgpu backend of the pipeline (`runtime.backend = "gpu"`, cargo feature `gpu`): the
//! same compressed forms gathered and shaded by `biscale-gpu`, timed with GPU timestamps
//! (submit-to-idle wall clock on a CPU adapter), and checked against the CPU results of the
//! same run.

use crate::error::Result;
use crate::metrics::{GpuRecord, ImageErrors, Timing};
use biscale_core::compress::CompressedForm;
use biscale_core::gather::moments::LightMoments;
use biscale_core::gather::relative_l2_error;
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::LightVector;
use biscale_core::scene::{Background, Camera, Render, ShadeScene};
use biscale_gpu::{GpuContext, GpuGather, GpuMoments, GpuShader};
use biscale_kernels::KernelDesc;
use biscale_shading::image::compare;
use biscale_shading::runtime::MomentsResolve;
use biscale_shading::synth::Brdf;

/// A device plus the shader for the run's scene and camera.
pub struct GpuBackend {
    ctx: GpuContext,
    shader: GpuShader,
    /// The shader's camera, for the background behind its image.
    camera: Camera,
    pub adapter: String,
}

impl GpuBackend {
    /// The device and the shader of `scene` seen by `camera`, its materials given the analytic
    /// BRDFs `analytic` (one per material, `None` for a table; what `"pixel_analytic"` shades
    /// with, uploaded once here).
    pub fn new(scene: &ShadeScene, camera: &Camera, analytic: &[Option<Brdf>]) -> Result<Self> {
        let ctx = GpuContext::new()?;
        let a = ctx.adapter();
        let adapter = format!("{} ({:?}, {})", a.name, a.backend, a.driver);
        let mut shader = GpuShader::new(&ctx, scene, camera)?;
        if analytic.iter().any(Option::is_some) {
            shader.set_brdfs(analytic)?;
        }
        log::info!("gpu: {adapter}");
        Ok(Self { ctx, shader, camera: *camera, adapter })
    }

    /// The same device with a shader for another scene (a method's materials on its basis).
    pub fn for_scene(&self, scene: &ShadeScene, camera: &Camera) -> Result<Self> {
        let shader = GpuShader::new(&self.ctx, scene, camera)?;
        Ok(Self { ctx: self.ctx.clone(), shader, camera: *camera, adapter: self.adapter.clone() })
    }

    /// Gather `form` with its program `kernels` and shade it on the GPU; errors are measured
    /// against the f64 product (`exact`) and the CPU render of the same form (`cpu`, over the
    /// CPU's coverage), after the GPU image gets the CPU's `background` behind it (silhouette
    /// pixels of an anti-aliased image are part background).
    ///
    /// With light `moments` the form is gathered three times on the GPU (once per moment) and
    /// the three `L*` resolved into `L*'` by a GPU pass ([`GpuMoments`]), which the shader reads
    /// in place: no round trip through the host. The gather time is then that of the three
    /// gathers plus the resolve pass, timed together in one submission (with GPU timestamps,
    /// the sum of their passes: the buffer copies between the gathers fall outside them);
    /// `L*'` is read back only for the error record. The image is shaded with `resolve`: the
    /// per-pixel resolves read the three gathers in place (`GpuShader::shade_moments`),
    /// `PixelAnalytic` with the BRDFs [`Self::new`] was given.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        form: &CompressedForm,
        kernels: &KernelDesc,
        light: &LightVector,
        moments: Option<(&LightMoments, &[VertexFrame])>,
        resolve: MomentsResolve,
        exact: &[[f64; 3]],
        cpu: &Render,
        background: &Background<'_>,
        repeats: usize,
    ) -> Result<GpuRecord> {
        let mut gather = GpuGather::new(&self.ctx, form, kernels)?;
        let ((method, gather_timing), (_, shade_timing), lstar, gpu) = match moments {
            None => {
                let timing = repeated(repeats, || gather.time_gather(light, 1))?;
                gather.gather(light)?;
                let render = self.shader.shade(&gather)?;
                let shade = repeated(repeats, || self.shader.time_shade(&gather, 1))?;
                (timing, shade, gather.read_lstar()?, render)
            }
            Some((m, frames)) => {
                let mut moments = GpuMoments::new(gather, frames)?;
                let timing = repeated(repeats, || moments.time_gather(m, 1))?;
                moments.gather(m)?;
                let render = self.shader.shade_moments(&moments, resolve)?;
                let shade = repeated(repeats, || self.shader.time_shade_moments(&moments, resolve, 1))?;
                (timing, shade, moments.read_lstar()?, render)
            }
        };
        let gpu = gpu.with_background(&self.camera, background);
        // Rasterised and ray-cast samples within rounding of a silhouette may land on either
        // side: such pixels differ in coverage (by a sample) and are counted, not compared.
        // Everywhere else the two average the same samples.
        let covered = |r: &Render, i: usize| match &r.coverage {
            Some(c) => c[i],
            None => f32::from(u8::from(r.mask[i])),
        };
        let same_samples: Vec<bool> = (0..cpu.mask.len()).map(|i| covered(&gpu, i) == covered(cpu, i)).collect();
        let coverage_mismatch = same_samples.iter().filter(|&&same| !same).count();
        let compared: Vec<bool> = cpu.mask.iter().zip(&same_samples).map(|(&c, &same)| c && same).collect();
        let m = compare(&gpu.image, &cpu.image, Some(&compared))?;
        // Where the two differ by more than 1e-3 of the pixel's value: with nearest-texel BTF
        // lookups, a hit point that rounds across a texel (or material) boundary picks the
        // neighbouring texel, a large difference in a few pixels; elsewhere they agree to f32.
        let differing_pixels = gpu
            .image
            .pixels
            .iter()
            .zip(&cpu.image.pixels)
            .zip(&compared)
            .filter(|((g, c), &covered)| {
                let scale = c.iter().fold(1e-6f32, |a, &b| a.max(b.abs()));
                covered && g.iter().zip(c.iter()).any(|(a, b)| (a - b).abs() > 1e-3 * scale)
            })
            .count();
        Ok(GpuRecord {
            adapter: self.adapter.clone(),
            timing: format!("{method:?}"),
            gather_ms: gather_timing.median_ms,
            shade_ms: shade_timing.median_ms,
            gather_timing: Some(gather_timing),
            shade_timing: Some(shade_timing),
            rel_error_lstar: relative_l2_error(lstar.values(), exact),
            image_vs_cpu: ImageErrors::from(&m),
            coverage_mismatch,
            differing_pixels,
            covered_pixels: cpu.mask.iter().filter(|&&c| c).count(),
        })
    }
}

/// A GPU stage timed `repeats` times (at least once), one measurement of one repetition each:
/// `biscale_gpu`'s own repetitions keep only their median, and the report wants the fastest and
/// slowest too. The samples are the same passes (GPU timestamps) or the same submit-to-idle
/// wall clock as one measurement of `repeats` repetitions, except that with the wall clock each
/// repetition now also carries the stage's small upload (the light vector) its call queues.
fn repeated(
    repeats: usize,
    mut once: impl FnMut() -> biscale_gpu::Result<biscale_gpu::Timing>,
) -> Result<(biscale_gpu::TimingMethod, Timing)> {
    let mut samples = vec![];
    let mut method = biscale_gpu::TimingMethod::WallClock;
    for _ in 0..repeats.max(1) {
        let t = once()?;
        method = t.method;
        samples.push(t.median_ms);
    }
    Ok((method, Timing::from_samples(&samples)))
}
