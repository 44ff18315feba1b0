//! Transfer stage: per-vertex visibility transfer matrices (docs/DESIGN.md sections 1 and 3).
//!
//! For a point p with frame F and a light texel k of the R x R cubemap whose centre direction
//! `d_k` lies above p's tangent plane, `T_p[j, k]` is the fraction of k's `s x s` children in
//! the visibility cubemap (resolution `s R`) whose rays from p are unoccluded, where `j` is
//! the local bin of `F.to_local(d_k)`. Children below the tangent plane count as occluded
//! (the surface itself blocks them). Everything else is 0, so values are multiples of
//! `1 / s^2` in (0, 1]: {1/4, 1/2, 3/4, 1} at the reference `s = 2`.
//!
//! * [`TransferSettings`]: the bases of `T` (light: the cubemap; local: the bin grid) and the
//!   visibility resolution, validated once.
//! * [`TransferScene`]: the geometry every visibility query of a mesh shares (frames, the
//!   normalised BVH, the origin offset), built once and used by the transfer build and by the
//!   ray-traced reference, so both have the same visibility semantics.
//! * [`build`] / [`build_range`]: `T` for a mesh, or for a range of its vertices (a shard).
//! * [`TransferMatrix`]: the stacked result, carrying its bases; `save` / `load` keep it as
//!   a file of its own (the stage cache).
//! * [`TransferView`]: `T` whole or as a sharded precompute's [`TransferParts`], read one
//!   part at a time: what every pass over `T` after the compressors takes.
//! * [`sh`]: the low-frequency method's SH transfer `M` (local SH x world SH), ray traced on
//!   the same [`TransferScene`] or projected from `T`.

mod build;
mod parts;
mod sampler;
mod scene;
pub mod sh;

pub use build::{
    build, build_range, nnz_strata, sample_nnz, worst_case_bytes, NnzEstimate, NnzStratum, TransferBuild,
    TransferMemory, TransferStats, BYTES_PER_NONZERO, MAX_TRANSFER_BYTES, NNZ_MARGIN_SIGMAS, NNZ_SAMPLE_VERTICES,
};
pub use parts::{PartFile, TransferParts, TransferView};
pub use sampler::{VisibilitySampler, VisibilityScratch};
pub use scene::{TransferScene, BVH_DIAGONAL, ORIGIN_OFFSET};

use crate::artifact::{Artifact, ArtifactError};
use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::compress::ArrayData;
use crate::error::{CoreError, Result};
use crate::sampling::{Cubemap, HemisphereGrid};
use std::path::Path;

/// Settings that determine `T`: the bases of its rows and columns and the visibility
/// resolution. Constructed through [`TransferSettings::new`], so a value in hand is valid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TransferSettings {
    cubemap: Cubemap,
    visibility_resolution: u32,
    grid: HemisphereGrid,
    visibility: Visibility,
}

/// How the transfer stage decides which visibility rays are occluded (`transfer.visibility`).
/// Both give the per-ray definition of `T` (a texel is covered exactly when the ray through
/// its centre hits a triangle); they can differ only on a ray within f32 rounding of a
/// triangle's edge: none on the bundled bunny and temple, 2 to 5 rays in 14 to 41 million on
/// the other bundled meshes (docs/DESIGN.md, "Visibility by coverage").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Visibility {
    /// Per vertex and cube face, the triangles the face could see rasterised front to back
    /// into its coverage mask with texel-centre sampling, skipping what is already covered
    /// (`geometry::bvh::coverage`).
    #[default]
    Coverage,
    /// Every ray traced: tile by tile against the tile's cone-culled candidate list when it
    /// is short, through the BVH in packets when it is long.
    Rays,
}

impl Visibility {
    /// The config's spelling.
    pub fn name(self) -> &'static str {
        match self {
            Visibility::Coverage => "coverage",
            Visibility::Rays => "rays",
        }
    }
}

impl Default for TransferSettings {
    /// The reference settings: cubemap 6x32x32, visibility 6x64x64 (2x2 box filter), 8x8 bins.
    fn default() -> Self {
        Self::new(32, 64, 8).expect("the reference settings are valid")
    }
}

impl TransferSettings {
    /// Light cubemap resolution `R` (N = 6 R^2), visibility cubemap resolution (a multiple of
    /// `R`: the box filter's `s = visibility / R`), local bin grid `m` (M = m^2).
    pub fn new(cubemap_resolution: u32, visibility_resolution: u32, local_grid: u32) -> Result<Self> {
        let cubemap = LightBasis::cubemap(cubemap_resolution)?.cubemap_layout().expect("a cubemap basis");
        let grid = LocalBasis::bins(local_grid)?.grid().expect("a bin basis");
        let r = cubemap_resolution;
        if visibility_resolution == 0 || !visibility_resolution.is_multiple_of(r) {
            return Err(CoreError::Invalid(format!(
                "visibility_resolution ({visibility_resolution}) must be a positive multiple of cubemap_resolution ({r})"
            )));
        }
        let s = (visibility_resolution / r) as u64;
        if s * s > u16::MAX as u64 {
            return Err(CoreError::Invalid(format!(
                "supersampling {s} (visibility_resolution / cubemap_resolution) gives more than 65535 children per texel"
            )));
        }
        Ok(Self { cubemap, visibility_resolution, grid, visibility: Visibility::default() })
    }

