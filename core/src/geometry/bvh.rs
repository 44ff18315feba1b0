//! Ray queries against a triangle mesh through an obvhs compressed wide BVH (CWBVH), and
//! for the transfer stage's occlusion rays, a four-wide tree traced in packets of rays from
//! one origin ([`super::bvh4`], collapsed from the same BVH2) and cone queries over a sphere
//! tree ([`ConeTree`]).
//!
//! Triangles are stored in BVH order so traversal touches them without an indirection;
//! [`Hit::triangle`] is translated back to the mesh's triangle index.
//!
//! Every occlusion path answers with [`RtTri::intersect`] of the triangles it does not cull,
//! so none can report a hit that test rejects. The packets' boxes are padded for the test's
//! tolerance band, so they cull no hit either (tested against brute force, band included).
//! obvhs's CWBVH culls by its own quantised boxes: on the temple unwelded (an axis-aligned
//! polygon soup) it let through rays that some triangle's test occludes, so `T` had 24 more
//! non-zeros through obvhs than through the packets (85,168,030 against 85,168,006); on the
//! bunnies the two agree.
//!
//! Triangle test: Moller-Trumbore ("Fast, Minimum Storage Ray/Triangle Intersection", 1997)
//! with the edges and normal precomputed ([`RtTri`]) and a barycentric tolerance of
//! [`EDGE_TOLERANCE`]: obvhs's own test rejects `u == -0.0`, so a ray through a shared edge
//! or vertex can slip between both triangles (measured: 63 leaking texels from the corners of
//! a closed box seen from inside, whose face diagonals lie exactly on texel-centre rays).
//! Growing every triangle by 1e-5 of its size closes those cracks at the cost of occluding
//! a band that thin beyond open boundaries.
//!
//! Depth: obvhs's CWBVH traversal keeps its pending nodes on a fixed stack of
//! [`MAX_CWBVH_DEPTH`] entries, so a tree must be shallower than that. Its PLOC builder gives a
//! chain, one level per few triangles, on a fan of slivers from one corner (how exporters
//! triangulate a large convex polygon: a 2,000-gon gave 78 levels), so a tree that deep is
//! rebuilt by median splits, whose depth is at most log2 of the triangle count.

use super::bvh4::Bvh4;
pub(crate) use super::bvh4::PACKET;
pub(crate) use coverage::{CoverScratch, FaceTile, MAX_TILE};

mod coverage;
use glam::{Vec2, Vec3, Vec3A};
use obvhs::{
    aabb::Aabb,
    bvh2::{node::Bvh2Node, reinsertion::ReinsertionOptimizer, Bvh2},
    cwbvh::{bvh2_to_cwbvh::bvh2_to_cwbvh, CwBvh},
    ploc::PlocBuilder,
    ray::{Ray, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};

/// Levels of a CWBVH that obvhs's traversal stack (32 entries) serves.
pub const MAX_CWBVH_DEPTH: usize = 32;

/// A closest hit: mesh triangle index, ray distance, and barycentrics `(b1, b2)` so that the
/// point is `(1 - b1 - b2) v0 + b1 v1 + b2 v2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub triangle: u32,
    pub t: f32,
    pub barycentric: Vec2,
}

/// A BVH over a triangle soup.
pub struct SceneBvh {
    bvh: CwBvh,
    /// Triangles in BVH primitive order.
    tris: Vec<RtTri>,
    /// Mesh triangle index of each BVH primitive.
    tri_ids: Vec<u32>,
    /// Sphere tree over the primitives for cone queries (see [`ConeTree`]).
    cones: ConeTree,
    /// The same triangles in a four-wide tree for the occlusion rays of the transfer stage
    /// ([`Bvh4`]); `None` when the tree would be too deep for its stack.
    wide: Option<Bvh4>,
}

impl std::fmt::Debug for SceneBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SceneBvh({} triangles)", self.tri_ids.len())
    }
}

