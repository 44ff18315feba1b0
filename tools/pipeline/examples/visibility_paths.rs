//! The transfer stage's two ways to decide visibility side by side on the same meshes:
//! `transfer.visibility = "rays"` (every ray traced) and `"coverage"` (each face's triangles
//! rasterised into its coverage mask). Builds `T` both ways, counts the entries and the rays
//! where they differ (the per-ray definition says a texel is covered exactly when the ray
//! through its centre hits; the two can differ only on rays within f32 rounding of a
//! triangle's edge), and times both, interleaved, as medians. Prints a Markdown table.
//!
//! ```text
//! cargo run --release -p biscale --example visibility_paths -- MESH... [--rounds 3] [--resolution 64]
//! ```

use anyhow::Result;
use biscale_core::geometry::Mesh;
use biscale_core::stats::median;
use biscale_core::transfer::{self, TransferSettings, Visibility};
use std::path::PathBuf;

#[derive(clap::Parser)]
struct Args {
    /// Meshes (OBJ or PLY), loaded as they are (no placement).
    #[arg(required = true)]
    meshes: Vec<PathBuf>,
    /// Timing rounds per path (interleaved).
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// Visibility cubemap resolution (the light cubemap is half of it: the 2x2 box filter).
    #[arg(long, default_value_t = 64)]
    resolution: u32,
}

fn main() -> Result<()> {
    let args = <Args as clap::Parser>::parse();
    let threads = rayon::current_num_threads();
    println!("{threads} threads, visibility 6x{r}x{r}, {} rounds (medians)\n", args.rounds, r = args.resolution);
    println!("| mesh | vertices | triangles | nnz | entries differing | rays differing | rays: s (M rays/s) | coverage: s (M rays/s) | speed-up |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let base = TransferSettings::new(args.resolution / 2, args.resolution, 8)?;
    for path in &args.meshes {
        let mesh = Mesh::load(path)?.mesh;
        let mut seconds = [vec![], vec![]];
        let mut built = [None, None];
        for _ in 0..args.rounds.max(1) {
            for (i, how) in [Visibility::Rays, Visibility::Coverage].into_iter().enumerate() {
                let b = transfer::build(&mesh, &base.with_visibility(how), None)?;
                seconds[i].push(b.stats.seconds);
                built[i] = Some(b);
            }
        }
        let [Some(rays), Some(cover)] = built else { unreachable!("at least one round") };
        // T's values are k / s^2 for k unoccluded children: the differing rays are the
        // differences of the counts.
        let s2 = (base.supersampling() * base.supersampling()) as f64;
        let (a, b) = (rays.matrix.csr(), cover.matrix.csr());
        let diff = a - b;
        let differences = diff.data().iter().filter(|&&d| d != 0.0);
        let entries = differences.clone().count();
        let differing = differences.fold(0.0, |sum, &d| sum + (d as f64 * s2).abs().round());
        let (ts, tc) = (median(&seconds[0]), median(&seconds[1]));
        let rate = |s: f64| rays.stats.rays_traced as f64 / s / 1e6;
        println!(
            "| {} | {} | {} | {} | {entries} | {differing:.0} of {} | {ts:.2} ({:.1}) | {tc:.2} ({:.1}) | {:.2}x |",
            path.display(),
            mesh.vertex_count(),
            mesh.triangles.len(),
            a.nnz(),
            rays.stats.rays_traced,
            rate(ts),
            rate(tc),
            ts / tc
        );
        assert_eq!(rays.stats.rays_traced, cover.stats.rays_traced, "both decide the rays above the horizon");
    }
    Ok(())
}
