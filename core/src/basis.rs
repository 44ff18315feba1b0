//! The bases that give stage outputs their meaning (docs/DESIGN.md section 9).
//!
//! A light vector, a transfer matrix, a compressed form, `L*` and a BTF all carry the basis
//! their numbers are coefficients of, instead of a bare size, so that two stages can only be
//! wired together when they agree, and the agreement is checked where the data is made:
//!
//! * [`LightBasis`]: the basis of the distant light `L`, the columns of `T`: the `R x R`
//!   cubemap (`L_k` = power through texel `k`), or real spherical harmonics of the world
//!   frame (`L_i = int L(w) y_i(w) dw`, the low-frequency method).
//! * [`LocalBasis`]: the basis of the local incident light `L*` at a vertex, the rows of each
//!   vertex's block of `T` and the light axis of the BTF: the `m x m` Shirley-Chiu bins of the
//!   upper hemisphere (`L*_j` = power through bin `j`), or real spherical harmonics of the
//!   vertex's local frame (`L*_i = int L*(w) y_i(w) dw`; the BTF's light axis in this basis is
//!   Sloan et al.'s radiance transfer texture).
//!
//! SH follow the one convention of [`crate::sh`]. Each basis is a closed enum, so adding one
//! makes the compiler list every place that must decide what it means. The constructors
//! validate (so a basis in hand is always usable), and
//! [`LocalBasis::tag`] / [`LocalBasis::parse`] are the one text form of a basis in artifact
//! headers and cache keys (`bins:8`, `cubemap:32`).

use crate::error::{CoreError, Result};
use crate::sampling::{Cubemap, HemisphereGrid};
use crate::sh::ShOrder;
use std::fmt;

/// Largest local grid side: `m = 64` gives 4096 bins per vertex, far past the 32 x 32 of the
/// scaling study.
pub const MAX_LOCAL_GRID: u32 = 64;

/// Largest cubemap resolution: `N = 6 R^2` must fit the 16-bit column indices of the
/// compressed forms (`6 * 104^2 = 64896`).
pub const MAX_CUBEMAP_RESOLUTION: u32 = 104;

/// The basis of `L*`: what the rows of one vertex's block of `T` stand for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LocalBasis {
    /// `m x m` equal-solid-angle Shirley-Chiu bins of the upper hemisphere (local frame,
    /// +Z = normal); coefficient `j` is the power through bin `j`.
    Bins(HemisphereGrid),
    /// Real spherical harmonics of the local frame (+Z = normal) to an order;
    /// coefficient `i` is `int L*(w) y_i(w) dw`.
    Sh(ShOrder),
    /// One coefficient: the irradiance `int L*(w) max(cos theta, 0) dw` of the local light
    /// truncated to an SH order (`sum_i l_i c_i`, `c` the clamped cosine's coefficients): the
    /// shadowed diffuse PRT of Sloan et al. 2002, all a Lambertian material needs.
    Irradiance(ShOrder),
}

impl LocalBasis {
    /// The `m x m` bin grid, `1 <= m <= MAX_LOCAL_GRID`.
    pub fn bins(m: u32) -> Result<Self> {
        if m == 0 || m > MAX_LOCAL_GRID {
            return Err(CoreError::Invalid(format!("local grid must be 1..={MAX_LOCAL_GRID} per side, got {m}")));
        }
        Ok(LocalBasis::Bins(HemisphereGrid::new(m)))
    }

    /// Local SH of order `n` (`1..=MAX_SH_ORDER`).
    pub fn sh(n: u32) -> Result<Self> {
        Ok(LocalBasis::Sh(ShOrder::new(n)?))
    }

    /// Number of coefficients per vertex, `M`.
    pub fn len(&self) -> usize {
        match self {
            LocalBasis::Bins(g) => g.len(),
            LocalBasis::Sh(o) => o.len(),
            LocalBasis::Irradiance(_) => 1,
        }
    }

    /// Never true for a constructed basis; for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The bin grid, `None` for a basis that is not bins.
    pub fn grid(&self) -> Option<HemisphereGrid> {
        match self {
            LocalBasis::Bins(g) => Some(*g),
            LocalBasis::Sh(_) | LocalBasis::Irradiance(_) => None,
        }
    }

