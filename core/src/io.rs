//! File output every stage shares: the one atomic writer, the single-file writer of commands
//! that write one file where the user names it, and the content hash that keys cached stage
//! outputs.
//!
//! Every write is atomic: the bytes go to a temporary file in the target's directory, which is
//! flushed, synced and then renamed over the target, so a failed or interrupted write never
//! leaves a half-written output (and a missing directory leaves nothing at all).
//! [`write_atomic`] is for paths inside folders biscale owns (a staged run folder, the cache);
//! a file at a path a user names goes through [`write_single_file`], which never replaces
//! what biscale did not write.

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
    let tmp = write_temporary(path, write)?;
    let result = std::fs::rename(&tmp, path).map_err(|source| CoreError::Io { path: path.into(), source });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Write the bytes of `path` into a new temporary sibling (`.<name>.tmp-<pid>-<n>`, created
/// exclusively, flushed, synced and closed) and return its path; on failure nothing is left.
fn write_temporary(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<(), String>,
) -> Result<PathBuf> {
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
    // Close the file before it is renamed or removed.
    drop(out);
    match result {
        Ok(()) => Ok(tmp),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Write `bytes` to `path` atomically ([`write_atomic`]).
pub fn write_atomic_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |f| f.write_all(bytes).map_err(|e| e.to_string()))
}

/// How biscale recognises a single output file it wrote itself: each format carries a mark
/// that biscale puts in every such file, where reading a few bytes finds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileMark {
    /// An OBJ mesh whose first line starts with [`OBJ_MARK`].
    Obj,
    /// A PNG whose first chunk after `IHDR` is the `tEXt` chunk [`png_mark_chunk`]
    /// (`Software`: [`MARK_TEXT`]), as [`mark_png`] puts it there.
    Png,
    /// A ZIP archive (a `.npz`) whose archive comment is [`MARK_TEXT`].
    Zip,
}

/// The text of every mark: what a single file biscale wrote says of itself.
pub const MARK_TEXT: &str = "written by biscale";
/// The first line of an OBJ biscale writes as a single file starts with this.
pub const OBJ_MARK: &str = "# written by biscale";

impl FileMark {
    /// What such a file is, for messages.
    pub fn what(self) -> &'static str {
        match self {
            Self::Obj => "OBJ mesh",
            Self::Png => "PNG image",
            Self::Zip => "NumPy .npz archive",
        }
    }

    /// Whether a file of `len` bytes, whose first bytes are `head` and last bytes `tail` (each
    /// up to [`MARK_PROBE`] bytes), carries this mark.
    fn found(self, head: &[u8], tail: &[u8]) -> bool {
        match self {
            Self::Obj => head.starts_with(OBJ_MARK.as_bytes()),
            Self::Png => head.len() >= 33 && head[33..].starts_with(&png_mark_chunk()),
            Self::Zip => {
                // The end-of-central-directory record is the last 22 bytes plus the comment.
                let n = MARK_TEXT.len();
                tail.len() >= 22 + n && {
                    let eocd = &tail[tail.len() - 22 - n..];
                    eocd.starts_with(b"PK\x05\x06")
                        && eocd[20..22] == (n as u16).to_le_bytes()
                        && eocd[22..] == *MARK_TEXT.as_bytes()
                }
            }
        }
    }
}

/// How many bytes of an existing file's head and of its tail are read for its mark.
const MARK_PROBE: u64 = 4096;

/// The `tEXt` chunk [`mark_png`] puts right after `IHDR`: keyword `Software`, text
/// [`MARK_TEXT`], with its length and CRC.
pub fn png_mark_chunk() -> Vec<u8> {
    let data = [b"Software\0".as_slice(), MARK_TEXT.as_bytes()].concat();
    let mut chunk = (data.len() as u32).to_be_bytes().to_vec();
    let typed = [b"tEXt".as_slice(), &data].concat();
    chunk.extend_from_slice(&typed);
    chunk.extend_from_slice(&crc32fast::hash(&typed).to_be_bytes());
    chunk
}

