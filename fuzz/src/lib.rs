//! The bodies of biscale's fuzz targets: one function per reader of untrusted input, each
//! taking the raw bytes of one input. For most inputs an error is the right answer; a panic,
//! an abort, a hang or an allocation past the fuzzer's memory limit is a bug. The cargo-fuzz
//! targets (`fuzz/fuzz_targets/`) are one call each, and the workspace's integration tests
//! (`tests/tests/integration/fuzz_seeds.rs`, which includes this file) run every body over
//! the committed seeds in `fuzz/seeds/<target>/`, so a plain `cargo test` exercises them.
//!
//! Beyond "no panic", each body checks what its reader promises: an error names the input's
//! file, a mesh that loads (OBJ or PLY) is valid, an env map that loads is finite and lat-long
//! or cube shaped, an artifact re-encodes to itself, a form that passes its compressor's checks
//! gathers without a panic, a passing [`FormCheck`] means what it says (checked against a plain
//! re-statement of each check below, in wide integers), a config that loads with its `--set`
//! overrides records them, and a shard manifest that loads keeps the promises its readers rely
//! on.
//!
//! This file is compiled in both places, so it is one module without submodules, and it uses
//! only crates both depend on.

use biscale::experiment::config::Experiment;
use biscale_compressors::registry;
use biscale_core::artifact::Artifact;
use biscale_core::basis::LightBasis;
use biscale_core::compress::{ArrayData, CompressedForm};
use biscale_core::geometry::Mesh;
use biscale_core::sampling::{EnvLayout, EnvMap, LightVector};
use biscale_core::scene::LpcaBtf;
use biscale_core::transfer::{TransferMatrix, TransferScene};
use biscale_kernels::{Count, Factor, FormCheck, FormData, KernelDesc, PassDesc, ScratchDesc};
use glam::{Vec2, Vec3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The body of a fuzz target: one input's bytes.
pub type Body = fn(&[u8]);

/// Every target: its name (the folder of its seeds, `fuzz/seeds/<name>/`, and of its cargo-fuzz
/// binary) and its body.
pub const TARGETS: &[(&str, Body)] = &[
    ("config", config),
    ("obj", obj),
    ("ply", ply),
    ("envmap", envmap),
    ("transfer", transfer),
    ("btf", btf),
    ("form", form),
    ("form_check", form_check),
    ("npz", npz),
    ("config_set", config_set),
    ("shard_manifest", shard_manifest),
    ("record_paths", record_paths),
];

/// The shape the `npz` target reads `L*` and forms for: 3 vertices, 2x2 local bins, a 6x2x2
/// light cubemap (the seeds are exports of a one-triangle scene at these settings).
fn npz_shape() -> biscale_core::basis::TransferShape {
    biscale_core::basis::TransferShape::new(
        3,
        biscale_core::basis::LocalBasis::bins(2).expect("a valid basis"),
        LightBasis::cubemap(2).expect("a valid basis"),
    )
}

/// Meshes up to this many triangles also get their transfer scene (frames and BVH) built, as
/// the pipeline does next; bigger ones would make single inputs slow without reaching new code.
const MAX_SCENE_TRIANGLES: usize = 4096;
/// Env maps up to this many pixels are also integrated into a light vector.
const MAX_LIGHT_PIXELS: usize = 1 << 12;
/// Forms of up to this many rows that pass their checks are also gathered on the CPU.
const MAX_GATHER_ROWS: usize = 1 << 16;
/// LPCA BTFs whose dense table has at most this many values are also decoded whole.
const MAX_DECODE_VALUES: usize = 1 << 20;

/// The repository root (configs and assets live there).
fn repo_root() -> PathBuf {
    // Both crates that compile this file live one folder below the root (`fuzz/`, `tests/`).
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("a crate below the repository root").to_path_buf()
}

/// Panics unless the error message names `file` (every reader's errors say where).
fn assert_names(error: &dyn std::fmt::Display, file: &str) {
    let message = error.to_string();
    assert!(message.contains(file), "the error does not name the file {file}: {message}");
}

/// A config file's text: `Experiment::parse` as if the file were in `configs/`, so the bundled
/// configs' relative mesh and env-map paths resolve and valid seeds parse.
pub fn config(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = repo_root().join("configs").join("fuzz-input.toml");
    if let Err(e) = Experiment::parse(&path, text.to_string()) {
        assert_names(&e, "fuzz-input.toml");
    }
}

/// A config file and `--set KEY=VALUE` overrides, as every command that reads a config takes
/// them: `Experiment::load_with`, which applies the overrides to the file's text
/// (`apply_overrides`), parses the result and blames an error on a set line on its `--set`.
///
/// The input: the file's bytes up to the first NUL byte, then each NUL-separated chunk one
/// `--set` argument (as on a command line: never a NUL inside, newlines allowed; bytes that
/// are not UTF-8 read lossily, where the command line's parser would refuse them). A seed
/// without a NUL is a config alone. The file is written as `configs/fuzz-input.toml` of a
/// temporary folder whose `assets` links to the repository's, so the bundled configs'
/// `../assets/...` paths resolve and valid seeds parse.
///
/// Beyond "no panic": an error names the file or the `--set` it comes from, and an experiment
/// that loads records its overrides and a config text (`source`, what a run's provenance
/// keeps as the config it ran) that parses again on its own.
pub fn config_set(data: &[u8]) {
    let input = load_config_set(data);
    match &input.loaded {
        Err(e) => {
            let message = e.to_string();
            assert!(
                message.contains("fuzz-input.toml") || message.starts_with("--set "),
                "the error names neither the file nor a --set: {message}"
            );
        }
        Ok(exp) => {
            assert_eq!(exp.overrides, input.sets, "the experiment does not record its overrides");
            if let Err(e) = Experiment::parse(&input.path(), exp.source.clone()) {
                panic!("the config text an experiment records does not parse again: {e}\n{}", exp.source);
            }
        }
    }
}

/// A [`config_set`] input loaded as the command line loads a config and its `--set`s.
pub struct ConfigSetInput {
    /// The temporary folder: `configs/fuzz-input.toml`, and `assets` linked to the repository's.
    pub dir: tempfile::TempDir,
    /// The `--set` arguments.
    pub sets: Vec<String>,
    pub loaded: Result<Experiment, biscale::experiment::config::ConfigError>,
}

impl ConfigSetInput {
    /// The config file.
    pub fn path(&self) -> PathBuf {
        self.dir.path().join("configs").join("fuzz-input.toml")
    }
}

/// Split a [`config_set`] input into the file and its `--set` arguments, write the file and
/// load it with them (`Experiment::load_with`).
pub fn load_config_set(data: &[u8]) -> ConfigSetInput {
    let mut chunks = data.split(|&b| b == 0);
    let text = chunks.next().unwrap_or_default();
    let sets: Vec<String> = chunks.map(|c| String::from_utf8_lossy(c).into_owned()).collect();
    let dir = tempfile::Builder::new().prefix("fuzz-config").tempdir().expect("a temporary folder");
    std::fs::create_dir(dir.path().join("configs")).expect("make the configs folder");
    std::os::unix::fs::symlink(repo_root().join("assets"), dir.path().join("assets")).expect("link the assets");
    let path = dir.path().join("configs").join("fuzz-input.toml");
    std::fs::write(&path, text).expect("write the temporary file");
    let loaded = Experiment::load_with(&path, &sets);
    ConfigSetInput { dir, sets, loaded }
}

/// A shard manifest (`manifest.json`) as `shard run`, `status`, `merge` and `sbatch` read it,
/// `Manifest::load`, twice: as it is, and resealed (parsed as a manifest and its checksum made
/// right, as a forger would), because a mutation almost never keeps the checksum valid and the
/// checks behind it would otherwise see few inputs. Every error names the file; a manifest that
/// loads keeps every promise its readers rely on (what goes into file names and generated
/// scripts is plain, each shard folder lies inside the plan's, the ranges tile the vertices),
/// and its summary and its first shards' states are read as `shard plan` and `status` do.
pub fn shard_manifest(data: &[u8]) {
    use biscale::shard::{self, Manifest};
    let dir = tempfile::Builder::new().prefix("fuzz-manifest").tempdir().expect("a temporary folder");
    let path = dir.path().join("manifest.json");
    let check = |bytes: &[u8]| {
        std::fs::write(&path, bytes).expect("write the temporary file");
        match Manifest::load(&path) {
            Err(e) => assert_names(&e, "manifest.json"),
            Ok((m, root)) => check_manifest(&m, &root, &path),
        }
    };
    check(data);
    if let Ok(mut m) = serde_json::from_slice::<Manifest>(data) {
        m.checksum = shard::manifest_checksum(&m);
        check(&serde_json::to_vec(&m).expect("a manifest serializes"));
    }
}

/// What a loaded manifest promises (`Manifest::load`'s checks, restated), then its summary
/// and the state of its first shards (none has run: missing).
fn check_manifest(m: &biscale::shard::Manifest, root: &Path, path: &Path) {
    use biscale::shard::{self, ShardState};
    assert_eq!(root, path.parent().unwrap(), "the plan's folder is not the manifest's");
    assert_eq!((m.format.as_str(), m.version), (shard::MANIFEST_FORMAT, shard::MANIFEST_VERSION));
    assert_eq!(m.checksum, shard::manifest_checksum(m), "a manifest with a wrong checksum loaded");
    assert!((1..=shard::MAX_SHARDS).contains(&m.shards.len()), "a plan of {} shards loaded", m.shards.len());
    let plain = |s: &str| {
        (1..=100).contains(&s.len())
            && !s.starts_with(['.', '-'])
            && s.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
    };
    assert!(plain(&m.experiment), "the experiment's name {:?} loaded", m.experiment);
    let mut at = 0;
    for (i, s) in m.shards.iter().enumerate() {
        assert_eq!((s.index, s.first_vertex), (i, at), "shard {i} is out of place");
        assert!(s.end_vertex >= s.first_vertex, "shard {i} ends before it starts");
        let inside = Path::new(&s.dir).components().all(|c| matches!(c, std::path::Component::Normal(_)));
        assert!(inside && s.dir.split('/').all(plain), "shard {i}'s folder {:?} loaded", s.dir);
        at = s.end_vertex;
    }
    assert_eq!(at, m.vertices, "the shards do not cover the vertices");
    let summary = shard::describe(m, path, None);
    assert!(summary.contains(&format!("in {} shards", m.shards.len())), "{summary}");
    for spec in m.shards.iter().take(8) {
        let state = shard::state(m, root, spec);
        assert!(matches!(state, ShardState::Missing), "shard {} of an empty folder: {state:?}", spec.index);
    }
}

/// An OBJ file: `Mesh::parse_obj` (what `Mesh::load_obj` runs on the file's bytes), then the
/// transfer scene of a small mesh that loads.
pub fn obj(data: &[u8]) {
    match Mesh::parse_obj(data, Path::new("fuzz-input.obj")) {
        Err(e) => assert_names(&e, "fuzz-input.obj"),
        Ok(load) => check_mesh(&load.mesh),
    }
}

/// A PLY file: `Mesh::parse_ply` (what `Mesh::load_ply` runs on the file's bytes), then the
/// transfer scene of a small mesh that loads.
pub fn ply(data: &[u8]) {
    match Mesh::parse_ply(data, Path::new("fuzz-input.ply")) {
        Err(e) => assert_names(&e, "fuzz-input.ply"),
        Ok(load) => check_mesh(&load.mesh),
    }
}

/// What validation promises of every mesh it lets through; then the transfer scene of a small
/// one.
fn check_mesh(m: &Mesh) {
    assert!(!m.triangles.is_empty(), "a mesh without triangles loaded");
    assert!(m.positions.iter().all(|p| p.is_finite()), "a non-finite position loaded");
    let n = m.positions.len();
    for t in &m.triangles {
        assert!(t.iter().all(|&i| (i as usize) < n), "triangle {t:?} out of range of {n} vertices");
        assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2], "triangle {t:?} repeats a vertex");
    }
    if let Some(uvs) = &m.uvs {
        assert_eq!(uvs.len(), n, "one uv per vertex");
        assert!(uvs.iter().all(|t| t.is_finite()), "a non-finite uv loaded");
    }
    if let Some(ids) = &m.materials {
        assert_eq!(ids.per_triangle.len(), m.triangles.len(), "one material per triangle");
    }
    if m.triangles.len() <= MAX_SCENE_TRIANGLES {
        let _ = TransferScene::new(m);
    }
}

