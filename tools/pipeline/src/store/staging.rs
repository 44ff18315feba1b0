//! Output folders that cannot lie, and never take what is not theirs: a run writes everything
//! into a fresh staging folder beside its output folder and swaps it in only when the last file
//! has landed, so the output folder always holds one whole run, the earlier one or the new one,
//! never a mix of both; and it replaces or deletes a folder only when that folder proves it
//! holds nothing but what biscale wrote.
//!
//! * **Where.** The output path is resolved first ([`resolve_target`]): a link is followed (the
//!   run lands where it points; the link stays a link), a dangling link is refused, and so are
//!   the working folder and the folders above it (`--out .`), which cannot be swapped.
//! * **Staging.** [`StagedDir::begin`] makes `<parent>/.<name>.staging-<pid>-<nanos>/` (the
//!   same file system as the output, so the swap is a rename), holding the marker. Nothing is
//!   written to the output folder while the run works.
//! * **Swap.** [`StagedDir::commit`] lists every file the run wrote in the marker, then
//!   exchanges the staging folder and the output folder in one atomic step
//!   (`renameat2(RENAME_EXCHANGE)` on Linux), then deletes the earlier run, now at the staging
//!   path. Where the exchange is not supported it falls back to two renames (the earlier run
//!   first moves aside to `.<name>.old-...`): a kill between them leaves no output folder but
//!   both runs whole beside it. A swap that fails removes the staging folder.
//! * **Marker, ownership by proof.** Each run folder holds a `.biscale-run` file, JSON: a random
//!   run id, a proof (a hash of the id that only biscale writes beside it), what ran, and every
//!   file and folder the run wrote with its size and content hash ([`Marker`]). An existing
//!   output folder is replaced only when it is empty or its marker verifies and every entry in
//!   it is one the marker lists, with the contents it lists: a folder holding a `plan.txt` of its own, a marker of
//!   an older biscale, or a run folder someone has since added a file to (or edited one in) is
//!   an error naming what biscale did not write, never a deletion.
//! * **Leftovers.** A run that fails removes its staging folder; a killed one leaves it
//!   behind. The next run into the same output removes the `.<name>.staging-*` and
//!   `.<name>.old-*` folders whose process is no longer alive and whose marker verifies: a
//!   person's folder that merely has such a name is left alone.
//! * **Fault injection.** With `BISCALE_FAULT_KILL_AT=<point>` set, [`fault_point`] kills the
//!   process with SIGKILL when the run reaches that point (`transfer`, `compression`, `images`,
//!   `metrics`, `report`): how the tests show that a `kill -9` at any stage leaves a whole run.

use biscale_core::io::ContentHash;
use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The marker file every run folder carries.
pub const MARKER: &str = ".biscale-run";
/// What the marker's proof hashes with the run id.
const PROOF_SALT: &str = "biscale output folder, marker format 2";

/// The contents of [`MARKER`]: who wrote the folder and everything it wrote.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Marker {
    /// A random 128-bit id of the run, 32 hex digits.
    pub run_id: String,
    /// [`Marker::proof_of`] the id: a marker a person wrote by hand, or one of an older
    /// biscale, does not carry it.
    pub proof: String,
    /// What ran (`biscale run CONFIG`).
    pub about: String,
    /// Every file the run wrote, by path relative to the folder (`/`-separated), with its size
    /// and content hash; the marker itself is not listed. Empty while the run works.
    pub files: BTreeMap<String, FileSum>,
    /// Every folder the run made, the same way.
    pub folders: Vec<String>,
    /// The name of the staging folder the marker was written into
    /// (`.<out>.staging-<pid>-<nanos>`): a killed run's folder is removed as a leftover only
    /// under this name, so a marker copied into a person's folder does not make it one.
    #[serde(default)]
    pub staging: String,
}

