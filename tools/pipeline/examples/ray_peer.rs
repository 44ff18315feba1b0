//! biscale's side of `scripts/ray_peer.py`: the transfer stage's visibility rays as a plain
//! ray list, traced through biscale's BVH (obvhs) and, by the script, through Mitsuba 3's
//! (Embree on its LLVM variant), so the two tracers are timed on the same mesh and the same
//! rays.
//!
//! The rays: from every vertex (offset along its normal as the transfer stage offsets it), one
//! per texel centre of a 6 x R x R direction cube (R = the visibility resolution, 64 at the
//! reference setting) above the vertex's tangent plane, in the BVH's normalised space
//! (`TransferScene`: centred, diagonal 1024). Writes `positions.npy`, `triangles.npy`,
//! `origins.npy`, `normals.npy`, `directions.npy` into OUT, times the occlusion queries on
//! 1 and 2 threads (medians of interleaved rounds) and the transfer stage itself, which
//! decides the same rays (by default by coverage, each face's triangles rasterised into a
//! mask; also timed tracing every ray, tile by tile with cone-culled candidate lists), and
//! prints one JSON object.
//!
//! ```text
//! cargo run --release -p biscale --example ray_peer -- MESH OUT [--resolution 64] [--rounds 3]
//! ```

use anyhow::Result;
use biscale::interop::npy::{self, ArrayRef, Elements};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::Cubemap;
use biscale_core::stats::median;
use biscale_core::transfer::{self, TransferScene, TransferSettings, Visibility};
use glam::Vec3;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// The transfer stage's ray start in the normalised space (`geometry::bvh::RAY_TMIN`).
const RAY_TMIN: f32 = 1e-4;

#[derive(clap::Parser)]
struct Args {
    /// The mesh (OBJ or PLY).
    mesh: PathBuf,
    /// Folder for the ray arrays.
    out: PathBuf,
    /// Direction cube resolution (the transfer stage's visibility resolution).
    #[arg(long, default_value_t = 64)]
    resolution: u32,
    /// Timing rounds per thread count.
    #[arg(long, default_value_t = 3)]
    rounds: usize,
}

fn main() -> Result<()> {
    let args = <Args as clap::Parser>::parse();
    let mesh = Mesh::load(&args.mesh)?.mesh;
    // The transfer stage's own normalised space, origins and BVH.
    let scene = TransferScene::new(&mesh)?;
    let (positions, bvh) = (scene.normalised_positions(), scene.bvh());
    let normals: Vec<Vec3> = scene.frames().iter().map(|f| f.normal).collect();
    let origins: Vec<Vec3> = (0..mesh.vertex_count()).map(|v| scene.vertex_origin(v)).collect();
    let cube = Cubemap::new(args.resolution);
    let dirs: Vec<Vec3> = (0..cube.texel_count()).map(|k| cube.texel_direction(k)).collect();

    std::fs::create_dir_all(&args.out)?;
    let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let tris: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    for (name, shape, data) in [
        ("positions", [positions.len(), 3], Elements::F32(&flat(positions))),
        ("origins", [origins.len(), 3], Elements::F32(&flat(&origins))),
        ("normals", [normals.len(), 3], Elements::F32(&flat(&normals))),
        ("directions", [dirs.len(), 3], Elements::F32(&flat(&dirs))),
    ] {
        npy::write_npy(&args.out.join(format!("{name}.npy")), &ArrayRef::new(&shape, data))?;
    }
    npy::write_npy(&args.out.join("triangles.npy"), &ArrayRef::new(&[mesh.triangles.len(), 3], Elements::U32(&tris)))?;

    // Every vertex's rays above its tangent plane: (rays, occluded).
    let trace = || -> (u64, u64) {
        (0..origins.len())
            .into_par_iter()
            .map(|v| {
                let (o, n) = (origins[v], normals[v]);
                let (mut rays, mut hit) = (0u64, 0u64);
                for d in &dirs {
                    if n.dot(*d) > 0.0 {
                        rays += 1;
                        hit += u64::from(bvh.occluded(o, *d, RAY_TMIN, f32::INFINITY));
                    }
                }
                (rays, hit)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
    };
    let pools: Vec<(usize, rayon::ThreadPool)> = [1, 2]
        .into_iter()
        .map(|n| Ok((n, rayon::ThreadPoolBuilder::new().num_threads(n).build()?)))
        .collect::<Result<_>>()?;
    let mut seconds: Vec<Vec<f64>> = vec![vec![]; pools.len()];
    let mut counts = (0, 0);
    for _ in 0..args.rounds.max(1) {
        for (i, (_, pool)) in pools.iter().enumerate() {
            let s = Instant::now();
            counts = pool.install(trace);
            seconds[i].push(s.elapsed().as_secs_f64());
        }
    }
    // The transfer stage both ways (`transfer.visibility`), interleaved, medians.
    let settings = TransferSettings::new(args.resolution / 2, args.resolution, 8)?;
    let mut stage = [vec![], vec![]];
    let mut rays_decided = 0;
    for _ in 0..args.rounds.max(1) {
        for (i, how) in [Visibility::Coverage, Visibility::Rays].into_iter().enumerate() {
            let build = transfer::build(&mesh, &settings.with_visibility(how), None)?;
            rays_decided = build.stats.rays_traced;
            stage[i].push(build.stats.seconds);
        }
    }
    let stage_of = |i: usize, how: Visibility| {
        serde_json::json!({
            "visibility": how.name(),
            "rays_traced": rays_decided,
            "seconds": median(&stage[i]),
            "threads": rayon::current_num_threads(),
        })
    };
    let mut out = serde_json::json!({
        "vertices": mesh.vertex_count(),
        "triangles": mesh.triangles.len(),
        "rays": counts.0,
        "occluded": counts.1,
        "transfer_stage": stage_of(0, Visibility::Coverage),
        "transfer_stage_rays": stage_of(1, Visibility::Rays),
    });
    for ((n, _), s) in pools.iter().zip(&seconds) {
        out[format!("bvh_seconds_{n}t")] = median(s).into();
    }
    println!("{out}");
    Ok(())
}