/// An env map: `EnvMap::load` on a temporary file, `.exr` when the bytes start with the
/// OpenEXR magic number and `.hdr` otherwise; then the light vector of a small map.
pub fn envmap(data: &[u8]) {
    let ext = if data.starts_with(&[0x76, 0x2f, 0x31, 0x01]) { ".exr" } else { ".hdr" };
    let file = tempfile::Builder::new().prefix("fuzz-input").suffix(ext).tempfile().expect("a temporary file");
    std::fs::write(file.path(), data).expect("write the temporary file");
    match EnvMap::load(file.path()) {
        Err(e) => assert_names(&e, "fuzz-input"),
        Ok((env, _warnings)) => {
            let shape_ok = match env.layout {
                EnvLayout::LatLong => env.width == 2 * env.height,
                EnvLayout::Cube => env.height == 6 * env.width,
            };
            assert!(env.height > 0 && shape_ok, "a {}x{} {:?} env map loaded", env.width, env.height, env.layout);
            assert_eq!(env.pixels.len(), env.width * env.height);
            assert!(env.pixels.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "a pixel is < 0 or not finite");
            if env.pixels.len() <= MAX_LIGHT_PIXELS {
                let cubemap = LightBasis::cubemap(4).expect("a valid basis").cubemap_layout().expect("a cubemap");
                let light = LightVector::from_env(&env, cubemap, 0.5);
                assert!(light.power.iter().flatten().all(|c| c.is_finite()), "the light vector is not finite");
            }
        }
    }
}

