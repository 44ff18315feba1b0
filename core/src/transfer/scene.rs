//! The geometry every visibility query of one mesh shares: vertex frames, a BVH over a
//! normalised copy of the mesh, and the ray-origin offset. Built once per mesh and used by
//! the transfer build ([`super::build_range`]) and by the ray-traced reference
//! ([`TransferScene::visibility_at`]), so that the reference's per-pixel `L*` has exactly the
//! visibility semantics of `T` and differs from the vertex render only by vertex sampling.
//!
//! * **Ray origin.** A query at point p with normal n traces from `p + eps n` with
//!   `eps = 1e-4 * diagonal` ([`ORIGIN_OFFSET`]): relative to the mesh's scale so any unit
//!   works; far above the f32 rounding of positions (~1e-7 relative), so the point's own
//!   triangles are not hit by rays above its tangent plane through rounding noise; far below
//!   any feature (bunny: 1.4e-3 against edges of ~0.2), so real close occluders (creases,
//!   concavities) still occlude. Rays leave the offset point from `RAY_TMIN` (the BVH's own
//!   near limit, `geometry::bvh`).
//! * **Scale.** The BVH is built on the mesh translated to its bounding-box centre and scaled
//!   to a diagonal of [`BVH_DIAGONAL`], a similarity transform that leaves every visibility
//!   answer unchanged but (a) keeps f32 precision for meshes far from the origin and (b) keeps
//!   obvhs's absolute node epsilon (`1e-4` world units: boxes the ray leaves before
//!   `t = 1e-4` are skipped) negligible against the origin offset whatever the mesh's units
//!   (a 1 mm mesh would otherwise lose its nearby occluders).

use super::sampler::{VisibilitySampler, VisibilityScratch};
use crate::error::{CoreError, Result};
use crate::geometry::{vertex_frames, Mesh, SceneBvh, VertexFrame};
use glam::Vec3;

/// Ray origins are offset along the normal by this fraction of the mesh's bounding box
/// diagonal (see the module docs).
pub const ORIGIN_OFFSET: f32 = 1e-4;

/// The diagonal of the normalised copy of the mesh the BVH is built on (module docs).
pub const BVH_DIAGONAL: f32 = 1024.0;

/// A mesh prepared for visibility queries (module docs).
pub struct TransferScene {
    frames: Vec<VertexFrame>,
    frame_fallbacks: usize,
    /// Vertex positions in the normalised space: `(p - centre) * scale`.
    positions: Vec<Vec3>,
    bvh: SceneBvh,
    centre: Vec3,
    scale: f32,
    /// [`ORIGIN_OFFSET`] times the diagonal, in the normalised space.
    origin_offset: f32,
}

impl TransferScene {
    /// Frames, normalised positions and the BVH of `mesh`. Errors on triangles that index
    /// past the vertices and on non-finite positions.
    pub fn new(mesh: &Mesh) -> Result<Self> {
        let vertices = mesh.vertex_count();
        if let Some((t, &bad)) =
            mesh.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= vertices))
        {
            return Err(CoreError::Invalid(format!(
                "triangle {t} refers to vertex {bad:?}, the mesh has {vertices} vertices"
            )));
        }
        if let Some(v) = mesh.positions.iter().position(|p| !p.is_finite()) {
            return Err(CoreError::Invalid(format!("vertex {v} has a non-finite position")));
        }
        let (frames, frame_fallbacks) = vertex_frames(mesh);
        let (lo, hi) = mesh.bounds();
        let centre = 0.5 * (lo + hi);
        let diagonal = mesh.diagonal();
        let scale = if diagonal > 0.0 { BVH_DIAGONAL / diagonal } else { 1.0 };
        let positions: Vec<Vec3> = mesh.positions.iter().map(|p| (*p - centre) * scale).collect();
        // A mesh a few subnormals across has no f32 scale to the BVH's size (1024 / 1e-37
        // overflows), and infinite positions break the BVH build. The pipeline's placement
        // brings tiny meshes into range first; here they are refused.
        if !scale.is_finite() || positions.iter().any(|p| !p.is_finite()) {
            return Err(CoreError::Invalid(format!(
                "the mesh spans {diagonal:e}, too small to trace in f32: scale it up (placement does)"
            )));
        }
        let bvh = SceneBvh::build(&positions, &mesh.triangles);
        Ok(Self {
            frames,
            frame_fallbacks,
            positions,
            bvh,
            centre,
            scale,
            origin_offset: ORIGIN_OFFSET * diagonal * scale,
        })
    }

    /// One frame per vertex ([`vertex_frames`]).
    pub fn frames(&self) -> &[VertexFrame] {
        &self.frames
    }

    /// Vertices whose normal fell back to +Y (see [`vertex_frames`]).
    pub fn frame_fallbacks(&self) -> usize {
        self.frame_fallbacks
    }

    pub fn vertex_count(&self) -> usize {
        self.frames.len()
    }

    /// The normalised-space ray origin of a query at world point `p` with unit normal `n`.
    fn origin(&self, p: Vec3, n: Vec3) -> Vec3 {
        (p - self.centre) * self.scale + n * self.origin_offset
    }

    /// The vertex positions in the BVH's normalised space (centred, diagonal [`BVH_DIAGONAL`]).
    pub fn normalised_positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// The BVH over the normalised positions, which every visibility query traces.
    pub fn bvh(&self) -> &SceneBvh {
        &self.bvh
    }

    /// The normalised-space ray origin of vertex `v` (offset along its normal).
    pub fn vertex_origin(&self, v: usize) -> Vec3 {
        self.positions[v] + self.frames[v].normal * self.origin_offset
    }

    /// True when the distant light is blocked along unit direction `dir` from the
    /// normalised-space `origin` (from [`Self::vertex_origin`]), with the transfer stage's ray
    /// start `RAY_TMIN`.
    pub(crate) fn occluded_from(&self, origin: Vec3, dir: Vec3) -> bool {
        self.bvh.occluded(origin, dir, crate::geometry::bvh::RAY_TMIN, f32::INFINITY)
    }

    /// The first surface hit along unit direction `dir` from the normalised-space `origin`
    /// (mesh triangle and barycentrics), with the transfer stage's ray start.
    pub(crate) fn closest_from(&self, origin: Vec3, dir: Vec3) -> Option<crate::geometry::Hit> {
        self.bvh.closest_hit(origin, dir, crate::geometry::bvh::RAY_TMIN, f32::INFINITY)
    }

    /// Unoccluded-children counts of vertex `v` (see [`VisibilitySampler::point_counts`]):
    /// `emit(j, k, count)` for every non-zero, in increasing `k`; returns the rays traced.
    pub(crate) fn vertex_counts(
        &self,
        sampler: &VisibilitySampler,
        v: usize,
        scratch: &mut VisibilityScratch,
        emit: impl FnMut(u32, u32, u32),
    ) -> u64 {
        let frame = &self.frames[v];
        let origin = self.positions[v] + frame.normal * self.origin_offset;
        sampler.point_counts(&self.bvh, origin, frame, scratch, emit)
    }

    /// The transfer entries at an arbitrary surface point `p` (world space) with frame
    /// `frame`, exactly as a vertex there would get them: `emit(j, k, value)` for every
    /// non-zero, in increasing `k`. Returns the rays traced.
    pub fn visibility_at(
        &self,
        sampler: &VisibilitySampler,
        p: Vec3,
        frame: &VertexFrame,
        emit: impl FnMut(u32, u32, f32),
    ) -> u64 {
        sampler.point_entries(&self.bvh, self.origin(p, frame.normal), frame, emit)
    }
}
