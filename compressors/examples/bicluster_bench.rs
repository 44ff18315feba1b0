//! Table I of Sun et al. for our biclustering on a real transfer matrix, plus build times.
//!
//! Builds `T` from a mesh with the reference transfer settings (6x32x32 light, 2x2 box-filtered
//! visibility, m x m local directions), biclusters it at each requested block size and column
//! cost, checks the result is exact (integer codes) and prints the stats as a table and JSON.
//! Every run builds afresh (the greedy output a budget sweep shares is released first).
//!
//! ```text
//! cargo run --release -p biscale-compressors --example bicluster_bench -- \
//!     [--mesh assets/meshes/bunny.obj] [--local-grid 8] [--blocks 0,64,256] [--runs 3] \
//!     [--column-costs 2,16] [--seed 0] [--threads N] [--json out.json] [--save form.bsf]
//! ```

use biscale_compressors::bicluster::{decompress_codes, table_stats, Bicluster, BiclusterStats};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::geometry::Mesh;
use biscale_core::transfer::{self, TransferSettings};
use std::path::PathBuf;

/// Table I of Sun et al. for biscale's biclustering of a real transfer matrix.
#[derive(clap::Parser)]
struct Args {
    /// The mesh T is built for.
    #[arg(long, default_value = "assets/meshes/bunny.obj")]
    mesh: PathBuf,
    /// Local bins per side, m (M = m^2 rows per vertex).
    #[arg(long, default_value_t = 8)]
    local_grid: u32,
    /// Block sizes in vertices to bicluster at (0: one block).
    #[arg(long, value_delimiter = ',', default_value = "0,32,64,128,256")]
    blocks: Vec<usize>,
    /// Timed runs per block size.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// The greedy's column costs (`column_cost`; the paper's is 2) to bicluster at.
    #[arg(long, value_delimiter = ',', default_value = "2")]
    column_costs: Vec<u32>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Write the stats as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Save each form next to this path (`<stem>.b<block>.bsf`, `<stem>.b<block>.c<cost>.bsf`
    /// for a column cost other than 2) and check it loads back.
    #[arg(long)]
    save: Option<PathBuf>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = <Args as clap::Parser>::parse();
    args.runs = args.runs.max(1);
    if args.threads > 0 {
        rayon::ThreadPoolBuilder::new().num_threads(args.threads).build_global()?;
    }
    let mesh = Mesh::load_obj(&args.mesh)?.mesh;
    let settings = TransferSettings::default().with_local_grid(args.local_grid)?;
    let build = transfer::build(&mesh, &settings, None)?;
    println!("T: {build}");
    let t = build.matrix;
    let mut all: Vec<(usize, u32, Vec<f64>, BiclusterStats)> = vec![];
    let grid = args.blocks.iter().flat_map(|&bv| args.column_costs.iter().map(move |&cc| (bv, cc)));
    for (bv, cc) in grid {
        let c = Bicluster { block_vertices: bv, column_cost: cc, ..Bicluster::default() };
        c.validate()?;
        let mut times = vec![];
        let mut form = None;
        for run in 0..args.runs {
            let f = c.compress(&t, &CompressContext { seed: args.seed, progress: None, sweep: None })?;
            times.push(f.build_seconds);
            if run == 0 {
                // Exactness on the real matrix: the biclusters sum to T in integer codes.
                let back = decompress_codes(&f)?;
                let want = biscale_compressors::bicluster::codes::quantize(&t, 0)?;
                assert!(back == want, "block_vertices {bv}: decompressed codes differ from T");
            }
            form = Some(f);
        }
        let form = form.unwrap();
        times.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let s = table_stats(&form, &t)?;
        println!(
            "block_vertices {:>5}, column_cost {:>2}: median {:7.2} s (runs {:?}) | biclusters {:>8} | MFLOPs {:.2} -> {:.2} ({:.1}%) | \
             bytes {} = {:.3} B/nnz, {:.2}% of dense, {:.1}% of CSR | r p50/p90/max {}/{}/{} | l p50/p90/max {}/{}/{} | row list mean {:.1} max {}",
            bv,
            cc,
            biscale_core::stats::median(&times),
            times.iter().map(|x| (x * 100.0).round() / 100.0).collect::<Vec<_>>(),
            s.biclusters,
            s.mflops_raw,
            s.mflops_biclustered,
            100.0 * s.flops_ratio,
            s.compressed_bytes,
            s.bytes_per_nnz,
            100.0 * s.ratio_to_dense,
            100.0 * s.ratio_to_csr,
            s.r.p50,
            s.r.p90,
            s.r.max,
            s.l.p50,
            s.l.p90,
            s.l.max,
            s.row_list_mean,
            s.row_list_max
        );
        println!("    bytes by array: {:?}", s.bytes_by_array);
        if let Some(p) = &args.save {
            let cost = if cc == 2 { String::new() } else { format!(".c{cc}") };
            let p = p.with_extension(format!("b{bv}{cost}.bsf"));
            form.save(&p)?;
            let back = biscale_core::compress::CompressedForm::load(&p)?;
            assert!(back == form, "form file round trip");
            println!("    saved {}", p.display());
        }
        all.push((bv, cc, times, s));
    }
    if let Some(p) = &args.json {
        let v: Vec<_> = all
            .iter()
            .map(|(bv, cc, times, s)| {
                serde_json::json!({"block_vertices": bv, "column_cost": cc, "build_seconds": times, "stats": s})
            })
            .collect();
        std::fs::write(p, serde_json::to_string_pretty(&v)?)?;
    }
    Ok(())
}
