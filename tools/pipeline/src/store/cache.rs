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
//! * `reference-<key>.bsf`: the per-pixel ground-truth image before its background
//!   ([`reference_key`]: the repaired mesh and its frames, the materials as shaded, the light
//!   vector, the visibility settings, the camera and [`REFERENCE_VERSION`]). Changing a
//!   compressor, a method or the output folder does not re-trace it.
//!
//! Keys are 128-bit content hashes ([`ContentHash`], XXH3-128), written as 32 hex digits in
//! the file name. A file also carries its key inside ([`CacheKey`]: the hash and a readable
//! account of the inputs it was built from, such as the mesh's own hash and vertex count and
//! the bases), and a file whose key is missing or differs from the one the run asks for (a
//! file copied or renamed over another, or written by an earlier biscale) is never trusted:
//! a warning names it, says what it holds and what the run needs, and the output is rebuilt.
//!
//! A file that is present but unusable (corrupt, another version, a different shape, a
//! foreign key) is reported as a warning and rebuilt; failing to write the cache is a warning
//! too, since the run has its result. Nothing read from the cache is trusted beyond what its
//! loader checks.
//!
//! `biscale cache clean` removes a file only when its contents prove it biscale's (its header
//! carries the key its name names, see [`list`]): a cache folder may hold a person's own
//! files, and a name is never proof.

use crate::store::RunOptions;
use biscale_core::artifact::{Artifact, Field, MAGIC};
use biscale_core::compress::Compressor;
use biscale_core::geometry::Mesh;
use biscale_core::io::ContentHash;
use biscale_core::sampling::LightVector;
use biscale_core::scene::{BtfRepresentation, Camera, ShadeScene};
use biscale_core::transfer::sh::ShTransferSettings;
use biscale_core::transfer::TransferSettings;
use biscale_shading::reference::ReferenceRule;
use biscale_shading::synth::Brdf;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Bump when the transfer semantics change, so old cache files are never reused.
pub const TRANSFER_VERSION: u32 = 3; // 3: 128-bit keys stored inside the file
/// Bump when the meaning of a compressed form's file changes.
pub const FORM_VERSION: u32 = 2;
/// Bump when the SH transfer's semantics change.
pub const SH_TRANSFER_VERSION: u32 = 2;
/// Bump whenever the per-pixel reference image could come out different for the same inputs:
/// a change to `biscale_shading::reference::render_reference` or to what it calls (the primary
/// rays and hit interpolation of `biscale_shading::cpu::render_rows`, `shade_point` and the
/// BTF lookups, `TransferScene::visibility_at` and `VisibilitySampler`, `TexelCosine`, the
/// camera's rays), or to how `stages::evaluate::reference` calls it. The key hashes the
/// inputs, not the code: without a bump a cached reference of the old code is reused.
/// 2: analytic materials' BRDFs evaluated at each texel's exact direction; 3: their view
/// clamped onto the shading horizon as the BTF's view grid clamps it.
pub const REFERENCE_VERSION: u32 = 3;

/// The kinds of cache file `biscale cache list` names and `biscale cache clean --kind` takes
/// (besides `other`, which clean never touches).
pub const KINDS: &[&str] = &["transfer", "form", "sh", "btf", "lpca", "reference", "temporary"];

/// Names of the fields that carry a cache file's key inside it.
const KEY_FIELD: &str = "cache.key";
const INPUTS_FIELD: &str = "cache.inputs";

/// The identity of a cached output: the content hash of everything that determines it, and
/// a readable account of those inputs (for messages; the hash alone decides). Both are
/// written into the file and checked when it is read back.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CacheKey {
    pub hash: u128,
    pub inputs: String,
}

impl CacheKey {
    pub fn new(hash: u128, inputs: impl Into<String>) -> Self {
        Self { hash, inputs: inputs.into() }
    }

    /// The hash as written in file names and inside files: 32 hex digits.
    pub fn hex(&self) -> String {
        format!("{:032x}", self.hash)
    }

    /// A key derived from this one for an output computed from it (`what` says how).
    pub fn derived(&self, what: &str) -> Self {
        let hash = ContentHash::default().write(&self.hash.to_le_bytes()).write_str(what).finish128();
        Self { hash, inputs: format!("{}; {what}", self.inputs) }
    }

    fn fields(&self) -> BTreeMap<String, Field> {
        BTreeMap::from([
            (KEY_FIELD.to_string(), Field::Str(self.hex())),
            (INPUTS_FIELD.to_string(), Field::Str(self.inputs.clone())),
        ])
    }

    /// Check that `a` (read from `path`) was written under this key, and take the key fields
    /// out of it.
    fn check(&self, a: &mut Artifact, path: &Path) -> Result<(), String> {
        let found = a.fields.remove(KEY_FIELD);
        let inputs = a.fields.remove(INPUTS_FIELD);
        match found {
            Some(Field::Str(k)) if k == self.hex() => Ok(()),
            Some(Field::Str(k)) => Err(format!(
                "{}: a foreign cache file: it was built for {} (key {k}); this run needs {} (key {})",
                path.display(),
                match inputs {
                    Some(Field::Str(i)) => i,
                    _ => "unknown inputs".into(),
                },
                self.inputs,
                self.hex()
            )),
            _ => Err(format!(
                "{}: the file carries no cache key (written by an earlier biscale, or not written by the cache)",
                path.display()
            )),
        }
    }
}

