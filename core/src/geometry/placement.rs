//! Where a mesh sits in f32: the one similarity every stage works under.
//!
//! Positions are f32, and several steps square or sum them (a bounding box diagonal, a ray
//! direction's length, obvhs's quantised wide-BVH boxes), so a mesh at 1e20 units overflows
//! (`1e20^2 > f32::MAX`) and one at 1e-6 units falls below the absolute epsilons of the
//! ray tracer. Everything biscale computes is invariant under a similarity applied to the
//! scene and the camera together (visibility, normals, light and view directions, the image
//! of a pinhole camera), so a mesh outside a comfortable range is moved and scaled into it
//! once, at load ([`condition`]), and every stage (the transfer's BVH, the shading BVH, the
//! camera, the reference) sees the same conditioned mesh. Config values in world units (a
//! camera position or target) go through the same [`Placement`].
//!
//! The scale is a power of two, so scaling itself rounds nothing; a mesh already in range
//! (diagonal in `[MIN_DIAGONAL, MAX_DIAGONAL]`, every coordinate within `MAX_COORDINATE`)
//! is left bit-for-bit as it is.

use super::Mesh;
use glam::{DVec3, Vec3};

/// Smallest bounding-box diagonal left as it is.
pub const MIN_DIAGONAL: f64 = 1e-3;
/// Largest bounding-box diagonal left as it is.
pub const MAX_DIAGONAL: f64 = 1e5;
/// Largest coordinate magnitude left as it is.
pub const MAX_COORDINATE: f64 = 1e5;

/// The similarity `p -> (p - centre) * scale` from the mesh's file coordinates to the ones
/// every stage uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub centre: DVec3,
    /// A power of two.
    pub scale: f64,
}

impl Placement {
    /// The placement that changes nothing.
    pub const IDENTITY: Self = Self { centre: DVec3::ZERO, scale: 1.0 };

    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }

    /// A point in file coordinates, in the conditioned ones.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        ((p.as_dvec3() - self.centre) * self.scale).as_vec3()
    }
}

/// Bounds and diagonal of `positions`, in f64 (no overflow for any finite f32 input).
fn bounds_f64(positions: &[Vec3]) -> Option<(DVec3, DVec3)> {
    let mut it = positions.iter().map(|p| p.as_dvec3());
    let first = it.next()?;
    Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
}

/// Move and scale `mesh` into range when it is not (see the module docs); the placement
/// used, which is [`Placement::IDENTITY`] for a mesh already in range (then nothing changed).
/// Positions must be finite (the loader checks).
pub fn condition(mesh: &mut Mesh) -> Placement {
    let Some((lo, hi)) = bounds_f64(&mesh.positions) else { return Placement::IDENTITY };
    let diagonal = (hi - lo).length();
    let far = lo.abs().max(hi.abs()).max_element();
    let in_range = (MIN_DIAGONAL..=MAX_DIAGONAL).contains(&diagonal) && far <= MAX_COORDINATE;
    if in_range || diagonal == 0.0 || !diagonal.is_finite() {
        return Placement::IDENTITY;
    }
    // Centre on the box and bring the diagonal into [0.5, 1) with a power of two.
    let scale = 2f64.powi(-(diagonal.log2().floor() as i32) - 1);
    let placement = Placement { centre: 0.5 * (lo + hi), scale };
    for p in &mut mesh.positions {
        *p = placement.apply(*p);
    }
    placement
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh_at(offset: f32, size: f32) -> Mesh {
        let p = |x: f32, y: f32, z: f32| Vec3::new(offset + x * size, offset + y * size, offset + z * size);
        Mesh {
            positions: vec![p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0), p(0.0, 0.0, 1.0)],
            uvs: None,
            triangles: vec![[0, 1, 2], [0, 3, 1]],
            materials: None,
        }
    }

    #[test]
    fn a_mesh_in_range_is_untouched() {
        let mut m = mesh_at(-3.0, 0.25);
        let before = m.positions.clone();
        assert!(condition(&mut m).is_identity());
        assert_eq!(m.positions, before);
    }

    #[test]
    fn huge_tiny_and_far_meshes_come_into_range_with_their_shape() {
        for (offset, size) in [(1e20, 1e20), (0.0, 1e-6), (1e14, 1e12), (0.0, 3e30), (-2e7, 1e4)] {
            let mut m = mesh_at(offset, size);
            let before = m.clone();
            let p = condition(&mut m);
            assert!(!p.is_identity(), "{offset} {size}");
            let (lo, hi) = bounds_f64(&m.positions).unwrap();
            let diagonal = (hi - lo).length();
            assert!((0.5..1.0).contains(&diagonal) || (diagonal - 1.0).abs() < 1e-6, "{offset} {size}: {diagonal}");
            assert!(lo.abs().max(hi.abs()).max_element() <= 1.0, "{offset} {size}");
            // The shape is kept: every edge scaled by the same power of two, to f32 rounding
            // of the input (the coordinates were rounded to f32 at `offset`).
            let rel = f64::from(f32::EPSILON) * (1.0 + offset.abs() as f64 / size as f64) * 4.0;
            for (a, b) in [(0, 1), (0, 2), (1, 3), (2, 3)] {
                let was = (before.positions[a].as_dvec3() - before.positions[b].as_dvec3()).length() * p.scale;
                let now = (m.positions[a].as_dvec3() - m.positions[b].as_dvec3()).length();
                assert!((was - now).abs() <= rel * was.max(1e-30), "{offset} {size}: edge {a}-{b}: {was} vs {now}");
            }
            assert_eq!(p.scale, 2f64.powi(p.scale.log2().round() as i32), "a power of two");
        }
    }
}