impl Marker {
    pub(super) fn new(about: &str) -> Self {
        static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let mut h = ContentHash::default();
        h.write(&nanos.to_le_bytes())
            .write(&std::process::id().to_le_bytes())
            .write(&COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed).to_le_bytes())
            .write(&entropy());
        let run_id = format!("{:032x}", h.finish128());
        Self {
            proof: Self::proof_of(&run_id),
            run_id,
            about: about.into(),
            files: BTreeMap::new(),
            folders: vec![],
            staging: String::new(),
        }
    }

    /// The proof that goes with a run id.
    pub fn proof_of(run_id: &str) -> String {
        format!("{:032x}", ContentHash::default().write_str(PROOF_SALT).write_str(run_id).finish128())
    }

    /// The marker of `dir`, if it has one that verifies.
    pub fn read(dir: &Path) -> Option<Self> {
        let path = dir.join(MARKER);
        // A link is not a marker biscale wrote.
        if !std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file() && m.len() < (64 << 20)) {
            return None;
        }
        let m: Self = serde_json::from_slice(&std::fs::read(&path).ok()?).ok()?;
        (m.run_id.len() == 32 && m.proof == Self::proof_of(&m.run_id)).then_some(m)
    }

    pub(super) fn write(&self, dir: &Path) -> Result<(), StagingError> {
        let path = dir.join(MARKER);
        let mut text = serde_json::to_string_pretty(self).expect("a marker serialises");
        text.push('\n');
        biscale_core::io::write_atomic(&path, |w| {
            std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
        })
        .map_err(|e| StagingError::Io { path, source: std::io::Error::other(e.to_string()) })
    }

    /// Record every file and folder under `dir` (but the marker).
    fn take_inventory(&mut self, dir: &Path) -> Result<(), StagingError> {
        self.files.clear();
        self.folders.clear();
        for (rel, entry) in entries(dir)? {
            match entry {
                Entry::File(sum) => {
                    self.files.insert(rel, sum);
                }
                Entry::Folder => self.folders.push(rel),
                // A run writes no links; if one is there, leaving it unlisted makes the folder
                // unreplaceable rather than trusted.
                Entry::Other => {}
            }
        }
        Ok(())
    }

    /// The first entry of `dir` this marker does not account for, if any.
    fn stranger_in(&self, dir: &Path) -> Result<Option<String>, StagingError> {
        for (rel, entry) in entries(dir)? {
            let listed = match entry {
                Entry::File(sum) => self.files.get(&rel) == Some(&sum),
                Entry::Folder => self.folders.contains(&rel),
                Entry::Other => false,
            };
            if !listed {
                return Ok(Some(rel));
            }
        }
        Ok(None)
    }
}

/// 16 bytes from the system's random source (zeros where it has none: the time, pid and
/// counter hashed with them still make the id unique on this machine).
fn entropy() -> [u8; 16] {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    let _ = std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut bytes));
    bytes
}

/// A file's size and XXH3-128 content hash (32 hex digits), as the marker lists it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileSum {
    pub bytes: u64,
    pub xxh3: String,
}

impl FileSum {
    pub(super) fn of(path: &Path) -> Result<Self, StagingError> {
        use std::io::Read;
        let mut file = std::fs::File::open(path).map_err(io(path))?;
        let mut h = ContentHash::default();
        let mut buf = vec![0u8; 1 << 20];
        let mut bytes = 0u64;
        loop {
            let n = file.read(&mut buf).map_err(io(path))?;
            if n == 0 {
                break;
            }
            h.write(&buf[..n]);
            bytes += n as u64;
        }
        Ok(Self { bytes, xxh3: format!("{:032x}", h.finish128()) })
    }
}

/// What [`entries`] finds.
pub(super) enum Entry {
    File(FileSum),
    Folder,
    /// A link or anything else that is neither a plain file nor a folder.
    Other,
}

/// Every entry under `dir` but its marker, by `/`-separated relative path, links not followed.
pub(super) fn entries(dir: &Path) -> Result<Vec<(String, Entry)>, StagingError> {
    fn walk(base: &Path, dir: &Path, out: &mut Vec<(String, Entry)>) -> Result<(), StagingError> {
        for e in std::fs::read_dir(dir).map_err(io(dir))? {
            let e = e.map_err(io(dir))?;
            let path = e.path();
            let meta = std::fs::symlink_metadata(&path).map_err(io(&path))?;
            let rel = path.strip_prefix(base).unwrap_or(&path);
            let rel = rel.iter().map(|c| c.to_string_lossy()).collect::<Vec<_>>().join("/");
            if rel == MARKER {
                continue;
            }
            if meta.is_dir() {
                out.push((rel, Entry::Folder));
                walk(base, &path, out)?;
            } else if meta.is_file() {
                out.push((rel, Entry::File(FileSum::of(&path)?)));
            } else {
                out.push((rel, Entry::Other));
            }
        }
        Ok(())
    }
    let mut out = vec![];
    walk(dir, dir, &mut out)?;
    Ok(out)
}

