//! Triangulating one polygon face of an OBJ or PLY file. Convex polygons become fans from
//! their first corner (what every OBJ reader does), in `O(n)`. A non-convex polygon's fan would
//! hold triangles outside the polygon, wound the wrong way, so it is cut by ear clipping in its
//! own plane instead. The triangles keep the polygon's winding either way.
//!
//! Convex means no corner turns backwards by more than the input's rounding can explain: the
//! corners are `f32`, each up to half an ulp of its largest coordinate off where it was meant
//! to be, which moves a corner's turn by up to that much times its two edges. For a regular
//! 100,000-gon the true turn is some 20 times smaller than that noise, so a third of its corners
//! turn backwards (issue 36: it was read as non-convex and ear-clipped, for tens of seconds). A
//! corner counts as convex when its turn is at least `-max(eps, rounding)` (`eps`: `1e-12` times
//! the squared diameter, the whole test before; so every polygon read as convex before still is).
//!
//! Ear clipping clips, each step, the ear of the lowest corner index (an ear: a convex corner
//! whose triangle with its two neighbours holds no other remaining corner, on its edges
//! included). Up to [`SMALL`] corners it is the plain loop, `O(n^2)` or worse. Above, the same
//! rule runs on a linked ring, with the ears in an ordered set; an ear is tested against only
//! the non-convex corners (the only ones that can lie in an ear of a simple polygon), found in
//! a k-d tree that skips the boxes outside the triangle or without one, the corner that last
//! blocked it first; after a clip only its two neighbours are tested again (the only corners
//! whose ear status can change in a simple polygon). So: the same triangles in the same order
//! for any simple polygon, about `O(n log n)` for combs and stars (100,000 corners in a quarter
//! of a second) and a little more for ragged random ones (0.6 s), `O(n^2)` at worst.
//! Self-intersecting polygons may be cut differently by the two; neither loops forever, and
//! both fan whatever is left when no ear remains.

use glam::{DVec2, DVec3, Vec3};
use std::collections::BTreeSet;

/// Polygons of at most this many corners are ear-clipped by the plain loop (above: the
/// indexed one, the same triangles for simple polygons).
pub const SMALL: usize = 64;

/// The position error the convexity test allows each corner coordinate, relative to the
/// polygon's largest coordinate: four ulps of `f32` (half an ulp is what parsing into `f32`
/// costs; the rest is room for text written with a few digits fewer).
const ROUNDING: f64 = 4.0 * f32::EPSILON as f64;

/// Emit the triangles of the polygon `corners` (in order) as corner indices. Returns whether
/// the polygon was non-convex (cut by ear clipping). Degenerate polygons (no area, so no
/// plane) are fanned; the mesh validation drops their zero-area triangles.
pub fn triangulate(corners: &[Vec3], mut emit: impl FnMut([usize; 3])) -> bool {
    let n = corners.len();
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
    let scale = q.iter().map(|x| (*x - q[0]).length_squared()).fold(0.0, f64::max);
    let eps = 1e-12 * scale;
    // Each corner's in-plane position is off by at most `delta` (its three coordinates' rounding),
    // which moves the turn `(b - a) x (c - b)` by at most `2 delta (|b - a| + |c - b|) + 4 delta^2`.
    let largest = p.iter().map(|x| x.abs().max_element()).fold(0.0, f64::max);
    let delta = 3f64.sqrt() * ROUNDING * largest;
    let nearly_convex = (0..n).all(|i| {
        let (a, b, c) = (q[(i + n - 1) % n], q[i], q[(i + 1) % n]);
        let noise = 2.0 * delta * ((b - a).length() + (c - b).length()) + 4.0 * delta * delta;
        turn(a, b, c) >= -eps.max(noise)
    });
    if nearly_convex {
        fan(&mut emit, &all);
        return false;
    }
    if n <= SMALL {
        clip_ears_plainly(&q, eps, &mut emit);
    } else {
        Ring::new(&q, eps).clip_ears(&mut emit);
    }
    true
}