/// The cache folder of a run.
#[derive(Clone, Debug)]
pub struct StageCache {
    dir: PathBuf,
}

impl StageCache {
    /// The run's cache (`--cache-dir`, else [`default_dir`]), `None` with `--no-cache`.
    pub fn new(opts: &RunOptions, _out_dir: &Path) -> Option<Self> {
        if opts.no_cache {
            return None;
        }
        Some(Self { dir: opts.cache_dir.clone().unwrap_or_else(default_dir) })
    }

    /// A cache in `dir`.
    pub fn in_dir(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn transfer_path(&self, key: &CacheKey) -> PathBuf {
        self.dir.join(format!("transfer-{}.bsf", key.hex()))
    }

    /// The file of a compressed form; the setting's label makes the folder readable.
    pub fn form_path(&self, key: &CacheKey, label: &str) -> PathBuf {
        let label: String =
            label.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        self.dir.join(format!("form-{}-{label}.bsf", key.hex()))
    }

    /// The file of an SH transfer `M` of order `n`.
    pub fn sh_transfer_path(&self, key: &CacheKey, n: u32) -> PathBuf {
        self.dir.join(format!("sh-{}-n{n}.bsf", key.hex()))
    }

    /// The file of a local-PCA BTF (its key is `materials::lpca_key`).
    pub fn lpca_path(&self, key: &CacheKey, label: &str) -> PathBuf {
        self.dir.join(format!("lpca-{}-{label}.btf", key.hex()))
    }

    pub fn btf_path(&self, key: &CacheKey, encoding: &str) -> PathBuf {
        self.dir.join(format!("btf-{}-{encoding}.btf", key.hex()))
    }

    /// The file of a per-pixel reference image (its key is [`reference_key`]).
    pub fn reference_path(&self, key: &CacheKey) -> PathBuf {
        self.dir.join(format!("reference-{}.bsf", key.hex()))
    }

    /// The output cached at `path` under `key`, decoded by `decode` and checked by `accept`:
    /// `None` when absent or unusable (then a warning names the file and says why: corrupt,
    /// foreign key, wrong shape).
    pub fn get<T, E: std::fmt::Display>(
        &self,
        path: &Path,
        key: &CacheKey,
        decode: impl FnOnce(Artifact) -> Result<T, E>,
        accept: impl FnOnce(&T) -> Result<(), String>,
    ) -> Option<T> {
        if !path.exists() {
            return None;
        }
        let read = Artifact::load(path).map_err(|e| e.to_string()).and_then(|mut a| {
            key.check(&mut a, path)?;
            let v = decode(a).map_err(|e| e.to_string())?;
            accept(&v).map(|()| v)
        });
        match read {
            Ok(v) => Some(v),
            Err(e) => {
                crate::util::warn(format_args!("ignoring unusable cache file (it is rebuilt): {e}"));
                None
            }
        }
    }

    /// Store `artifact` at `path` with `key` inside it (atomic); a failure is a warning.
    pub fn put(&self, path: &Path, key: &CacheKey, artifact: &Artifact) {
        let stored = std::fs::create_dir_all(&self.dir)
            .map_err(|e| format!("{}: {e}", self.dir.display()))
            .and_then(|()| artifact.save_with(path, &key.fields()).map_err(|e| e.to_string()));
        if let Err(e) = stored {
            crate::util::warn(format_args!("could not write the cache file {}: {e}", path.display()));
        }
    }

    /// [`Self::put`] of an artifact that may fail to build (a warning too).
    pub fn put_with<E: std::fmt::Display>(
        &self,
        path: &Path,
        key: &CacheKey,
        artifact: impl FnOnce() -> Result<Artifact, E>,
    ) {
        match artifact() {
            Ok(a) => self.put(path, key, &a),
            Err(e) => crate::util::warn(format_args!("could not write the cache file {}: {e}", path.display())),
        }
    }
}

/// The key of the transfer stage: the mesh, the transfer settings (both bases and the
/// visibility resolution) and the versions.
pub fn transfer_key(mesh: &Mesh, s: &TransferSettings) -> CacheKey {
    let mut h = ContentHash::default();
    h.write(&TRANSFER_VERSION.to_le_bytes()).write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write_str(&s.light_basis().tag())
        .write(&s.visibility_resolution().to_le_bytes())
        .write_str(&s.local_basis().tag())
        .write_str(s.visibility().name());
    let mesh_hash = mesh_hash(mesh);
    h.write(&mesh_hash.to_le_bytes());
    CacheKey::new(
        h.finish128(),
        format!(
            "T of {}, light {}, local {}, visibility {} by {}",
            describe_mesh(mesh, mesh_hash),
            s.light_basis(),
            s.local_basis(),
            s.visibility_resolution(),
            s.visibility().name()
        ),
    )
}

/// The key of the SH transfer `M` (the low-frequency method): the mesh, the order, the rays,
/// the seed and the bounces (and their albedos, which the caller hashes into `bounce_key`).
pub fn sh_transfer_key(mesh: &Mesh, s: &ShTransferSettings, bounces: u32, bounce_key: u128) -> CacheKey {
    let mut h = ContentHash::default();
    h.write(&SH_TRANSFER_VERSION.to_le_bytes()).write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write(&s.order().n().to_le_bytes()).write(&s.rays().to_le_bytes()).write(&s.seed().to_le_bytes());
    h.write(&bounces.to_le_bytes()).write(&bounce_key.to_le_bytes());
    let mesh_hash = mesh_hash(mesh);
    h.write(&mesh_hash.to_le_bytes());
    CacheKey::new(
        h.finish128(),
        format!(
            "SH transfer of {}, order {}, {} rays, seed {}, {bounces} bounce(s) (albedos {bounce_key:032x})",
            describe_mesh(mesh, mesh_hash),
            s.order().n(),
            s.rays(),
            s.seed()
        ),
    )
}

/// The key of the per-pixel reference image that `rule` renders of `scene` under `light` with
/// `settings`' visibility, seen by `camera`, before any background is added (a run adds it
/// after loading, from the env map). Everything `render_reference` reads, by content: the
/// mesh (positions, triangles, UVs) and the vertex frames it interpolates, each material's
/// BTF as shaded (its table, or a local-PCA fit's stored values; not its name) and tiling,
/// the per-triangle material ids, the light vector's basis and every texel's power (so the
/// env map, its rotation, `sun_boost` and the cubemap resolution as they came out), both
/// bases and the visibility resolution, every field of the camera (position, target, up,
/// field of view, width and height after `reference_downscale`, samples per pixel), the rule,
/// each material's analytic BRDF (its every parameter) and [`REFERENCE_VERSION`]. Nothing
/// random is drawn, so no seed.
pub fn reference_key(
    scene: &ShadeScene,
    light: &LightVector,
    settings: &TransferSettings,
    camera: &Camera,
    rule: ReferenceRule,
    analytic: &[Option<Brdf>],
) -> CacheKey {
    let mut h = ContentHash::default();
    h.write(&REFERENCE_VERSION.to_le_bytes()).write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write_str(&format!("{rule:?}"));
    // Debug prints every parameter, f32s as their shortest exact decimal.
    h.write_str(&format!("{analytic:?}"));
    h.write_str(&settings.light_basis().tag())
        .write(&settings.visibility_resolution().to_le_bytes())
        .write_str(&settings.local_basis().tag());
    let c = camera;
    let mut floats = FloatHash::default();
    floats.extend(&mut h, [c.position, c.target, c.up].iter().flat_map(|v| v.to_array()));
    floats.extend(&mut h, [c.fov_y_degrees]);
    floats.flush(&mut h);
    h.write(&c.width.to_le_bytes()).write(&c.height.to_le_bytes()).write(&c.samples_per_pixel.to_le_bytes());
    let mesh_hash = mesh_hash(scene.mesh());
    h.write(&mesh_hash.to_le_bytes());
    let frames = scene.frames();
    h.write(&(frames.len() as u64).to_le_bytes());
    floats.extend(&mut h, frames.iter().flat_map(|f| [f.tangent, f.bitangent, f.normal]).flat_map(|v| v.to_array()));
    floats.flush(&mut h);
    let light_hash = {
        let mut l = ContentHash::default();
        l.write_str(&light.basis().tag()).write(&(light.power.len() as u64).to_le_bytes());
        floats.extend(&mut l, light.power.iter().flatten().copied());
        floats.flush(&mut l);
        l.finish128()
    };
    h.write(&light_hash.to_le_bytes());
    let materials_hash = {
        let mut m = ContentHash::default();
        m.write(&(scene.materials().len() as u64).to_le_bytes());
        for material in scene.materials() {
            m.write(&material.tiling.to_bits().to_le_bytes());
            match &material.btf {
                BtfRepresentation::Dense(b) => {
                    m.write_str("dense").write_str(&b.local_basis().tag());
                    m.write(&b.spatial()[0].to_le_bytes()).write(&b.spatial()[1].to_le_bytes());
                    m.write(&b.view_grid().map_or(0, |g| g.m).to_le_bytes());
                    m.write(&(b.data().len() as u64).to_le_bytes());
                    floats.extend(&mut m, b.data().iter().flatten().copied());
                    floats.flush(&mut m);
                }
                BtfRepresentation::Lpca(l) => {
                    let mut a = l.to_artifact();
                    a.fields.remove("name");
                    m.write_str("lpca").write(&a.encode());
                }
            }
        }
        match scene.triangle_materials() {
            None => m.write(&[0]),
            Some(ids) => {
                m.write(&[1]).write(&(ids.len() as u64).to_le_bytes());
                let bytes: Vec<u8> = ids.iter().flat_map(|i| i.to_le_bytes()).collect();
                m.write(&bytes)
            }
        };
        m.finish128()
    };
    h.write(&materials_hash.to_le_bytes());
    CacheKey::new(
        h.finish128(),
        format!(
            "{rule:?} reference {}x{} ({} sample(s) per pixel) from ({:.4}, {:.4}, {:.4}) at ({:.4}, {:.4}, {:.4}), \
             fov {} deg, of {}, {} material(s) (hash {materials_hash:032x}), light {} (hash {light_hash:032x}), \
             local {}, visibility {}",
            c.width,
            c.height,
            c.samples_per_pixel,
            c.position.x,
            c.position.y,
            c.position.z,
            c.target.x,
            c.target.y,
            c.target.z,
            c.fov_y_degrees,
            describe_mesh(scene.mesh(), mesh_hash),
            scene.materials().len(),
            light.basis(),
            settings.local_basis(),
            settings.visibility_resolution()
        ),
    )
}

/// f32 values fed to a [`ContentHash`] as little-endian bytes, a block at a time (one hash
/// update per value would dominate the key of a large mesh).
#[derive(Default)]
struct FloatHash {
    buf: Vec<u8>,
}

impl FloatHash {
    const BLOCK: usize = 1 << 16;