    /// These settings with another way to decide visibility (the same `T`, see [`Visibility`]).
    pub fn with_visibility(&self, visibility: Visibility) -> Self {
        Self { visibility, ..*self }
    }

    /// How visibility is decided.
    pub fn visibility(&self) -> Visibility {
        self.visibility
    }

    /// These settings with another local grid `m`.
    pub fn with_local_grid(&self, m: u32) -> Result<Self> {
        Ok(Self::new(self.cubemap().resolution, self.visibility_resolution, m)?.with_visibility(self.visibility))
    }

    /// The basis of `L` and of `T`'s columns: the light cubemap.
    pub fn light_basis(&self) -> LightBasis {
        LightBasis::Cubemap(self.cubemap)
    }

    /// The basis of `L*` and of each vertex's rows of `T`: the local bins.
    pub fn local_basis(&self) -> LocalBasis {
        LocalBasis::Bins(self.grid)
    }

    /// The light cubemap (R x R per face).
    pub fn cubemap(&self) -> Cubemap {
        self.cubemap
    }

    /// The local bin grid (m x m).
    pub fn local_grid(&self) -> HemisphereGrid {
        self.grid
    }

    /// Resolution of the visibility cubemap.
    pub fn visibility_resolution(&self) -> u32 {
        self.visibility_resolution
    }

    /// Supersampling factor `s = visibility_resolution / cubemap_resolution`.
    pub fn supersampling(&self) -> u32 {
        self.visibility_resolution / self.cubemap().resolution
    }

    /// The shape of `T` for `vertices` vertices.
    pub fn shape(&self, vertices: usize) -> TransferShape {
        TransferShape::new(vertices, self.local_basis(), self.light_basis())
    }
}

/// The stacked transfer matrix: row `v * M + j`, column = light coefficient `k`. In the bins x
/// cubemap bases (`build`) the values are visibility fractions in (0, 1], multiples of `1 / s^2`
/// for supersampling `s`; in the SH bases ([`sh`]) they are the projections `M_p[i][j]`, of
/// either sign.
///
/// The bases are part of the value: `rows == vertices * local_basis.len()` and
/// `cols == light_basis.len()` hold by construction ([`TransferMatrix::new`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TransferMatrix {
    shape: TransferShape,
    csr: sprs::CsMat<f32>,
}

impl TransferMatrix {
    /// `T` in the given bases; the CSR's shape must be `(vertices * M, N)` and its values
    /// finite, or the error says which does not hold.
    pub fn new(local: LocalBasis, light: LightBasis, csr: sprs::CsMat<f32>) -> Result<Self> {
        if !csr.is_csr() {
            return Err(CoreError::Invalid("the transfer matrix must be stored by rows (CSR)".into()));
        }
        if csr.cols() != light.len() {
            return Err(CoreError::Invalid(format!(
                "the transfer matrix has {} columns, its light basis ({light}) has {}",
                csr.cols(),
                light.len()
            )));
        }
        let shape = TransferShape::from_rows(csr.rows(), local, light)?;
        if let Some(i) = csr.data().iter().position(|v| !v.is_finite()) {
            return Err(CoreError::Invalid(format!("the transfer matrix's value {i} is not finite")));
        }
        Ok(Self { shape, csr })
    }

    pub fn shape(&self) -> TransferShape {
        self.shape
    }
    pub fn local_basis(&self) -> LocalBasis {
        self.shape.local
    }
    pub fn light_basis(&self) -> LightBasis {
        self.shape.light
    }
    pub fn vertices(&self) -> usize {
        self.shape.vertices
    }
    /// `M`, the rows per vertex.
    pub fn local_dirs(&self) -> usize {
        self.shape.local_dirs()
    }
    pub fn rows(&self) -> usize {
        self.csr.rows()
    }
    pub fn cols(&self) -> usize {
        self.csr.cols()
    }
    pub fn nnz(&self) -> usize {
        self.csr.nnz()
    }
    /// The stored values that are not 0 (what Table I counts as `T`'s non-zeros).
    pub fn nonzero_values(&self) -> usize {
        self.csr.data().iter().filter(|&&x| x != 0.0).count()
    }
    /// The sparse matrix itself (rows `v * M + j`).
    pub fn csr(&self) -> &sprs::CsMat<f32> {
        &self.csr
    }
    /// The sparse matrix, by value.
    pub fn into_csr(self) -> sprs::CsMat<f32> {
        self.csr
    }

