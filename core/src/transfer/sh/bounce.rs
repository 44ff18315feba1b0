//! Interreflection in the SH transfer (the self-interreflection of Sloan et al.'s `M_p` for
//! lighting at infinity): each bounce adds, for every ray of a vertex that hits the mesh, the
//! light leaving the hit point towards the vertex.
//!
//! The surface the light bounces off is taken to be Lambertian with a per-triangle albedo `rho`
//! (the caller's: the pipeline uses each material's mean reflectance under uniform light,
//! averaged over RGB so `M` stays monochrome). Its exit radiance is then `rho / pi` times its
//! irradiance, which is linear in `L_sh`: the irradiance transfer `e_q = c^T M_q` of the
//! previous iteration at the hit point, interpolated barycentrically from the hit triangle's
//! vertices. So with `B` bounces,
//!
//! `M_p^(b) = M_p^(0) + sum_{rays s hitting} (2 pi / S) y(F_p^T w_s) (rho_t / pi) (sum_k beta_k e_{q_k}^(b-1))^T`,
//!
//! `b = 1..B`, on the same strata as the direct transfer (the rays are traced once more, for
//! their hits). Each bounce is one more reflection: `B = 0` is shadowed transfer only.

use super::{assemble, eval_into, stratum_direction, to_world, ShTransferSettings};
use crate::error::{CoreError, Result};
use crate::transfer::{TransferMatrix, TransferScene};
use glam::DVec3;
use rayon::prelude::*;

/// One ray of a vertex that hit the mesh: its local direction, the triangle and the hit's
/// barycentric weights of the triangle's three vertices.
struct RayHit {
    local: DVec3,
    triangle: u32,
    weights: [f64; 3],
}

/// `direct` (a ray-traced SH transfer of `scene` with `settings`) with `bounces` bounces of
/// interreflection off triangles of albedo `albedo[t]` (`triangles` the mesh's). Errors when
/// the sizes do not fit or an albedo is not in `[0, 1]`.
pub fn add_bounces(
    scene: &TransferScene,
    triangles: &[[u32; 3]],
    settings: &ShTransferSettings,
    direct: &TransferMatrix,
    albedo: &[f32],
    bounces: u32,
) -> Result<TransferMatrix> {
    let order = settings.order();
    let (n, vertices) = (order.len(), scene.vertex_count());
    if direct.local_basis() != settings.bases().0
        || direct.light_basis() != settings.bases().1
        || direct.vertices() != vertices
    {
        return Err(CoreError::Invalid(format!(
            "the direct transfer is {}, the settings give {order} for {vertices} vertices",
            direct.shape()
        )));
    }
    if albedo.len() != triangles.len() {
        return Err(CoreError::Invalid(format!("{} albedos for {} triangles", albedo.len(), triangles.len())));
    }
    if let Some(t) = albedo.iter().position(|a| !(0.0..=1.0).contains(a)) {
        return Err(CoreError::Invalid(format!("triangle {t}'s bounce albedo {} is not in [0, 1]", albedo[t])));
    }
    if bounces == 0 {
        return Ok(direct.clone());
    }
    let weight = 2.0 * std::f64::consts::PI / settings.rays() as f64;
    // The hits of every vertex's strata.
    let hits: Vec<Vec<RayHit>> = (0..vertices)
        .into_par_iter()
        .map(|v| {
            let frame = scene.frames()[v];
            let origin = scene.vertex_origin(v);
            (0..settings.rays())
                .filter_map(|s| {
                    let local = stratum_direction(settings, v, s);
                    let hit = scene.closest_from(origin, to_world(&frame, local).as_vec3())?;
                    let (b1, b2) = (hit.barycentric.x as f64, hit.barycentric.y as f64);
                    Some(RayHit { local, triangle: hit.triangle, weights: [1.0 - b1 - b2, b1, b2] })
                })
                .collect()
        })
        .collect();
    let c = crate::sh::clamped_cosine(order);
    let dense_direct: Vec<Vec<f64>> = (0..vertices).map(|v| dense_block(direct, v, n)).collect();
    let mut current = dense_direct.clone();
    for _ in 0..bounces {
        // e_v = c^T M_v: the irradiance each vertex receives, as a functional of L_sh.
        let e: Vec<Vec<f64>> =
            current.par_iter().map(|m| (0..n).map(|j| (0..n).map(|i| c[i] * m[i * n + j]).sum()).collect()).collect();
        current = (0..vertices)
            .into_par_iter()
            .map(|v| {
                let mut m = dense_direct[v].clone();
                let (mut y, mut out) = (vec![0.0f64; n], vec![0.0f64; n]);
                for h in &hits[v] {
                    let rho = albedo[h.triangle as usize] as f64;
                    if rho == 0.0 {
                        continue;
                    }
                    let t = triangles[h.triangle as usize];
                    out.fill(0.0);
                    for (k, &beta) in h.weights.iter().enumerate() {
                        for (o, x) in out.iter_mut().zip(&e[t[k] as usize]) {
                            *o += beta * x;
                        }
                    }
                    eval_into(order, h.local, &mut y);
                    let scale = weight * rho / std::f64::consts::PI;
                    for (i, &yi) in y.iter().enumerate() {
                        let a = scale * yi;
                        for (mij, &oj) in m[i * n..(i + 1) * n].iter_mut().zip(&out) {
                            *mij += a * oj;
                        }
                    }
                }
                m
            })
            .collect();
    }
    assemble(order, &current)
}

/// Vertex `v`'s `n x n` block of `m`, dense and row-major (f64).
fn dense_block(m: &TransferMatrix, v: usize, n: usize) -> Vec<f64> {
    let mut out = vec![0.0f64; n * n];
    for i in 0..n {
        if let Some(row) = m.csr().outer_view(v * n + i) {
            for (j, &x) in row.iter() {
                out[i * n + j] = x as f64;
            }
        }
    }
    out
}