/// Insert [`png_mark_chunk`] after the `IHDR` chunk of an encoded PNG (always its first: the
/// 8-byte signature, then 25 bytes of `IHDR`). `None` when `png` does not start that way.
pub fn mark_png(png: &[u8]) -> Option<Vec<u8>> {
    (png.len() >= 33 && png.starts_with(b"\x89PNG\r\n\x1a\n") && &png[12..16] == b"IHDR")
        .then(|| [&png[..33], &png_mark_chunk(), &png[33..]].concat())
}

/// Write one file where a user names it (`biscale generate --out`, `diff --error-image`,
/// Python's `Form.save`), whole or not at all ([`write_atomic`]'s temporary and rename), and
/// never over what biscale did not write:
///
/// * nothing there: written, by a rename that refuses to replace (`renameat2` with
///   `RENAME_NOREPLACE`; a link where that is not supported), so something made at the path
///   meanwhile is not replaced either;
/// * a regular file carrying `mark` (biscale wrote it): replaced, by an atomic exchange, after
///   which what was exchanged out is checked again and, if it changed meanwhile, put back;
/// * a regular file without the mark (a user's, or an input): refused, unless `force`;
/// * a link, a device node, a FIFO, a socket or a folder: refused, `force` or not. Nothing is
///   read from it: a device or FIFO is only looked at, never opened.
///
/// `-` is standard output: the bytes are streamed there (the way to write to a pipe).
/// `write` must leave `mark` in the bytes it writes, so the next run may replace the file.
pub fn write_single_file(
    path: &Path,
    mark: FileMark,
    force: bool,
    write: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<(), String>,
) -> Result<()> {
    if path.as_os_str() == "-" {
        return write_stdout(write);
    }
    let refused = |message: String| CoreError::Refused { path: path.into(), message };
    let existing = check_single_target(path, mark, force)?;
    let io = |source: std::io::Error| CoreError::Io { path: path.into(), source };
    let tmp = write_temporary(path, write)?;
    let result = match existing {
        None => publish_new(&tmp, path).map_err(|e| match e.kind() {
            std::io::ErrorKind::AlreadyExists => {
                refused("something was made at this path while biscale wrote; it is left as it is".into())
            }
            _ => io(e),
        }),
        Some(before) => publish_over(&tmp, path, mark, force, before),
    };
    // On success the temporary path holds the replaced file (or nothing); either way it goes.
    let _ = std::fs::remove_file(&tmp);
    result
}

/// [`write_single_file`] to standard output.
fn write_stdout(write: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<(), String>) -> Result<()> {
    use std::os::fd::{AsFd, FromRawFd, IntoRawFd};
    let stdout = std::io::stdout();
    let fd = stdout.as_fd().try_clone_to_owned().map_err(|source| CoreError::Io { path: "-".into(), source })?;
    // SAFETY: `fd` is an owned duplicate of standard output, handed to the File that owns it.
    let mut out = BufWriter::new(unsafe { File::from_raw_fd(fd.into_raw_fd()) });
    let path = PathBuf::from("<standard output>");
    write(&mut out).map_err(|message| CoreError::Input { path: path.clone(), message })?;
    out.flush().map_err(|source| CoreError::Io { path, source })
}

/// What is at a single file's path before it is written: `None` for nothing, else the
/// identity (device, inode) of the regular file that may be replaced; or the refusal.
fn check_single_target(path: &Path, mark: FileMark, force: bool) -> Result<Option<(u64, u64)>> {
    use std::os::unix::fs::MetadataExt;
    let refused = |message: String| CoreError::Refused { path: path.into(), message };
    let meta = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(CoreError::Io { path: path.into(), source }),
        Ok(m) => m,
    };
    if let Some(kind) = not_regular(&meta.file_type()) {
        return Err(refused(format!(
            "is {kind}, not a file biscale wrote; biscale writes a single output file only where nothing is or over              a {} it wrote itself (name a new file, or `-` to stream to standard output)",
            mark.what()
        )));
    }
    if force {
        return Ok(Some((meta.dev(), meta.ino())));
    }
    match carries_mark(path, mark) {
        Ok(true) => Ok(Some((meta.dev(), meta.ino()))),
        Ok(false) => Err(refused(format!(
            "exists and is not a {} biscale wrote (it lacks the mark \"{MARK_TEXT}\" biscale puts in every such file);              name a new file, or give --force to replace it",
            mark.what()
        ))),
        Err(source) => Err(CoreError::Io { path: path.into(), source }),
    }
}