/// The container of every stage output, read back by what `TransferMatrix::load` runs.
pub fn transfer(data: &[u8]) {
    let Some(a) = artifact(data) else { return };
    match TransferMatrix::from_artifact(a) {
        Err(e) => assert_names(&e, "fuzz-input.bsf"),
        Ok(t) => {
            assert_eq!(t.rows(), t.vertices() * t.local_dirs());
            assert!(t.csr().data().iter().all(|v| v.is_finite()), "a non-finite value loaded");
            let again = t.to_artifact().expect("a loaded matrix fits its file");
            assert_eq!(TransferMatrix::from_artifact(again).expect("a saved matrix loads"), t);
        }
    }
}

/// The BTF caches: the dense reader and the local-PCA reader on the same artifact, then a few
/// lookups of what loads.
pub fn btf(data: &[u8]) {
    let Some(a) = artifact(data) else { return };
    match biscale_shading::synth::btf_from_artifact(a.clone()) {
        Err(e) => assert_names(&e, "fuzz-input.bsf"),
        Ok(b) => {
            let mut out = vec![[0.0; 3]; b.light_count()];
            for (uv, view) in lookups() {
                b.eval_into(uv, view, &mut out);
                assert!(out.iter().flatten().all(|c| c.is_finite()), "a loaded BTF evaluates to a non-finite value");
            }
        }
    }
    match LpcaBtf::from_artifact(a) {
        Err(e) => assert_names(&e, "fuzz-input.bsf"),
        Ok(b) => {
            let mut out = vec![[0.0; 3]; b.local_basis().len()];
            for (uv, view) in lookups() {
                b.eval_into(uv, view, &mut out);
            }
            let views = b.view_grid().map_or(1, |g| g.len());
            let values = b.spatial().iter().map(|&s| s as usize).product::<usize>() * views * out.len() * 3;
            if values <= MAX_DECODE_VALUES {
                let _ = b.decode();
            }
        }
    }
}

