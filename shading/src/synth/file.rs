//! The BTF file: any [`Btf`] as one versioned, checksummed binary file, so a synthesized BTF
//! is computed once and cached, or shipped with a scene.
//!
//! Layout (all integers little-endian, floats IEEE):
//!
//! ```text
//! magic        8 bytes  b"BSCBTF\0\0"
//! version      u32      BTF_FORMAT_VERSION
//! total_len    u64      length of the whole file (catches truncation first)
//! header:
//!   width, height       u32 each    spatial texels (1..=4096 each)
//!   light_m             u32         light grid side (1..=256)
//!   view_m              u32         view grid side (1..=256), 0 = no view axis
//!   encoding            u8          0 = f32, 1 = f16, 2 = u8 with per-texel scale
//!   name                u32 length (<= 4096) + UTF-8 bytes
//! payload      the table data[(texel * V + view) * M + light][channel], in that order:
//!   f32: 3 f32 per entry;  f16: 3 IEEE half floats per entry;
//!   u8:  one f32 scale per texel (the texel's largest value), then 3 bytes per entry,
//!        value = byte / 255 * scale
//! crc32        u32      CRC-32 (IEEE) of every byte before it
//! ```
//!
//! Accuracy of the encodings. f16 keeps 11 significant bits (relative error <= 2^-11 = 4.9e-4
//! for values above 6.1e-5, absolute 3e-8 below); u8 rounds to 1/510 of the texel's largest
//! value, so small values in a texel with a bright specular peak lose relative accuracy.
//! Measured on a 64x64 x 12x12 x 8x8 Phong BTF of `bumps` (kd 0.3/0.2/0.1, ks 0.5/0.6/0.7,
//! n = 20; the `benchmark` test): f16 relative RMS error 2.1e-4 (max 4.8e-4 of the texel's
//! maximum), 226 MB; u8 relative RMS error 1.1e-2 (max 2.0e-3 of the texel's maximum), 113 MB.
//! f16 is accurate enough for rendering; u8 is for previews and storage-bound experiments.
//!
//! Writes are atomic ([`biscale_core::io::write_atomic`]). Loading checks the size, magic, version
//! and declared length before reading the rest, so a truncated or huge-claiming file never
//! causes a large allocation; then the checksum; then every value is decoded and checked
//! finite. Every error names the file.

use crate::error::{Result, ShadingError};
use biscale_core::basis::LocalBasis;
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::Btf;
use biscale_core::Rgb;
use half::f16;
use std::io::Read;
use std::path::Path;

/// First eight bytes of every BTF file.
pub const BTF_MAGIC: [u8; 8] = *b"BSCBTF\0\0";
/// The format version this code writes and reads.
pub const BTF_FORMAT_VERSION: u32 = 1;
const PREAMBLE: usize = 8 + 4 + 8;
const FIXED_HEADER: usize = 4 * 4 + 1 + 4;
const MAX_NAME: usize = 4096;
const MAX_SPATIAL: u32 = 4096;

/// How a BTF file stores its values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BtfEncoding {
    /// 4 bytes per channel, lossless.
    F32,
    /// IEEE half floats: 2 bytes per channel, relative error <= 4.9e-4.
    F16,
    /// 1 byte per channel with a per-texel f32 scale: error <= 0.2% of the texel's maximum.
    U8,
}

impl BtfEncoding {
    /// `f32`, `f16` or `u8` (config and report names).
    pub fn name(self) -> &'static str {
        match self {
            BtfEncoding::F32 => "f32",
            BtfEncoding::F16 => "f16",
            BtfEncoding::U8 => "u8",
        }
    }

    /// Inverse of [`Self::name`].
    pub fn from_name(name: &str) -> Result<Self> {
        [BtfEncoding::F32, BtfEncoding::F16, BtfEncoding::U8]
            .into_iter()
            .find(|e| e.name() == name)
            .ok_or_else(|| ShadingError::Invalid(format!("unknown BTF encoding '{name}' (expected f32, f16 or u8)")))
    }

    fn tag(self) -> u8 {
        match self {
            BtfEncoding::F32 => 0,
            BtfEncoding::F16 => 1,
            BtfEncoding::U8 => 2,
        }
    }

    fn from_tag(tag: u8) -> Option<Self> {
        match tag {
            0 => Some(BtfEncoding::F32),
            1 => Some(BtfEncoding::F16),
            2 => Some(BtfEncoding::U8),
            _ => None,
        }
    }

    /// Payload bytes for `texels` texels of `entries` table entries in all.
    fn payload_len(self, texels: u128, entries: u128) -> u128 {
        match self {
            BtfEncoding::F32 => entries * 12,
            BtfEncoding::F16 => entries * 6,
            BtfEncoding::U8 => texels * 4 + entries * 3,
        }
    }
}