impl SceneBvh {
    /// Build over `triangles` (indices into `positions`). An empty mesh gives a BVH that
    /// nothing hits.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let soup: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: positions[t[0] as usize].into(),
                v1: positions[t[1] as usize].into(),
                v2: positions[t[2] as usize].into(),
            })
            .collect();
        if soup.is_empty() {
            return Self {
                bvh: CwBvh::default(),
                tris: vec![],
                tri_ids: vec![],
                cones: ConeTree::default(),
                wide: None,
            };
        }
        // obvhs's `build_cwbvh_from_tris` without the pre-splits (off in this preset) and the
        // debug-build validation, which panics on the deep trees replaced below.
        let p = BvhBuildParams::medium_build();
        let indices = (0..soup.len() as u32).collect();
        let mut bvh2 = PlocBuilder::with_capacity(soup.len()).build(
            p.ploc_search_distance,
            &soup,
            indices,
            p.sort_precision,
            p.search_depth_threshold,
        );
        ReinsertionOptimizer::default().run(&mut bvh2, p.reinsertion_batch_ratio, None);
        let leaf = p.max_prims_per_leaf.clamp(1, 3);
        let mut bvh = bvh2_to_cwbvh(&bvh2, leaf, true, false);
        if cwbvh_depth(&bvh) >= MAX_CWBVH_DEPTH {
            bvh2 = median_split_bvh2(&soup);
            bvh = bvh2_to_cwbvh(&bvh2, leaf, true, false);
        }
        let tri_ids: Vec<u32> = bvh.primitive_indices.clone();
        let tris: Vec<RtTri> = tri_ids.iter().map(|&i| RtTri::new(&soup[i as usize])).collect();
        let cones = ConeTree::build(&tris);
        // The four-wide tree names triangles by their index in `tris` (BVH order), so its
        // occluders and the cone lists' share the one-entry cache.
        let mut bvh_index = vec![0u32; soup.len()];
        for (p, &i) in tri_ids.iter().enumerate() {
            bvh_index[i as usize] = p as u32;
        }
        let wide = Bvh4::build(&bvh2, &tris, &bvh_index);
        Self { bvh, tris, tri_ids, cones, wide }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// True if any triangle intersects the open segment `origin + t dir`, `t in (tmin, tmax)`.
    /// `dir` must be unit length (or at least non-zero and finite).
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), tmin, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| self.tris[id].intersect(r))
    }

    /// Primitives (BVH order) that a ray from `origin` could hit if its direction `d` is within
    /// `cone` and above the plane through `origin` with normal `normal` (`d . normal > 0`),
    /// appended to `out`. Conservative: every primitive such a ray hits (with the
    /// [`EDGE_TOLERANCE`] of the triangle test) is listed; others may be. The query stops as
    /// soon as more than `limit` are found and returns false: a list that long is not used
    /// (the caller traces through the BVH), and finishing it cost most of the transfer time on
    /// large meshes, where a tile's cone can hold thousands of far triangles.
    pub(crate) fn cone_candidates(
        &self,
        origin: Vec3A,
        normal: Vec3A,
        cone: &Cone,
        out: &mut Vec<u32>,
        limit: usize,
    ) -> bool {
        self.cones.query(origin, normal, cone, out, limit)
    }

    /// [`Self::occluded_cached`] testing only `candidates` (from [`Self::cone_candidates`]
    /// for a cone containing `dir`): the same answer, by brute force over a short list, one
    /// triangle at a time (the reference of [`Self::occluded_in_tile`]).
    #[cfg(test)]
    pub(crate) fn occluded_among(&self, origin: Vec3A, dir: &RayDir, candidates: &[u32], cache: &mut u32) -> bool {
        let ray = Ray { origin, direction: dir.dir, inv_direction: dir.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
        if let Some(tri) = self.tris.get(*cache as usize) {
            if tri.intersect(&ray) < f32::INFINITY {
                return true;
            }
        }
        for &id in candidates {
            if self.tris[id as usize].intersect(&ray) < f32::INFINITY {
                *cache = id;
                return true;
            }
        }
        false
    }

    /// `candidates` seen from `origin`, for [`Self::occluded_in_tile`]: `c = v0 - origin` and
    /// `c . ng` computed as [`RtTri::intersect`] computes them.
    pub(crate) fn prepare_tile(&self, origin: Vec3A, candidates: &[u32], out: &mut TileTriangles) {
        out.chunks.clear();
        out.ids.clear();
        for group in candidates.chunks(LANES) {
            let mut chunk = TriChunk::default();
            for (lane, &id) in group.iter().enumerate() {
                let t = &self.tris[id as usize];
                let c = t.v0 - origin;
                for a in 0..3 {
                    chunk.c[a][lane] = c[a];
                    chunk.e1[a][lane] = t.e1[a];
                    chunk.e2[a][lane] = t.e2[a];
                    chunk.ng[a][lane] = t.ng[a];
                }
                chunk.c_ng[lane] = c.dot(t.ng);
            }
            out.chunks.push(chunk);
        }
        out.ids.extend_from_slice(candidates);
    }

    /// [`Self::occluded_among`] over a prepared tile ([`Self::prepare_tile`] of the same
    /// candidates and `origin`): the same answer, bit for bit. Each lane repeats
    /// [`RtTri::intersect`]'s operations in its order (glam's `dot` sums `(x + y) + z`, its
    /// `cross` the same products; nothing is fused), eight triangles at a time.
    #[inline]
    pub(crate) fn occluded_in_tile(&self, origin: Vec3A, dir: &RayDir, tile: &TileTriangles, cache: &mut u32) -> bool {
        let ray = Ray { origin, direction: dir.dir, inv_direction: dir.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
        if let Some(tri) = self.tris.get(*cache as usize) {
            if tri.intersect(&ray) < f32::INFINITY {
                return true;
            }
        }
        let d = [dir.dir.x, dir.dir.y, dir.dir.z];
        for (k, chunk) in tile.chunks.iter().enumerate() {
            let hits = chunk_hits(chunk, d);
            if hits != 0 {
                *cache = tile.ids[k * LANES + hits.trailing_zeros() as usize];
                return true;
            }
        }
        false
    }

    /// [`Self::occluded`] for the unbounded ray `origin + t dir`, `t >= RAY_TMIN`, with the direction
    /// and its reciprocal precomputed ([`RayDir`]), and a one-entry occluder cache: `cache`
    /// holds the BVH primitive that occluded the previous (coherent) ray, or `u32::MAX`; it is
    /// tested first and updated on every traversal hit. The answer is that of
    /// [`Self::occluded`] (a cached triangle is only accepted where its own test reports a hit).
    #[inline]
    pub(crate) fn occluded_cached(&self, origin: Vec3A, dir: &RayDir, cache: &mut u32) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let ray = Ray { origin, direction: dir.dir, inv_direction: dir.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
        if let Some(tri) = self.tris.get(*cache as usize) {
            if tri.intersect(&ray) < f32::INFINITY {
                return true;
            }
        }
        let mut hit = u32::MAX;
        let miss = self.bvh.ray_traverse_miss(ray, |r, id| {
            let t = self.tris[id].intersect(r);
            if t < f32::INFINITY {
                hit = id as u32;
            }
            t
        });
        if !miss {
            *cache = hit;
        }
        !miss
    }

    /// [`Self::occluded_cached`] for up to [`PACKET`] rays from one origin at once: bit `i` of
    /// the result is set when ray `i` (`origin + t dirs[i]`, `t >= RAY_TMIN`) is occluded.
    /// Each ray's answer is the triangle test's over every triangle (brute force; see the
    /// module docs for where obvhs's [`Self::occluded`] can differ); the rays share the BVH
    /// nodes they visit (fetched once for the packet) and the one-entry occluder cache.
    pub(crate) fn occluded_packet(&self, origin: Vec3A, dirs: &[&RayDir], cache: &mut u32) -> u32 {
        debug_assert!(dirs.len() <= PACKET);
        if dirs.is_empty() {
            return 0;
        }
        let n = dirs.len().min(PACKET);
        let rays: [Ray; PACKET] = std::array::from_fn(|i| {
            let d = dirs[i.min(n - 1)];
            Ray { origin, direction: d.dir, inv_direction: d.inv, tmin: RAY_TMIN, tmax: f32::INFINITY }
        });
        let rays = &rays[..n];
        let mut occluded = 0u32;
        if let Some(tri) = self.tris.get(*cache as usize) {
            for (i, ray) in rays.iter().enumerate() {
                if tri.intersect(ray) < f32::INFINITY {
                    occluded |= 1 << i;
                }
            }
        }
        let all = u32::MAX >> (u32::BITS as usize - n);
        if occluded == all {
            return occluded;
        }
        match &self.wide {
            Some(wide) => occluded | wide.occluded_packet(rays, all & !occluded, cache),
            None => {
                for (i, d) in dirs[..n].iter().enumerate() {
                    if occluded & 1 << i == 0 && self.occluded_cached(origin, d, cache) {
                        occluded |= 1 << i;
                    }
                }
                occluded
            }
        }
    }

    /// The closest hit along `origin + t dir` with `t in (tmin, tmax)`.
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), tmin, tmax);
        let mut hit = RayHit::none();
        if !self.bvh.ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r)) {
            return None;
        }
        let id = hit.primitive_id as usize;
        let tri = &self.tris[id];
        let p = Vec3::from(ray.origin + ray.direction * hit.t);
        let corners = Triangle { v0: tri.v0, v1: tri.v0 + tri.e1, v2: tri.v0 + tri.e2 };
        Some(Hit { triangle: self.tri_ids[id], t: hit.t, barycentric: barycentric(&corners, p) })
    }
}

