//! A procedurally generated temple: flat architectural pieces with several materials, the
//! second bundled example (`configs/temple.toml`).
//!
//! Every piece is built from flat faces, each meshed as its own grid of cells no larger than
//! [`TempleOptions::cell`] (so per-vertex `L*` resolves the shadows of columns and roof) with
//! planar texture coordinates in world units (one unit of uv = one unit of length, so a
//! material's `tiling` is its patches per unit length on every piece). Faces do not share
//! vertices across edges: each keeps its own flat normal and tangent, as masonry should.
//!
//! Materials (OBJ `usemtl`): `ground`, `steps` (the three-step base), `columns` (octagonal
//! shafts), `marble` (plinths, capitals, architrave, pediments) and `roof` (the two slopes).

use biscale_core::geometry::{MaterialIds, Mesh};
use glam::{Vec2, Vec3};

/// Size parameters of the temple.
#[derive(Clone, Copy, Debug)]
pub struct TempleOptions {
    /// Columns along the front and the back, corners included.
    pub columns_x: u32,
    /// Columns along each side, corners included.
    pub columns_z: u32,
    /// Largest cell edge of the face grids, world units.
    pub cell: f32,
}

impl Default for TempleOptions {
    fn default() -> Self {
        Self { columns_x: 6, columns_z: 4, cell: 0.4 }
    }
}

/// Accumulates faces with their material (the temple's, and [`crate::chair`]'s).
#[derive(Default)]
pub(crate) struct Builder {
    positions: Vec<Vec3>,
    uvs: Vec<Vec2>,
    triangles: Vec<[u32; 3]>,
    materials: MaterialIds,
    current: u16,
    cell: f32,
    faces: u32,
}

impl Builder {
    /// A different uv origin for every face: neighbouring faces then never share a
    /// (position, uv) pair at their common corners, which the mesh loader would weld into one
    /// vertex with a normal averaged across the edge. (It also varies the patch's phase.)
    fn next_offset(&mut self) -> Vec2 {
        self.faces += 1;
        Vec2::new((self.faces as f32 * 0.618_034).fract(), (self.faces as f32 * 0.414_214).fract())
    }

    /// A builder whose face grids have cells no larger than `cell` (at least 0.002).
    pub(crate) fn new(cell: f32) -> Self {
        Builder { cell: cell.max(0.002), ..Default::default() }
    }

    pub(crate) fn material(&mut self, name: &str) {
        self.current = self.materials.intern(name).expect("a generated scene names a few materials");
    }

    /// The parallelogram `o + s a + t b` (`s, t` in `[0, 1]`), facing `a x b`, meshed as a grid
    /// of cells no larger than `cell`; uv = `(s |a|, t |b|)`.
    pub(crate) fn quad(&mut self, o: Vec3, a: Vec3, b: Vec3) {
        let (la, lb) = (a.length(), b.length());
        let na = ((la / self.cell).ceil() as u32).max(1);
        let nb = ((lb / self.cell).ceil() as u32).max(1);
        let base = self.positions.len() as u32;
        let offset = self.next_offset();
        for j in 0..=nb {
            for i in 0..=na {
                let (s, t) = (i as f32 / na as f32, j as f32 / nb as f32);
                self.positions.push(o + a * s + b * t);
                self.uvs.push(offset + Vec2::new(s * la, t * lb));
            }
        }
        let at = |i: u32, j: u32| base + j * (na + 1) + i;
        for j in 0..nb {
            for i in 0..na {
                // Counter-clockwise about a x b.
                self.triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                self.triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
                self.materials.per_triangle.extend([self.current; 2]);
            }
        }
    }

    /// The triangle `(p0, p1, p2)` (counter-clockwise about its normal), split into `n^2`
    /// triangles; planar uv along `p1 - p0` and its in-plane normal.
    fn triangle(&mut self, p0: Vec3, p1: Vec3, p2: Vec3) {
        let longest = (p1 - p0).length().max((p2 - p0).length()).max((p2 - p1).length());
        let n = ((longest / self.cell).ceil() as u32).max(1);
        let normal = (p1 - p0).cross(p2 - p0).normalize();
        let e1 = (p1 - p0).normalize();
        let e2 = normal.cross(e1);
        let offset = self.next_offset();
        let mut index = vec![];
        for j in 0..=n {
            let mut row = vec![];
            for i in 0..=(n - j) {
                let p = p0 + (p1 - p0) * (i as f32 / n as f32) + (p2 - p0) * (j as f32 / n as f32);
                row.push(self.positions.len() as u32);
                self.positions.push(p);
                self.uvs.push(offset + Vec2::new((p - p0).dot(e1), (p - p0).dot(e2)));
            }
            index.push(row);
        }
        for j in 0..n as usize {
            for i in 0..(n as usize - j) {
                self.triangles.push([index[j][i], index[j][i + 1], index[j + 1][i]]);
                self.materials.per_triangle.push(self.current);
                if i + 1 < n as usize - j {
                    self.triangles.push([index[j][i + 1], index[j + 1][i + 1], index[j + 1][i]]);
                    self.materials.per_triangle.push(self.current);
                }
            }
        }
    }

