//! Real spherical harmonics: the low-frequency basis of the SH bi-scale method (Sloan et al.
//! 2003) and of the light it is lit by (docs/DESIGN.md section 9).
//!
//! Convention, written down once and used by every stage:
//!
//! * **Real, orthonormal** over the sphere: `int y_i y_j dw = delta_ij`.
//! * **Order** `n` holds the bands `l = 0..n-1`, `n^2` coefficients; coefficient `i = l (l + 1) + m`
//!   for `m = -l..=l`. Orders `1..=MAX_SH_ORDER` (order 5, 25 coefficients, is Sloan's).
//! * **No Condon-Shortley phase**: band 1 is `sqrt(3 / 4 pi) (y, z, x)`, so the band-1 block of a
//!   rotation is the 3 x 3 rotation matrix itself with its axes permuted (what the Ivanic-
//!   Ruedenberg recurrences of [`rotation`] start from).
//! * **Pole along +Z of whatever frame the direction is given in**: the world frame for the
//!   light (`L_sh`), the vertex's local frame (+Z = normal) for `L*` and the BTF's light axis.
//!   With `(x, y, z)` a unit direction, `theta` is measured from +Z and `phi = atan2(y, x)`:
//!   `y_l^m = sqrt(2) K_l^m P_l^m(cos theta) cos(m phi)` for `m > 0`, `sqrt(2) K_l^|m| P_l^|m| sin(|m| phi)`
//!   for `m < 0`, `K_l^0 P_l^0` for `m = 0`, `K_l^m = sqrt((2l + 1) (l - |m|)! / (4 pi (l + |m|)!))`.
//!
//! [`eval`] evaluates all `n^2` functions at once from the Cartesian direction, by the
//! associated-Legendre recurrence on `P_l^m / sin^m theta` times `Re/Im (x + i y)^m` (no
//! trigonometry, stable in f64 for the orders here). [`quadrature`] holds the exact rules the
//! tests (and exact hemisphere integrals) use; [`rotation`] rotates coefficient vectors;
//! [`light`] projects the cubemap light onto SH; [`rtt`] projects a BTF's light axis (the
//! radiance transfer texture).

pub mod light;
pub mod quadrature;
pub mod rotation;
pub mod rtt;
#[cfg(test)]
mod tests;

pub use light::ShProjection;
pub use rotation::ShRotation;

use crate::error::{CoreError, Result};
use glam::DVec3;
use std::f64::consts::PI;
use std::fmt;

/// Highest SH order accepted (64 coefficients, bands 0..7).
pub const MAX_SH_ORDER: u32 = 8;

/// A validated SH order `n` (`1..=MAX_SH_ORDER`): bands `0..n`, `n^2` coefficients.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ShOrder(u32);

impl ShOrder {
    pub fn new(n: u32) -> Result<Self> {
        if n == 0 || n > MAX_SH_ORDER {
            return Err(CoreError::Invalid(format!("SH order must be 1..={MAX_SH_ORDER}, got {n}")));
        }
        Ok(Self(n))
    }

    /// `n`, the number of bands.
    pub fn n(self) -> u32 {
        self.0
    }

    /// `n^2`, the number of coefficients.
    pub fn len(self) -> usize {
        (self.0 * self.0) as usize
    }

    /// Never true for a constructed order; for clippy's `len` convention.
    pub fn is_empty(self) -> bool {
        false
    }
}

impl fmt::Display for ShOrder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "order {} SH", self.0)
    }
}

/// Coefficient index of `(l, m)`.
pub const fn index(l: i32, m: i32) -> usize {
    (l * (l + 1) + m) as usize
}

/// The normalisation `K_l^m` (for `m >= 0`).
fn k(l: usize, m: usize) -> f64 {
    // (l - m)! / (l + m)! as a product, exact enough for l < 8.
    let mut ratio = 1.0;
    for f in (l - m + 1)..=(l + m) {
        ratio /= f as f64;
    }
    ((2 * l + 1) as f64 * ratio / (4.0 * PI)).sqrt()
}

