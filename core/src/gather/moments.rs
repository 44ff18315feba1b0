//! Direction moments: `L*` with each texel's exact cosine instead of its bin's mean cosine.
//!
//! The paper's shading weights every texel of local bin `j` by the bin's mean cosine
//! `cosbar_j` (the BTF value `b(u, e, d_j)` includes it, docs/DESIGN.md section 3). That is exact
//! only for a fully visible, evenly lit bin: a sun near the horizon in an outer bin is
//! over-weighted up to an order of magnitude, and an occluder that removes a bin's low part
//! darkens it. The cosine of texel `k` at a vertex with normal `n` is `n . d_k`, linear in the
//! texel's direction, so gathering the three light vectors `L d_x`, `L d_y`, `L d_z` through the
//! *same* `T` (the same compressed form: only the gather's arithmetic grows) gives each bin the
//! radiance-weighted direction sum `D_j = sum_k T[j, k] L_k d_k`, and
//!
//! `L*'_j = (n . D_j) / cosbar_j = sum_k T[j, k] L_k (n . d_k) / cosbar_j`.
//!
//! Dotted with the unchanged BTF, `b_j L*'_j = f_j (n . D_j)`: the exact per-texel cosine, the
//! rest of the BRDF still at the bin centre. For a white Lambertian material this is the exact
//! direct irradiance `sum_k T[j, k] L_k cos_k / pi` of `T`'s visibility. `d_k` is the texel's
//! centre direction, the one `T` bins it by; `n` is the vertex normal `T` was traced with.
//!
//! Every gather is linear in the light, so [`gather_with_moments`] works through any
//! compressor's CPU gather, lossless or not, and [`exact_cosine_product`] is its f64
//! reference, computed per texel from `T` and not from the moments.

use crate::compress::{CompressError, CompressedForm, Compressor};
use crate::error::{CoreError, Result};
use crate::gather::LocalRadiance;
use crate::geometry::VertexFrame;
use crate::sampling::{Cubemap, HemisphereGrid, LightVector};
use crate::transfer::TransferMatrix;
use glam::DVec3;
use rayon::prelude::*;

/// The three direction moments of a cubemap light vector: `along[a]` is `L_k d_k[a]` for the
/// world axes `a = x, y, z` (per RGB channel), `d_k` the centre direction of texel `k`.
#[derive(Clone, Debug, PartialEq)]
pub struct LightMoments {
    pub along: [LightVector; 3],
}

impl LightMoments {
    /// The moments of `light`; an error unless it is in a cubemap basis (an SH light has no
    /// texels to take directions of).
    pub fn new(light: &LightVector) -> Result<Self> {
        let directions = texel_directions(cubemap_of(light)?);
        let along = [0, 1, 2].map(|a| {
            let power =
                (light.power.iter().zip(&directions)).map(|(l, d)| l.map(|x| (x as f64 * d[a]) as f32)).collect();
            LightVector::new(light.basis(), power).expect("same basis, same length")
        });
        Ok(Self { along })
    }
}

/// The cubemap of `light`'s basis; an error unless it has one (an SH light has no texels to
/// take directions of).
fn cubemap_of(light: &LightVector) -> Result<Cubemap> {
    light.cubemap().ok_or_else(|| {
        CoreError::Invalid(format!(
            "light moments need a cubemap light basis, the light vector is in the {}",
            light.basis()
        ))
    })
}

/// Every texel's centre direction, in f64.
fn texel_directions(cube: Cubemap) -> Vec<DVec3> {
    (0..cube.texel_count()).map(|k| cube.texel_direction_f64(k)).collect()
}

/// The weight light moments give entry `T[j, k]` at a point with unit normal `n`:
/// `(n . d_k) / cosbar_j`, texel `k`'s own cosine over its bin's mean cosine. Shared by the
/// f64 per-texel product ([`exact_cosine_product`]) and the per-pixel reference renderer.
#[derive(Clone, Debug)]
pub struct TexelCosine {
    inverse_mean_cosine: Vec<f64>,
    directions: Vec<DVec3>,
}

