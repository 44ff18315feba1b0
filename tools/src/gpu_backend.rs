//! The wgpu backend of the pipeline (`runtime.backend = "gpu"`, cargo feature `gpu`): the
//! same compressed forms gathered and shaded by `biscale-gpu`, timed with GPU timestamps
//! (submit-to-idle wall clock on a CPU adapter), and checked against the CPU results of the
//! same run.

use crate::metrics::{GpuRecord, ImageErrors};
use crate::pipeline::Result;
use biscale_core::compress::CompressedForm;
use biscale_core::gather::moments::{resolve, LightMoments};
use biscale_core::gather::relative_l2_error;
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::LightVector;
use biscale_core::scene::{Background, Camera, Render, ShadeScene};
use biscale_gpu::{GpuContext, GpuGather, GpuShader};
use biscale_kernels::KernelDesc;
use biscale_shading::image::compare;

/// A device plus the shader for the run's scene and camera.
pub struct GpuBackend {
    ctx: GpuContext,
    shader: GpuShader,
    /// The shader's camera, for the background behind its image.
    camera: Camera,
    pub adapter: String,
}

impl GpuBackend {
    pub fn new(scene: &ShadeScene, camera: &Camera) -> Result<Self> {
        let ctx = GpuContext::new()?;
        let a = ctx.adapter();
        let adapter = format!("{} ({:?}, {})", a.name, a.backend, a.driver);
        let shader = GpuShader::new(&ctx, scene, camera)?;
        crate::note!("gpu: {adapter}");
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
    /// With light `moments` the form is gathered three times on the GPU (once per moment; the
    /// gather time is their sum), the three `L*` are read back and resolved on the CPU
    /// ([`resolve`]) and the result shaded by the GPU: no fused kernel yet.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        form: &CompressedForm,
        kernels: &KernelDesc,
        light: &LightVector,
        moments: Option<(&LightMoments, &[VertexFrame])>,
        exact: &[[f64; 3]],
        cpu: &Render,
        background: &Background<'_>,
        repeats: usize,
    ) -> Result<GpuRecord> {
        let mut gather = GpuGather::new(&self.ctx, form, kernels)?;
        let (gather_timing, lstar, gpu) = match moments {
            None => {
                let timing = gather.time_gather(light, repeats)?;
                gather.gather(light)?;
                (timing, gather.read_lstar()?, self.shader.shade(&gather)?)
            }
            Some((m, frames)) => {
                let (mut parts, mut timings) = (vec![], vec![]);
                for l in &m.along {
                    timings.push(gather.time_gather(l, repeats)?);
                    gather.gather(l)?;
                    parts.push(gather.read_lstar()?);
                }
                let mut timing = timings.remove(0);
                timing.median_ms += timings.iter().map(|t| t.median_ms).sum::<f64>();
                let lstar = resolve([&parts[0], &parts[1], &parts[2]], frames, m.lobe)?;
                let render = self.shader.shade_lstar(&lstar)?;
                (timing, lstar, render)
            }
        };
        let shade_timing = self.shader.time_shade(&gather, repeats)?;
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
            timing: format!("{:?}", gather_timing.method),
            gather_ms: gather_timing.median_ms,
            shade_ms: shade_timing.median_ms,
            rel_error_lstar: relative_l2_error(lstar.values(), exact),
            image_vs_cpu: ImageErrors::from(&m),
            coverage_mismatch,
            differing_pixels,
            covered_pixels: cpu.mask.iter().filter(|&&c| c).count(),
        })
    }
}
