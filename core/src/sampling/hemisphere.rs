//! Local direction grids on the hemisphere (docs/DESIGN.md section 3).
//!
//! An `m x m` grid on the unit square is mapped to the unit disk by the Shirley-Chiu
//! concentric map and lifted to the hemisphere area-preservingly (`z = 1 - r^2`), so every
//! bin subtends exactly `2 pi / m^2` steradians. The same parameterization indexes the BTF's
//! light directions (`j`, the rows of each vertex's block of `T`) and view directions.
//! Local frame: +Z is the surface normal, +X the tangent, +Y the bitangent.

use glam::{DVec2, DVec3, Vec3};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// Shirley-Chiu concentric map: unit square `[0,1]^2` to the unit disk.
pub fn square_to_disk(u: f64, v: f64) -> DVec2 {
    let a = 2.0 * u - 1.0;
    let b = 2.0 * v - 1.0;
    if a == 0.0 && b == 0.0 {
        return DVec2::ZERO;
    }
    let (r, phi) = if a.abs() > b.abs() { (a, FRAC_PI_4 * (b / a)) } else { (b, FRAC_PI_2 - FRAC_PI_4 * (a / b)) };
    DVec2::new(r * phi.cos(), r * phi.sin())
}

/// Inverse of [`square_to_disk`].
pub fn disk_to_square(p: DVec2) -> (f64, f64) {
    wedge_to_square(p.length(), p.x, p.y)
}

/// The square point of the disk point at radius `r` in the direction of `(x, y)` (any scale).
/// In the wedge `|x| >= |y|` the point came from `a = +-r`, `b = a (4 / pi) atan(y / x)` (and
/// symmetrically with `x` and `y` swapped), so one `atan` of a ratio in `[-1, 1]` inverts the
/// concentric map, with no angle unwrapping and no normalisation (this runs once per light bin
/// per vertex in the light-moments resolve).
#[inline]
fn wedge_to_square(r: f64, x: f64, y: f64) -> (f64, f64) {
    if r == 0.0 || (x == 0.0 && y == 0.0) {
        return (0.5, 0.5);
    }
    let (a, b) = if x.abs() >= y.abs() {
        let a = r.copysign(x);
        (a, a * (y / x).atan() / FRAC_PI_4)
    } else {
        let b = r.copysign(y);
        (b * (x / y).atan() / FRAC_PI_4, b)
    };
    (((a + 1.0) * 0.5).clamp(0.0, 1.0), ((b + 1.0) * 0.5).clamp(0.0, 1.0))
}

/// Unit square to the upper hemisphere (+Z up), area preserving.
pub fn square_to_hemisphere(u: f64, v: f64) -> DVec3 {
    let d = square_to_disk(u, v);
    let r2 = d.length_squared().min(1.0);
    let s = (2.0 - r2).sqrt();
    DVec3::new(d.x * s, d.y * s, 1.0 - r2)
}

/// Inverse of [`square_to_hemisphere`] for a non-zero vector `d` of any length (a direction
/// below the horizon is projected onto it): the disk radius is `sqrt(1 - z)` of the unit
/// direction, and its angle is that of `(d.x, d.y)`.
#[inline]
pub fn hemisphere_to_square(d: DVec3) -> (f64, f64) {
    let z = (d.z / d.length()).clamp(0.0, 1.0);
    wedge_to_square((1.0 - z).sqrt(), d.x, d.y)
}

/// An `m x m` grid of equal-solid-angle bins over the upper hemisphere.
/// Bin `j = row * m + col`, where `col` indexes `u` and `row` indexes `v`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct HemisphereGrid {
    pub m: u32,
}

impl HemisphereGrid {
    pub const fn new(m: u32) -> Self {
        Self { m }
    }

    /// Number of bins `M = m^2`.
    pub fn len(&self) -> usize {
        (self.m * self.m) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.m == 0
    }