    fn extend(&mut self, h: &mut ContentHash, values: impl IntoIterator<Item = f32>) {
        for v in values {
            self.buf.extend_from_slice(&v.to_bits().to_le_bytes());
            if self.buf.len() >= Self::BLOCK {
                self.flush(h);
            }
        }
    }

    fn flush(&mut self, h: &mut ContentHash) {
        h.write(&self.buf);
        self.buf.clear();
    }
}

/// A mesh in a key's account: its vertex and triangle counts and its content hash.
fn describe_mesh(mesh: &Mesh, mesh_hash: u128) -> String {
    format!(
        "the mesh of {} vertices and {} triangles (mesh hash {mesh_hash:032x})",
        mesh.vertex_count(),
        mesh.triangle_count()
    )
}

/// The content hash of a mesh (positions, triangles, UVs), hashed once into every key of it.
fn mesh_hash(mesh: &Mesh) -> u128 {
    let mut h = ContentHash::default();
    h.write(&(mesh.positions.len() as u64).to_le_bytes());
    for p in &mesh.positions {
        for c in p.to_array() {
            h.write(&c.to_le_bytes());
        }
    }
    h.write(&(mesh.triangles.len() as u64).to_le_bytes());
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
    h.finish128()
}

/// The key of one setting's compressed form of the `T` keyed `transfer` (see the module
/// docs), or `None` when this build cannot identify itself (then forms are not cached).
pub fn form_key(transfer: &CacheKey, compressor: &dyn Compressor, seed: u64) -> Option<CacheKey> {
    let build = build_identity()?;
    let mut h = ContentHash::default();
    h.write(&FORM_VERSION.to_le_bytes())
        .write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes())
        .write(&build.to_le_bytes())
        .write(&transfer.hash.to_le_bytes())
        .write_str(compressor.kind())
        .write_str(&compressor.params().to_string())
        .write(&seed.to_le_bytes())
        .write(&compressor.code_identity().unwrap_or(0).to_le_bytes());
    Some(CacheKey::new(
        h.finish128(),
        format!(
            "a {} form ({}, seed {seed}, this biscale build) of {}",
            compressor.kind(),
            compressor.params(),
            transfer.inputs
        ),
    ))
}