/// Levels of `bvh` (the root alone is 1).
fn cwbvh_depth(bvh: &CwBvh) -> usize {
    let mut deepest = 0;
    let mut todo = vec![(0usize, 1usize)];
    while let Some((node, depth)) = todo.pop() {
        deepest = deepest.max(depth);
        let n = &bvh.nodes[node];
        for child in (0..8).filter(|&c| !n.is_child_empty(c) && !n.is_leaf(c)) {
            todo.push((n.child_node_index(child) as usize, depth + 1));
        }
    }
    deepest
}

/// A BVH2 of one triangle per leaf, split at the median centroid along the widest axis of
/// the centroids at every node: at most `ceil(log2 n) + 1` levels whatever the geometry.
fn median_split_bvh2(soup: &[Triangle]) -> Bvh2 {
    let boxes: Vec<Aabb> = soup.iter().map(|t| t.aabb()).collect();
    let mut order: Vec<u32> = (0..soup.len() as u32).collect();
    let mut nodes = vec![Bvh2Node::default()];
    let mut todo = vec![(0usize, 0usize, soup.len())];
    while let Some((node, start, end)) = todo.pop() {
        let part = &mut order[start..end];
        let bounds = part.iter().fold(Aabb::empty(), |b, &i| b.union(&boxes[i as usize]));
        if part.len() == 1 {
            nodes[node] = Bvh2Node::new(bounds, 1, start as u32);
            continue;
        }
        let mut centres = Aabb::empty();
        for &i in part.iter() {
            centres.extend(boxes[i as usize].center());
        }
        let axis = centres.largest_axis();
        let mid = part.len() / 2;
        let key = |i: &u32| boxes[*i as usize].center_axis(axis);
        part.select_nth_unstable_by(mid, |a, b| key(a).total_cmp(&key(b)));
        let left = nodes.len();
        nodes.extend([Bvh2Node::default(); 2]);
        nodes[node] = Bvh2Node::new(bounds, 0, left as u32);
        todo.extend([(left, start, start + mid), (left + 1, start + mid, end)]);
    }
    Bvh2 { nodes, primitive_indices: order, ..Bvh2::default() }
}

/// Barycentric slack of the triangle test (see the module docs): hits are accepted for
/// `u, v >= -EDGE_TOLERANCE` and `u + v <= 1 + EDGE_TOLERANCE`.
pub const EDGE_TOLERANCE: f32 = 1e-5;

/// A triangle prepared for ray tests: `v0`, edges `e1 = v1 - v0`, `e2 = v2 - v0`, and the
/// unnormalised normal `ng = e1 x e2` (64 bytes, one cache line).
#[derive(Clone, Copy, Debug)]
pub(crate) struct RtTri {
    pub v0: Vec3A,
    pub e1: Vec3A,
    pub e2: Vec3A,
    pub ng: Vec3A,
}

impl RtTri {
    fn new(t: &Triangle) -> Self {
        let (e1, e2) = (t.v1 - t.v0, t.v2 - t.v0);
        Self { v0: t.v0, e1, e2, ng: e1.cross(e2) }
    }