    /// Solid angle of every bin, `2 pi / M`.
    pub fn bin_solid_angle(&self) -> f64 {
        2.0 * PI / self.len() as f64
    }

    /// The bin containing local direction `d` (+Z = normal), or `None` below the horizon
    /// (`z <= 0`).
    pub fn bin_of(&self, d: Vec3) -> Option<u32> {
        self.bin_of_f64(d.as_dvec3())
    }

    /// f64 version of [`Self::bin_of`].
    pub fn bin_of_f64(&self, d: DVec3) -> Option<u32> {
        if d.z <= 0.0 || !d.is_finite() {
            return None;
        }
        let (u, v) = hemisphere_to_square(d);
        let m = self.m as f64;
        let col = ((u * m) as u32).min(self.m - 1);
        let row = ((v * m) as u32).min(self.m - 1);
        Some(row * self.m + col)
    }

    /// Centre of bin `j` on the unit square.
    pub fn bin_centre_uv(&self, j: u32) -> (f64, f64) {
        let m = self.m as f64;
        (((j % self.m) as f64 + 0.5) / m, ((j / self.m) as f64 + 0.5) / m)
    }

    /// Unit direction through the centre of bin `j` (local frame).
    pub fn bin_direction(&self, j: u32) -> Vec3 {
        let (u, v) = self.bin_centre_uv(j);
        square_to_hemisphere(u, v).as_vec3()
    }

    /// Mean of `cos(theta) = z` over bin `j`'s solid angle. Because the map is
    /// area-preserving this is the mean of `1 - r^2` over the bin's square, and on the
    /// concentric map `r = max(|a|, |b|)` with `(a, b) = (2u - 1, 2v - 1)`. The bin is cut
    /// into 32x32 cells; `a^2` or `b^2` is integrated exactly on cells where one of them
    /// dominates, and in closed form on the cells the diagonal `|a| = |b|` cuts corner to corner
    /// (exact up to rounding). The sum over all bins times `2 pi / M` is `pi`.
    pub fn bin_mean_cosine(&self, j: u32) -> f64 {
        const S: i64 = 32;
        let m = self.m as i64;
        let h = 2.0 / (m * S) as f64;
        // Cells are indexed in units of h from the centre (a = 0), so the classification
        // below is exact integer arithmetic. `lo` is the cell's smaller |coordinate| in units.
        let lo = |i: i64| if i >= 0 { i } else { -i - 1 };
        let (c0, r0) = ((j as i64 % m) * S - m * S / 2, (j as i64 / m) * S - m * S / 2);
        // Exact integral of x^2 over [p, p + h] for p = lo * h.
        let sq = |l: i64| {
            let (x0, x1) = (l as f64 * h, (l + 1) as f64 * h);
            (x1 * x1 * x1 - x0 * x0 * x0) / 3.0
        };
        let mut r2 = 0.0;
        for i in c0..c0 + S {
            for k in r0..r0 + S {
                let (la, lb) = (lo(i), lo(k));
                r2 += if la > lb {
                    sq(la) * h
                } else if lb > la {
                    sq(lb) * h
                } else {
                    // The diagonal cuts this cell corner to corner: in |a|,|b| it is
                    // [p, p+h]^2 split along a = b, and the integral of max(a, b)^2 is
                    // 2 * int_p^{p+h} x^2 (x - p) dx.
                    let p = la as f64 * h;
                    let f = |x: f64| x.powi(4) / 4.0 - p * x.powi(3) / 3.0;
                    2.0 * (f(p + h) - f(p))
                };
            }
        }
        1.0 - r2 / (2.0 / m as f64).powi(2)
    }

    /// Every bin's [`Self::bin_mean_cosine`], in bin order. Each is an integral over 1,024
    /// cells, and the light-moments resolve needs all of them on every call, so each grid
    /// size's are computed once per process and shared.
    pub fn mean_cosines(&self) -> std::sync::Arc<[f64]> {
        use std::collections::HashMap;
        use std::sync::{Arc, Mutex, OnceLock};
        static KNOWN: OnceLock<Mutex<HashMap<u32, Arc<[f64]>>>> = OnceLock::new();
        let mut known = KNOWN.get_or_init(Default::default).lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        known.entry(self.m).or_insert_with(|| (0..self.len() as u32).map(|j| self.bin_mean_cosine(j)).collect()).clone()
    }

