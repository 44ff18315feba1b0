//! Files written into a folder that is not a run folder: `export`, `export-matrix`, `btf`,
//! `viz` and `shard plan` write a few files into a folder the user names, which may be a
//! working folder full of other files. Such a command never overwrites a file it cannot prove
//! it wrote, and never leaves half its files behind.
//!
//! * **Staged.** [`SharedFolder::begin`] makes a staging folder inside the target
//!   (`.<PENDING>.staging-<pid>-<nanos>/`, a [`StagedDir`] with its marker, so a killed
//!   command's leftover is removed by proof the next time), and the command writes there.
//! * **Published by proof.** [`SharedFolder::publish`] checks every file written against the
//!   target first: a name that is free is taken; a name that exists is replaced only when the
//!   folder's marker ([`MARKER`], the same record a run folder carries) verifies and lists that
//!   file with the contents it has now, so a file a person wrote, or one biscale wrote that was
//!   edited since, is an error naming it, and nothing is moved. Then the files are renamed in
//!   (the same file system, so each lands whole) and the marker records them.
//! * **Early word.** `begin` takes the names a command knows it will write and refuses before
//!   any work when one of them is taken; `publish` checks every file again, also those whose
//!   names depend on the work (a material's or a setting's label).
//!
//! A folder with a marker that does not verify (written by hand, or by an older biscale) is
//! refused: what biscale wrote there could not be recorded.

use super::staging::{entries, io, Entry, FileSum, Marker, StagedDir, StagingError, MARKER};
use std::path::{Path, PathBuf};

/// The name the staging folder is made for (`.<PENDING>.staging-<pid>-<nanos>` in the target).
const PENDING: &str = "biscale-pending";

/// A command's files on their way into a shared folder.
#[derive(Debug)]
pub struct SharedFolder {
    /// The folder the files land in (resolved: absolute, links followed).
    dir: PathBuf,
    staged: StagedDir,
    about: String,
}

/// Where a staged file landed.
#[derive(Clone, Debug)]
pub struct Published {
    from: PathBuf,
    to: PathBuf,
}

impl Published {
    /// The published path of a file the command wrote under [`SharedFolder::path`].
    pub fn path(&self, staged: &Path) -> PathBuf {
        staged.strip_prefix(&self.from).map_or_else(|_| staged.to_path_buf(), |rel| self.to.join(rel))
    }
}

impl SharedFolder {
    /// Prepare writing into `dir` (made when missing; a link is followed, a file refused):
    /// refuse when `dir` holds a marker biscale did not write or when a name in `expect`
    /// (relative, `/`-separated) is taken by a file that is not biscale's, then make the
    /// staging folder.
    pub fn begin(dir: &Path, about: &str, expect: &[&str]) -> Result<Self, StagingError> {
        let is_link = std::fs::symlink_metadata(dir).is_ok_and(|m| m.file_type().is_symlink());
        if is_link && !dir.exists() {
            return Err(StagingError::BadTarget {
                path: dir.to_path_buf(),
                why: "a link to nothing (its target does not exist)".into(),
            });
        }
        if dir.exists() && !dir.is_dir() {
            return Err(StagingError::NotAFolder { path: dir.to_path_buf() });
        }
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let dir = std::fs::canonicalize(dir).map_err(io(dir))?;
        let marker = folder_marker(&dir)?;
        for name in expect {
            check_free(&dir, marker.as_ref(), name)?;
        }
        let staged = StagedDir::begin(&dir.join(PENDING), about)?;
        Ok(Self { dir, staged, about: about.into() })
    }

    /// The folder to write into now (the staging folder).
    pub fn path(&self) -> &Path {
        self.staged.path()
    }

    /// The folder the files land in.
    pub fn target(&self) -> &Path {
        &self.dir
    }

    /// Check every file written against the target, move them in and record them in the
    /// target's marker. On an error nothing has moved (short of a failing rename, which names
    /// its file) and the staging folder is removed.
    pub fn publish(self) -> Result<Published, StagingError> {
        let from = self.staged.path().to_path_buf();
        let mut marker = folder_marker(&self.dir)?;
        let written = entries(&from)?;
        // Check first: every folder is a folder or free, every file free or biscale's.
        for (rel, entry) in &written {
            match entry {
                Entry::Folder => {
                    let at = self.dir.join(rel);
                    if std::fs::symlink_metadata(&at).is_ok_and(|m| !m.is_dir()) {
                        return Err(StagingError::ForeignFile { path: at });
                    }
                }
                Entry::File(_) => check_free(&self.dir, marker.as_ref(), rel)?,
                Entry::Other => {
                    return Err(StagingError::BadTarget {
                        path: from.join(rel),
                        why: "a command wrote something that is neither a file nor a folder".into(),
                    })
                }
            }
        }
        let marker = marker.get_or_insert_with(|| Marker::new(&self.about));
        marker.about = self.about.clone();
        for (rel, entry) in written {
            let at = self.dir.join(&rel);
            match entry {
                Entry::Folder => {
                    if !at.is_dir() {
                        std::fs::create_dir(&at).map_err(io(&at))?;
                        if !marker.folders.contains(&rel) {
                            marker.folders.push(rel);
                        }
                    }
                }
                Entry::File(sum) => {
                    std::fs::rename(from.join(&rel), &at).map_err(io(&at))?;
                    marker.files.insert(rel, sum);
                }
                Entry::Other => unreachable!("refused above"),
            }
        }
        marker.write(&self.dir)?;
        // Dropping the staged folder removes what is left of it (its marker, empty folders).
        Ok(Published { from, to: self.dir })
    }
}

