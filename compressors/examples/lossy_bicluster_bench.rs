//! Lossy biclustering on a real transfer matrix: storage, flops, build time and errors for a
//! list of error budgets, beside the lossless form and the alternative mechanisms measured
//! against it: coarser value codes (`T` rounded to multiples of 1/2, then biclustered
//! losslessly), biclustering the pruned matrix again, and an estimate of merging each
//! bicluster into the one that shares most of its rows.
//!
//! ```text
//! cargo run --release -p biscale-compressors --example lossy_bicluster_bench -- \
//!     [--mesh assets/meshes/bunny.obj] [--env assets/envmaps/blender_forest.exr] \
//!     [--rotation-degrees 120] [--budgets 0.01,0.02,0.05,0.1,0.2,0.3] [--seed 3] [--block-vertices 1024]
//! ```
//!
//! Columns: bytes and flops as a share of the lossless form; `build s` the form's build time
//! (a budget's is its pruning alone: the budgets share the lossless form's greedy output, as
//! a sweep in `biscale run` does); `frob` the relative Frobenius error of `T` (what the budget
//! bounds, recomputed from the arrays); `sky` the relative `L*` error under the uniform sky;
//! `env`, `sun`, `rand` the relative `L*` error of the CPU gather against the f64 product
//! under the env map, a random light with a 10^6 sun and one without
//! (`testing::random_light`). Every budget's achieved Frobenius error is checked to be at
//! most the budget.

use biscale_compressors::bicluster::{achieved_error, Bicluster};
use biscale_compressors::testing::random_light;
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::transfer::{self, TransferMatrix, TransferSettings};
use std::path::PathBuf;

/// Lossy biclustering against its error budget on a real transfer matrix.
#[derive(clap::Parser)]
struct Args {
    /// The mesh T is built for (reference transfer settings).
    #[arg(long, default_value = "assets/meshes/bunny.obj")]
    mesh: PathBuf,
    /// The env map of the `env` column.
    #[arg(long, default_value = "assets/envmaps/blender_forest.exr")]
    env: PathBuf,
    /// Rotation of the env map about the up axis, degrees.
    #[arg(long, default_value_t = 120.0)]
    rotation_degrees: f64,
    /// Error budgets (relative Frobenius error of T) to build.
    #[arg(long, value_delimiter = ',', default_value = "0.01,0.02,0.05,0.1,0.2,0.3")]
    budgets: Vec<f64>,
    /// Seed of the greedy (the compare configs use 3).
    #[arg(long, default_value_t = 3)]
    seed: u64,
    /// Vertices per biclustered block.
    #[arg(long, default_value_t = 1024)]
    block_vertices: usize,
}

/// T with every value passed through `f` (zeros dropped).
fn map_values(t: &TransferMatrix, f: impl Fn(f32) -> f32) -> Result<TransferMatrix, Box<dyn std::error::Error>> {
    let csr = t.csr();
    let mut tri = sprs::TriMat::new((csr.rows(), csr.cols()));
    for (i, row) in csr.outer_iterator().enumerate() {
        for (k, &v) in row.iter() {
            let w = f(v);
            if w != 0.0 {
                tri.add_triplet(i, k, w);
            }
        }
    }
    Ok(TransferMatrix::new(t.local_basis(), t.light_basis(), tri.to_csr())?)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = <Args as clap::Parser>::parse();
    let mesh = Mesh::load_obj(&args.mesh)?.mesh;
    let settings = TransferSettings::default();
    let t = transfer::build(&mesh, &settings, None)?.matrix;
    println!("T: {}: {} x {}, {} non-zeros", args.mesh.display(), t.rows(), t.cols(), t.nnz());
    let (env, _) = EnvMap::load(&args.env)?;
    let lights = [
        ("env", LightVector::from_env(&env, settings.cubemap(), args.rotation_degrees.to_radians())),
        ("sun", random_light(settings.cubemap().resolution, 1)),
        ("rand", random_light(settings.cubemap().resolution, 2)),
    ];
    let refs: Vec<_> = lights.iter().map(|(_, l)| reference_product(&t, l)).collect();
    let ctx = CompressContext { seed: args.seed, progress: None, sweep: None };
    let lossless_c = Bicluster { block_vertices: args.block_vertices, ..Bicluster::default() };
    let lossless = lossless_c.compress(&t, &ctx)?;
    println!(
        "{:<22} {:>9} {:>7} {:>7} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "setting", "bytes", "bytes%", "flops%", "build s", "frob", "sky", "env", "sun", "rand", "dropped"
    );
    let row = |name: &str,
               c: &dyn Compressor,
               form: &CompressedForm,
               of: &TransferMatrix|
     -> Result<(), Box<dyn std::error::Error>> {
        let err = achieved_error(form, of)?;
        // Against the original T: the rounding variant's form stands for a rounded copy.
        let frob_vs_t = if std::ptr::eq(of, &t) { err.frobenius } else { frobenius_between(&t, of) };
        let sky = if std::ptr::eq(of, &t) { err.sky.unwrap_or(f64::NAN) } else { f64::NAN };
        let mut errs = vec![];
        for ((_, l), r) in lights.iter().zip(&refs) {
            errs.push(relative_l2_error(c.gather(form, l)?.values(), r));
        }
        println!(
            "{name:<22} {:>9} {:>6.1}% {:>6.1}% {:>7.2} {:>9.2e} {:>9.2e} {:>9.2e} {:>9.2e} {:>9.2e} {:>8}",
            form.bytes(),
            100.0 * form.bytes() as f64 / lossless.bytes() as f64,
            100.0 * form.flops_per_gather as f64 / lossless.flops_per_gather as f64,
            form.build_seconds,
            frob_vs_t,
            sky,
            errs[0],
            errs[1],
            errs[2],
            form.meta.get("dropped_biclusters").copied().unwrap_or(0)
        );
        Ok(())
    };
    row("lossless", &lossless_c, &lossless, &t)?;
    for &b in &args.budgets {
        let c = Bicluster { error_budget: b, ..lossless_c.clone() };
        let form = c.compress(&t, &ctx)?;
        let achieved = achieved_error(&form, &t)?.frobenius;
        assert!(achieved <= b, "budget {b}: achieved {achieved}");
        row(&format!("prune e{b}"), &c, &form, &t)?;
    }
    // Tried and not kept: biclustering the pruned matrix T' again from scratch (lossless).
    {
        let pruned = Bicluster { error_budget: 0.1, ..lossless_c.clone() }.compress(&t, &ctx)?;
        let t_prime = biscale_compressors::bicluster::decompress(&pruned)?;
        let again = lossless_c.compress(&t_prime, &ctx)?;
        println!(
            "re-biclustering T' of e0.1: {} bytes ({:.1}% of lossless) against the pruned form's {} ({:.1}%)",
            again.bytes(),
            100.0 * again.bytes() as f64 / lossless.bytes() as f64,
            pruned.bytes(),
            100.0 * pruned.bytes() as f64 / lossless.bytes() as f64
        );
    }
    // The alternative mechanism: coarser value codes (halves, rounding 1/4 and 3/4 up).
    let halves = map_values(&t, |v| (v * 2.0 + 0.01).round() / 2.0)?;
    let form = lossless_c.compress(&halves, &ctx)?;
    row("codes in halves", &lossless_c, &form, &halves)?;
    merge_estimate(&lossless)?;
    Ok(())
}

