//! The stage cache: stage outputs on disk, each keyed by a content hash of everything that
//! determines it, so a run recomputes only what its config changed. Three stages are cached,
//! all as biscale artifacts (`biscale_core::artifact`: versioned, checksummed, written
//! atomically):
//!
//! * `transfer-<key>.bsf`: `T`. Key: the repaired mesh, the transfer settings (both bases and
//!   the visibility resolution) and [`TRANSFER_VERSION`]. Changing a compressor, the light or
//!   the materials does not re-trace visibility.
//! * `form-<key>-<label>.bsf`: one setting's compressed form. Key: `T`'s key, the compressor
//!   kind and its resolved parameters, the seed, the code of a plugin (its library's bytes),
//!   and the identity of this biscale build (its executable's size and modification time):
//!   compressor code changes more often than the transfer stage's, so a form is only reused by
//!   the build that made it.
//! * `sh-<key>-n<order>.bsf`: the low-frequency method's SH transfer `M` ([`sh_transfer_key`]:
//!   the mesh, the order, the rays, the seed, the bounces).
//! * `btf-<key>-<encoding>.btf`: a synthesized BTF (its key is `materials::synth_key`).
//! * `lpca-<key>-<setting>.btf`: a local-PCA BTF (`materials::lpca_key`: the dense table's
//!   content, the setting and the seed).
//!
//! A file that is present but unusable (corrupt, another version, a different shape) is
//! reported as a warning and rebuilt; failing to write the cache is a warning too, since the
//! run has its result. Nothing read from the cache is trusted beyond what its loader checks.

use crate::pipeline::RunOptions;
use biscale_core::compress::Compressor;
use biscale_core::geometry::Mesh;
use biscale_core::io::ContentHash;
use biscale_core::transfer::sh::ShTransferSettings;
use biscale_core::transfer::TransferSettings;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Bump when the transfer semantics change, so old cache files are never reused.
pub const TRANSFER_VERSION: u32 = 2;
/// Bump when the meaning of a compressed form's file changes.
pub const FORM_VERSION: u32 = 1;
/// Bump when the SH transfer's semantics change.
pub const SH_TRANSFER_VERSION: u32 = 1;

/// The cache folder of a run.
#[derive(Clone, Debug)]
pub struct StageCache {
    dir: PathBuf,
}

impl StageCache {
    /// The run's cache (`--cache-dir`, else `<out parent>/.cache`), `None` with `--no-cache`.
    pub fn new(opts: &RunOptions, out_dir: &Path) -> Option<Self> {
        if opts.no_cache {
            return None;
        }
        let dir = opts.cache_dir.clone().unwrap_or_else(|| {
            out_dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).join(".cache")
        });
        Some(Self { dir })
    }

    /// A cache in `dir`.
    pub fn in_dir(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn transfer_path(&self, key: u64) -> PathBuf {
        self.dir.join(format!("transfer-{key:016x}.bsf"))
    }

    /// The file of a compressed form; the setting's label makes the folder readable.
    pub fn form_path(&self, key: u64, label: &str) -> PathBuf {
        let label: String =
            label.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        self.dir.join(format!("form-{key:016x}-{label}.bsf"))
    }

    /// The file of an SH transfer `M` of order `n`.
    pub fn sh_transfer_path(&self, key: u64, n: u32) -> PathBuf {
        self.dir.join(format!("sh-{key:016x}-n{n}.bsf"))
    }

    /// The file of a local-PCA BTF (its key is `materials::lpca_key`).
    pub fn lpca_path(&self, key: u64, label: &str) -> PathBuf {
        self.dir.join(format!("lpca-{key:016x}-{label}.btf"))
    }

    pub fn btf_path(&self, key: u64, encoding: &str) -> PathBuf {
        self.dir.join(format!("btf-{key:016x}-{encoding}.btf"))
    }

    /// The output cached at `path`, checked by `accept`: `None` when absent or unusable (then
    /// a warning names the file and says why).
    pub fn get<T, E: std::fmt::Display>(
        &self,
        path: &Path,
        load: impl FnOnce(&Path) -> Result<T, E>,
        accept: impl FnOnce(&T) -> Result<(), String>,
    ) -> Option<T> {
        if !path.exists() {
            return None;
        }
        match load(path).map_err(|e| e.to_string()).and_then(|v| accept(&v).map(|()| v)) {
            Ok(v) => Some(v),
            Err(e) => {
                eprintln!("warning: ignoring unusable cache file (it is rebuilt): {e}");
                None
            }
        }
    }

    /// Store an output at `path` with `save` (atomic); a failure is a warning.
    pub fn put<E: std::fmt::Display>(&self, path: &Path, save: impl FnOnce(&Path) -> Result<(), E>) {
        let stored = std::fs::create_dir_all(&self.dir)
            .map_err(|e| format!("{}: {e}", self.dir.display()))
            .and_then(|()| save(path).map_err(|e| e.to_string()));
        if let Err(e) = stored {
            eprintln!("warning: could not write the cache file {}: {e}", path.display());
        }
    }
}

/// Content hash of the inputs of the transfer stage.
pub fn transfer_key(mesh: &Mesh, s: &TransferSettings) -> u64 {
    let mut h = ContentHash::default();
    h.write(&TRANSFER_VERSION.to_le_bytes()).write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write_str(&s.light_basis().tag())
        .write(&s.visibility_resolution().to_le_bytes())
        .write_str(&s.local_basis().tag());
    hash_mesh(&mut h, mesh);
    h.finish()
}

/// Content hash of the inputs of the SH transfer `M` (the low-frequency method): the mesh,
/// the order, the rays, the seed and the bounces (and their albedos, which the caller hashes
/// into `bounce_key`).
pub fn sh_transfer_key(mesh: &Mesh, s: &ShTransferSettings, bounces: u32, bounce_key: u64) -> u64 {
    let mut h = ContentHash::default();
    h.write(&SH_TRANSFER_VERSION.to_le_bytes()).write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write(&s.order().n().to_le_bytes()).write(&s.rays().to_le_bytes()).write(&s.seed().to_le_bytes());
    h.write(&bounces.to_le_bytes()).write(&bounce_key.to_le_bytes());
    hash_mesh(&mut h, mesh);
    h.finish()
}

fn hash_mesh(h: &mut ContentHash, mesh: &Mesh) {
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
}

/// Content hash of one setting's compressed form (see the module docs), or `None` when this
/// build cannot identify itself (then forms are not cached).
pub fn form_key(transfer_key: u64, compressor: &dyn Compressor, seed: u64) -> Option<u64> {
    let build = build_identity()?;
    let mut h = ContentHash::default();
    h.write(&FORM_VERSION.to_le_bytes())
        .write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes())
        .write(&build.to_le_bytes())
        .write(&transfer_key.to_le_bytes())
        .write_str(compressor.kind())
        .write_str(&compressor.params().to_string())
        .write(&seed.to_le_bytes())
        .write(&compressor.code_identity().unwrap_or(0).to_le_bytes());
    Some(h.finish())
}

/// The running executable's path, size and modification time, hashed once.
fn build_identity() -> Option<u64> {
    static ID: OnceLock<Option<u64>> = OnceLock::new();
    *ID.get_or_init(|| {
        let exe = std::env::current_exe().ok()?;
        let meta = std::fs::metadata(&exe).ok()?;
        let modified = meta.modified().ok()?.duration_since(std::time::UNIX_EPOCH).ok()?;
        let mut h = ContentHash::default();
        h.write_str(&exe.to_string_lossy()).write(&meta.len().to_le_bytes()).write(&modified.as_nanos().to_le_bytes());
        Some(h.finish())
    })
}