    /// The rows of the vertices in `range`, as a matrix of its own (a shard's part of `T`).
    pub fn vertex_rows(&self, range: std::ops::Range<usize>) -> Result<Self> {
        if range.start > range.end || range.end > self.vertices() {
            return Err(CoreError::Invalid(format!(
                "vertex range {range:?} is not within {} vertices",
                self.vertices()
            )));
        }
        let m = self.local_dirs();
        let ip = self.csr.indptr();
        let ip = ip.raw_storage();
        let (lo, hi) = (ip[range.start * m], ip[range.end * m]);
        let indptr = ip[range.start * m..=range.end * m].iter().map(|&p| p - lo).collect();
        let csr = sprs::CsMat::new(
            (range.len() * m, self.cols()),
            indptr,
            self.csr.indices()[lo..hi].to_vec(),
            self.csr.data()[lo..hi].to_vec(),
        );
        Self::new(self.local_basis(), self.light_basis(), csr)
    }

    /// The matrix whose rows are those of `parts`, in order (the inverse of
    /// [`Self::vertex_rows`] over consecutive ranges): every part must be in the same bases.
    /// Parts are taken one at a time, so a caller can load them as they are needed.
    pub fn stack(parts: impl IntoIterator<Item = Self>) -> Result<Self> {
        let mut bases = None;
        let (mut indptr, mut indices, mut data) = (vec![0usize], Vec::new(), Vec::new());
        for (i, p) in parts.into_iter().enumerate() {
            let (local, light) = *bases.get_or_insert((p.local_basis(), p.light_basis()));
            if p.local_basis() != local || p.light_basis() != light {
                return Err(CoreError::Invalid(format!(
                    "part {i} is {} x {}, part 0 {local} x {light}",
                    p.local_basis(),
                    p.light_basis()
                )));
            }
            let base = indices.len();
            let (ip, ix, d) = p.csr.into_raw_storage();
            indptr.extend(ip[1..].iter().map(|&x| base + x - ip[0]));
            indices.extend_from_slice(&ix);
            data.extend_from_slice(&d);
        }
        let (local, light) = bases.ok_or_else(|| CoreError::Invalid("no matrices to stack".into()))?;
        let rows = indptr.len() - 1;
        let csr = sprs::CsMat::try_new((rows, light.len()), indptr, indices, data)
            .map_err(|e| CoreError::Invalid(format!("stacking transfer parts: {}", e.3)))?;
        Self::new(local, light, csr)
    }
}

/// `T` as a file ([`crate::artifact`], kind `transfer`): the shape, then the CSR arrays
/// `row_ptr` (u32, rows + 1), `col` (u16: N <= 6 x 104^2 < 2^16 by the cubemap limit) and
/// `values` (f32).
impl TransferMatrix {
    /// The artifact kind of a transfer matrix.
    pub const ARTIFACT: &'static str = "transfer";

    /// `T` as an artifact. More than 2^32 non-zeros are refused.
    pub fn to_artifact(&self) -> Result<Artifact> {
        if self.nnz() > u32::MAX as usize || self.cols() > u16::MAX as usize + 1 {
            return Err(CoreError::TooLarge(format!(
                "{} non-zeros in {} columns do not fit the transfer file's u32 offsets and u16 columns",
                self.nnz(),
                self.cols()
            )));
        }
        let csr = &self.csr;
        Ok(Artifact::new(Self::ARTIFACT)
            .with_shape(self.shape)
            .with_array("row_ptr", ArrayData::U32(csr.indptr().raw_storage().iter().map(|&p| p as u32).collect()))
            .with_array("col", ArrayData::U16(csr.indices().iter().map(|&c| c as u16).collect()))
            .with_array("values", ArrayData::F32(csr.data().to_vec())))
    }

    /// Write `T` to `path` atomically ([`Self::to_artifact`]).
    pub fn save(&self, path: &Path) -> Result<()> {
        let a = self.to_artifact().map_err(|e| match e {
            CoreError::TooLarge(msg) => CoreError::TooLarge(format!("{}: {msg}", path.display())),
            e => e,
        })?;
        a.save(path)
    }

    /// Read a matrix written by [`Self::save`]; a file whose arrays are not a valid CSR
    /// matrix of its shape is an error naming it.
    pub fn load(path: &Path) -> std::result::Result<Self, ArtifactError> {
        Self::from_artifact(Artifact::load(path)?)
    }

    /// The matrix an artifact holds (see [`Self::load`]).
    pub fn from_artifact(mut a: Artifact) -> std::result::Result<Self, ArtifactError> {
        a.expect_kind(Self::ARTIFACT)?;
        let shape = a.shape()?;
        let (row_ptr, col, values) = match (a.take_array("row_ptr")?, a.take_array("col")?, a.take_array("values")?) {
            (ArrayData::U32(p), ArrayData::U16(c), ArrayData::F32(v)) => (p, c, v),
            _ => return Err(a.corrupt("row_ptr, col and values must be u32, u16 and f32")),
        };
        let csr = sprs::CsMat::try_new(
            (shape.rows(), shape.cols()),
            row_ptr.into_iter().map(|p| p as usize).collect(),
            col.into_iter().map(|c| c as usize).collect(),
            values,
        )
        .map_err(|e| a.corrupt(format!("not a valid CSR matrix of {shape}: {}", e.3)))?;
        Self::new(shape.local, shape.light, csr).map_err(|e| a.corrupt(e.to_string()))
    }
}

#[cfg(test)]
mod tests;