/// Triangles `idx[0] idx[i] idx[i + 1]`.
fn fan(emit: &mut dyn FnMut([usize; 3]), idx: &[usize]) {
    for i in 1..idx.len().saturating_sub(1) {
        emit([idx[0], idx[i], idx[i + 1]]);
    }
}

/// How far `a b c` turns left at `b` (twice the signed area of the triangle).
fn turn(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - b)
}

/// Whether a corner that turns by `turn` is convex enough to be an ear (a NaN turn is not).
fn convex(turn: f64, eps: f64) -> bool {
    turn > eps
}

/// The plain ear-clipping loop (the reference of [`Ring`]): each step the lowest corner that
/// is an ear against every remaining corner.
fn clip_ears_plainly(q: &[DVec2], eps: f64, emit: &mut dyn FnMut([usize; 3])) {
    let turn = |a: usize, b: usize, c: usize| turn(q[a], q[b], q[c]);
    let mut left: Vec<usize> = (0..q.len()).collect();
    while left.len() > 3 {
        let m = left.len();
        let ear = (0..m).find(|&i| {
            let (a, b, c) = (left[(i + m - 1) % m], left[i], left[(i + 1) % m]);
            turn(a, b, c) > eps
                && left.iter().all(|&x| x == a || x == b || x == c || !inside_or_on(q[x], q[a], q[b], q[c]))
        });
        let Some(i) = ear else {
            // Self-intersecting or collinear remains: no ear; fan what is left.
            fan(emit, &left);
            return;
        };
        emit([left[(i + m - 1) % m], left[i], left[(i + 1) % m]]);
        left.remove(i);
    }
    emit([left[0], left[1], left[2]]);
}

/// The indexed ear clipping of large polygons (module docs).
struct Ring<'a> {
    q: &'a [DVec2],
    eps: f64,
    prev: Vec<usize>,
    next: Vec<usize>,
    /// Each corner's turn with its current neighbours.
    turn: Vec<f64>,
    alive: Vec<bool>,
    /// The remaining non-convex corners (turn `<= eps`): what can keep a corner from being an ear.
    obstacles: KdTree,
    /// The corner that last kept each corner from being an ear (`usize::MAX`: none yet).
    blocker: Vec<usize>,
    ears: BTreeSet<usize>,
}

impl<'a> Ring<'a> {
    fn new(q: &'a [DVec2], eps: f64) -> Self {
        let n = q.len();
        let prev: Vec<usize> = (0..n).map(|i| (i + n - 1) % n).collect();
        let next: Vec<usize> = (0..n).map(|i| (i + 1) % n).collect();
        let turn: Vec<f64> = (0..n).map(|i| turn(q[prev[i]], q[i], q[next[i]])).collect();
        let mut obstacles = KdTree::new(q);
        for i in 0..n {
            if !convex(turn[i], eps) {
                obstacles.set(i, true);
            }
        }
        let mut ring = Ring {
            q,
            eps,
            prev,
            next,
            turn,
            alive: vec![true; n],
            obstacles,
            blocker: vec![usize::MAX; n],
            ears: BTreeSet::new(),
        };
        for i in 0..n {
            if ring.is_ear(i) {
                ring.ears.insert(i);
            }
        }
        ring
    }

    /// Whether corner `b` is an ear now: convex, and no remaining non-convex corner in or on
    /// its triangle.
    fn is_ear(&mut self, b: usize) -> bool {
        if !convex(self.turn[b], self.eps) {
            return false;
        }
        let (a, c) = (self.prev[b], self.next[b]);
        let q = self.q;
        let tri = [q[a], q[b], q[c]];
        // What blocked this corner last still does, most of the time: try it first.
        let last = self.blocker[b];
        if last != usize::MAX
            && self.obstacles.active[last]
            && last != a
            && last != c
            && inside_or_on(q[last], tri[0], tri[1], tri[2])
        {
            return false;
        }
        match self.obstacles.find_in(tri, [a, b, c]) {
            Some(i) => {
                self.blocker[b] = i;
                false
            }
            None => true,
        }
    }