    /// Distance `t` in `[ray.tmin, ray.tmax]` of the hit, or infinity. Solving
    /// `o + t d = v0 + u e1 + v e2` by Cramer's rule with `c = v0 - o`, `r = d x c`:
    /// `u = -(e2 . r) / (d . ng)`, `v = (e1 . r) / (d . ng)`, `t = (c . ng) / (d . ng)`.
    /// A ray parallel to the plane gives infinities or NaN, which fail the comparisons.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray) -> f32 {
        let c = self.v0 - ray.origin;
        let r = ray.direction.cross(c);
        let inv_det = 1.0 / ray.direction.dot(self.ng);
        let u = -self.e2.dot(r) * inv_det;
        let v = self.e1.dot(r) * inv_det;
        if u >= -EDGE_TOLERANCE && v >= -EDGE_TOLERANCE && u + v <= 1.0 + EDGE_TOLERANCE {
            let t = c.dot(self.ng) * inv_det;
            if t >= ray.tmin && t <= ray.tmax {
                return t;
            }
        }
        f32::INFINITY
    }
}

/// Lanes of a [`TileTriangles`] chunk.
const LANES: usize = 8;

/// Eight triangles, structure of arrays, as one ray from the tile's origin tests them.
#[derive(Clone, Copy, Debug, Default)]
struct TriChunk {
    /// `c = v0 - origin`, the edges and the unnormalised normal, per axis.
    c: [[f32; LANES]; 3],
    e1: [[f32; LANES]; 3],
    e2: [[f32; LANES]; 3],
    ng: [[f32; LANES]; 3],
    /// `c . ng`, the numerator of every ray's `t` (it does not depend on the direction).
    c_ng: [f32; LANES],
}

/// The candidate occluders of one tile ([`SceneBvh::cone_candidates`]) prepared for its
/// rays, which all start at one origin: eight triangles to a chunk in structure-of-arrays
/// form, with what depends only on the origin computed once, so a ray tests a chunk in one
/// pass the compiler vectorises ([`SceneBvh::occluded_in_tile`]). Unused lanes are zero
/// triangles, which no ray hits (their determinant is 0, so `u` is NaN).
#[derive(Clone, Debug, Default)]
pub(crate) struct TileTriangles {
    chunks: Vec<TriChunk>,
    /// The BVH primitive of each lane (for the occluder cache).
    ids: Vec<u32>,
}

impl TileTriangles {
    pub(crate) fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// Which lanes of `chunk` the ray in direction `d` hits (bit `i` for lane `i`), with
/// [`RtTri::intersect`]'s arithmetic and acceptance test.
// The comparisons are combined with `&`, not `&&` (or `contains`), so that all eight lanes
// are computed without branches.
#[allow(clippy::manual_range_contains)]
#[inline(always)]
fn chunk_hits(chunk: &TriChunk, d: [f32; 3]) -> u32 {
    let TriChunk { c, e1, e2, ng, c_ng } = chunk;
    let mut hit = [false; LANES];
    for i in 0..LANES {
        // r = d x c, as glam's cross.
        let r = [d[1] * c[2][i] - d[2] * c[1][i], d[2] * c[0][i] - d[0] * c[2][i], d[0] * c[1][i] - d[1] * c[0][i]];
        let inv_det = 1.0 / ((d[0] * ng[0][i] + d[1] * ng[1][i]) + d[2] * ng[2][i]);
        let u = -((e2[0][i] * r[0] + e2[1][i] * r[1]) + e2[2][i] * r[2]) * inv_det;
        let v = ((e1[0][i] * r[0] + e1[1][i] * r[1]) + e1[2][i] * r[2]) * inv_det;
        let t = c_ng[i] * inv_det;
        hit[i] = (u >= -EDGE_TOLERANCE)
            & (v >= -EDGE_TOLERANCE)
            & (u + v <= 1.0 + EDGE_TOLERANCE)
            & (t >= RAY_TMIN)
            & (t <= f32::INFINITY);
    }
    hit.iter().enumerate().fold(0, |m, (i, &h)| m | (h as u32) << i)
}

/// Start of the occlusion rays of the transfer stage, `t >= RAY_TMIN`: obvhs's node test skips
/// boxes the ray leaves before `t = 1e-4` (its `EPSILON`), so hits closer than that are
/// found or not depending on the tree; starting every such ray there makes the BVH and the
/// brute-force paths agree exactly.
pub(crate) const RAY_TMIN: f32 = 1e-4;

/// A cone of directions: unit `axis`, half-angle given by its cosine and sine.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cone {
    pub axis: Vec3A,
    pub cos: f32,
    pub sin: f32,
}

impl Cone {
    /// Does every direction of the cone lie below the plane with unit normal `n`? The axis
    /// is then more than 90 degrees plus the half-angle from `n` (1e-6 of slack for the f32
    /// dot product), so no ray of it is above the horizon.
    #[inline]
    pub(crate) fn below(&self, n: Vec3A) -> bool {
        self.axis.dot(n) < -self.sin - 1e-6
    }

    /// Does every direction of the cone lie above that plane (the axis less than 90 degrees
    /// minus the half-angle from `n`, with the same slack)?
    #[inline]
    pub(crate) fn above(&self, n: Vec3A) -> bool {
        self.axis.dot(n) > self.sin + 1e-6
    }
}

/// A sphere tree over the primitives in BVH order (contiguous ranges of the CWBVH leaf
/// order are spatially compact), stored in depth-first order with skip links so a query
/// is one loop. Each sphere bounds its triangles grown by the test's edge tolerance.
#[derive(Clone, Debug, Default)]
struct ConeTree {
    /// Node spheres `(centre, radius)`.
    spheres: Vec<(Vec3A, f32)>,
    /// `(first primitive, end primitive, next node after this subtree)`; a leaf when the
    /// next node is `index + 1`.
    ranges: Vec<(u32, u32, u32)>,
    /// Per-primitive spheres, for the leaf-level test.
    tri_spheres: Vec<(Vec3A, f32)>,
    /// Absolute slack added to every radius and plane test (1e-6 of the scene's size, over
    /// f32 rounding of the tests).
    slack: f32,
}

const CONE_LEAF: usize = 8;