/// The path, size and modification time of the file holding this code, hashed once: the
/// executable, or the shared library biscale is linked into (the Python module, whose process's
/// executable is the interpreter, which says nothing of biscale's code).
fn build_identity() -> Option<u128> {
    static ID: OnceLock<Option<u128>> = OnceLock::new();
    *ID.get_or_init(|| {
        let exe = code_file()?;
        let meta = std::fs::metadata(&exe).ok()?;
        let modified = meta.modified().ok()?.duration_since(std::time::UNIX_EPOCH).ok()?;
        let mut h = ContentHash::default();
        h.write_str(&exe.to_string_lossy()).write(&meta.len().to_le_bytes()).write(&modified.as_nanos().to_le_bytes());
        Some(h.finish128())
    })
}

/// The file this code was loaded from: `dladdr` of one of its functions, where that is a
/// shared library; else the running executable.
fn code_file() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        // SAFETY: `dladdr` only reads the address (a function of this crate) and fills `info`;
        // `dli_fname`, when set, points at a NUL-terminated path the loader keeps alive.
        let mut info: libc::Dl_info = unsafe { std::mem::zeroed() };
        let found = unsafe { libc::dladdr(code_file as *const libc::c_void, &mut info) } != 0;
        if found && !info.dli_fname.is_null() {
            let name = unsafe { std::ffi::CStr::from_ptr(info.dli_fname) };
            let path = PathBuf::from(std::ffi::OsStr::from_bytes(name.to_bytes()));
            let library =
                std::fs::canonicalize(&path).ok().filter(|p| std::fs::canonicalize(&exe).ok().as_ref() != Some(p));
            if let Some(library) = library.filter(|_| path.is_absolute()) {
                return Some(library);
            }
        }
    }
    Some(exe)
}

#[cfg(test)]
mod tests {
    use super::*;
    use biscale_core::compress::ArrayData;

    fn artifact() -> Artifact {
        Artifact::new("probe").with("n", Field::U64(3)).with_array("v", ArrayData::F32(vec![1.0, 2.0]))
    }

