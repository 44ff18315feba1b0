//! Triangulating one polygon face of an OBJ file. Convex polygons become fans from their
//! first corner (what every OBJ reader does). A non-convex polygon's fan would hold triangles
//! outside the polygon, wound the wrong way, so it is cut by ear clipping in its own plane
//! instead. The triangles keep the polygon's winding either way.

use glam::{DVec2, DVec3, Vec3};

/// Emit the triangles of the polygon `corners` (in order) as corner indices. Returns whether
/// the polygon was non-convex (cut by ear clipping). Degenerate polygons (no area, so no
/// plane) are fanned; the mesh validation drops their zero-area triangles.
pub fn triangulate(corners: &[Vec3], mut emit: impl FnMut([usize; 3])) -> bool {
    let n = corners.len();
    let fan = |emit: &mut dyn FnMut([usize; 3]), idx: &[usize]| {
        for i in 1..idx.len().saturating_sub(1) {
            emit([idx[0], idx[i], idx[i + 1]]);
        }
    };
    let all: Vec<usize> = (0..n).collect();
    if n <= 3 {
        fan(&mut emit, &all);
        return false;
    }
    let p: Vec<DVec3> = corners.iter().map(|c| c.as_dvec3()).collect();
    // Newell's normal: the polygon's area vector, robust for any simple polygon.
    let normal: DVec3 = (0..n).map(|i| p[i].cross(p[(i + 1) % n])).sum();
    let Some(normal) = normal.try_normalize() else {
        fan(&mut emit, &all);
        return false;
    };
    // In-plane coordinates with u x v = normal: the polygon runs counter-clockwise in them.
    let u = normal.any_orthonormal_vector();
    let v = normal.cross(u);
    let q: Vec<DVec2> = p.iter().map(|x| DVec2::new(x.dot(u), x.dot(v))).collect();
    let turn = |a: usize, b: usize, c: usize| (q[b] - q[a]).perp_dot(q[c] - q[b]);
    let scale = q.iter().map(|x| (*x - q[0]).length_squared()).fold(0.0, f64::max);
    let eps = 1e-12 * scale;
    if (0..n).all(|i| turn((i + n - 1) % n, i, (i + 1) % n) >= -eps) {
        fan(&mut emit, &all);
        return false;
    }
    let mut left = all;
    while left.len() > 3 {
        let m = left.len();
        let ear = (0..m).find(|&i| {
            let (a, b, c) = (left[(i + m - 1) % m], left[i], left[(i + 1) % m]);
            turn(a, b, c) > eps
                && left.iter().all(|&x| x == a || x == b || x == c || !inside_or_on(q[x], q[a], q[b], q[c]))
        });
        let Some(i) = ear else {
            // Self-intersecting or collinear remains: no ear; fan what is left.
            fan(&mut emit, &left);
            return true;
        };
        emit([left[(i + m - 1) % m], left[i], left[(i + 1) % m]]);
        left.remove(i);
    }
    emit([left[0], left[1], left[2]]);
    true
}

/// Whether `x` lies in the counter-clockwise triangle `a b c` or on its edges.
fn inside_or_on(x: DVec2, a: DVec2, b: DVec2, c: DVec2) -> bool {
    (b - a).perp_dot(x - a) >= 0.0 && (c - b).perp_dot(x - b) >= 0.0 && (a - c).perp_dot(x - c) >= 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tris(corners: &[Vec3]) -> (Vec<[usize; 3]>, bool) {
        let mut out = vec![];
        let nonconvex = triangulate(corners, |t| out.push(t));
        (out, nonconvex)
    }

    fn area2(a: DVec2, b: DVec2, c: DVec2) -> f64 {
        (b - a).perp_dot(c - a)
    }

    #[test]
    fn convex_polygons_are_fans_from_the_first_corner() {
        let quad = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        assert_eq!(tris(&quad), (vec![[0, 1, 2], [0, 2, 3]], false));
        assert_eq!(tris(&quad[..3]), (vec![[0, 1, 2]], false));
    }

    #[test]
    fn a_non_convex_polygon_is_covered_exactly_by_triangles_of_its_own_winding() {
        // Regression (hostile input): the fan of this chevron from corner 0 produced a
        // triangle outside the polygon with reversed winding.
        let flat: [(f32, f32); 5] = [(0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (2.0, 1.0), (0.0, 3.0)];
        let area = 4.0 * 3.0 - 0.5 * 4.0 * 2.0; // the box minus the notch
                                                // In the xy plane and tilted into 3D (the in-plane frame must not matter).
        let tilt = glam::Quat::from_euler(glam::EulerRot::XYZ, 0.7, -0.4, 1.9);
        for rot in [glam::Quat::IDENTITY, tilt] {
            let corners: Vec<Vec3> = flat.iter().map(|&(x, y)| rot * Vec3::new(x, y, 0.0)).collect();
            let (t, nonconvex) = tris(&corners);
            assert!(nonconvex);
            assert_eq!(t.len(), 3);
            let q: Vec<DVec2> = flat.iter().map(|&(x, y)| DVec2::new(x as f64, y as f64)).collect();
            let mut sum = 0.0;
            for &[a, b, c] in &t {
                let a2 = area2(q[a], q[b], q[c]);
                assert!(a2 > 0.0, "triangle {a} {b} {c} is wound against the polygon");
                sum += a2 / 2.0;
                // The centroid lies inside the polygon: not in the notch.
                let g = (q[a] + q[b] + q[c]) / 3.0;
                assert!(g.y <= 1.0 + (g.x - 2.0).abs(), "centroid {g} in the notch");
            }
            assert!((sum - area).abs() < 1e-4, "area {sum} vs {area}");
        }
    }

    #[test]
    fn degenerate_polygons_are_fanned() {
        let line = [Vec3::ZERO, Vec3::X, Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.0, 0.0, 0.0)];
        assert_eq!(tris(&line), (vec![[0, 1, 2], [0, 2, 3]], false));
    }
}
