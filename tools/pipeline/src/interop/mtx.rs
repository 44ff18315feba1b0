//! Matrix Market text for `T` and `L` (`biscale export-matrix`, `biscale export --format mtx`):
//! the format SciPy's `scipy.io.mmread` and MATLAB read.

use crate::error::Result;
use biscale_core::io::write_atomic;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use std::io::Write;
use std::path::Path;

/// `T.mtx` and `L.mtx` in `dir`.
pub fn write_mtx(t: &TransferMatrix, light: &LightVector, dir: &Path) -> Result<()> {
    write_t_mtx(t, dir)?;
    write_l_mtx(light, dir)?;
    Ok(())
}

/// `T.mtx` in `dir` (coordinate, real, general; 1-based): its path.
pub fn write_t_mtx(t: &TransferMatrix, dir: &Path) -> Result<std::path::PathBuf> {
    let tp = dir.join("T.mtx");
    write_atomic(&tp, |f| {
        (|| -> std::io::Result<()> {
            writeln!(f, "%%MatrixMarket matrix coordinate real general")?;
            writeln!(
                f,
                "% biscale transfer matrix: row = vertex * M + j (M = {}), column = cubemap texel",
                t.local_dirs()
            )?;
            writeln!(f, "{} {} {}", t.rows(), t.cols(), t.nnz())?;
            for (r, row) in t.csr().outer_iterator().enumerate() {
                for (c, v) in row.iter() {
                    writeln!(f, "{} {} {}", r + 1, c + 1, v)?;
                }
            }
            Ok(())
        })()
        .map_err(|e| e.to_string())
    })?;
    Ok(tp)
}

/// `L.mtx` in `dir` (array N x 3, column-major): its path.
pub fn write_l_mtx(light: &LightVector, dir: &Path) -> Result<std::path::PathBuf> {
    let lp = dir.join("L.mtx");
    write_atomic(&lp, |f| {
        (|| -> std::io::Result<()> {
            writeln!(f, "%%MatrixMarket matrix array real general")?;
            writeln!(f, "% biscale light vector: power per cubemap texel (radiance x solid angle), RGB columns")?;
            writeln!(f, "{} 3", light.len())?;
            for c in 0..3 {
                for p in &light.power {
                    writeln!(f, "{:e}", p[c])?;
                }
            }
            Ok(())
        })()
        .map_err(|e| e.to_string())
    })?;
    Ok(lp)
}
