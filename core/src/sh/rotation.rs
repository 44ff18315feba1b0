//! Rotation of SH coefficient vectors (Ivanic and Ruedenberg 1996, with their 1998
//! corrections): the block of band `l` is built from the band-1 block (the 3 x 3 rotation with
//! its axes permuted to the band's `(y, z, x)` order) and the block of band `l - 1` by a
//! recurrence, so rotating the light costs `sum_l (2l + 1)^2` multiply-adds instead of a
//! re-projection of the environment.
//!
//! Convention: for a rotation `R` of directions, [`ShRotation::new`] builds the matrix that
//! maps the coefficients of `f` to those of the rotated function `g(w) = f(R^T w)` (`f`
//! carried along by `R`). Tested against re-projection of the rotated function.

use super::{index, ShOrder};
use glam::DMat3;

/// The block-diagonal rotation of the coefficients of one order.
#[derive(Clone, Debug, PartialEq)]
pub struct ShRotation {
    order: ShOrder,
    /// Band blocks: `bands[l]` is `(2l + 1) x (2l + 1)`, row-major, indexed by `m + l`.
    bands: Vec<Vec<f64>>,
}

impl ShRotation {
    /// The rotation of order-`order` coefficients that carries functions along `r` (a proper
    /// rotation; an improper or non-orthogonal matrix gives a matrix that is not orthogonal).
    pub fn new(order: ShOrder, r: DMat3) -> Self {
        let n = order.n() as usize;
        let mut bands: Vec<Vec<f64>> = vec![vec![1.0]];
        if n > 1 {
            // Band 1 in (y, z, x) order: entry (m, m') = R[p(m)][p(m')], p(-1) = y, p(0) = z, p(1) = x.
            let p = [1usize, 2, 0];
            let at = |row: usize, col: usize| r.col(col)[row];
            let mut b1 = vec![0.0; 9];
            for i in 0..3 {
                for j in 0..3 {
                    b1[i * 3 + j] = at(p[i], p[j]);
                }
            }
            bands.push(b1);
        }
        for l in 2..n {
            let next = band(l, &bands[1], &bands[l - 1]);
            bands.push(next);
        }
        Self { order, bands }
    }

    /// A rotation by `angle` radians about +Y (the environment map's `rotation_degrees`).
    pub fn about_y(order: ShOrder, angle: f64) -> Self {
        Self::new(order, DMat3::from_rotation_y(angle))
    }

    pub fn order(&self) -> ShOrder {
        self.order
    }

    /// Entry `(i, j)` of the full `n^2 x n^2` matrix (0 across bands).
    pub fn entry(&self, i: usize, j: usize) -> f64 {
        let (li, lj) = ((i as f64).sqrt() as usize, (j as f64).sqrt() as usize);
        if li != lj {
            return 0.0;
        }
        let w = 2 * li + 1;
        self.bands[li][(i - li * li) * w + (j - li * li)]
    }

    /// `out = R c` for one coefficient vector (`c.len() == out.len() == n^2`).
    pub fn apply(&self, c: &[f64], out: &mut [f64]) {
        for (l, b) in self.bands.iter().enumerate() {
            let (w, base) = (2 * l + 1, l * l);
            for i in 0..w {
                out[base + i] = (0..w).map(|j| b[i * w + j] * c[base + j]).sum();
            }
        }
    }
}

/// Entry `(a, b)` of a band block, `a, b` in `-l..=l`.
fn at(block: &[f64], l: i32, a: i32, b: i32) -> f64 {
    block[((a + l) * (2 * l + 1) + (b + l)) as usize]
}

/// The band-`l` block from band 1 (`r1`) and band `l - 1` (`prev`).
fn band(l: usize, r1: &[f64], prev: &[f64]) -> Vec<f64> {
    let li = l as i32;
    let w = 2 * l + 1;
    let mut out = vec![0.0; w * w];
    // P(i, a, b) of Ivanic and Ruedenberg: i in -1..=1, a in -(l-1)..=(l-1), b in -l..=l.
    let p = |i: i32, a: i32, b: i32| -> f64 {
        let r = |x: i32, y: i32| at(r1, 1, x, y);
        let q = |x: i32, y: i32| at(prev, li - 1, x, y);
        if b == li {
            r(i, 1) * q(a, li - 1) - r(i, -1) * q(a, -li + 1)
        } else if b == -li {
            r(i, 1) * q(a, -li + 1) + r(i, -1) * q(a, li - 1)
        } else {
            r(i, 0) * q(a, b)
        }
    };
    for m in -li..=li {
        for mp in -li..=li {
            let d = (m == 0) as i32 as f64;
            let denom = if mp.abs() < li { ((li + mp) * (li - mp)) as f64 } else { (2 * li * (2 * li - 1)) as f64 };
            let am = m.abs();
            let u = (((li + m) * (li - m)) as f64 / denom).sqrt();
            let v = 0.5 * ((1.0 + d) * ((li + am - 1) * (li + am)) as f64 / denom).sqrt() * (1.0 - 2.0 * d);
            let wc = -0.5 * (((li - am - 1) * (li - am)) as f64 / denom).max(0.0).sqrt() * (1.0 - d);
            let mut value = 0.0;
            if u != 0.0 {
                value += u * p(0, m, mp);
            }
            if v != 0.0 {
                let vv = if m == 0 {
                    p(1, 1, mp) + p(-1, -1, mp)
                } else if m > 0 {
                    let d1 = (m == 1) as i32 as f64;
                    p(1, m - 1, mp) * (1.0 + d1).sqrt() - p(-1, -m + 1, mp) * (1.0 - d1)
                } else {
                    let d1 = (m == -1) as i32 as f64;
                    p(1, m + 1, mp) * (1.0 - d1) + p(-1, -m - 1, mp) * (1.0 + d1).sqrt()
                };
                value += v * vv;
            }
            if wc != 0.0 {
                let ww = if m > 0 { p(1, m + 1, mp) + p(-1, -m - 1, mp) } else { p(1, m - 1, mp) - p(-1, -m + 1, mp) };
                value += wc * ww;
            }
            out[((m + li) * w as i32 + (mp + li)) as usize] = value;
        }
    }
    let _ = index; // the band layout is the coefficient layout of `index`
    out
}
