//! The distant light in SH: projection of a cubemap light vector onto world-frame SH, its
//! reconstruction back onto the cubemap (for the projection error), and rotation.
//!
//! **Quadrature.** The cubemap light `L_k` is the power through texel `k`, i.e. the integral
//! of a radiance that is constant (`L_k / omega_k`) over each texel. Its SH coefficients are
//! then exactly `L_i = sum_k (L_k / omega_k) int_texel y_i dw`, and the only approximation is
//! the texel integral of `y_i`: each texel is cut into `s x s` sub-texels (the texels of the
//! `s R` cubemap, with their exact solid angles) and `y_i` taken at their centres, the
//! midpoint rule, whose error falls as `1 / s^2` (tested). [`ShProjection`] holds the
//! resulting `N x n^2` table `Y[k][i] = (1 / omega_k) int_texel y_i dw`, so projection is
//! `L_sh = Y^T L` and reconstruction `L'_k = omega_k sum_i Y[k][i] L_i`.

use super::{eval_into, ShOrder, ShRotation};
use crate::basis::LightBasis;
use crate::error::{CoreError, Result};
use crate::sampling::{Cubemap, LightVector};
use rayon::prelude::*;

/// Sub-texels per texel side of the light projection ([`ShProjection`]).
pub const LIGHT_SUBTEXELS: u32 = 4;

/// The texel-averaged SH of a cubemap (see the module docs).
#[derive(Clone, Debug)]
pub struct ShProjection {
    order: ShOrder,
    cubemap: Cubemap,
    /// `Y[k * n^2 + i]`: the mean of `y_i` over texel `k`.
    mean: Vec<f64>,
}

impl ShProjection {
    /// The table for `cubemap` and `order` with `s x s` sub-texels per texel.
    pub fn new(cubemap: Cubemap, order: ShOrder, s: u32) -> Self {
        let n = order.len();
        let fine = Cubemap::new(cubemap.resolution * s);
        let s = s as usize;
        let mean: Vec<f64> = (0..cubemap.texel_count())
            .into_par_iter()
            .flat_map_iter(|k| {
                let (face, row, col) = cubemap.texel_coords(k);
                let (mut acc, mut y, mut omega) = (vec![0.0f64; n], vec![0.0f64; n], 0.0f64);
                for sr in 0..s {
                    for sc in 0..s {
                        let f = fine.texel_index(face, row * s + sr, col * s + sc);
                        let w = fine.texel_solid_angle(f);
                        eval_into(order, fine.texel_direction_f64(f), &mut y);
                        for (a, v) in acc.iter_mut().zip(&y) {
                            *a += w * v;
                        }
                        omega += w;
                    }
                }
                acc.into_iter().map(move |a| a / omega)
            })
            .collect();
        Self { order, cubemap, mean }
    }

    pub fn order(&self) -> ShOrder {
        self.order
    }

    pub fn cubemap(&self) -> Cubemap {
        self.cubemap
    }

    /// `L_sh = Y^T L` for a light on this projection's cubemap (in f64, rounded to f32 once).
    pub fn project(&self, light: &LightVector) -> Result<LightVector> {
        if light.basis() != LightBasis::Cubemap(self.cubemap) {
            return Err(CoreError::Invalid(format!(
                "projecting a light in the {} with a projection of the {}",
                light.basis(),
                LightBasis::Cubemap(self.cubemap)
            )));
        }
        let n = self.order.len();
        let mut acc = vec![[0.0f64; 3]; n];
        for (k, p) in light.power.iter().enumerate() {
            for (i, a) in acc.iter_mut().enumerate() {
                // Radiance L_k / omega_k times int_texel y_i = omega_k * mean: the omegas cancel.
                let y = self.mean[k * n + i];
                for c in 0..3 {
                    a[c] += p[c] as f64 * y;
                }
            }
        }
        LightVector::new(LightBasis::Sh(self.order), acc.iter().map(|a| a.map(|x| x as f32)).collect())
    }

    /// The cubemap light of the band-limited radiance `sum_i L_i y_i`: `L'_k = int_texel
    /// sum_i L_i y_i = omega_k sum_i Y[k][i] L_i`.
    pub fn reconstruct(&self, sh: &LightVector) -> Result<LightVector> {
        if sh.basis() != LightBasis::Sh(self.order) {
            return Err(CoreError::Invalid(format!(
                "reconstructing a light in the {} with a projection of {}",
                sh.basis(),
                self.order
            )));
        }
        let n = self.order.len();
        let power = (0..self.cubemap.texel_count())
            .map(|k| {
                let w = self.cubemap.texel_solid_angle(k);
                let mut p = [0.0f64; 3];
                for i in 0..n {
                    let y = self.mean[k * n + i] * w;
                    for c in 0..3 {
                        p[c] += y * sh.power[i][c] as f64;
                    }
                }
                p.map(|x| x as f32)
            })
            .collect();
        LightVector::new(LightBasis::Cubemap(self.cubemap), power)
    }

    /// How much of `light` (on this cubemap) lies above the order: the relative L2 difference,
    /// over texels and channels, between `light` and the reconstruction of its projection,
    /// weighting each texel's radiance by its solid angle (`sum omega (L / omega - L' / omega)^2`).
    pub fn projection_error(&self, light: &LightVector) -> Result<f64> {
        let back = self.reconstruct(&self.project(light)?)?;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (k, (a, b)) in light.power.iter().zip(&back.power).enumerate() {
            let w = self.cubemap.texel_solid_angle(k);
            for c in 0..3 {
                let (a, b) = (a[c] as f64 / w, b[c] as f64 / w);
                num += w * (a - b) * (a - b);
                den += w * a * a;
            }
        }
        Ok(crate::stats::relative_l2(num, den))
    }
}

impl LightVector {
    /// This SH light rotated by `rotation` (the environment carried along it; see
    /// [`ShRotation`]); an error for a light that is not SH of the rotation's order.
    pub fn rotated_sh(&self, rotation: &ShRotation) -> Result<LightVector> {
        if self.basis() != LightBasis::Sh(rotation.order()) {
            return Err(CoreError::Invalid(format!(
                "rotating a light in the {} by {} rotation",
                self.basis(),
                rotation.order()
            )));
        }
        let n = rotation.order().len();
        let mut power = vec![[0.0f32; 3]; n];
        let (mut a, mut b) = (vec![0.0f64; n], vec![0.0f64; n]);
        for c in 0..3 {
            for (x, p) in a.iter_mut().zip(&self.power) {
                *x = p[c] as f64;
            }
            rotation.apply(&a, &mut b);
            for (p, x) in power.iter_mut().zip(&b) {
                p[c] = *x as f32;
            }
        }
        LightVector::new(self.basis(), power)
    }
}