impl TexelCosine {
    /// The weights for `light`'s texels and `grid`'s bins; an error unless `light` is in a
    /// cubemap basis.
    pub fn new(light: &LightVector, grid: &HemisphereGrid) -> Result<Self> {
        Ok(Self { inverse_mean_cosine: inverse_mean_cosines(grid), directions: texel_directions(cubemap_of(light)?) })
    }

    /// `(n . d_k) / cosbar_j`.
    pub fn weight(&self, n: DVec3, j: usize, k: usize) -> f64 {
        n.dot(self.directions[k]) * self.inverse_mean_cosine[j]
    }
}

/// The bin grid of a local basis and the checks every moments function shares: `L*` must be
/// in bins (the mean cosine is a bin's), and there must be one frame per vertex.
fn bins_and_frames(
    t_local: crate::basis::LocalBasis,
    vertices: usize,
    frames: &[VertexFrame],
) -> Result<HemisphereGrid> {
    let grid = t_local
        .grid()
        .ok_or_else(|| CoreError::Invalid(format!("light moments need a local basis of bins, T's is {t_local}")))?;
    if frames.len() != vertices {
        return Err(CoreError::Invalid(format!(
            "light moments need one vertex frame per vertex: {} frames for {vertices} vertices",
            frames.len()
        )));
    }
    Ok(grid)
}

/// `1 / cosbar_j` for every bin.
fn inverse_mean_cosines(grid: &HemisphereGrid) -> Vec<f64> {
    (0..grid.len() as u32).map(|j| 1.0 / grid.bin_mean_cosine(j)).collect()
}

/// `L*'` from the three gathered moments: `(n_v . D_{v,j}) / cosbar_j` per channel, `n_v` the
/// normal of `frames[v]`.
pub fn resolve(along: [&LocalRadiance; 3], frames: &[VertexFrame]) -> Result<LocalRadiance> {
    let basis = along[0].basis();
    let vertices = along[0].vertices();
    if along.iter().any(|a| a.basis() != basis || a.vertices() != vertices) {
        return Err(CoreError::Invalid("the three gathered moments differ in basis or vertex count".into()));
    }
    let grid = bins_and_frames(basis, vertices, frames)?;
    let inv = inverse_mean_cosines(&grid);
    let m = grid.len();
    let mut out = LocalRadiance::zeros(basis, vertices);
    out.values_mut().par_chunks_mut(m).zip(frames).enumerate().for_each(|(v, (out, frame))| {
        let n = frame.normal.as_dvec3();
        let rows = [along[0].vertex(v), along[1].vertex(v), along[2].vertex(v)];
        for (j, o) in out.iter_mut().enumerate() {
            for c in 0..3 {
                let dot = n.x * rows[0][j][c] as f64 + n.y * rows[1][j][c] as f64 + n.z * rows[2][j][c] as f64;
                o[c] = (dot * inv[j]) as f32;
            }
        }
    });
    Ok(out)
}

/// `L*'` through `compressor`'s CPU gather of `form`: the three moments
/// ([`Compressor::gather_three`], one fused pass where the compressor has one), then
/// [`resolve`]. `frames` are the vertex frames `T` was traced with.
pub fn gather_with_moments(
    compressor: &dyn Compressor,
    form: &CompressedForm,
    moments: &LightMoments,
    frames: &[VertexFrame],
) -> std::result::Result<LocalRadiance, CompressError> {
    let [x, y, z] = &moments.along;
    let gathered = compressor.gather_three(form, [x, y, z])?;
    resolve([&gathered[0], &gathered[1], &gathered[2]], frames).map_err(|e| CompressError::External(Box::new(e)))
}