    /// The five visible faces of the box `[lo, hi]` (no bottom: it rests on something).
    pub(crate) fn open_box(&mut self, lo: Vec3, hi: Vec3) {
        let d = hi - lo;
        let (x, y, z) = (Vec3::X * d.x, Vec3::Y * d.y, Vec3::Z * d.z);
        self.quad(Vec3::new(lo.x, hi.y, lo.z), z, x); // +Y
        self.quad(Vec3::new(hi.x, lo.y, lo.z), y, z); // +X
        self.quad(lo, z, y); // -X
        self.quad(Vec3::new(lo.x, lo.y, hi.z), x, y); // +Z
        self.quad(lo, y, x); // -Z
    }

    /// The six faces of the box `[lo, hi]` (one that stands clear of everything).
    pub(crate) fn closed_box(&mut self, lo: Vec3, hi: Vec3) {
        self.open_box(lo, hi);
        let d = hi - lo;
        self.quad(lo, Vec3::X * d.x, Vec3::Z * d.z); // -Y
    }

    /// An octagonal prism of circumradius `r` from `y0` to `y1` about `(cx, cz)` (sides only).
    fn octagonal_shaft(&mut self, cx: f32, cz: f32, r: f32, y0: f32, y1: f32) {
        let corner = |k: u32| {
            let a = k as f32 * std::f32::consts::TAU / 8.0;
            Vec3::new(cx + r * a.cos(), y0, cz + r * a.sin())
        };
        for k in 0..8 {
            let (p, q) = (corner(k), corner(k + 1));
            self.quad(p, Vec3::Y * (y1 - y0), q - p);
        }
    }

    pub(crate) fn finish(self) -> Mesh {
        Mesh {
            positions: self.positions,
            uvs: Some(self.uvs),
            triangles: self.triangles,
            materials: Some(self.materials),
        }
    }
}

