//! Ray queries against a triangle mesh through an obvhs compressed wide BVH (CWBVH).
//!
//! Triangles are stored in BVH order so traversal touches them without an indirection;
//! [`Hit::triangle`] is translated back to the mesh's triangle index.

use glam::{Vec2, Vec3, Vec3A};
use obvhs::{
    cwbvh::{builder::build_cwbvh_from_tris, CwBvh},
    ray::{Ray, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};
use std::time::Duration;

/// A closest hit: mesh triangle index, ray distance, and barycentrics `(b1, b2)` so that the
/// point is `(1 - b1 - b2) v0 + b1 v1 + b2 v2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub triangle: u32,
    pub t: f32,
    pub barycentric: Vec2,
}

/// A BVH over a triangle soup.
pub struct SceneBvh {
    bvh: CwBvh,
    /// Triangles in BVH primitive order.
    tris: Vec<Triangle>,
    /// Mesh triangle index of each BVH primitive.
    tri_ids: Vec<u32>,
}

impl SceneBvh {
    /// Build over `triangles` (indices into `positions`). An empty mesh gives a BVH that
    /// nothing hits.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let soup: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: positions[t[0] as usize].into(),
                v1: positions[t[1] as usize].into(),
                v2: positions[t[2] as usize].into(),
            })
            .collect();
        if soup.is_empty() {
            return Self { bvh: CwBvh::default(), tris: vec![], tri_ids: vec![] };
        }
        let bvh = build_cwbvh_from_tris(&soup, BvhBuildParams::medium_build(), &mut Duration::default());
        let tri_ids: Vec<u32> = bvh.primitive_indices.clone();
        let tris = tri_ids.iter().map(|&i| soup[i as usize]).collect();
        Self { bvh, tris, tri_ids }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// True if any triangle intersects the open segment `origin + t dir`, `t in (tmin, tmax)`.
    /// `dir` must be unit length (or at least non-zero and finite).
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), tmin, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| self.tris[id].intersect(r))
    }

    /// The closest hit along `origin + t dir` with `t in (tmin, tmax)`.
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), tmin, tmax);
        let mut hit = RayHit::none();
        if !self.bvh.ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r)) {
            return None;
        }
        let id = hit.primitive_id as usize;
        let tri = &self.tris[id];
        let p = Vec3::from(ray.origin + ray.direction * hit.t);
        Some(Hit { triangle: self.tri_ids[id], t: hit.t, barycentric: barycentric(tri, p) })
    }
}

/// Barycentrics `(b1, b2)` of point `p` (assumed on the triangle's plane).
fn barycentric(tri: &Triangle, p: Vec3) -> Vec2 {
    let (a, b, c) = (Vec3::from(tri.v0), Vec3::from(tri.v1), Vec3::from(tri.v2));
    let (e1, e2, ep) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (dp1, dp2) = (ep.dot(e1), ep.dot(e2));
    let den = d11 * d22 - d12 * d12;
    if den.abs() < f32::MIN_POSITIVE {
        return Vec2::ZERO;
    }
    let b1 = (d22 * dp1 - d12 * dp2) / den;
    let b2 = (d11 * dp2 - d12 * dp1) / den;
    Vec2::new(b1, b2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        // Unit square in the XZ plane at y = 0, facing +Y.
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        (p, vec![[0, 3, 2], [0, 2, 1]])
    }

    #[test]
    fn hits_and_misses() {
        let (p, t) = quad();
        let bvh = SceneBvh::build(&p, &t);
        let down = Vec3::new(0.0, -1.0, 0.0);
        assert!(bvh.occluded(Vec3::new(0.3, 1.0, 0.6), down, 0.0, f32::INFINITY));
        assert!(!bvh.occluded(Vec3::new(1.3, 1.0, 0.6), down, 0.0, f32::INFINITY));
        assert!(!bvh.occluded(Vec3::new(0.3, 1.0, 0.6), down, 0.0, 0.5), "tmax respected");
        let h = bvh.closest_hit(Vec3::new(0.3, 2.0, 0.6), down, 0.0, f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        let tri = t[h.triangle as usize];
        let bary = h.barycentric;
        let q = p[tri[0] as usize] * (1.0 - bary.x - bary.y) + p[tri[1] as usize] * bary.x + p[tri[2] as usize] * bary.y;
        assert!((q - Vec3::new(0.3, 0.0, 0.6)).length() < 1e-5);
    }

    #[test]
    fn empty_scene_hits_nothing() {
        let bvh = SceneBvh::build(&[], &[]);
        assert!(!bvh.occluded(Vec3::ZERO, Vec3::X, 0.0, 1.0));
        assert!(bvh.closest_hit(Vec3::ZERO, Vec3::X, 0.0, 1.0).is_none());
    }
}