/// Patch coordinates and local view directions to look a BTF up at: inside and outside the
/// patch, overhead, grazing and below the horizon.
fn lookups() -> [(Vec2, Vec3); 4] {
    [
        (Vec2::new(0.25, 0.75), Vec3::Z),
        (Vec2::new(-3.5, 17.25), Vec3::new(0.6, -0.3, 0.2).normalize()),
        (Vec2::new(0.999, 0.0), Vec3::new(1.0, 0.0, 0.0)),
        (Vec2::new(1e9, -1e9), Vec3::new(0.1, 0.2, -0.97).normalize()),
    ]
}

/// A compressed form, as `CompressedForm::load` reads it; then, for a built-in kind, its
/// compressor's structural checks, and the CPU gather of a form that passes them (what the
/// pipeline does with a cached form).
pub fn form(data: &[u8]) {
    let Some(a) = artifact(data) else { return };
    let form = match CompressedForm::from_artifact(a) {
        Err(e) => return assert_names(&e, "fuzz-input.bsf"),
        Ok(form) => form,
    };
    let again = CompressedForm::from_artifact(form.to_artifact()).expect("a saved form loads");
    assert_eq!(again.to_artifact().encode(), form.to_artifact().encode(), "a form re-encodes to itself");
    let Some(kind) = registry::KINDS.iter().find(|k| k.name == form.kind && k.role != registry::Role::External) else {
        return;
    };
    let compressor = (kind.build)(&serde_json::json!({})).expect("a built-in builds with its defaults");
    let Ok(kernels) = compressor.kernels(&form) else { return };
    if kernels.check_form(&form).is_err() || form.rows() > MAX_GATHER_ROWS {
        return;
    }
    let light =
        LightVector::new(form.light_basis(), vec![[1.0, 0.5, 0.25]; form.cols()]).expect("a light of the basis");
    let _ = compressor.gather(&form, &light);
}

/// An artifact's bytes as `Artifact::decode` reads them, twice: as they are, then resealed
/// (their total length and CRC-32 made right), because a mutation almost never keeps the
/// checksum valid and the readers behind it would otherwise see few inputs. The resealed
/// artifact, if it decodes, is returned; every error must name the file, and what decodes
/// must re-encode to bytes that decode to the same artifact.
fn artifact(data: &[u8]) -> Option<Artifact> {
    let path = Path::new("fuzz-input.bsf");
    let decode = |bytes: &[u8]| match Artifact::decode(bytes, path) {
        Err(e) => {
            assert_names(&e, "fuzz-input.bsf");
            None
        }
        Ok(a) => {
            // Bytes, not values: an f64 field may hold a NaN, which is not equal to itself.
            let bytes = a.encode();
            let back = Artifact::decode(&bytes, path).expect("an encoded artifact decodes");
            assert_eq!(back.encode(), bytes, "an artifact does not re-encode to itself");
            Some(a)
        }
    };
    let raw = decode(data);
    let sealed = decode(&reseal(data)?);
    // Resealing a valid artifact changes nothing (this checks `crc32` below as well).
    assert!(raw.is_none() || sealed.is_some(), "a valid artifact no longer decodes once resealed");
    sealed
}

