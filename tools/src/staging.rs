//! Output folders that cannot lie: a run writes everything into a fresh staging folder beside
//! its output folder and swaps it in only when the last file has landed, so the output folder
//! always holds one whole run, the earlier one or the new one, never a mix of both.
//!
//! * **Staging.** [`StagedDir::begin`] makes `<parent>/.<name>.staging-<pid>-<nanos>/` (the
//!   same file system as the output, so the swap is a rename). Nothing is written to the
//!   output folder while the run works.
//! * **Swap.** [`StagedDir::commit`] exchanges the staging folder and the output folder in one
//!   atomic step (`renameat2(RENAME_EXCHANGE)` on Linux), then deletes the earlier run, now
//!   at the staging path. Where the exchange is not supported it falls back to two renames
//!   (the earlier run first moves aside to `.<name>.old-...`): a kill between them leaves no
//!   output folder but both runs whole beside it.
//! * **Leftovers.** A run that fails removes its staging folder; a killed one leaves it behind. The next run into the same
//!   output removes every `.<name>.staging-*` and `.<name>.old-*` folder whose process is no
//!   longer alive, so neither stale files nor temporary folders survive.
//! * **Marker.** Each run folder holds a `.biscale-run` file (the config it ran). An existing
//!   output folder is replaced only if it carries that marker (or a `plan.txt` of an older
//!   biscale) or is empty: `--out` pointing at a folder of other files is an error, never a
//!   deletion.
//! * **Fault injection.** With `BISCALE_FAULT_KILL_AT=<point>` set, [`fault_point`] kills the
//!   process with SIGKILL when the run reaches that point (`transfer`, `compression`, `images`,
//!   `metrics`, `report`): how the tests show that a `kill -9` at any stage leaves a whole run.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The marker file every run folder carries.
pub const MARKER: &str = ".biscale-run";

/// A run's staging folder and the output folder it becomes.
#[derive(Debug)]
pub struct StagedDir {
    staging: PathBuf,
    target: PathBuf,
}

/// Why a staged output could not be prepared or swapped in. Each names the folders.
#[derive(Debug, thiserror::Error)]
pub enum StagingError {
    #[error("{}: exists and is not a biscale output folder (it has no {MARKER} or plan.txt and is not empty); choose another --out or remove it", path.display())]
    NotAnOutputFolder { path: PathBuf },
    #[error("{}: the output must be a folder, and this is a file", path.display())]
    NotAFolder { path: PathBuf },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StagingError + '_ {
    move |source| StagingError::Io { path: path.to_path_buf(), source }
}

impl StagedDir {
    /// Prepare a staged run whose output folder is `target`: check that `target` may be
    /// replaced, clear leftovers of killed runs, and make an empty staging folder holding the
    /// marker (`about` is written into it).
    pub fn begin(target: &Path, about: &str) -> Result<Self, StagingError> {
        if target.exists() {
            check_replaceable(target)?;
        }
        let parent = parent_of(target);
        std::fs::create_dir_all(&parent).map_err(io(&parent))?;
        remove_leftovers(target);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let staging = sibling(target, &format!("staging-{}-{nanos}", std::process::id()));
        std::fs::create_dir(&staging).map_err(io(&staging))?;
        let marker = staging.join(MARKER);
        std::fs::write(&marker, format!("{about}\n")).map_err(io(&marker))?;
        Ok(Self { staging, target: target.to_path_buf() })
    }

    /// The folder the run writes into.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The output folder the run becomes.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Swap the staged run in for the output folder and delete the earlier run.
    pub fn commit(mut self) -> Result<PathBuf, StagingError> {
        // Taken out, so that dropping `self` no longer removes the staging folder.
        let staging = std::mem::take(&mut self.staging);
        let target = self.target.clone();
        if !target.exists() {
            std::fs::rename(&staging, &target).map_err(io(&target))?;
            return Ok(target);
        }
        check_replaceable(&target)?;
        if exchange(&staging, &target).is_ok() {
            // The earlier run is now at the staging path.
            let _ = std::fs::remove_dir_all(&staging);
            return Ok(target);
        }
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let old = sibling(&target, &format!("old-{}-{nanos}", std::process::id()));
        std::fs::rename(&target, &old).map_err(io(&target))?;
        std::fs::rename(&staging, &target).map_err(io(&target))?;
        let _ = std::fs::remove_dir_all(&old);
        Ok(target)
    }
}

