//! Transfer stage: per-vertex visibility transfer matrices (DESIGN.md sections 1 and 3).
//!
//! For a point p with frame F and a light texel k of the R x R cubemap whose centre direction
//! `d_k` lies above p's tangent plane, `T_p[j, k]` is the fraction of k's `s x s` children in
//! the visibility cubemap (resolution `s R`) whose rays from p are unoccluded, where `j` is
//! the local bin of `F.to_local(d_k)`. Children below the tangent plane count as occluded
//! (the surface itself blocks them). Everything else is 0, so values are multiples of
//! `1 / s^2` in (0, 1]: {1/4, 1/2, 3/4, 1} at the reference `s = 2`.

use crate::error::{CoreError, Result};
use crate::geometry::{SceneBvh, VertexFrame};
use crate::sampling::{Cubemap, HemisphereGrid};
use glam::Vec3;

/// Settings that determine `T`.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferSettings {
    /// Cubemap resolution R of the light (N = 6 R^2). Reference: 32.
    pub cubemap_resolution: u32,
    /// Resolution of the visibility cubemap; a multiple of `cubemap_resolution`.
    /// Reference: 64 (2x2 box filter).
    pub visibility_resolution: u32,
    /// Local direction grid m (M = m^2 bins). Reference: 8.
    pub local_grid: u32,
}

impl Default for TransferSettings {
    fn default() -> Self {
        Self { cubemap_resolution: 32, visibility_resolution: 64, local_grid: 8 }
    }
}

impl TransferSettings {
    /// Supersampling factor `s = visibility_resolution / cubemap_resolution`.
    pub fn supersampling(&self) -> u32 {
        self.visibility_resolution / self.cubemap_resolution.max(1)
    }

    /// Check the settings are usable.
    pub fn validate(&self) -> Result<()> {
        let (r, v, m) = (self.cubemap_resolution, self.visibility_resolution, self.local_grid);
        if r == 0 || m == 0 || v == 0 {
            return Err(CoreError::Invalid("cubemap, visibility and local grid resolutions must be positive".into()));
        }
        if v % r != 0 {
            return Err(CoreError::Invalid(format!(
                "visibility_resolution ({v}) must be a multiple of cubemap_resolution ({r})"
            )));
        }
        if 6 * (r as u64).pow(2) > u16::MAX as u64 + 1 {
            return Err(CoreError::Invalid(format!("cubemap_resolution {r} gives more than 65536 texels")));
        }
        Ok(())
    }
}

/// The stacked transfer matrix: row `v * M + j`, column = cubemap texel `k`.
/// Values are visibility fractions in (0, 1], multiples of `1 / s^2` for supersampling `s`.
#[derive(Clone, Debug)]
pub struct TransferMatrix {
    pub vertices: usize,
    pub local_dirs: usize,
    pub cubemap: Cubemap,
    pub csr: sprs::CsMat<f32>,
}

impl TransferMatrix {
    pub fn rows(&self) -> usize {
        self.csr.rows()
    }
    pub fn cols(&self) -> usize {
        self.csr.cols()
    }
    pub fn nnz(&self) -> usize {
        self.csr.nnz()
    }
}

/// Directions shared by every point's visibility query: coarse texel centres, their
/// children in the visibility cubemap, and the local grid.
pub struct VisibilitySampler {
    pub settings: TransferSettings,
    pub cubemap: Cubemap,
    pub grid: HemisphereGrid,
    coarse_dirs: Vec<Vec3>,
    /// Children of coarse texel k: `fine_dirs[k * s^2 .. (k + 1) * s^2]`.
    fine_dirs: Vec<Vec3>,
    s2: usize,
}

impl VisibilitySampler {
    pub fn new(settings: &TransferSettings) -> Result<Self> {
        settings.validate()?;
        let cubemap = Cubemap::new(settings.cubemap_resolution);
        let fine = Cubemap::new(settings.visibility_resolution);
        let s = settings.supersampling() as usize;
        let coarse_dirs = (0..cubemap.texel_count()).map(|k| cubemap.texel_direction(k)).collect();
        let mut fine_dirs = Vec::with_capacity(fine.texel_count());
        for k in 0..cubemap.texel_count() {
            let (face, row, col) = cubemap.texel_coords(k);
            for a in 0..s {
                for b in 0..s {
                    fine_dirs.push(fine.texel_direction(fine.texel_index(face, row * s + a, col * s + b)));
                }
            }
        }
        Ok(Self {
            settings: settings.clone(),
            cubemap,
            grid: HemisphereGrid::new(settings.local_grid),
            coarse_dirs,
            fine_dirs,
            s2: s * s,
        })
    }

    /// Transfer entries of one shading point at `origin` (already offset off the surface)
    /// with frame `frame`: calls `emit(j, k, value)` for every non-zero, in increasing `k`.
    /// Returns the number of rays traced.
    pub fn point_entries(
        &self,
        bvh: &SceneBvh,
        origin: Vec3,
        frame: &VertexFrame,
        mut emit: impl FnMut(u32, u32, f32),
    ) -> u64 {
        let n = frame.normal;
        let mut rays = 0u64;
        let inv = 1.0 / self.s2 as f32;
        for (k, d) in self.coarse_dirs.iter().enumerate() {
            if d.dot(n) <= 0.0 {
                continue;
            }
            let Some(j) = self.grid.bin_of(frame.to_local(*d)) else { continue };
            let mut visible = 0u32;
            for c in &self.fine_dirs[k * self.s2..(k + 1) * self.s2] {
                if c.dot(n) <= 0.0 {
                    continue;
                }
                rays += 1;
                if !bvh.occluded(origin, *c, 0.0, f32::INFINITY) {
                    visible += 1;
                }
            }
            if visible > 0 {
                emit(j, k as u32, visible as f32 * inv);
            }
        }
        rays
    }
}