/// The normalisation factors to `MAX_SH_ORDER`, `sqrt(2) K_l^|m|` for `m != 0` and `K_l^0`,
/// by index (computed once).
fn norms() -> &'static [f64; (MAX_SH_ORDER * MAX_SH_ORDER) as usize] {
    static NORMS: std::sync::OnceLock<[f64; (MAX_SH_ORDER * MAX_SH_ORDER) as usize]> = std::sync::OnceLock::new();
    NORMS.get_or_init(|| norm_table(MAX_SH_ORDER as usize))
}

fn norm_table(n: usize) -> [f64; (MAX_SH_ORDER * MAX_SH_ORDER) as usize] {
    let mut out = [0.0; (MAX_SH_ORDER * MAX_SH_ORDER) as usize];
    for l in 0..n {
        for m in -(l as i32)..=(l as i32) {
            let kk = k(l, m.unsigned_abs() as usize);
            out[index(l as i32, m)] = if m == 0 { kk } else { std::f64::consts::SQRT_2 * kk };
        }
    }
    out
}

/// All `order^2` real SH at the unit direction `d` into `out` (`out.len() >= order^2`).
/// `d` need not be normalised exactly: it is normalised here (a zero vector gives the
/// values at +Z).
pub fn eval_into(order: ShOrder, d: DVec3, out: &mut [f64]) {
    let n = order.n() as usize;
    let d = d.try_normalize().unwrap_or(DVec3::Z);
    let (x, y, z) = (d.x, d.y, d.z);
    let norm = norms();
    // Re/Im of (x + i y)^m, m = 0..n-1.
    let mut c = [0.0f64; MAX_SH_ORDER as usize];
    let mut s = [0.0f64; MAX_SH_ORDER as usize];
    c[0] = 1.0;
    for m in 1..n {
        c[m] = x * c[m - 1] - y * s[m - 1];
        s[m] = x * s[m - 1] + y * c[m - 1];
    }
    // q = P_l^m(z) / sin^m(theta) without the Condon-Shortley phase, by the upward recurrence
    // in l for each m: q_m^m = (2m - 1)!!, q_{m+1}^m = (2m + 1) z q_m^m,
    // q_l^m = ((2l - 1) z q_{l-1}^m - (l + m - 1) q_{l-2}^m) / (l - m).
    let mut qmm = 1.0f64;
    for m in 0..n {
        if m > 0 {
            qmm *= (2 * m - 1) as f64;
        }
        let (mut q2, mut q1) = (0.0f64, qmm);
        for l in m..n {
            let q = if l == m {
                qmm
            } else if l == m + 1 {
                (2 * m + 1) as f64 * z * qmm
            } else {
                ((2 * l - 1) as f64 * z * q1 - (l + m - 1) as f64 * q2) / (l - m) as f64
            };
            if l > m {
                q2 = q1;
                q1 = q;
            }
            let (li, mi) = (l as i32, m as i32);
            if m == 0 {
                out[index(li, 0)] = norm[index(li, 0)] * q;
            } else {
                out[index(li, mi)] = norm[index(li, mi)] * q * c[m];
                out[index(li, -mi)] = norm[index(li, -mi)] * q * s[m];
            }
        }
    }
}

/// All `order^2` real SH at `d`.
pub fn eval(order: ShOrder, d: DVec3) -> Vec<f64> {
    let mut out = vec![0.0; order.len()];
    eval_into(order, d, &mut out);
    out
}

/// SH coefficients of the clamped cosine `max(z, 0)` (local frame, +Z = normal) to `order`:
/// zonal (only `m = 0`), `c_l = 2 pi K_l^0 int_0^1 mu P_l(mu) dmu`, integrated exactly by a
/// Gauss-Legendre rule. The irradiance of local light `l` is `sum_i l_i c_i` (exact when
/// `l` lies in the span; otherwise the truncation error of the clamped cosine).
pub fn clamped_cosine(order: ShOrder) -> Vec<f64> {
    let n = order.n() as usize;
    let (nodes, weights) = quadrature::gauss_legendre(n + 2, 0.0, 1.0);
    let mut out = vec![0.0; order.len()];
    let mut y = vec![0.0; order.len()];
    for (&mu, &w) in nodes.iter().zip(&weights) {
        // On the pole axis through the azimuth 0 plane: y_l^0 depends on mu only.
        eval_into(order, DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu), &mut y);
        for l in 0..n as i32 {
            out[index(l, 0)] += 2.0 * PI * w * mu * y[index(l, 0)];
        }
    }
    out
}
