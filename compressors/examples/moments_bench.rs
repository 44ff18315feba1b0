//! What light moments cost in the gather: each form's plain CPU gather against
//! [`gather_with_moments`] (three gathers of the direction moments and the resolve, with the
//! BRDF at the bin centre and at the bin's mean direction), timed in interleaved rounds on one
//! real `T`, medians and their ratio; and the resolve alone (after one `gather_three`), for
//! each lobe.
//!
//! ```text
//! cargo run --release -p biscale-compressors --example moments_bench -- \
//!     [--mesh assets/meshes/bunny.obj] [--env assets/envmaps/blender_sunset.exr] [--rounds 11] [--threads N]
//! ```

use biscale_compressors::registry;
use biscale_core::compress::CompressContext;
use biscale_core::gather::moments::{exact_moments_product, gather_with_moments, resolve, LightMoments, Lobe};
use biscale_core::gather::relative_l2_error;
use biscale_core::geometry::Mesh;
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::stats::median;
use biscale_core::transfer::{self, TransferScene, TransferSettings};
use std::path::PathBuf;
use std::time::Instant;

/// Plain gather against the light-moments gather, per compressor.
#[derive(clap::Parser)]
struct Args {
    /// The mesh T is built for (reference transfer settings).
    #[arg(long, default_value = "assets/meshes/bunny.obj")]
    mesh: PathBuf,
    /// The environment map lighting it.
    #[arg(long, default_value = "assets/envmaps/blender_sunset.exr")]
    env: PathBuf,
    /// Interleaved timing rounds (the median is reported).
    #[arg(long, default_value_t = 11)]
    rounds: usize,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = <Args as clap::Parser>::parse();
    if args.threads > 0 {
        rayon::ThreadPoolBuilder::new().num_threads(args.threads).build_global()?;
    }
    let mesh = Mesh::load_obj(&args.mesh)?.mesh;
    let settings = TransferSettings::default();
    let t = transfer::build(&mesh, &settings, None)?.matrix;
    let frames = TransferScene::new(&mesh)?.frames().to_vec();
    let (env, _) = EnvMap::load(&args.env)?;
    let light = LightVector::from_env(&env, settings.cubemap(), 0.0);
    let moments = LightMoments::new(&light)?;
    let exact = exact_moments_product(&t, &light, &frames, moments.lobe)?;
    println!(
        "T: {} vertices, {} non-zeros; {} rounds, {} threads",
        t.vertices(),
        t.nnz(),
        args.rounds,
        rayon::current_num_threads()
    );
    println!(
        "| compressor | plain gather ms | gather_three ms | moments, lobe at bin centre ms | ratio | moments, lobe at mean direction ms | ratio | resolve alone, bin centre / mean direction ms | rel. error of L*' |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let settings: [(&str, serde_json::Value); 4] = [
        ("sparse", serde_json::json!({})),
        ("bicluster", serde_json::json!({ "block_vertices": 1024 })),
        ("cpca", serde_json::json!({ "clusters": 32, "components": 8 })),
        ("haar", serde_json::json!({ "terms": 12 })),
    ];
    let centre = moments.clone().with_lobe(Lobe::BinCentre);
    for (name, params) in settings {
        let c = registry::build(name, &params)?;
        let form = c.compress(&t, &CompressContext::default())?;
        let (mut plain, mut three, mut with_centre, mut with) = (vec![], vec![], vec![], vec![]);
        let (mut resolve_centre, mut resolve_mean) = (vec![], vec![]);
        let [x, y, z] = &moments.along;
        let mut last = None;
        for _ in 0..args.rounds.max(1) {
            let s = Instant::now();
            std::hint::black_box(c.gather(&form, &light)?);
            plain.push(s.elapsed().as_secs_f64() * 1e3);
            let s = Instant::now();
            let parts = std::hint::black_box(c.gather_three(&form, [x, y, z])?);
            three.push(s.elapsed().as_secs_f64() * 1e3);
            let parts = [&parts[0], &parts[1], &parts[2]];
            for (lobe, times) in [(Lobe::BinCentre, &mut resolve_centre), (Lobe::MeanDirection, &mut resolve_mean)] {
                let s = Instant::now();
                std::hint::black_box(resolve(parts, &frames, lobe)?);
                times.push(s.elapsed().as_secs_f64() * 1e3);
            }
            let s = Instant::now();
            std::hint::black_box(gather_with_moments(c.as_ref(), &form, &centre, &frames)?);
            with_centre.push(s.elapsed().as_secs_f64() * 1e3);
            let s = Instant::now();
            last = Some(gather_with_moments(c.as_ref(), &form, &moments, &frames)?);
            with.push(s.elapsed().as_secs_f64() * 1e3);
        }
        let (p, g, wc, w) = (median(&plain), median(&three), median(&with_centre), median(&with));
        let err = relative_l2_error(last.expect("one round").values(), &exact);
        let (rc, rm) = (median(&resolve_centre), median(&resolve_mean));
        println!(
            "| {name} | {p:.3} | {g:.3} | {wc:.3} | {:.2} | {w:.3} | {:.2} | {rc:.3} / {rm:.3} | {err:.2e} |",
            wc / p,
            w / p
        );
    }
    Ok(())
}
