//! The fixed inputs of biscale's benchmarks (`benches/stages.rs`), built once per process:
//! the bundled bunny (1,839 vertices) and the sunset sky, at a tiny transfer setting for the
//! transfer stage and at the reference setting (6x32x32 cubemap, 6x64x64 visibility, 8x8 bins:
//! 5.1 M non-zeros) for everything after it.
//!
//! ```sh
//! cargo bench -p biscale-benches --bench stages                    # every group
//! cargo bench -p biscale-benches --bench stages -- gather          # one group (divan's filter)
//! DIVAN_THREADS=1 cargo bench -p biscale-benches --bench stages    # divan runs each benchmark on 1 thread
//! RAYON_NUM_THREADS=1 cargo bench -p biscale-benches --bench stages  # the stages themselves on 1 thread
//! ```
//!
//! `benches/synth.rs` (`--bench synth`) measures the synthesized BTFs on inputs of its own;
//! `cargo bench -p biscale-benches` with no `--bench` runs both.

use biscale_compressors::registry;
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::geometry::{Mesh, VertexFrame};
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::transfer::{self, TransferMatrix, TransferScene, TransferSettings};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The repository root (assets live there).
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("benches/ sits below the root").to_path_buf()
}

/// The bundled bunny.
pub fn bunny() -> &'static Mesh {
    static MESH: OnceLock<Mesh> = OnceLock::new();
    MESH.get_or_init(|| Mesh::load_obj(&root().join("assets/meshes/bunny.obj")).expect("the bundled bunny").mesh)
}

/// The bunny's vertex frames (what `T`'s rows are expressed in).
pub fn frames() -> &'static [VertexFrame] {
    static FRAMES: OnceLock<Vec<VertexFrame>> = OnceLock::new();
    FRAMES.get_or_init(|| TransferScene::new(bunny()).expect("a scene").frames().to_vec())
}

/// The tiny transfer setting of `configs/smoke.toml`: 6x8x8 cubemap, 6x16x16 visibility, 4x4 bins.
pub fn tiny_settings() -> TransferSettings {
    TransferSettings::new(8, 16, 4).expect("valid settings")
}

/// `T` of the bunny at the reference setting (traced once per process, a few seconds).
pub fn reference_t() -> &'static TransferMatrix {
    static T: OnceLock<TransferMatrix> = OnceLock::new();
    T.get_or_init(|| transfer::build(bunny(), &TransferSettings::default(), None).expect("T").matrix)
}

/// The sunset sky as `T`'s light vector.
pub fn light() -> &'static LightVector {
    static L: OnceLock<LightVector> = OnceLock::new();
    L.get_or_init(|| {
        let (env, _) = EnvMap::load(&root().join("assets/envmaps/blender_sunset.exr")).expect("the bundled sky");
        LightVector::from_env(&env, TransferSettings::default().cubemap(), 0.0)
    })
}

/// The compressor settings every group times: the bundled bunny config's representative
/// settings (`configs/bunny.toml`).
pub const SETTINGS: [&str; 4] = ["sparse", "bicluster", "cpca", "haar"];

/// The compressor of `kind` at its benchmark parameters.
pub fn compressor(kind: &str) -> Box<dyn Compressor> {
    let params = match kind {
        "sparse" => serde_json::json!({}),
        "bicluster" => serde_json::json!({ "block_vertices": 1024 }),
        "cpca" => serde_json::json!({ "clusters": 32, "components": 8 }),
        "haar" => serde_json::json!({ "terms": 12 }),
        other => panic!("no benchmark parameters for {other}"),
    };
    registry::build(kind, &params).expect("a built-in compressor")
}

/// The form of `kind` on [`reference_t`], built once per process.
pub fn form(kind: &str) -> &'static CompressedForm {
    static FORMS: OnceLock<Vec<CompressedForm>> = OnceLock::new();
    let forms = FORMS.get_or_init(|| {
        SETTINGS
            .iter()
            .map(|k| compressor(k).compress(reference_t(), &CompressContext::default()).expect("a form"))
            .collect()
    });
    &forms[SETTINGS.iter().position(|k| *k == kind).expect("a benchmarked kind")]
}
