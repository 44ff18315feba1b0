//! Winding consistency: faces wound against the rest of their surface (a partly inside-out
//! mesh). Checked, never changed: the loader reports what it finds as a line in
//! [`super::MeshLoad::repairs`] and leaves every face as it is.
//!
//! Two triangles that share an edge agree on their orientation when they traverse that edge in
//! opposite directions. Faces are joined into connected components across the edges shared by
//! exactly two of them (edges are keyed by corner *positions*, so uv seams do not cut a
//! surface apart; boundary edges and edges of three or more faces join nothing; a face
//! repeated with the same winding is its copy's duplicate, not reversed), and each face
//! gets a parity relative to its component's first face: flipped or not. Within a component
//!
//! * closed (every edge shared by exactly two faces) and consistently re-orientable: the
//!   outside is known. The faces whose winding gives the re-oriented surface a negative volume
//!   are reversed; when that is all of them, the whole component is inside out;
//! * otherwise (open, or non-orientable or tangled): the faces of the smaller parity class are
//!   reversed (they disagree with the majority across the edges that connect them).
//!
//! Cost: a sort of the vertices by position (in parallel), a counting sort of the half-edges
//! by vertex and a union-find: about `O(V log V + T)` time and 70 bytes per triangle while it
//! runs.

use glam::{DVec3, Vec3};
use rayon::slice::ParallelSliceMut;

/// What [`check`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Winding {
    /// Triangles checked.
    pub faces: usize,
    /// Connected components (faces joined across edges shared by exactly two faces).
    pub components: usize,
    /// Faces that look reversed (see the module docs).
    pub reversed_faces: usize,
    /// Components that hold at least one reversed face.
    pub components_with_reversed: usize,
    /// Closed components whose every face is reversed: wholly inside out.
    pub inside_out_components: usize,
}