/// `data` with the artifact header's total length (bytes 12..20) and the trailing CRC-32 set
/// to what they must be; `None` when it is too short to hold them.
fn reseal(data: &[u8]) -> Option<Vec<u8>> {
    if data.len() < 24 {
        return None;
    }
    let mut out = data.to_vec();
    out[12..20].copy_from_slice(&(data.len() as u64).to_le_bytes());
    let body = out.len() - 4;
    let crc = crc32(&out[..body]);
    out[body..].copy_from_slice(&crc.to_le_bytes());
    Some(out)
}

/// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320), the artifact container's checksum.
fn crc32(bytes: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut table = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 == 1 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
                k += 1;
            }
            table[i] = c;
            i += 1;
        }
        table
    };
    !bytes.iter().fold(!0u32, |c, &b| TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8))
}

/// The declarative form checks a plugin's kernel description gives, on arbitrary arrays. The
/// input is text, one item per line (unknown lines are skipped, so mutated inputs still say
/// something):
///
/// ```text
/// shape VERTICES LOCAL_DIRS COLS
/// meta KEY VALUE
/// array NAME u8|i8|u16|i16|u32|f32 VALUE...
/// len ARRAY COUNT          ptr ARRAY COUNT TOTAL     below ARRAY BOUND
/// finite ARRAY             finitehalf ARRAY          range COUNT MIN MAX
/// grouped IDS PTR GROUP_ROWS BASES
/// pass COUNT               scratch COUNT
/// ```
///
/// A COUNT is factors joined by `*`: `rows`, `cols`, `vertices`, `dirs`, an integer,
/// `meta:KEY`, `meta:KEY+N` or `len:ARRAY`. Every check runs on its own and all of them as one
/// `KernelDesc::check_form`; each that passes is re-checked against the plain meaning of the
/// check.
pub fn form_check(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let (form, desc) = probe_form(text);
    for check in &desc.checks {
        if check.run(&form).is_ok() {
            assert!(holds(check, &form), "{check:?} passed on a form where it does not hold");
        }
    }
    if desc.check_form(&form).is_ok() {
        assert!(desc.checks.iter().all(|c| holds(c, &form)));
        assert!(desc.meta_keys.iter().all(|k| form.meta.contains_key(k)));
        let counts = desc.passes.iter().map(|p| &p.threads).chain(desc.scratch.iter().map(|s| &s.words));
        assert!(counts.into_iter().all(|c| count(c, &form).is_some()), "a count of a passing form does not evaluate");
    }
}

/// A form of arbitrary shape, arrays and meta values, for [`form_check`].
#[derive(Debug, Default)]
struct Probe {
    vertices: usize,
    local_dirs: usize,
    cols: usize,
    arrays: Vec<(String, ArrayData)>,
    meta: BTreeMap<String, u64>,
}

impl FormData for Probe {
    fn kind(&self) -> &str {
        "probe"
    }
    fn find_array(&self, name: &str) -> Option<&ArrayData> {
        self.arrays.iter().find(|(n, _)| n == name).map(|(_, a)| a)
    }
    fn find_meta(&self, key: &str) -> Option<u64> {
        self.meta.get(key).copied()
    }
    fn rows(&self) -> usize {
        self.vertices * self.local_dirs
    }
    fn cols(&self) -> usize {
        self.cols
    }
    fn vertices(&self) -> usize {
        self.vertices
    }
    fn local_dirs(&self) -> usize {
        self.local_dirs
    }
}

