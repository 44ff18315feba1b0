//! A four-wide BVH traced by packets of rays from one origin, for the transfer stage's
//! occlusion rays that its cone-culled lists do not serve.
//!
//! A tile's rays all start at the vertex and point within a narrow cone, so they visit
//! mostly the same nodes. Traced one by one through obvhs's CWBVH, each ray fetched those
//! nodes again, and on a mesh whose tree no longer fits in the L2 that fetching, not the box
//! arithmetic, was the transfer stage's largest cost (a one-ray-at-a-time version of this
//! tree was no faster than obvhs's). Here a packet of up to [`PACKET`] rays walks the tree
//! together: each node's four child boxes (stored as f32 planes) are tested against every
//! active ray, and a child is opened, once, for the rays that hit it.
//!
//! Exactness: a ray is occluded when some triangle's [`RtTri::intersect`] accepts it
//! (`t >= tmin`); the traversal must never cull a box around such a hit. Each box is the
//! triangles' bounds grown by the [`EDGE_TOLERANCE`] band the triangle test accepts (twice
//! over, relative to the triangle's extent) plus a relative and an absolute margin, and the
//! slab test compares `t_near <= t_far * (1 + 2^-20)`, far more than the few ulps of rounding
//! in `(plane - o) / d`. Culling only ever removes triangles the ray cannot hit, so the answer
//! is the brute-force answer (tested against it, and the transfer stage's `T` against the
//! per-ray definition).

use super::bvh::{RtTri, EDGE_TOLERANCE};
use glam::{Vec3A, Vec4};
use obvhs::bvh2::Bvh2;

/// Rays of a packet ([`Bvh4::occluded_packet`]): the bits of a `u32`.
pub(crate) const PACKET: usize = 32;
const _: () = assert!(PACKET <= u32::BITS as usize);
/// Quads of rays in a packet (one 4-lane slab test each).
const QUADS: usize = PACKET / 4;
/// Largest subtree (in triangles) kept as one leaf.
const LEAF_MAX: u32 = 4;
/// Deepest tree the fixed traversal stack serves: a pop pushes at most four children, so
/// `3 * depth + 1` entries are enough.
const MAX_DEPTH: usize = 80;
const STACK: usize = 3 * MAX_DEPTH + 1;
/// Child codes: a node index, or a leaf (`LEAF | count << COUNT_SHIFT | first triangle`).
const LEAF: u32 = 1 << 31;
const COUNT_SHIFT: u32 = 28;
const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;
const EMPTY: u32 = u32::MAX;
/// Slack of the slab test: `t_near <= t_far * FAR_SLACK` (see the module docs).
const FAR_SLACK: f32 = 1.0 + 1.0 / (1 << 20) as f32;

/// Four children: boxes as `lo[axis][child]`, `hi[axis][child]`, and what each child is.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct Node4 {
    lo: [Vec4; 3],
    hi: [Vec4; 3],
    child: [u32; 4],
    /// Bit `c` set when child `c` exists.
    full: u32,
}

/// The four-wide tree: nodes (the root is node 0, unless the tree is one leaf or empty) and
/// the triangles in leaf order with their indices in the caller's triangle list.
#[derive(Clone, Debug, Default)]
pub(crate) struct Bvh4 {
    nodes: Vec<Node4>,
    /// The root when it is a single leaf (a scene of at most `LEAF_MAX` triangles).
    root_leaf: Option<u32>,
    tris: Vec<RtTri>,
    ids: Vec<u32>,
}

/// The box `lo..hi` grown by `band` (the triangle test's tolerance band) plus margins for
/// the rounding of the box and of the slab test.
fn grow(lo: Vec3A, hi: Vec3A, band: Vec3A) -> (Vec3A, Vec3A) {
    let pad = band + lo.abs().max(hi.abs()) * 1e-6 + Vec3A::splat(1e-30);
    (lo - pad, hi + pad)
}

/// Bounds of one triangle, grown by the test's tolerance band and a margin.
fn padded_box(t: &RtTri) -> (Vec3A, Vec3A) {
    let (v1, v2) = (t.v0 + t.e1, t.v0 + t.e2);
    // A hit with barycentrics down to -EDGE_TOLERANCE lies within EDGE_TOLERANCE * (|e1| +
    // |e2|) per axis of the triangle: grown by twice that.
    grow(t.v0.min(v1).min(v2), t.v0.max(v1).max(v2), (t.e1.abs() + t.e2.abs()) * (2.0 * EDGE_TOLERANCE))
}