    /// The SH order, `None` for a basis that is not SH.
    pub fn sh_order(&self) -> Option<ShOrder> {
        match self {
            LocalBasis::Sh(o) => Some(*o),
            LocalBasis::Bins(_) | LocalBasis::Irradiance(_) => None,
        }
    }

    /// The text form: `bins:<m>`, `sh:<n>` or `irradiance:<n>`.
    pub fn tag(&self) -> String {
        match self {
            LocalBasis::Bins(g) => format!("bins:{}", g.m),
            LocalBasis::Sh(o) => format!("sh:{}", o.n()),
            LocalBasis::Irradiance(o) => format!("irradiance:{}", o.n()),
        }
    }

    /// Inverse of [`Self::tag`]; the error says what was expected.
    pub fn parse(s: &str) -> Result<Self> {
        match s.split_once(':') {
            Some(("bins", m)) => Self::bins(parse_u32(m, s)?),
            Some(("sh", n)) => Self::sh(parse_u32(n, s)?),
            Some(("irradiance", n)) => Ok(LocalBasis::Irradiance(ShOrder::new(parse_u32(n, s)?)?)),
            _ => Err(CoreError::Invalid(format!(
                "unknown local basis {s:?} (expected bins:<m>, sh:<n> or irradiance:<n>)"
            ))),
        }
    }
}

impl fmt::Display for LocalBasis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LocalBasis::Bins(g) => write!(f, "{m}x{m} bins", m = g.m),
            LocalBasis::Sh(o) => write!(f, "local {o}"),
            LocalBasis::Irradiance(o) => write!(f, "irradiance of local {o}"),
        }
    }
}

/// The basis of the distant light `L`: what the columns of `T` stand for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LightBasis {
    /// The `R x R` cubemap (faces +X, -X, +Y, -Y, +Z, -Z); coefficient `k` is the power
    /// through texel `k`.
    Cubemap(Cubemap),
    /// Real spherical harmonics of the world frame to an order; coefficient `i` is
    /// `int L(w) y_i(w) dw`.
    Sh(ShOrder),
}

impl LightBasis {
    /// The cubemap of resolution `r`, `1 <= r <= MAX_CUBEMAP_RESOLUTION`.
    pub fn cubemap(r: u32) -> Result<Self> {
        if r == 0 || r > MAX_CUBEMAP_RESOLUTION {
            return Err(CoreError::Invalid(format!(
                "cubemap resolution must be 1..={MAX_CUBEMAP_RESOLUTION} (N = 6 R^2 must fit 16-bit indices), got {r}"
            )));
        }
        Ok(LightBasis::Cubemap(Cubemap::new(r)))
    }

    /// World-frame SH of order `n` (`1..=MAX_SH_ORDER`).
    pub fn sh(n: u32) -> Result<Self> {
        Ok(LightBasis::Sh(ShOrder::new(n)?))
    }

    /// Number of coefficients, `N`.
    pub fn len(&self) -> usize {
        match self {
            LightBasis::Cubemap(c) => c.texel_count(),
            LightBasis::Sh(o) => o.len(),
        }
    }

    /// Never true for a constructed basis; for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cubemap, `None` for a basis that is not a cubemap.
    pub fn cubemap_layout(&self) -> Option<Cubemap> {
        match self {
            LightBasis::Cubemap(c) => Some(*c),
            LightBasis::Sh(_) => None,
        }
    }

    /// The SH order, `None` for a basis that is not SH.
    pub fn sh_order(&self) -> Option<ShOrder> {
        match self {
            LightBasis::Sh(o) => Some(*o),
            LightBasis::Cubemap(_) => None,
        }
    }

    /// The text form: `cubemap:<R>` or `sh:<n>`.
    pub fn tag(&self) -> String {
        match self {
            LightBasis::Cubemap(c) => format!("cubemap:{}", c.resolution),
            LightBasis::Sh(o) => format!("sh:{}", o.n()),
        }
    }

    /// Inverse of [`Self::tag`].
    pub fn parse(s: &str) -> Result<Self> {
        match s.split_once(':') {
            Some(("cubemap", r)) => Self::cubemap(parse_u32(r, s)?),
            Some(("sh", n)) => Self::sh(parse_u32(n, s)?),
            _ => Err(CoreError::Invalid(format!("unknown light basis {s:?} (expected cubemap:<R> or sh:<n>)"))),
        }
    }
}