/// Build the temple (see the module docs). The base's footprint is centred on the origin,
/// +Y up, the front (the pediment with the entrance side) facing -Z.
pub fn build(opts: &TempleOptions) -> Mesh {
    let mut b = Builder::new(opts.cell.max(0.02));
    let (nx, nz) = (opts.columns_x.max(2), opts.columns_z.max(2));
    let spacing = 1.0f32;
    // Column centres span (nx - 1) x (nz - 1) spacings; the top step overhangs them by 0.6.
    let half = Vec2::new((nx - 1) as f32 * spacing / 2.0, (nz - 1) as f32 * spacing / 2.0);
    let step_h = 0.18;
    let steps = 3;

    b.material("ground");
    let g = half + Vec2::splat(2.2);
    b.quad(Vec3::new(-g.x, 0.0, -g.y), Vec3::Z * 2.0 * g.y, Vec3::X * 2.0 * g.x);

    b.material("steps");
    for k in 0..steps {
        let grow = 0.6 + 0.3 * (steps - 1 - k) as f32;
        let lo = Vec3::new(-half.x - grow, k as f32 * step_h, -half.y - grow);
        let hi = Vec3::new(half.x + grow, (k + 1) as f32 * step_h, half.y + grow);
        b.open_box(lo, hi);
    }
    let floor = steps as f32 * step_h;

    let (radius, plinth_h, shaft_h, capital_h) = (0.2f32, 0.1f32, 2.2f32, 0.12f32);
    let centres: Vec<Vec2> = (0..nx)
        .flat_map(|i| (0..nz).map(move |j| (i, j)))
        .filter(|&(i, j)| i == 0 || j == 0 || i == nx - 1 || j == nz - 1)
        .map(|(i, j)| Vec2::new(-half.x + i as f32 * spacing, -half.y + j as f32 * spacing))
        .collect();
    b.material("columns");
    for c in &centres {
        b.octagonal_shaft(c.x, c.y, radius, floor + plinth_h, floor + plinth_h + shaft_h);
    }
    b.material("marble");
    let top = floor + plinth_h + shaft_h;
    for c in &centres {
        let w = radius * 1.3;
        b.open_box(Vec3::new(c.x - w, floor, c.y - w), Vec3::new(c.x + w, floor + plinth_h, c.y + w));
        let w = radius * 1.45;
        b.open_box(Vec3::new(c.x - w, top, c.y - w), Vec3::new(c.x + w, top + capital_h, c.y + w));
    }
    // Architrave: a beam all round (a box whose underside is visible between the columns).
    let beam_lo = Vec3::new(-half.x - 0.35, top + capital_h, -half.y - 0.35);
    let beam_hi = Vec3::new(half.x + 0.35, top + capital_h + 0.4, half.y + 0.35);
    b.open_box(beam_lo, beam_hi);
    let d = beam_hi - beam_lo;
    b.quad(beam_lo, Vec3::X * d.x, Vec3::Z * d.z); // underside, facing -Y

    // Gable roof, ridge along X, with pediments at both ends.
    let overhang = 0.15;
    let (y0, rise) = (beam_hi.y, 0.9f32);
    let (x0, x1) = (beam_lo.x - overhang, beam_hi.x + overhang);
    let (z0, z1) = (beam_lo.z - overhang, beam_hi.z + overhang);
    let zc = 0.5 * (z0 + z1);
    b.material("roof");
    b.quad(Vec3::new(x0, y0, z0), Vec3::new(0.0, rise, zc - z0), Vec3::X * (x1 - x0));
    b.quad(Vec3::new(x0, y0, z1), Vec3::X * (x1 - x0), Vec3::new(0.0, rise, zc - z1));
    b.material("marble");
    // Pediments (facing -X and +X), set back to the beam's ends.
    let (px0, px1) = (beam_lo.x, beam_hi.x);
    b.triangle(Vec3::new(px0, y0, z0), Vec3::new(px0, y0, z1), Vec3::new(px0, y0 + rise, zc));
    b.triangle(Vec3::new(px1, y0, z1), Vec3::new(px1, y0, z0), Vec3::new(px1, y0 + rise, zc));
    b.finish()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A generated scene's materials are `names` in order, every triangle has one and each
    /// has triangles, and loading it repairs nothing: no degenerate triangles, no duplicated
    /// vertices within a face.
    pub(crate) fn assert_materials_and_no_repairs(mesh: &Mesh, names: &[&str], label: &str) {
        let m = mesh.materials.as_ref().unwrap();
        assert_eq!(m.names, names);
        assert_eq!(m.per_triangle.len(), mesh.triangles.len());
        assert!(m.counts().iter().all(|&c| c > 0), "{:?}", m.counts());
        let load = Mesh::from_parts_with_materials(
            mesh.positions.clone(),
            mesh.uvs.clone(),
            mesh.triangles.clone(),
            mesh.materials.clone(),
            label,
        )
        .unwrap();
        assert!(load.repairs.is_empty(), "{:?}", load.repairs);
    }

    #[test]
    fn faces_face_outward_and_every_triangle_has_a_material() {
        let mesh = build(&TempleOptions::default());
        assert_materials_and_no_repairs(&mesh, &["ground", "steps", "columns", "marble", "roof"], "temple");
        let m = mesh.materials.as_ref().unwrap();
        // Outward: the ground faces +Y; every roof triangle faces up; each column triangle's
        // normal points away from its shaft axis (no face points into the solid).
        let normal = |t: &[u32; 3]| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            (b - a).cross(c - a).normalize()
        };
        for (t, &id) in mesh.triangles.iter().zip(&m.per_triangle) {
            let n = normal(t);
            match m.names[id as usize].as_str() {
                "ground" => assert!(n.dot(Vec3::Y) > 0.999),
                "roof" => assert!(n.y > 0.5, "{n}"),
                "columns" => {
                    assert!(n.y.abs() < 1e-5, "shaft sides are vertical: {n}");
                    // Away from the nearest column axis (columns sit on a unit lattice
                    // offset by half a spacing in x for 6 columns, none in z for 4... so
                    // use the axis of the shaft: the nearest lattice point in xz).
                    let c = t.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / 3.0;
                    let axis = Vec3::new((c.x - 0.5).round() + 0.5, c.y, (c.z - 0.5).round() + 0.5);
                    assert!(n.dot(c - axis) > 0.0, "column face points inward: {n} at {c}");
                }
                _ => {}
            }
        }
        // The uv is in world units (up to a per-face offset): along any ground edge the uv
        // distance equals the length.
        let uvs = mesh.uvs.as_ref().unwrap();
        let t = mesh.triangles[0];
        let (p0, p1) = (mesh.positions[t[0] as usize], mesh.positions[t[1] as usize]);
        assert!(((uvs[t[0] as usize] - uvs[t[1] as usize]).length() - (p0 - p1).length()).abs() < 1e-5);
    }
}