/// Check the winding of `triangles` (indices into `positions`, all in range, as a [`Mesh`]
/// holds them; see the module docs). Changes nothing.
///
/// [`Mesh`]: super::Mesh
pub fn check(positions: &[Vec3], triangles: &[[u32; 3]]) -> Winding {
    let faces = triangles.len();
    // Face ids and a direction bit share a u32, and so do the `3 x faces` half-edge counts
    // (2^30 faces is 32 times the most `generate subdivide` makes).
    if faces == 0 || faces >= 1 << 30 || positions.len() > u32::MAX as usize {
        return Winding { faces, ..Winding::default() };
    }
    // 1. One id per distinct position (-0.0 is 0.0), so uv seams join: the vertices sorted by
    //    position, each run of equal ones named by its first.
    let bits = |i: u32| {
        let p = positions[i as usize];
        [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits())
    };
    let mut by_position: Vec<u32> = (0..positions.len() as u32).collect();
    by_position.par_sort_unstable_by_key(|&i| bits(i));
    let mut canon = vec![0u32; positions.len()];
    for run in by_position.chunk_by(|&i, &j| bits(i) == bits(j)) {
        for &i in run {
            canon[i as usize] = run[0];
        }
    }
    drop(by_position);
    // 2. The half-edges bucketed by their edge's lower vertex (a counting sort), each bucket
    //    sorted by the upper one: then the half-edges of an edge are neighbours.
    let mut start = vec![0u32; positions.len() + 1];
    let edges = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|i| canon[i as usize]);
        [(a, b), (b, c), (c, a)].into_iter().filter(|(a, b)| a != b)
    };
    for t in triangles {
        for (a, b) in edges(t) {
            start[a.min(b) as usize + 1] += 1;
        }
    }
    for v in 0..positions.len() {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    // (upper vertex, face << 1 | 1 when the face runs lower to upper)
    let mut half = vec![(0u32, 0u32); start[positions.len()] as usize];
    for (f, t) in triangles.iter().enumerate() {
        for (a, b) in edges(t) {
            let slot = &mut fill[a.min(b) as usize];
            half[*slot as usize] = (a.max(b), (f as u32) << 1 | u32::from(a < b));
            *slot += 1;
        }
    }
    drop(fill);
    for v in 0..positions.len() {
        half[start[v] as usize..start[v + 1] as usize].sort_unstable();
    }
    // 3. Join faces across the edges of exactly two faces; parity 1 when they traverse it the
    //    same way (one of the two is flipped relative to the other).
    let mut sets = ParitySets::new(faces);
    let mut open = vec![false; faces];
    let mut conflicts = Vec::new();
    let groups =
        (0..positions.len()).flat_map(|v| half[start[v] as usize..start[v + 1] as usize].chunk_by(|x, y| x.0 == y.0));
    for group in groups {
        if let [(_, x), (_, y)] = group {
            let (f, g) = ((x >> 1) as usize, (y >> 1) as usize);
            // A face repeated with the same winding (same corners, so it traverses every edge
            // as its copy does) is a duplicate, not a reversed face.
            let same_way = (x & 1) == (y & 1);
            let corners = |f: usize| {
                let mut c = triangles[f].map(|i| canon[i as usize]);
                c.sort_unstable();
                c
            };
            let duplicate = same_way && corners(f) == corners(g);
            if duplicate {
                // Two copies bound no volume across this edge.
                open[f] = true;
                open[g] = true;
            }
            if f != g && !sets.join(f, g, same_way && !duplicate) {
                conflicts.push(f);
            }
        } else {
            for (_, x) in group {
                open[(x >> 1) as usize] = true;
            }
        }
    }
    drop(half);
    drop(start);
    // 4. Per component (indexed by its root): the faces of each parity, closedness, and the
    //    signed volume with parity-1 faces flipped (about the centre, for less cancellation).
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for p in positions {
        lo = lo.min(p.as_dvec3());
        hi = hi.max(p.as_dvec3());
    }
    let centre = 0.5 * (lo + hi);
    let mut count = vec![[0u32; 2]; faces];
    let mut volume = vec![[0.0f64; 2]; faces];
    let mut closed = vec![true; faces];
    for (f, t) in triangles.iter().enumerate() {
        let (root, parity) = sets.find(f);
        let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3() - centre);
        let det = a.dot(b.cross(c));
        count[root][parity as usize] += 1;
        // [signed volume, scale]
        volume[root][0] += if parity { -det } else { det };
        volume[root][1] += det.abs();
        closed[root] &= !open[f];
    }
    for f in conflicts {
        let (root, _) = sets.find(f);
        closed[root] = false;
    }
    let mut out = Winding { faces, ..Winding::default() };
    for f in 0..faces {
        let [n0, n1] = count[f].map(|n| n as usize);
        if n0 + n1 == 0 {
            continue;
        }
        out.components += 1;
        let [v, scale] = volume[f];
        let reversed = if closed[f] && v.abs() > 1e-9 * scale {
            if v > 0.0 {
                n1
            } else {
                n0
            }
        } else {
            n0.min(n1)
        };
        if reversed > 0 {
            out.reversed_faces += reversed;
            out.components_with_reversed += 1;
            out.inside_out_components += usize::from(reversed == n0 + n1);
        }
    }
    out
}

/// A warning when [`check`] finds reversed faces: how many, where, and what to do; `None` for
/// a consistently wound mesh.
pub fn warning(positions: &[Vec3], triangles: &[[u32; 3]]) -> Option<String> {
    let w = check(positions, triangles);
    (w.reversed_faces > 0).then(|| {
        let inside_out = match w.inside_out_components {
            0 => String::new(),
            k => format!(", {k} of them closed and wholly inside out"),
        };
        format!(
            "{} of {} faces ({:.1}%) look reversed, in {} of {} connected components{inside_out}: each is wound \
             against its edge-neighbours (or its closed surface's outside), so its normal points into the solid \
             and it, and the vertices around it, see little or no sky and render dark. Left as loaded: re-orient \
             the faces consistently outward in the source (e.g. Blender: Mesh > Normals > Recalculate Outside; \
             MeshLab: Normals > Re-Orient all faces coherently) and load it again",
            w.reversed_faces,
            w.faces,
            100.0 * w.reversed_faces as f64 / w.faces as f64,
            w.components_with_reversed,
            w.components,
        )
    })
}

