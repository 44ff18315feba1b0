//! Build time, storage, flops and accuracy of the lossy compressors (CPCA, Haar) on a real
//! transfer matrix, next to the raw sparse baseline.
//!
//! ```text
//! cargo run --release -p biscale-compressors --example lossy_bench -- \
//!     [assets/meshes/bunny.obj] [assets/envmaps/blender_forest.exr] [cpca|haar|all|cpca-iterations]
//! ```
//!
//! `err T` is the relative Frobenius error of the rows the form stands for (what the
//! compressors minimise). Errors are relative L2 of `L*` over all rows and channels against the f64
//! `reference_product`, for a random light with a 10^6 sun (`testing::random_light`, odd
//! seed), a random light without one (even seed), and the env map (`LightVector::from_env`,
//! R = 32, no rotation). Gather times are single runs of the CPU gather (rayon).

use biscale_compressors::cpca::Cpca;
use biscale_compressors::haar::{Haar, HaarWeighting};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::random_light;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::transfer::{self, TransferSettings};
use std::error::Error;
use std::time::Instant;

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mesh_path = args.first().map(String::as_str).unwrap_or("assets/meshes/bunny.obj");
    let env_path = args.get(1).map(String::as_str).unwrap_or("assets/envmaps/blender_forest.exr");
    let which = args.get(2).map(String::as_str).unwrap_or("all");

    let t0 = Instant::now();
    let mesh = Mesh::load_obj(mesh_path.as_ref())?.mesh;
    let settings = TransferSettings::default();
    let t = transfer::build(&mesh, &settings, None)?.matrix;
    let row_nnz: Vec<usize> = (0..t.rows()).map(|r| t.csr().outer_view(r).map_or(0, |v| v.nnz())).collect();
    let nz_rows = row_nnz.iter().filter(|&&n| n > 0).count();
    println!(
        "T: {mesh_path}: {} vertices, {} x {} ({} rows non-zero), {} nnz, {:.1} nnz/row (max {}), {:.1}s to build",
        t.vertices(),
        t.rows(),
        t.cols(),
        nz_rows,
        t.nnz(),
        t.nnz() as f64 / t.rows() as f64,
        row_nnz.iter().max().unwrap_or(&0),
        t0.elapsed().as_secs_f64()
    );

    let (env, _) = EnvMap::load(env_path.as_ref())?;
    let lights = [
        ("random+sun", random_light(settings.cubemap().resolution, 1)),
        ("random", random_light(settings.cubemap().resolution, 2)),
        ("env", LightVector::from_env(&env, settings.cubemap(), 0.0)),
    ];
    let references: Vec<_> = lights.iter().map(|(_, l)| reference_product(&t, l)).collect();
    println!("env light: {env_path}");
    println!(
        "{:<28} {:>9} {:>12} {:>8} {:>12} {:>9} {:>10} {:>12} {:>12} {:>12}",
        "compressor", "build s", "bytes", "vs csr", "flops", "gather s", "err T", "err sun", "err random", "err env"
    );

    let sparse_bytes = Sparse.compress(&t, &CompressContext::default())?.bytes();
    let run = |name: String, c: &dyn Compressor| -> Result<(), Box<dyn Error>> {
        // Progress reports, with their times: CPCA reports once per assignment/refit round.
        let reports = std::sync::Mutex::new(Vec::<(f64, f64)>::new());
        let start = Instant::now();
        let progress = |f: f64| reports.lock().unwrap().push((f, start.elapsed().as_secs_f64()));
        let ctx = CompressContext { seed: 1, progress: Some(&progress), sweep: None };
        let form = c.compress(&t, &ctx)?;
        if c.kind() == "cpca" {
            let r = reports.lock().unwrap();
            let times: Vec<String> = r.iter().map(|(_, s)| format!("{s:.1}")).collect();
            println!(
                "  {name}: {} rounds (of {} at most), progress at [{}] s",
                r.len().saturating_sub(1),
                c.params()["iterations"],
                times.join(", ")
            );
        }
        let mut errs = vec![];
        let mut gather_s = 0.0;
        for ((_, light), reference) in lights.iter().zip(&references) {
            let g0 = Instant::now();
            let lstar = c.gather(&form, light)?;
            gather_s = g0.elapsed().as_secs_f64();
            errs.push(relative_l2_error(lstar.values(), reference));
        }
        let t_err = match c.kind() {
            "cpca" => biscale_compressors::cpca::relative_frobenius_error(&form, &t)?,
            "haar" => biscale_compressors::haar::relative_frobenius_error(&form, &t)?,
            _ => 0.0,
        };
        println!(
            "{:<28} {:>9.2} {:>12} {:>8.3} {:>12} {:>9.3} {:>10.4} {:>12.4e} {:>12.4e} {:>12.4e}",
            name,
            form.build_seconds,
            form.bytes(),
            form.bytes() as f64 / sparse_bytes as f64,
            form.flops_per_gather,
            gather_s,
            t_err,
            errs[0],
            errs[1],
            errs[2]
        );
        Ok(())
    };

    run("sparse".into(), &Sparse)?;
    if which == "all" || which == "haar" {
        for terms in [6, 12, 24, 48] {
            run(format!("haar T={terms}"), &Haar::with_terms(terms))?;
        }
        run(
            "haar T=12 unweighted".into(),
            &Haar { terms: 12, weighting: HaarWeighting::Magnitude, f16_values: false },
        )?;
        run("haar T=12 f16".into(), &Haar { terms: 12, weighting: HaarWeighting::Area, f16_values: true })?;
    }
    if which == "all" || which == "cpca" {
        for (k, c) in [(8, 4), (32, 8)] {
            run(format!("cpca K={k} C={c}"), &Cpca::new(k, c))?;
        }
    }
    if which == "cpca-iterations" {
        for iterations in [1, 3, 6, 12, 24] {
            run(format!("cpca 32x8 iterations={iterations}"), &Cpca { iterations, ..Cpca::default() })?;
        }
        for power_iterations in [1, 4] {
            run(
                format!("cpca 32x8 power_iterations={power_iterations}"),
                &Cpca { power_iterations, ..Cpca::default() },
            )?;
        }
    }
    Ok(())
}
