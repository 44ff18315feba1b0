//! The one file format of biscale's stage outputs: a versioned, checksummed container of named
//! scalar fields and named typed arrays. The transfer matrix (`TransferMatrix::save`), every
//! compressed form (`CompressedForm::save`) and every BTF (`biscale_shading::synth::save_btf`)
//! are written as one, so they are cached on disk and loaded back by one reader that trusts
//! nothing it reads (docs/DESIGN.md sections 2 and 4). It is also simple to read from other
//! languages: a header of little-endian integers and UTF-8 names, then the raw arrays.
//!
//! Layout (all integers little-endian):
//!
//! ```text
//! magic        8 bytes  b"BISCALE\0"
//! version      u32      CONTAINER_VERSION
//! total_len    u64      length of the whole file (catches truncation before anything else)
//! kind         u32 length + UTF-8 bytes ("transfer", "form", "btf")
//! fields       u32 count, then per field: name (u32 length + UTF-8), tag u8
//!              (0 = u64, 1 = f64 bits, 2 = UTF-8 string), value (u64 / u64 / u32 length + bytes)
//! arrays       u32 count, then per array: name (u32 length + UTF-8), element type u8
//!              (0 u8, 1 i8, 2 u16, 3 i16, 4 u32, 5 f32), element count u64
//! payload      every array's elements in header order, tightly packed
//! crc32        u32      CRC-32 (IEEE) of every byte before it
//! ```
//!
//! Writes are atomic ([`crate::io::write_atomic`]). Loading reads the file once, checks size,
//! magic, version, length and checksum, then parses with every length validated against the
//! bytes actually present before anything is allocated: a corrupt file is an
//! [`ArtifactError`] naming the file and the problem, never a panic. The files of earlier
//! biscale versions (each format had its own magic) are recognised and refused by name.

use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::compress::{ArrayData, NamedArray};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// First eight bytes of every artifact.
pub const MAGIC: [u8; 8] = *b"BISCALE\0";
/// The container version this code writes and reads.
pub const CONTAINER_VERSION: u32 = 2;
/// Magics of the per-type formats the container replaced (compressed forms and BTFs).
const OLD_MAGICS: [(&[u8; 8], &str); 2] = [(b"BSCFORM\0", "compressed-form"), (b"BSCBTF\0\0", "BTF")];
/// Magic, version and total length.
const PREAMBLE: usize = 8 + 4 + 8;
const CRC_BYTES: usize = 4;
/// Bytes [`Artifact::peek`] reads: enough for any header biscale writes.
pub const PEEK_BYTES: u64 = 1 << 20;

/// A named scalar of an artifact's header.
#[derive(Clone, Debug, PartialEq)]
pub enum Field {
    U64(u64),
    F64(f64),
    Str(String),
}

/// Why an artifact could not be read or written. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ArtifactError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a biscale file (bad magic bytes)", path.display())]
    WrongMagic { path: PathBuf },
    #[error("{}: a {what} file in a format of an earlier biscale; this build reads container format {}: delete it (a cache file is rebuilt)", path.display(), CONTAINER_VERSION)]
    OldFormat { path: PathBuf, what: &'static str },
    #[error("{}: container format version {found}, this build reads version {supported}", path.display())]
    WrongVersion { path: PathBuf, found: u32, supported: u32 },
    #[error("{}: truncated or padded: the file has {actual} bytes, its header says {expected}", path.display())]
    Truncated { path: PathBuf, actual: u64, expected: u64 },
    #[error("{}: checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupt", path.display())]
    Checksum { path: PathBuf, stored: u32, computed: u32 },
    #[error("{}: corrupt: {what}", path.display())]
    Corrupt { path: PathBuf, what: String },
}

/// A stage output as fields and arrays (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Artifact {
    /// What the file holds (`transfer`, `form`, `btf`).
    pub kind: String,
    pub fields: BTreeMap<String, Field>,
    pub arrays: Vec<NamedArray>,
    /// The file it was read from (names it in errors; empty for one made in memory).
    pub source: PathBuf,
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