impl ConeTree {
    fn build(tris: &[RtTri]) -> Self {
        // The region the triangle test accepts is the triangle scaled by 1 + 3 tol about its
        // centroid; bound it scaled by 1 + 4 tol for f32 slack.
        let grow = 1.0 + 4.0 * EDGE_TOLERANCE;
        let corners: Vec<[Vec3A; 3]> = tris
            .iter()
            .map(|t| {
                let v = [t.v0, t.v0 + t.e1, t.v0 + t.e2];
                let c = (v[0] + v[1] + v[2]) / 3.0;
                v.map(|p| c + (p - c) * grow)
            })
            .collect();
        let tri_spheres = corners
            .iter()
            .map(|v| {
                let c = (v[0] + v[1] + v[2]) / 3.0;
                (c, v.iter().map(|p| (*p - c).length()).fold(0.0, f32::max))
            })
            .collect();
        let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        for v in corners.iter().flatten() {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        let mut tree = Self { slack: 1e-6 * (hi - lo).length(), tri_spheres, ..Default::default() };
        if !tris.is_empty() {
            tree.build_range(&corners, 0, tris.len());
        }
        tree
    }

    fn build_range(&mut self, corners: &[[Vec3A; 3]], a: usize, b: usize) {
        let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        for v in corners[a..b].iter().flatten() {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        let me = self.spheres.len();
        self.spheres.push((0.5 * (lo + hi), 0.5 * (hi - lo).length()));
        self.ranges.push((a as u32, b as u32, 0));
        if b - a > CONE_LEAF {
            let mid = (a + b) / 2;
            self.build_range(corners, a, mid);
            self.build_range(corners, mid, b);
        }
        self.ranges[me].2 = self.spheres.len() as u32;
    }

    /// Can a ray from `o` with direction in `cone` and `d . n > 0` reach the sphere?
    /// Conservative: false only when it certainly cannot.
    #[inline(always)]
    fn reachable(&self, sphere: (Vec3A, f32), o: Vec3A, n: Vec3A, cone: &Cone) -> bool {
        let (w, r) = self.seen_from(sphere, o);
        !behind(w, r, n) && meets_cone(w, r, cone)
    }

    /// The sphere's centre relative to `o`, and its radius padded by the slack the
    /// conservative tests need: f32 rounding relative to the distance (the L1 norm bounds the
    /// distance from above, so no square root is needed for it).
    #[inline(always)]
    fn seen_from(&self, (c, r): (Vec3A, f32), o: Vec3A) -> (Vec3A, f32) {
        let w = c - o;
        (w, r + self.slack + 1e-6 * (w.x.abs() + w.y.abs() + w.z.abs()))
    }
}

/// Does the sphere of (padded) radius `r` at `w` from the origin lie wholly on or below the
/// plane through the origin with normal `n`, where no ray above it goes? Every point x of
/// the sphere has `x . n <= w . n + r`; a ray point has `x . n = t d . n > 0`.
#[inline(always)]
fn behind(w: Vec3A, r: f32, n: Vec3A) -> bool {
    w.dot(n) + r <= 0.0
}

/// Does the sphere of (padded) radius `r` at `w` from the origin meet `cone`? Conservative.
#[inline(always)]
fn meets_cone(w: Vec3A, r: f32, cone: &Cone) -> bool {
    let d2 = w.length_squared();
    if d2 <= r * r {
        return true;
    }
    // The sphere subtends a cone of half-angle b around w (sin b = r / |w|); it meets
    // the query cone iff angle(w, axis) <= a + b (a + b < pi for the tiles used):
    // w . axis >= cos(a + b) |w| = cos a sqrt(|w|^2 - r^2) - sin a r, one square root.
    w.dot(cone.axis) + cone.sin * r >= cone.cos * (d2 - r * r).sqrt()
}

impl ConeTree {
    /// Append the reachable primitives to `out`; false (the list cut short) once it holds
    /// more than `limit`.
    fn query(&self, o: Vec3A, n: Vec3A, cone: &Cone, out: &mut Vec<u32>, limit: usize) -> bool {
        let mut i = 0usize;
        while i < self.ranges.len() {
            let (a, b, next) = self.ranges[i];
            if !self.reachable(self.spheres[i], o, n, cone) {
                i = next as usize;
                continue;
            }
            if next as usize == i + 1 {
                for p in a..b {
                    if self.reachable(self.tri_spheres[p as usize], o, n, cone) {
                        out.push(p);
                    }
                }
                if out.len() > limit {
                    return false;
                }
            }
            i += 1;
        }
        true
    }
}

/// A ray direction with its component-wise reciprocal precomputed as obvhs's `Ray::new`
/// does, for directions reused by many rays.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RayDir {
    pub dir: Vec3A,
    pub inv: Vec3A,
}

impl RayDir {
    pub fn new(dir: Vec3) -> Self {
        let r = Ray::new(Vec3A::ZERO, Vec3A::from(dir), 0.0, f32::INFINITY);
        Self { dir: r.direction, inv: r.inv_direction }
    }
}

/// Barycentrics `(b1, b2)` of point `p` (assumed on the triangle's plane).
fn barycentric(tri: &Triangle, p: Vec3) -> Vec2 {
    let (a, b, c) = (Vec3::from(tri.v0), Vec3::from(tri.v1), Vec3::from(tri.v2));
    let (e1, e2, ep) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (dp1, dp2) = (ep.dot(e1), ep.dot(e2));
    let den = d11 * d22 - d12 * d12;
    if den.abs() < f32::MIN_POSITIVE {
        return Vec2::ZERO;
    }
    let b1 = (d22 * dp1 - d12 * dp2) / den;
    let b2 = (d11 * dp2 - d12 * dp1) / den;
    Vec2::new(b1, b2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        // Unit square in the XZ plane at y = 0, facing +Y.
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        (p, vec![[0, 3, 2], [0, 2, 1]])
    }

    #[test]
    fn a_capped_cone_query_is_the_full_list_or_a_longer_prefix_of_it() {
        // A grid of 20 x 20 quads under a point looking down through cones of several widths.
        let (mut p, mut t) = (vec![], vec![]);
        for i in 0..20 {
            for j in 0..20 {
                let b = p.len() as u32;
                let (x, z) = (i as f32, j as f32);
                p.extend([Vec3::new(x, 0.0, z), Vec3::new(x + 1.0, 0.0, z), Vec3::new(x + 1.0, 0.0, z + 1.0)]);
                t.push([b, b + 2, b + 1]);
            }
        }
        let bvh = SceneBvh::build(&p, &t);
        let (o, n) = (Vec3A::new(10.0, 3.0, 10.0), Vec3A::NEG_Y);
        for angle in [0.05f32, 0.3, 0.8, 1.2] {
            let cone = Cone { axis: Vec3A::NEG_Y, cos: angle.cos(), sin: angle.sin() };
            let mut full = vec![];
            assert!(bvh.cone_candidates(o, n, &cone, &mut full, usize::MAX));
            for limit in [0, 1, 5, 40, 1000] {
                let mut capped = vec![];
                let complete = bvh.cone_candidates(o, n, &cone, &mut capped, limit);
                assert_eq!(complete, full.len() <= limit, "angle {angle}, limit {limit}");
                if complete {
                    assert_eq!(capped, full);
                } else {
                    assert!(capped.len() > limit && full.starts_with(&capped), "angle {angle}, limit {limit}");
                }
            }
        }
    }

    #[test]
    fn hits_and_misses() {
        let (p, t) = quad();
        let bvh = SceneBvh::build(&p, &t);
        let down = Vec3::new(0.0, -1.0, 0.0);
        assert!(bvh.occluded(Vec3::new(0.3, 1.0, 0.6), down, 0.0, f32::INFINITY));
        assert!(!bvh.occluded(Vec3::new(1.3, 1.0, 0.6), down, 0.0, f32::INFINITY));
        assert!(!bvh.occluded(Vec3::new(0.3, 1.0, 0.6), down, 0.0, 0.5), "tmax respected");
        let h = bvh.closest_hit(Vec3::new(0.3, 2.0, 0.6), down, 0.0, f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        let tri = t[h.triangle as usize];
        let bary = h.barycentric;
        let q =
            p[tri[0] as usize] * (1.0 - bary.x - bary.y) + p[tri[1] as usize] * bary.x + p[tri[2] as usize] * bary.y;
        assert!((q - Vec3::new(0.3, 0.0, 0.6)).length() < 1e-5);
    }

    /// Regression (hostile input): a convex 2,000-gon fanned from one corner, as OBJ
    /// exporters triangulate it, made obvhs's builder a 78-level chain, past its 32-entry
    /// traversal stack (and debug builds panicked in its validation).
    #[test]
    fn a_fan_of_slivers_builds_a_shallow_bvh_that_finds_every_hit() {
        let n = 2000;
        let p: Vec<Vec3> = (0..n)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / n as f32;
                Vec3::new(a.cos(), 0.0, a.sin())
            })
            .collect();
        let t: Vec<[u32; 3]> = (1..n as u32 - 1).map(|i| [0, i + 1, i]).collect();
        let bvh = SceneBvh::build(&p, &t);
        assert!(cwbvh_depth(&bvh.bvh) < MAX_CWBVH_DEPTH, "depth {}", cwbvh_depth(&bvh.bvh));
        assert_eq!(bvh.len(), t.len());
        // Rays up through the disc near the fan's corner, where every sliver's box overlaps,
        // hit the disc; rays beside it do not.
        let up = Vec3::Y;
        for k in 0..500 {
            let a = std::f32::consts::PI * (0.65 + 0.7 * k as f32 / 500.0);
            let r = 0.01 + 0.5 * (k % 7) as f32 / 7.0;
            let o = Vec3::new(1.0 + r * a.cos(), -1.0, r * a.sin());
            assert!(bvh.occluded(o, up, 0.0, f32::INFINITY), "ray {k} from {o} slipped through");
            let h = bvh.closest_hit(o, up, 0.0, f32::INFINITY).expect("a hit");
            assert!((h.t - 1.0).abs() < 1e-5);
        }
        assert!(!bvh.occluded(Vec3::new(1.01, -1.0, 0.0), up, 0.0, f32::INFINITY));
    }

