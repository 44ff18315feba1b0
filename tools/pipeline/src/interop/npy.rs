//! NumPy's file formats, written and read without Python: `.npy` (one array) and `.npz` (a
//! zip archive of `.npy` files, what `numpy.savez` writes), for `biscale export` and
//! `biscale eval` (`crate::interop`).
//!
//! * **`.npy`** (format 1.0, or 2.0 when the header passes 64 KiB): the magic `\x93NUMPY`, the
//!   version, a little-endian header length, and a Python dict literal
//!   `{'descr': '<f4', 'fortran_order': False, 'shape': (3, 4), }` padded with spaces to a
//!   multiple of 64 bytes and ended by a newline; then the elements in C order. We write
//!   little-endian numbers (`|u1 |i1 <u2 <i2 <u4 <i4 <u8 <i8 <f4 <f8`) and 0-d Unicode strings
//!   (`<Un`, UTF-32), and read those plus big-endian and native byte orders, booleans (as
//!   `u8`), byte strings (`|Sn`), format versions 1 to 3 and Fortran-ordered arrays
//!   (reordered to C order).
//! * **`.npz`**: a zip archive, member `name.npy` per array, through the `zip` crate. We write
//!   stored (uncompressed) members with a fixed timestamp, system and permissions, so equal
//!   arrays give equal files, and ZIP64 records only where a size or an offset passes 4 GiB;
//!   we read stored and deflated members (what `numpy.savez_compressed` writes) with or
//!   without ZIP64 (`numpy.savez` always writes ZIP64 extra fields), checking every CRC, and
//!   check the archive as a whole before inflating anything ([`read_npz`]).
//!
//! Every read is bounds-checked: a truncated or inconsistent file is an [`NpyError`] naming
//! the file, the member and what is wrong, never a panic. The `.npy` codec is our own because
//! of that: the crate for it (npyz 0.9) parses the header dict with a grammar whose time nearly
//! doubles with each nested bracket (25 levels, a 120-byte header, take over a minute) and
//! panics on a shape whose element count overflows.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Why a NumPy file could not be written or read; each names the file (and the member of an
/// archive).
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// The file is not what it should be: `what` says what is wrong and where.
    #[error("{}: {what}", path.display())]
    Format { path: PathBuf, what: String },
    /// Refused before writing (a path that holds what biscale did not write), or an encoder
    /// failure while writing.
    #[error(transparent)]
    Core(#[from] biscale_core::CoreError),
}

fn format_err(path: &Path, what: impl Into<String>) -> NpyError {
    NpyError::Format { path: path.to_path_buf(), what: what.into() }
}

/// An array's elements, owned.
#[derive(Clone, Debug, PartialEq)]
pub enum NpyData {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    I32(Vec<i32>),
    U64(Vec<u64>),
    I64(Vec<i64>),
    F32(Vec<f32>),
    F64(Vec<f64>),
    /// A 0-d string (`<Un` or `|Sn`).
    Str(String),
}

/// An array read from a file: its shape (C order) and its elements.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: NpyData,
}