    /// Recompute corner `i`'s turn with its current neighbours, and its ear status.
    fn update(&mut self, i: usize) {
        self.turn[i] = turn(self.q[self.prev[i]], self.q[i], self.q[self.next[i]]);
        self.obstacles.set(i, !convex(self.turn[i], self.eps));
        if self.is_ear(i) {
            self.ears.insert(i);
        } else {
            self.ears.remove(&i);
        }
    }

    fn clip_ears(mut self, emit: &mut dyn FnMut([usize; 3])) {
        let mut left = self.q.len();
        while left > 3 {
            let Some(b) = self.ears.pop_first() else {
                // No ear (self-intersecting or collinear remains): fan what is left.
                fan(emit, &self.remaining());
                return;
            };
            let (a, c) = (self.prev[b], self.next[b]);
            emit([a, b, c]);
            self.alive[b] = false;
            self.obstacles.set(b, false);
            self.next[a] = c;
            self.prev[c] = a;
            left -= 1;
            self.update(a);
            self.update(c);
        }
        let r = self.remaining();
        emit([r[0], r[1], r[2]]);
    }

    /// The remaining corners in index order.
    fn remaining(&self) -> Vec<usize> {
        (0..self.q.len()).filter(|&i| self.alive[i]).collect()
    }
}

/// A k-d tree over the corners, each marked active or not, that finds an active corner in or
/// on a triangle, visiting only the nodes whose box meets the triangle and that hold active
/// corners.
struct KdTree {
    q: Vec<DVec2>,
    /// The corners in tree order: each node holds a range of it.
    order: Vec<usize>,
    /// Each corner's leaf.
    leaf: Vec<usize>,
    active: Vec<bool>,
    nodes: Vec<KdNode>,
    /// How far outside a box a corner may be and still pass the triangle test (rounding): the
    /// boxes are grown by it before they are ruled out.
    slack: f64,
    /// The nodes still to visit in a search (kept to save an allocation per search).
    stack: Vec<usize>,
}

struct KdNode {
    lo: DVec2,
    hi: DVec2,
    range: std::ops::Range<usize>,
    /// Child nodes (`None` for a leaf).
    children: Option<[usize; 2]>,
    parent: usize,
    /// Active corners under this node.
    active: usize,
}

impl KdTree {
    const LEAF: usize = 8;

    fn new(q: &[DVec2]) -> Self {
        let n = q.len();
        let mut tree = KdTree {
            q: q.to_vec(),
            order: (0..n).collect(),
            leaf: vec![0; n],
            active: vec![false; n],
            nodes: Vec::with_capacity(2 * n / Self::LEAF + 2),
            slack: 0.0,
            stack: Vec::new(),
        };
        tree.build(0..n, usize::MAX);
        let root = &tree.nodes[0];
        tree.slack = 1e-9 * (root.hi - root.lo).max_element();
        tree
    }

    fn build(&mut self, range: std::ops::Range<usize>, parent: usize) -> usize {
        let id = self.nodes.len();
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for &i in &self.order[range.clone()] {
            lo = lo.min(self.q[i]);
            hi = hi.max(self.q[i]);
        }
        self.nodes.push(KdNode { lo, hi, range: range.clone(), children: None, parent, active: 0 });
        if range.len() <= Self::LEAF {
            for &i in &self.order[range] {
                self.leaf[i] = id;
            }
            return id;
        }
        let extent = hi - lo;
        let q = &self.q;
        let key = |i: &usize| if extent.x >= extent.y { q[*i].x } else { q[*i].y };
        let mid = range.len() / 2;
        self.order[range.clone()].select_nth_unstable_by(mid, |i, j| key(i).total_cmp(&key(j)));
        let left = self.build(range.start..range.start + mid, id);
        let right = self.build(range.start + mid..range.end, id);
        self.nodes[id].children = Some([left, right]);
        id
    }

