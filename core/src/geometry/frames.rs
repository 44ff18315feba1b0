//! Per-vertex orthonormal frames (docs/DESIGN.md section 3): the area-weighted smooth normal,
//! a tangent from the UV parameterization where the mesh has one (anisotropic BTFs need it),
//! otherwise the projection of a fixed oblique axis ([`TANGENT_REFERENCE`]), so tangents vary
//! smoothly between neighbouring vertices; a basis from the normal alone (Duff et al. 2017,
//! "Building an Orthonormal Basis, Revisited") is the fallback where that axis is parallel to
//! the normal.

use crate::geometry::Mesh;
use glam::{DVec3, Vec3};

/// Orthonormal frame: local +X = tangent, +Y = bitangent, +Z = normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexFrame {
    pub tangent: Vec3,
    pub bitangent: Vec3,
    pub normal: Vec3,
}

impl VertexFrame {
    /// A frame around unit normal `n` with the branchless basis of Duff et al.
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let tangent = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let bitangent = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { tangent, bitangent, normal: n }
    }

    /// A frame around unit normal `n` whose tangent is `t` made orthogonal to `n`
    /// (Gram-Schmidt); falls back to [`Self::from_normal`] when `t` is (nearly) parallel to `n`.
    pub fn from_normal_tangent(n: Vec3, t: Vec3) -> Self {
        // In f64: when t is nearly parallel to n the f32 residual would lose orthogonality.
        let (nd, td) = (n.as_dvec3().normalize(), t.as_dvec3());
        let t = td - nd * nd.dot(td);
        let len = t.length();
        // Negated on purpose: a NaN length must also fall back to the normal-only frame.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(len > 1e-6 * td.length()) {
            return Self::from_normal(n);
        }
        let tangent = t / len;
        Self { tangent: tangent.as_vec3(), bitangent: nd.cross(tangent).as_vec3(), normal: n }
    }

    /// World direction expressed in this frame.
    #[inline]
    pub fn to_local(&self, w: Vec3) -> Vec3 {
        Vec3::new(w.dot(self.tangent), w.dot(self.bitangent), w.dot(self.normal))
    }

    /// Local direction expressed in world space.
    #[inline]
    pub fn to_world(&self, l: Vec3) -> Vec3 {
        self.tangent * l.x + self.bitangent * l.y + self.normal * l.z
    }
}

/// Tangent direction for meshes without UVs: the tangent is this fixed axis projected onto
/// the tangent plane. Neighbouring vertices then get nearly the same tangent, which matters
/// because `L*` is binned in each vertex's own frame and interpolated across triangles: a
/// per-vertex basis such as Duff et al.'s flips by 180 degrees across the whole `n.z = 0`
/// equator, mixing unrelated bins there. A fixed axis is singular only where the normal is
/// parallel to it (any continuous tangent field on a sphere has such points); an oblique
/// axis keeps those points away from axis-aligned floors and walls.
pub const TANGENT_REFERENCE: Vec3 = Vec3::new(0.267_261_24, 0.534_522_5, 0.801_783_7);

/// Frames of every vertex, and the number of vertices whose normal had to fall back to +Y
/// because their incident triangles' normals cancel (or they have none).
pub fn vertex_frames(mesh: &Mesh) -> (Vec<VertexFrame>, usize) {
    let n = mesh.positions.len();
    let mut normals = vec![DVec3::ZERO; n];
    let mut tangents = vec![DVec3::ZERO; n];
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize].as_dvec3());
        // |cross| = 2 * area: summing raw cross products is the area weighting.
        let face = (b - a).cross(c - a);
        for &i in tri {
            normals[i as usize] += face;
        }
        if let Some(uvs) = &mesh.uvs {
            let [ua, ub, uc] = tri.map(|i| uvs[i as usize].as_dvec2());
            let (e1, e2) = (b - a, c - a);
            let (d1, d2) = (ub - ua, uc - ua);
            let det = d1.x * d2.y - d2.x * d1.y;
            if det.abs() > 1e-20 {
                // dP/du, weighted by the triangle's area like the normal.
                let t = (e1 * d2.y - e2 * d1.y) / det;
                let w = face.length() / t.length().max(1e-300);
                for &i in tri {
                    tangents[i as usize] += t * w;
                }
            }
        }
    }
    let mut fallbacks = 0;
    let frames = normals
        .iter()
        .zip(&tangents)
        .map(|(nrm, tan)| {
            let len = nrm.length();
            let normal = if len > 0.0 && len.is_finite() {
                (*nrm / len).as_vec3()
            } else {
                fallbacks += 1;
                Vec3::Y
            };
            if mesh.uvs.is_some() {
                VertexFrame::from_normal_tangent(normal, tan.as_vec3())
            } else {
                VertexFrame::from_normal_tangent(normal, TANGENT_REFERENCE)
            }
        })
        .collect();
    (frames, fallbacks)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn assert_orthonormal(f: &VertexFrame) {
        for (a, b) in [(f.tangent, f.bitangent), (f.tangent, f.normal), (f.bitangent, f.normal)] {
            assert!(a.dot(b).abs() < 1e-5, "{f:?}");
        }
        for v in [f.tangent, f.bitangent, f.normal] {
            assert!((v.length() - 1.0).abs() < 1e-5, "{f:?}");
        }
        assert!((f.tangent.cross(f.bitangent) - f.normal).length() < 1e-5, "right-handed: {f:?}");
    }

    #[test]
    fn frames_are_orthonormal_for_random_and_axis_normals() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut normals: Vec<Vec3> = (0..10000)
            .map(|_| Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)))
            .filter(|v| v.length() > 1e-3)
            .map(|v| v.normalize())
            .collect();
        normals.extend([
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.0, -1e-7, -1.0).normalize(),
        ]);
        for n in normals {
            let f = VertexFrame::from_normal(n);
            assert_orthonormal(&f);
            let w = Vec3::new(0.3, -0.5, 0.8).normalize();
            assert!((f.to_world(f.to_local(w)) - w).length() < 1e-5);
            assert_orthonormal(&VertexFrame::from_normal_tangent(n, Vec3::new(0.2, 0.9, -0.1)));
            assert_orthonormal(&VertexFrame::from_normal_tangent(n, n));
        }
    }

    #[test]
    fn tangents_without_uvs_vary_smoothly_across_the_equator() {
        // Two nearby normals on either side of n.z = 0 must get nearly the same tangent.
        let mesh = |n: Vec3| Mesh {
            positions: vec![Vec3::ZERO, n.any_orthonormal_vector(), n.cross(n.any_orthonormal_vector())],
            uvs: None,
            triangles: vec![[0, 1, 2]],
            materials: None,
        };
        let a = vertex_frames(&mesh(Vec3::new(0.6, 0.8, 0.001).normalize())).0[0];
        let b = vertex_frames(&mesh(Vec3::new(0.6, 0.8, -0.001).normalize())).0[0];
        assert!(a.tangent.dot(b.tangent) > 0.999, "{a:?} {b:?}");
    }

    #[test]
    fn mesh_frames_follow_uvs() {
        // A quad in the XZ plane (normal +Y) with u along +X.
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, 1.0), Vec3::Z],
            uvs: Some(vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE, glam::Vec2::Y]),
            triangles: vec![[0, 3, 2], [0, 2, 1]],
            materials: None,
        };
        let (frames, fallbacks) = vertex_frames(&mesh);
        assert_eq!(fallbacks, 0);
        for f in frames {
            assert!((f.normal - Vec3::Y).length() < 1e-6);
            assert!((f.tangent - Vec3::X).length() < 1e-6);
            assert_orthonormal(&f);
        }
    }
}