/// An array's elements, borrowed (what is written).
#[derive(Clone, Copy, Debug)]
pub enum Elements<'a> {
    U8(&'a [u8]),
    I8(&'a [i8]),
    U16(&'a [u16]),
    I16(&'a [i16]),
    U32(&'a [u32]),
    I32(&'a [i32]),
    U64(&'a [u64]),
    I64(&'a [i64]),
    F32(&'a [f32]),
    F64(&'a [f64]),
    Str(&'a str),
}

/// One array to write: its shape and its elements in C order.
#[derive(Clone, Debug)]
pub struct ArrayRef<'a> {
    pub shape: Vec<usize>,
    pub elements: Elements<'a>,
}

impl<'a> ArrayRef<'a> {
    /// An array of `shape` (its elements must fill it: checked when written).
    pub fn new(shape: &[usize], elements: Elements<'a>) -> Self {
        Self { shape: shape.to_vec(), elements }
    }

    /// A 1-d array of every element.
    pub fn flat(elements: Elements<'a>) -> Self {
        let n = match elements {
            Elements::Str(_) => return Self { shape: vec![], elements },
            e => e.len(),
        };
        Self { shape: vec![n], elements }
    }

    /// A 0-d Unicode string (`numpy.array("...")`).
    pub fn string(s: &'a str) -> Self {
        Self { shape: vec![], elements: Elements::Str(s) }
    }
}

/// A compressed form's array as elements to write, at its own width.
impl<'a> From<&'a biscale_core::compress::ArrayData> for Elements<'a> {
    fn from(data: &'a biscale_core::compress::ArrayData) -> Self {
        use biscale_core::compress::ArrayData;
        match data {
            ArrayData::U8(v) => Elements::U8(v),
            ArrayData::I8(v) => Elements::I8(v),
            ArrayData::U16(v) => Elements::U16(v),
            ArrayData::I16(v) => Elements::I16(v),
            ArrayData::U32(v) => Elements::U32(v),
            ArrayData::F32(v) => Elements::F32(v),
        }
    }
}

impl Elements<'_> {
    /// Number of elements (1 for a string).
    pub fn len(&self) -> usize {
        match self {
            Elements::U8(v) => v.len(),
            Elements::I8(v) => v.len(),
            Elements::U16(v) => v.len(),
            Elements::I16(v) => v.len(),
            Elements::U32(v) => v.len(),
            Elements::I32(v) => v.len(),
            Elements::U64(v) => v.len(),
            Elements::I64(v) => v.len(),
            Elements::F32(v) => v.len(),
            Elements::F64(v) => v.len(),
            Elements::Str(_) => 1,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// NumPy's type string (`<f4`, ...).
    fn descr(&self) -> String {
        match self {
            Elements::U8(_) => "|u1".into(),
            Elements::I8(_) => "|i1".into(),
            Elements::U16(_) => "<u2".into(),
            Elements::I16(_) => "<i2".into(),
            Elements::U32(_) => "<u4".into(),
            Elements::I32(_) => "<i4".into(),
            Elements::U64(_) => "<u8".into(),
            Elements::I64(_) => "<i8".into(),
            Elements::F32(_) => "<f4".into(),
            Elements::F64(_) => "<f8".into(),
            Elements::Str(s) => format!("<U{}", s.chars().count().max(1)),
        }
    }

    /// Bytes of the elements as stored.
    fn data_bytes(&self) -> u64 {
        let width = match self {
            Elements::U8(_) | Elements::I8(_) => 1,
            Elements::U16(_) | Elements::I16(_) => 2,
            Elements::U32(_) | Elements::I32(_) | Elements::F32(_) => 4,
            Elements::U64(_) | Elements::I64(_) | Elements::F64(_) => 8,
            Elements::Str(s) => return 4 * s.chars().count().max(1) as u64,
        };
        width * self.len() as u64
    }

    /// Write the elements, little-endian, in chunks.
    fn write_to(&self, w: &mut dyn Write) -> std::io::Result<()> {
        fn chunks<T: Copy, const B: usize>(
            v: &[T],
            w: &mut dyn Write,
            le: impl Fn(T) -> [u8; B],
        ) -> std::io::Result<()> {
            let mut buf = Vec::with_capacity(B * 8192);
            for c in v.chunks(8192) {
                buf.clear();
                for &x in c {
                    buf.extend_from_slice(&le(x));
                }
                w.write_all(&buf)?;
            }
            Ok(())
        }
        match *self {
            Elements::U8(v) => w.write_all(v),
            Elements::I8(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::U16(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::I16(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::U32(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::I32(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::U64(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::I64(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::F32(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::F64(v) => chunks(v, w, |x| x.to_le_bytes()),
            Elements::Str(s) => {
                let mut units: Vec<u32> = s.chars().map(u32::from).collect();
                if units.is_empty() {
                    units.push(0);
                }
                chunks(&units, w, |x| x.to_le_bytes())
            }
        }
    }
}

impl NpyData {
    /// The borrowed elements.
    pub fn elements(&self) -> Elements<'_> {
        match self {
            NpyData::U8(v) => Elements::U8(v),
            NpyData::I8(v) => Elements::I8(v),
            NpyData::U16(v) => Elements::U16(v),
            NpyData::I16(v) => Elements::I16(v),
            NpyData::U32(v) => Elements::U32(v),
            NpyData::I32(v) => Elements::I32(v),
            NpyData::U64(v) => Elements::U64(v),
            NpyData::I64(v) => Elements::I64(v),
            NpyData::F32(v) => Elements::F32(v),
            NpyData::F64(v) => Elements::F64(v),
            NpyData::Str(s) => Elements::Str(s),
        }
    }

    /// NumPy's name of the element type (`float32`, `uint16`, `str`, ...), for messages.
    pub fn dtype_name(&self) -> &'static str {
        match self {
            NpyData::U8(_) => "uint8",
            NpyData::I8(_) => "int8",
            NpyData::U16(_) => "uint16",
            NpyData::I16(_) => "int16",
            NpyData::U32(_) => "uint32",
            NpyData::I32(_) => "int32",
            NpyData::U64(_) => "uint64",
            NpyData::I64(_) => "int64",
            NpyData::F32(_) => "float32",
            NpyData::F64(_) => "float64",
            NpyData::Str(_) => "str",
        }
    }

    /// Number of elements (1 for a string).
    pub fn len(&self) -> usize {
        self.elements().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl NpyArray {
    /// The shape as NumPy prints it: `(3,)`, `(2, 3)`, `()`.
    pub fn shape_text(&self) -> String {
        shape_text(&self.shape)
    }

    /// The array viewed for writing.
    pub fn as_ref(&self) -> ArrayRef<'_> {
        ArrayRef { shape: self.shape.clone(), elements: self.data.elements() }
    }
}

/// A shape as NumPy prints it.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        s => format!("({})", s.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")),
    }
}

/// The `.npy` header of `a` (magic, version, length, dict, padding): format 1.0 unless the
/// dict needs more than 64 KiB.
fn npy_header(a: &ArrayRef<'_>) -> Vec<u8> {
    let shape = match a.shape.as_slice() {
        [n] => format!("({n},)"),
        s => format!("({})", s.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")),
    };
    let dict = format!("{{'descr': '{}', 'fortran_order': False, 'shape': {shape}, }}", a.elements.descr());
    // Magic (6) + version (2) + length (2 or 4) + dict + padding + '\n', a multiple of 64.
    let (version, len_bytes) = if dict.len() + 11 < 65536 { (1u8, 2) } else { (2u8, 4) };
    let unpadded = 6 + 2 + len_bytes + dict.len() + 1;
    let total = unpadded.div_ceil(64) * 64;
    let header_len = total - 6 - 2 - len_bytes;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"\x93NUMPY");
    out.extend_from_slice(&[version, 0]);
    match version {
        1 => out.extend_from_slice(&(header_len as u16).to_le_bytes()),
        _ => out.extend_from_slice(&(header_len as u32).to_le_bytes()),
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(total - 1, b' ');
    out.push(b'\n');
    out
}

fn check_fills(a: &ArrayRef<'_>, name: &str, path: &Path) -> Result<(), NpyError> {
    let count = a.shape.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
    let wanted = match a.elements {
        Elements::Str(_) if a.shape.is_empty() => 1,
        Elements::Str(_) => return Err(format_err(path, format!("array '{name}': a string array must be 0-d"))),
        e => e.len(),
    };
    if count != Some(wanted) {
        return Err(format_err(
            path,
            format!("array '{name}': shape {} does not hold its {wanted} elements", shape_text(&a.shape)),
        ));
    }
    Ok(())
}

/// Write one array as a `.npy` file, atomically (a temporary file, then a rename).
pub fn write_npy(path: &Path, a: &ArrayRef<'_>) -> Result<(), NpyError> {
    check_fills(a, "array", path)?;
    let header = npy_header(a);
    biscale_core::io::write_atomic(path, |f| {
        f.write_all(&header).and_then(|()| a.elements.write_to(f)).map_err(|e| e.to_string())
    })
    .map_err(|e| format_err(path, e.to_string()))
}

/// Write `members` (name without `.npy`, array) as a `.npz` archive, atomically. Names must
/// be plain (`[A-Za-z0-9_.-]`, not empty) and distinct.
pub fn write_npz(path: &Path, members: &[(&str, ArrayRef<'_>)]) -> Result<(), NpyError> {
    write_npz_with(path, members, false)
}

/// [`write_npz`], with ZIP64 records for every member when `force_zip64` (tests reach the
/// ZIP64 path this way without writing 4 GiB).
pub fn write_npz_with(path: &Path, members: &[(&str, ArrayRef<'_>)], force_zip64: bool) -> Result<(), NpyError> {
    write_npz_at(path, members, force_zip64, None)
}

/// [`write_npz`] at a path a user names (Python's `Form.save`): a new file, or a `.npz`
/// biscale wrote (its archive comment is biscale's mark), a user's regular file only with
/// `force`, never a link, device, FIFO or folder ([`biscale_core::io::write_single_file`]).
pub fn write_npz_single(path: &Path, members: &[(&str, ArrayRef<'_>)], force: bool) -> Result<(), NpyError> {
    write_npz_at(path, members, false, Some(force))
}

/// [`write_npz_with`] into a folder biscale owns (`single: None`: replaced atomically) or
/// at a path a user names (`Some(force)`).
fn write_npz_at(
    path: &Path,
    members: &[(&str, ArrayRef<'_>)],
    force_zip64: bool,
    single: Option<bool>,
) -> Result<(), NpyError> {
    for (i, (name, a)) in members.iter().enumerate() {
        let plain = !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || "_.-".contains(c));
        if !plain {
            return Err(format_err(path, format!("array name {name:?}: only letters, digits, '_', '.' and '-'")));
        }
        if members[..i].iter().any(|(n, _)| n == name) {
            return Err(format_err(path, format!("two arrays are called '{name}'")));
        }
        check_fills(a, name, path)?;
    }
    let write =
        |f: &mut std::io::BufWriter<std::fs::File>| write_zip(f, members, force_zip64).map_err(|e| e.to_string());
    Ok(match single {
        None => biscale_core::io::write_atomic(path, write),
        Some(force) => biscale_core::io::write_single_file(path, biscale_core::io::FileMark::Zip, force, write),
    }?)
}

/// The archive: one stored member per array, in the given order, and biscale's mark
/// ([`biscale_core::io::MARK_TEXT`]) as the archive comment. Every field the `zip` crate
/// would otherwise take from the clock or the host (time, system, permissions) is fixed, so
/// equal arrays give equal files on every machine.
fn write_zip<W: Write + Seek>(f: W, members: &[(&str, ArrayRef<'_>)], force_zip64: bool) -> zip::result::ZipResult<()> {
    let mut zip = zip::ZipWriter::new(f);
    zip.set_comment(biscale_core::io::MARK_TEXT)?;
    for (name, a) in members {
        let header = npy_header(a);
        let size = header.len() as u64 + a.elements.data_bytes();
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .last_modified_time(zip::DateTime::default())
            .system(zip::System::Unix)
            .unix_permissions(0o644)
            .large_file(force_zip64 || size >= zip::ZIP64_BYTES_THR);
        zip.start_file(format!("{name}.npy"), options)?;
        zip.write_all(&header)?;
        a.elements.write_to(&mut zip)?;
    }
    zip.finish()?;
    Ok(())
}

/// Read a `.npy` file (a regular file only: a device or FIFO is refused, not read without end).
pub fn read_npy(path: &Path) -> Result<NpyArray, NpyError> {
    read_npy_within(path, MAX_INFLATED_BYTES)
}

/// [`read_npy`] of a file the caller expects to hold at most `limit` bytes (an `L*` of the
/// config's shape): a larger one is refused before it is read.
pub fn read_npy_within(path: &Path, limit: u64) -> Result<NpyArray, NpyError> {
    let bytes = biscale_core::io::read_regular(path, limit, ".npy array of the expected shape")
        .map_err(|source| NpyError::Io { path: path.into(), source })?;
    parse_npy(&bytes).map_err(|what| format_err(path, what))
}

/// Read every array of a `.npz` file, in the archive's order, named without `.npy`. A crafted
/// archive (two members of one name or over one member's bytes, more bytes declared than there
/// is memory for) is refused before anything is inflated.
pub fn read_npz(path: &Path) -> Result<Vec<(String, NpyArray)>, NpyError> {
    read_npz_within(path, MAX_INFLATED_BYTES)
}

/// [`read_npz`] of an archive the caller expects to hold at most `limit` bytes of arrays in
/// all (an `L*` of the config's shape, say): members that declare more are refused before
/// anything is inflated, and so is a member whose directory entry disagrees with its own
/// `.npy` header (read first, from the member's first bytes).
pub fn read_npz_within(path: &Path, limit: u64) -> Result<Vec<(String, NpyArray)>, NpyError> {
    let (file, _) =
        biscale_core::io::open_regular(path).map_err(|source| NpyError::Io { path: path.into(), source })?;
    let members = zip_members(std::io::BufReader::new(file), limit)
        .map_err(|what| format_err(path, format!("not a readable .npz archive: {what}")))?;
    let mut out = vec![];
    for (name, data) in members {
        let Some(stem) = name.strip_suffix(".npy") else {
            return Err(format_err(path, format!("member '{name}' is not a .npy file")));
        };
        let array = parse_npy(&data).map_err(|what| format_err(path, format!("array '{stem}': {what}")))?;
        out.push((stem.to_string(), array));
    }
    Ok(out)
}

/// A little-endian reader over a byte slice whose every read is bounds-checked.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn at(bytes: &'a [u8], pos: usize) -> Self {
        Self { bytes, pos }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| format!("truncated: needs {n} bytes at offset {}", self.pos))?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().expect("2 bytes")))
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
}

fn to_usize(x: u64, what: &str) -> Result<usize, String> {
    usize::try_from(x).map_err(|_| format!("{what} {x} is too large"))
}

/// The most bytes the members of one `.npz` may declare in all (and never more than the
/// memory available, `estimate::available`).
const MAX_INFLATED_BYTES: u64 = 64 << 30;

/// The members of a zip archive (name, uncompressed bytes), in central-directory order.
///
/// The `zip` crate reads the container (end records, ZIP64, central directory, local headers)
/// and inflates, failing a member whose output passes its declared size or whose CRC-32 is
/// wrong. Before anything is inflated or allocated, the archive is checked as a whole here
/// (issue class "a 1.5 MB .npz makes eval allocate 1.5 GB"): names are unique (NumPy would
/// read the last of two), no two members' bytes overlap, only stored and deflated members, and
/// the sizes they declare fit in the memory there is. A member's buffer then grows as it
/// inflates, read through a `take` of its declared size (plus one byte, to see a longer one).
fn zip_members<R: Read + Seek>(reader: R, limit: u64) -> Result<Vec<(String, Vec<u8>)>, String> {
    let mut zip = zip::ZipArchive::new(reader).map_err(|e| e.to_string())?;
    if zip.has_duplicate_names() {
        let start = zip.central_directory_start();
        let name = first_repeated_name(zip.into_inner(), start).unwrap_or_else(|| "?".into());
        return Err(format!("member '{name}' appears twice (which one is meant is ambiguous)"));
    }
    let (mut names, mut declared) = (vec![], 0u64);
    for i in 0..zip.len() {
        let e = zip.by_index_data(i).map_err(|e| format!("central directory entry {i}: {e}"))?;
        let name = String::from_utf8_lossy(e.name_raw()).into_owned();
        if e.encrypted() {
            return Err(format!("member '{name}' is encrypted"));
        }
        match e.compression() {
            zip::CompressionMethod::Stored | zip::CompressionMethod::Deflated => {}
            m => return Err(format!("member '{name}': compression method {m} (only stored and deflate are read)")),
        }
        declared = declared.saturating_add(e.size());
        names.push(name);
    }
    let memory = MAX_INFLATED_BYTES.min(crate::estimate::available().map_or(MAX_INFLATED_BYTES, |a| a.bytes));
    if declared > memory {
        return Err(format!(
            "its members declare {declared} bytes in all ({:.2} GB) where {memory} bytes are available to read them \
             into: refused before inflating",
            declared as f64 / 1e9
        ));
    }
    if declared > limit {
        return Err(format!(
            "its members declare {declared} bytes in all, more than the {limit} bytes the arrays it should hold \
             take: refused before inflating"
        ));
    }
    // Each member's bytes, local header to end of data (its local header read, nothing
    // inflated): two entries over one member's bytes are a crafted archive.
    let mut spans = vec![];
    for (i, name) in names.iter().enumerate() {
        let file = zip.by_index_raw(i).map_err(|e| format!("member '{name}': {e}"))?;
        let start = file.header_start();
        let end = file.data_start().unwrap_or(start).saturating_add(file.compressed_size());
        spans.push((start, end, name));
    }
    spans.sort();
    if let Some(w) = spans.windows(2).find(|w| w[1].0 < w[0].1) {
        return Err(format!("member '{}' shares its bytes with member '{}' (a crafted archive)", w[1].2, w[0].2));
    }
    let mut out = vec![];
    for (i, name) in names.iter().enumerate() {
        let mut file = zip.by_index(i).map_err(|e| format!("member '{name}': {e}"))?;
        let expected = file.size();
        // The member's own .npy header first: its shape and dtype fix the member's size, and a
        // directory entry that claims more than that is refused before the rest is inflated.
        let mut data = npy_head(&mut file, expected).map_err(|e| format!("member '{name}': {e}"))?;
        data.reserve(to_usize(expected.min(1 << 26), "size")?.saturating_sub(data.len()));
        (&mut file)
            .take((expected + 1).saturating_sub(data.len() as u64))
            .read_to_end(&mut data)
            .map_err(|e| format!("member '{name}': {e}"))?;
        if data.len() as u64 != expected {
            return Err(format!("member '{name}' holds {} bytes, its directory entry says {expected}", data.len()));
        }
        out.push((name.clone(), data));
    }
    Ok(out)
}

/// Where the header text of the `.npy` file `bytes` starts and how long it is, after its magic
/// and version (the first 10 bytes suffice for version 1, 12 for versions 2 and 3).
fn header_span(bytes: &[u8]) -> Result<(usize, usize), String> {
    let mut c = Cursor::at(bytes, 0);
    if c.take(6).ok() != Some(b"\x93NUMPY".as_slice()) {
        return Err("not a .npy file (no \\x93NUMPY magic)".into());
    }
    let version = c.take(2)?;
    let header_len = match version[0] {
        1 => c.u16()? as usize,
        2 | 3 => to_usize(c.u32()? as u64, "header length")?,
        v => return Err(format!(".npy format version {v}.{} is not supported", version[1])),
    };
    Ok((c.pos, header_len))
}

/// The first bytes of a `.npy` member of `declared` bytes, through its header, after checking
/// that the header's shape and dtype need exactly `declared` bytes (a member that is not a
/// `.npy` is returned as read so far, for the caller's own error).
fn npy_head(r: &mut impl Read, declared: u64) -> Result<Vec<u8>, String> {
    // 12 bytes hold the preamble of every version; a shorter member or one that is not a
    // `.npy` goes back as read, for `parse_npy`'s own error.
    let mut head = vec![0u8; 12.min(declared as usize)];
    r.read_exact(&mut head).map_err(|e| e.to_string())?;
    let Ok((start, header_len)) = header_span(&head) else { return Ok(head) };
    let end = start as u64 + header_len as u64;
    if end > declared.min(1 << 20) {
        return Err(format!("its .npy header of {header_len} bytes does not fit the member's {declared} bytes"));
    }
    // (A header shorter than what was read already ends inside it: nothing more to read.)
    let (read, end) = (head.len(), end as usize);
    if end > read {
        head.resize(end, 0);
        r.read_exact(&mut head[read..]).map_err(|e| e.to_string())?;
    }
    let text = std::str::from_utf8(&head[start..end]).map_err(|_| "the header is not text".to_string())?;
    let h = parse_header(text)?;
    let (_, width, _) = parse_descr(&h.descr)?;
    let needed =
        h.shape.iter().try_fold(width as u64, |a, &n| a.checked_mul(n as u64)).and_then(|n| n.checked_add(end as u64));
    if needed != Some(declared) {
        return Err(format!(
            "its directory entry says {declared} bytes, its .npy header (shape {} of '{}') needs {}: refused before \
             inflating",
            shape_text(&h.shape),
            h.descr,
            needed.map_or("more than 2^64".to_string(), |n| n.to_string())
        ));
    }
    Ok(head)
}

/// The first name the central directory at `start` lists twice, for the error message alone
/// (`ZipArchive` keeps one entry per name). `None` where the walk finds none.
fn first_repeated_name<R: Read + Seek>(mut r: R, start: u64) -> Option<String> {
    r.seek(SeekFrom::Start(start)).ok()?;
    let mut seen = std::collections::BTreeSet::new();
    loop {
        let mut fixed = [0u8; 46];
        r.read_exact(&mut fixed).ok()?;
        if fixed[..4] != 0x0201_4b50u32.to_le_bytes() {
            return None;
        }
        let len = |at: usize| u16::from_le_bytes([fixed[at], fixed[at + 1]]);
        let mut name = vec![0; len(28).into()];
        r.read_exact(&mut name).ok()?;
        let name = String::from_utf8_lossy(&name).into_owned();
        if !seen.insert(name.clone()) {
            return Some(name);
        }
        r.seek(SeekFrom::Current(i64::from(len(30)) + i64::from(len(32)))).ok()?;
    }
}

/// The element type of a `descr`: (kind letter, byte width, big-endian).
fn parse_descr(descr: &str) -> Result<(char, usize, bool), String> {
    let bad = || format!("unsupported dtype '{descr}'");
    let mut chars = descr.chars();
    let (order, rest) = match chars.next() {
        Some(c @ ('<' | '>' | '|' | '=')) => (c, chars.as_str()),
        _ => ('=', descr),
    };
    let mut rest_chars = rest.chars();
    let kind = rest_chars.next().ok_or_else(bad)?;
    let width: usize = rest_chars.as_str().parse().map_err(|_| bad())?;
    let big = order == '>' || (order == '=' && cfg!(target_endian = "big"));
    match (kind, width) {
        ('u' | 'i', 1 | 2 | 4 | 8) | ('f', 4 | 8) | ('b', 1) => Ok((kind, width, big)),
        ('U', n) => Ok(('U', n.checked_mul(4).ok_or_else(bad)?, big)),
        ('S', n) => Ok(('S', n, big)),
        _ => Err(bad()),
    }
}

/// The header dict's three entries.
struct Header {
    descr: String,
    fortran_order: bool,
    shape: Vec<usize>,
}

/// Parse the Python dict literal of a `.npy` header (the subset NumPy writes).
fn parse_header(text: &str) -> Result<Header, String> {
    let bad = |what: &str| format!("header {text:?}: {what}");
    let s = text.trim().trim_end_matches('\n').trim();
    let inner = s.strip_prefix('{').and_then(|s| s.trim_end().strip_suffix('}')).ok_or_else(|| bad("not a dict"))?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    let mut rest = inner.trim_start();
    while !rest.is_empty() {
        let quote =
            rest.chars().next().filter(|c| *c == '\'' || *c == '"').ok_or_else(|| bad("a key is not a string"))?;
        let end = rest[1..].find(quote).ok_or_else(|| bad("unterminated key"))? + 1;
        let key = &rest[1..end];
        rest = rest[end + 1..].trim_start().strip_prefix(':').ok_or_else(|| bad("no ':' after a key"))?.trim_start();
        match key {
            "descr" => {
                let q =
                    rest.chars().next().filter(|c| *c == '\'' || *c == '"').ok_or_else(|| {
                        bad("'descr' is not a plain type string (structured dtypes are not supported)")
                    })?;
                let end = rest[1..].find(q).ok_or_else(|| bad("unterminated 'descr'"))? + 1;
                descr = Some(rest[1..end].to_string());
                rest = &rest[end + 1..];
            }
            "fortran_order" => {
                let (value, after) = if let Some(r) = rest.strip_prefix("True") {
                    (true, r)
                } else if let Some(r) = rest.strip_prefix("False") {
                    (false, r)
                } else {
                    return Err(bad("'fortran_order' is not True or False"));
                };
                fortran = Some(value);
                rest = after;
            }
            "shape" => {
                let open = rest.strip_prefix('(').ok_or_else(|| bad("'shape' is not a tuple"))?;
                let close = open.find(')').ok_or_else(|| bad("unterminated 'shape'"))?;
                let dims = open[..close]
                    .split(',')
                    .map(str::trim)
                    .filter(|d| !d.is_empty())
                    .map(|d| d.trim_end_matches('L').parse::<usize>().map_err(|_| bad("a dimension is not a size")))
                    .collect::<Result<Vec<_>, _>>()?;
                shape = Some(dims);
                rest = &open[close + 1..];
            }
            other => return Err(bad(&format!("unknown key '{other}'"))),
        }
        rest = rest.trim_start();
        rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
    }
    Ok(Header {
        descr: descr.ok_or_else(|| bad("no 'descr'"))?,
        fortran_order: fortran.ok_or_else(|| bad("no 'fortran_order'"))?,
        shape: shape.ok_or_else(|| bad("no 'shape'"))?,
    })
}

/// Parse a whole `.npy` file held in memory.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    let (start, header_len) = header_span(bytes)?;
    let mut c = Cursor::at(bytes, start);
    let text = std::str::from_utf8(c.take(header_len)?).map_err(|_| "the header is not text".to_string())?;
    let h = parse_header(text)?;
    let (kind, width, big) = parse_descr(&h.descr)?;
    let count = h.shape.iter().try_fold(1usize, |a, &n| a.checked_mul(n)).ok_or("the shape overflows")?;
    let data = &bytes[c.pos..];
    let needed = count.checked_mul(width).ok_or("the shape overflows")?;
    if data.len() != needed {
        return Err(format!(
            "holds {} bytes of data, shape {} of '{}' needs {needed}",
            data.len(),
            shape_text(&h.shape),
            h.descr
        ));
    }
    fn read<T, const B: usize>(data: &[u8], big: bool, f: impl Fn([u8; B]) -> T) -> Vec<T> {
        data.chunks_exact(B)
            .map(|c| {
                let mut b: [u8; B] = c.try_into().expect("chunk of B");
                if big {
                    b.reverse();
                }
                f(b)
            })
            .collect()
    }
    let mut out = match (kind, width) {
        ('u' | 'b', 1) => NpyData::U8(data.to_vec()),
        ('i', 1) => NpyData::I8(data.iter().map(|&b| b as i8).collect()),
        ('u', 2) => NpyData::U16(read(data, big, u16::from_le_bytes)),
        ('i', 2) => NpyData::I16(read(data, big, i16::from_le_bytes)),
        ('u', 4) => NpyData::U32(read(data, big, u32::from_le_bytes)),
        ('i', 4) => NpyData::I32(read(data, big, i32::from_le_bytes)),
        ('u', 8) => NpyData::U64(read(data, big, u64::from_le_bytes)),
        ('i', 8) => NpyData::I64(read(data, big, i64::from_le_bytes)),
        ('f', 4) => NpyData::F32(read(data, big, f32::from_le_bytes)),
        ('f', 8) => NpyData::F64(read(data, big, f64::from_le_bytes)),
        ('U' | 'S', _) if count != 1 => {
            return Err(format!("a string array of shape {} (only single strings are read)", shape_text(&h.shape)))
        }
        ('U', _) => {
            let units = read(data, big, u32::from_le_bytes);
            let s: Option<String> = units.into_iter().take_while(|&u| u != 0).map(char::from_u32).collect();
            NpyData::Str(s.ok_or("the string is not valid UTF-32")?)
        }
        ('S', _) => {
            let end = data.iter().position(|&b| b == 0).unwrap_or(data.len());
            NpyData::Str(String::from_utf8(data[..end].to_vec()).map_err(|_| "the byte string is not UTF-8")?)
        }
        _ => return Err(format!("unsupported dtype '{}'", h.descr)),
    };
    if h.fortran_order && h.shape.len() > 1 {
        out = to_c_order(out, &h.shape);
    }
    Ok(NpyArray { shape: h.shape, data: out })
}

/// Elements stored in Fortran (column-major) order, reordered to C order.
fn to_c_order(data: NpyData, shape: &[usize]) -> NpyData {
    fn reorder<T: Copy>(v: Vec<T>, shape: &[usize]) -> Vec<T> {
        // Fortran strides: the first axis is contiguous.
        let mut strides = vec![1usize; shape.len()];
        for a in 1..shape.len() {
            strides[a] = strides[a - 1] * shape[a - 1];
        }
        let mut index = vec![0usize; shape.len()];
        let mut out = Vec::with_capacity(v.len());
        for _ in 0..v.len() {
            out.push(v[index.iter().zip(&strides).map(|(i, s)| i * s).sum::<usize>()]);
            // Next C-order index: the last axis fastest.
            for a in (0..shape.len()).rev() {
                index[a] += 1;
                if index[a] < shape[a] {
                    break;
                }
                index[a] = 0;
            }
        }
        out
    }
    match data {
        NpyData::U8(v) => NpyData::U8(reorder(v, shape)),
        NpyData::I8(v) => NpyData::I8(reorder(v, shape)),
        NpyData::U16(v) => NpyData::U16(reorder(v, shape)),
        NpyData::I16(v) => NpyData::I16(reorder(v, shape)),
        NpyData::U32(v) => NpyData::U32(reorder(v, shape)),
        NpyData::I32(v) => NpyData::I32(reorder(v, shape)),
        NpyData::U64(v) => NpyData::U64(reorder(v, shape)),
        NpyData::I64(v) => NpyData::I64(reorder(v, shape)),
        NpyData::F32(v) => NpyData::F32(reorder(v, shape)),
        NpyData::F64(v) => NpyData::F64(reorder(v, shape)),
        s @ NpyData::Str(_) => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<(String, NpyArray)> {
        let a = |shape: &[usize], data| NpyArray { shape: shape.to_vec(), data };
        vec![
            ("u8".into(), a(&[3], NpyData::U8(vec![0, 7, 255]))),
            ("i8".into(), a(&[2], NpyData::I8(vec![-128, 127]))),
            ("u16".into(), a(&[1, 2], NpyData::U16(vec![1, 65535]))),
            ("i16".into(), a(&[2, 1], NpyData::I16(vec![-2, 3]))),
            ("u32".into(), a(&[0], NpyData::U32(vec![]))),
            ("i32".into(), a(&[2], NpyData::I32(vec![i32::MIN, 5]))),
            ("u64".into(), a(&[1], NpyData::U64(vec![u64::MAX]))),
            ("i64".into(), a(&[2], NpyData::I64(vec![-1, i64::MAX]))),
            ("f32".into(), a(&[2, 2, 1], NpyData::F32(vec![1.5, -0.0, f32::MIN_POSITIVE, 3e38]))),
            ("f64".into(), a(&[], NpyData::F64(vec![std::f64::consts::PI]))),
            ("meta".into(), a(&[], NpyData::Str("{\"a\": \"é ✓\"}".into()))),
        ]
    }

    fn crc_of(bytes: &[u8]) -> u32 {
        let mut crc = flate2::Crc::new();
        crc.update(bytes);
        crc.sum()
    }

    fn deflate(bytes: &[u8]) -> Vec<u8> {
        let mut enc = flate2::write::DeflateEncoder::new(vec![], flate2::Compression::default());
        enc.write_all(bytes).unwrap();
        enc.finish().unwrap()
    }

    /// A member of an archive built by hand, independently of the `zip` crate: method 0
    /// (stored) or 8 (deflated), and the CRC and size its headers declare.
    struct Hand<'a> {
        name: &'a [u8],
        method: u16,
        crc: u32,
        packed: &'a [u8],
        size: u32,
    }

    /// A member's local header and data.
    fn local(m: &Hand<'_>) -> Vec<u8> {
        let mut b = 0x0403_4b50u32.to_le_bytes().to_vec();
        b.extend_from_slice(&[20, 0, 0, 0]);
        b.extend_from_slice(&m.method.to_le_bytes());
        b.extend_from_slice(&[0, 0, 0, 0]);
        b.extend_from_slice(&m.crc.to_le_bytes());
        b.extend_from_slice(&(m.packed.len() as u32).to_le_bytes());
        b.extend_from_slice(&m.size.to_le_bytes());
        b.extend_from_slice(&(m.name.len() as u16).to_le_bytes());
        b.extend_from_slice(&0u16.to_le_bytes());
        b.extend_from_slice(m.name);
        b.extend_from_slice(m.packed);
        b
    }

    /// A zip archive of `members` (local headers back to back, then the central directory);
    /// `at[i]`, where given, is the local header offset member `i`'s directory entry claims.
    fn hand_zip(members: &[Hand<'_>], at: &[Option<u32>]) -> Vec<u8> {
        let mut zip = vec![];
        let mut offsets = vec![];
        for (m, at) in members.iter().zip(at) {
            offsets.push(at.unwrap_or(zip.len() as u32));
            zip.extend_from_slice(&local(m));
        }
        let cd = zip.len() as u32;
        for (m, offset) in members.iter().zip(offsets) {
            zip.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
            zip.extend_from_slice(&[20, 0, 20, 0, 0, 0]);
            zip.extend_from_slice(&m.method.to_le_bytes());
            zip.extend_from_slice(&[0, 0, 0, 0]);
            zip.extend_from_slice(&m.crc.to_le_bytes());
            zip.extend_from_slice(&(m.packed.len() as u32).to_le_bytes());
            zip.extend_from_slice(&m.size.to_le_bytes());
            zip.extend_from_slice(&(m.name.len() as u16).to_le_bytes());
            zip.extend_from_slice(&[0u8; 12]);
            zip.extend_from_slice(&offset.to_le_bytes());
            zip.extend_from_slice(m.name);
        }
        let cd_size = zip.len() as u32 - cd;
        let n = (members.len() as u16).to_le_bytes();
        zip.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
        zip.extend_from_slice(&[0, 0, 0, 0, n[0], n[1], n[0], n[1]]);
        zip.extend_from_slice(&cd_size.to_le_bytes());
        zip.extend_from_slice(&cd.to_le_bytes());
        zip.extend_from_slice(&0u16.to_le_bytes());
        zip
    }

    #[test]
    fn npz_round_trips_every_type_with_and_without_zip64() {
        let dir = tempfile::tempdir().unwrap();
        for zip64 in [false, true] {
            let path = dir.path().join(format!("x{zip64}.npz"));
            let arrays = sample();
            let members: Vec<(&str, ArrayRef<'_>)> = arrays.iter().map(|(n, a)| (n.as_str(), a.as_ref())).collect();
            write_npz_with(&path, &members, zip64).unwrap();
            assert_eq!(read_npz(&path).unwrap(), arrays);
        }
        // Stored, with fixed timestamps: equal arrays, equal files.
        let again = dir.path().join("again.npz");
        let arrays = sample();
        let members: Vec<(&str, ArrayRef<'_>)> = arrays.iter().map(|(n, a)| (n.as_str(), a.as_ref())).collect();
        write_npz(&again, &members).unwrap();
        assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(dir.path().join("xfalse.npz")).unwrap());
    }

    #[test]
    fn npy_headers_are_aligned_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        for (name, a) in sample() {
            let path = dir.path().join(format!("{name}.npy"));
            write_npy(&path, &a.as_ref()).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
            assert_eq!((10 + header_len) % 64, 0, "{name}");
            assert_eq!(bytes[9 + header_len], b'\n');
            assert_eq!(read_npy(&path).unwrap(), a, "{name}");
        }
    }

    #[test]
    fn fortran_order_big_endian_and_deflate_are_read() {
        // (2, 3) float64 [[0, 1, 2], [3, 4, 5]] stored column-major: 0 3 1 4 2 5.
        let dict = "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16 + 1).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.push(b'\n');
        for x in [0.0f64, 3.0, 1.0, 4.0, 2.0, 5.0] {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
        let a = parse_npy(&bytes).unwrap();
        assert_eq!((a.shape.as_slice(), a.data), (&[2usize, 3][..], NpyData::F64(vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0])));
        let dict = "{'descr': '>u2', 'fortran_order': False, 'shape': (2,), }";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16 + 1).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.extend_from_slice(b"\n\x01\x02\x00\x03");
        assert_eq!(parse_npy(&bytes).unwrap().data, NpyData::U16(vec![0x0102, 3]));
        // A deflated member, as numpy.savez_compressed writes.
        let payload = {
            let dir = tempfile::tempdir().unwrap();
            let p = dir.path().join("a.npy");
            write_npy(&p, &ArrayRef::flat(Elements::F32(&[1.0, 2.0, 3.0]))).unwrap();
            std::fs::read(p).unwrap()
        };
        let packed = deflate(&payload);
        let a = Hand { name: b"a.npy", method: 8, crc: crc_of(&payload), packed: &packed, size: payload.len() as u32 };
        let zip = hand_zip(&[a], &[None]);
        let members_of = |bytes: &[u8]| zip_members(std::io::Cursor::new(bytes.to_vec()), MAX_INFLATED_BYTES);
        let members = members_of(&zip).unwrap();
        assert_eq!(members, vec![("a.npy".to_string(), payload)]);
        // A flipped byte is a CRC error, a cut file a located error, never a panic.
        let mut bad = zip.clone();
        bad[40] ^= 0xff;
        assert!(members_of(&bad).is_err());
        for cut in [0, 10, 30, zip.len() - 30, zip.len() - 1] {
            assert!(members_of(&zip[..cut]).is_err(), "{cut}");
        }
    }

    /// Issue class "a 1.5 MB .npz makes eval allocate 1.5 GB": two entries of one name, two
    /// entries over one member's bytes, and a member declaring a terabyte are refused from
    /// the central directory, before anything is inflated or allocated.
    /// A deflated member is bounded twice before it is inflated: by what its own `.npy` header
    /// says it holds (a member whose directory size disagrees is refused) and by what the caller
    /// expects the archive to hold (`read_npz_within`: an `L*` of the config's shape). A small
    /// file that inflates to far more than either is refused; its header is parsed from at most
    /// the preamble and the header itself, whatever their length (a zero-length header too).
    #[test]
    fn deflated_members_are_bounded_by_their_header_and_the_callers_shape() {
        use std::io::Write as _;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.npz");
        let member = |header: &[u8], data_len: usize| {
            let mut zip = zip::ZipWriter::new(std::fs::File::create(&p).unwrap());
            let opts = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
            zip.start_file("lstar.npy", opts).unwrap();
            zip.write_all(header).unwrap();
            zip.write_all(&vec![0u8; data_len]).unwrap();
            zip.finish().unwrap();
        };
        let ten_mb = 10 << 20;
        let header = npy_header(&ArrayRef::new(&[ten_mb], Elements::U8(&vec![0u8; ten_mb])));
        // Honest: 10 MB of zeros, a few kilobytes on disk.
        member(&header, ten_mb);
        assert!(std::fs::metadata(&p).unwrap().len() < 100_000);
        assert_eq!(read_npz(&p).unwrap()[0].1.data.len(), ten_mb);
        let e = read_npz_within(&p, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("more than the 1048576 bytes") && e.contains("refused before inflating"), "{e}");
        // Lying: the header says 3 bytes, the directory 10 MB.
        let small = npy_header(&ArrayRef::new(&[3], Elements::U8(&[0, 0, 0])));
        member(&small, ten_mb);
        let e = read_npz(&p).unwrap_err().to_string();
        assert!(e.contains("its .npy header (shape (3,) of '|u1') needs") && e.contains("refused before"), "{e}");
        // A version-1 preamble declaring a zero-length header: an error, not a panic.
        member(b"\x93NUMPY\x01\x00\x00\x00abcd", 0);
        assert!(read_npz(&p).is_err());
    }

    #[test]
    fn crafted_archives_are_refused_before_inflating() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.npz");
        let one = [1u8, 2, 3];
        let good = |zip64: bool| {
            let members = [("a", ArrayRef::flat(Elements::U8(&one))), ("b", ArrayRef::flat(Elements::U8(&one)))];
            write_npz_with(&p, &members, zip64).unwrap();
            std::fs::read(&p).unwrap()
        };
        // The central-directory entry of `b.npy`: the last place its name stands, less the
        // entry's fixed 46 bytes.
        let entry_of_b = |bytes: &[u8]| bytes.windows(5).rposition(|w| w == b"b.npy").unwrap() - 46;
        let read = |bytes: Vec<u8>| {
            std::fs::write(&p, bytes).unwrap();
            read_npz(&p).unwrap_err().to_string()
        };
        assert_eq!(
            read_npz(&{
                std::fs::write(&p, good(false)).unwrap();
                p.clone()
            })
            .unwrap()
            .len(),
            2
        );

        let mut twice = good(false);
        let at = entry_of_b(&twice) + 46;
        twice[at] = b'a';
        let e = read(twice);
        assert!(e.contains("member 'a.npy' appears twice"), "{e}");

        let mut shared = good(false);
        let at = entry_of_b(&shared) + 42;
        shared[at..at + 4].copy_from_slice(&0u32.to_le_bytes());
        let e = read(shared);
        assert!(e.contains("shares its bytes"), "{e}");

        // ZIP64: the extra field's first value is the uncompressed size.
        let mut huge = good(true);
        let at = entry_of_b(&huge) + 46 + 5 + 4;
        huge[at..at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let e = read(huge);
        assert!(e.contains("refused before inflating") && e.contains("x.npz"), "{e}");
    }

    /// A member inside another member's bytes (the overlapping-files zip bomb), a deflated
    /// member that inflates past its declared size, and one shorter than it: errors that name
    /// the member, with buffers bounded by the declared sizes.
    #[test]
    fn overlapping_and_lying_members_are_refused() {
        let members_of = |bytes: &[u8]| zip_members(std::io::Cursor::new(bytes.to_vec()), MAX_INFLATED_BYTES);
        let payload = b"the inner member".as_slice();
        let b = Hand { name: b"b.npy", method: 0, crc: crc_of(payload), packed: payload, size: payload.len() as u32 };
        let inner = local(&b);
        let a = Hand { name: b"a.npy", method: 0, crc: crc_of(&inner), packed: &inner, size: inner.len() as u32 };
        // Each member is whole and its CRC right; b's directory entry points into a's data.
        let nested = hand_zip(&[a, b], &[None, Some(30 + 5)]);
        let e = members_of(&nested).unwrap_err();
        assert!(e.contains("member 'b.npy' shares its bytes with member 'a.npy'"), "{e}");

        let zeros = vec![0u8; 1 << 22];
        let packed = deflate(&zeros);
        let bomb = Hand { name: b"a.npy", method: 8, crc: crc_of(&zeros), packed: &packed, size: 1000 };
        let e = members_of(&hand_zip(&[bomb], &[None])).unwrap_err();
        assert!(e.starts_with("member 'a.npy'") && e.contains("declared"), "{e}");

        let short = Hand { name: b"a.npy", method: 0, crc: crc_of(payload), packed: payload, size: 1000 };
        let e = members_of(&hand_zip(&[short], &[None])).unwrap_err();
        assert!(e.contains("member 'a.npy' holds 16 bytes, its directory entry says 1000"), "{e}");
    }

    /// Hostile bytes (a written archive, flipped, overwritten with extreme values, cut) are
    /// an error or an archive, never a panic; through `read_npz` every error names the file.
    #[test]
    fn mangled_archives_are_errors_never_panics() {
        let dir = tempfile::tempdir().unwrap();
        let arrays = sample();
        let members: Vec<(&str, ArrayRef<'_>)> = arrays.iter().map(|(n, a)| (n.as_str(), a.as_ref())).collect();
        let mut seeds = vec![];
        for zip64 in [false, true] {
            let p = dir.path().join("seed.npz");
            write_npz_with(&p, &members[..3], zip64).unwrap();
            seeds.push(std::fs::read(&p).unwrap());
        }
        let payload = b"\x93NUMPY".as_slice();
        let packed = deflate(payload);
        let a = Hand { name: b"a.npy", method: 8, crc: crc_of(payload), packed: &packed, size: payload.len() as u32 };
        seeds.push(hand_zip(&[a], &[None]));
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = |n: usize| {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) as usize % n.max(1)
        };
        let p = dir.path().join("x.npz");
        for round in 0..3000 {
            let mut bytes = seeds[round % seeds.len()].clone();
            for _ in 0..1 + next(3) {
                if bytes.is_empty() {
                    break;
                }
                // Half the time in the central directory and end records, at the end.
                let at = if next(2) == 0 { bytes.len().saturating_sub(1 + next(400)) } else { next(bytes.len()) };
                match next(4) {
                    0 => bytes[at] ^= 1 << next(8),
                    1 => bytes[at] = [0, 0xff, 0x7f, 0x80][next(4)],
                    2 => {
                        let value = [0u32, 0xffff_ffff, 0x7fff_ffff, 1 << 20][next(4)].to_le_bytes();
                        let end = (at + 4).min(bytes.len());
                        bytes[at..end].copy_from_slice(&value[..end - at]);
                    }
                    _ => bytes.truncate(at),
                }
            }
            match zip_members(std::io::Cursor::new(bytes.clone()), MAX_INFLATED_BYTES) {
                Ok(members) => members.iter().for_each(|(_, data)| drop(parse_npy(data))),
                Err(e) => assert!(!e.is_empty()),
            }
            if round % 10 == 0 {
                std::fs::write(&p, &bytes).unwrap();
                if let Err(e) = read_npz(&p) {
                    assert!(e.to_string().contains("x.npz"), "{e}");
                }
            }
        }
    }

    /// The bytes of a small archive, pinned: equal arrays give equal files on every machine
    /// and with every version of the `zip` crate (an upgrade that changes them changes what
    /// `export` writes, so this pin moves only on purpose).
    #[test]
    fn npz_bytes_are_pinned() {
        let dir = tempfile::tempdir().unwrap();
        let arrays = sample();
        let members: Vec<(&str, ArrayRef<'_>)> = arrays.iter().map(|(n, a)| (n.as_str(), a.as_ref())).collect();
        let mut pins = vec![];
        for zip64 in [false, true] {
            let p = dir.path().join("x.npz");
            write_npz_with(&p, &members, zip64).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            pins.push((bytes.len(), format!("{:08x}", crc_of(&bytes))));
        }
        // Moved on purpose: biscale's mark as the archive comment (18 bytes) since the
        // single-file writers recognise their own files by it.
        assert_eq!(pins, [(2553, "d300da02".to_string()), (2993, "7f49316c".to_string())]);
    }

    #[test]
    fn bad_files_and_names_are_errors() {
        assert!(parse_npy(b"nope").unwrap_err().contains("magic"));
        let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (4,), }\n";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.extend_from_slice(&[0; 12]);
        assert!(parse_npy(&bytes).unwrap_err().contains("holds 12 bytes of data, shape (4,) of '<f4' needs 16"));
        let dict = "{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (), }\n";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        assert!(parse_npy(&bytes).unwrap_err().contains("structured"));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.npz");
        let one = [1u8];
        let e = write_npz(&p, &[("a/b", ArrayRef::flat(Elements::U8(&one)))]).unwrap_err();
        assert!(e.to_string().contains("only letters"), "{e}");
        let e = write_npz(&p, &[("a", ArrayRef::new(&[2], Elements::U8(&one)))]).unwrap_err();
        assert!(e.to_string().contains("shape (2,) does not hold its 1 elements"), "{e}");
        assert!(!p.exists());
    }
}