/// Encode `btf` as the bytes of a BTF file (see the module docs). Errors:
/// values that f16 cannot hold (above 65504), negative values with the u8 encoding, a name
/// longer than 4096 bytes.
pub fn encode_btf(btf: &Btf, encoding: BtfEncoding) -> Result<Vec<u8>> {
    if btf.name().len() > MAX_NAME {
        return Err(ShadingError::Invalid(format!(
            "BTF name is {} bytes, at most {MAX_NAME} are stored",
            btf.name().len()
        )));
    }
    if btf.spatial().iter().any(|&s| s > MAX_SPATIAL) {
        return Err(ShadingError::Invalid(format!(
            "BTF '{}': {:?} texels exceeds {MAX_SPATIAL} per side",
            btf.name(),
            btf.spatial()
        )));
    }
    let texels = btf.texel_count();
    let total = PREAMBLE
        + FIXED_HEADER
        + btf.name().len()
        + encoding.payload_len(texels as u128, btf.data().len() as u128) as usize
        + 4;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&BTF_MAGIC);
    out.extend_from_slice(&BTF_FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(total as u64).to_le_bytes());
    let light_m = btf
        .local_basis()
        .grid()
        .map(|g| g.m)
        .ok_or_else(|| ShadingError::Invalid(format!("BTF '{}': only bin bases have a file format", btf.name())))?;
    for v in [btf.spatial()[0], btf.spatial()[1], light_m, btf.view_grid().map_or(0, |g| g.m)] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.push(encoding.tag());
    out.extend_from_slice(&(btf.name().len() as u32).to_le_bytes());
    out.extend_from_slice(btf.name().as_bytes());
    match encoding {
        BtfEncoding::F32 => {
            for c in btf.data().iter().flatten() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        BtfEncoding::F16 => {
            for (i, c) in btf.data().iter().flatten().enumerate() {
                let h = f16::from_f32(*c);
                if !h.is_finite() {
                    return Err(ShadingError::Invalid(format!(
                        "BTF '{}': value {c} at entry {} does not fit f16 (max 65504); use f32",
                        btf.name(),
                        i / 3
                    )));
                }
                out.extend_from_slice(&h.to_bits().to_le_bytes());
            }
        }
        BtfEncoding::U8 => {
            if let Some(i) = btf.data().iter().flatten().position(|c| *c < 0.0) {
                return Err(ShadingError::Invalid(format!(
                    "BTF '{}': negative value at entry {}: the u8 encoding needs non-negative values",
                    btf.name(),
                    i / 3
                )));
            }
            let per = btf.data().len() / texels;
            let scales: Vec<f32> =
                btf.data().chunks(per).map(|t| t.iter().flatten().copied().fold(0.0f32, f32::max)).collect();
            for s in &scales {
                out.extend_from_slice(&s.to_le_bytes());
            }
            for (t, chunk) in btf.data().chunks(per).enumerate() {
                let s = scales[t];
                for c in chunk.iter().flatten() {
                    out.push(if s > 0.0 { (c / s * 255.0).round().clamp(0.0, 255.0) as u8 } else { 0 });
                }
            }
        }
    }
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    debug_assert_eq!(out.len(), total);
    Ok(out)
}

/// Write `btf` to `path` atomically (see the module docs).
pub fn save_btf(btf: &Btf, path: &Path, encoding: BtfEncoding) -> Result<()> {
    let bytes = encode_btf(btf, encoding)?;
    Ok(biscale_core::io::write_atomic_bytes(path, &bytes)?)
}

