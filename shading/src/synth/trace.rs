//! Ray casting against a periodic (tiled) height field.
//!
//! Rather than building a BVH over a 3x3 tiling, rays are **wrapped periodically**: a 2D
//! digital differential analyzer (Amanatides and Woo 1987, "A fast voxel traversal algorithm
//! for ray tracing") walks the cells the ray's ground projection crosses, in unbounded cell
//! coordinates, and looks heights up modulo the grid size. That makes the tiling infinite
//! (a grazing shadow or view ray may cross several patches; a 3x3 tiling would let rays that
//! leave it escape), costs no memory per tile, and stops as soon as the ray is above the
//! highest sample while rising. Cells whose highest corner is below the ray over the cell's
//! parameter interval are skipped without testing their triangles, and empty space is skipped
//! in strides: with tables of the highest height within 2, 8 and 32 cells of every cell
//! (periodic max filters), a ray that stays above that height while it moves that many cells
//! jumps ahead and restarts the walk (a conservative test, so no hit is ever skipped).
//!
//! Everything is f64: the traversal runs in grid units (cell = unit square) where positions
//! reach a few thousand, and the plane tests of the two triangles per cell are exact enough
//! there that no edge tolerance beyond `1e-9` of a cell is needed. The tests check every
//! answer against [`biscale_core::geometry::SceneBvh`] over an explicit tiling.

use super::heightfield::HeightField;
use glam::DVec3;

/// A closest hit in patch units.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TraceHit {
    /// Distance along the (unit) ray (read by the tests; the generator uses `point`).
    #[cfg_attr(not(test), allow(dead_code))]
    pub t: f64,
    /// Hit point in patch units (unwrapped: `x`, `y` may lie outside `[0, 1)`).
    pub point: DVec3,
    /// Index of the triangle: `2 * (j * N + i) + k` for cell `(i, j)` (wrapped), `k = 0` for
    /// the triangle below the diagonal (`y <= x` in the cell), `1` above.
    pub triangle: u32,
}

/// Barycentric-style slack of the in-triangle test, in cell units: closes cracks between the
/// two triangles of a cell and between cells for rays through shared edges.
const EDGE_EPS: f64 = 1e-9;

pub(crate) struct PeriodicTracer {
    n: usize,
    /// Heights, `h[j * n + i]`.
    h: Vec<f64>,
    /// Highest corner of each cell.
    cell_max: Vec<f64>,
    hmin: f64,
    hmax: f64,
    /// Unit geometric normal of each triangle, in patch units.
    normals: Vec<DVec3>,
    /// Empty-space skipping tables `(r, max over cells within r of each cell, either axis)`,
    /// largest `r` first.
    skips: Vec<(usize, Vec<f64>)>,
}

impl PeriodicTracer {
    pub fn new(hf: &HeightField) -> Self {
        let n = hf.width as usize;
        let h: Vec<f64> = hf.h.iter().map(|&v| v as f64).collect();
        let at = |i: usize, j: usize| h[(j % n) * n + (i % n)];
        let mut cell_max = Vec::with_capacity(n * n);
        let mut normals = Vec::with_capacity(2 * n * n);
        let nf = n as f64;
        for j in 0..n {
            for i in 0..n {
                let (h00, h10, h11, h01) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                cell_max.push(h00.max(h10).max(h11).max(h01));
                // Lower triangle (0,0),(1,0),(1,1): z = h00 + (h10 - h00) x + (h11 - h10) y in
                // cell units; with x = N * patch x the patch-space normal is (-a N, -b N, 1).
                normals.push(DVec3::new(-(h10 - h00) * nf, -(h11 - h10) * nf, 1.0).normalize());
                // Upper triangle (0,0),(1,1),(0,1): a = h11 - h01, b = h01 - h00.
                normals.push(DVec3::new(-(h11 - h01) * nf, -(h01 - h00) * nf, 1.0).normalize());
            }
        }
        let hmin = h.iter().copied().fold(f64::INFINITY, f64::min);
        let hmax = h.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        // Radii 2, 8, 32 (each table dilates the previous one), those smaller than the grid.
        let mut skips: Vec<(usize, Vec<f64>)> = vec![];
        let mut prev = (0usize, cell_max.clone());
        for r in [2usize, 8, 32] {
            if r >= n {
                break;
            }
            let table = dilate(&prev.1, n, r - prev.0);
            prev = (r, table.clone());
            skips.push((r, table));
        }
        skips.reverse();
        Self { n, h, cell_max, hmin, hmax, normals, skips }
    }

    pub fn hmax(&self) -> f64 {
        self.hmax
    }

    pub fn triangle_count(&self) -> usize {
        self.normals.len()
    }

