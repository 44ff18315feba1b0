//! Writes the binary seeds of the fuzzing suite into `fuzz/seeds/` (the text seeds, configs,
//! OBJ files and form-check scripts, are written by hand, and so are the PLY files, the two
//! binary tetrahedra and their truncation included): small valid EXR and HDR env maps, a
//! transfer matrix, a compressed form of each built-in compressor, dense and local-PCA BTFs,
//! `.npz` files and recipes for `biscale eval` (an `L*` and forms of that matrix), shard
//! manifests, and hostile variants of each (a header claiming a huge image, lying lengths under
//! a valid checksum, truncation, a manifest forged with its checksum made right).
//! Deterministic, so re-running it leaves the committed files unchanged; target names after
//! `--` write only those targets' seeds:
//!
//! ```sh
//! cargo run --manifest-path fuzz/Cargo.toml --example seeds
//! cargo run --manifest-path fuzz/Cargo.toml --example seeds -- shard_manifest
//! ```

use biscale_compressors::registry;
use biscale_core::artifact::{Artifact, Field};
use biscale_core::basis::{LightBasis, LocalBasis};
use biscale_core::compress::{ArrayData, CompressContext};
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::{Btf, HdrImage, LpcaBtf, LpcaQuantize, LpcaSettings, LpcaUnit};
use biscale_core::transfer::TransferMatrix;
use biscale_shading::synth::{btf_artifact, BtfEncoding};
use std::path::{Path, PathBuf};

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("seeds");
    let only: Vec<String> = std::env::args().skip(1).collect();
    let wanted = |target: &str| only.is_empty() || only.iter().any(|o| o == target);
    if wanted("envmap") {
        envmaps(&root.join("envmap"));
    }
    if ["transfer", "form", "npz"].iter().any(|t| wanted(t)) {
        let t = transfer(&root.join("transfer"));
        forms(&root.join("form"), &t);
        npzs(&root.join("npz"), &t);
    }
    if wanted("btf") {
        btfs(&root.join("btf"));
    }
    if wanted("shard_manifest") {
        manifests(&root.join("shard_manifest"));
    }
}

/// A small deterministic pseudo-random stream (seeds must not change from run to run).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::create_dir_all(dir).expect("create the seed folder");
    let path: PathBuf = dir.join(name);
    std::fs::write(&path, bytes).expect("write a seed");
    println!("{} ({} bytes)", path.display(), bytes.len());
}

/// `bytes` with its total length and CRC-32 made right again, so a lie inside passes the
/// container's checks and reaches the reader behind them.
fn reseal(mut bytes: Vec<u8>) -> Vec<u8> {
    let total = bytes.len() as u64;
    bytes[12..20].copy_from_slice(&total.to_le_bytes());
    let n = bytes.len() - 4;
    let crc = crc32fast::hash(&bytes[..n]);
    bytes[n..].copy_from_slice(&crc.to_le_bytes());
    bytes
}

/// Replace the first occurrence of `from` in `bytes` by `to` (same length).
fn patch(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    assert_eq!(from.len(), to.len());
    let at = bytes.windows(from.len()).position(|w| w == from).expect("the pattern to patch");
    let mut out = bytes.to_vec();
    out[at..at + to.len()].copy_from_slice(to);
    out
}

