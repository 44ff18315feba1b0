//! Synthesized BTFs (`biscale_shading::synth`): what they cost to build and what their
//! encodings and local-PCA compression lose. Each part builds multi-minute tables once and
//! prints its figures (times, sizes, errors), so this is a plain `main`, not a divan group.
//! The figures are in BENCHMARKS.md ("Synthesized BTFs and several materials", "Local-PCA BTFs").
//!
//! ```sh
//! cargo bench -p biscale-benches --bench synth              # both parts
//! cargo bench -p biscale-benches --bench synth -- speed     # synthesis speed, f16 / u8 files
//! cargo bench -p biscale-benches --bench synth -- lpca      # local-PCA compression
//! BISCALE_LPCA_BENCH_RES=64 cargo bench -p biscale-benches --bench synth -- lpca  # one patch size
//! ```
//!
//! A filter selects the parts whose name (`synth::speed`, `synth::lpca`) contains it, as
//! divan's does for `stages`, so `cargo bench -p biscale-benches -- gather` runs none of
//! them. Run as a test (`cargo test --benches`, no `--bench` argument), it does nothing.

use biscale_core::basis::LocalBasis;
use biscale_core::scene::{LpcaBtf, LpcaSettings};
use biscale_shading::synth::{
    decode_btf, encode_btf, synthesize, Brdf, BtfEncoding, BtfSpec, HeightField, Pattern, Recipe,
};
use rand::{Rng, SeedableRng};
use std::path::Path;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !args.iter().any(|a| a == "--bench") {
        println!("synth: benchmarks only (cargo bench -p biscale-benches --bench synth)");
        return;
    }
    let filters: Vec<&str> = args.iter().filter(|a| !a.starts_with('-')).map(String::as_str).collect();
    let selected = |name: &str| filters.is_empty() || filters.iter().any(|f| name.contains(f));
    if selected("synth::speed") {
        speed();
    }
    if selected("synth::lpca") {
        lpca();
    }
}

/// `res x res` texels of `hf` under `brdf`, `m x m` light bins, `v x v` views (or none).
fn spec(hf: HeightField, brdf: Brdf, res: u32, m: u32, v: Option<u32>) -> BtfSpec {
    let local_basis = LocalBasis::bins(m).expect("bins");
    BtfSpec { resolution: res, local_basis, view_grid: v, ..BtfSpec::new(hf, brdf) }
}

const LAMBERT: Brdf = Brdf::Lambertian { albedo: [0.8, 0.5, 0.25] };
const PHONG: Brdf = Brdf::Phong { kd: [0.3, 0.2, 0.1], ks: [0.5, 0.6, 0.7], exponent: 20.0 };
const ASHIKHMIN: Brdf = Brdf::AshikhminShirley { rd: [0.4, 0.3, 0.2], rs: [0.05, 0.1, 0.2], nu: 60.0, nv: 8.0 };

/// The speed target (a 64x64-texel table under a minute) for each BRDF and with one bounce,
/// and the measured accuracy of the Phong table's f16 and u8 encodings.
fn speed() {
    for (name, brdf, inter) in [
        ("lambertian", LAMBERT, false),
        ("phong", PHONG, false),
        ("ashikhmin-shirley", ASHIKHMIN, false),
        ("lambertian+bounce", LAMBERT, true),
    ] {
        let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.06, 4, 1), 128).expect("a height field");
        let s = BtfSpec { interreflection: inter, ..spec(hf, brdf, 64, 8, Some(12)) };
        // The machine is shared: report the process's CPU time too (Linux /proc, clock ticks
        // of 10 ms), which is what two idle cores would divide between them.
        let cpu = || {
            let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
            let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
            let tick = |k: usize| fields.get(k).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
            (tick(11) + tick(12)) / 100.0
        };
        let (t, c) = (Instant::now(), cpu());
        let btf = synthesize(&s, None).expect("a BTF");
        println!(
            "{name}: 64x64 texels x 12x12 views x 8x8 lights, 2x2 supersampling: {:.2} s wall, {:.1} s CPU",
            t.elapsed().as_secs_f64(),
            cpu() - c
        );
        if name == "phong" {
            for enc in [BtfEncoding::F16, BtfEncoding::U8] {
                // The file's bytes, read back with `load_btf`'s checks (without the disk).
                let bytes = encode_btf(&btf, enc).expect("an encoding");
                let q = decode_btf(&bytes, Path::new("b.btf")).expect("a decoded BTF");
                let (mut num, mut den, mut max_rel_texel) = (0.0f64, 0.0f64, 0.0f64);
                let per = btf.view_count() * btf.light_count();
                for (ta, tb) in btf.data().chunks(per).zip(q.data().chunks(per)) {
                    let max = ta.iter().flatten().copied().fold(0.0f32, f32::max) as f64;
                    for (a, b) in ta.iter().flatten().zip(tb.iter().flatten()) {
                        num += ((a - b) as f64).powi(2);
                        den += (*a as f64).powi(2);
                        max_rel_texel = max_rel_texel.max((a - b).abs() as f64 / max.max(1e-30));
                    }
                }
                println!(
                    "  {}: {} bytes, relative RMS error {:.2e}, max error / texel max {:.2e}",
                    enc.name(),
                    bytes.len(),
                    (num / den).sqrt(),
                    max_rel_texel
                );
            }
        }
    }
}