/// A run's staging folder and the output folder it becomes.
#[derive(Debug)]
pub struct StagedDir {
    staging: PathBuf,
    target: PathBuf,
    marker: Marker,
}

/// Why a staged output could not be prepared or swapped in. Each names the folders.
#[derive(Debug, thiserror::Error)]
pub enum StagingError {
    #[error("{}: exists and is not a biscale output folder (it is not empty and has no {MARKER} that biscale wrote); biscale never replaces a folder it cannot prove is its own: choose another --out or remove it", path.display())]
    NotAnOutputFolder { path: PathBuf },
    #[error("{}: a biscale output folder, but it now holds {stranger}, which the run that wrote it did not write (or not with these contents); biscale never replaces what it did not write: move it out or choose another --out", path.display())]
    ForeignEntry { path: PathBuf, stranger: String },
    #[error("{}: exists and biscale did not write it (or it has changed since biscale did); biscale never overwrites a file it cannot prove is its own: move it or choose another --out", path.display())]
    ForeignFile { path: PathBuf },
    #[error("{}: holds a {MARKER} that biscale did not write (or one of an older biscale), so biscale cannot record what it writes there: choose another --out", path.display())]
    ForeignMarker { path: PathBuf },
    #[error("{}: the output must be a folder, and this is a file", path.display())]
    NotAFolder { path: PathBuf },
    #[error("{}: {why}; choose another --out", path.display())]
    BadTarget { path: PathBuf, why: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
}

pub(super) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StagingError + '_ {
    move |source| StagingError::Io { path: path.to_path_buf(), source }
}

/// Where a run into `target` lands: an absolute path with `.` and `..` resolved, a link
/// followed to the folder it names (so a swap replaces that folder and the link stays); an
/// error for a dangling link, for the file system's root, and for the working folder or a
/// folder that holds it (the swap would pull it from under the process).
pub fn resolve_target(target: &Path) -> Result<PathBuf, StagingError> {
    let bad = |why: &str| StagingError::BadTarget { path: target.to_path_buf(), why: why.into() };
    let is_link = std::fs::symlink_metadata(target).is_ok_and(|m| m.file_type().is_symlink());
    let resolved = if is_link {
        std::fs::canonicalize(target).map_err(|_| bad("a link to nothing (its target does not exist)"))?
    } else if target.exists() {
        std::fs::canonicalize(target).map_err(io(target))?
    } else {
        let name = target.file_name().ok_or_else(|| bad("not a folder name"))?;
        let parent = parent_of(target);
        std::fs::create_dir_all(&parent).map_err(io(&parent))?;
        std::fs::canonicalize(&parent).map_err(io(&parent))?.join(name)
    };
    if resolved.parent().is_none() {
        return Err(bad("the root of the file system cannot be an output folder"));
    }
    if let Ok(cwd) = std::env::current_dir().and_then(std::fs::canonicalize) {
        if cwd.starts_with(&resolved) {
            return Err(bad("the folder you are working in (or one that holds it) cannot be swapped for a run's output; name a subfolder"));
        }
    }
    Ok(resolved)
}

impl StagedDir {
    /// Prepare a staged run whose output folder is `target`: resolve it ([`resolve_target`]),
    /// check that it may be replaced, clear leftovers of killed runs, and make an empty
    /// staging folder holding the marker (`about` is written into it).
    pub fn begin(target: &Path, about: &str) -> Result<Self, StagingError> {
        let target = resolve_target(target)?;
        if target.exists() {
            check_replaceable(&target)?;
        }
        remove_leftovers(&target);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let staging = sibling(&target, &format!("staging-{}-{nanos}", std::process::id()));
        std::fs::create_dir(&staging).map_err(io(&staging))?;
        let mut marker = Marker::new(about);
        marker.staging = staging.file_name().map_or(String::new(), |n| n.to_string_lossy().into_owned());
        let staged = Self { staging, target, marker };
        // From here on, dropping `staged` removes the staging folder.
        staged.marker.write(&staged.staging)?;
        Ok(staged)
    }

    /// The folder the run writes into.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The output folder the run becomes (resolved: absolute, links followed).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// The run's id, as its marker records it.
    pub fn run_id(&self) -> &str {
        &self.marker.run_id
    }

