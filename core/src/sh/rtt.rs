//! The radiance transfer texture (RTT) of Sloan et al. 2003: a BTF's light axis projected onto
//! the local SH, so that the per-pixel shading `B = sum_i RTT_i(u, e) l_i` takes the SH
//! incident light `l` of the low-frequency method directly.
//!
//! It is built from the *same* tabulated BTF as the all-frequency path (bins `j`, values `b_j`
//! multiplying the power `L*_j` through bin `j`). For a local radiance `l(w) = sum_i l_i y_i(w)`
//! the power through bin `j` is `sum_i l_i Y_ji` with `Y_ji = int_{bin j} y_i dw`, so
//!
//! `B = sum_j b_j L*_j = sum_i l_i RTT_i`, `RTT_i = sum_j b_j Y_ji`:
//!
//! the SH shading of band-limited light equals the binned shading exactly, and the method's only
//! loss at the meso scale is what the truncation of `l` removes. `Y_ji` is integrated by the
//! midpoint rule on `s x s` equal-area cells of each bin's concentric square ([`bin_integrals`]);
//! [`RttReport::quadrature_error`] measures it against twice as many cells per side.
//!
//! [`RttReport::projection_error`] says how much of the BTF's light dependence the order keeps:
//! with `beta(w) = b_j / omega_j` on bin `j` (so `B = int beta l`), `P_n beta` has coefficients
//! `RTT_i / omega` (all bins have the solid angle `omega = 2 pi / M`), and by Pythagoras the
//! relative L2 error of the projection is `sqrt(1 - |P_n beta|^2 / |beta|^2)`, summed over texels,
//! views and channels. Glossy BTFs lose most; a Lambertian one keeps nearly all.

use super::{eval_into, ShOrder};
use crate::basis::LocalBasis;
use crate::error::{CoreError, Result};
use crate::sampling::hemisphere::square_to_hemisphere;
use crate::sampling::HemisphereGrid;
use crate::scene::{Btf, BtfRepresentation};
use rayon::prelude::*;

/// Cells per side of each bin for the bin integrals of the RTT.
pub const BIN_CELLS: u32 = 8;

/// `Y[j * n^2 + i] = int_{bin j} y_i dw`, midpoint rule on `s x s` equal-area cells per bin.
pub fn bin_integrals(grid: HemisphereGrid, order: ShOrder, s: u32) -> Vec<f64> {
    let (n, m) = (order.len(), grid.m);
    let cell = grid.bin_solid_angle() / (s * s) as f64;
    (0..grid.len() as u32)
        .into_par_iter()
        .flat_map_iter(|j| {
            let (row, col) = (j / m, j % m);
            let (mut acc, mut y) = (vec![0.0f64; n], vec![0.0f64; n]);
            for a in 0..s {
                for b in 0..s {
                    let u = (col as f64 + (b as f64 + 0.5) / s as f64) / m as f64;
                    let v = (row as f64 + (a as f64 + 0.5) / s as f64) / m as f64;
                    eval_into(order, square_to_hemisphere(u, v), &mut y);
                    for (x, yi) in acc.iter_mut().zip(&y) {
                        *x += cell * yi;
                    }
                }
            }
            acc
        })
        .collect()
}

/// How well the RTT represents its BTF (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RttReport {
    /// Relative L2 error of the BTF's light dependence lost to the order.
    pub projection_error: f64,
    /// Largest difference of a bin integral `Y_ji` between `BIN_CELLS` and twice as many cells
    /// per side, relative to the largest `|Y_ji|`.
    pub quadrature_error: f64,
}

/// The RTT of `btf` (a BTF on a bin basis) at `order`: the same patch and view samples, its
/// light axis in `LocalBasis::Sh(order)`.
pub fn radiance_transfer_texture(btf: &Btf, order: ShOrder) -> Result<(Btf, RttReport)> {
    let Projection { m, n, y, quadrature_error, omega } = Projection::new(btf.local_basis(), btf.name(), order)?;
    let values: &[f32] = bytemuck::cast_slice(btf.data());
    let groups: Vec<(Vec<[f32; 3]>, f64, f64)> = values
        .par_chunks(3 * m)
        .map(|b| {
            let mut out = vec![0.0f32; 3 * n];
            let (beta2, proj2) = project_segment(b, &y, n, omega, &mut out);
            (out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(), beta2, proj2)
        })
        .collect();
    let (beta2, proj2) = groups.iter().fold((0.0, 0.0), |(a, b), g| (a + g.1, b + g.2));
    let projection_error = if beta2 > 0.0 { (1.0 - proj2 / beta2).max(0.0).sqrt() } else { 0.0 };
    let data: Vec<[f32; 3]> = groups.into_iter().flat_map(|g| g.0).collect();
    let rtt = Btf::new(
        btf.spatial(),
        LocalBasis::Sh(order),
        btf.view_grid(),
        data,
        format!("{} (RTT, {order})", btf.name()),
    )?;
    Ok((rtt, RttReport { projection_error, quadrature_error }))
}

/// What projecting a BTF's light axis onto SH needs: `M` bins, `n` coefficients, the bin
/// integrals `Y` and their quadrature error, the bins' solid angle.
struct Projection {
    m: usize,
    n: usize,
    y: Vec<f64>,
    quadrature_error: f64,
    omega: f64,
}

impl Projection {
    /// For a BTF named `name` whose light directions are `basis` (bins, else an error).
    fn new(basis: LocalBasis, name: &str, order: ShOrder) -> Result<Self> {
        let grid = basis.grid().ok_or_else(|| {
            CoreError::Invalid(format!("an RTT is projected from a BTF on bins, '{name}' is on {basis}"))
        })?;
        let y = bin_integrals(grid, order, BIN_CELLS);
        let fine = bin_integrals(grid, order, 2 * BIN_CELLS);
        let ymax = y.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let quadrature_error = y.iter().zip(&fine).fold(0.0f64, |a, (p, q)| a.max((p - q).abs())) / ymax.max(1e-300);
        Ok(Self { m: grid.len(), n: order.len(), y, quadrature_error, omega: grid.bin_solid_angle() })
    }
}