/// Union-find over faces, each with its parity (flipped or not) relative to its set's root.
struct ParitySets {
    parent: Vec<u32>,
    /// Parity relative to `parent`.
    parity: Vec<bool>,
    size: Vec<u32>,
}

impl ParitySets {
    fn new(n: usize) -> Self {
        ParitySets { parent: (0..n as u32).collect(), parity: vec![false; n], size: vec![1; n] }
    }

    /// The root of `x` and the parity of `x` relative to it (compressing the path).
    fn find(&mut self, x: usize) -> (usize, bool) {
        let mut root = x;
        let mut parity = false;
        while self.parent[root] as usize != root {
            parity ^= self.parity[root];
            root = self.parent[root] as usize;
        }
        // Point the path at the root, each node with its own parity to it.
        let mut node = x;
        let mut to_root = parity;
        while self.parent[node] as usize != root && node != root {
            let (next, step) = (self.parent[node] as usize, self.parity[node]);
            self.parent[node] = root as u32;
            self.parity[node] = to_root;
            to_root ^= step;
            node = next;
        }
        (root, parity)
    }

    /// Record that `x` and `y` differ by `flipped`; false when that contradicts what is known.
    fn join(&mut self, x: usize, y: usize, flipped: bool) -> bool {
        let ((rx, px), (ry, py)) = (self.find(x), self.find(y));
        if rx == ry {
            return px ^ py == flipped;
        }
        let (big, small) = if self.size[rx] >= self.size[ry] { (rx, ry) } else { (ry, rx) };
        self.parent[small] = big as u32;
        self.parity[small] = px ^ py ^ flipped;
        self.size[big] += self.size[small];
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{grid_plane, uv_sphere};
    use crate::geometry::Mesh;

    /// Flip `share` of the faces, scattered over the mesh; returns how many.
    fn flip_share(mesh: &mut Mesh, share: f64) -> usize {
        let n = mesh.triangles.len();
        let mut flipped = 0;
        for (i, t) in mesh.triangles.iter_mut().enumerate() {
            // A scrambled order (Knuth's multiplicative hash) so flipped faces are scattered.
            if ((i as u64 * 2_654_435_761) % n as u64) < (share * n as f64) as u64 {
                t.swap(1, 2);
                flipped += 1;
            }
        }
        flipped
    }

    #[test]
    fn a_partly_inside_out_sphere_is_warned_about() {
        // Regression (issue 36): with 40% of a closed sphere's faces reversed, 37% of the
        // vertices rendered black and nothing was said (the sky warning waits for half).
        let sphere = uv_sphere(Vec3::ZERO, 1.0, 16, 24);
        let ok = check(&sphere.positions, &sphere.triangles);
        assert_eq!((ok.reversed_faces, ok.components, ok.faces), (0, 1, sphere.triangle_count()), "{ok:?}");
        assert!(warning(&sphere.positions, &sphere.triangles).is_none());
        let mut bad = sphere.clone();
        let flipped = flip_share(&mut bad, 0.4);
        assert_eq!(flipped, bad.triangle_count() * 2 / 5);
        let w = check(&bad.positions, &bad.triangles);
        assert_eq!((w.reversed_faces, w.components, w.components_with_reversed), (flipped, 1, 1), "{w:?}");
        let text = warning(&bad.positions, &bad.triangles).expect("a warning");
        let share = format!("{:.1}%", 100.0 * flipped as f64 / bad.triangle_count() as f64);
        assert!(text.starts_with(&format!("{flipped} of {} faces", bad.triangle_count())), "{text}");
        assert!(text.contains(&share) && text.contains("re-orient"), "{text}");
        // The majority reversed: the closed surface's volume still tells which side is out.
        let mut worse = sphere.clone();
        let flipped = flip_share(&mut worse, 0.6);
        assert_eq!(check(&worse.positions, &worse.triangles).reversed_faces, flipped);
    }

    #[test]
    fn a_wholly_inside_out_closed_component_is_named_beside_a_good_one() {
        // A plane and an inside-out sphere: the plane is fine, the sphere is all reversed
        // although it is consistent in itself.
        let plane = grid_plane(4, 4.0);
        let mut ball = uv_sphere(Vec3::Y, 0.5, 8, 12);
        for t in &mut ball.triangles {
            t.swap(1, 2);
        }
        let both = crate::geometry::shapes::merged(&[plane.clone(), ball.clone()]);
        let w = check(&both.positions, &both.triangles);
        let expected = Winding {
            faces: both.triangle_count(),
            components: 2,
            reversed_faces: ball.triangle_count(),
            components_with_reversed: 1,
            inside_out_components: 1,
        };
        assert_eq!(w, expected);
        let text = warning(&both.positions, &both.triangles).unwrap();
        assert!(text.contains("in 1 of 2 connected components, 1 of them closed and wholly inside out"), "{text}");
        // An open surface has no outside: a wholly flipped plane is consistent, not reversed.
        let mut down = plane.clone();
        for t in &mut down.triangles {
            t.swap(1, 2);
        }
        assert_eq!(check(&down.positions, &down.triangles).reversed_faces, 0);
        // One face flipped in the plane: the minority.
        down.triangles[5].swap(0, 1);
        assert_eq!(check(&down.positions, &down.triangles).reversed_faces, 1);
    }

    #[test]
    fn seams_and_non_manifold_edges_do_not_confuse_the_check() {
        // The sphere unwelded into a triangle soup (every triangle its own vertices) still
        // joins by positions; a fin on an edge (three faces) joins nothing there.
        let sphere = uv_sphere(Vec3::ZERO, 1.0, 6, 8);
        let mut positions = vec![];
        let mut triangles = vec![];
        for t in &sphere.triangles {
            let base = positions.len() as u32;
            positions.extend(t.map(|i| sphere.positions[i as usize]));
            triangles.push([base, base + 1, base + 2]);
        }
        assert_eq!(check(&positions, &triangles).components, 1);
        assert!(warning(&positions, &triangles).is_none());
        let [a, b, _] = triangles[0].map(|i| positions[i as usize]);
        let base = positions.len() as u32;
        positions.extend([a, b, Vec3::splat(3.0)]);
        triangles.push([base, base + 1, base + 2]);
        assert!(warning(&positions, &triangles).is_none());
        // A face repeated as it is (here over a uv seam: another vertex, the same position)
        // is a duplicate, and repeated the other way round a two-sided sheet: neither is
        // reversed. A third face wound against them is.
        let positions = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Y, Vec3::ONE];
        assert!(warning(&positions, &[[0, 1, 2], [0, 1, 3]]).is_none());
        assert!(warning(&positions, &[[0, 1, 2], [1, 0, 3]]).is_none());
        assert!(warning(&positions, &[[0, 1, 2], [0, 1, 3], [1, 4, 2]]).is_none());
        assert_eq!(check(&positions, &[[0, 1, 2], [2, 4, 1]]).reversed_faces, 1);
    }

    #[test]
    fn the_bundled_meshes_are_consistently_wound() {
        // No false alarm on any mesh the configs use (the bunny and the teapot have open
        // boundaries or edges of three faces).
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/meshes");
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "obj" || e == "ply") {
                let load = Mesh::load(&path).unwrap();
                let w = check(&load.mesh.positions, &load.mesh.triangles);
                assert_eq!(w.reversed_faces, 0, "{}: {w:?}", path.display());
                assert!(!load.repairs.iter().any(|r| r.contains("reversed")), "{}: {:?}", path.display(), load.repairs);
                seen += 1;
            }
        }
        assert!(seen >= 6, "{seen} meshes in {}", dir.display());
    }
}