    /// Unit geometric normal of a triangle (patch units).
    pub fn normal(&self, triangle: u32) -> DVec3 {
        self.normals[triangle as usize]
    }

    /// The first hit along `origin + t dir` with `t > tmin` (`dir` unit length, patch units).
    pub fn closest_hit(&self, origin: DVec3, dir: DVec3, tmin: f64) -> Option<TraceHit> {
        self.walk(origin, dir, tmin, false)
    }

    /// True if the ray `origin + t dir`, `t > tmin`, hits the surface.
    pub fn occluded(&self, origin: DVec3, dir: DVec3, tmin: f64) -> bool {
        self.walk(origin, dir, tmin, true).is_some()
    }

    fn walk(&self, origin: DVec3, dir: DVec3, tmin: f64, any: bool) -> Option<TraceHit> {
        let nf = self.n as f64;
        let n = self.n as i64;
        // Grid space: x and y scaled by N (cells are unit squares); z and t unchanged. Every
        // t below is absolute along the ray from `origin`, so the walk can restart anywhere.
        let (gx, gy) = (origin.x * nf, origin.y * nf);
        let (dx, dy, dz) = (dir.x * nf, dir.y * nf, dir.z);
        if !(gx.is_finite() && gy.is_finite() && origin.z.is_finite() && dir.is_finite()) {
            return None;
        }
        let (sx, sy) = (if dx > 0.0 { 1 } else { -1 }, if dy > 0.0 { 1 } else { -1 });
        let (ddx, ddy) = (
            if dx == 0.0 { f64::INFINITY } else { 1.0 / dx.abs() },
            if dy == 0.0 { f64::INFINITY } else { 1.0 / dy.abs() },
        );
        // Grid units travelled per unit t along the faster axis (for skips).
        let speed = dx.abs().max(dy.abs());
        // DDA state at parameter t: cell (ix, iy), wrapped (wi, wj), next boundary crossings.
        let start = |t: f64| {
            let (px, py) = (gx + dx * t, gy + dy * t);
            let (ix, iy) = (px.floor() as i64, py.floor() as i64);
            let next = |g: f64, i: i64, d: f64| {
                if d == 0.0 {
                    f64::INFINITY
                } else {
                    ((i + (d > 0.0) as i64) as f64 - g) / d
                }
            };
            (ix.rem_euclid(n), iy.rem_euclid(n), ix, iy, next(gx, ix, dx), next(gy, iy, dy))
        };
        let (mut wi, mut wj, mut ix, mut iy, mut tx, mut ty) = start(0.0);
        let mut t_in = 0.0f64;
        // A ray can cross at most this many cells before it must leave the height range
        // (grazing rays); the cap only matters for exactly horizontal rays.
        let max_steps = 64 * self.n + 64;
        for _ in 0..max_steps {
            let z_in = origin.z + dz * t_in;
            if dz >= 0.0 && z_in > self.hmax {
                return None;
            }
            if dz < 0.0 && z_in < self.hmin - 1e-9 {
                return None;
            }
            let cell = wj as usize * self.n + wi as usize;
            // Empty-space skipping: if the ray stays above everything within `r` cells (in
            // both axes) while it moves `r` cells, jump there and restart the walk.
            if speed > 0.0 {
                let skip = self.skips.iter().find(|(r, table)| {
                    let t_skip = *r as f64 / speed;
                    let z_low = if dz >= 0.0 { z_in } else { z_in + dz * t_skip };
                    z_low > table[cell] + 1e-12
                });
                if let Some(&(r, _)) = skip {
                    t_in += r as f64 / speed;
                    (wi, wj, ix, iy, tx, ty) = start(t_in);
                    continue;
                }
            }
            let t_out = tx.min(ty);
            // Lowest ray height over the cell's interval (t_out may be infinite).
            let z_low = if dz >= 0.0 {
                z_in
            } else if t_out.is_finite() {
                origin.z + dz * t_out
            } else {
                f64::NEG_INFINITY
            };
            if z_low <= self.cell_max[cell] + 1e-12 {
                if let Some(hit) = self.cell_hit(
                    origin,
                    gx - ix as f64,
                    gy - iy as f64,
                    dx,
                    dy,
                    dz,
                    wi as usize,
                    wj as usize,
                    tmin,
                    any,
                ) {
                    return Some(hit);
                }
            }
            // Step to the next cell across x or y; the wrapped index stays in 0..n.
            let step = |i: &mut i64, w: &mut i64, s: i64| {
                *i += s;
                *w = (*w + s).rem_euclid(n);
            };
            if tx < ty {
                step(&mut ix, &mut wi, sx);
                t_in = tx;
                tx += ddx;
            } else {
                step(&mut iy, &mut wj, sy);
                t_in = ty;
                ty += ddy;
            }
            if !t_in.is_finite() {
                return None;
            }
        }
        None
    }