impl Bvh4 {
    /// Collapse `bvh2` into four-wide nodes over the caller's `tris`, where `bvh2`'s primitive
    /// `p` (as `bvh2.primitive_indices` names it) is `tris[index_of[p]]` and occluders are
    /// reported by that index; `None` if the result would be deeper than [`MAX_DEPTH`] or too
    /// large to address (the caller then keeps obvhs's traversal).
    pub(crate) fn build(bvh2: &Bvh2, tris: &[RtTri], index_of: &[u32]) -> Option<Self> {
        if bvh2.nodes.is_empty() || tris.is_empty() {
            return Some(Self::default());
        }
        if tris.len() >= FIRST_MASK as usize {
            return None;
        }
        let n2 = &bvh2.nodes;
        // Triangles under each BVH2 node, children before parents (the reinsertion pass
        // leaves nodes in no particular order). A BVH2 leaf bigger than a leaf here can hold
        // is not expected from obvhs's builders; refuse it rather than split it.
        let mut count = vec![0u32; n2.len()];
        let mut todo = vec![(0usize, false)];
        while let Some((i, children_done)) = todo.pop() {
            let n = &n2[i];
            if n.is_leaf() {
                if n.prim_count > LEAF_MAX {
                    return None;
                }
                count[i] = n.prim_count;
            } else if children_done {
                count[i] = count[n.first_index as usize] + count[n.first_index as usize + 1];
            } else {
                todo.extend([(i, true), (n.first_index as usize, false), (n.first_index as usize + 1, false)]);
            }
        }
        let mut out = Self::default();
        let boxes: Vec<(Vec3A, Vec3A)> = tris.iter().map(padded_box).collect();
        // Append the triangles under BVH2 node `i` to the leaf order; returns the child code.
        let leaf = |out: &mut Self, i: usize| -> (u32, Vec3A, Vec3A) {
            let first = out.tris.len() as u32;
            let mut todo = vec![i];
            let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
            while let Some(j) = todo.pop() {
                let n = &n2[j];
                if n.is_leaf() {
                    for p in n.first_index..n.first_index + n.prim_count {
                        let id = index_of[bvh2.primitive_indices[p as usize] as usize];
                        out.tris.push(tris[id as usize]);
                        out.ids.push(id);
                        let (l, h) = boxes[id as usize];
                        (lo, hi) = (lo.min(l), hi.max(h));
                    }
                } else {
                    todo.extend([n.first_index as usize + 1, n.first_index as usize]);
                }
            }
            let k = out.tris.len() as u32 - first;
            (LEAF | k << COUNT_SHIFT | first, lo, hi)
        };
        if count[0] <= LEAF_MAX {
            let (code, ..) = leaf(&mut out, 0);
            out.root_leaf = Some(code);
            return Some(out);
        }
        // Depth-first: (BVH2 node, its slot in the four-wide tree, depth).
        out.nodes.push(Node4::empty());
        let mut todo = vec![(0usize, 0usize, 1usize)];
        while let Some((i, slot, depth)) = todo.pop() {
            if depth > MAX_DEPTH {
                return None;
            }
            // Open the largest internal grandchildren until there are four children.
            let n = &n2[i];
            let mut kids = vec![n.first_index as usize, n.first_index as usize + 1];
            while kids.len() < 4 {
                let open = kids
                    .iter()
                    .enumerate()
                    .filter(|(_, &k)| !n2[k].is_leaf() && count[k] > LEAF_MAX)
                    .max_by(|a, b| n2[*a.1].aabb().half_area().total_cmp(&n2[*b.1].aabb().half_area()));
                let Some((p, &k)) = open else { break };
                let first = n2[k].first_index as usize;
                kids[p] = first;
                kids.push(first + 1);
            }
            for (c, &k) in kids.iter().enumerate() {
                if count[k] == 0 {
                    continue;
                }
                let (code, lo, hi) = if count[k] <= LEAF_MAX {
                    leaf(&mut out, k)
                } else {
                    let child = out.nodes.len();
                    out.nodes.push(Node4::empty());
                    todo.push((k, child, depth + 1));
                    // obvhs's box, grown like the leaves' (it holds the unpadded triangles).
                    let b = n2[k].aabb();
                    let (lo, hi) = grow(b.min, b.max, (b.max - b.min) * (2.0 * EDGE_TOLERANCE));
                    (child as u32, lo, hi)
                };
                let node = &mut out.nodes[slot];
                node.child[c] = code;
                node.full |= 1 << c;
                for a in 0..3 {
                    node.lo[a][c] = lo[a];
                    node.hi[a][c] = hi[a];
                }
            }
        }
        Some(out)
    }

