//! Quadrature rules that integrate the SH bases exactly: Gauss-Legendre in `cos theta` times
//! a uniform rule in `phi` is exact for every polynomial in `(x, y, z)` of degree below the
//! rules' orders, which is what products of spherical harmonics restricted to a sphere or to
//! the upper hemisphere are.

use glam::DVec3;
use std::f64::consts::PI;

/// `n`-point Gauss-Legendre nodes and weights on `[a, b]` (exact for polynomials of degree
/// `< 2n`), by Newton's iteration on `P_n` from Chebyshev starting points, in f64.
pub fn gauss_legendre(n: usize, a: f64, b: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut nodes, mut weights) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            // P_n(x) and P_n'(x) by the three-term recurrence.
            let (mut p0, mut p1) = (1.0f64, x);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 {
                1.0
            } else if n == 1 {
                x
            } else {
                p1
            };
            let pn1 = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (x * pn - pn1) / (x * x - 1.0);
            let dx = pn / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        nodes[i] = 0.5 * (b - a) * x + 0.5 * (b + a);
        weights[i] = (b - a) / ((1.0 - x * x) * dp * dp);
    }
    (nodes, weights)
}

/// Directions and solid-angle weights of a product rule over the sphere (`upper_only`: the
/// upper hemisphere `z >= 0`) with `n` Gauss-Legendre nodes in `z` and `2n` azimuths: exact
/// for polynomials in `(x, y, z)` of degree `< 2n`.
pub fn sphere_rule(n: usize, upper_only: bool) -> Vec<(DVec3, f64)> {
    let (nodes, weights) = gauss_legendre(n, if upper_only { 0.0 } else { -1.0 }, 1.0);
    let azimuths = 2 * n;
    let mut out = Vec::with_capacity(n * azimuths);
    for (&z, &w) in nodes.iter().zip(&weights) {
        let r = (1.0 - z * z).max(0.0).sqrt();
        for a in 0..azimuths {
            let phi = 2.0 * PI * (a as f64 + 0.5) / azimuths as f64;
            out.push((DVec3::new(r * phi.cos(), r * phi.sin(), z), w * 2.0 * PI / azimuths as f64));
        }
    }
    out
}