/// Project one light segment `b` (`M` bins, RGB interleaved) onto the `n` SH coefficients
/// (`out`, RGB interleaved): `out_i = sum_j b_j Y_ji`, in f64, rounded once. Returns the
/// segment's `|beta|^2` and `|P_n beta|^2` (module docs).
fn project_segment(b: &[f32], y: &[f64], n: usize, omega: f64, out: &mut [f32]) -> (f64, f64) {
    let mut acc = vec![[0.0f64; 3]; n];
    let mut beta2 = 0.0f64;
    for (j, bj) in b.chunks_exact(3).enumerate() {
        for c in 0..3 {
            let v = bj[c] as f64;
            beta2 += v * v / omega;
            for i in 0..n {
                acc[i][c] += v * y[j * n + i];
            }
        }
    }
    let proj2: f64 = acc.iter().flatten().map(|r| (r / omega).powi(2)).sum();
    for (o, a) in out.chunks_exact_mut(3).zip(&acc) {
        for c in 0..3 {
            o[c] = a[c] as f32;
        }
    }
    (beta2, proj2)
}

/// The RTT of a BTF in either representation: a dense table's is [`radiance_transfer_texture`];
/// an LPCA BTF's is the LPCA BTF whose means and eigen-BRDFs are projected segment by segment
/// ([`LpcaBtf::map_lights`]: the projection is linear, so this is exactly the RTT of the LPCA's
/// table, and the weights and clusters are unchanged; Müller et al. 2004 project their
/// eigen-BRDFs into SH the same way). The projection error is measured on the LPCA's own
/// table, unit by unit, without decoding it whole.
pub fn radiance_transfer(btf: &BtfRepresentation, order: ShOrder) -> Result<(BtfRepresentation, RttReport)> {
    let lpca = match btf {
        BtfRepresentation::Dense(b) => {
            let (rtt, report) = radiance_transfer_texture(b, order)?;
            return Ok((rtt.into(), report));
        }
        BtfRepresentation::Lpca(l) => l,
    };
    let Projection { m, n, y, quadrature_error, omega } = Projection::new(lpca.local_basis(), lpca.name(), order)?;
    let d = 3 * m * lpca.segments_per_unit();
    let (beta2, proj2) = (0..lpca.units())
        .into_par_iter()
        .map(|u| {
            let (mut row, mut out) = (vec![0.0f32; d], vec![0.0f32; 3 * n]);
            lpca.decode_unit(u, &mut row);
            row.chunks_exact(3 * m).fold((0.0, 0.0), |(a, b), seg| {
                let (x, y) = project_segment(seg, &y, n, omega, &mut out);
                (a + x, b + y)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let projection_error = if beta2 > 0.0 { (1.0 - proj2 / beta2).max(0.0).sqrt() } else { 0.0 };
    let rtt = lpca.map_lights(LocalBasis::Sh(order), format!("{} (RTT, {order})", lpca.name()), |seg, out| {
        project_segment(seg, &y, n, omega, out);
    });
    Ok((rtt.into(), RttReport { projection_error, quadrature_error }))
}

/// Largest relative deviation from the Lambertian shape accepted by [`lambertian_albedo`]
/// (f16 tables round to 2^-11 relative).
pub const LAMBERTIAN_TOLERANCE: f64 = 2e-3;

/// The albedo per texel when `btf` is Lambertian in shape: view-independent and, in every
/// texel, `b_j = rho / pi * cosbar_j` for all bins (to [`LAMBERTIAN_TOLERANCE`] of the
/// texel's largest value); `None` otherwise. Since `sum_j cosbar_j omega_j = pi`, the albedo is
/// `rho = sum_j b_j omega_j`.
pub fn lambertian_albedo(btf: &Btf) -> Option<Vec<[f32; 3]>> {
    let grid = btf.local_basis().grid()?;
    if btf.view_grid().is_some() {
        return None;
    }
    let (m, omega) = (grid.len(), grid.bin_solid_angle());
    let cosbar = grid.mean_cosines();
    btf.data()
        .chunks(m)
        .map(|b| {
            let rho: [f64; 3] = std::array::from_fn(|c| b.iter().map(|v| v[c] as f64 * omega).sum());
            let max = b.iter().flatten().fold(0.0f32, |a, &x| a.max(x.abs())) as f64;
            let fits = b.iter().zip(cosbar.iter()).all(|(v, cb)| {
                (0..3).all(|c| (v[c] as f64 - rho[c] / std::f64::consts::PI * cb).abs() <= LAMBERTIAN_TOLERANCE * max)
            });
            fits.then(|| rho.map(|x| x as f32))
        })
        .collect()
}

/// The BTF of a Lambertian-shaped table ([`lambertian_albedo`]) in the irradiance basis of
/// `order`: one value per texel, `rho / pi`, so that `B = rho / pi * E`. `None` when the table
/// is not Lambertian in shape.
pub fn irradiance_btf(btf: &Btf, order: ShOrder) -> Result<Option<Btf>> {
    let Some(albedo) = lambertian_albedo(btf) else { return Ok(None) };
    let data = albedo.iter().map(|a| a.map(|x| x / std::f32::consts::PI)).collect();
    let name = format!("{} (diffuse PRT, {order})", btf.name());
    Ok(Some(Btf::new(btf.spatial(), LocalBasis::Irradiance(order), None, data, name)?))
}
