//! The compressed-form file: any [`CompressedForm`] as one versioned, checksummed binary file,
//! so that a compression stage's output can be cached on disk and loaded by the runtime or a
//! plugin host without knowing the compressor (DESIGN.md sections 2 and 4).
//!
//! Layout (all integers little-endian):
//!
//! ```text
//! magic            8 bytes  b"BSCFORM\0"
//! version          u32      FORMAT_VERSION
//! total_len        u64      length of the whole file (catches truncation before anything else)
//! header:
//!   kind           u32 length + UTF-8 bytes
//!   vertices                      u64
//!   local basis, light basis      u32 length + UTF-8 tag each (`bins:8`, `cubemap:32`)
//!   lossless                      u8 (0 or 1)
//!   flops_per_gather              u64
//!   build_seconds                 f64 (IEEE bits)
//!   meta count     u32, then per entry: key (u32 length + UTF-8), value u64
//!   array count    u32, then per array: name (u32 length + UTF-8), element type u8
//!                  (0 u8, 1 i8, 2 u16, 3 i16, 4 u32, 5 f32), element count u64
//! payload          every array's elements in header order, tightly packed
//! crc32            u32      CRC-32 (IEEE) of every byte before it
//! ```
//!
//! Writes are atomic (a temporary file in the same folder, synced, then renamed). Loading
//! reads the file once, checks size, magic, version, length and checksum, then parses with
//! every length validated against the bytes actually present before anything is allocated:
//! a corrupt file is a [`FormFileError`] naming the file and the problem, never a panic.

use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::compress::{ArrayData, CompressedForm, NamedArray};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// First eight bytes of every form file.
pub const MAGIC: [u8; 8] = *b"BSCFORM\0";
/// The format version this code writes and reads.
pub const FORMAT_VERSION: u32 = 2;
/// Magic, version and total length.
const PREAMBLE: usize = 8 + 4 + 8;
const CRC_BYTES: usize = 4;

#[derive(Debug, thiserror::Error)]
pub enum FormFileError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a compressed-form file (bad magic bytes)", path.display())]
    WrongMagic { path: PathBuf },
    #[error("{}: compressed-form format version {found}, this build reads version {supported}", path.display())]
    WrongVersion { path: PathBuf, found: u32, supported: u32 },
    #[error("{}: truncated or padded: the file has {actual} bytes, its header says {expected}", path.display())]
    Truncated { path: PathBuf, actual: u64, expected: u64 },
    #[error("{}: checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupt", path.display())]
    Checksum { path: PathBuf, stored: u32, computed: u32 },
    #[error("{}: corrupt: {what}", path.display())]
    Corrupt { path: PathBuf, what: String },
    #[error("{}: cannot be written: {what}", path.display())]
    Unwritable { path: PathBuf, what: String },
}

fn type_tag(a: &ArrayData) -> u8 {
    match a {
        ArrayData::U8(_) => 0,
        ArrayData::I8(_) => 1,
        ArrayData::U16(_) => 2,
        ArrayData::I16(_) => 3,
        ArrayData::U32(_) => 4,
        ArrayData::F32(_) => 5,
    }
}

