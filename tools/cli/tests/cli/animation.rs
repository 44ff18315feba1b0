//! `[runtime.animation]`: the light turned and the camera orbited, checked from the outside.
//! Frame 0 of either path is the run's own light and camera, so each setting's frame-0 error
//! must be the error the run recorded for its still image; a lossless form stays lossless on
//! every frame; the animated PNGs hold every frame at the run's size.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap().to_path_buf()
}

fn biscale(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_biscale")).args(args).current_dir(root()).output().expect("run biscale");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// The PNG chunks of `bytes`: (type, data), checked against the file's length.
fn chunks(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "a PNG signature");
    let (mut out, mut at) = (vec![], 8);
    while at < bytes.len() {
        let len = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let kind = String::from_utf8_lossy(&bytes[at + 4..at + 8]).into_owned();
        out.push((kind, bytes[at + 8..at + 8 + len].to_vec()));
        at += 12 + len;
    }
    assert_eq!(at, bytes.len());
    out
}

fn be32(b: &[u8]) -> u32 {
    u32::from_be_bytes(b[..4].try_into().unwrap())
}

#[test]
fn animated_frames_start_at_the_runs_own_image_and_stream_into_animated_pngs() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("run"), dir.path().join("cache"));
    let (ok, _, err) = biscale(&[
        "run",
        "configs/smoke.toml",
        "--set",
        "methods=[{kind=\"sh\", order=3}]",
        "--set",
        "runtime.animation.light_frames=6",
        "--set",
        "runtime.animation.camera_frames=3",
        "--set",
        "runtime.animation.settings=[\"bicluster\", \"haar-t4\", \"sh-n3\"]",
        // The stiff case and the per-pixel moments: every turned frame makes the run's light
        // (sun boost included) and its moment gathers the way the run does.
        "--set",
        "lighting.sun_boost=20",
        "--set",
        "runtime.light_moments=true",
        "--set",
        "runtime.moments_resolve=\"pixel\"",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let m: Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let still = |name: &str| -> f64 {
        let all = m["compressors"].as_array().unwrap().iter().chain(m["methods"].as_array().unwrap());
        all.clone().find(|c| c["name"] == name).unwrap()["image"]["vs_uncompressed"]["rel_l2"].as_f64().unwrap()
    };
    let animations = m["animations"].as_array().unwrap();
    assert_eq!(animations.len(), 2);
    for (a, (path, frames)) in animations.iter().zip([("light", 6usize), ("camera", 3)]) {
        assert_eq!(a["path"], path);
        assert_eq!(a["frames"].as_u64(), Some(frames as u64));
        assert!(out.join(a["plot"].as_str().unwrap()).is_file());
        assert!(out.join(a["plot"].as_str().unwrap()).with_extension("svg").is_file());
        let names: Vec<&str> = a["series"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["uncompressed", "bicluster", "haar-t4", "sh-n3"]);
        for s in a["series"].as_array().unwrap() {
            let name = s["name"].as_str().unwrap();
            let e: Vec<f64> = s["rel_l2"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            let g: Vec<f64> = s["gather_ms"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            assert_eq!(e.len(), frames, "{path} {name}");
            match name {
                "uncompressed" => assert!(e.iter().all(|&x| x == 0.0)),
                // Frame 0 is the run's light and camera: the still image's error, to rounding.
                other => assert!((e[0] - still(other)).abs() <= 1e-6 * still(other).max(1e-3), "{path} {other}: {e:?}"),
            }
            match name {
                "bicluster" => assert!(e.iter().all(|&x| x < 1e-5), "lossless on every frame: {e:?}"),
                "haar-t4" | "sh-n3" => assert!(e.iter().all(|&x| x > 1e-3), "{name} is lossy on every frame: {e:?}"),
                _ => {}
            }
            // The camera path re-shades the run's L*; the light path gathers every frame.
            assert_eq!(g.iter().all(|&x| x == 0.0), path == "camera", "{path} {name}: {g:?}");
            // The animated PNG: every frame at the run's 96x72.
            let png = std::fs::read(out.join(s["apng"].as_str().unwrap())).unwrap();
            let c = chunks(&png);
            let ihdr = &c.iter().find(|(k, _)| k == "IHDR").unwrap().1;
            assert_eq!((be32(&ihdr[0..]), be32(&ihdr[4..])), (96, 72));
            let actl = &c.iter().find(|(k, _)| k == "acTL").expect("an animation control chunk").1;
            assert_eq!(be32(actl) as usize, frames, "{path} {name}");
            assert_eq!(c.iter().filter(|(k, _)| k == "fcTL").count(), frames);
        }
    }
    // The light turns: the lossy settings' errors change from frame to frame.
    let haar = &animations[0]["series"][2]["rel_l2"];
    assert_ne!(haar[0], haar[3], "{haar}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Animation") && report.contains("animation/light/sh-n3.png"), "{report}");
    let plan = std::fs::read_to_string(out.join("plan.txt")).unwrap();
    assert!(plan.contains("run   animate    6 frames of the light"), "{plan}");

    // A setting the run does not have is refused before any work, naming the ones it has.
    let bad = dir.path().join("bad");
    let (ok, _, err) = biscale(&[
        "run",
        "configs/smoke.toml",
        "--set",
        "runtime.animation.light_frames=2",
        "--set",
        "runtime.animation.settings=[\"bicluster-b7\"]",
        "--out",
        bad.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("runtime.animation.settings names `bicluster-b7`") && err.contains("haar-t8"), "{err}");
    assert!(!bad.exists(), "nothing is left behind");
}
