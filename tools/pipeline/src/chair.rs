//! A procedurally generated chair on a wooden floor: Table I's "Chair" analogue (the paper's
//! Fig. 6 scene: 16,101 vertices, three measured BTFs), for `biscale reproduce`.
//!
//! Built like the temple ([`crate::temple`]) from flat faces, each meshed as its own grid of
//! cells no larger than [`ChairOptions::cell`], with planar texture coordinates in world units
//! and no vertex shared across an edge. Materials (OBJ `usemtl`): `floor` (the boards under
//! it), `wood` (legs, stretchers, seat frame, back posts and top rail) and `fabric` (the seat
//! and back cushions). The chair stands on the origin, +Y up, its seat front facing -Z; the
//! seat is 0.5 units square at 0.45 units above the floor, the back 1.0 unit high.

use crate::temple::Builder;
use biscale_core::geometry::Mesh;
use glam::Vec3;

/// Size parameter of the chair.
#[derive(Clone, Copy, Debug)]
pub struct ChairOptions {
    /// Largest cell edge of the face grids, world units.
    pub cell: f32,
}

impl Default for ChairOptions {
    fn default() -> Self {
        Self { cell: 0.05 }
    }
}

/// One box of the chair: its material, its corners, and whether its underside is meshed
/// (everything but the legs, which stand on the floor).
struct Part {
    material: &'static str,
    lo: Vec3,
    hi: Vec3,
    underside: bool,
}

impl Part {
    /// Its faces, in its material.
    fn mesh_into(&self, b: &mut Builder) {
        b.material(self.material);
        match self.underside {
            true => b.closed_box(self.lo, self.hi),
            false => b.open_box(self.lo, self.hi),
        }
    }
}

/// The chair's boxes, wood before fabric.
fn parts() -> Vec<Part> {
    let v = Vec3::new;
    let part = |material, lo, hi, underside| Part { material, lo, hi, underside };
    let mut p = vec![];
    let (half, leg, seat_y, frame_h) = (0.25f32, 0.05f32, 0.45f32, 0.06f32);
    // Legs at the four corners; the rear two run on up as the back posts.
    for (x, z) in [(-1.0f32, -1.0f32), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (cx, cz) = (x * (half - leg / 2.0), z * (half - leg / 2.0));
        let top = if z > 0.0 { 1.0 } else { seat_y - frame_h };
        p.push(part("wood", v(cx - leg / 2.0, 0.0, cz - leg / 2.0), v(cx + leg / 2.0, top, cz + leg / 2.0), false));
    }
    // Stretchers between the legs, clear of the floor.
    let (s, sy) = (0.03f32, 0.14f32);
    let inner = half - leg;
    for z in [-1.0f32, 1.0] {
        let cz = z * (half - leg / 2.0);
        p.push(part("wood", v(-inner, sy, cz - s / 2.0), v(inner, sy + s, cz + s / 2.0), true));
    }
    for x in [-1.0f32, 1.0] {
        let cx = x * (half - leg / 2.0);
        p.push(part("wood", v(cx - s / 2.0, sy + 0.05, -inner), v(cx + s / 2.0, sy + 0.05 + s, inner), true));
    }
    // The seat frame, between the back posts, and the top rail between them.
    let back = half - leg;
    p.push(part("wood", v(-half, seat_y - frame_h, -half), v(half, seat_y, back), true));
    p.push(part("wood", v(-inner, 0.88, back), v(inner, 0.98, half), true));
    // The seat cushion on the frame, and the back cushion against the posts' front.
    p.push(part("fabric", v(-half + 0.01, seat_y, -half + 0.01), v(half - 0.01, seat_y + 0.07, back - 0.005), false));
    p.push(part("fabric", v(-inner + 0.005, seat_y + 0.12, back - 0.06), v(inner - 0.005, 0.86, back), true));
    p
}

/// Build the chair (see the module docs).
pub fn build(opts: &ChairOptions) -> Mesh {
    let mut b = Builder::new(opts.cell);
    b.material("floor");
    let f = 0.9f32;
    b.quad(Vec3::new(-f, 0.0, -f), Vec3::Z * 2.0 * f, Vec3::X * 2.0 * f);
    for p in parts() {
        p.mesh_into(&mut b);
    }
    b.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chair_has_three_materials_faces_outward_and_loads_without_repairs() {
        let mesh = build(&ChairOptions::default());
        crate::temple::tests::assert_materials_and_no_repairs(&mesh, &["floor", "wood", "fabric"], "chair");
        let m = mesh.materials.as_ref().unwrap();
        // The floor faces up; every face of every box points away from the box's centre, and
        // a box has an underside exactly when it is meant to (not the legs on the floor, nor
        // the seat cushion on its frame).
        let normal = |mesh: &Mesh, t: &[u32; 3]| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            ((b - a).cross(c - a).normalize(), (a + b + c) / 3.0)
        };
        for (t, &id) in mesh.triangles.iter().zip(&m.per_triangle) {
            if m.names[id as usize] == "floor" {
                assert!(normal(&mesh, t).0.dot(Vec3::Y) > 0.999);
            }
        }
        for p in parts() {
            let mut b = Builder::new(0.05);
            p.mesh_into(&mut b);
            let one = b.finish();
            let centre = (p.lo + p.hi) / 2.0;
            let mut down = 0;
            for t in &one.triangles {
                let (n, at) = normal(&one, t);
                assert!(n.dot(at - centre) > 0.0, "a face of the box at {centre} points inward: {n} at {at}");
                down += (n.y < -0.999) as usize;
            }
            assert_eq!(down > 0, p.underside, "box at {centre}");
        }
        // Finer cells, more vertices: the grid size sets the count (reproduce picks it).
        let fine = build(&ChairOptions { cell: 0.025 });
        assert!(fine.vertex_count() > 3 * mesh.vertex_count(), "{} vs {}", fine.vertex_count(), mesh.vertex_count());
    }
}