    /// List what the run wrote in its marker, swap the staged run in for the output folder and
    /// delete the earlier run. On an error the staging folder is removed and the output folder
    /// is as it was.
    pub fn commit(mut self) -> Result<PathBuf, StagingError> {
        self.marker.take_inventory(&self.staging)?;
        self.marker.write(&self.staging)?;
        let target = self.target.clone();
        if !target.exists() {
            std::fs::rename(&self.staging, &target).map_err(io(&target))?;
            self.staging = PathBuf::new();
            return Ok(target);
        }
        check_replaceable(&target)?;
        if biscale_core::io::exchange(&self.staging, &target).is_ok() {
            // The earlier run is now at the staging path, and proved biscale's above.
            let earlier = std::mem::take(&mut self.staging);
            let _ = std::fs::remove_dir_all(&earlier);
            return Ok(target);
        }
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let old = sibling(&target, &format!("old-{}-{nanos}", std::process::id()));
        std::fs::rename(&target, &old).map_err(io(&target))?;
        if let Err(e) = std::fs::rename(&self.staging, &target) {
            // Put the earlier run back; dropping `self` removes the staging folder.
            let _ = std::fs::rename(&old, &target);
            return Err(io(&target)(e));
        }
        self.staging = PathBuf::new();
        let _ = std::fs::remove_dir_all(&old);
        Ok(target)
    }
}

/// A run that fails (an error, a panic, a swap that could not be made) removes its staging
/// folder; a killed one leaves it for the next run to remove.
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

/// An existing `target` may be replaced when it is empty, or when its marker verifies and
/// accounts for every entry in it.
fn check_replaceable(target: &Path) -> Result<(), StagingError> {
    if !std::fs::symlink_metadata(target).map_err(io(target))?.is_dir() {
        return Err(StagingError::NotAFolder { path: target.to_path_buf() });
    }
    let empty = std::fs::read_dir(target).map_err(io(target))?.next().is_none();
    if empty {
        return Ok(());
    }
    let Some(marker) = Marker::read(target) else {
        return Err(StagingError::NotAnOutputFolder { path: target.to_path_buf() });
    };
    match marker.stranger_in(target)? {
        None => Ok(()),
        Some(stranger) => Err(StagingError::ForeignEntry { path: target.to_path_buf(), stranger }),
    }
}

