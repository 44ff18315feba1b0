//! The per-pixel reference image is cached by content (`reference-<key>.bsf`): a second run of
//! the same config loads it instead of tracing it, writes the same images and numbers, and says
//! so; a run whose camera differs traces its own.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

/// `biscale ARGS` in the checkout: success, stdout, stderr.
fn biscale(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale"))
        .args(args)
        .current_dir(root())
        .env_remove("BISCALE_FAULT_KILL_AT")
        .output()
        .expect("run biscale");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// `biscale run configs/smoke.toml` with the reference on and `sets`, into `out` with `cache`:
/// its log.
fn run(out: &Path, cache: &Path, sets: &[&str]) -> String {
    let mut args = vec!["run", "configs/smoke.toml", "--out", out.to_str().unwrap(), "--cache-dir"];
    args.extend([cache.to_str().unwrap(), "--set", "report.reference=true"]);
    for s in sets {
        args.extend(["--set", s]);
    }
    let (ok, _, err) = biscale(&args);
    assert!(ok, "{args:?}: {err}");
    err
}

fn metrics(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap()
}

/// The reference files of the cache folder.
fn references(cache: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(cache)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("reference-"))
        .collect();
    v.sort();
    v
}

#[test]
fn a_second_run_loads_the_reference_and_a_moved_camera_traces_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let (first, second) = (dir.path().join("first"), dir.path().join("second"));
    // `T` first, so that both runs load it and differ in the reference alone (a traced `T`
    // records the rays it traced, a loaded one none).
    let mtx = dir.path().join("mtx");
    let (ok, _, err) = biscale(&[
        "export-matrix",
        "configs/smoke.toml",
        "--out",
        mtx.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");

    let log = run(&first, &cache, &[]);
    assert!(log.contains("reference: traced") && !log.contains("reference: loaded"), "{log}");
    let stored = references(&cache);
    assert_eq!(stored.len(), 1, "{stored:?}");
    assert_eq!(metrics(&first)["reference"]["cached"], serde_json::Value::Bool(false));

    // The plan computes the key the run wrote under.
    let (ok, plan, err) = biscale(&["plan", "configs/smoke.toml", "--cache-dir", cache.to_str().unwrap()]);
    assert!(ok, "{err}");
    let line = plan.lines().find(|l| l.contains("reference  ground truth")).unwrap_or_else(|| panic!("{plan}"));
    assert!(line.trim_start().starts_with("load") && line.ends_with(&stored[0]), "{line}");

    let log = run(&second, &cache, &[]);
    let loaded = format!("reference: loaded from cache {}", cache.join(&stored[0]).display());
    assert!(log.contains(&loaded) && !log.contains("reference: traced"), "{log}");
    assert_eq!(references(&cache), stored, "nothing new written");
    let m = metrics(&second);
    assert_eq!(m["reference"]["cached"], serde_json::Value::Bool(true));
    // The trace time travels with the image.
    assert_eq!(m["reference"]["seconds"], metrics(&first)["reference"]["seconds"]);
    let report = std::fs::read_to_string(second.join("report.md")).unwrap();
    assert!(report.contains(" s (cached) (each pixel's own visibility"), "the report says it was cached");
    for image in ["reference.exr", "reference.png", "reference_mask.png"] {
        let (a, b) =
            (std::fs::read(first.join("images").join(image)), std::fs::read(second.join("images").join(image)));
        assert!(a.unwrap() == b.unwrap(), "{image} differs between the traced and the cached run");
    }
    let same = Command::new("python3")
        .arg(root().join("scripts/same_results.py"))
        .args([&first, &second])
        .output()
        .expect("python3 runs scripts/same_results.py");
    assert!(
        same.status.success(),
        "{}{}",
        String::from_utf8_lossy(&same.stdout),
        String::from_utf8_lossy(&same.stderr)
    );

    // Another camera is another reference: traced and stored beside the first.
    let moved = dir.path().join("moved");
    let log = run(&moved, &cache, &["runtime.camera.azimuth_degrees=75", "compressors=[{kind=\"sparse\"}]"]);
    assert!(log.contains("reference: traced") && !log.contains("reference: loaded"), "{log}");
    assert_eq!(metrics(&moved)["reference"]["cached"], serde_json::Value::Bool(false));
    assert_eq!(references(&cache).len(), 2);

    // `cache list` names the kind and what each file was traced from.
    let (ok, listed, err) = biscale(&["cache", "list", "--cache-dir", cache.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert_eq!(listed.lines().filter(|l| l.starts_with("reference ")).count(), 2, "{listed}");
    assert!(listed.contains("GroundTruth reference 48x36"), "the inputs are listed: {listed}");
}

/// A flat GGX material (a synthesized patch of zero amplitude) is its BRDF: the reference
/// evaluates it at each texel's direction and says so in the record and the report; its
/// parameters are part of the reference's key.
#[test]
fn a_flat_ggx_material_is_shaded_by_its_brdf_in_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let ggx = |alpha: f32| {
        format!(
            "scene.material={{kind=\"synthesized\", name=\"gold\", pattern=\"bumps\", amplitude=0.0, view_grid=4, \
             brdf={{kind=\"rough_conductor\", alpha={alpha}, eta=[0.2, 0.9, 1.1], k=[3.9, 2.4, 2.2]}}}}"
        )
    };
    let only_raw = "compressors=[{kind=\"sparse\"}]";
    let first = dir.path().join("first");
    run(&first, &cache, &[&ggx(0.2), only_raw]);
    let m = metrics(&first);
    assert_eq!(m["reference"]["shading"], "gold: rough-conductor BRDF, exact");
    // The vertex render against it: glossy under the apartment's lamps, far from exact but
    // the same picture (a wrong frame or a lost cosine gives errors near or above 1).
    let err = m["reference"]["uncompressed_vs_reference"]["rel_l2"].as_f64().unwrap();
    assert!(err > 0.0 && err < 0.5, "uncompressed vs reference: {err}");
    let report = std::fs::read_to_string(first.join("report.md")).unwrap();
    assert!(report.contains("gold: rough-conductor BRDF, exact"), "the report names the reference's shading");
    assert_eq!(references(&cache).len(), 1);
    let rougher = dir.path().join("rougher");
    let log = run(&rougher, &cache, &[&ggx(0.25), only_raw]);
    assert!(log.contains("reference: traced"), "another alpha is another reference: {log}");
    assert_eq!(references(&cache).len(), 2);
    // The bundled smoke material is Lambertian: its BRDF too.
    let lambert = dir.path().join("lambert");
    run(&lambert, &cache, &[only_raw]);
    assert_eq!(metrics(&lambert)["reference"]["shading"], "lambertian: lambertian BRDF, exact");
}