    #[test]
    fn median_splits_are_balanced_and_keep_every_triangle() {
        let tri = |x: f32| Triangle {
            v0: Vec3A::new(x, 0.0, 0.0),
            v1: Vec3A::new(x + 1.0, 0.0, 0.0),
            v2: Vec3A::new(x, 1.0, 0.0),
        };
        let soup: Vec<Triangle> = (0..1000).map(|i| tri(i as f32)).collect();
        let b = median_split_bvh2(&soup);
        assert_eq!(b.depth(0), 11, "ceil(log2 1000) + 1 levels");
        let mut prims = b.primitive_indices.clone();
        prims.sort_unstable();
        assert_eq!(prims, (0..1000).collect::<Vec<u32>>());
        assert!(cwbvh_depth(&bvh2_to_cwbvh(&b, 3, true, false)) <= 4);
    }

    /// A closed unit sphere (shared edges) and `count` random triangles around it: centres
    /// uniform in `[-half, half]^3`, corners offset by up to one of `sizes` per axis. Returns
    /// the sphere's vertex count (its vertices come first), the positions and the triangles.
    fn sphere_with_soup(
        rng: &mut rand_chacha::ChaCha8Rng,
        count: usize,
        half: f32,
        sizes: &[f32],
    ) -> (usize, Vec<Vec3>, Vec<[u32; 3]>) {
        use rand::Rng;
        let sphere = crate::geometry::shapes::uv_sphere(Vec3::ZERO, 1.0, 10, 14);
        let (mut positions, mut triangles) = (sphere.positions.clone(), sphere.triangles.clone());
        let uniform = |rng: &mut rand_chacha::ChaCha8Rng, r: f32| {
            Vec3::new(rng.gen_range(-r..r), rng.gen_range(-r..r), rng.gen_range(-r..r))
        };
        for _ in 0..count {
            let base = positions.len() as u32;
            let c = uniform(rng, half);
            let size = sizes[rng.gen_range(0..sizes.len())];
            for _ in 0..3 {
                positions.push(c + uniform(rng, size));
            }
            triangles.push([base, base + 1, base + 2]);
        }
        (sphere.positions.len(), positions, triangles)
    }