    /// A test executable is its own code file (the module's case, a library, is tested by
    /// python/tests: its forms are cached under keys of its own).
    #[test]
    fn the_code_of_an_executable_is_the_executable() {
        assert_eq!(code_file(), std::env::current_exe().ok());
        assert!(build_identity().is_some());
    }

    fn decode(a: Artifact) -> Result<Artifact, String> {
        Ok(a)
    }

    /// Every kind of cache file (T, forms, SH transfers, BTFs, LPCA BTFs) goes through `put`
    /// and `get`: a file of another key at this key's path, or one without a key, is not
    /// taken; the right one is, without the key fields.
    #[test]
    fn foreign_and_keyless_cache_files_are_not_taken() {
        let dir = tempfile::tempdir().unwrap();
        let cache = StageCache::in_dir(dir.path());
        let mine = CacheKey::new(1 << 100 | 7, "mine");
        let theirs = CacheKey::new(1 << 100 | 8, "theirs");
        let path = cache.btf_path(&mine, "f16");
        assert!(path.to_string_lossy().contains(&format!("{:032x}", mine.hash)));
        cache.put(&path, &theirs, &artifact());
        assert!(cache.get(&path, &mine, decode, |_| Ok(())).is_none(), "a foreign file is rebuilt");
        artifact().save(&path).unwrap();
        assert!(cache.get(&path, &mine, decode, |_| Ok(())).is_none(), "a file without a key is rebuilt");
        cache.put(&path, &mine, &artifact());
        let back = cache.get(&path, &mine, decode, |_| Ok(())).expect("its own file is taken");
        assert_eq!(Artifact { source: Default::default(), ..back }, artifact());
        // `accept` still has the last word.
        assert!(cache.get(&path, &mine, decode, |_| Err("no".into())).is_none());
    }

    #[test]
    fn a_foreign_file_is_named_with_what_it_holds_and_what_the_run_needs() {
        let mine = CacheKey::new(1, "T of the bunny");
        let theirs = CacheKey::new(2, "T of the teapot");
        let mut a = Artifact::decode(&artifact().encode_with(&theirs.fields()), Path::new("c/x.bsf")).unwrap();
        let e = mine.check(&mut a, Path::new("c/x.bsf")).unwrap_err();
        assert!(e.contains("c/x.bsf") && e.contains("teapot") && e.contains("bunny") && e.contains("foreign"), "{e}");
    }

    #[test]
    fn keys_change_with_the_mesh_and_settings() {
        use biscale_core::geometry::shapes;
        let s = TransferSettings::new(8, 16, 4).unwrap();
        let mesh = shapes::uv_sphere(glam::Vec3::ZERO, 1.0, 6, 8);
        let mut moved = mesh.clone();
        moved.positions[0].x += 1e-3;
        assert_eq!(transfer_key(&mesh, &s), transfer_key(&mesh, &s));
        assert_ne!(transfer_key(&mesh, &s).hash, transfer_key(&moved, &s).hash);
        assert_ne!(transfer_key(&mesh, &s).hash, transfer_key(&mesh, &TransferSettings::new(8, 16, 2).unwrap()).hash);
        let rays = s.with_visibility(biscale_core::transfer::Visibility::Rays);
        assert_ne!(transfer_key(&mesh, &s).hash, transfer_key(&mesh, &rays).hash);
        assert!(transfer_key(&mesh, &rays).inputs.contains("by rays"));
        assert!(transfer_key(&mesh, &s).inputs.contains("mesh hash"));
    }

    /// The reference's key changes with every input the reference reads (the mesh, a frame,
    /// the materials' tables and tiling, the light's power, the visibility resolution, every
    /// field of the camera, the rule) and is the same for the same inputs built twice.
    #[test]
    fn the_reference_key_changes_with_each_input_it_reads() {
        use biscale_core::geometry::{shapes, vertex_frames};
        use biscale_core::scene::{Btf, Material};
        let s = TransferSettings::new(8, 16, 4).unwrap();
        let scene_of = |mesh: &Mesh, material: Material| {
            ShadeScene::new(mesh.clone(), vertex_frames(mesh).0, vec![material], None).unwrap()
        };
        let grey = || Material::new(Btf::lambertian([0.5; 3], s.local_basis()).unwrap());
        let mesh = shapes::uv_sphere(glam::Vec3::ZERO, 1.0, 6, 8);
        let light = LightVector::constant(s.light_basis(), [1.0, 0.9, 0.8]);
        let camera = Camera::frame_bounds(glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0), 32, 24, 20.0, 10.0, 40.0);
        let rule = ReferenceRule::GroundTruth;
        let lambert = |a: f32| Brdf::Lambertian { albedo: [a; 3] };
        let base = reference_key(&scene_of(&mesh, grey()), &light, &s, &camera, rule, &[]);
        assert_eq!(base, reference_key(&scene_of(&mesh.clone(), grey()), &light, &s, &camera, rule, &[]));
        assert!(base.inputs.contains("mesh hash") && base.inputs.contains("32x24"), "{}", base.inputs);

