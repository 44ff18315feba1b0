//! Golden images: the smoke config's renders, error figures, an inset and the report's
//! storage plot, held against the blessed copies in `tests/golden/smoke/`. A change to the
//! shading, the tone map, the error colour map or its colour bar, the insets or the plots
//! fails here, where every numeric test would pass.
//!
//! Tolerance: a PNG is 8-bit sRGB of f32 results, and the last bits of a few pixels may
//! differ with the CPU or the maths library; so a pixel matches when no channel differs by
//! more than 2 levels, and an image matches when at most 0.1% of its pixels (6 of the
//! smoke's 96 x 72) do not. A tone-map change moves most covered pixels by many levels (the
//! test checks that half a stop of exposure fails it), a colour-bar change thousands.
//!
//! Re-bless after an intended change, then look at the images before committing them:
//!
//! ```sh
//! BISCALE_BLESS=1 cargo test -p biscale-tests --test integration golden
//! git diff --stat tests/golden
//! ```

use biscale::experiment::config::Experiment;
use biscale::run::run;
use biscale::store::RunOptions;
use biscale_tests::workspace_root;
use std::path::{Path, PathBuf};

/// The images held: renders, an error figure against the uncompressed render and against
/// the ground truth (colour map and bar), an inset, the reference, and a report plot whose
/// axes are storage and error (no timings).
const GOLDEN: [&str; 8] = [
    "images/uncompressed.png",
    "images/haar-t4.png",
    "images/bicluster.png",
    "images/haar-t4_error.png",
    "images/haar-t4_error_reference.png",
    "images/haar-t4_inset.png",
    "images/reference.png",
    "error_vs_storage.png",
];

fn golden_dir() -> PathBuf {
    workspace_root().join("tests/golden/smoke")
}

/// Run the smoke config (with `--set`-style overrides) into `out`.
fn smoke(out: &Path, overrides: &[String]) {
    let exp = Experiment::load_with(&workspace_root().join("configs/smoke.toml"), overrides).unwrap();
    let opts = RunOptions {
        out_dir: Some(out.to_path_buf()),
        cache_dir: Some(biscale_tests::cache_beside(out)),
        no_cache: false,
    };
    run(&exp, &opts).unwrap();
}

/// How many pixels of `got` differ from `want` by more than 2 levels in a channel (all of
/// them when the sizes differ).
fn differing(got: &image::RgbImage, want: &image::RgbImage) -> usize {
    if got.dimensions() != want.dimensions() {
        return (got.width() * got.height()).max(1) as usize;
    }
    got.pixels().zip(want.pixels()).filter(|(a, b)| a.0.iter().zip(b.0).any(|(x, y)| x.abs_diff(y) > 2)).count()
}

fn allowed(img: &image::RgbImage) -> usize {
    (img.width() * img.height()) as usize / 1000
}

#[test]
fn smoke_renders_and_figures_match_the_blessed_images() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("smoke");
    smoke(&out, &[]);
    if std::env::var("BISCALE_BLESS").is_ok_and(|v| v == "1") {
        for name in GOLDEN {
            let to = golden_dir().join(Path::new(name).file_name().unwrap());
            std::fs::create_dir_all(golden_dir()).unwrap();
            std::fs::copy(out.join(name), &to).unwrap();
            eprintln!("blessed {}", to.display());
        }
        return;
    }
    let mut failures = vec![];
    for name in GOLDEN {
        let got = image::open(out.join(name)).unwrap().to_rgb8();
        let path = golden_dir().join(Path::new(name).file_name().unwrap());
        let want = image::open(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (bless with BISCALE_BLESS=1, see this file's docs)", path.display()))
            .to_rgb8();
        let n = differing(&got, &want);
        if n > allowed(&want) {
            failures.push(format!("{name}: {n} pixels differ by more than 2 levels (at most {})", allowed(&want)));
        }
    }
    assert!(failures.is_empty(), "{}\n(an intended change: re-bless, see golden.rs)", failures.join("\n"));

    // The comparison can fail: half a stop more exposure (the tone map) breaks every render.
    let brighter = dir.path().join("brighter");
    smoke(&brighter, &["report.exposure=0.5".to_string()]);
    for name in ["images/uncompressed.png", "images/haar-t4.png", "images/reference.png"] {
        let got = image::open(brighter.join(name)).unwrap().to_rgb8();
        let want = image::open(golden_dir().join(Path::new(name).file_name().unwrap())).unwrap().to_rgb8();
        assert!(differing(&got, &want) > 10 * allowed(&want), "{name}: the tone map moved and the test did not see it");
    }
}
