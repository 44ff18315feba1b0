//! The cubemap layout shared by every stage (docs/DESIGN.md section 3).
//!
//! Faces are ordered +X, -X, +Y, -Y, +Z, -Z with the Vulkan/OpenGL orientation; texel
//! `k = face*R*R + row*R + col`; directions pass through texel centres. Each texel's solid
//! angle is computed exactly with the four-corner arctangent formula, so the sum over the
//! sphere is 4*pi to float precision.

use glam::DVec3;
use glam::Vec3;

/// A cubemap resolution `R` (texels per face edge). `N = 6 R^2` texels in all.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Cubemap {
    pub resolution: u32,
}

/// Face ids in storage order.
pub const FACE_NAMES: [&str; 6] = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"];

impl Cubemap {
    pub const fn new(resolution: u32) -> Self {
        Self { resolution }
    }

    /// Number of texels, `6 R^2`.
    pub fn texel_count(&self) -> usize {
        6 * (self.resolution as usize).pow(2)
    }

    /// `(face, row, col)` of texel `k`.
    pub fn texel_coords(&self, k: usize) -> (usize, usize, usize) {
        let r = self.resolution as usize;
        (k / (r * r), (k / r) % r, k % r)
    }

    /// Texel index of `(face, row, col)`.
    pub fn texel_index(&self, face: usize, row: usize, col: usize) -> usize {
        let r = self.resolution as usize;
        face * r * r + row * r + col
    }

    /// Unit direction through the centre of texel `k` (f64).
    pub fn texel_direction_f64(&self, k: usize) -> DVec3 {
        let (face, row, col) = self.texel_coords(k);
        let r = self.resolution as f64;
        let a = 2.0 * (col as f64 + 0.5) / r - 1.0;
        let b = 2.0 * (row as f64 + 0.5) / r - 1.0;
        face_point(face, a, b).normalize()
    }

    /// Unit direction through the centre of texel `k`.
    pub fn texel_direction(&self, k: usize) -> Vec3 {
        self.texel_direction_f64(k).as_vec3()
    }

    /// The texel whose square contains direction `d` (need not be normalised, must be non-zero).
    pub fn texel_of(&self, d: Vec3) -> usize {
        let (face, a, b) = face_coords(d.as_dvec3());
        let r = self.resolution as f64;
        let col = (((a + 1.0) * 0.5 * r).floor() as isize).clamp(0, r as isize - 1) as usize;
        let row = (((b + 1.0) * 0.5 * r).floor() as isize).clamp(0, r as isize - 1) as usize;
        self.texel_index(face, row, col)
    }

    /// Exact solid angle of texel `k` in steradians.
    pub fn texel_solid_angle(&self, k: usize) -> f64 {
        let (_, row, col) = self.texel_coords(k);
        let r = self.resolution as f64;
        let a0 = 2.0 * col as f64 / r - 1.0;
        let a1 = 2.0 * (col + 1) as f64 / r - 1.0;
        let b0 = 2.0 * row as f64 / r - 1.0;
        let b1 = 2.0 * (row + 1) as f64 / r - 1.0;
        corner_integral(a1, b1) - corner_integral(a0, b1) - corner_integral(a1, b0) + corner_integral(a0, b0)
    }

    /// Solid angles of all texels in storage order.
    pub fn solid_angles(&self) -> Vec<f64> {
        (0..self.texel_count()).map(|k| self.texel_solid_angle(k)).collect()
    }

    /// The four texels of the cubemap at twice this resolution that tile texel `k`
    /// (used for the 2x2 box-filtered visibility).
    pub fn children(&self, k: usize) -> [usize; 4] {
        let (face, row, col) = self.texel_coords(k);
        let fine = Cubemap::new(self.resolution * 2);
        [
            fine.texel_index(face, 2 * row, 2 * col),
            fine.texel_index(face, 2 * row, 2 * col + 1),
            fine.texel_index(face, 2 * row + 1, 2 * col),
            fine.texel_index(face, 2 * row + 1, 2 * col + 1),
        ]
    }
}

/// Point on the face-`face` plane at face coordinates `(a, b)` in [-1, 1]^2
/// (`a` grows with the column, `b` with the row), Vulkan/OpenGL orientation.
pub(crate) fn face_point(face: usize, a: f64, b: f64) -> DVec3 {
    match face {
        0 => DVec3::new(1.0, -b, -a),
        1 => DVec3::new(-1.0, -b, a),
        2 => DVec3::new(a, 1.0, b),
        3 => DVec3::new(a, -1.0, -b),
        4 => DVec3::new(a, -b, 1.0),
        _ => DVec3::new(-a, -b, -1.0),
    }
}