fn envmaps(dir: &Path) {
    let mut rng = Lcg(1);
    let mut img = HdrImage::new(8, 4);
    for p in &mut img.pixels {
        *p = [rng.next() * 4.0, rng.next(), rng.next() * 0.5];
    }
    let tmp = tempfile::tempdir().expect("a temporary folder");
    let exr = tmp.path().join("a.exr");
    img.write_exr(&exr).expect("write an EXR");
    let bytes = std::fs::read(&exr).expect("read it back");
    write(dir, "latlong_8x4.exr", &bytes);
    // The data window claims 1,048,576 x 524,288 pixels (xMax, yMax = 1048575, 524287).
    let window = |w: i32, h: i32| {
        let mut b = b"dataWindow\0box2i\0\x10\0\0\0".to_vec();
        for v in [0, 0, w - 1, h - 1] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b
    };
    write(dir, "huge_data_window.exr", &patch(&bytes, &window(8, 4), &window(1 << 20, 1 << 19)));
    write(dir, "truncated.exr", &bytes[..bytes.len() / 2]);
    let mut bad = img.clone();
    bad.pixels[5] = [f32::NAN, 1.0, f32::INFINITY];
    bad.pixels[6] = [-2.0, 0.0, 1.0];
    bad.write_exr(&exr).expect("write an EXR");
    write(dir, "nan_inf_negative.exr", &std::fs::read(&exr).expect("read it back"));
    HdrImage::new(4, 4).write_exr(&exr).expect("write an EXR");
    write(dir, "square.exr", &std::fs::read(&exr).expect("read it back"));

    // Radiance HDR: flat (uncompressed) scanlines of RGBE pixels.
    let hdr = |w: usize, h: usize, header_size: &str, pixel: [u8; 4]| {
        let mut b = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n{header_size}\n").into_bytes();
        for _ in 0..w * h {
            b.extend_from_slice(&pixel);
        }
        b
    };
    write(dir, "latlong_8x4.hdr", &hdr(8, 4, "-Y 4 +X 8", [128, 64, 32, 129]));
    // The brightest value RGBE can hold (mantissa 255, exponent 127).
    write(dir, "brightest.hdr", &hdr(8, 4, "-Y 4 +X 8", [255, 255, 255, 255]));
    // A header claiming 10^5 x 2 10^5 pixels over 8 bytes of data.
    write(dir, "huge_header.hdr", &hdr(2, 1, "-Y 100000 +X 200000", [1, 2, 3, 128]));
}

/// A transfer matrix of 3 vertices, 2x2 bins, cubemap 2 (12 x 24), values multiples of 1/4.
fn transfer(dir: &Path) -> TransferMatrix {
    let (local, light) = (LocalBasis::bins(2).expect("bins"), LightBasis::cubemap(2).expect("cubemap"));
    let mut tri = sprs::TriMat::new((3 * local.len(), light.len()));
    let mut rng = Lcg(2);
    for r in 0..3 * local.len() {
        for c in 0..light.len() {
            if rng.next() < 0.3 {
                tri.add_triplet(r, c, (1.0 + (rng.next() * 4.0).floor().min(3.0)) / 4.0);
            }
        }
    }
    let t = TransferMatrix::new(local, light, tri.to_csr()).expect("a valid matrix");
    let good = t.to_artifact().expect("it fits").encode();
    write(dir, "t_3x4x24.bsf", &good);
    write(dir, "truncated.bsf", &good[..good.len() - 9]);
    // The header's total length claims more than the file holds.
    let mut long = good.clone();
    long[12..20].copy_from_slice(&(1u64 << 40).to_le_bytes());
    write(dir, "total_len_oversized.bsf", &long);
    // Arrays that lie under a valid checksum.
    let a = t.to_artifact().expect("it fits");
    let with = |name: &str, data: ArrayData| {
        let mut b = a.clone();
        b.arrays.iter_mut().find(|x| x.name == name).expect("the array").data = data;
        b.encode()
    };
    let ptr = a.arrays.iter().find(|x| x.name == "row_ptr").expect("row_ptr").data.clone();
    if let ArrayData::U32(mut p) = ptr {
        p.swap(3, 4);
        p[4] += 1;
        write(dir, "row_ptr_decreasing.bsf", &with("row_ptr", ArrayData::U32(p)));
    }
    write(dir, "vertices_huge.bsf", &a.clone().with("vertices", Field::U64(u64::MAX / 3)).encode());
    // The first array's element count claims 2^61 elements.
    let mut lie = good.clone();
    let at = lie.windows(8).position(|w| w == b"row_ptr\x04").expect("row_ptr's header") + 8;
    lie[at..at + 8].copy_from_slice(&(1u64 << 61).to_le_bytes());
    write(dir, "array_len_lying.bsf", &reseal(lie));
    t
}