    /// Both triangles of the cell with wrapped index `(wi, wj)`; `(ox, oy)` is the ray origin
    /// relative to the cell's corner (grid units), `(dx, dy, dz)` the grid-space direction.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn cell_hit(
        &self,
        origin: DVec3,
        ox: f64,
        oy: f64,
        dx: f64,
        dy: f64,
        dz: f64,
        wi: usize,
        wj: usize,
        tmin: f64,
        any: bool,
    ) -> Option<TraceHit> {
        let n = self.n;
        let i1 = if wi + 1 == n { 0 } else { wi + 1 };
        let j1 = if wj + 1 == n { 0 } else { wj + 1 };
        let (h00, h10, h11, h01) = (self.h[wj * n + wi], self.h[wj * n + i1], self.h[j1 * n + i1], self.h[j1 * n + wi]);
        let mut best: Option<(f64, u32)> = None;
        // Plane z = h00 + a x + b y over the triangle's footprint (both planes pass through
        // corner (0, 0)); t from oz + dz t = h00 + a (ox + dx t) + b (oy + dy t).
        for k in 0..2u32 {
            let (a, b) = if k == 0 { (h10 - h00, h11 - h10) } else { (h11 - h01, h01 - h00) };
            let den = dz - a * dx - b * dy;
            if den == 0.0 {
                continue;
            }
            let t = (h00 + a * ox + b * oy - origin.z) / den;
            // `t <= tmin` written so that NaN (a degenerate plane) is rejected too.
            if t.is_nan() || t <= tmin || best.is_some_and(|(bt, _)| bt <= t) {
                continue;
            }
            let (x, y) = (ox + dx * t, oy + dy * t);
            let r = -EDGE_EPS..=1.0 + EDGE_EPS;
            // Lower triangle: y <= x; upper: y >= x.
            let inside = if k == 0 { y <= x + EDGE_EPS } else { y >= x - EDGE_EPS };
            if r.contains(&x) && r.contains(&y) && inside {
                best = Some((t, 2 * (wj * n + wi) as u32 + k));
                if any {
                    break;
                }
            }
        }
        let nf = n as f64;
        best.map(|(t, triangle)| TraceHit { t, point: origin + t * DVec3::new(dx / nf, dy / nf, dz), triangle })
    }
}

