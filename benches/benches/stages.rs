//! One divan group per pipeline stage, on the fixed inputs of `biscale_benches` (the bunny and
//! the sunset sky): transfer (tiny and reference settings), each compressor's build, each
//! form's gather (plain, and with light moments), and the CPU shader. Run with
//! `cargo bench -p biscale-benches --bench stages [-- FILTER]`; the figures are in BENCHMARKS.md.

use biscale_benches::{bunny, compressor, form, frames, light, reference_t, tiny_settings, SETTINGS};
use biscale_core::basis::LocalBasis;
use biscale_core::compress::CompressContext;
use biscale_core::gather::moments::{gather_with_moments, LightMoments};
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_core::transfer::{self, TransferSettings};
use divan::Bencher;

fn main() {
    divan::main();
}

/// Tracing `T` (visibility, box filter, binning into the local bins).
#[divan::bench_group(sample_count = 3, sample_size = 1)]
mod transfer_stage {
    use super::*;

    /// 6x8x8 cubemap, 6x16x16 visibility, 4x4 bins (configs/smoke.toml).
    #[divan::bench]
    fn tiny(bencher: Bencher<'_, '_>) {
        let (mesh, settings) = (bunny(), tiny_settings());
        bencher.bench(|| transfer::build(mesh, &settings, None).expect("T"));
    }

    /// 6x32x32 cubemap, 6x64x64 visibility, 8x8 bins (the paper's setting).
    #[divan::bench]
    fn reference(bencher: Bencher<'_, '_>) {
        let (mesh, settings) = (bunny(), TransferSettings::default());
        bencher.bench(|| transfer::build(mesh, &settings, None).expect("T"));
    }
}

/// Each compressor's build on the reference `T`.
#[divan::bench_group(sample_count = 3, sample_size = 1)]
mod compress {
    use super::*;

    #[divan::bench(args = SETTINGS)]
    fn build(bencher: Bencher<'_, '_>, kind: &str) {
        let (t, c) = (reference_t(), compressor(kind));
        // No sweep in the context: every sample builds afresh (a sweep would serve the
        // bicluster greedy's output to every sample after the first, timing only the pruning).
        bencher.bench(|| c.compress(t, &CompressContext::default()).expect("a form"));
    }
}

/// Each form's gather `L* = T L` (RGB), and the light-moments gather (three gathers of the
/// direction moments and the resolve).
#[divan::bench_group(sample_count = 30)]
mod gather {
    use super::*;

    #[divan::bench(args = SETTINGS)]
    fn plain(bencher: Bencher<'_, '_>, kind: &str) {
        let (f, c, l) = (form(kind), compressor(kind), light());
        bencher.bench(|| c.gather(f, l).expect("L*"));
    }

    #[divan::bench(args = SETTINGS)]
    fn moments(bencher: Bencher<'_, '_>, kind: &str) {
        let (f, c) = (form(kind), compressor(kind));
        let m = LightMoments::new(light()).expect("moments");
        bencher.bench(|| gather_with_moments(c.as_ref(), f, &m, frames()).expect("L*'"));
    }
}

/// The CPU per-pixel shader at 320x240, one sample per pixel, from the sparse gather's `L*`.
#[divan::bench_group(sample_count = 10)]
mod shade {
    use super::*;

    #[divan::bench(args = ["lambertian", "phong"])]
    fn cpu_320x240(bencher: Bencher<'_, '_>, kind: &str) {
        let bins = LocalBasis::bins(8).expect("bins");
        let btf = match kind {
            "lambertian" => Btf::lambertian([0.8; 3], bins),
            _ => Btf::phong([0.3; 3], [0.6; 3], 24.0, bins, 12),
        }
        .expect("a BTF");
        let mesh = bunny().clone();
        let (min, max) = mesh.bounds();
        let scene = ShadeScene::new(mesh, frames().to_vec(), vec![Material::new(btf)], None).expect("a scene");
        let lstar = compressor("sparse").gather(form("sparse"), light()).expect("L*");
        let camera = Camera::frame_bounds(min, max, 320, 240, 30.0, 20.0, 40.0);
        bencher.bench(|| biscale_shading::cpu::shade(&scene, &lstar, &camera).expect("an image"));
    }
}
