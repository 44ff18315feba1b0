//! The BTF file: any [`Btf`] as a biscale artifact ([`biscale_core::artifact`], kind `btf`), so
//! a synthesized BTF is computed once and cached, or shipped with a scene, in the same
//! checksummed container as `T` and the compressed forms.
//!
//! Fields: `name`, `width` and `height` (spatial texels, 1..=4096 each), `local_basis` (the
//! light bins' tag, `bins:8`), `view_grid` (view grid side, 0 = no view axis) and `encoding`
//! (`f32`, `f16`, `u8`). The table `data[(texel * V + view) * M + light][channel]` is stored in
//! that order as:
//!
//! ```text
//! f32:  values  f32, 3 per entry
//! f16:  values  u16, 3 IEEE half floats per entry
//! u8:   scales  f32, one per texel (the texel's largest value)
//!       codes   u8, 3 per entry, value = code / 255 * scale
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
//! The container checks length and checksum; this reader then checks the dimensions against
//! the arrays' lengths before building anything, and every decoded value for finiteness.
//! Every error names the file.

use crate::error::{Result, ShadingError};
use biscale_core::artifact::{Artifact, ArtifactError, Field};
use biscale_core::basis::LocalBasis;
use biscale_core::compress::ArrayData;
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::Btf;
use biscale_core::Rgb;
use half::f16;
use std::path::Path;

/// The artifact kind of a BTF.
pub const BTF_ARTIFACT: &str = "btf";
const MAX_NAME: usize = 4096;
const MAX_SPATIAL: u32 = 4096;
const MAX_VIEW_GRID: u32 = 256;

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
    /// Bytes per stored channel value (`u8` tables also store an f32 scale per texel).
    pub fn value_bytes(self) -> u64 {
        match self {
            BtfEncoding::F32 => 4,
            BtfEncoding::F16 => 2,
            BtfEncoding::U8 => 1,
        }
    }

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
}

/// `btf` as an artifact in `encoding` (see the module docs). Errors: values that f16 cannot
/// hold (above 65504), negative values with the u8 encoding, a name longer than 4096 bytes,
/// more than 4096 texels a side.
pub fn btf_artifact(btf: &Btf, encoding: BtfEncoding) -> Result<Artifact> {
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
    let a = Artifact::new(BTF_ARTIFACT)
        .with("name", Field::Str(btf.name().to_string()))
        .with("width", Field::U64(btf.spatial()[0] as u64))
        .with("height", Field::U64(btf.spatial()[1] as u64))
        .with("local_basis", Field::Str(btf.local_basis().tag()))
        .with("view_grid", Field::U64(btf.view_grid().map_or(0, |g| g.m as u64)))
        .with("encoding", Field::Str(encoding.name().into()));
    let values = || btf.data().iter().flatten();
    Ok(match encoding {
        BtfEncoding::F32 => a.with_array("values", ArrayData::F32(values().copied().collect())),
        BtfEncoding::F16 => {
            let mut bits = Vec::with_capacity(btf.data().len() * 3);
            for (i, c) in values().enumerate() {
                let h = f16::from_f32(*c);
                if !h.is_finite() {
                    return Err(ShadingError::Invalid(format!(
                        "BTF '{}': value {c} at entry {} does not fit f16 (max 65504); use f32",
                        btf.name(),
                        i / 3
                    )));
                }
                bits.push(h.to_bits());
            }
            a.with_array("values", ArrayData::U16(bits))
        }
        BtfEncoding::U8 => {
            if let Some(i) = values().position(|c| *c < 0.0) {
                return Err(ShadingError::Invalid(format!(
                    "BTF '{}': negative value at entry {}: the u8 encoding needs non-negative values",
                    btf.name(),
                    i / 3
                )));
            }
            let per = btf.data().len() / btf.texel_count();
            let scales: Vec<f32> =
                btf.data().chunks(per).map(|t| t.iter().flatten().copied().fold(0.0f32, f32::max)).collect();
            let mut codes = Vec::with_capacity(btf.data().len() * 3);
            for (t, chunk) in btf.data().chunks(per).enumerate() {
                let s = scales[t];
                codes.extend(chunk.iter().flatten().map(|c| {
                    if s > 0.0 {
                        (c / s * 255.0).round().clamp(0.0, 255.0) as u8
                    } else {
                        0
                    }
                }));
            }
            a.with_array("scales", ArrayData::F32(scales)).with_array("codes", ArrayData::U8(codes))
        }
    })
}

