//! On-disk cache of the transfer matrix, keyed by a hash of everything that determines it
//! (the repaired mesh, the transfer settings, and the cache format version), so changing a
//! compressor parameter or the light does not re-trace visibility. Files are written
//! atomically and carry a checksum; a corrupt file is reported and rebuilt, never trusted.

use crate::pipeline::RunOptions;
use biscale_compressors::sparse::Sparse;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::form_file::{load_form, save_form};
use biscale_core::geometry::Mesh;
use biscale_core::io::ContentHash;
use biscale_core::transfer::{TransferMatrix, TransferSettings};
use std::path::{Path, PathBuf};

/// Bump when the transfer semantics change, so old cache files are never reused.
const TRANSFER_VERSION: u32 = 1;

/// Content hash of the inputs of the transfer stage.
pub fn transfer_key(mesh: &Mesh, s: &TransferSettings) -> u64 {
    let mut h = ContentHash::default();
    h.write(&TRANSFER_VERSION.to_le_bytes());
    h.write_str(&s.light_basis().tag())
        .write(&s.visibility_resolution().to_le_bytes())
        .write_str(&s.local_basis().tag());
    h.write(&(mesh.positions.len() as u64).to_le_bytes());
    for p in &mesh.positions {
        for c in p.to_array() {
            h.write(&c.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for i in t {
            h.write(&i.to_le_bytes());
        }
    }
    if let Some(uvs) = &mesh.uvs {
        for uv in uvs {
            for c in uv.to_array() {
                h.write(&c.to_le_bytes());
            }
        }
    }
    h.finish()
}

/// The run's cache folder (`--cache-dir`, else `<out parent>/.cache`), `None` with `--no-cache`.
pub fn cache_dir(opts: &RunOptions, out_dir: &Path) -> Option<PathBuf> {
    if opts.no_cache {
        return None;
    }
    Some(opts.cache_dir.clone().unwrap_or_else(|| {
        out_dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).join(".cache")
    }))
}

pub struct TransferCache {
    dir: PathBuf,
}

impl TransferCache {
    /// The cache for a run, or `None` when caching is off.
    pub fn new(opts: &RunOptions, out_dir: &Path) -> Option<Self> {
        if opts.no_cache {
            return None;
        }
        cache_dir(opts, out_dir).map(|dir| Self { dir })
    }

    pub fn path(&self, key: u64) -> PathBuf {
        self.dir.join(format!("transfer-{key:016x}.bsf"))
    }

    /// The cached matrix, `Ok(None)` when absent, an error when present but unusable.
    pub fn load(&self, key: u64, s: &TransferSettings) -> Result<Option<TransferMatrix>, String> {
        let path = self.path(key);
        if !path.exists() {
            return Ok(None);
        }
        let form = load_form(&path).map_err(|e| e.to_string())?;
        let bad = |m: &str| format!("{}: {m}", path.display());
        let (rows, cols) = (form.rows(), form.cols());
        if form.kind != "sparse" || form.light_basis() != s.light_basis() || form.local_basis() != s.local_basis() {
            return Err(bad("shape does not match the settings"));
        }
        let row_ptr = form.u32s("row_ptr").map_err(|e| bad(&e.to_string()))?;
        let col_idx = form.u32s("col_idx").map_err(|e| bad(&e.to_string()))?;
        let values = form.f32s("values").map_err(|e| bad(&e.to_string()))?;
        let csr = sprs::CsMat::try_new(
            (rows, cols),
            row_ptr.iter().map(|&p| p as usize).collect(),
            col_idx.iter().map(|&c| c as usize).collect(),
            values.to_vec(),
        )
        .map_err(|e| bad(&format!("invalid CSR: {}", e.3)))?;
        Ok(Some(TransferMatrix::new(s.local_basis(), s.light_basis(), csr).map_err(|e| bad(&e.to_string()))?))
    }

    pub fn store(&self, key: u64, t: &TransferMatrix) -> Result<(), String> {
        std::fs::create_dir_all(&self.dir).map_err(|e| format!("{}: {e}", self.dir.display()))?;
        let form = Sparse.compress(t, &CompressContext::default()).map_err(|e| e.to_string())?;
        save_form(&form, &self.path(key)).map_err(|e| e.to_string())
    }
}