impl fmt::Display for LightBasis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LightBasis::Cubemap(c) => write!(f, "6x{r}x{r} cubemap", r = c.resolution),
            LightBasis::Sh(o) => write!(f, "world {o}"),
        }
    }
}

fn parse_u32(v: &str, whole: &str) -> Result<u32> {
    v.parse().map_err(|_| CoreError::Invalid(format!("basis {whole:?}: {v:?} is not a size")))
}

/// The shape every per-vertex stage output shares: `vertices` blocks of `local.len()` rows,
/// each a combination of `light.len()` light coefficients. `T`, its compressed forms and
/// `L*` (which has no light axis but keeps the light basis it was gathered from) carry one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TransferShape {
    pub vertices: usize,
    pub local: LocalBasis,
    pub light: LightBasis,
}

impl TransferShape {
    pub fn new(vertices: usize, local: LocalBasis, light: LightBasis) -> Self {
        Self { vertices, local, light }
    }

    /// Rows of `T`: `vertices * M`.
    pub fn rows(&self) -> usize {
        self.vertices * self.local.len()
    }

    /// Columns of `T`: `N`.
    pub fn cols(&self) -> usize {
        self.light.len()
    }

    /// `M`, the local coefficients per vertex.
    pub fn local_dirs(&self) -> usize {
        self.local.len()
    }

    /// The shape whose `rows` are `rows`, or an error when they are not whole vertices.
    pub fn from_rows(rows: usize, local: LocalBasis, light: LightBasis) -> Result<Self> {
        let m = local.len();
        if !rows.is_multiple_of(m) {
            return Err(CoreError::Invalid(format!(
                "{rows} rows are not a whole number of vertices of {local} ({m} rows each)"
            )));
        }
        Ok(Self::new(rows / m, local, light))
    }
}

impl fmt::Display for TransferShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} vertices x {} from a {}", self.vertices, self.local, self.light)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_round_trip_and_bad_ones_are_errors() {
        for m in [1, 4, 8, 32, 64] {
            let b = LocalBasis::bins(m).unwrap();
            assert_eq!(LocalBasis::parse(&b.tag()).unwrap(), b);
            assert_eq!(b.len(), (m * m) as usize);
        }
        for r in [1, 8, 32, 104] {
            let b = LightBasis::cubemap(r).unwrap();
            assert_eq!(LightBasis::parse(&b.tag()).unwrap(), b);
            assert_eq!(b.len(), 6 * (r * r) as usize);
        }
        for n in 1..=crate::sh::MAX_SH_ORDER {
            let (l, w) = (LocalBasis::sh(n).unwrap(), LightBasis::sh(n).unwrap());
            assert_eq!((LocalBasis::parse(&l.tag()).unwrap(), LightBasis::parse(&w.tag()).unwrap()), (l, w));
            assert_eq!((l.len(), w.len()), ((n * n) as usize, (n * n) as usize));
            assert_eq!((l.grid(), w.cubemap_layout(), l.sh_order().unwrap().n()), (None, None, n));
        }
        let irr = LocalBasis::Irradiance(ShOrder::new(5).unwrap());
        assert_eq!((LocalBasis::parse(&irr.tag()).unwrap(), irr.len(), irr.tag().as_str()), (irr, 1, "irradiance:5"));
        for bad in ["bins:0", "bins:65", "bins:x", "sh:0", "sh:9", "irradiance:0", "cubemap:8", "bins", ""] {
            assert!(LocalBasis::parse(bad).is_err(), "{bad}");
        }
        for bad in ["cubemap:0", "cubemap:105", "bins:8", "sh:0", "sh:9"] {
            assert!(LightBasis::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn shape_counts_rows_and_columns() {
        let s = TransferShape::new(3, LocalBasis::bins(4).unwrap(), LightBasis::cubemap(8).unwrap());
        assert_eq!((s.rows(), s.cols(), s.local_dirs()), (48, 384, 16));
        assert_eq!(TransferShape::from_rows(48, s.local, s.light).unwrap(), s);
        assert!(TransferShape::from_rows(47, s.local, s.light).is_err());
    }
}
