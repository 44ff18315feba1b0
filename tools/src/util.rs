//! Small shared helpers of the pipeline: atomic file writes, progress bars, hashing.

use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::Path;

/// Write `bytes` to `path` atomically through the shading crate's temporary-file-and-rename
/// writer, so a failed write never leaves a half-written output behind.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), biscale_shading::ShadingError> {
    biscale_shading::image::write_atomic(path, |f| f.write_all(bytes).map_err(|e| e.to_string()))
}

/// A progress bar on stderr for `len` steps of `what` (hidden when stderr is not a terminal).
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} ({elapsed} < {eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// 64-bit FNV-1a: a small stable hash for cache keys (not for security).
#[derive(Clone, Copy)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv64 {
    pub fn write(&mut self, bytes: &[u8]) -> &mut Self {
        for b in bytes {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
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
        assert_eq!(Fnv64::default().write(b"a").finish(), 0xaf63dc4c8601ec8c);
    }
}
