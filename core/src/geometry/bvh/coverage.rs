//! Visibility without tracing every ray: the triangles a tile of texel-centre directions could
//! hit, rasterised into the tile's coverage mask front to back (docs/DESIGN.md, "Visibility
//! by coverage").
//!
//! All rays of a transfer query leave one origin, and a ray is occluded as soon as any
//! triangle is hit: no depth is needed, only which texel centres each triangle covers. So a
//! tile (up to 64 x 64 texels of one cube face) keeps a bit per texel, and the sphere tree of
//! the cone queries ([`super::ConeTree`]) is walked front to back (the nearer child first). A
//! node is skipped when it is behind the tangent plane (as the cone query skips it), when its
//! sphere's footprint holds no texel centre of the tile (a sphere reaching the face's plane,
//! whose footprint is unbounded, is tested against the tile's cone instead), and when every
//! texel of its footprint is already covered. A triangle is tested only on the open texels of
//! its footprint's rows that lie within the row's span of its three edge conditions, and the
//! walk stops when the whole tile is covered. The work is that of the visible surface, not of
//! the rays.
//!
//! **The per-texel test is the ray test, rearranged.** [`super::RtTri::intersect`] solves
//! `o + t d = v0 + u e1 + v e2` by Cramer's rule: with `c = v0 - o`, `u = (e2 x c) . d / den`,
//! `v = (c x e1) . d / den`, `t = (c . ng) / den`, `den = ng . d`. All three numerators and
//! the denominator are linear in `d`, so per triangle and origin the coverage test
//! precomputes `P = e2 x c`, `Q = c x e1`, `ng` and `c . ng`, flips their signs so `c . ng > 0`,
//! and accepts a direction when `den > 0`, `P . d >= -tol den`, `Q . d >= -tol den`,
//! `P . d + Q . d <= (1 + tol) den` and `c . ng >= RAY_TMIN den`: the same region as the ray
//! test ([`super::EDGE_TOLERANCE`] and all), without the division. The two can differ only
//! for a direction within f32 rounding of that region's boundary (the tests count and bound
//! them; docs/DESIGN.md gives the counts on the bundled meshes).
//!
//! **Footprints.** A sphere `(c, r)` entirely in front of a face's plane (`w . W > r`, with
//! `w = c - o` and the face's axes `W`, `A`, `B`: a texel centre's direction is
//! `W + a A + b B`) projects onto the face coordinates `a = x . A / x . W` in the interval
//! whose ends are the roots of `(w_W^2 - r^2) a^2 - 2 w_A w_W a + w_A^2 - r^2 = 0` (the planes
//! through the origin tangent to the sphere), and likewise for `b`. The texel centres inside
//! it, widened by a hundredth of a texel for rounding, are the footprint.
//!
//! **Row spans.** Each edge condition is linear in the direction, so along a row of texel
//! centres (`b` fixed) it holds on a half-line of `a`; the three half-lines meet in the span of
//! columns the triangle can cover in that row. The spans are widened (each condition's constant
//! by 1e-5 of its coefficients, the ends by a hundredth of a texel) so that they only leave out
//! texels the exact test rejects.

use super::{behind, meets_cone, Cone, ConeTree, SceneBvh, EDGE_TOLERANCE, RAY_TMIN};
use glam::Vec3A;

/// The widest tile, in texels: a row of the coverage mask is one `u64`.
pub(crate) const MAX_TILE: usize = 64;

/// A rectangle of texel centres on one cube face, as the coverage test sees it: the face's
/// axes (texel `(row, col)` of a face of resolution `res` looks along `W + a A + b B` with
/// `a = 2 (col + 0.5) / res - 1`, `b = 2 (row + 0.5) / res - 1`) and the tile's first row and
/// column and its size (at most [`MAX_TILE`] each way), and a cone containing its directions.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FaceTile {
    /// A cone containing the tile's directions.
    pub cone: Cone,
    pub w: Vec3A,
    pub a: Vec3A,
    pub b: Vec3A,
    pub res: u32,
    pub row0: u32,
    pub col0: u32,
    pub rows: u32,
    pub cols: u32,
}

/// Scratch of [`SceneBvh::cover_tile`]: the walk's stack.
#[derive(Clone, Debug, Default)]
pub(crate) struct CoverScratch {
    stack: Vec<u32>,
}

/// Texel rows and columns (tile-local, inclusive) a footprint covers.
#[derive(Clone, Copy, Debug)]
struct Rect {
    r0: u32,
    r1: u32,
    c0: u32,
    c1: u32,
}

impl Rect {
    /// Column bits `c0..=c1`.
    #[inline(always)]
    fn col_mask(&self) -> u64 {
        (u64::MAX >> (63 - (self.c1 - self.c0))) << self.c0
    }

    /// Whether any texel of the rectangle is still open.
    #[inline(always)]
    fn any_open(&self, open: &[u64]) -> bool {
        let m = self.col_mask();
        open[self.r0 as usize..=self.r1 as usize].iter().any(|&row| row & m != 0)
    }
}