/// A run that fails (an error, a panic) removes its staging folder; a killed one leaves it
/// for the next run to remove.
impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.staging.as_os_str().is_empty() {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// `target`'s parent folder (`.` for a bare name).
fn parent_of(target: &Path) -> PathBuf {
    target.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf()
}

/// `<parent>/.<name>.<what>`.
fn sibling(target: &Path, what: &str) -> PathBuf {
    let mut name = OsString::from(".");
    name.push(target.file_name().unwrap_or(target.as_os_str()));
    name.push(".");
    name.push(what);
    parent_of(target).join(name)
}

/// An existing `target` may be replaced when it is a run folder or empty.
fn check_replaceable(target: &Path) -> Result<(), StagingError> {
    if !target.is_dir() {
        return Err(StagingError::NotAFolder { path: target.to_path_buf() });
    }
    if target.join(MARKER).is_file() || target.join("plan.txt").is_file() {
        return Ok(());
    }
    let mut entries = std::fs::read_dir(target).map_err(io(target))?;
    match entries.next() {
        None => Ok(()),
        Some(_) => Err(StagingError::NotAnOutputFolder { path: target.to_path_buf() }),
    }
}

/// Remove the staging and set-aside folders of runs into `target` whose process is gone.
fn remove_leftovers(target: &Path) {
    let Some(name) = target.file_name().map(|n| n.to_string_lossy().into_owned()) else { return };
    let Ok(entries) = std::fs::read_dir(parent_of(target)) else { return };
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = file.strip_prefix(&format!(".{name}.")) else { continue };
        let Some(id) = rest.strip_prefix("staging-").or_else(|| rest.strip_prefix("old-")) else { continue };
        let pid: Option<u32> = id.split('-').next().and_then(|p| p.parse().ok());
        let alive = pid.is_some_and(|p| p != std::process::id() && Path::new(&format!("/proc/{p}")).exists());
        if pid.is_some() && !alive {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Atomically exchange two paths (Linux `renameat2` with `RENAME_EXCHANGE`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let ca = CString::new(a.as_os_str().as_bytes()).map_err(std::io::Error::other)?;
    let cb = CString::new(b.as_os_str().as_bytes()).map_err(std::io::Error::other)?;
    // SAFETY: both are valid NUL-terminated paths that live across the call.
    let r = unsafe { libc::renameat2(libc::AT_FDCWD, ca.as_ptr(), libc::AT_FDCWD, cb.as_ptr(), libc::RENAME_EXCHANGE) };
    match r {
        0 => Ok(()),
        _ => Err(std::io::Error::last_os_error()),
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// The environment variable that names a fault point ([`fault_point`]).
pub const FAULT_VAR: &str = "BISCALE_FAULT_KILL_AT";

/// Kill this process with SIGKILL if `BISCALE_FAULT_KILL_AT` names `point` (see the module
/// docs): no destructor, no cleanup, exactly what `kill -9` leaves.
pub fn fault_point(point: &str) {
    if std::env::var(FAULT_VAR).is_ok_and(|v| v == point) {
        eprintln!("{FAULT_VAR}={point}: killing this process (SIGKILL)");
        // SAFETY: kill(2) on our own pid; it does not return.
        unsafe {
            libc::kill(libc::getpid(), libc::SIGKILL);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn a_run_replaces_the_earlier_one_whole() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        let first = StagedDir::begin(&out, "first").unwrap();
        std::fs::write(first.path().join("a.txt"), "1").unwrap();
        std::fs::write(first.path().join("only-first.txt"), "1").unwrap();
        // Nothing is at the output until the commit.
        assert!(!out.exists());
        first.commit().unwrap();
        assert_eq!(files(&out), [MARKER, "a.txt", "only-first.txt"]);

        let second = StagedDir::begin(&out, "second").unwrap();
        std::fs::write(second.path().join("a.txt"), "2").unwrap();
        // While the second works, the output is still the first, untouched.
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).unwrap(), "1");
        second.commit().unwrap();
        // The first's files do not survive, and nothing is left beside the output.
        assert_eq!(files(&out), [MARKER, "a.txt"]);
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).unwrap(), "2");
        assert_eq!(files(root.path()), ["run"]);
    }

    #[test]
    fn a_failed_run_leaves_the_earlier_one_and_nothing_beside_it() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        let first = StagedDir::begin(&out, "first").unwrap();
        std::fs::write(first.path().join("a.txt"), "1").unwrap();
        first.commit().unwrap();
        let second = StagedDir::begin(&out, "second").unwrap();
        std::fs::write(second.path().join("a.txt"), "2").unwrap();
        drop(second); // the run returned an error
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).unwrap(), "1");
        assert_eq!(files(root.path()), ["run"]);
    }

    #[test]
    fn leftovers_of_dead_runs_are_removed_and_live_ones_kept() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        // pid 0 is never a process's; our own pid is alive.
        std::fs::create_dir(root.path().join(".run.staging-0-1")).unwrap();
        std::fs::create_dir(root.path().join(".run.old-0-1")).unwrap();
        let other_live = format!(".run.staging-{}-5", std::os::unix::process::parent_id());
        std::fs::create_dir(root.path().join(&other_live)).unwrap();
        std::fs::create_dir(root.path().join(".other.staging-0-1")).unwrap();
        let s = StagedDir::begin(&out, "x").unwrap();
        let mut left = files(root.path());
        left.retain(|f| !s.path().ends_with(f));
        assert_eq!(left, [".other.staging-0-1", other_live.as_str()]);
    }

    #[test]
    fn a_folder_of_other_files_is_never_replaced() {
        let root = tempfile::tempdir().unwrap();
        let precious = root.path().join("docs");
        std::fs::create_dir(&precious).unwrap();
        std::fs::write(precious.join("thesis.tex"), "x").unwrap();
        let e = StagedDir::begin(&precious, "x").unwrap_err().to_string();
        assert!(e.contains("docs") && e.contains("not a biscale output folder"), "{e}");
        assert!(precious.join("thesis.tex").exists());
        // A file is refused too; an empty folder and an older run's folder (plan.txt) are fine.
        std::fs::write(root.path().join("f"), "x").unwrap();
        assert!(StagedDir::begin(&root.path().join("f"), "x").is_err());
        std::fs::create_dir(root.path().join("empty")).unwrap();
        StagedDir::begin(&root.path().join("empty"), "x").unwrap().commit().unwrap();
        std::fs::create_dir(root.path().join("old")).unwrap();
        std::fs::write(root.path().join("old/plan.txt"), "x").unwrap();
        StagedDir::begin(&root.path().join("old"), "x").unwrap().commit().unwrap();
        assert_eq!(files(&root.path().join("old")), [MARKER]);
    }
}