/// Whether the regular file at `path` carries `mark`: it is opened without following a link
/// and without blocking, checked to be a regular file, and at most [`MARK_PROBE`] bytes of
/// its head and of its tail are read.
fn carries_mark(path: &Path, mark: FileMark) -> std::io::Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = OpenOptions::new().read(true).custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK).open(path)?;
    let meta = f.metadata()?;
    if !meta.is_file() {
        return Ok(false);
    }
    let len = meta.len();
    let mut head = vec![];
    (&mut f).take(MARK_PROBE).read_to_end(&mut head)?;
    let mut tail = vec![];
    f.seek(SeekFrom::Start(len.saturating_sub(MARK_PROBE)))?;
    f.take(MARK_PROBE).read_to_end(&mut tail)?;
    Ok(mark.found(&head, &tail))
}

/// Move `tmp` to `path` where nothing is: fails with `AlreadyExists` if something is.
fn publish_new(tmp: &Path, path: &Path) -> std::io::Result<()> {
    match rename_noreplace(tmp, path) {
        Err(e) if unsupported(&e) => {}
        other => return other,
    }
    // A hard link is never made over an existing name either.
    std::fs::hard_link(tmp, path)?;
    std::fs::remove_file(tmp)
}

/// Replace the file at `path`, which was the regular file `before` (device, inode), by `tmp`:
/// the two are exchanged, then what came out is checked to be that same file, still
/// acceptable; if not, the exchange is undone and the write refused.
fn publish_over(tmp: &Path, path: &Path, mark: FileMark, force: bool, before: (u64, u64)) -> Result<()> {
    use std::os::unix::fs::MetadataExt;
    let io = |source: std::io::Error| CoreError::Io { path: path.into(), source };
    match exchange(tmp, path) {
        Ok(()) => {
            let same = std::fs::symlink_metadata(tmp).is_ok_and(|m| m.is_file() && (m.dev(), m.ino()) == before);
            if same && (force || carries_mark(tmp, mark).unwrap_or(false)) {
                return Ok(());
            }
            exchange(tmp, path).map_err(io)?;
            return Err(CoreError::Refused {
                path: path.into(),
                message: "was replaced by something else while biscale wrote; it is left as it is".into(),
            });
        }
        Err(e) if unsupported(&e) => {}
        Err(e) => return Err(io(e)),
    }
    // Without an exchange: check again just before the rename (a window remains).
    let now = std::fs::symlink_metadata(path).map_err(io)?;
    if !(now.is_file() && (now.dev(), now.ino()) == before) {
        return Err(CoreError::Refused {
            path: path.into(),
            message: "was replaced by something else while biscale wrote; it is left as it is".into(),
        });
    }
    std::fs::rename(tmp, path).map_err(io)
}