/// The third mechanism, estimated without building forms: merging each bicluster into the
/// bicluster of its block that shares most of its rows (its columns join the partner; the
/// rows of the two sets' symmetric difference are then wrong by the bicluster's values) against
/// dropping it, both ranked by squared error per byte saved and summed without interactions.
fn merge_estimate(form: &CompressedForm) -> Result<(), Box<dyn std::error::Error>> {
    use biscale_compressors::bicluster::BiclusterView;
    let v = BiclusterView::new(form)?;
    let nb = v.biclusters();
    let mut members: Vec<Vec<u32>> = vec![vec![]; nb];
    let mut lists: Vec<Vec<u32>> = vec![vec![]; v.rows];
    for i in 0..v.rows {
        for b in v.row_biclusters(i) {
            members[b].push(i as u32);
            lists[i].push(b as u32);
        }
    }
    let energy = form.meta.get("energy2_codes").map(|&e| e as f64);
    let energy = energy.unwrap_or_else(|| {
        // T = sum of the biclusters (lossless): its energy from the decompressed codes.
        let c = biscale_compressors::bicluster::decompress_codes(form).expect("a valid form");
        c.codes.iter().map(|&x| (x as f64).powi(2)).sum()
    });
    let (mut drops, mut merges) = (vec![], vec![]);
    let mut shared = std::collections::HashMap::new();
    for b in 0..nb {
        let (_, ts) = v.bicluster(b);
        let t2: f64 = ts.iter().map(|&x| (x as f64).powi(2)).sum();
        let r = members[b].len() as f64;
        drops.push((r * t2, 2.0 * r + 3.0 * ts.len() as f64 + 4.0));
        shared.clear();
        for &i in &members[b] {
            for &o in &lists[i as usize] {
                if o as usize != b {
                    *shared.entry(o).or_insert(0u32) += 1;
                }
            }
        }
        let diff =
            shared.iter().map(|(&o, &c)| members[o as usize].len() as f64 + r - 2.0 * c as f64).min_by(f64::total_cmp);
        if let Some(d) = diff {
            merges.push((d * t2, 2.0 * r + 4.0));
        }
    }
    println!("estimate without interactions, share of the lossless bytes saved at a relative Frobenius error:");
    for (name, mut moves) in [("drop", drops), ("merge into the partner", merges)] {
        moves.sort_by(|a, b| (a.0 / a.1).total_cmp(&(b.0 / b.1)));
        let (mut e2, mut saved, mut next) = (0.0, 0.0, 0.01f64);
        let mut cells = vec![];
        for (c, by) in moves {
            e2 += c;
            saved += by;
            while (e2 / energy).sqrt() >= next && next <= 0.5 {
                cells.push(format!("{next}: {:.1}%", 100.0 * saved / form.bytes() as f64));
                next *= 2.0;
            }
        }
        println!("  {name:<24} {}", cells.join(", "));
    }
    Ok(())
}

/// `||A - B||_F / ||A||_F` of two matrices of one shape, in f64.
fn frobenius_between(a: &TransferMatrix, b: &TransferMatrix) -> f64 {
    let (mut e2, mut a2) = (0.0f64, 0.0f64);
    let mut acc = std::collections::BTreeMap::new();
    for i in 0..a.rows() {
        acc.clear();
        for (k, &v) in a.csr().outer_view(i).expect("row").iter() {
            *acc.entry(k).or_insert(0.0) += v as f64;
            a2 += (v as f64).powi(2);
        }
        for (k, &v) in b.csr().outer_view(i).expect("row").iter() {
            *acc.entry(k).or_insert(0.0) -= v as f64;
        }
        e2 += acc.values().map(|d: &f64| d * d).sum::<f64>();
    }
    (e2 / a2).sqrt()
}