fn tag_width(tag: u8) -> Option<usize> {
    match tag {
        0 | 1 => Some(1),
        2 | 3 => Some(2),
        4 | 5 => Some(4),
        _ => None,
    }
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

/// The file's bytes for `form`.
pub fn encode_form(form: &CompressedForm) -> Vec<u8> {
    let mut out = Vec::with_capacity(PREAMBLE + 256 + form.bytes() as usize + CRC_BYTES);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u64.to_le_bytes()); // total_len, patched below
    put_str(&mut out, &form.kind);
    out.extend_from_slice(&(form.vertices() as u64).to_le_bytes());
    put_str(&mut out, &form.local_basis().tag());
    put_str(&mut out, &form.light_basis().tag());
    out.push(form.lossless as u8);
    out.extend_from_slice(&form.flops_per_gather.to_le_bytes());
    out.extend_from_slice(&form.build_seconds.to_bits().to_le_bytes());
    out.extend_from_slice(&(form.meta.len() as u32).to_le_bytes());
    for (k, v) in &form.meta {
        put_str(&mut out, k);
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&(form.arrays.len() as u32).to_le_bytes());
    for a in &form.arrays {
        put_str(&mut out, &a.name);
        out.push(type_tag(&a.data));
        out.extend_from_slice(&(a.data.len() as u64).to_le_bytes());
    }
    for a in &form.arrays {
        match &a.data {
            ArrayData::U8(v) => out.extend_from_slice(v),
            ArrayData::I8(v) => out.extend(v.iter().map(|&x| x as u8)),
            ArrayData::U16(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
            ArrayData::I16(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
            ArrayData::U32(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
            ArrayData::F32(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_bits().to_le_bytes())),
        }
    }
    let total = (out.len() + CRC_BYTES) as u64;
    out[12..20].copy_from_slice(&total.to_le_bytes());
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Write `form` to `path` atomically (temporary file + rename in the same folder).
pub fn save_form(form: &CompressedForm, path: &Path) -> Result<(), FormFileError> {
    let bytes = encode_form(form);
    let io = |source| FormFileError::Io { path: path.to_path_buf(), source };
    let name = path.file_name().ok_or_else(|| FormFileError::Unwritable {
        path: path.to_path_buf(),
        what: "the path has no file name".into(),
    })?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

/// A bounds-checked reader over the file's bytes.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    fn corrupt(&self, what: impl Into<String>) -> FormFileError {
        FormFileError::Corrupt { path: self.path.to_path_buf(), what: what.into() }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], FormFileError> {
        if n > self.bytes.len() - self.at {
            return Err(self.corrupt(format!(
                "{what} needs {n} bytes at offset {}, only {} remain",
                self.at,
                self.bytes.len() - self.at
            )));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    fn u8(&mut self, what: &str) -> Result<u8, FormFileError> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, FormFileError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn u64(&mut self, what: &str) -> Result<u64, FormFileError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn usize(&mut self, what: &str) -> Result<usize, FormFileError> {
        let v = self.u64(what)?;
        usize::try_from(v).map_err(|_| self.corrupt(format!("{what} {v} does not fit this machine")))
    }
    fn string(&mut self, what: &str) -> Result<String, FormFileError> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        String::from_utf8(b.to_vec()).map_err(|_| self.corrupt(format!("{what} is not UTF-8")))
    }
    /// A count of items each at least `min_bytes` long, checked against what remains.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, FormFileError> {
        let n = self.u32(what)? as usize;
        if n.saturating_mul(min_bytes) > self.bytes.len() - self.at {
            return Err(self.corrupt(format!("{what} {n} cannot fit in the {} bytes left", self.bytes.len() - self.at)));
        }
        Ok(n)
    }
}

/// Parse a form file's bytes (`path` only names the file in errors).
pub fn decode_form(bytes: &[u8], path: &Path) -> Result<CompressedForm, FormFileError> {
    let p = || path.to_path_buf();
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
        return Err(FormFileError::WrongMagic { path: p() });
    }
    if bytes.len() < PREAMBLE + CRC_BYTES {
        return Err(FormFileError::Truncated {
            path: p(),
            actual: bytes.len() as u64,
            expected: (PREAMBLE + CRC_BYTES) as u64,
        });
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    if version != FORMAT_VERSION {
        return Err(FormFileError::WrongVersion { path: p(), found: version, supported: FORMAT_VERSION });
    }
    let total = u64::from_le_bytes(bytes[12..20].try_into().unwrap());
    if total != bytes.len() as u64 {
        return Err(FormFileError::Truncated { path: p(), actual: bytes.len() as u64, expected: total });
    }
    let body_end = bytes.len() - CRC_BYTES;
    let stored = u32::from_le_bytes(bytes[body_end..].try_into().unwrap());
    let computed = crc32fast::hash(&bytes[..body_end]);
    if stored != computed {
        return Err(FormFileError::Checksum { path: p(), stored, computed });
    }
    let mut r = Reader { bytes: &bytes[..body_end], at: PREAMBLE, path };
    let kind = r.string("kind")?;
    let vertices = r.usize("vertices")?;
    let local = LocalBasis::parse(&r.string("local basis")?).map_err(|e| r.corrupt(e.to_string()))?;
    let light = LightBasis::parse(&r.string("light basis")?).map_err(|e| r.corrupt(e.to_string()))?;
    let lossless = match r.u8("lossless flag")? {
        0 => false,
        1 => true,
        x => return Err(r.corrupt(format!("lossless flag is {x}, not 0 or 1"))),
    };
    let flops_per_gather = r.u64("flops_per_gather")?;
    let build_seconds = f64::from_bits(r.u64("build_seconds")?);
    let nmeta = r.count("meta count", 4 + 8)?;
    let mut meta = BTreeMap::new();
    for _ in 0..nmeta {
        let k = r.string("meta key")?;
        let v = r.u64("meta value")?;
        if meta.insert(k.clone(), v).is_some() {
            return Err(r.corrupt(format!("meta key '{k}' appears twice")));
        }
    }
    let narrays = r.count("array count", 4 + 1 + 8)?;
    let mut specs = Vec::with_capacity(narrays);
    let mut payload = 0usize;
    for i in 0..narrays {
        let name = r.string("array name")?;
        let tag = r.u8("array element type")?;
        let width =
            tag_width(tag).ok_or_else(|| r.corrupt(format!("array {i} ('{name}') has unknown element type {tag}")))?;
        let len = r.usize("array length")?;
        let nbytes = len
            .checked_mul(width)
            .and_then(|b| b.checked_add(payload))
            .ok_or_else(|| r.corrupt(format!("array '{name}' length {len} overflows")))?;
        payload = nbytes;
        specs.push((name, tag, len));
    }
    let left = r.bytes.len() - r.at;
    if payload != left {
        return Err(r.corrupt(format!("the arrays declare {payload} bytes of data, the file holds {left}")));
    }
    let mut arrays = Vec::with_capacity(narrays);
    for (name, tag, len) in specs {
        let b = r.take(len * tag_width(tag).unwrap(), "array data")?;
        let data = match tag {
            0 => ArrayData::U8(b.to_vec()),
            1 => ArrayData::I8(b.iter().map(|&x| x as i8).collect()),
            2 => ArrayData::U16(b.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect()),
            3 => ArrayData::I16(b.chunks_exact(2).map(|c| i16::from_le_bytes([c[0], c[1]])).collect()),
            4 => ArrayData::U32(b.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect()),
            _ => ArrayData::F32(
                b.chunks_exact(4).map(|c| f32::from_bits(u32::from_le_bytes(c.try_into().unwrap()))).collect(),
            ),
        };
        arrays.push(NamedArray { name, data });
    }
    let mut form = CompressedForm::new(kind, TransferShape::new(vertices, local, light));
    form.arrays = arrays;
    form.meta = meta;
    form.lossless = lossless;
    form.flops_per_gather = flops_per_gather;
    form.build_seconds = build_seconds;
    Ok(form)
}

/// Load a form written by [`save_form`].
pub fn load_form(path: &Path) -> Result<CompressedForm, FormFileError> {
    let bytes = std::fs::read(path).map_err(|source| FormFileError::Io { path: path.to_path_buf(), source })?;
    decode_form(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> CompressedForm {
        let shape = TransferShape::new(3, LocalBasis::bins(2).unwrap(), LightBasis::cubemap(2).unwrap());
        let mut f = CompressedForm::new("bicluster", shape)
            .with_array("a_u8", ArrayData::U8(vec![0, 1, 255]))
            .with_array("a_i8", ArrayData::I8(vec![-128, -1, 0, 127]))
            .with_array("a_u16", ArrayData::U16(vec![0, 65535, 1234]))
            .with_array("a_i16", ArrayData::I16(vec![i16::MIN, -7, i16::MAX]))
            .with_array("a_u32", ArrayData::U32(vec![u32::MAX, 0, 42]))
            .with_array("empty", ArrayData::F32(vec![]))
            .with_array("a_f32", ArrayData::F32(vec![-0.0, 1.5e-42, f32::MAX, f32::INFINITY, 0.1]));
        f.meta = BTreeMap::from([("value_scale".into(), 4), ("big".into(), u64::MAX)]);
        f.lossless = true;
        f.flops_per_gather = 123_456_789_012;
        f.build_seconds = 0.1 + 0.2;
        f
    }

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("biscale-form-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn round_trip_every_array_type() {
        let form = sample();
        let path = tmp("round.bsform");
        save_form(&form, &path).unwrap();
        let back = load_form(&path).unwrap();
        assert_eq!(back, form);
        assert_eq!(back.build_seconds.to_bits(), form.build_seconds.to_bits());
        // No temporary file is left behind.
        let left: Vec<_> = std::fs::read_dir(path.parent().unwrap())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
            .collect();
        assert!(left.is_empty());
        // Overwriting works (rename over an existing file).
        let mut f2 = form.clone();
        f2.kind = "sparse".into();
        save_form(&f2, &path).unwrap();
        assert_eq!(load_form(&path).unwrap().kind, "sparse");
        // An empty form too.
        let mut empty = form;
        empty.arrays.clear();
        empty.meta.clear();
        empty.kind.clear();
        assert_eq!(decode_form(&encode_form(&empty), Path::new("x")).unwrap(), empty);
    }

    #[test]
    fn corrupt_files_are_clear_errors() {
        let path = Path::new("/some/dir/form.bsform");
        let good = encode_form(&sample());
        let msg = |e: FormFileError| {
            let s = e.to_string();
            assert!(s.contains("form.bsform"), "error does not name the file: {s}");
            s
        };
        // Wrong magic.
        let mut b = good.clone();
        b[0] = b'X';
        assert!(matches!(decode_form(&b, path), Err(FormFileError::WrongMagic { .. })));
        assert!(matches!(decode_form(b"", path), Err(FormFileError::WrongMagic { .. })));
        // Wrong version.
        let mut b = good.clone();
        b[8..12].copy_from_slice(&1u32.to_le_bytes());
        let e = decode_form(&b, path).unwrap_err();
        assert!(matches!(e, FormFileError::WrongVersion { found: 1, supported: 2, .. }));
        assert!(msg(e).contains("version 1"));
        // Truncated anywhere (including inside the preamble).
        for cut in [9, 15, 30, good.len() / 2, good.len() - 1] {
            let e = decode_form(&good[..cut], path).unwrap_err();
            assert!(matches!(e, FormFileError::Truncated { .. }), "cut {cut}: {e}");
            msg(e);
        }
        // Trailing garbage.
        let mut b = good.clone();
        b.push(0);
        assert!(matches!(decode_form(&b, path), Err(FormFileError::Truncated { .. })));
        // Any flipped bit after the preamble fails the checksum.
        for at in [PREAMBLE, PREAMBLE + 5, good.len() / 2, good.len() - 5, good.len() - 1] {
            let mut b = good.clone();
            b[at] ^= 0x10;
            let e = decode_form(&b, path).unwrap_err();
            assert!(matches!(e, FormFileError::Checksum { .. }), "byte {at}: {e}");
            assert!(msg(e).contains("corrupt"));
        }
    }

    /// A file with a valid checksum but lying lengths (as a buggy writer could make) must
    /// fail cleanly without allocating what the lengths claim.
    #[test]
    fn lying_lengths_with_valid_checksum_are_errors() {
        let path = Path::new("lie.bsform");
        let reseal = |mut b: Vec<u8>| {
            let n = b.len() - CRC_BYTES;
            let crc = crc32fast::hash(&b[..n]);
            b[n..].copy_from_slice(&crc.to_le_bytes());
            b
        };
        let good = encode_form(&sample());
        // The kind string's length claims 4 GiB.
        let mut b = good.clone();
        b[PREAMBLE..PREAMBLE + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode_form(&reseal(b), path), Err(FormFileError::Corrupt { .. })));
        // The first array's length claims u64::MAX elements: find its length field.
        let form = sample();
        let tags = form.local_basis().tag().len() + form.light_basis().tag().len();
        let mut at = PREAMBLE + 4 + form.kind.len() + 8 + 8 + tags + 1 + 16 + 4;
        for k in form.meta.keys() {
            at += 4 + k.len() + 8;
        }
        at += 4 + 4 + form.arrays[0].name.len() + 1;
        let mut b = good.clone();
        assert_eq!(u64::from_le_bytes(b[at..at + 8].try_into().unwrap()), 3);
        b[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        let e = decode_form(&reseal(b), path).unwrap_err();
        assert!(matches!(e, FormFileError::Corrupt { .. }), "{e}");
        // One element more than the payload holds.
        let mut b = good.clone();
        b[at..at + 8].copy_from_slice(&4u64.to_le_bytes());
        assert!(matches!(decode_form(&reseal(b), path), Err(FormFileError::Corrupt { .. })));
        // Unknown element type.
        let mut b = good;
        b[at - 1] = 9;
        let e = decode_form(&reseal(b), path).unwrap_err();
        assert!(e.to_string().contains("unknown element type 9"), "{e}");
    }

    #[test]
    fn missing_file_is_io_error_naming_it() {
        let e = load_form(Path::new("/nonexistent/dir/f.bsform")).unwrap_err();
        assert!(matches!(e, FormFileError::Io { .. }));
        assert!(e.to_string().contains("f.bsform"));
    }
}