/// Atomically exchange two paths (Linux `renameat2` with `RENAME_EXCHANGE`); `Unsupported`
/// elsewhere, and `EINVAL` where the file system cannot ([`unsupported`] tells both).
pub fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    return rename2(a, b, libc::RENAME_EXCHANGE);
    #[cfg(not(target_os = "linux"))]
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Rename `from` to `to` only where nothing is (Linux `renameat2` with `RENAME_NOREPLACE`):
/// `AlreadyExists` if something is; `Unsupported` elsewhere ([`unsupported`]).
pub fn rename_noreplace(from: &Path, to: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    return rename2(from, to, libc::RENAME_NOREPLACE);
    #[cfg(not(target_os = "linux"))]
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Whether `e` says the atomic rename is not available here (another OS, an old kernel, a
/// file system without it), so a caller falls back to a plainer way.
pub fn unsupported(e: &std::io::Error) -> bool {
    #[cfg(target_os = "linux")]
    if matches!(e.raw_os_error(), Some(libc::EINVAL | libc::ENOSYS)) {
        return true;
    }
    e.kind() == std::io::ErrorKind::Unsupported
}

#[cfg(target_os = "linux")]
fn rename2(from: &Path, to: &Path, flags: libc::c_uint) -> std::io::Result<()> {
    use std::os::unix::ffi::OsStrExt;
    let c = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes()).map_err(std::io::Error::other);
    let (a, b) = (c(from)?, c(to)?);
    // SAFETY: two NUL-terminated paths that live across the call.
    let r = unsafe { libc::renameat2(libc::AT_FDCWD, a.as_ptr(), libc::AT_FDCWD, b.as_ptr(), flags) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// What a file that is not a regular file is, for messages ("a symbolic link", "a folder", "a
/// device node", "a FIFO", "a socket"); `None` for a regular file. One wording for the
/// writers that refuse such a path and the readers that refuse to open one.
pub fn not_regular(t: &std::fs::FileType) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    Some(match () {
        _ if t.is_file() => return None,
        _ if t.is_symlink() => "a symbolic link",
        _ if t.is_dir() => "a folder",
        _ if t.is_char_device() || t.is_block_device() => "a device node",
        _ if t.is_fifo() => "a FIFO",
        _ if t.is_socket() => "a socket",
        _ => "neither a file nor a folder",
    })
}

/// Whether two paths name one existing file or folder (links followed; device and inode
/// compared).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => (x.dev(), x.ino()) == (y.dev(), y.ino()),
        _ => false,
    }
}

/// Open `path` for reading only if it is (or a link leads to) a regular file: it is opened
/// without blocking (a FIFO does not hang the open) and checked with `fstat`, so a device
/// node, FIFO, socket or folder is refused (`InvalidInput`, saying what it is) before a byte
/// is read. Returns the file and its length. Errors are plain I/O errors, so every reader
/// wraps them in its own error type with the path.
pub fn open_regular(path: &Path) -> std::io::Result<(File, u64)> {
    use std::os::unix::fs::OpenOptionsExt;
    let file = OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(path)?;
    let meta = file.metadata()?;
    if let Some(kind) = not_regular(&meta.file_type()) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("is {kind}, not a regular file (biscale reads only regular files)"),
        ));
    }
    Ok((file, meta.len()))
}

/// [`open_regular`] for a reader that opens the file itself (a decoder that takes a path):
/// refuses what is not a regular file before that reader can block on it or read it without
/// end; returns its length.
pub fn check_regular(path: &Path) -> std::io::Result<u64> {
    open_regular(path).map(|(_, len)| len)
}

/// Read the whole regular file at `path` ([`open_regular`]), refused up front when it holds
/// more than `max` bytes: what a file of its kind (`what`, for the message) can legitimately
/// hold. The read itself stops at `max` bytes too, should the file grow meanwhile.
pub fn read_regular(path: &Path, max: u64, what: &str) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let (file, len) = open_regular(path)?;
    if len > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{len} bytes: more than any {what} holds ({max} bytes at most)"),
        ));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max).read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// [`read_regular`] as UTF-8 text.
pub fn read_regular_text(path: &Path, max: u64, what: &str) -> std::io::Result<String> {
    String::from_utf8(read_regular(path, max, what)?)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("not UTF-8 text: {e}")))
}

/// Whether `rel`, a path a record names (a run's `metrics.json`: its images and plots), stays
/// inside the record's own folder as written: relative, not empty, made of plain names only
/// (no `..`, no root, no control characters). `Err` says what is wrong. A record names files
/// inside its own run folder only: [`inside_folder`] also refuses links on the way.
pub fn plain_relative(rel: &str) -> std::result::Result<(), &'static str> {
    use std::path::Component;
    if rel.is_empty() {
        return Err("is empty");
    }
    if rel.chars().any(char::is_control) {
        return Err("holds a control character");
    }
    for c in Path::new(rel).components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err("climbs out of the run folder (`..`)"),
            Component::RootDir | Component::Prefix(_) => return Err("is absolute"),
        }
    }
    Ok(())
}