impl Artifact {
    /// An empty artifact of `kind`.
    pub fn new(kind: &str) -> Self {
        Self { kind: kind.into(), fields: BTreeMap::new(), arrays: vec![], source: PathBuf::new() }
    }

    /// Add a field (builder style).
    pub fn with(mut self, name: &str, value: Field) -> Self {
        self.fields.insert(name.into(), value);
        self
    }

    /// Add an array (builder style).
    pub fn with_array(mut self, name: &str, data: ArrayData) -> Self {
        self.arrays.push(NamedArray { name: name.into(), data });
        self
    }

    /// The file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        self.encode_with(&BTreeMap::new())
    }

    /// The file's bytes with `extra` fields besides the artifact's own (an extra field of the
    /// same name wins): how the stage cache stores its key inside a file without copying the
    /// arrays.
    pub fn encode_with(&self, extra: &BTreeMap<String, Field>) -> Vec<u8> {
        let mut fields: BTreeMap<&str, &Field> = self.fields.iter().map(|(k, v)| (k.as_str(), v)).collect();
        fields.extend(extra.iter().map(|(k, v)| (k.as_str(), v)));
        let payload: u64 = self.arrays.iter().map(|a| a.data.bytes()).sum();
        let mut out = Vec::with_capacity(PREAMBLE + 256 + payload as usize + CRC_BYTES);
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&CONTAINER_VERSION.to_le_bytes());
        out.extend_from_slice(&0u64.to_le_bytes()); // total_len, patched below
        put_str(&mut out, &self.kind);
        out.extend_from_slice(&(fields.len() as u32).to_le_bytes());
        for (name, value) in fields {
            put_str(&mut out, name);
            match value {
                Field::U64(v) => {
                    out.push(0);
                    out.extend_from_slice(&v.to_le_bytes());
                }
                Field::F64(v) => {
                    out.push(1);
                    out.extend_from_slice(&v.to_bits().to_le_bytes());
                }
                Field::Str(s) => {
                    out.push(2);
                    put_str(&mut out, s);
                }
            }
        }
        out.extend_from_slice(&(self.arrays.len() as u32).to_le_bytes());
        for a in &self.arrays {
            put_str(&mut out, &a.name);
            out.push(type_tag(&a.data));
            out.extend_from_slice(&(a.data.len() as u64).to_le_bytes());
        }
        for a in &self.arrays {
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

    /// Write the artifact to `path` atomically.
    pub fn save(&self, path: &Path) -> Result<(), crate::CoreError> {
        crate::io::write_atomic_bytes(path, &self.encode())
    }

    /// Write the artifact with `extra` fields ([`Self::encode_with`]) to `path` atomically.
    pub fn save_with(&self, path: &Path, extra: &BTreeMap<String, Field>) -> Result<(), crate::CoreError> {
        crate::io::write_atomic_bytes(path, &self.encode_with(extra))
    }

    /// Read the artifact at `path`.
    pub fn load(path: &Path) -> Result<Self, ArtifactError> {
        // A regular file only (a device or FIFO named as a part or cache entry is refused, not
        // read without end); its size is then checked against its own header by `decode`.
        let bytes = crate::io::read_regular(path, u64::MAX, "artifact")
            .map_err(|source| ArtifactError::Io { path: path.to_path_buf(), source })?;
        Self::decode(&bytes, path)
    }

    /// Parse an artifact's bytes (`path` names the file in errors).
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Self, ArtifactError> {
        let p = || path.to_path_buf();
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            if let Some((_, what)) = OLD_MAGICS.iter().find(|(m, _)| bytes.starts_with(&m[..])) {
                return Err(ArtifactError::OldFormat { path: p(), what });
            }
            return Err(ArtifactError::WrongMagic { path: p() });
        }
        if bytes.len() < PREAMBLE + CRC_BYTES {
            return Err(ArtifactError::Truncated {
                path: p(),
                actual: bytes.len() as u64,
                expected: (PREAMBLE + CRC_BYTES) as u64,
            });
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
        if version != CONTAINER_VERSION {
            return Err(ArtifactError::WrongVersion { path: p(), found: version, supported: CONTAINER_VERSION });
        }
        let total = u64::from_le_bytes(bytes[12..20].try_into().unwrap());
        if total != bytes.len() as u64 {
            return Err(ArtifactError::Truncated { path: p(), actual: bytes.len() as u64, expected: total });
        }
        let body_end = bytes.len() - CRC_BYTES;
        let stored = u32::from_le_bytes(bytes[body_end..].try_into().unwrap());
        let computed = crc32fast::hash(&bytes[..body_end]);
        if stored != computed {
            return Err(ArtifactError::Checksum { path: p(), stored, computed });
        }
        let mut r = Reader { bytes: &bytes[..body_end], at: PREAMBLE, path };
        let (kind, fields) = r.kind_and_fields()?;
        let narrays = r.count("array count", 4 + 1 + 8)?;
        let mut specs = Vec::with_capacity(narrays);
        let mut payload = 0usize;
        for i in 0..narrays {
            let name = r.string("array name")?;
            let tag = r.u8("array element type")?;
            let width = tag_width(tag)
                .ok_or_else(|| r.corrupt(format!("array {i} ('{name}') has unknown element type {tag}")))?;
            let len = r.usize("array length")?;
            payload = len
                .checked_mul(width)
                .and_then(|b| b.checked_add(payload))
                .ok_or_else(|| r.corrupt(format!("array '{name}' length {len} overflows")))?;
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
        Ok(Self { kind, fields, arrays, source: path.to_path_buf() })
    }

    /// The kind and fields of the artifact at `path`, read from its first bytes (at most
    /// [`PEEK_BYTES`]) without its arrays: for listing large files (a cache of transfer
    /// matrices) without reading them. The checksum covers the whole file, so what this
    /// returns is unverified; [`Self::load`] checks everything.
    pub fn peek(path: &Path) -> Result<(String, BTreeMap<String, Field>), ArtifactError> {
        use std::io::Read;
        let io = |source| ArtifactError::Io { path: path.to_path_buf(), source };
        let mut bytes = vec![];
        crate::io::open_regular(path).map_err(io)?.0.take(PEEK_BYTES).read_to_end(&mut bytes).map_err(io)?;
        let p = || path.to_path_buf();
        if bytes.len() < PREAMBLE || bytes[..MAGIC.len()] != MAGIC {
            if let Some((_, what)) = OLD_MAGICS.iter().find(|(m, _)| bytes.starts_with(&m[..])) {
                return Err(ArtifactError::OldFormat { path: p(), what });
            }
            return Err(ArtifactError::WrongMagic { path: p() });
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
        if version != CONTAINER_VERSION {
            return Err(ArtifactError::WrongVersion { path: p(), found: version, supported: CONTAINER_VERSION });
        }
        Reader { bytes: &bytes, at: PREAMBLE, path }.kind_and_fields()
    }

    /// An error naming the file unless this is an artifact of `kind`.
    pub fn expect_kind(&self, kind: &str) -> Result<(), ArtifactError> {
        if self.kind != kind {
            return Err(self.corrupt(format!("holds a {} where a {kind} was expected", self.kind)));
        }
        Ok(())
    }

    /// A [`ArtifactError::Corrupt`] naming this artifact's file.
    pub fn corrupt(&self, what: impl Into<String>) -> ArtifactError {
        ArtifactError::Corrupt { path: self.source.clone(), what: what.into() }
    }

    fn field(&self, name: &str) -> Result<&Field, ArtifactError> {
        self.fields.get(name).ok_or_else(|| self.corrupt(format!("no field '{name}'")))
    }

    /// The u64 field `name`.
    pub fn u64(&self, name: &str) -> Result<u64, ArtifactError> {
        match self.field(name)? {
            Field::U64(v) => Ok(*v),
            _ => Err(self.corrupt(format!("field '{name}' is not an integer"))),
        }
    }

    /// The u64 field `name` as a usize.
    pub fn usize(&self, name: &str) -> Result<usize, ArtifactError> {
        let v = self.u64(name)?;
        usize::try_from(v).map_err(|_| self.corrupt(format!("field '{name}' = {v} does not fit this machine")))
    }

    /// The f64 field `name`.
    pub fn f64(&self, name: &str) -> Result<f64, ArtifactError> {
        match self.field(name)? {
            Field::F64(v) => Ok(*v),
            _ => Err(self.corrupt(format!("field '{name}' is not a float"))),
        }
    }

    /// The string field `name`.
    pub fn str(&self, name: &str) -> Result<&str, ArtifactError> {
        match self.field(name)? {
            Field::Str(s) => Ok(s),
            _ => Err(self.corrupt(format!("field '{name}' is not a string"))),
        }
    }

    /// Record a transfer shape (fields `vertices`, `local_basis`, `light_basis`, the bases as
    /// their tags such as `bins:8` and `cubemap:32`).
    pub fn with_shape(self, shape: TransferShape) -> Self {
        self.with("vertices", Field::U64(shape.vertices as u64))
            .with("local_basis", Field::Str(shape.local.tag()))
            .with("light_basis", Field::Str(shape.light.tag()))
    }

    /// The shape recorded by [`Self::with_shape`]. Its row count must fit a u32 (every gather
    /// indexes rows with one), so a corrupt vertex count cannot ask for a huge `L*`.
    pub fn shape(&self) -> Result<TransferShape, ArtifactError> {
        let local = LocalBasis::parse(self.str("local_basis")?).map_err(|e| self.corrupt(e.to_string()))?;
        let light = LightBasis::parse(self.str("light_basis")?).map_err(|e| self.corrupt(e.to_string()))?;
        let vertices = self.usize("vertices")?;
        match vertices.checked_mul(local.len()) {
            Some(rows) if rows <= u32::MAX as usize => Ok(TransferShape::new(vertices, local, light)),
            _ => Err(self.corrupt(format!("{vertices} vertices of {local} exceed 2^32 rows"))),
        }
    }

    /// Take the array `name` out of the artifact.
    pub fn take_array(&mut self, name: &str) -> Result<ArrayData, ArtifactError> {
        let i = self
            .arrays
            .iter()
            .position(|a| a.name == name)
            .ok_or_else(|| self.corrupt(format!("no array '{name}'")))?;
        Ok(self.arrays.remove(i).data)
    }
}

/// A bounds-checked reader over the file's bytes.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    /// The kind and the fields, which follow the preamble.
    fn kind_and_fields(&mut self) -> Result<(String, BTreeMap<String, Field>), ArtifactError> {
        let kind = self.string("kind")?;
        let nfields = self.count("field count", 4 + 1 + 4)?;
        let mut fields = BTreeMap::new();
        for _ in 0..nfields {
            let name = self.string("field name")?;
            let value = match self.u8("field type")? {
                0 => Field::U64(self.u64("field value")?),
                1 => Field::F64(f64::from_bits(self.u64("field value")?)),
                2 => Field::Str(self.string("field value")?),
                t => return Err(self.corrupt(format!("field '{name}' has unknown type {t}"))),
            };
            if fields.insert(name.clone(), value).is_some() {
                return Err(self.corrupt(format!("field '{name}' appears twice")));
            }
        }
        Ok((kind, fields))
    }
    fn corrupt(&self, what: impl Into<String>) -> ArtifactError {
        ArtifactError::Corrupt { path: self.path.to_path_buf(), what: what.into() }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], ArtifactError> {
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

    fn u8(&mut self, what: &str) -> Result<u8, ArtifactError> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, ArtifactError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn u64(&mut self, what: &str) -> Result<u64, ArtifactError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn usize(&mut self, what: &str) -> Result<usize, ArtifactError> {
        let v = self.u64(what)?;
        usize::try_from(v).map_err(|_| self.corrupt(format!("{what} {v} does not fit this machine")))
    }
    fn string(&mut self, what: &str) -> Result<String, ArtifactError> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        String::from_utf8(b.to_vec()).map_err(|_| self.corrupt(format!("{what} is not UTF-8")))
    }
    /// A count of items each at least `min_bytes` long, checked against what remains.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, ArtifactError> {
        let n = self.u32(what)? as usize;
        if n.saturating_mul(min_bytes) > self.bytes.len() - self.at {
            return Err(self.corrupt(format!("{what} {n} cannot fit in the {} bytes left", self.bytes.len() - self.at)));
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Artifact {
        Artifact::new("probe")
            .with("count", Field::U64(u64::MAX))
            .with("seconds", Field::F64(0.1 + 0.2))
            .with("basis", Field::Str("bins:8".into()))
            .with_array("a_u8", ArrayData::U8(vec![0, 1, 255]))
            .with_array("a_i8", ArrayData::I8(vec![-128, -1, 0, 127]))
            .with_array("a_u16", ArrayData::U16(vec![0, 65535, 1234]))
            .with_array("a_i16", ArrayData::I16(vec![i16::MIN, -7, i16::MAX]))
            .with_array("a_u32", ArrayData::U32(vec![u32::MAX, 0, 42]))
            .with_array("empty", ArrayData::F32(vec![]))
            .with_array("a_f32", ArrayData::F32(vec![-0.0, 1.5e-42, f32::MAX, f32::INFINITY, 0.1]))
    }

    #[test]
    fn round_trip_every_field_and_array_type() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bsf");
        let a = sample();
        a.save(&path).unwrap();
        let back = Artifact::load(&path).unwrap();
        assert_eq!(Artifact { source: PathBuf::new(), ..back.clone() }, a);
        assert_eq!(back.f64("seconds").unwrap().to_bits(), (0.1f64 + 0.2).to_bits());
        assert_eq!((back.u64("count").unwrap(), back.str("basis").unwrap()), (u64::MAX, "bins:8"));
        assert!(back.str("count").is_err() && back.u64("nope").is_err());
        back.expect_kind("probe").unwrap();
        assert!(back.expect_kind("form").unwrap_err().to_string().contains("a.bsf"));
        // Nothing but the file is left behind; overwriting works.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        Artifact::new("other").save(&path).unwrap();
        assert_eq!(Artifact::load(&path).unwrap().kind, "other");
    }

    #[test]
    fn extra_fields_are_stored_beside_the_artifacts_own() {
        let a = sample();
        let mut extra = BTreeMap::new();
        extra.insert("cache.key".to_string(), Field::Str("00ff".into()));
        extra.insert("count".to_string(), Field::U64(7));
        let back = Artifact::decode(&a.encode_with(&extra), Path::new("x")).unwrap();
        assert_eq!(back.str("cache.key").unwrap(), "00ff");
        // An extra field of the same name wins; every other field and array is unchanged.
        assert_eq!(back.u64("count").unwrap(), 7);
        assert_eq!(back.arrays, a.arrays);
        assert_eq!(back.fields.len(), a.fields.len() + 1);
        // No extras: exactly the plain encoding.
        assert_eq!(a.encode_with(&BTreeMap::new()), a.encode());
    }

    #[test]
    fn corrupt_files_are_clear_errors() {
        let path = Path::new("/some/dir/a.bsf");
        let good = sample().encode();
        let msg = |e: ArtifactError| {
            let s = e.to_string();
            assert!(s.contains("a.bsf"), "error does not name the file: {s}");
            s
        };
        let mut b = good.clone();
        b[0] = b'X';
        assert!(matches!(Artifact::decode(&b, path), Err(ArtifactError::WrongMagic { .. })));
        assert!(matches!(Artifact::decode(b"", path), Err(ArtifactError::WrongMagic { .. })));
        // Files of the formats version 2 replaced.
        for old in [&b"BSCFORM\0\x01\0\0\0"[..], &b"BSCBTF\0\0\x01\0\0\0"[..]] {
            let e = Artifact::decode(old, path).unwrap_err();
            assert!(matches!(e, ArtifactError::OldFormat { .. }), "{e}");
            assert!(msg(e).contains("earlier biscale"));
        }
        let mut b = good.clone();
        b[8..12].copy_from_slice(&7u32.to_le_bytes());
        let e = Artifact::decode(&b, path).unwrap_err();
        assert!(matches!(e, ArtifactError::WrongVersion { found: 7, supported: 2, .. }));
        msg(e);
        for cut in [9, 15, 30, good.len() / 2, good.len() - 1] {
            let e = Artifact::decode(&good[..cut], path).unwrap_err();
            assert!(matches!(e, ArtifactError::Truncated { .. }), "cut {cut}: {e}");
            msg(e);
        }
        let mut b = good.clone();
        b.push(0);
        assert!(matches!(Artifact::decode(&b, path), Err(ArtifactError::Truncated { .. })));
        for at in [PREAMBLE, PREAMBLE + 5, good.len() / 2, good.len() - 5, good.len() - 1] {
            let mut b = good.clone();
            b[at] ^= 0x10;
            let e = Artifact::decode(&b, path).unwrap_err();
            assert!(matches!(e, ArtifactError::Checksum { .. }), "byte {at}: {e}");
            assert!(msg(e).contains("corrupt"));
        }
        let e = Artifact::load(Path::new("/nonexistent/dir/f.bsf")).unwrap_err();
        assert!(matches!(e, ArtifactError::Io { .. }) && e.to_string().contains("f.bsf"));
    }

    /// A file with a valid checksum but lying lengths (as a buggy writer could make) must fail
    /// cleanly without allocating what the lengths claim.
    #[test]
    fn lying_lengths_with_valid_checksum_are_errors() {
        let path = Path::new("lie.bsf");
        let reseal = |mut b: Vec<u8>| {
            let n = b.len() - CRC_BYTES;
            let crc = crc32fast::hash(&b[..n]);
            b[n..].copy_from_slice(&crc.to_le_bytes());
            b
        };
        let good = sample().encode();
        // The kind string's length claims 4 GiB.
        let mut b = good.clone();
        b[PREAMBLE..PREAMBLE + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(Artifact::decode(&reseal(b), path), Err(ArtifactError::Corrupt { .. })));
        // The first array's length claims u64::MAX elements: find its length field.
        let a = sample();
        let mut at = PREAMBLE + 4 + a.kind.len() + 4;
        for (name, value) in &a.fields {
            at += 4
                + name.len()
                + 1
                + match value {
                    Field::Str(s) => 4 + s.len(),
                    _ => 8,
                };
        }
        at += 4 + 4 + a.arrays[0].name.len() + 1;
        let mut b = good.clone();
        assert_eq!(u64::from_le_bytes(b[at..at + 8].try_into().unwrap()), 3);
        b[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(matches!(Artifact::decode(&reseal(b), path), Err(ArtifactError::Corrupt { .. })));
        // One element more than the payload holds.
        let mut b = good.clone();
        b[at..at + 8].copy_from_slice(&4u64.to_le_bytes());
        assert!(matches!(Artifact::decode(&reseal(b), path), Err(ArtifactError::Corrupt { .. })));
        // Unknown element type.
        let mut b = good;
        b[at - 1] = 9;
        let e = Artifact::decode(&reseal(b), path).unwrap_err();
        assert!(e.to_string().contains("unknown element type 9"), "{e}");
    }

    fn shape() -> TransferShape {
        TransferShape::new(3, LocalBasis::bins(2).unwrap(), LightBasis::cubemap(2).unwrap())
    }

    #[test]
    fn forms_round_trip_with_meta_and_stats() {
        use crate::compress::CompressedForm;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bsf");
        let mut f = CompressedForm::new("bicluster", shape())
            .with_array("z_last", ArrayData::U16(vec![1, 2]))
            .with_array("a_first", ArrayData::F32(vec![0.5]));
        f.meta = BTreeMap::from([("value_scale".into(), 4), ("big".into(), u64::MAX)]);
        f.lossless = true;
        f.flops_per_gather = 123_456_789_012;
        f.build_seconds = 0.1 + 0.2;
        f.save(&path).unwrap();
        let back = CompressedForm::load(&path).unwrap();
        assert_eq!(back, f, "array order, meta, stats and shape survive");
        // A transfer file is not a form, and the error says so naming the file.
        let e = CompressedForm::from_artifact(Artifact::new("transfer").with_shape(shape())).unwrap_err();
        assert!(matches!(e, ArtifactError::Corrupt { .. }) && e.to_string().contains("form was expected"), "{e}");
        let bad = f.to_artifact().with("lossless", Field::U64(2));
        assert!(CompressedForm::from_artifact(bad).unwrap_err().to_string().contains("lossless"));
        let bad = f.to_artifact().with("meta.x", Field::Str("1".into()));
        assert!(CompressedForm::from_artifact(bad).unwrap_err().to_string().contains("meta.x"));
        // A vertex count whose rows overflow is refused before anything is sized by it.
        let huge = f.to_artifact().with("vertices", Field::U64(u64::MAX / 2));
        assert!(CompressedForm::from_artifact(huge).unwrap_err().to_string().contains("2^32 rows"));
        let tag = f.to_artifact().with("local_basis", Field::Str("bins:0".into()));
        assert!(matches!(CompressedForm::from_artifact(tag), Err(ArtifactError::Corrupt { .. })));
    }

    #[test]
    fn transfer_matrices_round_trip_and_bad_csr_is_an_error() {
        use crate::transfer::TransferMatrix;
        let s = shape();
        let mut tri = sprs::TriMat::new((s.rows(), s.cols()));
        for (r, c, v) in [(0, 0, 0.25f32), (0, 23, 1.0), (5, 7, 0.5), (11, 23, 0.75)] {
            tri.add_triplet(r, c, v);
        }
        let t = TransferMatrix::new(s.local, s.light, tri.to_csr()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.bsf");
        t.save(&path).unwrap();
        assert_eq!(TransferMatrix::load(&path).unwrap(), t);
        // Arrays that are no CSR matrix of the recorded shape (checksum valid): errors naming it.
        let a = Artifact::load(&path).unwrap();
        let with = |name: &str, data: ArrayData| {
            let mut b = a.clone();
            b.arrays.iter_mut().find(|x| x.name == name).unwrap().data = data;
            b.save(&path).unwrap();
            TransferMatrix::load(&path).unwrap_err()
        };
        let e = with("row_ptr", ArrayData::U32(vec![0, 2, 1, 3, 3, 3, 3, 4, 4, 4, 4, 4, 4]));
        assert!(matches!(e, ArtifactError::Corrupt { .. }) && e.to_string().contains("t.bsf"), "{e}");
        let e = with("col", ArrayData::U16(vec![0, 23, 7, 24]));
        assert!(e.to_string().contains("CSR"), "{e}");
        let e = with("values", ArrayData::F32(vec![0.25, f32::NAN, 0.5, 0.75]));
        assert!(e.to_string().contains("not finite"), "{e}");
        let e = with("col", ArrayData::U32(vec![0, 23, 7, 23]));
        assert!(e.to_string().contains("u16"), "{e}");
        let mut b = a.clone();
        b.kind = "form".into();
        b.save(&path).unwrap();
        assert!(TransferMatrix::load(&path).unwrap_err().to_string().contains("transfer was expected"));
    }
}
