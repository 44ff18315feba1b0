//! biscale's side of `scripts/peer_bench.py`: on the `T` and `L` a `biscale export` wrote
//! (`t.npz`, `l.npz`), build the sparse, bicluster (1024-vertex blocks), CPCA (32 clusters x 8
//! components) and Haar (12 terms) forms, and time each RGB gather on 1 and 2 threads
//! (interleaved rounds, medians), plus CPCA's build. Prints one JSON object, which the script
//! sets beside SciPy's `T @ L` and scikit-learn's KMeans + PCA. The gathers are checked
//! against an f64 `T L` first, so a fast wrong answer cannot be timed.
//!
//! ```text
//! cargo run --release -p biscale --example peer_gather -- EXPORT_DIR [--rounds 21]
//! ```

use anyhow::{bail, Context, Result};
use biscale::interop::npy::{self, NpyArray, NpyData};
use biscale_compressors::registry;
use biscale_core::basis::{LightBasis, LocalBasis};
use biscale_core::compress::CompressContext;
use biscale_core::gather::{reference_product, relative_l2_error};
use biscale_core::sampling::LightVector;
use biscale_core::stats::median;
use biscale_core::transfer::TransferMatrix;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Parser)]
struct Args {
    /// A `biscale export --what t,l` folder.
    export: PathBuf,
    /// Interleaved timing rounds per thread count (medians are reported).
    #[arg(long, default_value_t = 21)]
    rounds: usize,
}

fn array<'a>(arrays: &'a [(String, NpyArray)], name: &str, path: &Path) -> Result<&'a NpyArray> {
    arrays
        .iter()
        .find(|(n, _)| n == name)
        .map(|(_, a)| a)
        .with_context(|| format!("{}: no array '{name}'", path.display()))
}

fn meta_shape(arrays: &[(String, NpyArray)], path: &Path) -> Result<(LocalBasis, LightBasis)> {
    let NpyData::Str(text) = &array(arrays, biscale::interop::META, path)?.data else {
        bail!("{}: metadata is not a string", path.display())
    };
    let meta: serde_json::Value = serde_json::from_str(text)?;
    let tag = |k: &str| meta["shape"][k].as_str().map(str::to_string).with_context(|| format!("no shape.{k}"));
    Ok((LocalBasis::parse(&tag("local_basis")?)?, LightBasis::parse(&tag("light_basis")?)?))
}

fn load(dir: &Path) -> Result<(TransferMatrix, LightVector)> {
    let tp = dir.join("t.npz");
    let t = npy::read_npz(&tp)?;
    let (local, light_basis) = meta_shape(&t, &tp)?;
    let (NpyData::I64(indptr), NpyData::I32(indices), NpyData::F32(data), NpyData::I64(shape)) = (
        &array(&t, "indptr", &tp)?.data,
        &array(&t, "indices", &tp)?.data,
        &array(&t, "data", &tp)?.data,
        &array(&t, "shape", &tp)?.data,
    ) else {
        bail!("{}: indptr int64, indices int32, data float32, shape int64 expected", tp.display())
    };
    let csr = sprs::CsMat::try_new(
        (shape[0] as usize, shape[1] as usize),
        indptr.iter().map(|&x| x as usize).collect(),
        indices.iter().map(|&x| x as usize).collect(),
        data.clone(),
    )
    .map_err(|e| anyhow::anyhow!("{}: not a CSR matrix: {}", tp.display(), e.3))?;
    let matrix = TransferMatrix::new(local, light_basis, csr)?;
    let lp = dir.join("l.npz");
    let l = npy::read_npz(&lp)?;
    let NpyData::F32(values) = &array(&l, "l", &lp)?.data else { bail!("{}: 'l' is not float32", lp.display()) };
    let light = LightVector::new(light_basis, values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())?;
    Ok((matrix, light))
}

fn main() -> Result<()> {
    let args = <Args as clap::Parser>::parse();
    let (t, light) = load(&args.export)?;
    // f64 T L, the check every gather passes before it is timed.
    let exact = reference_product(&t, &light);
    let settings: [(&str, serde_json::Value); 4] = [
        ("sparse", serde_json::json!({})),
        ("bicluster", serde_json::json!({ "block_vertices": 1024 })),
        ("cpca", serde_json::json!({ "clusters": 32, "components": 8 })),
        ("haar", serde_json::json!({ "terms": 12 })),
    ];
    let pools: Vec<(usize, rayon::ThreadPool)> = [1, 2]
        .into_iter()
        .map(|n| Ok((n, rayon::ThreadPoolBuilder::new().num_threads(n).build()?)))
        .collect::<Result<_>>()?;
    let mut out = serde_json::Map::new();
    out.insert("rows".into(), t.rows().into());
    out.insert("cols".into(), t.cols().into());
    out.insert("nnz".into(), t.nnz().into());
    for (name, params) in settings {
        let c = registry::build(name, &params)?;
        let start = Instant::now();
        let form = c.compress(&t, &CompressContext::default())?;
        let build_s = start.elapsed().as_secs_f64();
        let lstar = c.gather(&form, &light)?;
        let error = relative_l2_error(lstar.values(), &exact);
        if form.lossless && error > 1e-5 {
            bail!("{name}: lossless form's gather is off by {error:.2e} relative to the f64 T L");
        }
        let mut times: Vec<Vec<f64>> = vec![vec![]; pools.len()];
        for _ in 0..args.rounds.max(1) {
            for (i, (_, pool)) in pools.iter().enumerate() {
                let s = Instant::now();
                pool.install(|| std::hint::black_box(c.gather(&form, &light)))?;
                times[i].push(s.elapsed().as_secs_f64() * 1e3);
            }
        }
        let mut entry = serde_json::Map::new();
        entry.insert("build_s".into(), build_s.into());
        entry.insert("bytes".into(), form.bytes().into());
        entry.insert("lstar_rel_error".into(), error.into());
        for ((n, _), t) in pools.iter().zip(&times) {
            entry.insert(format!("gather_ms_{n}t"), median(t).into());
        }
        out.insert(name.into(), entry.into());
        eprintln!("peer_gather: {name} done");
    }
    println!("{}", serde_json::Value::Object(out));
    Ok(())
}
