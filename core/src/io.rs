//! File output every stage shares: the one atomic writer, and the content hash that keys
//! cached stage outputs.
//!
//! Every write is atomic: the bytes go to a temporary file in the target's directory, which is
//! flushed, synced and then renamed over the target, so a failed or interrupted write never
//! leaves a half-written output (and a missing directory leaves nothing at all).

use crate::error::{CoreError, Result};
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Write `path` through a temporary sibling file and a rename (see the module docs).
/// `write` reports encoder failures as a message, which becomes [`CoreError::Input`] naming
/// the file.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<(), String>,
) -> Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let io = |source: std::io::Error| CoreError::Io { path: path.into(), source };
    let name = path.file_name().ok_or_else(|| CoreError::Invalid(format!("{}: not a file path", path.display())))?;
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp: PathBuf = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let file = OpenOptions::new().write(true).create_new(true).open(&tmp).map_err(io)?;
    let mut out = BufWriter::new(file);
    let result = write(&mut out)
        .map_err(|message| CoreError::Input { path: path.into(), message })
        .and_then(|()| out.flush().map_err(io))
        .and_then(|()| out.get_ref().sync_all().map_err(io));
    // Close the file before renaming or removing it.
    drop(out);
    let result = result.and_then(|()| std::fs::rename(&tmp, path).map_err(io));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Write `bytes` to `path` atomically ([`write_atomic`]).
pub fn write_atomic_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |f| f.write_all(bytes).map_err(|e| e.to_string()))
}

/// The content hash behind every cache key: XXH3-128 (`xxhash-rust`), fast and stable across
/// versions and platforms, with 128 bits so that two different inputs sharing a key is not a
/// practical concern (64-bit FNV-1a, used before, was weak on long, similar inputs such as
/// meshes). Not a cryptographic hash: a cache is a local folder, not a trust boundary, and
/// every file read from it is still checked by its loader. A stage output's key hashes
/// everything that determines it, plus a version the stage bumps when its meaning changes.
#[derive(Clone)]
pub struct ContentHash(xxhash_rust::xxh3::Xxh3);

impl Default for ContentHash {
    fn default() -> Self {
        Self(xxhash_rust::xxh3::Xxh3::new())
    }
}

impl std::fmt::Debug for ContentHash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ContentHash({:032x})", self.finish128())
    }
}

impl ContentHash {
    pub fn write(&mut self, bytes: &[u8]) -> &mut Self {
        self.0.update(bytes);
        self
    }

    /// Hash a length-prefixed string (so `"ab" + "c"` and `"a" + "bc"` differ).
    pub fn write_str(&mut self, s: &str) -> &mut Self {
        self.write(&(s.len() as u64).to_le_bytes()).write(s.as_bytes())
    }

    /// The 128-bit hash: what cache keys use.
    pub fn finish128(&self) -> u128 {
        self.0.digest128()
    }

    /// The low 64 bits of [`Self::finish128`]: for identities that are themselves hashed into
    /// a 128-bit key (a plugin library's code identity, say).
    pub fn finish(&self) -> u64 {
        self.finish128() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_hash_is_xxh3_128() {
        // Published XXH3-128 reference values (seed 0): the empty input, and "a" fed whole and
        // in pieces (the streaming state must not depend on how the input is split).
        assert_eq!(ContentHash::default().finish128(), 0x99aa06d3014798d86001c324468d497f);
        let whole = ContentHash::default().write(b"abc").finish128();
        let parts = ContentHash::default().write(b"a").write(b"bc").finish128();
        assert_eq!(whole, parts);
        assert_eq!(whole, 0x06b05ab6733a618578af5f94892f3950);
        assert_eq!(ContentHash::default().write(b"abc").finish(), 0x78af5f94892f3950);
    }

    #[test]
    fn length_prefixed_strings_do_not_run_together() {
        let ab_c = ContentHash::default().write_str("ab").write_str("c").finish128();
        let a_bc = ContentHash::default().write_str("a").write_str("bc").finish128();
        assert_ne!(ab_c, a_bc);
    }
}