/// The form and the kernel description (its checks, passes and scratch) a text describes.
fn probe_form(text: &str) -> (Probe, KernelDesc) {
    let mut form = Probe { vertices: 1, local_dirs: 1, cols: 1, ..Probe::default() };
    let mut desc = KernelDesc {
        kind: "probe".into(),
        wgsl: String::new(),
        passes: vec![],
        scratch: vec![],
        meta_keys: vec![],
        checks: vec![],
    };
    for line in text.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        let num = |i: usize| w.get(i).and_then(|s| s.parse::<u64>().ok());
        let name = |i: usize| w.get(i).map(|s| s.to_string());
        let cnt = |i: usize| w.get(i).and_then(|s| parse_count(s));
        let check = match w.first().copied() {
            Some("shape") => {
                // Small enough that rows (vertices x dirs) fit any usize.
                let (v, m, n) = (num(1).unwrap_or(1), num(2).unwrap_or(1), num(3).unwrap_or(1));
                form.vertices = v.min(1 << 24) as usize;
                form.local_dirs = m.min(1 << 12) as usize;
                form.cols = n.min(1 << 24) as usize;
                None
            }
            Some("meta") => {
                if let (Some(k), Some(v)) = (name(1), num(2)) {
                    form.meta.insert(k.clone(), v);
                    desc.meta_keys.push(k);
                }
                None
            }
            Some("array") => {
                if let (Some(n), Some(data)) = (name(1), w.get(2).and_then(|t| parse_array(t, &w[3..]))) {
                    form.arrays.push((n, data));
                }
                None
            }
            Some("len") => name(1).zip(cnt(2)).map(|(array, count)| FormCheck::Len { array, count }),
            Some("ptr") => {
                name(1).zip(cnt(2)).zip(cnt(3)).map(|((array, count), total)| FormCheck::Ptr { array, count, total })
            }
            Some("below") => name(1).zip(cnt(2)).map(|(array, bound)| FormCheck::Below { array, bound }),
            Some("finite") => name(1).map(|array| FormCheck::Finite { array }),
            Some("finitehalf") => name(1).map(|array| FormCheck::FiniteHalf { array }),
            Some("range") => {
                cnt(1).zip(num(2)).zip(num(3)).map(|((count, min), max)| FormCheck::Range { count, min, max })
            }
            Some("grouped") => match (name(1), name(2), cnt(3), name(4)) {
                (Some(ids), Some(ptr), Some(group_rows), Some(bases)) => {
                    Some(FormCheck::Grouped { ids, ptr, group_rows, bases })
                }
                _ => None,
            },
            Some("pass") => {
                if let Some(threads) = cnt(1) {
                    desc.passes.push(PassDesc { entry_point: "main".into(), threads });
                }
                None
            }
            Some("scratch") => {
                if let Some(words) = cnt(1) {
                    desc.scratch.push(ScratchDesc { name: format!("s{}", desc.scratch.len()), words });
                }
                None
            }
            _ => None,
        };
        desc.checks.extend(check);
    }
    (form, desc)
}

/// A COUNT of [`form_check`]'s input.
fn parse_count(s: &str) -> Option<Count> {
    let factor = |f: &str| -> Option<Factor> {
        Some(match f {
            "rows" => Factor::Rows,
            "cols" => Factor::Cols,
            "vertices" => Factor::Vertices,
            "dirs" => Factor::LocalDirs,
            _ => match f.split_once(':') {
                Some(("len", a)) => Factor::Len(a.into()),
                Some(("meta", k)) => match k.split_once('+') {
                    Some((k, add)) => Factor::MetaPlus(k.into(), add.parse().ok()?),
                    None => Factor::Meta(k.into()),
                },
                _ => Factor::Const(f.parse().ok()?),
            },
        })
    };
    s.split('*').map(factor).collect::<Option<Vec<_>>>().map(Count)
}

/// An ARRAY of [`form_check`]'s input: integers wrap into the element type (so every bit
/// pattern can be written), floats parse as f32 (`nan` and `inf` included).
fn parse_array(ty: &str, values: &[&str]) -> Option<ArrayData> {
    let ints = || values.iter().filter_map(|v| v.parse::<i64>().ok());
    Some(match ty {
        "u8" => ArrayData::U8(ints().map(|v| v as u8).collect()),
        "i8" => ArrayData::I8(ints().map(|v| v as i8).collect()),
        "u16" => ArrayData::U16(ints().map(|v| v as u16).collect()),
        "i16" => ArrayData::I16(ints().map(|v| v as i16).collect()),
        "u32" => ArrayData::U32(ints().map(|v| v as u32).collect()),
        "f32" => ArrayData::F32(values.iter().filter_map(|v| v.parse::<f32>().ok()).collect()),
        _ => return None,
    })
}

/// The value of `count` in wide arithmetic, or `None` where the check must fail: a missing
/// array or meta value, or a value past u64.
fn count(c: &Count, form: &Probe) -> Option<u128> {
    let mut n: u128 = 1;
    for f in &c.0 {
        let v: u128 = match f {
            Factor::Const(c) => *c as u128,
            Factor::Rows => form.rows() as u128,
            Factor::Cols => form.cols as u128,
            Factor::Vertices => form.vertices as u128,
            Factor::LocalDirs => form.local_dirs as u128,
            Factor::Meta(k) => *form.meta.get(k)? as u128,
            Factor::MetaPlus(k, a) => *form.meta.get(k)? as u128 + *a as u128,
            Factor::Len(a) => form.find_array(a)?.len() as u128,
        };
        n = n.checked_mul(v)?;
    }
    (n <= u64::MAX as u128).then_some(n)
}

/// The elements of an integer array, widened; `None` for a missing or f32 array.
fn ints(form: &Probe, name: &str) -> Option<Vec<i128>> {
    Some(match form.find_array(name)? {
        ArrayData::U8(v) => v.iter().map(|&x| x as i128).collect(),
        ArrayData::I8(v) => v.iter().map(|&x| x as i128).collect(),
        ArrayData::U16(v) => v.iter().map(|&x| x as i128).collect(),
        ArrayData::I16(v) => v.iter().map(|&x| x as i128).collect(),
        ArrayData::U32(v) => v.iter().map(|&x| x as i128).collect(),
        ArrayData::F32(_) => return None,
    })
}