    /// The eight-lane tile test gives every triangle's answer of the one-at-a-time test, bit
    /// for bit: on a closed mesh (shared edges) and random triangles, from origins on and off
    /// the surface, for random rays and for rays aimed exactly at vertices and edge midpoints
    /// (where the edge tolerance decides), with candidate lists of every length modulo 8.
    #[test]
    fn the_tile_test_matches_the_triangle_test_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (sphere_vertices, positions, triangles) = sphere_with_soup(&mut rng, 60, 2.0, &[0.5]);
        let bvh = SceneBvh::build(&positions, &triangles);
        let all: Vec<u32> = (0..bvh.len() as u32).collect();
        let mut tile = TileTriangles::default();
        let (mut checked, mut hits) = (0usize, 0usize);
        for round in 0..40 {
            let origin = match round % 2 {
                0 => Vec3A::new(rng.gen_range(-2.5..2.5), rng.gen_range(-2.5..2.5), rng.gen_range(-2.5..2.5)),
                _ => Vec3A::from(positions[rng.gen_range(0..sphere_vertices)]) * 1.0001,
            };
            let len = rng.gen_range(1..=all.len().min(120));
            let start = rng.gen_range(0..=all.len() - len);
            let candidates = &all[start..start + len];
            bvh.prepare_tile(origin, candidates, &mut tile);
            for r in 0..200 {
                let target = match r % 3 {
                    0 => Vec3A::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)),
                    1 => {
                        let t = &bvh.tris[candidates[rng.gen_range(0..len)] as usize];
                        [t.v0, t.v0 + t.e1, t.v0 + t.e2][rng.gen_range(0..3)] - origin
                    }
                    _ => {
                        let t = &bvh.tris[candidates[rng.gen_range(0..len)] as usize];
                        t.v0 + 0.5 * [t.e1, t.e2, t.e1 + t.e2][rng.gen_range(0..3)] - origin
                    }
                };
                if target.length_squared() == 0.0 {
                    continue;
                }
                let dir = RayDir::new(Vec3::from(target.normalize()));
                let ray =
                    Ray { origin, direction: dir.dir, inv_direction: dir.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
                let d = [dir.dir.x, dir.dir.y, dir.dir.z];
                for (k, chunk) in tile.chunks.iter().enumerate() {
                    let mask = chunk_hits(chunk, d);
                    for lane in 0..LANES {
                        let want = candidates
                            .get(k * LANES + lane)
                            .is_some_and(|&id| bvh.tris[id as usize].intersect(&ray) < f32::INFINITY);
                        assert_eq!(mask >> lane & 1 == 1, want, "round {round}, ray {r}, lane {}", k * LANES + lane);
                        hits += want as usize;
                        checked += 1;
                    }
                }
                let (mut c1, mut c2) = (u32::MAX, u32::MAX);
                assert_eq!(
                    bvh.occluded_in_tile(origin, &dir, &tile, &mut c1),
                    bvh.occluded_among(origin, &dir, candidates, &mut c2)
                );
            }
        }
        assert!(hits > 1000 && checked > 100_000, "{hits} hits of {checked}");
    }

    /// A packet of rays from one origin is answered as each ray alone, by brute force over
    /// every triangle (the definition), whatever the packet's size, the rays' spread (random
    /// directions, and rays through vertices and edge midpoints, where the tolerance band
    /// decides) and the occluder cache. Scenes: a sphere with a random soup around it (a
    /// four-wide tree several levels deep), four triangles (one leaf), and one.
    #[test]
    fn packets_answer_as_each_ray_alone() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
        let (sphere_vertices, positions, triangles) = sphere_with_soup(&mut rng, 400, 3.0, &[0.02, 0.3, 1.0]);
        let (mut checked, mut hits) = (0usize, 0usize);
        for scene in 0..3 {
            let tris = match scene {
                0 => &triangles[..],
                1 => &triangles[triangles.len() - 4..],
                _ => &triangles[triangles.len() - 1..],
            };
            let bvh = SceneBvh::build(&positions, tris);
            let wide = bvh.wide.as_ref().expect("a four-wide tree");
            let mut ids = wide.triangle_ids().to_vec();
            ids.sort_unstable();
            assert_eq!(ids, (0..bvh.len() as u32).collect::<Vec<_>>(), "every triangle in exactly one leaf");
            for round in 0..300 {
                let origin = match round % 3 {
                    0 => Vec3A::new(rng.gen_range(-3.5..3.5), rng.gen_range(-3.5..3.5), rng.gen_range(-3.5..3.5)),
                    1 => Vec3A::from(positions[rng.gen_range(0..sphere_vertices)]) * 1.0001,
                    _ => Vec3A::ZERO,
                };
                let n = rng.gen_range(1..=PACKET);
                let spread = [0.05f32, 0.5, 2.0][rng.gen_range(0..3)];
                let axis = Vec3A::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
                let dirs: Vec<RayDir> = (0..n)
                    .filter_map(|r| {
                        let t = &bvh.tris[rng.gen_range(0..bvh.len())];
                        let target = match r % 5 {
                            0 => {
                                axis + spread
                                    * Vec3A::new(
                                        rng.gen_range(-1.0..1.0),
                                        rng.gen_range(-1.0..1.0),
                                        rng.gen_range(-1.0..1.0),
                                    )
                            }
                            1 => [t.v0, t.v0 + t.e1, t.v0 + t.e2][rng.gen_range(0..3)] - origin,
                            2 => t.v0 + 0.5 * [t.e1, t.e2, t.e1 + t.e2][rng.gen_range(0..3)] - origin,
                            // Just outside a corner, inside the tolerance band: outside the
                            // triangle's exact bounds, so only the boxes' padding finds it.
                            3 => {
                                let corners = [t.v0, t.v0 + t.e1, t.v0 + t.e2];
                                let centre = (corners[0] + corners[1] + corners[2]) / 3.0;
                                let v = corners[rng.gen_range(0..3)];
                                v + (v - centre) * 4e-6 - origin
                            }
                            _ => [Vec3A::X, Vec3A::NEG_Y, Vec3A::Z, axis][rng.gen_range(0..4)],
                        };
                        (target.length_squared() > 0.0).then(|| RayDir::new(Vec3::from(target.normalize())))
                    })
                    .collect();
                let refs: Vec<&RayDir> = dirs.iter().collect();
                let mut cache = match round % 2 {
                    0 => u32::MAX,
                    _ => rng.gen_range(0..bvh.len() as u32),
                };
                let got = bvh.occluded_packet(origin, &refs, &mut cache);
                assert_eq!(got.checked_shr(dirs.len() as u32).unwrap_or(0), 0, "bits past the packet");
                for (i, d) in dirs.iter().enumerate() {
                    let ray =
                        Ray { origin, direction: d.dir, inv_direction: d.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
                    let want = bvh.tris.iter().any(|t| t.intersect(&ray) < f32::INFINITY);
                    assert_eq!(got >> i & 1 == 1, want, "scene {scene}, round {round}, ray {i} of {}", dirs.len());
                    hits += want as usize;
                    checked += 1;
                }
                if got != 0 {
                    assert!(cache < bvh.len() as u32, "the cache names an occluder");
                }
            }
        }
        assert!(hits > 2000 && checked > 8000 && hits < checked - 2000, "{hits} hits of {checked}");
    }

    /// The cone query is conservative: every triangle that a ray from the origin, inside the
    /// cone and above the plane, hits is listed. Random soups (near and far, tiny and large
    /// triangles), origins, normals and cones from 0.01 to 0.95 rad; directions sampled in
    /// each cone, half of them on its rim.
    #[test]
    fn the_cone_query_lists_every_triangle_its_rays_hit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let unit = |rng: &mut rand_chacha::ChaCha8Rng| loop {
            let v = Vec3A::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            if v.length_squared() > 0.01 && v.length_squared() <= 1.0 {
                break v.normalize();
            }
        };
        let (mut p, mut t) = (vec![], vec![]);
        for i in 0..400u32 {
            let c = Vec3::new(rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0));
            let size = [0.01, 0.3, 2.0][i as usize % 3];
            for _ in 0..3 {
                p.push(
                    c + size * Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)),
                );
            }
            t.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        let bvh = SceneBvh::build(&p, &t);
        let mut hits = 0;
        for _ in 0..300 {
            let o = Vec3A::new(rng.gen_range(-2.0..2.0), rng.gen_range(-2.0..2.0), rng.gen_range(-2.0..2.0));
            let n = unit(&mut rng);
            let axis = unit(&mut rng);
            let angle: f32 = rng.gen_range(0.01..0.95);
            let cone = Cone { axis, cos: angle.cos(), sin: angle.sin() };
            let mut listed = vec![];
            assert!(bvh.cone_candidates(o, n, &cone, &mut listed, usize::MAX));
            // An orthonormal pair across the axis, to sample directions at an angle from it.
            let side = if axis.x.abs() < 0.9 { Vec3A::X } else { Vec3A::Y };
            let (b1, b2) = (axis.cross(side).normalize(), axis.cross(axis.cross(side)).normalize());
            for k in 0..200 {
                let theta = if k % 2 == 0 { angle } else { rng.gen_range(0.0..angle) };
                let phi: f32 = rng.gen_range(0.0..std::f32::consts::TAU);
                let d = (axis * theta.cos() + (b1 * phi.cos() + b2 * phi.sin()) * theta.sin()).normalize();
                if d.dot(n) <= 0.0 {
                    continue;
                }
                let dir = RayDir::new(Vec3::from(d));
                let ray =
                    Ray { origin: o, direction: dir.dir, inv_direction: dir.inv, tmin: RAY_TMIN, tmax: f32::INFINITY };
                for (id, tri) in bvh.tris.iter().enumerate() {
                    if tri.intersect(&ray) < f32::INFINITY {
                        hits += 1;
                        assert!(listed.contains(&(id as u32)), "triangle {id} hit along {d} but not listed");
                    }
                }
            }
        }
        assert!(hits > 1000, "{hits} hits checked");
    }

    #[test]
    fn empty_scene_hits_nothing() {
        let bvh = SceneBvh::build(&[], &[]);
        assert!(!bvh.occluded(Vec3::ZERO, Vec3::X, 0.0, 1.0));
        assert!(bvh.closest_hit(Vec3::ZERO, Vec3::X, 0.0, 1.0).is_none());
    }
}