/// What [`FaceTile::footprint`] finds.
enum Footprint {
    /// These texels.
    Rect(Rect),
    /// No texel of the tile.
    None,
    /// The sphere reaches the face's plane: its footprint is unbounded.
    Plane,
}

impl FaceTile {
    /// The whole tile.
    fn all(&self) -> Rect {
        Rect { r0: 0, r1: self.rows - 1, c0: 0, c1: self.cols - 1 }
    }

    /// Texel centres `first..=last` (tile-local) whose face coordinate lies in `[lo, hi]`, of
    /// `n` starting at face texel `start`; `None` when there are none.
    #[inline(always)]
    fn span(&self, lo: f32, hi: f32, start: u32, n: u32) -> Option<(u32, u32)> {
        // Texel centre i sits at a = 2 (i + 0.5) / res - 1, so a maps to i = (a + 1) res / 2 - 0.5.
        let h = 0.5 * self.res as f32;
        // Clamped to the face first, so the float-to-int casts are in range (NaN goes to 0:
        // conservative); floor and ceil by hand, as a call each without SSE4.1.
        let x0 = ((lo + 1.0) * h - 0.5 - 0.01).clamp(-1.0, self.res as f32);
        let x1 = ((hi + 1.0) * h - 0.5 + 0.01).clamp(-1.0, self.res as f32);
        let (t0, t1) = (x0 as i32, x1 as i32);
        let first = (t0 + ((t0 as f32) < x0) as i32).max(start as i32);
        let last = (t1 - ((t1 as f32) > x1) as i32).min((start + n - 1) as i32);
        (first <= last).then(|| ((first - start as i32) as u32, (last - start as i32) as u32))
    }

    /// The texels through which the sphere of radius `r` at `w` from the origin can be seen
    /// (module docs; conservative).
    #[inline(always)]
    fn footprint(&self, w: Vec3A, r: f32) -> Footprint {
        let ww = w.dot(self.w);
        // Nearly touching the plane the interval ends blow up.
        if ww <= r * 1.001 {
            return Footprint::Plane;
        }
        let den = ww * ww - r * r;
        let inv = 1.0 / den;
        let ends = |wx: f32| {
            let root = r * (wx * wx + den).sqrt();
            ((wx * ww - root) * inv, (wx * ww + root) * inv)
        };
        let (a0, a1) = ends(w.dot(self.a));
        let (b0, b1) = ends(w.dot(self.b));
        let (Some((c0, c1)), Some((r0, r1))) =
            (self.span(a0, a1, self.col0, self.cols), self.span(b0, b1, self.row0, self.rows))
        else {
            return Footprint::None;
        };
        Footprint::Rect(Rect { r0, r1, c0, c1 })
    }
}

/// One triangle seen from the tile's origin, as the coverage test wants it (module docs).
struct EdgeTest {
    p: Vec3A,
    q: Vec3A,
    ng: Vec3A,
    c_ng: f32,
}

impl EdgeTest {
    #[inline(always)]
    fn hits(&self, d: Vec3A) -> bool {
        let den = self.ng.dot(d);
        let (u, v) = (self.p.dot(d), self.q.dot(d));
        (den > 0.0)
            & (u >= -EDGE_TOLERANCE * den)
            & (v >= -EDGE_TOLERANCE * den)
            & (u + v <= (1.0 + EDGE_TOLERANCE) * den)
            & (self.c_ng >= RAY_TMIN * den)
    }
}

/// The three edge conditions of an [`EdgeTest`] as linear functions of a texel's face
/// coordinates: `g . (W + a A + b B) = (g_W + b g_B) + a g_A >= 0`, with `g_W` raised by a
/// margin far above f32 rounding, so that the columns of a row they admit are a superset of
/// those the exact test accepts (module docs).
struct Spans {
    w: [f32; 3],
    b: [f32; 3],
    /// `-1 / g_A` (0 where `g_A` is 0), and the sign of `g_A`.
    inv_a: [f32; 3],
    sign_a: [f32; 3],
}

impl EdgeTest {
    fn spans(&self, tile: &FaceTile) -> Spans {
        let tol = EDGE_TOLERANCE;
        let g = [self.p + tol * self.ng, self.q + tol * self.ng, (1.0 + tol) * self.ng - self.p - self.q];
        let mut spans = Spans { w: [0.0; 3], b: [0.0; 3], inv_a: [0.0; 3], sign_a: [0.0; 3] };
        for i in 0..3 {
            let (gw, ga, gb) = (g[i].dot(tile.w), g[i].dot(tile.a), g[i].dot(tile.b));
            spans.w[i] = gw + 1e-5 * (gw.abs() + ga.abs() + gb.abs());
            spans.b[i] = gb;
            if ga != 0.0 {
                spans.inv_a[i] = -1.0 / ga;
                spans.sign_a[i] = ga.signum();
            }
        }
        spans
    }
}