fn forms(dir: &Path, t: &TransferMatrix) {
    let ctx = CompressContext::default();
    let settings = [
        ("sparse", serde_json::json!({})),
        ("bicluster", serde_json::json!({ "block_vertices": 2 })),
        ("cpca", serde_json::json!({ "clusters": 2, "components": 1 })),
        ("haar", serde_json::json!({ "terms": 4 })),
    ];
    for (kind, params) in settings {
        let c = registry::build(kind, &params).expect("a built-in compressor");
        let mut form = c.compress(t, &ctx).expect("it compresses");
        form.build_seconds = 0.0; // a wall-clock time: the seeds must not change from run to run
        let a = form.to_artifact();
        write(dir, &format!("{kind}.bsf"), &a.encode());
        // Every integer array of the form off by a lot, one at a time, under a valid checksum.
        for (i, arr) in a.arrays.iter().enumerate() {
            let bumped = match &arr.data {
                ArrayData::U32(v) if !v.is_empty() => {
                    ArrayData::U32(v.iter().map(|x| x.wrapping_add(1 << 20)).collect())
                }
                ArrayData::U16(v) if !v.is_empty() => ArrayData::U16(v.iter().map(|x| x.wrapping_add(999)).collect()),
                _ => continue,
            };
            let mut b = a.clone();
            b.arrays[i].data = bumped;
            write(dir, &format!("{kind}_{}_out_of_range.bsf", arr.name), &b.encode());
        }
        for (key, _) in form.meta.iter().take(1) {
            let b = a.clone().with(&format!("meta.{key}"), Field::U64(u64::MAX));
            write(dir, &format!("{kind}_meta_{key}_max.bsf"), &b.encode());
        }
    }
}

fn btfs(dir: &Path) {
    let local = LocalBasis::bins(2).expect("bins");
    let phong = Btf::phong([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], 20.0, local, 2).expect("a phong BTF");
    for enc in [BtfEncoding::F32, BtfEncoding::F16, BtfEncoding::U8] {
        let a = btf_artifact(&phong, enc).expect("it encodes");
        write(dir, &format!("phong_{}.bsf", enc.name()), &a.encode());
    }
    // A 2x2-texel patch of varied values, for local PCA.
    let mut rng = Lcg(3);
    let grid = HemisphereGrid::new(2);
    let data = (0..4 * grid.len() * local.len()).map(|_| [rng.next(), rng.next() * 0.5, rng.next() * 0.25]).collect();
    let patch = Btf::new([2, 2], local, Some(grid), data, "patch").expect("a BTF");
    let dense = btf_artifact(&patch, BtfEncoding::F32).expect("it encodes");
    write(dir, "patch_2x2_f32.bsf", &dense.encode());
    write(dir, "patch_width_0.bsf", &dense.clone().with("width", Field::U64(0)).encode());
    write(dir, "patch_view_grid_huge.bsf", &dense.clone().with("view_grid", Field::U64(1 << 40)).encode());
    write(dir, "patch_wrong_length.bsf", &dense.clone().with("width", Field::U64(3)).encode());
    for (unit, q) in [(LpcaUnit::Texel, LpcaQuantize::F32), (LpcaUnit::View, LpcaQuantize::U8)] {
        let s = LpcaSettings { unit, quantize: q, ..LpcaSettings::new(2, 1) };
        let (lpca, _) = LpcaBtf::compress(&patch, &s, 7).expect("it compresses");
        let a = lpca.to_artifact();
        let unit_name = if unit == LpcaUnit::Texel { "texel" } else { "view" };
        write(dir, &format!("lpca_{unit_name}_{}.bsf", q.name()), &a.encode());
        if unit == LpcaUnit::Texel {
            let b = a.clone().with("clusters", Field::U64(u64::MAX));
            write(dir, "lpca_clusters_max.bsf", &b.encode());
            let b = a.clone().with("components", Field::U64(1 << 40)).with("clusters", Field::U64(1 << 40));
            write(dir, "lpca_components_huge.bsf", &b.encode());
            let mut b: Artifact = a.clone();
            if let Some(c) = b.arrays.iter_mut().find(|x| x.name == "cluster") {
                c.data = ArrayData::U16(vec![2; c.data.len()]);
            }
            write(dir, "lpca_cluster_id_out_of_range.bsf", &b.encode());
        }
    }
}

