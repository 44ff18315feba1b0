//! Build facts for run provenance (`metrics.json`'s `run` record): the git commit of the
//! checkout biscale is built from and whether its tracked files differed from that commit when
//! it was built, and the compiler's version. Outside a git checkout (a packaged crate) both git values are empty.

use std::path::Path;
use std::process::Command;

fn output(cmd: &mut Command) -> Option<String> {
    let out = cmd.output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let git = |args: &[&str]| output(Command::new("git").arg("-C").arg(&root).args(args));
    let commit = git(&["rev-parse", "HEAD"]).unwrap_or_default();
    let dirty = match commit.is_empty() {
        true => String::new(),
        false => git(&["status", "--porcelain", "--untracked-files=no"])
            .map_or(String::new(), |s| (!s.is_empty()).to_string()),
    };
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let rustc = output(Command::new(rustc).arg("--version")).unwrap_or_default();
    println!("cargo:rustc-env=BISCALE_GIT_COMMIT={commit}");
    println!("cargo:rustc-env=BISCALE_GIT_DIRTY={dirty}");
    println!("cargo:rustc-env=BISCALE_RUSTC={rustc}");
    // Rerun when the checked-out commit or the index moves (a commit, a checkout, `git add`);
    // the dirty flag is the tree's state at the last such build.
    if let Some(git_dir) = git(&["rev-parse", "--absolute-git-dir"]) {
        for f in ["HEAD", "index"] {
            println!("cargo:rerun-if-changed={git_dir}/{f}");
        }
        if let Some(head_ref) = git(&["symbolic-ref", "-q", "HEAD"]) {
            println!("cargo:rerun-if-changed={git_dir}/{head_ref}");
        }
    }
    // And when the sources biscale is built from change, so that "dirty" is not stale after
    // an edit that was never added.
    for crate_dir in ["core", "compressors", "shading", "gpu", "tools"] {
        let src = root.join(crate_dir).join("src");
        if src.is_dir() {
            println!("cargo:rerun-if-changed={}", src.display());
        }
    }
    println!("cargo:rerun-if-changed=build.rs");
}