/// The bytes of `btf`'s file in `encoding` ([`btf_artifact`]).
pub fn encode_btf(btf: &Btf, encoding: BtfEncoding) -> Result<Vec<u8>> {
    Ok(btf_artifact(btf, encoding)?.encode())
}

/// Write `btf` to `path` atomically.
pub fn save_btf(btf: &Btf, path: &Path, encoding: BtfEncoding) -> Result<()> {
    Ok(btf_artifact(btf, encoding)?.save(path)?)
}

/// Read a BTF file written by [`save_btf`] (see the module docs for the checks).
pub fn load_btf(path: &Path) -> Result<Btf> {
    btf_from_artifact(Artifact::load(path)?)
}

/// Decode a whole BTF file held in memory (what [`encode_btf`] returns), with the same checks
/// as [`load_btf`]; `source` names it in errors. Used to give a BTF exactly the values its
/// encoding stores, whether or not it went through a file.
pub fn decode_btf(bytes: &[u8], source: &Path) -> Result<Btf> {
    btf_from_artifact(Artifact::decode(bytes, source)?)
}

/// The BTF an artifact holds.
pub fn btf_from_artifact(mut a: Artifact) -> Result<Btf> {
    a.expect_kind(BTF_ARTIFACT)?;
    let corrupt = |a: &Artifact, what: String| ShadingError::from(a.corrupt(what));
    let name = a.str("name")?.to_string();
    let (w, h, view_m) = (a.u64("width")?, a.u64("height")?, a.u64("view_grid")?);
    if !(1..=MAX_SPATIAL as u64).contains(&w) || !(1..=MAX_SPATIAL as u64).contains(&h) {
        return Err(corrupt(&a, format!("spatial size {w}x{h} (1..={MAX_SPATIAL} a side)")));
    }
    if view_m > MAX_VIEW_GRID as u64 {
        return Err(corrupt(&a, format!("view grid {view_m} (at most {MAX_VIEW_GRID})")));
    }
    let local = LocalBasis::parse(a.str("local_basis")?).map_err(|e| corrupt(&a, e.to_string()))?;
    let encoding = BtfEncoding::from_name(a.str("encoding")?).map_err(|e| corrupt(&a, e.to_string()))?;
    let texels = (w * h) as usize;
    let views = if view_m == 0 { 1 } else { (view_m * view_m) as usize };
    let per = views * local.len();
    let entries = texels * per;
    // Every length is checked against the dimensions before any table is built.
    let take = |a: &mut Artifact, name: &str, len: usize| {
        let data = a.take_array(name)?;
        if data.len() != len {
            return Err(corrupt(
                a,
                format!("array '{name}' has {} elements, {w}x{h} texels of {per} entries need {len}", data.len()),
            ));
        }
        Ok(data)
    };
    let data: Vec<Rgb> =
        match (encoding, take(&mut a, if encoding == BtfEncoding::U8 { "codes" } else { "values" }, entries * 3)?) {
            (BtfEncoding::F32, ArrayData::F32(v)) => v.chunks_exact(3).map(|e| [e[0], e[1], e[2]]).collect(),
            (BtfEncoding::F16, ArrayData::U16(v)) => {
                v.chunks_exact(3).map(|e| std::array::from_fn(|c| f16::from_bits(e[c]).to_f32())).collect()
            }
            (BtfEncoding::U8, ArrayData::U8(codes)) => {
                let scales = match take(&mut a, "scales", texels)? {
                    ArrayData::F32(s) => s,
                    other => {
                        return Err(corrupt(&a, format!("array 'scales' is {}, expected f32", other.element_type())))
                    }
                };
                if let Some(t) = scales.iter().position(|s| !(s.is_finite() && *s >= 0.0)) {
                    return Err(corrupt(&a, format!("texel {t} has scale {}", scales[t])));
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
            (_, other) => {
                return Err(corrupt(&a, format!("the {} table is stored as {}", encoding.name(), other.element_type())))
            }
        };
    if let Some(i) = data.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
        return Err(corrupt(&a, format!("non-finite value at entry {i}")));
    }
    let view_grid = (view_m > 0).then(|| HemisphereGrid::new(view_m as u32));
    Btf::new([w as u32, h as u32], local, view_grid, data, name).map_err(|e| corrupt(&a, e.to_string()))
}

impl From<ArtifactError> for ShadingError {
    fn from(e: ArtifactError) -> Self {
        ShadingError::Core(e.into())
    }
}