/// Periodic max filter of an `n x n` grid over a `(2 r + 1)^2` window.
fn dilate(src: &[f64], n: usize, r: usize) -> Vec<f64> {
    let mut rows = vec![f64::NEG_INFINITY; n * n];
    for j in 0..n {
        for i in 0..n {
            let mut m = f64::NEG_INFINITY;
            for k in 0..=2 * r {
                m = m.max(src[j * n + (i + n * (r / n + 1) + k - r) % n]);
            }
            rows[j * n + i] = m;
        }
    }
    let mut out = vec![f64::NEG_INFINITY; n * n];
    for j in 0..n {
        for i in 0..n {
            let mut m = f64::NEG_INFINITY;
            for k in 0..=2 * r {
                m = m.max(rows[((j + n * (r / n + 1) + k - r) % n) * n + i]);
            }
            out[j * n + i] = m;
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::synth::heightfield::{Pattern, Recipe};
    use biscale_core::geometry::SceneBvh;
    use glam::Vec3;
    use rand::{Rng, SeedableRng};

    /// The height field as an explicit mesh tiled `(2 r + 1)^2` times around the unit patch.
    pub fn tiled_mesh(hf: &HeightField, r: i32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let n = hf.width as usize;
        let side = (2 * r as usize + 1) * n + 1;
        let mut pos = Vec::with_capacity(side * side);
        for j in 0..side {
            for i in 0..side {
                let (x, y) = ((i as f64) / n as f64 - r as f64, (j as f64) / n as f64 - r as f64);
                pos.push(Vec3::new(x as f32, y as f32, hf.h[(j % n) * n + (i % n)]));
            }
        }
        let mut tris = vec![];
        let id = |i: usize, j: usize| (j * side + i) as u32;
        for j in 0..side - 1 {
            for i in 0..side - 1 {
                tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (pos, tris)
    }

    #[test]
    fn periodic_walk_agrees_with_bvh_over_a_tiling() {
        // Random rays from above into a bumpy patch, and shadow rays from the hit points: the
        // DDA must find the same first hit as a BVH over an explicit 5x5 tiling (rays start in
        // the centre patch and cannot travel 2 patches horizontally before leaving the height
        // range: |tan| <= 4 and the range is 0.12). Disagreements are allowed only where the
        // two tests' edge tolerances differ (the core BVH grows triangles by 1e-5 of their
        // size, in f32): rays within ~1e-5 of a cell edge, a few per 10^4.
        // Two fields: a small bumpy one (skip radii 2 and 8) and a larger pitted one (2, 8, 32).
        for hf in [
            HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.12, 3, 7), 24).unwrap(),
            HeightField::procedural(&Recipe::new(Pattern::Holes, 0.12, 2, 7), 64).unwrap(),
        ] {
            compare_with_bvh(&hf);
        }
    }

    fn compare_with_bvh(hf: &HeightField) {
        let tracer = PeriodicTracer::new(hf);
        let (pos, tris) = tiled_mesh(hf, 2);
        let bvh = SceneBvh::build(&pos, &tris);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut mismatches, mut shadow_mismatch, mut shadowed, rays) = (0, 0, 0, 4000);
        for _ in 0..rays {
            let z: f64 = rng.gen_range(0.25..1.0);
            let phi: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let s = (1.0 - z * z).sqrt();
            let dir = -DVec3::new(s * phi.cos(), s * phi.sin(), z);
            let origin = DVec3::new(rng.gen(), rng.gen(), tracer.hmax() + 0.01);
            let a = tracer.closest_hit(origin, dir, 0.0).expect("a ray from above always hits a height field");
            let b = bvh.closest_hit(origin.as_vec3(), dir.as_vec3(), 0.0, f32::INFINITY).unwrap();
            if (a.t - b.t as f64).abs() > 1e-4 {
                mismatches += 1;
                continue;
            }
            // Same triangle (up to wrapping): the normals agree.
            let t = tris[b.triangle as usize].map(|k| pos[k as usize].as_dvec3());
            let nb = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            assert!((nb - tracer.normal(a.triangle)).length() < 1e-3, "{nb} vs {}", tracer.normal(a.triangle));
            // Shadow ray towards a random upper direction.
            let z: f64 = rng.gen_range(0.1..1.0);
            let phi: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let s = (1.0 - z * z).sqrt();
            let l = DVec3::new(s * phi.cos(), s * phi.sin(), z);
            if tracer.normal(a.triangle).dot(l) <= 0.01 {
                continue;
            }
            let p = a.point + 1e-5 * tracer.normal(a.triangle);
            let occ_a = tracer.occluded(p, l, 1e-7);
            let occ_b = bvh.occluded(p.as_vec3(), l.as_vec3(), 1e-5, f32::INFINITY);
            shadowed += occ_a as u32;
            shadow_mismatch += (occ_a != occ_b) as u32;
        }
        eprintln!(
            "{} samples: {mismatches} hit and {shadow_mismatch} shadow mismatches, {shadowed} shadowed",
            hf.width
        );
        assert!(mismatches <= 4, "{mismatches} closest-hit mismatches in {rays}");
        assert!(shadow_mismatch <= 4, "{shadow_mismatch} shadow mismatches");
        assert!(shadowed > 100, "the test must exercise shadowing ({shadowed})");
    }

    #[test]
    fn grazing_rays_cross_many_patches() {
        // A single thin wall at x = 0.5 of height 0.1 in an otherwise flat patch: a ray
        // starting at x = 0.9 with slope 1/100 travels 0.9 + 8.6 patches... it must still
        // be caught by a wall in a later tile, which a 3x3 tiling would miss.
        let n = 16;
        let mut h = vec![0.0f32; n * n];
        for j in 0..n {
            h[j * n + 8] = 0.1;
        }
        let hf = HeightField { width: n as u32, height: n as u32, h };
        let tracer = PeriodicTracer::new(&hf);
        let dir = DVec3::new(1.0, 0.0, -0.01).normalize();
        // Starts at z = 0.09 above x = 0.9 (past the wall); the next wall (x = 1.5) is reached
        // at z = 0.084 < 0.1: hit in the second tile.
        let hit = tracer.closest_hit(DVec3::new(0.9, 0.3, 0.09), dir, 0.0).unwrap();
        assert!(hit.point.x > 1.4 && hit.point.x < 1.5, "{:?}", hit.point);
        // Rising rays past the top stop at once; a flat-out ray above the top is a miss.
        assert!(!tracer.occluded(DVec3::new(0.2, 0.2, 0.2), DVec3::new(1.0, 0.0, 0.0), 0.0));
        assert!(tracer.occluded(DVec3::new(0.2, 0.2, 0.05), DVec3::new(1.0, 0.0, 0.0), 0.0));
    }
}