/// The f64 reference of `L*'`: for every row `(v, j)`, `sum_k T[j, k] L_k (n_v . d_k) / cosbar_j`
/// with each texel's own cosine (not through the moments).
pub fn exact_cosine_product(t: &TransferMatrix, light: &LightVector, frames: &[VertexFrame]) -> Result<Vec<[f64; 3]>> {
    if t.light_basis() != light.basis() {
        return Err(CoreError::Invalid(format!(
            "the light vector is in the {}, T's light basis is the {}",
            light.basis(),
            t.light_basis()
        )));
    }
    let grid = bins_and_frames(t.local_basis(), t.vertices(), frames)?;
    let cosine = TexelCosine::new(light, &grid)?;
    let m = grid.len();
    let csr = t.csr();
    Ok((0..csr.rows())
        .into_par_iter()
        .map(|r| {
            let (v, j) = (r / m, r % m);
            let n = frames[v].normal.as_dvec3();
            let row = csr.outer_view(r).expect("row in range");
            let mut acc = [0.0f64; 3];
            for (k, &value) in row.iter() {
                let w = value as f64 * cosine.weight(n, j, k);
                let l = light.power[k];
                for c in 0..3 {
                    acc[c] += w * l[c] as f64;
                }
            }
            acc
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::{LightBasis, LocalBasis};
    use crate::gather::{reference_product, relative_l2_error};
    use crate::sampling::Cubemap;
    use glam::Vec3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn random_frames(n: usize, rng: &mut ChaCha8Rng) -> Vec<VertexFrame> {
        (0..n)
            .map(|_| {
                let d = Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
                VertexFrame::from_normal(if d.length() > 0.1 { d.normalize() } else { Vec3::Y })
            })
            .collect()
    }

    /// The one-vertex `T` of an unoccluded vertex with frame `f`: every texel whose centre is
    /// above the tangent plane, value 1, in the bin of its local direction.
    fn open_sky_t(cube: Cubemap, grid: HemisphereGrid, f: &VertexFrame) -> TransferMatrix {
        let mut rows = vec![vec![]; grid.len()];
        for k in 0..cube.texel_count() {
            if let Some(j) = grid.bin_of(f.to_local(cube.texel_direction(k))) {
                rows[j as usize].push((k, 1.0f32));
            }
        }
        t_of_rows(cube, grid, &rows)
    }

    fn t_of_rows(cube: Cubemap, grid: HemisphereGrid, rows: &[Vec<(usize, f32)>]) -> TransferMatrix {
        crate::testing::transfer_from_rows(LocalBasis::Bins(grid), LightBasis::Cubemap(cube), rows)
    }

    /// Moments resolved in f32 agree with the per-texel f64 product on random T (values in
    /// (0, 1], random normals, random light) and on a stiff sun 1e7 above the sky: the sum of
    /// three f32 gathers loses about `3 * eps * |D_j| / |n . D_j|` relative, and this T's rows
    /// are gathered in f64 here, so the bound is rounding of the light moments and the sum.
    #[test]
    fn resolved_moments_match_the_per_texel_reference_on_random_and_stiff_light() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (cube, grid) = (Cubemap::new(8), HemisphereGrid::new(4));
        let frames = random_frames(40, &mut rng);
        let rows: Vec<Vec<(usize, f32)>> = (0..40 * grid.len())
            .map(|_| {
                let mut row = vec![];
                for k in 0..cube.texel_count() {
                    if rng.gen::<f64>() < 0.3 {
                        row.push((k, rng.gen_range(1..=4) as f32 / 4.0));
                    }
                }
                row
            })
            .collect();
        let t = t_of_rows(cube, grid, &rows);
        for stiff in [false, true] {
            let mut power: Vec<[f32; 3]> = (0..cube.texel_count()).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect();
            if stiff {
                power[rng.gen_range(0..cube.texel_count())] = [1e7, 5e6, 2e6];
            }
            let light = LightVector::new(LightBasis::Cubemap(cube), power).unwrap();
            let moments = LightMoments::new(&light).unwrap();
            let gathered = moments
                .along
                .clone()
                .map(|l| LocalRadiance::from_f64(LocalBasis::Bins(grid), 40, &reference_product(&t, &l)).unwrap());
            let fast = resolve([&gathered[0], &gathered[1], &gathered[2]], &frames).unwrap();
            let exact = exact_cosine_product(&t, &light, &frames).unwrap();
            let err = relative_l2_error(fast.values(), &exact);
            // Per row the terms n . d_k have either sign (random T puts texels below the
            // horizon too), so cancellation can amplify rounding; 1e-5 is 100 f32 ulps.
            assert!(err < 1e-5, "stiff {stiff}: relative error {err:e}");
        }
    }

    /// An open vertex under a constant sky of radiance 1: `sum_j cosbar_j L*'_j` is the
    /// cosine-weighted solid angle of the texels above the plane, `pi` up to the texel-centre
    /// rule (texels straddling the horizon: at most about 2 pi / R of the solid angle at
    /// resolution R, here 1.5%). With the bin mean cosine the same sum is checked too.
    #[test]
    fn an_open_vertex_under_a_constant_sky_sees_pi() {
        let (cube, grid) = (Cubemap::new(64), HemisphereGrid::new(8));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for f in random_frames(5, &mut rng) {
            let t = open_sky_t(cube, grid, &f);
            let power = (0..cube.texel_count()).map(|k| [cube.texel_solid_angle(k) as f32; 3]).collect();
            let light = LightVector::new(LightBasis::Cubemap(cube), power).unwrap();
            let exact = exact_cosine_product(&t, &light, &[f]).unwrap();
            let e: f64 = (0..grid.len()).map(|j| grid.bin_mean_cosine(j as u32) * exact[j][0]).sum();
            assert!((e - PI).abs() < 0.015 * PI, "exact-cosine irradiance {e} vs pi");
            // The exact-cosine sum is the direct sum of cos_k Omega_k over the texels in T, up
            // to the light's f32 storage of Omega_k (half an ulp, 6e-8 relative, per texel).
            let direct: f64 = (0..cube.texel_count())
                .map(|k| cube.texel_direction_f64(k).dot(f.normal.as_dvec3()))
                .zip(0..)
                .filter(|(c, _)| *c > 0.0)
                .map(|(c, k)| c * cube.texel_solid_angle(k))
                .sum();
            assert!((e - direct).abs() < 6e-8 * direct, "{e} vs {direct}");
        }
    }

    /// A sun in one outer-ring texel: the paper's bin rule weights it by `cosbar_j`, moments by
    /// its own cosine, and the ratio of the two `L*` in its bin is exactly `cos_k / cosbar_j`.
    #[test]
    fn a_low_sun_gets_its_own_cosine() {
        let (cube, grid) = (Cubemap::new(32), HemisphereGrid::new(8));
        let f = VertexFrame::from_normal(Vec3::Y);
        let t = open_sky_t(cube, grid, &f);
        // The texel nearest 3 degrees above the horizon.
        let sun_dir = Vec3::new(0.0, (3.0f32).to_radians().sin(), (3.0f32).to_radians().cos());
        let k = cube.texel_of(sun_dir);
        let mut power = vec![[0.0f32; 3]; cube.texel_count()];
        power[k] = [1e6; 3];
        let light = LightVector::new(LightBasis::Cubemap(cube), power).unwrap();
        let exact = exact_cosine_product(&t, &light, &[f]).unwrap();
        let paper = reference_product(&t, &light);
        let j = grid.bin_of(f.to_local(cube.texel_direction(k))).unwrap() as usize;
        let cos_k = cube.texel_direction_f64(k).dot(DVec3::Y);
        let want = cos_k / grid.bin_mean_cosine(j as u32);
        assert!(want < 0.5, "the sun is low: cos {cos_k} against the bin's mean cosine");
        assert!((exact[j][0] / paper[j][0] - want).abs() < 1e-12, "{} vs {want}", exact[j][0] / paper[j][0]);
    }

    #[test]
    fn bad_inputs_are_refused_with_what_is_wrong() {
        let (cube, grid) = (Cubemap::new(4), HemisphereGrid::new(2));
        let f = VertexFrame::from_normal(Vec3::Y);
        let t = open_sky_t(cube, grid, &f);
        let light = LightVector::new(LightBasis::Cubemap(cube), vec![[1.0; 3]; cube.texel_count()]).unwrap();
        let e = exact_cosine_product(&t, &light, &[f, f]).unwrap_err().to_string();
        assert!(e.contains("2 frames for 1 vertices"), "{e}");
        let sh = LightVector::new(LightBasis::Sh(crate::sh::ShOrder::new(2).unwrap()), vec![[1.0; 3]; 4]).unwrap();
        let e = LightMoments::new(&sh).unwrap_err().to_string();
        assert!(e.contains("cubemap"), "{e}");
    }
}
