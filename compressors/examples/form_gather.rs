//! Time the CPU gather of saved compressed forms (`.bsf`, as `bicluster_bench --save` or the
//! stage cache writes them): one RGB light (`gather`) and three at once (`gather_three`, the
//! light-moments path), on a rayon pool of each requested size, in interleaved rounds
//! (medians). A bicluster form's gather is first checked against an f64 product of its own
//! decompressed matrix, and its `gather_three` against `gather` bit for bit, so a fast wrong
//! answer cannot be timed; other kinds are timed unchecked (`peer_gather` checks every
//! built-in form against `T`).
//!
//! It is the quick loop for work on a gather kernel: save the form once, then alternate two
//! builds of this example on it.
//!
//! ```text
//! cargo run --release -p biscale-compressors --example bicluster_bench -- --blocks 1024 --save /tmp/bunny.bsf
//! cargo run --release -p biscale-compressors --example form_gather -- /tmp/bunny.b1024.bsf [--rounds 31] [--threads 1,2]
//! ```

use biscale_compressors::registry;
use biscale_compressors::testing::random_light;
use biscale_core::compress::CompressedForm;
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::stats::median;
use std::path::PathBuf;
use std::time::Instant;

/// Time saved forms' CPU gathers.
#[derive(clap::Parser)]
struct Args {
    /// Saved forms (`.bsf`).
    forms: Vec<PathBuf>,
    /// Interleaved timing rounds (medians are reported).
    #[arg(long, default_value_t = 31)]
    rounds: usize,
    /// Rayon pool sizes to time on.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    threads: Vec<usize>,
    /// Seed of the random light.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn main() {
    if let Err(e) = run() {
        eprintln!("form_gather: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let args = <Args as clap::Parser>::parse();
    if args.forms.is_empty() {
        return Err("name at least one saved form (.bsf)".into());
    }
    let mut forms = vec![];
    for path in &args.forms {
        let form = CompressedForm::load(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let compressor = registry::build(&form.kind, &serde_json::json!({})).map_err(|e| format!("{e}"))?;
        let res = form
            .light_basis()
            .cubemap_layout()
            .ok_or_else(|| format!("{}: not a cubemap-light form", path.display()))?
            .resolution;
        let lights: Vec<_> = (0..3).map(|i| random_light(res, args.seed + i)).collect();
        let t = match form.kind.as_str() {
            "bicluster" => Some(biscale_compressors::bicluster::decompress(&form).map_err(|e| e.to_string())?),
            _ => None,
        };
        if let Some(t) = &t {
            let reference = reference_product(t, &lights[0]);
            let got = compressor.gather(&form, &lights[0]).map_err(|e| e.to_string())?;
            let err = relative_l2_error(got.values(), &reference);
            println!("{}: {} rows, relative L2 against f64 T L {err:.2e}", path.display(), form.rows());
            if err > 1e-5 {
                return Err(format!("{}: the gather is wrong ({err:.2e})", path.display()));
            }
            let three =
                compressor.gather_three(&form, [&lights[0], &lights[1], &lights[2]]).map_err(|e| e.to_string())?;
            if three[0].values() != got.values() {
                return Err(format!("{}: gather_three's first light differs from gather", path.display()));
            }
        }
        forms.push((path.clone(), form, compressor, lights));
    }
    for &threads in &args.threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| e.to_string())?;
        let mut one = vec![vec![]; forms.len()];
        let mut three = vec![vec![]; forms.len()];
        for _ in 0..args.rounds {
            for (f, (_, form, c, lights)) in forms.iter().enumerate() {
                pool.install(|| -> Result<(), String> {
                    let t0 = Instant::now();
                    std::hint::black_box(c.gather(form, &lights[0]).map_err(|e| e.to_string())?);
                    one[f].push(t0.elapsed().as_secs_f64() * 1e3);
                    let t0 = Instant::now();
                    std::hint::black_box(
                        c.gather_three(form, [&lights[0], &lights[1], &lights[2]]).map_err(|e| e.to_string())?,
                    );
                    three[f].push(t0.elapsed().as_secs_f64() * 1e3);
                    Ok(())
                })?;
            }
        }
        for (f, (path, ..)) in forms.iter().enumerate() {
            println!(
                "{threads} thread(s) {}: gather {:.3} ms, gather_three {:.3} ms",
                path.display(),
                median(&one[f]),
                median(&three[f])
            );
        }
    }
    Ok(())
}