        let mut moved = mesh.clone();
        moved.positions[0].x += 1e-3;
        let mut turned = scene_of(&mesh, grey());
        let mut frames = turned.frames().to_vec();
        frames[3].normal.y += 1e-3;
        turned = ShadeScene::new(mesh.clone(), frames, vec![grey()], None).unwrap();
        let red = Material::new(Btf::lambertian([0.6, 0.5, 0.5], s.local_basis()).unwrap());
        let tiled = Material { tiling: 2.0, ..grey() };
        let mut brighter = light.clone();
        brighter.power[5][1] *= 1.001;
        let mut moved_camera = camera;
        moved_camera.position.x += 1e-3;
        let mut more_samples = camera;
        more_samples.samples_per_pixel = 4;
        let others = [
            ("mesh", reference_key(&scene_of(&moved, grey()), &light, &s, &camera, rule, &[])),
            ("frame", reference_key(&turned, &light, &s, &camera, rule, &[])),
            ("albedo", reference_key(&scene_of(&mesh, red), &light, &s, &camera, rule, &[])),
            ("tiling", reference_key(&scene_of(&mesh, tiled), &light, &s, &camera, rule, &[])),
            ("light", reference_key(&scene_of(&mesh, grey()), &brighter, &s, &camera, rule, &[])),
            (
                "visibility",
                reference_key(
                    &scene_of(&mesh, grey()),
                    &light,
                    &TransferSettings::new(8, 32, 4).unwrap(),
                    &camera,
                    rule,
                    &[],
                ),
            ),
            ("camera", reference_key(&scene_of(&mesh, grey()), &light, &s, &moved_camera, rule, &[])),
            ("size", reference_key(&scene_of(&mesh, grey()), &light, &s, &Camera { width: 16, ..camera }, rule, &[])),
            ("samples", reference_key(&scene_of(&mesh, grey()), &light, &s, &more_samples, rule, &[])),
            ("rule", reference_key(&scene_of(&mesh, grey()), &light, &s, &camera, ReferenceRule::Binned, &[])),
            ("analytic", reference_key(&scene_of(&mesh, grey()), &light, &s, &camera, rule, &[Some(lambert(0.5))])),
            (
                "analytic parameter",
                reference_key(&scene_of(&mesh, grey()), &light, &s, &camera, rule, &[Some(lambert(0.5 + 1e-6))]),
            ),
        ];
        let mut seen = std::collections::BTreeSet::from([base.hash]);
        for (what, key) in &others {
            assert!(seen.insert(key.hash), "changing the {what} left the key as it was");
        }
        let cache = StageCache::in_dir("c");
        assert_eq!(cache.reference_path(&base), Path::new("c").join(format!("reference-{}.bsf", base.hex())));
        assert_eq!(parse_name(&format!("reference-{}.bsf", base.hex())), Some(("reference", base.hex().as_str())));
        assert_eq!(parse_name(&format!("reference-{}-x.bsf", base.hex())), None);
    }
}

/// The cache folder every command shares unless given `--cache-dir`:
/// `$XDG_CACHE_HOME/biscale`, else `$HOME/.cache/biscale`, else `.cache` in the working folder.
pub fn default_dir() -> PathBuf {
    let absolute = |var: &str| std::env::var_os(var).map(PathBuf::from).filter(|p| p.is_absolute());
    match (absolute("XDG_CACHE_HOME"), absolute("HOME")) {
        (Some(xdg), _) => xdg.join("biscale"),
        (None, Some(home)) => home.join(".cache").join("biscale"),
        (None, None) => PathBuf::from(".cache"),
    }
}

/// One file of a cache folder (`biscale cache list`).
#[derive(Clone, Debug)]
pub struct Entry {
    pub name: String,
    /// `transfer`, `form`, `sh`, `btf`, `lpca`, `reference`, `temporary` (a write that never
    /// finished) or `other` (not proved biscale's by its contents, whatever its name).
    pub kind: &'static str,
    pub bytes: u64,
    pub modified: std::time::SystemTime,
    /// The inputs it was built from, as its key records them (read from the file's header).
    pub inputs: Option<String>,
}

/// The kind a cache file's name claims, with the key its name carries: `<kind>-<32 hex>.bsf`
/// for `T` and the reference, `<kind>-<32 hex>-<rest>` for the others, `.bsf` for matrices and forms, `.btf` for
/// BTFs. A name is only a claim: [`owned`] checks it against the file's own header.
fn parse_name(name: &str) -> Option<(&'static str, &str)> {
    let (kind, ext): (&'static str, &str) = match name.split('-').next()? {
        "transfer" => ("transfer", ".bsf"),
        "form" => ("form", ".bsf"),
        "sh" => ("sh", ".bsf"),
        "btf" => ("btf", ".btf"),
        "lpca" => ("lpca", ".btf"),
        "reference" => ("reference", ".bsf"),
        _ => return None,
    };
    let rest = name.strip_prefix(kind)?.strip_prefix('-')?.strip_suffix(ext)?;
    let hex = rest.get(..32)?;
    let tail = &rest[32..];
    let tail_ok = match kind {
        "transfer" | "reference" => tail.is_empty(),
        _ => tail.len() > 1 && tail.starts_with('-'),
    };
    (hex.bytes().all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase()) && tail_ok).then_some((kind, hex))
}

