//! Small analytic meshes for tests and examples: a grid plane, a UV sphere, a closed box.

use crate::geometry::{MaterialIds, Mesh};
use glam::{Vec2, Vec3};

/// A `cells x cells` grid of size `size` in the XZ plane at y = 0, facing +Y, centred on the
/// origin, with UVs (u along +X).
pub fn grid_plane(cells: u32, size: f32) -> Mesh {
    let n = cells + 1;
    let mut positions = vec![];
    let mut uvs = vec![];
    for iz in 0..n {
        for ix in 0..n {
            let (u, v) = (ix as f32 / cells as f32, iz as f32 / cells as f32);
            positions.push(Vec3::new((u - 0.5) * size, 0.0, (v - 0.5) * size));
            uvs.push(Vec2::new(u, v));
        }
    }
    let mut triangles = vec![];
    for iz in 0..cells {
        for ix in 0..cells {
            let i = iz * n + ix;
            // Counter-clockwise seen from +Y.
            triangles.push([i, i + n, i + n + 1]);
            triangles.push([i, i + n + 1, i + 1]);
        }
    }
    Mesh { positions, uvs: Some(uvs), triangles, materials: None }
}

/// A UV sphere of `radius` centred at `centre` with `rings` latitude bands and `segments`
/// longitude segments, outward-facing, without UVs (poles are single vertices).
pub fn uv_sphere(centre: Vec3, radius: f32, rings: u32, segments: u32) -> Mesh {
    let mut positions = vec![centre + Vec3::Y * radius];
    for r in 1..rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = 2.0 * std::f32::consts::PI * s as f32 / segments as f32;
            positions.push(centre + radius * Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()));
        }
    }
    positions.push(centre - Vec3::Y * radius);
    let bottom = positions.len() as u32 - 1;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + (s % segments);
    let mut triangles = vec![];
    for s in 0..segments {
        triangles.push([0, ring(1, s + 1), ring(1, s)]);
        triangles.push([bottom, ring(rings - 1, s), ring(rings - 1, s + 1)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (ring(r, s), ring(r, s + 1), ring(r + 1, s), ring(r + 1, s + 1));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    Mesh { positions, uvs: None, triangles, materials: None }
}

/// An axis-aligned closed box, outward-facing (8 vertices, 12 triangles).
pub fn closed_box(min: Vec3, max: Vec3) -> Mesh {
    let p = |x: bool, y: bool, z: bool| {
        Vec3::new(if x { max.x } else { min.x }, if y { max.y } else { min.y }, if z { max.z } else { min.z })
    };
    let positions = vec![
        p(false, false, false),
        p(true, false, false),
        p(true, true, false),
        p(false, true, false),
        p(false, false, true),
        p(true, false, true),
        p(true, true, true),
        p(false, true, true),
    ];
    let triangles = vec![
        [0, 3, 2],
        [0, 2, 1], // -Z
        [4, 5, 6],
        [4, 6, 7], // +Z
        [0, 4, 7],
        [0, 7, 3], // -X
        [1, 2, 6],
        [1, 6, 5], // +X
        [3, 7, 6],
        [3, 6, 2], // +Y
        [0, 1, 5],
        [0, 5, 4], // -Y
    ];
    Mesh { positions, uvs: None, triangles, materials: None }
}

/// Concatenate meshes into one (UVs are kept only if every part has them). Materials are
/// merged by name when any part has them; parts without are [`MaterialIds::DEFAULT_NAME`].
pub fn merged(parts: &[Mesh]) -> Mesh {
    let mut out = Mesh { positions: vec![], uvs: Some(vec![]), triangles: vec![], materials: None };
    if parts.iter().any(|m| m.materials.is_some()) {
        let mut ids = MaterialIds::default();
        for m in parts {
            // Parts come from meshes whose ids fit u16, and a merged mesh of more than 65,536
            // names is not a test scene: interning cannot fail here.
            let mut intern = |n: &str| ids.intern(n).expect("fewer than 65,536 material names");
            let local: Vec<u16> = match &m.materials {
                Some(mm) => mm.names.iter().map(|n| intern(n)).collect(),
                None => vec![intern(MaterialIds::DEFAULT_NAME)],
            };
            match &m.materials {
                Some(mm) => ids.per_triangle.extend(mm.per_triangle.iter().map(|&i| local[i as usize])),
                None => ids.per_triangle.extend(std::iter::repeat_n(local[0], m.triangles.len())),
            }
        }
        out.materials = Some(ids);
    }
    for m in parts {
        let base = out.positions.len() as u32;
        out.positions.extend(&m.positions);
        out.triangles.extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
        match (&mut out.uvs, &m.uvs) {
            (Some(all), Some(uvs)) => all.extend(uvs),
            _ => out.uvs = None,
        }
    }
    out
}

/// A copy of `mesh` with every triangle using the material `name`.
pub fn with_material(mut mesh: Mesh, name: &str) -> Mesh {
    mesh.materials = Some(MaterialIds { names: vec![name.to_string()], per_triangle: vec![0; mesh.triangles.len()] });
    mesh
}

/// Cylindrical texture coordinates about the vertical axis through the mesh's bounding-box
/// centre: `u` = azimuth `atan2(x, z) / 2 pi + 1/2` times the mean radius' circumference,
/// `v` = height above the lowest vertex, both in world units (so a material's tiling is
/// patches per unit length and texels stay roughly square away from the poles).
/// Triangles that straddle the seam (u jumping by more than half a turn) get copies of their
/// low-u vertices at `u + circumference`, so interpolation never runs the long way round;
/// the copies are new vertices (the seam then has two frames per position).
pub fn cylindrical_uvs(mesh: &Mesh) -> Mesh {
    let (lo, hi) = mesh.bounds();
    let centre = 0.5 * (lo + hi);
    let radius = if mesh.positions.is_empty() {
        1.0
    } else {
        mesh.positions.iter().map(|p| Vec2::new(p.x - centre.x, p.z - centre.z).length()).sum::<f32>()
            / mesh.positions.len() as f32
    };
    let circumference = std::f32::consts::TAU * radius.max(1e-6);
    let uv_of = |p: Vec3| {
        let turn = (p.x - centre.x).atan2(p.z - centre.z) / std::f32::consts::TAU + 0.5;
        Vec2::new(turn * circumference, p.y - lo.y)
    };
    let mut positions = mesh.positions.clone();
    let mut uvs: Vec<Vec2> = mesh.positions.iter().map(|&p| uv_of(p)).collect();
    let mut copy_of: std::collections::HashMap<u32, u32> = Default::default();
    let mut triangles = mesh.triangles.clone();
    for t in &mut triangles {
        let us = t.map(|i| uvs[i as usize].x);
        let (min, max) =
            (us.iter().copied().fold(f32::INFINITY, f32::min), us.iter().copied().fold(f32::NEG_INFINITY, f32::max));
        if max - min > 0.5 * circumference {
            for i in t.iter_mut() {
                if uvs[*i as usize].x < 0.5 * circumference {
                    *i = *copy_of.entry(*i).or_insert_with(|| {
                        positions.push(positions[*i as usize]);
                        uvs.push(uvs[*i as usize] + Vec2::new(circumference, 0.0));
                        positions.len() as u32 - 1
                    });
                }
            }
        }
    }
    Mesh { positions, uvs: Some(uvs), triangles, materials: mesh.materials.clone() }
}

/// One level of midpoint subdivision: every triangle becomes four, edge midpoints are
/// shared between neighbours (so a closed mesh stays closed). Positions (and UVs) of the
/// new vertices are edge midpoints: the shape is unchanged, only the vertex density grows
/// (V + E vertices, 4F triangles), which is what the scaling study needs.
pub fn subdivide_midpoint(mesh: &Mesh) -> Mesh {
    use std::collections::HashMap;
    let mut positions = mesh.positions.clone();
    let mut uvs = mesh.uvs.clone();
    let mut midpoint: HashMap<(u32, u32), u32> = HashMap::new();
    let mut mid = |a: u32, b: u32, positions: &mut Vec<Vec3>, uvs: &mut Option<Vec<Vec2>>| -> u32 {
        let key = (a.min(b), a.max(b));
        *midpoint.entry(key).or_insert_with(|| {
            positions.push(0.5 * (positions[a as usize] + positions[b as usize]));
            if let Some(uv) = uvs {
                uv.push(0.5 * (uv[a as usize] + uv[b as usize]));
            }
            positions.len() as u32 - 1
        })
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for &[a, b, c] in &mesh.triangles {
        let ab = mid(a, b, &mut positions, &mut uvs);
        let bc = mid(b, c, &mut positions, &mut uvs);
        let ca = mid(c, a, &mut positions, &mut uvs);
        triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    let materials = mesh.materials.as_ref().map(|m| MaterialIds {
        names: m.names.clone(),
        per_triangle: m.per_triangle.iter().flat_map(|&i| [i; 4]).collect(),
    });
    Mesh { positions, uvs, triangles, materials }
}

/// The polygon soup of `mesh`: every triangle gets three vertices of its own, so no edge is
/// shared and every vertex's normal is its face's. Each triangle also gets its own texture
/// chart (the corners of cell `t` of a square grid of charts), so that the copies of a position
/// differ in their uv and a loader that welds exact duplicates (`Mesh::load_obj` does) keeps
/// them apart: the soup survives the round trip through an OBJ file, as the output of a
/// modeller that unwelds at every uv seam would. Positions are unchanged, so the surface and
/// what it occludes are the same; only the vertex count (3F) and the shading frames change.
pub fn unweld(mesh: &Mesh) -> Mesh {
    let f = mesh.triangles.len();
    let side = (f as f64).sqrt().ceil().max(1.0) as usize;
    let cell = 1.0 / side as f32;
    let mut positions = Vec::with_capacity(3 * f);
    let mut uvs = Vec::with_capacity(3 * f);
    for (t, tri) in mesh.triangles.iter().enumerate() {
        positions.extend(tri.map(|i| mesh.positions[i as usize]));
        let corner = Vec2::new((t % side) as f32, (t / side) as f32) * cell;
        uvs.extend([corner, corner + Vec2::new(0.9 * cell, 0.0), corner + Vec2::new(0.0, 0.9 * cell)]);
    }
    let triangles = (0..f as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
    Mesh { positions, uvs: Some(uvs), triangles, materials: mesh.materials.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sum over triangles of the signed volume: positive for outward-facing closed meshes.
    fn signed_volume(m: &Mesh) -> f32 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn closed_shapes_face_outward() {
        let b = closed_box(Vec3::splat(-1.0), Vec3::splat(1.0));
        assert!((signed_volume(&b) - 8.0).abs() < 1e-5);
        let s = uv_sphere(Vec3::ZERO, 1.0, 32, 64);
        let v = signed_volume(&s);
        assert!(v > 0.97 * 4.0 / 3.0 * std::f32::consts::PI && v < 4.0 / 3.0 * std::f32::consts::PI);
    }

    #[test]
    fn subdivision_quadruples_faces_and_keeps_the_shape() {
        let b = closed_box(Vec3::splat(-1.0), Vec3::splat(1.0));
        let s = subdivide_midpoint(&b);
        // V + E vertices (8 + 18), 4F triangles; still closed with the same volume.
        assert_eq!((s.positions.len(), s.triangles.len()), (26, 48));
        assert!((signed_volume(&s) - 8.0).abs() < 1e-5);
        let m = merged(&[grid_plane(2, 1.0), b]);
        assert_eq!((m.positions.len(), m.triangles.len()), (17, 20));
        assert!(m.uvs.is_none());
        assert!(m.triangles.iter().flatten().all(|&i| (i as usize) < m.positions.len()));
    }

    /// The soup has three vertices per triangle at the same positions (same volume), flat
    /// normals, and survives an OBJ round trip through the welding loader.
    #[test]
    fn unwelded_soup_keeps_its_vertices_through_an_obj_file() {
        let sphere = uv_sphere(Vec3::ZERO, 1.0, 8, 12);
        let soup = unweld(&sphere);
        let f = sphere.triangles.len();
        assert_eq!((soup.positions.len(), soup.triangles.len()), (3 * f, f));
        assert!((signed_volume(&soup) - signed_volume(&sphere)).abs() < 1e-6);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("soup.obj");
        std::fs::write(&path, soup.to_obj()).unwrap();
        let loaded = Mesh::load_obj(&path).unwrap();
        assert!(loaded.repairs.iter().all(|r| !r.contains("welded")), "{:?}", loaded.repairs);
        assert_eq!(loaded.mesh.positions.len(), 3 * f);
        let (frames, fallbacks) = crate::geometry::vertex_frames(&loaded.mesh);
        assert_eq!(fallbacks, 0);
        for (t, tri) in loaded.mesh.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| loaded.mesh.positions[i as usize]);
            let face = (b - a).cross(c - a).normalize();
            for &i in tri {
                let n = frames[i as usize].normal;
                assert!(n.dot(face) > 1.0 - 1e-5, "triangle {t}: vertex normal {n} against face {face}");
            }
        }
    }

    #[test]
    fn plane_faces_up() {
        let m = grid_plane(4, 2.0);
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            assert!((b - a).cross(c - a).y > 0.0);
        }
    }

    #[test]
    fn cylindrical_uvs_never_wrap_inside_a_triangle() {
        let sphere = uv_sphere(Vec3::new(0.3, 1.0, -0.2), 0.7, 12, 24);
        let m = cylindrical_uvs(&sphere);
        let uvs = m.uvs.as_ref().unwrap();
        let circumference = std::f32::consts::TAU * 0.7;
        assert_eq!(m.triangles.len(), sphere.triangles.len());
        let pole = |i: u32| i == 0 || i as usize == sphere.positions.len() - 1;
        // (Fans around a pole on the axis have no meaningful azimuth: skipped.)
        for t in m.triangles.iter().filter(|t| !t.iter().any(|&i| pole(i))) {
            let us = t.map(|i| uvs[i as usize].x);
            let spread = us.iter().copied().fold(f32::MIN, f32::max) - us.iter().copied().fold(f32::MAX, f32::min);
            // 24 segments: a triangle spans 1/24 of a turn.
            assert!(spread < 0.5 * circumference, "{us:?}");
            // Copies keep the position.
            for &i in t {
                assert!(
                    i as usize >= sphere.positions.len() || m.positions[i as usize] == sphere.positions[i as usize]
                );
            }
        }
        // v is the height above the lowest vertex, in world units.
        for (p, uv) in m.positions.iter().zip(uvs) {
            assert!((uv.y - (p.y - 0.3)).abs() < 1e-5);
        }
        assert!(m.positions.len() > sphere.positions.len(), "the seam was split");
    }
}