/// Whether a half float's bits are a finite number: from the IEEE 754 binary16 layout (1 sign,
/// 5 exponent, 10 mantissa bits), whose all-ones exponent is infinity or NaN.
fn half_is_finite(bits: u16) -> bool {
    (bits >> 10) & 0x1f != 0x1f
}

/// Whether `check` holds of `form`, stated plainly (what the check's documentation says).
fn holds(check: &FormCheck, form: &Probe) -> bool {
    match check {
        FormCheck::Len { array, count: c } => {
            form.find_array(array).zip(count(c, form)).is_some_and(|(a, n)| a.len() as u128 == n)
        }
        FormCheck::Ptr { array, count: c, total } => match (ints(form, array), count(c, form), count(total, form)) {
            (Some(p), Some(n), Some(total)) => {
                p.len() as u128 == n + 1
                    && p.first() == Some(&0)
                    && p.last().is_some_and(|&l| l as u128 == total)
                    && p.windows(2).all(|w| w[0] <= w[1])
            }
            _ => false,
        },
        FormCheck::Below { array, bound } => match (ints(form, array), count(bound, form)) {
            (Some(v), Some(b)) => v.iter().all(|&x| x >= 0 && (x as u128) < b),
            _ => false,
        },
        FormCheck::Finite { array } => {
            matches!(form.find_array(array), Some(ArrayData::F32(v)) if v.iter().all(|x| x.is_finite()))
        }
        FormCheck::FiniteHalf { array } => {
            matches!(form.find_array(array), Some(ArrayData::U16(v)) if v.iter().all(|&b| half_is_finite(b)))
        }
        FormCheck::Range { count: c, min, max } => {
            count(c, form).is_some_and(|v| (*min as u128..=*max as u128).contains(&v))
        }
        FormCheck::Grouped { ids, ptr, group_rows, bases } => {
            let (Some(id), Some(p), Some(g), Some(base)) =
                (ints(form, ids), ints(form, ptr), count(group_rows, form), ints(form, bases))
            else {
                return false;
            };
            let rows = form.rows();
            if p.len() != rows + 1 || (g == 0 && rows > 0) {
                return false;
            }
            (0..rows).all(|r| {
                let group = r / g as usize;
                let (Some(&lo), Some(&hi)) = (base.get(group), base.get(group + 1)) else { return false };
                let (start, end) = (p[r], p[r + 1]);
                0 <= start
                    && start <= end
                    && end <= id.len() as i128
                    && id[start as usize..end as usize].iter().all(|&x| x >= 0 && lo + x < hi)
            })
        }
    }
}