/// `.npz` files as `biscale export` writes them for the 3-vertex matrix of [`transfer`] (an
/// `L*` and two forms; the ZIP64 layout too), a bare `.npy`, and each as an `NPZ:` recipe
/// (the `npz` target's well-formed-archive input: see `npz` in `fuzz/src/lib.rs`).
fn npzs(dir: &Path, t: &TransferMatrix) {
    use biscale::interop::npy::{self, ArrayRef, Elements};
    use biscale::interop::META;
    let tmp = tempfile::tempdir().expect("a temporary folder");
    let shape = serde_json::json!({
        "vertices": 3, "local_basis": t.local_basis().tag(), "light_basis": t.light_basis().tag(),
    });
    let npy_bytes = |a: &ArrayRef<'_>| {
        let p = tmp.path().join("a.npy");
        npy::write_npy(&p, a).expect("write a .npy");
        std::fs::read(&p).expect("read it back")
    };
    let recipe = |meta: &str, arrays: &[(&str, ArrayRef<'_>)]| {
        let mut b = b"NPZ:".to_vec();
        b.extend_from_slice(meta.as_bytes());
        for (name, a) in arrays {
            b.extend_from_slice(&[0xFF, 0xFE]);
            b.extend_from_slice(format!("{name}=").as_bytes());
            b.extend_from_slice(&npy_bytes(a));
        }
        b
    };
    let archive = |arrays: &[(&str, ArrayRef<'_>)], meta: &str, zip64: bool| {
        let p = tmp.path().join("a.npz");
        let mut members = arrays.to_vec();
        members.push((META, ArrayRef::string(meta)));
        npy::write_npz_with(&p, &members, zip64).expect("write a .npz");
        std::fs::read(&p).expect("read it back")
    };

    let mut rng = Lcg(4);
    let lstar: Vec<f32> = (0..t.rows() * 3).map(|_| rng.next()).collect();
    let lstar_meta =
        serde_json::json!({ "format": "biscale-npz", "version": 1, "what": "lstar", "shape": shape }).to_string();
    let arrays = [("lstar", ArrayRef::new(&[t.rows(), 3], Elements::F32(&lstar)))];
    write(dir, "lstar.npz", &archive(&arrays, &lstar_meta, false));
    write(dir, "lstar_zip64.npz", &archive(&arrays, &lstar_meta, true));
    write(dir, "lstar.recipe", &recipe(&lstar_meta, &arrays));
    write(dir, "lstar.npy", &npy_bytes(&arrays[0].1));

    let ctx = CompressContext::default();
    for (kind, params) in
        [("sparse", serde_json::json!({})), ("cpca", serde_json::json!({ "clusters": 2, "components": 1 }))]
    {
        let c = registry::build(kind, &params).expect("a built-in compressor");
        let form = c.compress(t, &ctx).expect("it compresses");
        let arrays: Vec<(&str, ArrayRef<'_>)> =
            form.arrays.iter().map(|a| (a.name.as_str(), ArrayRef::flat(Elements::from(&a.data)))).collect();
        let meta = serde_json::json!({
            "format": "biscale-npz", "version": 1, "what": "form", "kind": kind, "shape": shape,
            "meta": form.meta, "lossless": form.lossless,
            "arrays": form.arrays.iter().map(|a| a.name.as_str()).collect::<Vec<_>>(),
        })
        .to_string();
        write(dir, &format!("form_{kind}.npz"), &archive(&arrays, &meta, false));
        write(dir, &format!("form_{kind}.recipe"), &recipe(&meta, &arrays));
    }
}

/// Shard manifests: a valid plan of two shards (of a config that need not exist: the reader
/// does not load it), the same with a wrong checksum, and hostile plans forged with their
/// checksum made right (as the CLI's test of them does): a newline and a command in the
/// experiment's name, no shards, a shard index and a vertex count of 2^64 - 1, absolute and
/// escaping shard folders, memory estimates of 2^64 - 1, quoted and unquoted `4G`.
fn manifests(dir: &Path) {
    use biscale::shard::{manifest_checksum, Manifest, ShardEstimate, ShardSpec, ShardedSetting};
    use biscale::shard::{MergeSetting, MANIFEST_FORMAT, MANIFEST_VERSION};
    let spec = |index: usize, first_vertex: usize, end_vertex: usize| ShardSpec {
        index,
        first_vertex,
        end_vertex,
        dir: format!("shards/{index:04}"),
        outputs: vec!["t.bsf".into(), "form-sparse.bsf".into()],
    };
    let plan = Manifest {
        format: MANIFEST_FORMAT.into(),
        version: MANIFEST_VERSION,
        created_by: "biscale 0.1.0".into(),
        experiment: "smoke".into(),
        config: "/home/user/biscale/configs/smoke.toml".into(),
        config_hash: "0123456789abcdef0123456789abcdef".into(),
        overrides: vec!["runtime.repeats=1".into()],
        checksum: String::new(),
        vertices: 1839,
        shape: "29424 x 384".into(),
        seed: 7,
        vertex_multiple: 1024,
        separable: vec![
            ShardedSetting { label: "sparse".into(), kind: "sparse".into(), vertex_multiple: 1 },
            ShardedSetting { label: "bicluster".into(), kind: "bicluster".into(), vertex_multiple: 1024 },
        ],
        in_merge: vec![MergeSetting {
            label: "cpca-k4-c2".into(),
            kind: "cpca".into(),
            why: "k-means clusters the units of every vertex together".into(),
        }],
        stacked: Some("the compressor cpca-k4-c2 runs in the merge on all of T".into()),
        estimate: ShardEstimate {
            nnz_per_vertex: 1234.5,
            shard_peak_bytes: 50 << 20,
            shard_base_bytes: 30 << 20,
            shard_bytes_per_nnz: 28.5,
            shard_output_bytes: 20 << 20,
            merge_peak_bytes: 200 << 20,
            transfer_cpu_seconds: 12.5,
        },
        shards: vec![spec(0, 0, 1024), spec(1, 1024, 1839)],
    };
    let sealed = |m: Manifest| {
        let m = Manifest { checksum: manifest_checksum(&m), ..m };
        serde_json::to_string_pretty(&m).expect("a manifest serializes")
    };
    let good = sealed(plan.clone());
    write(dir, "plan_2_shards.json", good.as_bytes());
    write(dir, "checksum_wrong.json", good.replace("\"smoke\"", "\"smoka\"").as_bytes());
    let forged = |name: &str, edit: &dyn Fn(&mut Manifest)| {
        let mut m = plan.clone();
        edit(&mut m);
        write(dir, name, sealed(m).as_bytes());
    };
    forged("experiment_newline.json", &|m| m.experiment = "x\ntouch /tmp/pwned\n#".into());
    forged("experiment_command.json", &|m| m.experiment = "$(touch /tmp/pwned)".into());
    forged("shards_0.json", &|m| {
        m.shards.clear();
        m.vertices = 0;
    });
    forged("shard_index_max.json", &|m| m.shards[1].index = usize::MAX);
    forged("vertices_max.json", &|m| {
        m.shards[1].end_vertex = usize::MAX;
        m.vertices = usize::MAX;
    });
    forged("shard_dir_absolute.json", &|m| m.shards[1].dir = "/tmp/elsewhere".into());
    forged("shard_dir_dotdot.json", &|m| m.shards[0].dir = "shards/../../x".into());
    forged("shard_dir_parent.json", &|m| m.shards[0].dir = "..".into());
    forged("mem_max.json", &|m| {
        m.estimate.shard_peak_bytes = u64::MAX;
        m.estimate.merge_peak_bytes = u64::MAX;
        m.estimate.shard_output_bytes = u64::MAX;
    });
    let mem = format!("\"shard_peak_bytes\": {}", 50u64 << 20);
    assert!(good.contains(&mem), "the estimate's field in the manifest's text");
    write(dir, "mem_unquoted.json", good.replace(&mem, "\"shard_peak_bytes\": 4G").as_bytes());
    write(dir, "mem_quoted.json", good.replace(&mem, "\"shard_peak_bytes\": \"4G\"").as_bytes());
}
