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

/// 64-bit FNV-1a: the small, stable hash behind every cache key (not for security). A stage
/// output's key hashes everything that determines it, plus a version the stage bumps when its
/// meaning changes.
#[derive(Clone, Copy, Debug)]
pub struct ContentHash(u64);

impl Default for ContentHash {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl ContentHash {
    pub fn write(&mut self, bytes: &[u8]) -> &mut Self {
        for b in bytes {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    /// Hash a length-prefixed string (so `"ab" + "c"` and `"a" + "bc"` differ).
    pub fn write_str(&mut self, s: &str) -> &mut Self {
        self.write(&(s.len() as u64).to_le_bytes()).write(s.as_bytes())
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv_is_stable() {
        // Reference value of FNV-1a 64 for "a".
        assert_eq!(ContentHash::default().write(b"a").finish(), 0xaf63dc4c8601ec8c);
    }
}