/// Remove the staging and set-aside folders of runs into `target` whose process is gone and
/// whose marker proves them biscale's.
fn remove_leftovers(target: &Path) {
    let Some(name) = target.file_name().map(|n| n.to_string_lossy().into_owned()) else { return };
    let Ok(entries) = std::fs::read_dir(parent_of(target)) else { return };
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = file.strip_prefix(&format!(".{name}.")) else { continue };
        let Some(id) = rest.strip_prefix("staging-").or_else(|| rest.strip_prefix("old-")) else { continue };
        let pid: Option<u32> = id.split('-').next().and_then(|p| p.parse().ok());
        let alive = pid.is_some_and(|p| p != std::process::id() && Path::new(&format!("/proc/{p}")).exists());
        let folder = std::fs::symlink_metadata(e.path()).is_ok_and(|m| m.is_dir());
        // Biscale's by proof: a finished run's folder (an `.old-` one) holds nothing its marker
        // does not list; a killed run's staging folder (its marker lists nothing yet) bears the
        // name its marker was written for.
        let owned = || {
            Marker::read(&e.path()).is_some_and(|m| match m.files.is_empty() && m.folders.is_empty() {
                true => m.staging == file,
                false => matches!(m.stranger_in(&e.path()), Ok(None)),
            })
        };
        if pid.is_some() && !alive && folder && owned() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
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

    /// A folder with a verifying marker and nothing else: what a killed run leaves.
    fn leftover(path: &Path) {
        std::fs::create_dir(path).unwrap();
        let mut m = Marker::new("killed");
        m.staging = path.file_name().unwrap().to_string_lossy().into_owned();
        m.write(path).unwrap();
        std::fs::write(path.join("half.exr"), "x").unwrap();
    }

    #[test]
    fn leftovers_of_dead_runs_are_removed_and_live_ones_and_look_alikes_kept() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        // pid 0 is never a process's; our own pid is alive.
        leftover(&root.path().join(".run.staging-0-1"));
        leftover(&root.path().join(".run.old-0-1"));
        let other_live = format!(".run.staging-{}-5", std::os::unix::process::parent_id());
        leftover(&root.path().join(&other_live));
        leftover(&root.path().join(".other.staging-0-1"));
        // A person's folders named like leftovers: no marker, a marker of their own, a link.
        std::fs::create_dir(root.path().join(".run.staging-999999-1")).unwrap();
        std::fs::write(root.path().join(".run.staging-999999-1/thesis.tex"), "x").unwrap();
        std::fs::create_dir(root.path().join(".run.old-0-2")).unwrap();
        std::fs::write(root.path().join(".run.old-0-2").join(MARKER), "{}").unwrap();
        std::os::unix::fs::symlink(root.path().join(".run.staging-0-1-x"), root.path().join(".run.staging-0-3"))
            .unwrap();
        let s = StagedDir::begin(&out, "x").unwrap();
        let mut left = files(root.path());
        left.retain(|f| !s.path().ends_with(f));
        assert_eq!(
            left,
            [".other.staging-0-1", ".run.old-0-2", ".run.staging-0-3", other_live.as_str(), ".run.staging-999999-1"]
                .iter()
                .map(|s| s.to_string())
                .collect::<std::collections::BTreeSet<_>>()
                .into_iter()
                .collect::<Vec<_>>()
        );
        assert!(root.path().join(".run.staging-999999-1/thesis.tex").exists());
    }

    /// Issue class "--out replaces a user's folder" (leftovers): a marker copied from a run
    /// into a person's folder named like a leftover does not make it one, whether the marker
    /// is a killed run's (bound to another folder name) or a finished run's (which does not
    /// list the person's files).
    #[test]
    fn a_copied_marker_does_not_make_a_persons_folder_a_leftover() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        // A finished run's marker, copied beside a person's notes.
        let done = StagedDir::begin(&root.path().join("done"), "done").unwrap();
        std::fs::write(done.path().join("a.txt"), "1").unwrap();
        let done = done.commit().unwrap();
        let finished = root.path().join(".run.old-0-7");
        std::fs::create_dir(&finished).unwrap();
        std::fs::copy(done.join(MARKER), finished.join(MARKER)).unwrap();
        std::fs::write(finished.join("notes.txt"), "mine").unwrap();
        // A killed run's marker (bound to its own folder), copied into another folder.
        leftover(&root.path().join(".run.staging-0-8"));
        let copied = root.path().join(".run.staging-0-9");
        std::fs::create_dir(&copied).unwrap();
        std::fs::copy(root.path().join(".run.staging-0-8").join(MARKER), copied.join(MARKER)).unwrap();
        std::fs::write(copied.join("notes.txt"), "mine").unwrap();
        let s = StagedDir::begin(&out, "x").unwrap();
        drop(s);
        assert_eq!(std::fs::read_to_string(finished.join("notes.txt")).unwrap(), "mine");
        assert_eq!(std::fs::read_to_string(copied.join("notes.txt")).unwrap(), "mine");
        // The genuine leftover, under the name its marker names, is gone.
        assert!(!root.path().join(".run.staging-0-8").exists());
    }

    /// Issue class "--out replaces a user's folder": a folder is replaced only when it proves
    /// it holds nothing but a run's files; a `plan.txt`, a hand-written or older marker, or a
    /// file added to (or edited in) a finished run makes it an error, and nothing is touched.
    #[test]
    fn a_folder_of_other_files_is_never_replaced() {
        let root = tempfile::tempdir().unwrap();
        let precious = root.path().join("docs");
        std::fs::create_dir(&precious).unwrap();
        std::fs::write(precious.join("thesis.tex"), "x").unwrap();
        let e = StagedDir::begin(&precious, "x").unwrap_err().to_string();
        assert!(e.contains("docs") && e.contains("not a biscale output folder"), "{e}");
        assert!(precious.join("thesis.tex").exists());
        // A file is refused too; an empty folder is fine.
        std::fs::write(root.path().join("f"), "x").unwrap();
        assert!(StagedDir::begin(&root.path().join("f"), "x").is_err());
        std::fs::create_dir(root.path().join("empty")).unwrap();
        StagedDir::begin(&root.path().join("empty"), "x").unwrap().commit().unwrap();
        // A plan.txt (what older biscales took for proof) or a marker without the proof.
        for (name, marker) in [("plan.txt", "notes"), (MARKER, "biscale run configs/x.toml\n")] {
            let d = root.path().join(format!("looks-like-{name}"));
            std::fs::create_dir(&d).unwrap();
            std::fs::write(d.join(name), marker).unwrap();
            std::fs::write(d.join("thesis.tex"), "x").unwrap();
            let e = StagedDir::begin(&d, "x").unwrap_err().to_string();
            assert!(e.contains("not a biscale output folder"), "{e}");
            assert_eq!(
                files(&d),
                [name, "thesis.tex"]
                    .iter()
                    .copied()
                    .collect::<std::collections::BTreeSet<_>>()
                    .into_iter()
                    .collect::<Vec<_>>()
            );
        }
        // A real run folder with a person's file added, or one of its files edited.
        let out = root.path().join("run");
        let first = StagedDir::begin(&out, "first").unwrap();
        std::fs::create_dir(first.path().join("images")).unwrap();
        std::fs::write(first.path().join("images/a.png"), "1").unwrap();
        first.commit().unwrap();
        std::fs::write(out.join("images/thesis.tex"), "x").unwrap();
        let e = StagedDir::begin(&out, "second").unwrap_err().to_string();
        assert!(e.contains("images/thesis.tex") && e.contains("did not write"), "{e}");
        std::fs::remove_file(out.join("images/thesis.tex")).unwrap();
        std::fs::write(out.join("images/a.png"), "edited by hand").unwrap();
        let e = StagedDir::begin(&out, "second").unwrap_err().to_string();
        assert!(e.contains("images/a.png"), "{e}");
        // An edit that keeps the size is caught too (the marker holds content hashes).
        std::fs::write(out.join("images/a.png"), "2").unwrap();
        let e = StagedDir::begin(&out, "second").unwrap_err().to_string();
        assert!(e.contains("images/a.png"), "{e}");
        // Back as the run wrote it: replaced.
        std::fs::write(out.join("images/a.png"), "1").unwrap();
        StagedDir::begin(&out, "second").unwrap().commit().unwrap();
        assert_eq!(files(&out), [MARKER]);
    }

    /// A file added while the run worked (after `begin`'s check) still stops the swap, and
    /// the failed swap leaves no staging folder.
    #[test]
    fn a_swap_refused_at_commit_leaves_nothing_beside_the_output() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        StagedDir::begin(&out, "first").unwrap().commit().unwrap();
        let second = StagedDir::begin(&out, "second").unwrap();
        std::fs::write(out.join("notes.md"), "written meanwhile").unwrap();
        let e = second.commit().unwrap_err().to_string();
        assert!(e.contains("notes.md"), "{e}");
        assert_eq!(files(root.path()), ["run"]);
        assert_eq!(std::fs::read_to_string(out.join("notes.md")).unwrap(), "written meanwhile");
    }

    /// A link is followed (the run lands where it points, the link stays); a dangling one is
    /// refused; the working folder and the folders above it are refused.
    #[test]
    fn links_are_followed_and_the_working_folder_refused() {
        let root = tempfile::tempdir().unwrap();
        let real = root.path().join("real");
        let link = root.path().join("link");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        let e = StagedDir::begin(&link, "x").unwrap_err().to_string();
        assert!(e.contains("link to nothing"), "{e}");
        std::fs::create_dir(&real).unwrap();
        let first = StagedDir::begin(&link, "x").unwrap();
        std::fs::write(first.path().join("a.txt"), "1").unwrap();
        first.commit().unwrap();
        let second = StagedDir::begin(&link, "x").unwrap();
        std::fs::write(second.path().join("a.txt"), "2").unwrap();
        second.commit().unwrap();
        assert!(link.is_symlink(), "the link stays a link");
        assert_eq!(std::fs::read_to_string(real.join("a.txt")).unwrap(), "2");
        assert_eq!(files(root.path()), ["link", "real"]);

        let cwd = std::env::current_dir().unwrap();
        for p in
            [cwd.clone(), cwd.join("."), cwd.parent().unwrap().to_path_buf(), PathBuf::from("."), PathBuf::from("/")]
        {
            let e = resolve_target(&p).unwrap_err().to_string();
            assert!(e.contains("working in") || e.contains("root"), "{}: {e}", p.display());
        }
    }
}
