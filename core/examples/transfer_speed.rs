//! Speed of the transfer build (docs/DESIGN.md section 8: medians over repeated runs).
//!
//! ```text
//! cargo run --release -p biscale-core --example transfer_speed -- assets/meshes/bunny.obj [runs] [R] [visibility] [m]
//! ```
//!
//! Builds `T` for the mesh at the reference settings (R = 32, visibility 64, 8x8 local
//! grid) `runs` times (default 5) and prints the medians of seconds, rays traced and
//! rays/second, the number of non-zeros and the value histogram. Threads: rayon's default
//! (set `RAYON_NUM_THREADS` to pin). Goals (issue): >= 10 million rays/s on 2 cores and the
//! bunny under 10 s.

use biscale_core::geometry::Mesh;
use biscale_core::stats::median;
use biscale_core::transfer::{self, TransferSettings};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = PathBuf::from(args.first().map(String::as_str).unwrap_or("assets/meshes/bunny.obj"));
    let arg = |i: usize, default: u32| -> Result<u32, Box<dyn std::error::Error>> {
        Ok(args.get(i).map(|s| s.parse()).transpose()?.unwrap_or(default))
    };
    let runs = arg(1, 5)?.max(1);
    let settings = TransferSettings::new(arg(2, 32)?, arg(3, 64)?, arg(4, 8)?)?;
    let load = Mesh::load_obj(&path)?;
    for r in &load.repairs {
        println!("repair: {r}");
    }
    let mesh = load.mesh;
    println!(
        "{}: {} vertices, {} triangles; settings {:?}; {} rayon threads; {runs} runs",
        path.display(),
        mesh.vertex_count(),
        mesh.triangle_count(),
        settings,
        rayon::current_num_threads()
    );
    let (mut secs, mut rays, mut rate) = (vec![], vec![], vec![]);
    let mut last = None;
    for i in 0..runs {
        let b = transfer::build(&mesh, &settings, None)?;
        println!(
            "run {i}: {:.3} s, {} rays, {:.2} Mrays/s, nnz {}",
            b.stats.seconds,
            b.stats.rays_traced,
            b.stats.rays_per_second / 1e6,
            b.matrix.nnz()
        );
        secs.push(b.stats.seconds);
        rays.push(b.stats.rays_traced as f64);
        rate.push(b.stats.rays_per_second);
        last = Some(b);
    }
    let b = last.expect("runs >= 1");
    println!(
        "median: {:.3} s, {:.0} rays, {:.2} Mrays/s; nnz {} ({:.2} per vertex); frame fallbacks {}",
        median(&secs),
        median(&rays),
        median(&rate) / 1e6,
        b.matrix.nnz(),
        b.matrix.nnz() as f64 / b.matrix.vertices().max(1) as f64,
        b.stats.frame_fallbacks
    );
    println!("value histogram:");
    for (v, c) in &b.stats.value_histogram {
        println!("  {v:>8.4}: {c}");
    }
    Ok(())
}