    /// Continuous grid coordinates of local direction `d` for bilinear interpolation between
    /// bin centres: `(x, y)` in `[0, m-1]` so that integer values are bin centres.
    /// Directions below the horizon are clamped onto it.
    #[inline]
    pub fn continuous_coords(&self, d: Vec3) -> (f32, f32) {
        let (u, v) = hemisphere_to_square(d.as_dvec3());
        let m = self.m as f64;
        let x = (u * m - 0.5).clamp(0.0, m - 1.0);
        let y = (v * m - 0.5).clamp(0.0, m - 1.0);
        (x as f32, y as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn concentric_round_trip() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for _ in 0..20000 {
            let (u, v): (f64, f64) = (rng.gen(), rng.gen());
            let (u2, v2) = disk_to_square(square_to_disk(u, v));
            assert!((u - u2).abs() < 1e-12 && (v - v2).abs() < 1e-12, "{u},{v} -> {u2},{v2}");
            let d = square_to_hemisphere(u, v);
            assert!((d.length() - 1.0).abs() < 1e-12 && d.z >= 0.0);
            let (u3, v3) = hemisphere_to_square(d);
            assert!((u - u3).abs() < 1e-9 && (v - v3).abs() < 1e-9);
        }
    }

    #[test]
    fn bins_have_equal_solid_angle() {
        // Monte Carlo over uniform hemisphere directions: every bin receives M^-1 of them.
        let grid = HemisphereGrid::new(8);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let n = 640_000;
        let mut counts = vec![0u32; grid.len()];
        for _ in 0..n {
            let z: f64 = rng.gen();
            let phi: f64 = rng.gen::<f64>() * 2.0 * PI;
            let s = (1.0 - z * z).sqrt();
            let d = DVec3::new(s * phi.cos(), s * phi.sin(), z);
            counts[grid.bin_of_f64(d).unwrap() as usize] += 1;
        }
        let expect = n as f64 / grid.len() as f64; // 10000, binomial sd = 99
        for c in counts {
            assert!((c as f64 - expect).abs() < 5.0 * expect.sqrt(), "{c} vs {expect}");
        }
    }

    #[test]
    fn bin_centres_land_in_their_bins() {
        for m in [1, 2, 8, 12, 32] {
            let grid = HemisphereGrid::new(m);
            for j in 0..grid.len() as u32 {
                assert_eq!(grid.bin_of(grid.bin_direction(j)), Some(j));
            }
        }
    }

    #[test]
    fn mean_cosines_integrate_to_pi() {
        for m in [2, 8, 12] {
            let grid = HemisphereGrid::new(m);
            let s: f64 = (0..grid.len() as u32).map(|j| grid.bin_mean_cosine(j)).sum::<f64>() * grid.bin_solid_angle();
            assert!((s - PI).abs() < 1e-12, "m={m}: {s}");
            // The shared table is the same numbers, computed once.
            let table = grid.mean_cosines();
            assert!((0..grid.len()).all(|j| table[j] == grid.bin_mean_cosine(j as u32)));
            assert!(std::sync::Arc::ptr_eq(&table, &grid.mean_cosines()));
        }
    }

    #[test]
    fn below_horizon_has_no_bin() {
        let grid = HemisphereGrid::new(8);
        assert_eq!(grid.bin_of(Vec3::new(1.0, 0.0, 0.0)), None);
        assert_eq!(grid.bin_of(Vec3::new(0.0, 0.3, -0.5)), None);
        assert_eq!(grid.bin_of(Vec3::new(f32::NAN, 0.0, 1.0)), None);
    }
}