/// Local-PCA compression of the bundled bunny's BTF (bumps, Phong, 32x32 texels x 12x12 views
/// x 8x8 lights) and of a 64x64-texel one: ratio, error and build time per setting, and the
/// cost of one evaluation (a texel's 64 light values at a view) dense against LPCA.
fn lpca() {
    let bunny = Brdf::Phong { kd: [0.55, 0.50, 0.45], ks: [0.25, 0.25, 0.25], exponent: 24.0 };
    // BISCALE_LPCA_BENCH_RES=64 runs one patch size only (for profiling).
    let only: Option<u32> = std::env::var("BISCALE_LPCA_BENCH_RES").ok().and_then(|v| v.parse().ok());
    for (res, samples) in [(32, 64), (64, 128)] {
        if only.is_some_and(|r| r != res) {
            continue;
        }
        let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.06, 4, 1), samples).expect("a height field");
        let btf = synthesize(&spec(hf, bunny, res, 8, Some(12)), None).expect("a BTF");
        let values = btf.data().len() * 3;
        println!(
            "{res}x{res} texels x 144 views x 64 lights: dense {:.1} MB f32, {:.1} MB f16",
            values as f64 * 4e-6,
            values as f64 * 2e-6
        );
        // Per view, a setting has 144x as many units: only small ones are timed.
        let settings: &[(usize, usize, bool)] = match res {
            32 => &[
                (1, 4, false),
                (8, 4, false),
                (16, 4, false),
                (32, 8, false),
                (16, 4, true),
                (32, 4, true),
                (64, 4, true),
            ],
            _ => &[(8, 4, false), (16, 4, false), (16, 4, true)],
        };
        for &(k, c, per_view) in settings {
            let t = Instant::now();
            let s = if per_view { LpcaSettings::new(k, c).per_view() } else { LpcaSettings::new(k, c) };
            let (lpca, r) = LpcaBtf::compress(&btf, &s, 1).expect("an LPCA BTF");
            let s = t.elapsed().as_secs_f64();
            println!(
                "  k{k} c{c}{}: {:.2} MB, ratio 1:{:.0} (f32) 1:{:.0} (f16), rel. RMS {:.2}%, max abs {:.3e}, build {s:.2} s",
                if per_view { " per view" } else { "" },
                lpca.bytes() as f64 * 1e-6,
                values as f64 * 4.0 / lpca.bytes() as f64,
                values as f64 * 2.0 / lpca.bytes() as f64,
                100.0 * r.relative_rms_error,
                r.max_abs_error
            );
            if (k, c) == (16, 4) {
                let label = if per_view { "lpca k16 c4 per view" } else { "lpca k16 c4" };
                let mut out = vec![[0.0f32; 3]; 64];
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
                let q: Vec<(glam::Vec2, glam::Vec3)> = (0..100_000)
                    .map(|_| {
                        let uv = glam::Vec2::new(rng.gen(), rng.gen());
                        let e = glam::Vec3::new(
                            rng.gen_range(-1.0..1.0),
                            rng.gen_range(-1.0..1.0),
                            rng.gen_range(0.1..1.0),
                        );
                        (uv, e.normalize())
                    })
                    .collect();
                let time = |f: &mut dyn FnMut(glam::Vec2, glam::Vec3)| {
                    let mut runs: Vec<f64> = (0..5)
                        .map(|_| {
                            let t = Instant::now();
                            q.iter().for_each(|&(uv, e)| f(uv, e));
                            t.elapsed().as_secs_f64() * 1e9 / q.len() as f64
                        })
                        .collect();
                    runs.sort_by(f64::total_cmp);
                    runs[2]
                };
                let dense_ns = time(&mut |uv, e| {
                    btf.eval_into(uv, e, &mut out);
                    std::hint::black_box(&out);
                });
                let lpca_ns = time(&mut |uv, e| {
                    lpca.eval_into(uv, e, &mut out);
                    std::hint::black_box(&out);
                });
                println!("    one lookup (64 lights, bilinear views), median of 5 x 100k: dense {dense_ns:.0} ns, {label} {lpca_ns:.0} ns");
            }
        }
    }
}