/// The parsed fixed part of a BTF file.
struct Header {
    spatial: [u32; 2],
    light_m: u32,
    view_m: u32,
    encoding: BtfEncoding,
    name: String,
    /// Offset of the payload.
    payload: usize,
    total: u64,
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

/// Parse and check the header from the first bytes of a file of `file_len` bytes.
fn parse_header(b: &[u8], file_len: u64, fail: &dyn Fn(String) -> ShadingError) -> Result<Header> {
    if b.len() < 8 || b[..8] != BTF_MAGIC {
        return Err(fail("not a BTF file (bad magic bytes)".into()));
    }
    if b.len() < PREAMBLE {
        return Err(fail(format!("truncated: only {} bytes", b.len())));
    }
    let version = le_u32(b, 8);
    if version != BTF_FORMAT_VERSION {
        return Err(fail(format!("BTF format version {version}, this build reads version {BTF_FORMAT_VERSION}")));
    }
    let total = u64::from_le_bytes(b[12..20].try_into().expect("8 bytes"));
    if total != file_len {
        return Err(fail(format!("truncated or padded: the file has {file_len} bytes, its header says {total}")));
    }
    if b.len() < PREAMBLE + FIXED_HEADER {
        return Err(fail("truncated header".into()));
    }
    let h = PREAMBLE;
    let (w, ht, light_m, view_m) = (le_u32(b, h), le_u32(b, h + 4), le_u32(b, h + 8), le_u32(b, h + 12));
    let encoding =
        BtfEncoding::from_tag(b[h + 16]).ok_or_else(|| fail(format!("unknown encoding tag {}", b[h + 16])))?;
    let name_len = le_u32(b, h + 17) as usize;
    if !(1..=MAX_SPATIAL).contains(&w) || !(1..=MAX_SPATIAL).contains(&ht) {
        return Err(fail(format!("corrupt header: spatial size {w}x{ht}")));
    }
    if !(1..=256).contains(&light_m) || view_m > 256 {
        return Err(fail(format!("corrupt header: light grid {light_m}, view grid {view_m}")));
    }
    if name_len > MAX_NAME {
        return Err(fail(format!("corrupt header: name length {name_len}")));
    }
    let payload = PREAMBLE + FIXED_HEADER + name_len;
    if b.len() < payload {
        return Err(fail("truncated header (name)".into()));
    }
    let name = std::str::from_utf8(&b[PREAMBLE + FIXED_HEADER..payload])
        .map_err(|_| fail("corrupt header: name is not UTF-8".into()))?
        .to_string();
    let texels = w as u128 * ht as u128;
    let views = if view_m == 0 { 1 } else { view_m as u128 * view_m as u128 };
    let entries = texels * views * (light_m as u128 * light_m as u128);
    let expect = payload as u128 + encoding.payload_len(texels, entries) + 4;
    if expect != total as u128 {
        return Err(fail(format!(
            "corrupt header: {w}x{ht} texels, {view_m}^2 views, {light_m}^2 lights in {} need {expect} bytes, the file has {total}",
            encoding.name()
        )));
    }
    Ok(Header { spatial: [w, ht], light_m, view_m, encoding, name, payload, total })
}

/// Read a BTF file written by [`save_btf`] (see the module docs for the checks).
pub fn load_btf(path: &Path) -> Result<Btf> {
    let io = |source: std::io::Error| ShadingError::Io { path: path.into(), source };
    let fail = |message: String| ShadingError::File { path: path.into(), message };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let file_len = file.metadata().map_err(io)?.len();
    // The header is at most PREAMBLE + FIXED_HEADER + MAX_NAME bytes: read that much first.
    let head_len = file_len.min((PREAMBLE + FIXED_HEADER + MAX_NAME) as u64) as usize;
    let mut bytes = vec![0u8; head_len];
    file.read_exact(&mut bytes).map_err(io)?;
    let header = parse_header(&bytes, file_len, &fail)?;
    // The declared length matched the file's and the dimensions: read the rest.
    bytes.resize(header.total as usize, 0);
    file.read_exact(&mut bytes[head_len..]).map_err(io)?;
    decode_body(&bytes, header, &fail)
}

/// Decode a whole BTF file held in memory (what [`encode_btf`] returns), with the same checks
/// as [`load_btf`]; `source` names it in errors. Used to give a BTF exactly the values its
/// encoding stores, whether or not it went through a file.
pub fn decode_btf(bytes: &[u8], source: &Path) -> Result<Btf> {
    let fail = |message: String| ShadingError::File { path: source.into(), message };
    let header = parse_header(bytes, bytes.len() as u64, &fail)?;
    decode_body(&bytes[..header.total as usize], header, &fail)
}

fn decode_body(bytes: &[u8], header: Header, fail: &dyn Fn(String) -> ShadingError) -> Result<Btf> {
    let body = bytes.len() - 4;
    let stored = le_u32(bytes, body);
    let computed = crc32fast::hash(&bytes[..body]);
    if stored != computed {
        return Err(fail(format!(
            "checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupt"
        )));
    }
    let payload = &bytes[header.payload..body];
    let texels = header.spatial[0] as usize * header.spatial[1] as usize;
    let views = if header.view_m == 0 { 1 } else { (header.view_m * header.view_m) as usize };
    let entries = texels * views * (header.light_m * header.light_m) as usize;
    let data: Vec<Rgb> = match header.encoding {
        BtfEncoding::F32 => payload
            .chunks_exact(12)
            .map(|e| std::array::from_fn(|c| f32::from_le_bytes(e[4 * c..4 * c + 4].try_into().expect("4 bytes"))))
            .collect(),
        BtfEncoding::F16 => payload
            .chunks_exact(6)
            .map(|e| std::array::from_fn(|c| f16::from_bits(u16::from_le_bytes([e[2 * c], e[2 * c + 1]])).to_f32()))
            .collect(),
        BtfEncoding::U8 => {
            let (scales, codes) = payload.split_at(texels * 4);
            let per = entries / texels;
            let scales: Vec<f32> =
                scales.chunks_exact(4).map(|s| f32::from_le_bytes(s.try_into().expect("4 bytes"))).collect();
            if let Some(t) = scales.iter().position(|s| !(s.is_finite() && *s >= 0.0)) {
                return Err(fail(format!("corrupt: texel {t} has scale {}", scales[t])));
            }
            codes
                .chunks_exact(3)
                .enumerate()
                .map(|(i, e)| {
                    let s = scales[i / per];
                    std::array::from_fn(|c| e[c] as f32 / 255.0 * s)
                })
                .collect()
        }
    };
    debug_assert_eq!(data.len(), entries);
    if let Some(i) = data.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
        return Err(fail(format!("corrupt: non-finite value at entry {i}")));
    }
    let local = LocalBasis::bins(header.light_m).map_err(|e| fail(format!("corrupt: {e}")))?;
    let views = (header.view_m > 0).then(|| HemisphereGrid::new(header.view_m));
    Btf::new(header.spatial, local, views, data, header.name).map_err(|e| fail(e.to_string()))
}