impl Spans {
    /// The tile columns (bits) of tile row `row` that all three conditions admit.
    #[inline(always)]
    fn cols(&self, tile: &FaceTile, row: u32) -> u64 {
        let y = 2.0 * ((tile.row0 + row) as f32 + 0.5) / tile.res as f32 - 1.0;
        let (mut lo, mut hi) = (-2.0f32, 2.0f32);
        for i in 0..3 {
            let c = self.w[i] + y * self.b[i];
            if self.sign_a[i] > 0.0 {
                lo = lo.max(c * self.inv_a[i]);
            } else if self.sign_a[i] < 0.0 {
                hi = hi.min(c * self.inv_a[i]);
            } else if c < 0.0 {
                return 0;
            }
        }
        match tile.span(lo, hi, tile.col0, tile.cols) {
            Some((c0, c1)) => Rect { r0: 0, r1: 0, c0, c1 }.col_mask(),
            None => 0,
        }
    }
}

impl ConeTree {
    /// The texels of `tile` through which a ray from `o` above the plane with normal `n`
    /// can reach the sphere (conservative): `None` when there are none. Behind the plane as
    /// [`Self::reachable`] tests it; a sphere reaching the face's plane is tested against the
    /// tile's cone instead of its footprint.
    #[inline(always)]
    fn visible_rect(&self, sphere: (Vec3A, f32), o: Vec3A, n: Vec3A, cone: &Cone, tile: &FaceTile) -> Option<Rect> {
        let (w, r) = self.seen_from(sphere, o);
        if behind(w, r, n) {
            return None;
        }
        match tile.footprint(w, r) {
            Footprint::Rect(rect) => Some(rect),
            Footprint::None => None,
            Footprint::Plane => meets_cone(w, r, cone).then(|| tile.all()),
        }
    }
}

impl SceneBvh {
    /// Cover `tile`'s texels seen from `origin` (module docs): sets the bit of every texel in
    /// `open` (row `i`, bit `j`: tile texel `(i, j)`, whose direction is `dirs[i * cols + j]`)
    /// whose ray `origin + t d`, `t >= RAY_TMIN`, some triangle occludes, and clears it from
    /// `open`. `normal` is the query's: as in [`Self::cone_candidates`], only triangles a ray
    /// within the tile's cone and above the plane can reach are tested.
    pub(crate) fn cover_tile(
        &self,
        origin: Vec3A,
        normal: Vec3A,
        tile: &FaceTile,
        dirs: &[Vec3A],
        open: &mut [u64],
        scratch: &mut CoverScratch,
    ) {
        let (tree, cone) = (&self.cones, &tile.cone);
        let mut open_rows = open.iter().filter(|&&m| m != 0).count();
        if tree.ranges.is_empty() || open_rows == 0 {
            return;
        }
        let cols = tile.cols as usize;
        let stack = &mut scratch.stack;
        stack.clear();
        stack.push(0);
        while let Some(i) = stack.pop() {
            let i = i as usize;
            let Some(rect) = tree.visible_rect(tree.spheres[i], origin, normal, cone, tile) else {
                continue;
            };
            if !rect.any_open(open) {
                continue;
            }
            let (first, end, next) = tree.ranges[i];
            if next as usize != i + 1 {
                // Near child first: it is the likelier to cover what the far one would.
                let (l, r) = (i + 1, tree.ranges[i + 1].2 as usize);
                let depth = |k: usize| (tree.spheres[k].0 - origin).dot(cone.axis);
                let (near, far) = if depth(l) <= depth(r) { (l, r) } else { (r, l) };
                stack.push(far as u32);
                stack.push(near as u32);
                continue;
            }
            for p in first..end {
                let Some(rect) = tree.visible_rect(tree.tri_spheres[p as usize], origin, normal, cone, tile) else {
                    continue;
                };
                if !rect.any_open(open) {
                    continue;
                }
                let mask = rect.col_mask();
                let t = &self.tris[p as usize];
                let c = t.v0 - origin;
                let c_ng = c.dot(t.ng);
                // `t = c . ng / den` is 0 (or NaN) for every ray: none is hit at t >= RAY_TMIN.
                if c_ng == 0.0 || !c_ng.is_finite() {
                    continue;
                }
                let sign = c_ng.signum();
                let test =
                    EdgeTest { p: t.e2.cross(c) * sign, q: c.cross(t.e1) * sign, ng: t.ng * sign, c_ng: c_ng * sign };
                let spans = test.spans(tile);
                for row in rect.r0..=rect.r1 {
                    let mut bits = open[row as usize] & mask;
                    if bits == 0 {
                        continue;
                    }
                    bits &= spans.cols(tile, row);
                    if bits == 0 {
                        continue;
                    }
                    let row = row as usize;
                    let line = &dirs[row * cols..(row + 1) * cols];
                    let mut hit = 0u64;
                    while bits != 0 {
                        let j = bits.trailing_zeros();
                        bits &= bits - 1;
                        hit |= (test.hits(line[j as usize]) as u64) << j;
                    }
                    if hit != 0 {
                        open[row] &= !hit;
                        if open[row] == 0 {
                            open_rows -= 1;
                        }
                    }
                }
                if open_rows == 0 {
                    return;
                }
            }
        }
    }
}
