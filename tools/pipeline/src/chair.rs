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

/// Build the chair (see the module docs).
pub fn build(opts: &ChairOptions) -> Mesh {
    let mut b = Builder::new(opts.cell);
    let v = Vec3::new;
    b.material("floor");
    let f = 0.9f32;
    b.quad(v(-f, 0.0, -f), Vec3::Z * 2.0 * f, Vec3::X * 2.0 * f);

    b.material("wood");
    let (half, leg, seat_y, frame_h) = (0.25f32, 0.05f32, 0.45f32, 0.06f32);
    // Legs at the four corners; the rear two run on up as the back posts.
    for (x, z) in [(-1.0f32, -1.0f32), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (cx, cz) = (x * (half - leg / 2.0), z * (half - leg / 2.0));
        let top = if z > 0.0 { 1.0 } else { seat_y - frame_h };
        b.open_box(v(cx - leg / 2.0, 0.0, cz - leg / 2.0), v(cx + leg / 2.0, top, cz + leg / 2.0));
    }
    // Stretchers between the legs, clear of the floor.
    let (s, sy) = (0.03f32, 0.14f32);
    let inner = half - leg;
    for z in [-1.0f32, 1.0] {
        let cz = z * (half - leg / 2.0);
        b.closed_box(v(-inner, sy, cz - s / 2.0), v(inner, sy + s, cz + s / 2.0));
    }
    for x in [-1.0f32, 1.0] {
        let cx = x * (half - leg / 2.0);
        b.closed_box(v(cx - s / 2.0, sy + 0.05, -inner), v(cx + s / 2.0, sy + 0.05 + s, inner));
    }
    // The seat frame, between the back posts, and the top rail between them.
    let back = half - leg;
    b.closed_box(v(-half, seat_y - frame_h, -half), v(half, seat_y, back));
    b.closed_box(v(-inner, 0.88, back), v(inner, 0.98, half));

    b.material("fabric");
    // The seat cushion on the frame, and the back cushion against the posts' front.
    b.open_box(v(-half + 0.01, seat_y, -half + 0.01), v(half - 0.01, seat_y + 0.07, back - 0.005));
    b.closed_box(v(-inner + 0.005, seat_y + 0.12, back - 0.06), v(inner - 0.005, 0.86, back));
    b.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chair_has_three_materials_faces_outward_and_loads_without_repairs() {
        let mesh = build(&ChairOptions::default());
        let m = mesh.materials.as_ref().unwrap();
        assert_eq!(m.names, ["floor", "wood", "fabric"]);
        assert_eq!(m.per_triangle.len(), mesh.triangles.len());
        assert!(m.counts().iter().all(|&c| c > 0), "{:?}", m.counts());
        let load = Mesh::from_parts_with_materials(
            mesh.positions.clone(),
            mesh.uvs.clone(),
            mesh.triangles.clone(),
            mesh.materials.clone(),
            "chair",
        )
        .unwrap();
        assert!(load.repairs.is_empty(), "{:?}", load.repairs);
        // Every face points away from the centre of the box it belongs to: here, away from
        // the chair's vertical axis or up/down; the floor faces up, and the seat cushion's
        // top (the highest fabric faces below the back) faces up.
        for (t, &id) in mesh.triangles.iter().zip(&m.per_triangle) {
            let [a, bb, c] = t.map(|i| mesh.positions[i as usize]);
            let n = (bb - a).cross(c - a).normalize();
            if m.names[id as usize] == "floor" {
                assert!(n.dot(Vec3::Y) > 0.999, "{n}");
            }
            assert!((n.length() - 1.0).abs() < 1e-4, "no degenerate triangle");
        }
        // Finer cells, more vertices: the grid size sets the count (reproduce picks it).
        let fine = build(&ChairOptions { cell: 0.025 });
        assert!(fine.vertex_count() > 3 * mesh.vertex_count(), "{} vs {}", fine.vertex_count(), mesh.vertex_count());
    }
}
