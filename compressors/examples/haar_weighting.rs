//! How the Haar selection's ranking (`weighting`: `area`, `side`, `magnitude`) changes the
//! error of `L*`: one `T` (the bunny at the reference setting), each weighting at several term
//! counts (so the same storage), each bundled sky, the relative L2 error of the gathered `L*`
//! against the f64 `T L`. Storage does not depend on the weighting (every row keeps `terms`
//! coefficients or all of its non-zero ones).
//!
//! ```text
//! cargo run --release -p biscale-compressors --example haar_weighting -- [--mesh assets/meshes/bunny.obj]
//! ```

use biscale_compressors::haar::{Haar, HaarWeighting};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::transfer::{self, TransferSettings};
use std::path::PathBuf;

#[derive(clap::Parser)]
struct Args {
    /// The mesh T is built for (reference transfer settings).
    #[arg(long, default_value = "assets/meshes/bunny.obj")]
    mesh: PathBuf,
    /// The skies (default: every bundled one).
    #[arg(long, num_args = 1..)]
    env: Vec<PathBuf>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = <Args as clap::Parser>::parse();
    let skies: Vec<PathBuf> = if args.env.is_empty() {
        ["blender_courtyard", "blender_forest", "blender_studio", "blender_sunset", "pmndrs_apartment"]
            .iter()
            .map(|n| PathBuf::from(format!("assets/envmaps/{n}.exr")))
            .collect()
    } else {
        args.env
    };
    let mesh = Mesh::load(&args.mesh)?.mesh;
    let settings = TransferSettings::default();
    let t = transfer::build(&mesh, &settings, None)?.matrix;
    let lights: Vec<(String, LightVector)> = skies
        .iter()
        .map(|p| {
            let (env, _) = EnvMap::load(p)?;
            let name = p.file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            Ok((name, LightVector::from_env(&env, settings.cubemap(), 0.0)))
        })
        .collect::<Result<_, Box<dyn std::error::Error>>>()?;
    let exact: Vec<_> = lights.iter().map(|(_, l)| reference_product(&t, l)).collect();
    println!("T: {} vertices, {} non-zeros; relative L2 error of L* against f64 T L", t.vertices(), t.nnz());
    print!("| terms | weighting | MiB |");
    for (name, _) in &lights {
        print!(" {name} |");
    }
    println!(" mean |");
    println!("|---|---|---|{}---|", "---|".repeat(lights.len()));
    for terms in [6, 12, 24] {
        for weighting in [HaarWeighting::Area, HaarWeighting::Side, HaarWeighting::Magnitude] {
            let haar = Haar { terms, weighting, f16_values: false };
            let form = haar.compress(&t, &CompressContext::default())?;
            let mut row =
                format!("| {terms} | {} | {:.2} |", weighting.name(), form.bytes() as f64 / (1u64 << 20) as f64);
            let mut sum = 0.0;
            for ((_, light), exact) in lights.iter().zip(&exact) {
                let e = relative_l2_error(haar.gather(&form, light)?.values(), exact);
                sum += e;
                row += &format!(" {e:.4} |");
            }
            println!("{row} {:.4} |", sum / lights.len() as f64);
        }
    }
    Ok(())
}
