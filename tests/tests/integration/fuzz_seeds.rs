//! The fuzzing suite's committed seeds under a plain `cargo test`: every file of
//! `fuzz/seeds/<target>/` goes through the body of its fuzz target (`fuzz/src/lib.rs`,
//! compiled here as a module, so the cargo-fuzz targets and this test run the same code). A
//! body panics where its reader breaks a promise: a panic of its own, an accepted input that
//! should have been refused, an error that does not name the file. The valid seeds must also
//! still be valid (a format change that leaves them stale would quietly blunt the fuzzer: run
//! `cargo run --manifest-path fuzz/Cargo.toml --example seeds` to write them again).

#[path = "../../../fuzz/src/lib.rs"]
mod bodies;

use biscale::experiment::config::Experiment;
use biscale_compressors::registry;
use biscale_core::artifact::Artifact;
use biscale_core::compress::CompressedForm;
use biscale_core::geometry::Mesh;
use biscale_core::sampling::EnvMap;
use biscale_core::scene::LpcaBtf;
use biscale_core::transfer::TransferMatrix;
use biscale_tests::workspace_root;
use std::path::{Path, PathBuf};

fn seeds(target: &str) -> Vec<PathBuf> {
    let dir = workspace_root().join("fuzz/seeds").join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
}

fn seed(target: &str, name: &str) -> (PathBuf, Vec<u8>) {
    let path = workspace_root().join("fuzz/seeds").join(target).join(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (path, bytes)
}

#[test]
fn every_seed_runs_through_its_fuzz_target() {
    let mut failed = vec![];
    for (target, body) in bodies::TARGETS {
        let files = seeds(target);
        assert!(files.len() >= 4, "fuzz/seeds/{target} holds {} seeds, expected a few", files.len());
        for file in files {
            let data = std::fs::read(&file).unwrap();
            if std::panic::catch_unwind(|| body(&data)).is_err() {
                failed.push(file.display().to_string());
            }
        }
    }
    assert!(failed.is_empty(), "seeds that fail their fuzz target (messages above): {failed:?}");
}

/// The valid seeds are read as valid, so the fuzzer starts from inputs that reach past the
/// readers' first checks.
#[test]
fn the_valid_seeds_still_load() {
    let configs = workspace_root().join("configs");
    for name in ["smoke.toml", "temple_lpca.toml", "compare.toml", "low_vs_all_bunny.toml"] {
        let (_, text) = seed("config", name);
        Experiment::parse(&configs.join(name), String::from_utf8(text).unwrap()).unwrap();
    }
    for name in ["tetrahedron.obj", "quads_objects_uvs.obj", "nonconvex_polygons.obj", "star_64.obj"] {
        let (path, bytes) = seed("obj", name);
        Mesh::parse_obj(&bytes, &path).unwrap();
    }
    for (name, triangles) in
        [("ascii_quads_uvs.ply", 5), ("ascii_nonconvex.ply", 3), ("tetrahedron_le.ply", 4), ("tetrahedron_be.ply", 4)]
    {
        let (path, bytes) = seed("ply", name);
        assert_eq!(Mesh::parse_ply(&bytes, &path).unwrap().mesh.triangle_count(), triangles, "{name}");
    }
    for name in ["latlong_8x4.exr", "latlong_8x4.hdr"] {
        let (env, _) = EnvMap::load(&seed("envmap", name).0).unwrap();
        assert_eq!((env.width, env.height), (8, 4), "{name}");
    }
    let artifact = |target: &str, name: &str| {
        let (path, bytes) = seed(target, name);
        Artifact::decode(&bytes, &path).unwrap()
    };
    let t = TransferMatrix::from_artifact(artifact("transfer", "t_3x4x24.bsf")).unwrap();
    assert_eq!((t.rows(), t.cols()), (12, 24));
    for kind in ["sparse", "bicluster", "cpca", "haar"] {
        let form = CompressedForm::from_artifact(artifact("form", &format!("{kind}.bsf"))).unwrap();
        let c = registry::build(kind, &serde_json::json!({})).unwrap();
        c.kernels(&form).unwrap().check_form(&form).unwrap();
    }
    for name in ["phong_f32.bsf", "phong_f16.bsf", "phong_u8.bsf", "patch_2x2_f32.bsf"] {
        biscale_shading::synth::btf_from_artifact(artifact("btf", name)).unwrap();
    }
    for name in ["lpca_texel_f32.bsf", "lpca_view_u8.bsf"] {
        LpcaBtf::from_artifact(artifact("btf", name)).unwrap();
    }
    // The `.npz` seeds are what `biscale eval` accepts for the 3-vertex matrix above.
    let shape = t.shape();
    for name in ["lstar.npz", "lstar_zip64.npz"] {
        let (lstar, _) = biscale::interop::read_lstar(&seed("npz", name).0, shape, false).unwrap();
        assert_eq!(lstar.values().len(), 12, "{name}");
    }
    for kind in ["sparse", "cpca"] {
        let form = biscale::interop::read_form(&seed("npz", &format!("form_{kind}.npz")).0, shape).unwrap().form;
        let c = registry::build(kind, &serde_json::json!({})).unwrap();
        c.kernels(&form).unwrap().check_form(&form).unwrap();
    }
    // The smoke config with the README's `--set`s (and a name): each applied.
    let input = bodies::load_config_set(&seed("config_set", "smoke_sets.bin").1);
    let exp = input.loaded.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((exp.name(), exp.overrides.len(), exp.file.runtime.light_moments), ("smoke-sets", 4, true));
    assert_eq!(exp.transfer_settings().local_basis(), biscale_core::basis::LocalBasis::bins(2).unwrap());
    let haar: Vec<&serde_json::Value> =
        exp.compressor_settings().iter().filter(|s| s.kind == "haar").map(|s| &s.params["terms"]).collect();
    assert_eq!(haar, [4, 8, 16]);
    // A plan of two shards.
    let (path, _) = seed("shard_manifest", "plan_2_shards.json");
    let (m, dir) = biscale::shard::Manifest::load(&path).unwrap();
    assert_eq!((m.shards.len(), m.vertices, dir.as_path()), (2, 1839, path.parent().unwrap()));
}

/// The hostile seeds the suite was asked for are refused, each for its own reason.
#[test]
fn the_hostile_seeds_are_refused_for_what_they_are() {
    let (path, _) = seed("envmap", "huge_data_window.exr");
    let e = EnvMap::load(&path).unwrap_err().to_string();
    assert!(e.contains("1048576 x 524288") && e.contains("over the limit"), "{e}");
    for (name, needle) in [
        ("lying_vertex_count.ply", "declares 1000000000000 `vertex` elements"),
        ("index_out_of_range.ply", "face 1 (line 14): vertex index -7 out of range"),
        ("truncated_le.ply", "face 3 (byte offset"),
    ] {
        let (path, bytes) = seed("ply", name);
        let e = Mesh::parse_ply(&bytes, &path).unwrap_err().to_string();
        assert!(e.contains(needle), "{name}: {e}");
    }
    // Found by the fuzzer: a tetrahedron a few subnormals across loads, and its transfer scene
    // is refused (its scale to the BVH's size overflows f32) instead of breaking the BVH build.
    let (path, bytes) = seed("ply", "subnormal_extent_be.ply");
    let mesh = Mesh::parse_ply(&bytes, &path).unwrap().mesh;
    let e = biscale_core::transfer::TransferScene::new(&mesh).err().expect("refused").to_string();
    assert!(e.contains("too small to trace"), "{e}");
    // Found by the fuzzer: tobj reads `l` records with its face parser, so their normal and
    // texture indices are checked as a face's are.
    let (path, bytes) = seed("obj", "line_record_index_counting_back.obj");
    let e = Mesh::parse_obj(&bytes, &path).unwrap_err().to_string();
    assert!(e.contains("normal index out of bounds") && e.contains("line 6"), "{e}");
    let (path, bytes) = seed("obj", "nan_inf_vertex.obj");
    let e = Mesh::parse_obj(&bytes, &path).unwrap_err().to_string();
    assert!(e.contains("OBJ vertex 4 (line 4)") && e.contains("non-finite"), "{e}");
    let (path, text) = seed("config", "nan_inf.toml");
    let e = Experiment::parse(&path, String::from_utf8(text).unwrap()).unwrap_err().to_string();
    assert!(e.contains(":6:") && e.contains("nan"), "{e}");
    for (name, needle) in [
        ("truncated.bsf", "truncated"),
        ("total_len_oversized.bsf", "truncated"),
        ("array_len_lying.bsf", "the arrays declare"),
        ("row_ptr_decreasing.bsf", "CSR"),
        ("vertices_huge.bsf", "2^32 rows"),
    ] {
        let (path, bytes) = seed("transfer", name);
        let e = Artifact::decode(&bytes, &path).and_then(TransferMatrix::from_artifact).unwrap_err().to_string();
        assert!(e.contains(needle) && e.contains(name), "{name}: {e}");
    }
    // `--set`s of every hostile class: refused, each naming its `--set` (or, for the file's own
    // error, the file's line), and a value with newlines stays one string value.
    for (name, needles) in [
        ("set_nan.bin", &["--set runtime.width: ", "NaN"][..]),
        ("set_inf_in_sweep.bin", &["--set compressors.3.terms: compressors[3].terms[1] = -inf"]),
        ("set_inf_exposure.bin", &["--set report.exposure: report.exposure = inf"]),
        ("file_nan_with_set.bin", &["fuzz-input.toml:6:11: scene.material.albedo[0] = NaN"]),
        ("set_non_ascii_key.bin", &["--set tränsfer.local_grid: a key is names of letters"]),
        ("set_non_ascii_kind.bin", &["--set compressors.0.kind: unknown compressor kind \"ハール\""]),
        ("set_huge_integer.bin", &["--set runtime.width: ", "18446744073709551616"]),
        ("set_i64_max.bin", &["--set transfer.cubemap_resolution: invalid value"]),
        ("set_huge_float.bin", &["--set compressors.2.clusters: "]),
        ("set_negative_seed.bin", &["--set seed: invalid value: integer `-1`"]),
        ("set_sweep_bomb.bin", &["sweeps 2048 settings", "over the limit of 1000"]),
        ("set_unknown_key.bin", &["--set runtime.no_such_key: unknown field `no_such_key`"]),
        ("set_unknown_table.bin", &["unknown field `nonexistent`"]),
        ("set_index_past_end.bin", &["--set compressors.9.terms: `compressors` has 4 entries"]),
        ("set_list_unindexed.bin", &["--set compressors.terms: `compressors` is a list of tables"]),
        ("set_sweep_of_tables.bin", &["--set compressors.1: `compressors` is a list of tables"]),
        ("set_list_replaced.bin", &["--set compressors: invalid type"]),
        ("set_into_value.bin", &["--set name.inner: `name` is a value, not a table"]),
        ("set_not_key_value.bin", &["--set novalue: expected KEY=VALUE"]),
        ("set_empty_key.bin", &["--set : a key is names"]),
        ("set_empty_segment.bin", &["--set a..b: a key is names"]),
        ("set_newline_table_injection.bin", &["string \"4\\n[evil]\\nx=1\", expected u32"]),
        ("set_newline_list_injection.bin", &["unknown compressor kind", "[[compressors]]\nkind=\"haar"]),
        ("set_newline_comment.bin", &["string \"1 # x\\nname = \\\"other\\\"\", expected usize"]),
    ] {
        let input = bodies::load_config_set(&seed("config_set", name).1);
        let e = input.loaded.err().unwrap_or_else(|| panic!("{name} loaded")).to_string();
        assert!(needles.iter().all(|n| e.contains(n)), "{name}: {e}");
    }
    // Manifests forged with their checksum made right are refused for the field itself.
    for (name, needle) in [
        ("checksum_wrong.json", "its checksum does not match"),
        ("experiment_newline.json", "the experiment's name \"x\\ntouch /tmp/pwned\\n#\" is not a plain name"),
        ("experiment_command.json", "is not a plain name"),
        ("shards_0.json", "0 shards: a plan has 1 to 100000"),
        ("shard_index_max.json", "shard 1's entry is inconsistent"),
        ("shard_dir_absolute.json", "shard 1's entry is inconsistent"),
        ("shard_dir_dotdot.json", "shard 0's entry is inconsistent"),
        ("shard_dir_parent.json", "shard 0's entry is inconsistent"),
        ("mem_unquoted.json", "not a shard manifest"),
        ("mem_quoted.json", "invalid type: string \"4G\", expected u64"),
    ] {
        let (path, _) = seed("shard_manifest", name);
        let e = biscale::shard::Manifest::load(&path).err().unwrap_or_else(|| panic!("{name} loaded")).to_string();
        assert!(e.contains(needle) && e.contains(name), "{name}: {e}");
    }
    let (path, bytes) = seed("form", "sparse_col_idx_out_of_range.bsf");
    let form = CompressedForm::from_artifact(Artifact::decode(&bytes, Path::new(&path)).unwrap()).unwrap();
    let e = registry::build("sparse", &serde_json::json!({})).unwrap().kernels(&form).unwrap().check_form(&form);
    assert!(e.unwrap_err().to_string().contains("'col_idx' element 0"));
}