    /// Mark corner `i` active or not.
    fn set(&mut self, i: usize, active: bool) {
        if self.active[i] == active {
            return;
        }
        self.active[i] = active;
        let mut node = self.leaf[i];
        while node != usize::MAX {
            let n = &mut self.nodes[node];
            if active {
                n.active += 1;
            } else {
                n.active -= 1;
            }
            node = n.parent;
        }
    }

    /// An active corner other than `skip` in or on the counter-clockwise triangle `tri`.
    fn find_in(&mut self, tri: [DVec2; 3], skip: [usize; 3]) -> Option<usize> {
        let (tlo, thi) = (tri[0].min(tri[1]).min(tri[2]) - self.slack, tri[0].max(tri[1]).max(tri[2]) + self.slack);
        let mut stack = std::mem::take(&mut self.stack);
        stack.clear();
        stack.push(0);
        let mut found = None;
        while let Some(id) = stack.pop() {
            let node = &self.nodes[id];
            if node.active == 0 || node.hi.cmplt(tlo).any() || node.lo.cmpgt(thi).any() {
                continue;
            }
            // Ruled out when the whole box is strictly outside one of the edges (by more than
            // the slack): test the corner of the box farthest inside that edge.
            let outside = (0..3).any(|k| {
                let (u, d) = (tri[k], tri[(k + 1) % 3] - tri[k]);
                let x = DVec2::new(
                    if d.y > 0.0 { node.lo.x } else { node.hi.x },
                    if d.x > 0.0 { node.hi.y } else { node.lo.y },
                );
                d.perp_dot(x - u) < -self.slack * d.length()
            });
            if outside {
                continue;
            }
            match node.children {
                Some(children) => stack.extend(children),
                None => {
                    found = self.order[node.range.clone()].iter().copied().find(|&i| {
                        self.active[i] && !skip.contains(&i) && inside_or_on(self.q[i], tri[0], tri[1], tri[2])
                    });
                    if found.is_some() {
                        break;
                    }
                }
            }
        }
        self.stack = stack;
        found
    }
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

