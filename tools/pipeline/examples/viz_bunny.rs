//! The matrix-structure pictures of [`biscale::viz`] on a real transfer matrix.
//!
//! Builds `T` for a mesh with the reference settings (6x32x32 light, 2x2 box-filtered
//! visibility, 8x8 local directions), biclusters it (default parameters, seed 0) and writes
//! every picture to the output folder; `--readme` also writes `docs/bicluster_patch.png`.
//!
//! ```text
//! cargo run --release -p biscale --no-default-features --example viz_bunny -- \
//!     [--mesh assets/meshes/bunny.obj] [--out out/viz] [--first auto|N] [--count 8] [--readme]
//! ```
//!
//! `--first auto` (the default) picks the window of `count` consecutive vertices that shares the
//! most bicluster columns between its vertices (sum over biclusters of `l x (vertices - 1)`),
//! where the structure the biclusters exploit shows best.

use biscale::viz::{self, HeatmapOptions, PatchLayout, PatchView};
use biscale_compressors::bicluster::Bicluster;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::geometry::Mesh;
use biscale_core::scene::Camera;
use biscale_core::transfer::{self, TransferSettings};
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let mut mesh_path = PathBuf::from("assets/meshes/bunny.obj");
    let mut out = PathBuf::from("out/viz");
    let (mut first, mut count, mut readme) = (None, 8usize, false);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().ok_or_else(|| anyhow::anyhow!("{a} needs a value"));
        match a.as_str() {
            "--mesh" => mesh_path = val()?.into(),
            "--out" => out = val()?.into(),
            "--first" => {
                let v = val()?;
                first = if v == "auto" { None } else { Some(v.parse()?) };
            }
            "--count" => count = val()?.parse()?,
            "--readme" => readme = true,
            _ => anyhow::bail!("unknown argument {a}"),
        }
    }
    std::fs::create_dir_all(&out)?;
    let mesh = Mesh::load_obj(&mesh_path)?.mesh;
    let t = transfer::build(&mesh, &TransferSettings::default(), None)?.matrix;
    println!("T: {} x {}, {} non-zeros", t.rows(), t.cols(), t.nnz());
    let form = Bicluster::default().compress(&t, &CompressContext::default())?;
    println!("{} biclusters, {:.1} s", form.meta("biclusters")?, form.build_seconds);
    let first = match first {
        Some(f) => f,
        None => biscale_compressors::bicluster::analysis::most_shared_window(&form, count)?,
    };
    println!("patch: vertices {first}..{}", first + count - 1);
    let panels = PatchView { first_vertex: first, vertices: count, layout: PatchLayout::CubemapPanels, cell: 4 };
    let matrix = PatchView { layout: PatchLayout::Matrix { compact: true }, cell: 2, vertices: count.min(4), ..panels };
    let mut written = vec![
        viz::write_sparsity(&t, &panels, &out.join("sparsity_panels.png"))?,
        viz::write_bicluster_patch(&t, &form, &panels, &out.join("biclusters_panels.png"))?,
        viz::write_sparsity(&t, &matrix, &out.join("sparsity_matrix.png"))?,
        viz::write_bicluster_patch(&t, &form, &matrix, &out.join("biclusters_matrix.png"))?,
        viz::write_bicluster_size_histograms(&form, &out.join("bicluster_sizes.png"))?,
        viz::write_value_histograms(&t, Some(&form), &out.join("values.png"))?,
    ];
    let (lo, hi) = mesh.bounds();
    let camera = Camera::frame_bounds(lo, hi, 640, 480, 0.0, 10.0, 35.0);
    let opts = HeatmapOptions::default();
    let cost = biscale_compressors::bicluster::analysis::gather_cost_per_vertex(&form)?;
    written.push(viz::write_vertex_heatmap(
        &mesh,
        &camera,
        &cost,
        "gather flops per vertex (biclusters)",
        &opts,
        &out.join("heat_gather_cost.png"),
    )?);
    let nnz = viz::nnz_per_vertex(&t);
    written.push(viz::write_vertex_heatmap(
        &mesh,
        &camera,
        &nnz,
        "non-zeros of T per vertex",
        &opts,
        &out.join("heat_nnz.png"),
    )?);
    let ratio: Vec<f32> =
        cost.iter().zip(&nnz).map(|(&c, &n)| if n > 0.0 { c / (2.0 * n) } else { f32::NAN }).collect();
    written.push(viz::write_vertex_heatmap(
        &mesh,
        &camera,
        &ratio,
        "biclustered / raw gather flops",
        &opts,
        &out.join("heat_flops_ratio.png"),
    )?);
    if readme {
        std::fs::create_dir_all("docs")?;
        written.push(viz::write_bicluster_patch(&t, &form, &panels, "docs/bicluster_patch.png".as_ref())?);
    }
    for p in written {
        println!("wrote {}", p.display());
    }
    Ok(())
}