/// The kind of the cache file `name` in `dir`, proved from its contents, not taken from its
/// name: a stage output is biscale's when its name parses ([`parse_name`]) and its header is a
/// biscale artifact carrying the key its name names; a temporary (`.<name>.tmp-<pid>-<n>`, what
/// an interrupted atomic write leaves) when the name it was written for parses, pid and counter
/// are numbers, and its bytes begin as an artifact does (an empty one holds nothing of anyone).
/// Everything else is `other`, and `biscale cache clean` never touches it, whatever its name.
/// Returns the kind and, for a stage output, the inputs its key records.
fn owned(dir: &Path, name: &str) -> (&'static str, Option<String>) {
    if let Some((kind, hex)) = parse_name(name) {
        if let Ok((_, fields)) = Artifact::peek(&dir.join(name)) {
            if matches!(fields.get(KEY_FIELD), Some(Field::Str(k)) if k == hex) {
                let inputs = match fields.get(INPUTS_FIELD) {
                    Some(Field::Str(s)) => Some(s.clone()),
                    _ => None,
                };
                return (kind, inputs);
            }
        }
        return ("other", None);
    }
    let temporary = name.strip_prefix('.').and_then(|n| n.rsplit_once(".tmp-")).is_some_and(|(target, id)| {
        let numbers = id
            .split_once('-')
            .is_some_and(|(pid, n)| [pid, n].iter().all(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())));
        numbers && parse_name(target).is_some() && starts_like_an_artifact(&dir.join(name))
    });
    (if temporary { "temporary" } else { "other" }, None)
}

/// Whether the file's first bytes are (a prefix of) the artifact magic.
fn starts_like_an_artifact(path: &Path) -> bool {
    use std::io::Read;
    let mut head = Vec::with_capacity(MAGIC.len());
    let read =
        biscale_core::io::open_regular(path).and_then(|(f, _)| f.take(MAGIC.len() as u64).read_to_end(&mut head));
    read.is_ok() && MAGIC.starts_with(&head)
}

/// Every file of the cache folder `dir`, by name (an absent folder is an empty cache), each
/// with the kind its contents prove ([`owned`]).
pub fn list(dir: &Path) -> std::io::Result<Vec<Entry>> {
    let read = match std::fs::read_dir(dir) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
        Err(e) => return Err(e),
    };
    let mut out = vec![];
    for e in read {
        let e = e?;
        // Not followed: a link in the cache folder is not a file biscale wrote.
        let meta = std::fs::symlink_metadata(e.path())?;
        if !meta.is_file() {
            continue;
        }
        let name = e.file_name().to_string_lossy().into_owned();
        let (kind, inputs) = owned(dir, &name);
        out.push(Entry { name, kind, bytes: meta.len(), modified: meta.modified()?, inputs });
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}

/// What `biscale cache clean` removes: biscale's files (never `other` ones) of the given
/// kinds (all when empty) last modified at least `older_than` ago.
#[derive(Clone, Debug, Default)]
pub struct CleanFilter {
    pub kinds: Vec<String>,
    pub older_than: Option<std::time::Duration>,
}