/// Inverse of [`face_point`]: the major-axis face of `d` and its face coordinates.
pub(crate) fn face_coords(d: DVec3) -> (usize, f64, f64) {
    let ad = d.abs();
    if ad.x >= ad.y && ad.x >= ad.z {
        if d.x > 0.0 {
            (0, -d.z / ad.x, -d.y / ad.x)
        } else {
            (1, d.z / ad.x, -d.y / ad.x)
        }
    } else if ad.y >= ad.z {
        if d.y > 0.0 {
            (2, d.x / ad.y, d.z / ad.y)
        } else {
            (3, d.x / ad.y, -d.z / ad.y)
        }
    } else if d.z > 0.0 {
        (4, d.x / ad.z, -d.y / ad.z)
    } else {
        (5, -d.x / ad.z, -d.y / ad.z)
    }
}

/// Exact solid angle of the rectangle `[a0, a1] x [b0, b1]` of one face's coordinates (the
/// four-corner formula of [`Cubemap::texel_solid_angle`], for any rectangle).
pub(crate) fn rect_solid_angle(a0: f64, a1: f64, b0: f64, b1: f64) -> f64 {
    corner_integral(a1, b1) - corner_integral(a0, b1) - corner_integral(a1, b0) + corner_integral(a0, b0)
}

/// Solid angle of the face region [0,x] x [0,y] (signed), the building block of the
/// four-corner formula: `atan2(x y, sqrt(x^2 + y^2 + 1))`.
fn corner_integral(x: f64, y: f64) -> f64 {
    (x * y).atan2((x * x + y * y + 1.0).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn solid_angles_sum_to_four_pi() {
        for r in [1, 2, 8, 32, 64] {
            let sum: f64 = Cubemap::new(r).solid_angles().iter().sum();
            assert!((sum - 4.0 * PI).abs() < 1e-12 * 4.0 * PI, "R={r}: {sum}");
        }
    }

    #[test]
    fn solid_angle_matches_direct_quadrature() {
        // Integrate the Jacobian 1/(1+a^2+b^2)^{3/2} over one corner texel by midpoint rule.
        let cm = Cubemap::new(4);
        let k = cm.texel_index(2, 0, 3);
        let n = 400;
        let (a0, b0, h) = (0.5, -1.0, 0.5);
        let mut s = 0.0;
        for i in 0..n {
            for j in 0..n {
                let a = a0 + h * (i as f64 + 0.5) / n as f64;
                let b = b0 + h * (j as f64 + 0.5) / n as f64;
                s += (1.0 + a * a + b * b).powf(-1.5) * (h / n as f64).powi(2);
            }
        }
        assert!((cm.texel_solid_angle(k) - s).abs() < 1e-7);
    }

    #[test]
    fn direction_round_trips_to_texel() {
        let cm = Cubemap::new(32);
        for k in 0..cm.texel_count() {
            assert_eq!(cm.texel_of(cm.texel_direction(k)), k);
            assert!((cm.texel_direction(k).length() - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn face_orientation_is_vulkan() {
        let cm = Cubemap::new(2);
        // +X face: row 0 is the top (+Y), col 0 is towards +Z.
        let d = cm.texel_direction(cm.texel_index(0, 0, 0));
        assert!(d.x > 0.0 && d.y > 0.0 && d.z > 0.0);
        // +Y face: row 0 towards -Z, col 0 towards -X.
        let d = cm.texel_direction(cm.texel_index(2, 0, 0));
        assert!(d.y > 0.0 && d.x < 0.0 && d.z < 0.0);
        // -Z face: col 0 towards +X.
        let d = cm.texel_direction(cm.texel_index(5, 1, 0));
        assert!(d.z < 0.0 && d.x > 0.0 && d.y < 0.0);
    }

    #[test]
    fn children_tile_parent() {
        let coarse = Cubemap::new(4);
        let fine = Cubemap::new(8);
        for k in 0..coarse.texel_count() {
            let kids = coarse.children(k);
            let sum: f64 = kids.iter().map(|&c| fine.texel_solid_angle(c)).sum();
            assert!((sum - coarse.texel_solid_angle(k)).abs() < 1e-13);
            for c in kids {
                assert_eq!(coarse.texel_of(fine.texel_direction(c)), k);
            }
        }
    }
}