    /// Which of `rays` (at most [`PACKET`], all from one origin, with one `tmin` and `tmax`)
    /// whose bit is set in `active` are occluded: bit `i` of the result is set when some
    /// triangle's [`RtTri::intersect`] accepts ray `i`. Each node's boxes are tested against
    /// every active ray at once: `(plane - o)` once per plane, times each ray's reciprocal,
    /// the single-ray slab test, so a ray enters a box exactly when it would alone. `cache`
    /// is set to the caller's index of an occluder found.
    pub(crate) fn occluded_packet(&self, rays: &[obvhs::ray::Ray], active: u32, cache: &mut u32) -> u32 {
        let mut occluded = 0u32;
        let leaf_hits = |code: u32, mask: u32, occluded: &mut u32, cache: &mut u32| {
            let first = (code & FIRST_MASK) as usize;
            let n = ((code & !LEAF) >> COUNT_SHIFT) as usize;
            for i in first..first + n {
                let mut m = mask & !*occluded;
                while m != 0 {
                    let r = m.trailing_zeros() as usize;
                    m &= m - 1;
                    if self.tris[i].intersect(&rays[r]) < f32::INFINITY {
                        *occluded |= 1 << r;
                        *cache = self.ids[i];
                    }
                }
            }
        };
        if let Some(code) = self.root_leaf {
            leaf_hits(code, active, &mut occluded, cache);
            return occluded;
        }
        if self.nodes.is_empty() || rays.is_empty() {
            return 0;
        }
        let o = rays[0].origin;
        // Reciprocal directions by axis in quads of rays, padded with the first ray (padding
        // lanes are never in a mask).
        let lane = |r: usize| &rays[r.min(rays.len() - 1)];
        let inv: [[Vec4; QUADS]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|q| Vec4::from_array(std::array::from_fn(|i| lane(4 * q + i).inv_direction[a])))
        });
        let (tmin, tmax) = (Vec4::splat(rays[0].tmin), Vec4::splat(rays[0].tmax));
        let mut stack = [(0u32, 0u32); STACK];
        stack[0] = (0, active);
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (index, mask) = stack[sp];
            let mask = mask & !occluded;
            if mask == 0 {
                continue;
            }
            let node = &self.nodes[index as usize];
            let mut full = node.full;
            while full != 0 {
                let c = full.trailing_zeros() as usize;
                full &= full - 1;
                let lo = [0, 1, 2].map(|a| Vec4::splat(node.lo[a][c] - o[a]));
                let hi = [0, 1, 2].map(|a| Vec4::splat(node.hi[a][c] - o[a]));
                let mut hit = 0u32;
                for q in 0..QUADS {
                    // Quads without an active ray are skipped (deep in the tree, most are).
                    if mask >> (4 * q) & 15 == 0 {
                        continue;
                    }
                    let (x0, x1) = (lo[0] * inv[0][q], hi[0] * inv[0][q]);
                    let (y0, y1) = (lo[1] * inv[1][q], hi[1] * inv[1][q]);
                    let (z0, z1) = (lo[2] * inv[2][q], hi[2] * inv[2][q]);
                    let near = x0.min(x1).max(y0.min(y1)).max(z0.min(z1)).max(tmin);
                    let far = x0.max(x1).min(y0.max(y1)).min(z0.max(z1)).min(tmax);
                    hit |= near.cmple(far * FAR_SLACK).bitmask() << (4 * q);
                }
                let m = hit & mask & !occluded;
                if m == 0 {
                    continue;
                }
                let code = node.child[c];
                if code & LEAF != 0 {
                    leaf_hits(code, m, &mut occluded, cache);
                    if occluded & active == active {
                        return occluded;
                    }
                } else {
                    stack[sp] = (code, m);
                    sp += 1;
                }
            }
        }
        occluded
    }
}

#[cfg(test)]
impl Bvh4 {
    /// The caller's index of every triangle, in leaf order.
    pub(crate) fn triangle_ids(&self) -> &[u32] {
        &self.ids
    }
}

impl Node4 {
    fn empty() -> Self {
        Self { lo: [Vec4::INFINITY; 3], hi: [Vec4::NEG_INFINITY; 3], child: [EMPTY; 4], full: 0 }
    }
}