/// Remove the files `filter` selects from `dir` (only list them with `dry_run`): the entries
/// removed.
pub fn clean(dir: &Path, filter: &CleanFilter, dry_run: bool) -> std::io::Result<Vec<Entry>> {
    let now = std::time::SystemTime::now();
    let mut removed = vec![];
    for e in list(dir)? {
        let kind_ok = e.kind != "other" && (filter.kinds.is_empty() || filter.kinds.iter().any(|k| k == e.kind));
        let old_enough = filter.older_than.is_none_or(|d| now.duration_since(e.modified).unwrap_or_default() >= d);
        if kind_ok && old_enough {
            if !dry_run {
                std::fs::remove_file(dir.join(&e.name))?;
            }
            removed.push(e);
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod listing_tests {
    use super::*;

    fn kinds(entries: &[Entry]) -> Vec<(String, &'static str)> {
        entries.iter().map(|e| (e.name.clone(), e.kind)).collect()
    }

    #[test]
    fn list_names_each_file_and_clean_removes_only_what_is_asked() {
        let dir = tempfile::tempdir().unwrap();
        let cache = StageCache::in_dir(dir.path());
        let key = CacheKey::new(0xabc, "mesh abc, 3 vertices");
        let artifact = Artifact::new("probe").with("n", Field::U64(1));
        cache.put(&cache.transfer_path(&key), &key, &artifact);
        cache.put(&cache.form_path(&key, "bicluster"), &key, &artifact);
        cache.put(&cache.reference_path(&key), &key, &artifact);
        let temp = format!(".transfer-{}.bsf.tmp-1-2", key.hex());
        std::fs::write(dir.path().join(&temp), &MAGIC[..5]).unwrap();
        std::fs::write(dir.path().join("notes.txt"), b"mine").unwrap();
        let all = list(dir.path()).unwrap();
        assert_eq!(
            kinds(&all),
            [
                (temp.clone(), "temporary"),
                (format!("form-{}-bicluster.bsf", key.hex()), "form"),
                ("notes.txt".to_string(), "other"),
                (format!("reference-{}.bsf", key.hex()), "reference"),
                (format!("transfer-{}.bsf", key.hex()), "transfer"),
            ]
        );
        assert_eq!(all[4].inputs.as_deref(), Some("mesh abc, 3 vertices"), "read from the header");
        assert!(all[4].bytes > 0);
        assert!(all.iter().all(|e| e.kind == "other" || KINDS.contains(&e.kind)), "every kind is one clean takes");

        // Too young to clean; a dry run removes nothing.
        let old = CleanFilter { kinds: vec![], older_than: Some(std::time::Duration::from_secs(3600)) };
        assert!(clean(dir.path(), &old, false).unwrap().is_empty());
        let temps = CleanFilter { kinds: vec!["temporary".into()], older_than: None };
        assert_eq!(clean(dir.path(), &temps, true).unwrap().len(), 1);
        assert_eq!(list(dir.path()).unwrap().len(), 5);
        assert_eq!(kinds(&clean(dir.path(), &temps, false).unwrap()), [(temp, "temporary")]);
        let references = CleanFilter { kinds: vec!["reference".into()], older_than: None };
        assert_eq!(
            kinds(&clean(dir.path(), &references, false).unwrap()),
            [(format!("reference-{}.bsf", key.hex()), "reference")]
        );
        // Everything of biscale's goes; the user's own file stays.
        assert_eq!(clean(dir.path(), &CleanFilter::default(), false).unwrap().len(), 2);
        assert_eq!(kinds(&list(dir.path()).unwrap()), [("notes.txt".to_string(), "other")]);
        assert!(list(&dir.path().join("absent")).unwrap().is_empty());
    }

    /// Issue class "cache clean deletes by file name": a cache folder that also holds a
    /// person's files, named like biscale's (stage outputs, temporaries, keys of the right
    /// length), keeps every one of them through `clean` of every kind; only the files whose
    /// header carries the key their name names, and the temporaries that begin as an artifact
    /// does, go.
    #[test]
    fn cache_clean_removes_only_files_whose_header_proves_them_biscales() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cache = StageCache::in_dir(d);
        let key = CacheKey::new(0x1234_5678_9abc_def0_1122_3344_5566_7788, "mesh m");
        let other_key = CacheKey::new(0x42, "mesh n");
        let artifact = Artifact::new("probe").with("n", Field::U64(1));
        let hex = key.hex();
        // biscale's own: two outputs and an interrupted write.
        cache.put(&cache.transfer_path(&key), &key, &artifact);
        cache.put(&cache.lpca_path(&key, "k4"), &key, &artifact);
        let temp = format!(".form-{hex}-sparse.bsf.tmp-77-0");
        std::fs::write(d.join(&temp), &artifact.encode()[..30]).unwrap();
        // A person's files, every one named to look like biscale's.
        let decoys: Vec<(String, Vec<u8>)> = vec![
            ("btf-wool.btf".into(), b"measured wool".to_vec()),
            (".thesis.tex.tmp-autosave".into(), b"\\chapter{}".to_vec()),
            (format!("transfer-{hex}.bsf.bak"), artifact.encode()),
            (format!("form-{hex}-notes.bsf"), b"my notes".to_vec()),
            (format!("sh-{hex}-n4.bsf"), Vec::new()),
            (format!("btf-{}-f16.btf", "A".repeat(32)), artifact.encode()),
            // A biscale artifact, but its header names another key than its file name.
            (format!("form-{hex}-copied.bsf"), artifact.encode_with(&other_key.fields())),
            // Temporaries by name whose bytes are not an artifact's, or whose target is not a
            // cache file's name.
            (format!(".transfer-{hex}.bsf.tmp-1-2"), b"draft".to_vec()),
            (".notes.txt.tmp-1-2".into(), Vec::new()),
            (format!(".form-{hex}-x.bsf.tmp-a-b"), Vec::new()),
        ];
        for (name, bytes) in &decoys {
            std::fs::write(d.join(name), bytes).unwrap();
        }
        let outside = tempfile::tempdir().unwrap();
        std::fs::write(outside.path().join("thesis.tex"), b"x").unwrap();
        std::os::unix::fs::symlink(
            outside.path().join("thesis.tex"),
            d.join(format!("transfer-{}.bsf", "0".repeat(32))),
        )
        .unwrap();

        for (name, _) in &decoys {
            let e = list(d).unwrap().into_iter().find(|e| &e.name == name).unwrap();
            assert_eq!(e.kind, "other", "{name}");
        }
        let mut removed: Vec<String> =
            clean(d, &CleanFilter::default(), false).unwrap().into_iter().map(|e| e.name).collect();
        removed.sort();
        assert_eq!(removed, [temp, format!("lpca-{hex}-k4.btf"), format!("transfer-{hex}.bsf")]);
        for (name, bytes) in &decoys {
            assert_eq!(&std::fs::read(d.join(name)).unwrap(), bytes, "{name} was changed");
        }
        assert!(outside.path().join("thesis.tex").exists());
        assert!(d.join(format!("transfer-{}.bsf", "0".repeat(32))).is_symlink());
    }
}