/// `dir/rel` for a path a record names, when [`plain_relative`] holds and no folder or file on
/// the way is a link (so the path cannot lead out of `dir`); `Err` says what is wrong.
pub fn inside_folder(dir: &Path, rel: &str) -> std::result::Result<PathBuf, String> {
    plain_relative(rel).map_err(str::to_string)?;
    let mut at = dir.to_path_buf();
    for c in Path::new(rel).components() {
        at.push(c);
        if std::fs::symlink_metadata(&at).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(format!("passes through a link ({})", at.display()));
        }
    }
    Ok(at)
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

    /// An OBJ writer for [`write_single_file`] tests: `text` after the mark.
    fn obj(path: &Path, force: bool, text: &str) -> Result<()> {
        write_single_file(path, FileMark::Obj, force, |f| {
            f.write_all(format!("{OBJ_MARK}\n{text}").as_bytes()).map_err(|e| e.to_string())
        })
    }

    #[test]
    fn a_single_file_is_written_new_or_over_its_own_only() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.obj");
        obj(&p, false, "v 0 0 0\n").unwrap();
        obj(&p, false, "v 1 1 1\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), format!("{OBJ_MARK}\nv 1 1 1\n"));
        // A user's file (an input, an EXR, notes) is refused and left byte for byte; with
        // force it is replaced, and then it is biscale's.
        let mine = dir.path().join("mine.obj");
        std::fs::write(&mine, "v 9 9 9\n").unwrap();
        let e = obj(&mine, false, "v 1 1 1\n").unwrap_err();
        assert!(matches!(&e, CoreError::Refused { .. }) && e.to_string().contains("give --force"), "{e}");
        assert_eq!(std::fs::read_to_string(&mine).unwrap(), "v 9 9 9\n");
        obj(&mine, true, "v 2 2 2\n").unwrap();
        obj(&mine, false, "v 3 3 3\n").unwrap();
        // Only the mark counts, not the name: a PNG mark is not an OBJ mark.
        assert!(!FileMark::Png.found(OBJ_MARK.as_bytes(), OBJ_MARK.as_bytes()));
        // Nothing but the file was left in the folder (no temporaries).
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 2, "{names:?}");
    }

    #[test]
    fn links_folders_fifos_and_devices_are_never_replaced() {
        use std::os::unix::fs::FileTypeExt;
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("target.obj");
        obj(&target, false, "").unwrap();
        let link = dir.path().join("link.obj");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let folder = dir.path().join("folder.obj");
        std::fs::create_dir(&folder).unwrap();
        let fifo = dir.path().join("fifo.obj");
        let c = |p: &Path| std::ffi::CString::new(p.to_str().unwrap()).unwrap();
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c(&fifo).as_ptr(), 0o644) }, 0);
        // A character device like /dev/null (1, 3), made here: only where this process may
        // (root, as CI); elsewhere that case is skipped with a note.
        let device = dir.path().join("null.obj");
        // SAFETY: a NUL-terminated path.
        let made = unsafe { libc::mknod(c(&device).as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) } == 0;
        if !made {
            eprintln!("note: mknod not permitted here; the device-node case is checked where it is (CI runs as root)");
        }
        for (p, kind) in
            [(&link, "a symbolic link"), (&folder, "a folder"), (&fifo, "a FIFO"), (&device, "a device node")]
        {
            if p == &device && !made {
                continue;
            }
            for force in [false, true] {
                let e = obj(p, force, "v 1 1 1\n").unwrap_err().to_string();
                assert!(e.contains(&format!("is {kind}")) && e.contains("standard output"), "{e}");
            }
        }
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), format!("{OBJ_MARK}\n"));
        assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        if made {
            assert!(std::fs::symlink_metadata(&device).unwrap().file_type().is_char_device());
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 4 + made as usize);
    }

    #[test]
    fn the_png_and_zip_marks_are_found_where_they_are_written() {
        let img = image::RgbImage::from_pixel(3, 2, image::Rgb([10, 20, 30]));
        let mut png = std::io::Cursor::new(vec![]);
        img.write_to(&mut png, image::ImageFormat::Png).unwrap();
        assert!(!FileMark::Png.found(png.get_ref(), png.get_ref()));
        let marked = mark_png(png.get_ref()).unwrap();
        assert!(FileMark::Png.found(&marked, &marked));
        // The marked PNG still decodes to the same pixels (the chunk's CRC is right).
        let back = image::load_from_memory_with_format(&marked, image::ImageFormat::Png).unwrap().to_rgb8();
        assert_eq!(back, img);
        assert!(mark_png(b"not a png at all, long enough to have 33 bytes").is_none());
        // A ZIP's end record with the mark as its comment, and one with another comment.
        let eocd = |comment: &[u8]| {
            let mut r = b"PK\x05\x06".to_vec();
            r.extend_from_slice(&[0; 16]);
            r.extend_from_slice(&(comment.len() as u16).to_le_bytes());
            r.extend_from_slice(comment);
            r
        };
        assert!(FileMark::Zip.found(b"", &[b"members".as_slice(), &eocd(MARK_TEXT.as_bytes())].concat()));
        assert!(!FileMark::Zip.found(b"", &eocd(b"written by numpy..")));
        assert!(!FileMark::Zip.found(b"", &eocd(b"")));
    }

    #[test]
    fn only_regular_files_are_read_and_only_as_much_as_they_may_hold() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        std::fs::write(&p, "{}").unwrap();
        assert_eq!(read_regular_text(&p, 2, "record").unwrap(), "{}");
        let e = read_regular(&p, 1, "record").unwrap_err().to_string();
        assert!(e.contains("2 bytes: more than any record holds (1 bytes at most)"), "{e}");
        // A link to a regular file is read; a FIFO (which would block) and a link to a device
        // (which would never end) are refused before any read.
        let link = dir.path().join("link.json");
        std::os::unix::fs::symlink(&p, &link).unwrap();
        assert_eq!(read_regular(&link, 10, "record").unwrap(), b"{}");
        let fifo = dir.path().join("fifo.json");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
        let zero = dir.path().join("zero.json");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        for (p, kind) in [(&fifo, "a FIFO"), (&zero, "a device node"), (&dir.path().to_path_buf(), "a folder")] {
            let e = read_regular(p, u64::MAX, "record").unwrap_err().to_string();
            assert!(e.contains(&format!("is {kind}, not a regular file")), "{e}");
        }
    }

    #[test]
    fn a_record_names_files_inside_its_folder_only() {
        for ok in ["images/a.png", "a.png", "./images/b.png"] {
            assert_eq!(plain_relative(ok), Ok(()), "{ok}");
        }
        for (bad, why) in [
            ("/etc/passwd", "absolute"),
            ("../secret.png", "climbs out"),
            ("images/../../x", "climbs out"),
            ("", "empty"),
            ("a\nb.png", "control"),
        ] {
            assert!(plain_relative(bad).unwrap_err().contains(why), "{bad}");
        }
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("images")).unwrap();
        std::os::unix::fs::symlink("/proc/self", dir.path().join("images/proc")).unwrap();
        assert_eq!(inside_folder(dir.path(), "images/a.png").unwrap(), dir.path().join("images/a.png"));
        let e = inside_folder(dir.path(), "images/proc/environ").unwrap_err();
        assert!(e.contains("passes through a link"), "{e}");
    }

    #[test]
    fn length_prefixed_strings_do_not_run_together() {
        let ab_c = ContentHash::default().write_str("ab").write_str("c").finish128();
        let a_bc = ContentHash::default().write_str("a").write_str("bc").finish128();
        assert_ne!(ab_c, a_bc);
    }
}