/// A `.npz` (or `.npy`) for `biscale eval`: the zip and `.npy` readers (`biscale::interop::npy`), then
/// what `eval` makes of the arrays (`interop::read_lstar`, `interop::read_form`).
///
/// Two kinds of input. Raw bytes are the file itself. Bytes starting with `NPZ:` are a recipe
/// for a well-formed archive, so mutations reach the readers behind the zip's CRC-32 checks:
/// chunks split at `0xFF 0xFE`, the first the metadata's JSON text, each next one
/// `name=` followed by a `.npy` file's bytes (chunks that do not parse are dropped); the
/// archive is written with `npy::write_npz`.
pub fn npz(data: &[u8]) {
    use biscale::interop::npy;
    let dir = tempfile::Builder::new().prefix("fuzz-npz").tempdir().expect("a temporary folder");
    let path = dir.path().join("fuzz-input.npz");
    match data.strip_prefix(b"NPZ:") {
        None => {
            std::fs::write(&path, data).expect("write the temporary file");
            if let Err(e) = npy::parse_npy(data) {
                assert!(!e.is_empty(), "an empty .npy error");
            }
        }
        Some(recipe) => {
            let mut chunks = split_chunks(recipe, &[0xFF, 0xFE]);
            let meta = String::from_utf8_lossy(chunks.next().unwrap_or_default()).into_owned();
            let mut arrays = vec![(biscale::interop::META.to_string(), None)];
            for chunk in chunks {
                let Some(eq) = chunk.iter().position(|&b| b == b'=') else { continue };
                let Ok(name) = std::str::from_utf8(&chunk[..eq]) else { continue };
                let Ok(array) = npy::parse_npy(&chunk[eq + 1..]) else { continue };
                arrays.push((name.to_string(), Some(array)));
            }
            let members: Vec<(&str, npy::ArrayRef<'_>)> = arrays
                .iter()
                .map(|(n, a)| (n.as_str(), a.as_ref().map_or_else(|| npy::ArrayRef::string(&meta), |a| a.as_ref())))
                .collect();
            if npy::write_npz(&path, &members).is_err() {
                return; // e.g. a name the writer refuses
            }
        }
    }
    match npy::read_npz(&path) {
        Err(e) => assert_names(&e, "fuzz-input.npz"),
        Ok(arrays) => {
            for (name, a) in &arrays {
                let count: Option<usize> = a.shape.iter().try_fold(1usize, |c, &n| c.checked_mul(n));
                let string = matches!(a.data, npy::NpyData::Str(_));
                assert!(
                    string || count == Some(a.data.len()),
                    "array '{name}': shape {:?}, {} elements",
                    a.shape,
                    a.data.len()
                );
            }
            // What was read writes back, and reads back to the same bytes (bytes, not values:
            // a NaN is not equal to itself).
            let (a, b) = (dir.path().join("a.npz"), dir.path().join("b.npz"));
            let write = |p: &Path, arrays: &[(String, npy::NpyArray)]| {
                let refs: Vec<(&str, npy::ArrayRef<'_>)> =
                    arrays.iter().map(|(n, a)| (n.as_str(), a.as_ref())).collect();
                npy::write_npz(p, &refs)
            };
            if write(&a, &arrays).is_ok() {
                let again = npy::read_npz(&a).expect("a written archive reads back");
                write(&b, &again).expect("what was read back writes");
                assert_eq!(
                    std::fs::read(&a).unwrap(),
                    std::fs::read(&b).unwrap(),
                    "an archive does not re-write to itself"
                );
            }
        }
    }
    let want = npz_shape();
    match biscale::interop::read_lstar(&path, want, false) {
        Err(e) => assert_names(&e, "fuzz-input.npz"),
        Ok((lstar, _)) => {
            assert_eq!(lstar.values().len(), want.rows(), "an L* of the wrong shape was accepted");
            assert!(lstar.values().iter().flatten().all(|x| x.is_finite()), "a non-finite L* was accepted");
        }
    }
    match biscale::interop::read_form(&path, want) {
        Err(e) => assert_names(&e, "fuzz-input.npz"),
        Ok(read) => {
            let form = read.form;
            // Issue 36: the statistics are the form's own, never the metadata's claims.
            let counted = biscale::interop::form_flops(&form).unwrap_or(0);
            assert_eq!(form.flops_per_gather, counted, "a form's flops are not counted from its arrays");
            assert_eq!(form.build_seconds, 0.0, "a form read from a file claims a build time");
            let Some(kind) = registry::KINDS.iter().find(|k| k.name == form.kind && k.role != registry::Role::External)
            else {
                return;
            };
            let compressor = (kind.build)(&serde_json::json!({})).expect("a built-in builds with its defaults");
            let Ok(kernels) = compressor.kernels(&form) else { return };
            if kernels.check_form(&form).is_err() {
                return;
            }
            let light = LightVector::new(form.light_basis(), vec![[1.0, 0.5, 0.25]; form.cols()])
                .expect("a light of the basis");
            let _ = compressor.gather(&form, &light);
        }
    }
}

/// `data` split at every occurrence of `sep`.
fn split_chunks<'a>(data: &'a [u8], sep: &'a [u8]) -> impl Iterator<Item = &'a [u8]> {
    let mut rest = Some(data);
    std::iter::from_fn(move || {
        let r = rest?;
        match r.windows(sep.len()).position(|w| w == sep) {
            Some(i) => {
                rest = Some(&r[i + sep.len()..]);
                Some(&r[..i])
            }
            None => {
                rest = None;
                Some(r)
            }
        }
    })
}

/// `record_paths`: a run record (`metrics.json`) whose file fields are arbitrary, as a
/// tampered one's would be. Every path [`biscale::metrics::named_files`] finds is either
/// refused by [`biscale_core::io::inside_folder`] or resolves to a path inside the run folder
/// made of plain names (no `..`, no root): what `biscale report` reads and embeds can never be
/// a file outside its run.
pub fn record_paths(data: &[u8]) {
    use std::path::Component;
    let Ok(value) = serde_json::from_slice::<serde_json::Value>(data) else { return };
    let dir = tempfile::Builder::new().prefix("fuzz-record").tempdir().expect("a temporary folder");
    for (field, rel) in biscale::metrics::named_files(&value) {
        assert!(!field.is_empty(), "a named file without its field");
        match biscale_core::io::inside_folder(dir.path(), &rel) {
            Err(why) => assert!(!why.is_empty(), "{field}: a refusal without its reason"),
            Ok(path) => {
                let inner = path.strip_prefix(dir.path()).expect("a path inside the run folder");
                assert!(
                    inner.components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir)),
                    "{field} = {rel:?} resolved to {}",
                    path.display()
                );
                assert!(!rel.starts_with('/') && !rel.split('/').any(|p| p == ".."), "{field} = {rel:?} was accepted");
            }
        }
    }
}