    /// The triangulation as it was before issue 36 (the oracle of the identity tests).
    fn triangulate_before(corners: &[Vec3], mut emit: impl FnMut([usize; 3])) -> bool {
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

    /// Twice the signed area of `a b c`.
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

    /// The corners in the xy plane (exactly, from f64 through f32).
    fn planar(xy: impl IntoIterator<Item = (f64, f64)>) -> Vec<Vec3> {
        xy.into_iter().map(|(x, y)| Vec3::new(x as f32, y as f32, 0.0)).collect()
    }

    /// A regular `n`-gon of radius `r` about `(cx, 0)`, counter-clockwise.
    fn regular(n: usize, r: f64, cx: f64) -> Vec<Vec3> {
        planar((0..n).map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            (cx + r * a.cos(), r * a.sin())
        }))
    }

    /// A star of `n` corners (`n / 2` spikes) between radii 1 and 0.5.
    fn star(n: usize) -> Vec<Vec3> {
        planar((0..n).map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = if i % 2 == 0 { 1.0 } else { 0.5 };
            (r * a.cos(), r * a.sin())
        }))
    }

    /// A comb of `teeth` teeth (`4 teeth` corners): unit-wide teeth 10 high, unit gaps 1 deep.
    fn comb(teeth: usize) -> Vec<Vec3> {
        let mut xy = vec![(0.0, 0.0), (2.0 * teeth as f64 - 1.0, 0.0)];
        for k in (0..teeth).rev() {
            let x = 2.0 * k as f64;
            xy.extend([(x + 1.0, 10.0), (x, 10.0)]);
            if k > 0 {
                xy.extend([(x, 1.0), (x - 1.0, 1.0)]);
            }
        }
        planar(xy)
    }

    /// A random star-shaped (so simple) polygon: `n` corners at increasing random angles and
    /// random radii about the origin (splitmix64 from `seed`).
    fn random_simple(n: usize, seed: u64) -> Vec<Vec3> {
        let mut state = seed;
        let mut next = move || {
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        planar((0..n).map(|i| {
            let a = std::f64::consts::TAU * (i as f64 + 0.8 * next()) / n as f64;
            let r = 0.2 + next();
            (r * a.cos(), r * a.sin())
        }))
    }

    /// The triangles' unsigned areas summed, and the polygon's (shoelace), in its xy plane.
    fn areas(corners: &[Vec3], t: &[[usize; 3]]) -> (f64, f64) {
        let q: Vec<DVec2> = corners.iter().map(|c| c.truncate().as_dvec2()).collect();
        let covered = t.iter().map(|&[a, b, c]| area2(q[a], q[b], q[c]).abs() / 2.0).sum();
        let n = q.len();
        let shoelace = (0..n).map(|i| q[i].perp_dot(q[(i + 1) % n])).sum::<f64>() / 2.0;
        (covered, shoelace)
    }

    #[test]
    fn a_convex_100k_gon_is_read_as_convex_and_fanned() {
        // Regression (issue 36): the f32 corners of a regular 100,000-gon turn backwards at a
        // third of them (the true turn is 20 times smaller than their rounding), some by more
        // than the old tolerance, so it was read as non-convex and ear-clipped for minutes.
        for cx in [0.0, 10.0] {
            let corners = regular(100_000, 1.0, cx);
            let (t, nonconvex) = tris(&corners);
            assert!(!nonconvex, "centre x {cx}");
            assert_eq!(t.len(), corners.len() - 2);
            assert!(t.iter().enumerate().all(|(i, &tri)| tri == [0, i + 1, i + 2]), "a fan from corner 0");
            let (covered, shoelace) = areas(&corners, &t);
            // Off the origin the rounding is coarser: the fan's slivers next to corner 0 are
            // wound backwards by it (signed, they still sum to the polygon's area exactly).
            let tolerance = if cx == 0.0 { 1e-9 } else { 1e-6 };
            assert!((covered - shoelace).abs() <= tolerance * shoelace, "{covered} vs {shoelace}");
            let q: Vec<DVec2> = corners.iter().map(|c| c.truncate().as_dvec2()).collect();
            let signed: f64 = t.iter().map(|&[a, b, c]| area2(q[a], q[b], q[c]) / 2.0).sum();
            assert!((signed - shoelace).abs() <= 1e-9 * shoelace, "{signed} vs {shoelace}");
            // The premise: some corners turn backwards by more than 1e-12 x diameter^2.
            let n = q.len();
            let eps = 1e-12 * 4.0;
            assert!((0..n).any(|i| turn(q[(i + n - 1) % n], q[i], q[(i + 1) % n]) < -eps), "centre x {cx}");
        }
        // Tilted into 3D (rounded there), still convex.
        let tilt = glam::Quat::from_euler(glam::EulerRot::XYZ, 0.7, -0.4, 1.9);
        let corners: Vec<Vec3> = regular(100_000, 3.0, 0.5).iter().map(|&c| tilt * c + Vec3::ONE).collect();
        let (t, nonconvex) = tris(&corners);
        assert!(!nonconvex && t.len() == corners.len() - 2);
    }

    #[test]
    fn large_non_convex_polygons_are_clipped_fast_and_exactly() {
        // Regression (issue 36): ear clipping was quadratic or worse in the corners.
        for (name, corners) in [("star", star(20_000)), ("comb", comb(5_000)), ("random", random_simple(20_000, 7))] {
            let (t, nonconvex) = tris(&corners);
            assert!(nonconvex, "{name}");
            assert_eq!(t.len(), corners.len() - 2, "{name}");
            let q: Vec<DVec2> = corners.iter().map(|c| c.truncate().as_dvec2()).collect();
            assert!(t.iter().all(|&[a, b, c]| area2(q[a], q[b], q[c]) > 0.0), "{name}: a triangle wound backwards");
            let (covered, shoelace) = areas(&corners, &t);
            assert!((covered - shoelace).abs() <= 1e-9 * shoelace, "{name}: {covered} vs {shoelace}");
        }
    }

    #[test]
    fn the_indexed_ear_clipping_cuts_simple_polygons_as_the_plain_loop_does() {
        // The same triangles in the same order: for polygons past SMALL (the indexed ring),
        // against the plain loop and against the triangulation before issue 36.
        let mut shapes: Vec<Vec<Vec3>> = (0..40).map(|s| random_simple(SMALL + 1 + 37 * s as usize, s)).collect();
        shapes.extend([star(SMALL + 2), star(1000), comb(SMALL / 4 + 1), comb(300), random_simple(4000, 99)]);
        // With collinear corners: a comb whose edges are cut in two.
        let c = comb(40);
        let mut split = vec![];
        for i in 0..c.len() {
            split.extend([c[i], (c[i] + c[(i + 1) % c.len()]) / 2.0]);
        }
        shapes.push(split);
        for (k, corners) in shapes.iter().enumerate() {
            assert!(corners.len() > SMALL);
            let (t, nonconvex) = tris(corners);
            let mut before = vec![];
            assert_eq!(triangulate_before(corners, |x| before.push(x)), nonconvex, "shape {k}");
            assert!(nonconvex, "shape {k}");
            assert_eq!(t, before, "shape {k} ({} corners)", corners.len());
        }
    }

    #[test]
    fn every_bundled_and_seed_face_triangulates_as_before() {
        // Results stay bit-identical: every face of the meshes the configs use (and the fuzz
        // seeds) gives the same triangles, in the same order, as before issue 36.
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let (mut files, mut faces) = (0, 0);
        for dir in ["assets/meshes", "fuzz/seeds/obj", "fuzz/seeds/ply"] {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let path = entry.unwrap().path();
                let bytes = std::fs::read(&path).unwrap();
                let polygons: Vec<Vec<Vec3>> = match path.extension().and_then(|e| e.to_str()) {
                    Some("obj") => obj_polygons(&String::from_utf8_lossy(&bytes)),
                    Some("ply") => match crate::geometry::ply::parse(&bytes) {
                        Ok(ply) => {
                            let mut at = 0;
                            (ply.arities.iter())
                                .map(|&n| {
                                    at += n as usize;
                                    ply.indices[at - n as usize..at]
                                        .iter()
                                        .map(|&i| ply.positions[i as usize])
                                        .collect()
                                })
                                .collect()
                        }
                        Err(_) => continue,
                    },
                    _ => continue,
                };
                files += 1;
                for corners in polygons {
                    let (mut now, mut before) = (vec![], vec![]);
                    let a = triangulate(&corners, |t| now.push(t));
                    let b = triangulate_before(&corners, |t| before.push(t));
                    assert_eq!((a, now), (b, before), "{}: {corners:?}", path.display());
                    faces += 1;
                }
            }
        }
        assert!(files >= 15 && faces > 23_000, "{files} files, {faces} faces");
    }

    /// The faces of OBJ text as corner positions (`v` and the position index of each `f`
    /// corner, negative ones counting back); faces naming no vertex are left out.
    fn obj_polygons(text: &str) -> Vec<Vec<Vec3>> {
        let mut v: Vec<Vec3> = vec![];
        let mut faces = vec![];
        for line in text.lines() {
            let mut w = line.split_whitespace();
            match w.next() {
                Some("v") => {
                    let c: Vec<f32> = w.take(3).map(|x| x.parse().unwrap_or(f32::NAN)).collect();
                    v.push(Vec3::new(c[0], c[1], c[2]));
                }
                Some("f") => {
                    let face: Option<Vec<Vec3>> = w
                        .map(|c| {
                            let i: i64 = c.split('/').next()?.parse().ok()?;
                            let i = if i < 0 { v.len() as i64 + i } else { i - 1 };
                            v.get(usize::try_from(i).ok()?).copied()
                        })
                        .collect();
                    faces.extend(face);
                }
                _ => {}
            }
        }
        faces
    }
}