/// The marker of `dir`: `None` when it has none, an error when it has one biscale did not write.
fn folder_marker(dir: &Path) -> Result<Option<Marker>, StagingError> {
    let path = dir.join(MARKER);
    if std::fs::symlink_metadata(&path).is_err() {
        return Ok(None);
    }
    Marker::read(dir).map(Some).ok_or(StagingError::ForeignMarker { path: dir.to_path_buf() })
}

/// `dir/rel` is free, or a plain file the marker lists with the contents it has now.
fn check_free(dir: &Path, marker: Option<&Marker>, rel: &str) -> Result<(), StagingError> {
    let at = dir.join(rel);
    let Ok(meta) = std::fs::symlink_metadata(&at) else { return Ok(()) };
    let ours = meta.is_file()
        && marker.and_then(|m| m.files.get(rel)).is_some_and(|listed| FileSum::of(&at).is_ok_and(|now| now == *listed));
    if ours {
        Ok(())
    } else {
        Err(StagingError::ForeignFile { path: at })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn publish(dir: &Path, files: &[(&str, &str)]) -> Result<Published, StagingError> {
        let shared = SharedFolder::begin(dir, "test", &[])?;
        for (name, text) in files {
            let p = shared.path().join(name);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, text).unwrap();
        }
        shared.publish()
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn files_land_beside_a_persons_files_and_replace_only_their_own() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("work");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("thesis.tex"), "draft").unwrap();
        let p = publish(&dir, &[("a.txt", "one"), ("sub/b.txt", "two")]).unwrap();
        assert_eq!(std::fs::read_to_string(dir.join("sub/b.txt")).unwrap(), "two");
        assert_eq!(p.path(&tmp.path().join("elsewhere")), tmp.path().join("elsewhere"));
        assert_eq!(names(&dir), [MARKER, "a.txt", "sub", "thesis.tex"]);
        // Its own file, unchanged, is replaced; the person's is never.
        publish(&dir, &[("a.txt", "one, again")]).unwrap();
        assert_eq!(std::fs::read_to_string(dir.join("a.txt")).unwrap(), "one, again");
        let e = publish(&dir, &[("fresh.txt", "x"), ("thesis.tex", "overwritten")]).unwrap_err();
        assert!(matches!(&e, StagingError::ForeignFile { path } if path.ends_with("thesis.tex")), "{e}");
        assert_eq!(std::fs::read_to_string(dir.join("thesis.tex")).unwrap(), "draft");
        // Nothing moved, nothing left beside: the refusal is whole.
        assert_eq!(names(&dir), [MARKER, "a.txt", "sub", "thesis.tex"]);
        // A file of its own that someone has edited since is theirs now.
        std::fs::write(dir.join("a.txt"), "edited by hand").unwrap();
        assert!(matches!(publish(&dir, &[("a.txt", "x")]), Err(StagingError::ForeignFile { .. })));
        assert_eq!(std::fs::read_to_string(dir.join("a.txt")).unwrap(), "edited by hand");
        // The early check refuses before the command works.
        assert!(matches!(SharedFolder::begin(&dir, "t", &["thesis.tex"]), Err(StagingError::ForeignFile { .. })));
        SharedFolder::begin(&dir, "t", &["sub/b.txt", "new.txt"]).unwrap();
    }

    #[test]
    fn a_hand_written_marker_a_file_target_and_a_dangling_link_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("work");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join(MARKER), "{\"run_id\": \"0\"}").unwrap();
        assert!(matches!(publish(&dir, &[("a", "x")]), Err(StagingError::ForeignMarker { .. })));
        assert_eq!(names(&dir), [MARKER]);
        let file = tmp.path().join("file");
        std::fs::write(&file, "x").unwrap();
        assert!(matches!(publish(&file, &[]), Err(StagingError::NotAFolder { .. })));
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(tmp.path().join("nowhere"), &link).unwrap();
        assert!(matches!(publish(&link, &[]), Err(StagingError::BadTarget { .. })));
        assert!(!tmp.path().join("nowhere").exists());
    }

    #[test]
    fn a_link_is_followed_and_stays_a_link() {
        let tmp = tempfile::tempdir().unwrap();
        let real = tmp.path().join("real");
        std::fs::create_dir(&real).unwrap();
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        publish(&link, &[("a.txt", "x")]).unwrap();
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read_to_string(real.join("a.txt")).unwrap(), "x");
    }

    #[test]
    fn a_failed_command_leaves_nothing_and_a_killed_ones_leftover_goes_next_time() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("work");
        {
            let shared = SharedFolder::begin(&dir, "t", &[]).unwrap();
            std::fs::write(shared.path().join("half.txt"), "x").unwrap();
            // Dropped without publishing: the command failed.
        }
        assert!(names(&dir).is_empty(), "{:?}", names(&dir));
        // A killed command's staging folder (a dead pid, its own marker) goes; a person's
        // folder with a look-alike name stays.
        let shared = SharedFolder::begin(&dir, "t", &[]).unwrap();
        let killed = dir.join(format!(".{PENDING}.staging-999999-1"));
        std::fs::rename(shared.path(), &killed).unwrap();
        let mut m = Marker::read(&killed).unwrap();
        m.staging = format!(".{PENDING}.staging-999999-1");
        m.write(&killed).unwrap();
        std::mem::forget(shared);
        let look_alike = dir.join(format!(".{PENDING}.staging-999999-2"));
        std::fs::create_dir(&look_alike).unwrap();
        std::fs::write(look_alike.join("notes.txt"), "mine").unwrap();
        publish(&dir, &[("a.txt", "x")]).unwrap();
        assert!(!killed.exists());
        assert!(look_alike.join("notes.txt").is_file());
    }
}
