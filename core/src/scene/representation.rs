//! A material's BTF as it is stored and evaluated: the dense table ([`Btf`]) or its local-PCA
//! form ([`LpcaBtf`]). Every shader takes a [`BtfRepresentation`] and evaluates it through one
//! interface: the CPU shaders call [`BtfRepresentation::eval_into`] / [`BtfRepresentation::shade`],
//! the wgpu shader has one WGSL function per kind behind the same header (`gpu/src/shade`).
//!
//! Both kinds look a texel up with [`super::btf::texel_of`] and blend the view samples with
//! [`super::btf::view_weights`], so an LPCA setting that keeps every component evaluates to
//! the dense table's values to rounding: the only difference between the two is how the
//! values of one (texel, view) are stored.

use super::btf::texel_of;
use super::{Btf, LpcaBtf};
use crate::basis::LocalBasis;
use crate::error::Result;
use crate::sampling::HemisphereGrid;
use crate::Rgb;
use glam::{Vec2, Vec3};
use std::borrow::Cow;

/// How a material's BTF is stored (module docs). The config key is `representation`.
#[derive(Clone, Debug, PartialEq)]
pub enum BtfRepresentation {
    /// The table `[texel][view][light]` as it is.
    Dense(Btf),
    /// Local PCA (Müller et al. 2004): cluster means, eigen-BRDFs, per-unit weights.
    Lpca(LpcaBtf),
}

impl From<Btf> for BtfRepresentation {
    fn from(b: Btf) -> Self {
        Self::Dense(b)
    }
}

impl From<LpcaBtf> for BtfRepresentation {
    fn from(b: LpcaBtf) -> Self {
        Self::Lpca(b)
    }
}

impl BtfRepresentation {
    /// `dense` or `lpca`, as in the config.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Dense(_) => "dense",
            Self::Lpca(_) => "lpca",
        }
    }

    pub fn name(&self) -> &str {
        match self {
            Self::Dense(b) => b.name(),
            Self::Lpca(l) => l.name(),
        }
    }

    /// The light directions `d_j` (the basis of the `L*` it is dotted with).
    pub fn local_basis(&self) -> LocalBasis {
        match self {
            Self::Dense(b) => b.local_basis(),
            Self::Lpca(l) => l.local_basis(),
        }
    }

    /// Patch size in texels.
    pub fn spatial(&self) -> [u32; 2] {
        match self {
            Self::Dense(b) => b.spatial(),
            Self::Lpca(l) => l.spatial(),
        }
    }

    /// View samples (`None`: view-independent).
    pub fn view_grid(&self) -> Option<HemisphereGrid> {
        match self {
            Self::Dense(b) => b.view_grid(),
            Self::Lpca(l) => l.view_grid(),
        }
    }

    /// Stored bytes (dense: 12 per RGB entry; LPCA: [`LpcaBtf::bytes`]).
    pub fn bytes(&self) -> u64 {
        match self {
            Self::Dense(b) => b.data().len() as u64 * 12,
            Self::Lpca(l) => l.bytes(),
        }
    }

    /// The dense table, decoded when compressed (for consumers that need every value:
    /// diffuse detection, bounce albedo, previews).
    pub fn to_dense(&self) -> Result<Cow<'_, Btf>> {
        match self {
            Self::Dense(b) => Ok(Cow::Borrowed(b)),
            Self::Lpca(l) => Ok(Cow::Owned(l.decode()?)),
        }
    }

    /// The nearest texel of `texel_uv` ([`texel_of`]).
    pub fn texel_of(&self, texel_uv: Vec2) -> usize {
        texel_of(self.spatial(), texel_uv)
    }

    /// `b(u, e, d_j)` for every light bin `j` ([`Btf::eval_into`], [`LpcaBtf::eval_into`]).
    ///
    /// # Panics
    /// If `out.len()` is not the light count (a caller bug).
    pub fn eval_into(&self, texel_uv: Vec2, view_local: Vec3, out: &mut [Rgb]) {
        match self {
            Self::Dense(b) => b.eval_into(texel_uv, view_local, out),
            Self::Lpca(l) => l.eval_into(texel_uv, view_local, out),
        }
    }

    /// `sum_j b(u, e, d_j) L*_j`, accumulated in f64: the BTF's values are evaluated in f32
    /// into `scratch` (one per light bin) and dotted with `lstar` (the interpolated `L*`).
    /// An LPCA BTF is evaluated from its eigen-BRDFs directly; its table is never decoded.
    pub fn shade(&self, texel_uv: Vec2, view_local: Vec3, lstar: &[[f64; 3]], scratch: &mut [Rgb]) -> Rgb {
        self.eval_into(texel_uv, view_local, scratch);
        let mut acc = [0.0f64; 3];
        for (b, l) in scratch.iter().zip(lstar) {
            for c in 0..3 {
                acc[c] += b[c] as f64 * l[c];
            }
        }
        acc.map(|x| x as f32)
    }
}
