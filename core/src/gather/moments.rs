//! Direction moments: `L*` with each texel's exact cosine instead of its bin's mean cosine, and
//! the BTF lobe at the light's mean direction instead of the bin centre.
//!
//! The paper's shading weights every texel of local bin `j` by the bin's mean cosine
//! `cosbar_j` (the BTF value `b(u, e, d_j)` includes it, docs/DESIGN.md section 3) and evaluates
//! the rest of the BRDF at the bin centre. That is exact only for a fully visible, evenly lit
//! bin: a sun near the horizon in an outer bin is over-weighted up to an order of magnitude,
//! and an occluder that removes a bin's low part darkens it. The cosine of texel `k` at a
//! vertex with normal `n` is `n . d_k`, linear in the texel's direction, so gathering the three
//! light vectors `L d_x`, `L d_y`, `L d_z` through the *same* `T` (the same compressed form:
//! only the gather's arithmetic grows) gives each bin the radiance-weighted direction sum
//! `D_j = sum_k T[j, k] L_k d_k` (per RGB channel). Its dot with the normal is the bin's light
//! with every texel's own cosine, and its direction is where that light comes from on average.
//!
//! [`resolve`] turns the moments into an `L*'` that every shader dots with the unchanged BTF:
//! bin `j`'s exact-cosine power `n . D_j` is handed to the bins around `D_j`'s direction with
//! bilinear weights, each divided by its own mean cosine, so that `sum_i b_i L*'_i` is
//! `sum_j f(D_j / |D_j|) (n . D_j)`, the BRDF interpolated in the BTF's light grid at the mean
//! direction. For a white Lambertian material this is the exact direct irradiance
//! `sum_k T[j, k] L_k cos_k / pi` of `T`'s visibility. `d_k` is where texel `k`'s light comes
//! from: the power-weighted mean direction of the source pixels it averages, per channel
//! (`LightVector::mean_direction`), or its centre for a light not splatted from an image; `T`
//! still bins the texel by its centre. `n` is the vertex normal `T` was traced with.
//!
//! Every gather is linear in the light, so [`gather_with_moments`] works through any
//! compressor's CPU gather, lossless or not. [`exact_moments_product`] is its f64 reference,
//! with `D_j` summed per texel from `T` and not from the moments; [`exact_cosine_product`] is
//! the per-texel exact-cosine light of each bin, before the redistribution (the irradiance a
//! white Lambertian vertex receives).

use crate::compress::{CompressError, CompressedForm, Compressor};
use crate::error::{CoreError, Result};
use crate::gather::LocalRadiance;
use crate::geometry::VertexFrame;
use crate::sampling::{Cubemap, HemisphereGrid, LightVector};
use crate::scene::btf::light_weights;
use crate::transfer::TransferMatrix;
use glam::DVec3;
use rayon::prelude::*;

/// The three direction moments of a cubemap light vector: `along[a]` is `L_k d_k[a]` for the
/// world axes `a = x, y, z` (per RGB channel), `d_k` texel `k`'s mean direction in that
/// channel ([`LightVector::mean_direction`]: its centre for a light without means).
#[derive(Clone, Debug, PartialEq)]
pub struct LightMoments {
    pub along: [LightVector; 3],
    /// Where [`resolve`] takes each bin's BRDF.
    pub lobe: Lobe,
}

/// Where the resolve of the moments takes each bin's BRDF.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lobe {
    /// At the bin's mean light direction (bilinear in the BTF's light grid): the general case.
    MeanDirection,
    /// At the bin centre, as the paper: only the cosine is exact. Exactly the same image for
    /// BTFs whose BRDF does not vary with the light direction (Lambertian ones), and the
    /// resolve is then a dot product per bin instead of a lookup of the direction in the grid.
    BinCentre,
}

impl LightMoments {
    /// The moments of `light`, resolved with the BRDF at each bin's mean direction; an error
    /// unless it is in a cubemap basis (an SH light has no texels to take directions of).
    pub fn new(light: &LightVector) -> Result<Self> {
        let directions = mean_directions(light)?;
        let along = [0, 1, 2].map(|a| {
            let power = (light.power.iter().zip(&directions))
                .map(|(l, d)| std::array::from_fn(|c| (l[c] as f64 * d[c][a]) as f32))
                .collect();
            LightVector::new(light.basis(), power).expect("same basis, same length")
        });
        Ok(Self { along, lobe: Lobe::MeanDirection })
    }

    /// The same moments, resolved with `lobe`.
    pub fn with_lobe(self, lobe: Lobe) -> Self {
        Self { lobe, ..self }
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

/// Every texel's mean direction per channel ([`LightVector::mean_direction`]), in f64.
fn mean_directions(light: &LightVector) -> Result<Vec<[DVec3; 3]>> {
    let n = cubemap_of(light)?.texel_count();
    Ok((0..n).map(|k| std::array::from_fn(|c| light.mean_direction(k, c).expect("a cubemap light"))).collect())
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
    grid: HemisphereGrid,
    inverse_mean_cosine: Vec<f64>,
    directions: Vec<DVec3>,
}

impl TexelCosine {
    /// The weights for `light`'s texels and `grid`'s bins; an error unless `light` is in a
    /// cubemap basis.
    pub fn new(light: &LightVector, grid: &HemisphereGrid) -> Result<Self> {
        Ok(Self {
            grid: *grid,
            inverse_mean_cosine: inverse_mean_cosines(grid),
            directions: texel_directions(cubemap_of(light)?),
        })
    }

    /// `(n . d_k) / cosbar_j`.
    pub fn weight(&self, n: DVec3, j: usize, k: usize) -> f64 {
        n.dot(self.directions[k]) * self.inverse_mean_cosine[j]
    }

    /// Texel `k` seen from a point with `frame`, spread over the (up to) four light bins around
    /// its own direction: `(i, (n . d_k) w_i / cosbar_i)` with the bilinear weights of
    /// [`light_weights`]. Summed into `L*` and dotted with a BTF, the texel contributes
    /// `f(d_k) (n . d_k)`, the BRDF interpolated at its exact direction (what [`resolve`] does
    /// with a bin's mean direction).
    pub fn spread(&self, frame: &VertexFrame, k: usize) -> [(usize, f64); 4] {
        let d = self.directions[k];
        let cosine = frame.normal.as_dvec3().dot(d);
        light_weights(self.grid, frame.to_local(d.as_vec3()))
            .map(|(i, w)| (i, cosine * w as f64 * self.inverse_mean_cosine[i]))
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

/// The checks the two f64 products share: `light` in `T`'s light basis, then
/// [`bins_and_frames`].
fn t_light_and_frames(t: &TransferMatrix, light: &LightVector, frames: &[VertexFrame]) -> Result<HemisphereGrid> {
    if t.light_basis() != light.basis() {
        return Err(CoreError::Invalid(format!(
            "the light vector is in the {}, T's light basis is the {}",
            light.basis(),
            t.light_basis()
        )));
    }
    bins_and_frames(t.local_basis(), t.vertices(), frames)
}

/// The Rec. 709 luminance weights of R, G and B: a bin's mean light direction is that of the
/// luminance of its three channels' moments (every resolve, CPU and GPU, uses these).
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// `1 / cosbar_j` for every bin.
fn inverse_mean_cosines(grid: &HemisphereGrid) -> Vec<f64> {
    grid.mean_cosines().iter().map(|c| 1.0 / c).collect()
}

/// `L*'` from the three gathered moments. Per vertex `v`, bin `j` and channel `c`, the bin's
/// light `D_{v,j,c}` brings the exact-cosine power `n_v . D_{v,j,c}`, arriving on average from
/// the direction of `D_{v,j}`, the luminance of the three channels' `D`. That power is handed to
/// the (up to) four light bins `i` around the mean direction with the bilinear weights `w_i` of
/// [`crate::scene::btf::light_weights`] (in `frames[v]`), each divided by its own mean cosine:
///
/// `L*'_{v,i,c} = sum_j w_i(D_{v,j}) (n_v . D_{v,j,c}) / cosbar_i`.
///
/// Dotted with a BTF (`b_i = f_i cosbar_i`), bin `j` contributes `f(D / |D|) (n . D_c)`: the
/// BRDF interpolated at the light's mean direction times its exact cosine. The weights sum to
/// 1, so a Lambertian BTF (constant `f`) sees exactly `sum_j n . D_{j,c}`, whatever the
/// directions. The shaders dot `L*'` with the BTF as they dot `L*`: nothing downstream changes.
///
/// With [`Lobe::BinCentre`] each bin keeps its own power: `L*'_{v,j,c} = (n_v . D_{v,j,c}) / cosbar_j`.
pub fn resolve(along: [&LocalRadiance; 3], frames: &[VertexFrame], lobe: Lobe) -> Result<LocalRadiance> {
    let basis = along[0].basis();
    let vertices = along[0].vertices();
    if along.iter().any(|a| a.basis() != basis || a.vertices() != vertices) {
        return Err(CoreError::Invalid("the three gathered moments differ in basis or vertex count".into()));
    }
    let grid = bins_and_frames(basis, vertices, frames)?;
    let inv: Vec<f32> = inverse_mean_cosines(&grid).into_iter().map(|x| x as f32).collect();
    let m = grid.len();
    let mut out = LocalRadiance::zeros(basis, vertices);
    out.values_mut().par_chunks_mut(m).zip(frames).enumerate().for_each_init(
        || Lanes::new(grid),
        |lanes, (v, (out, frame))| {
            let rows = [along[0].vertex(v), along[1].vertex(v), along[2].vertex(v)];
            lanes.redistribute(grid, frame, lobe, rows);
            for ((o, a), inv) in out.iter_mut().zip(lanes.acc()).zip(&inv) {
                *o = [a[0] * inv, a[1] * inv, a[2] * inv];
            }
        },
    );
    Ok(out)
}

/// [`resolve`] at a point between vertices: a vertex's three moments (`M` rows each,
/// world-space direction sums as the gathers give them) resolved at the point's own frame
/// instead of the vertex's. Moments are world-space, so a light that falls in different bins
/// of neighbouring vertices' frames is one direction here, handed to the bins around it in the
/// point's frame; blending rows resolved in the vertices' frames splits it between two local
/// directions.
#[derive(Clone, Debug)]
pub struct PointResolve {
    grid: HemisphereGrid,
    inverse_mean_cosine: Vec<f64>,
    lobe: Lobe,
}

impl PointResolve {
    /// The resolve on `basis`'s bins; an error unless it has bins.
    pub fn new(basis: crate::basis::LocalBasis, lobe: Lobe) -> Result<Self> {
        let grid = basis
            .grid()
            .ok_or_else(|| CoreError::Invalid(format!("light moments need a local bin basis, not {basis}")))?;
        Ok(Self { grid, inverse_mean_cosine: inverse_mean_cosines(&grid), lobe })
    }

    /// `out[i]` = `L*'_i` of the moments `along[a][j]` (`D_{j}` along world axis `a`, RGB) at
    /// `frame`, as [`resolve`] gives it for a vertex (there in f32 lanes, here in f64).
    pub fn resolve(&self, frame: &VertexFrame, along: [&[[f64; 3]]; 3], out: &mut [[f64; 3]]) {
        let d = |j: usize, c: usize| DVec3::new(along[0][j][c], along[1][j][c], along[2][j][c]);
        redistribute(self.grid, frame, self.lobe, d, out);
        for (o, inv) in out.iter_mut().zip(&self.inverse_mean_cosine) {
            *o = o.map(|x| x * inv);
        }
    }

    /// Working lanes for [`Self::resolve_lanes`] (one per thread).
    pub fn lanes(&self) -> PointLanes {
        PointLanes { lanes: Lanes::new(self.grid) }
    }

    /// [`Self::resolve`] of a vertex's stored (f32) rows of the three gathers, in the f32
    /// lanes of the vertex [`resolve`]: exactly the vertex's arithmetic (bit for bit the
    /// vertex resolve of the same rows at the same frame), several times faster than the f64
    /// form (the bins' directions are located all at once, with a polynomial arctangent).
    pub fn resolve_lanes(
        &self,
        lanes: &mut PointLanes,
        frame: &VertexFrame,
        along: [&[[f32; 3]]; 3],
        out: &mut [[f64; 3]],
    ) {
        let PointLanes { lanes } = lanes;
        lanes.redistribute(self.grid, frame, self.lobe, along);
        self.divide(lanes.acc(), out);
    }

    /// [`Self::resolve_lanes`] of vertex `v` of `moments`, laid out once per light: the same
    /// bits, without gathering and transposing the vertex's rows at every hit.
    pub fn resolve_prepared(
        &self,
        lanes: &mut PointLanes,
        frame: &VertexFrame,
        moments: &PointMoments,
        v: usize,
        out: &mut [[f64; 3]],
    ) {
        let spread = &mut lanes.lanes.spread;
        spread.spread(self.grid, frame, self.lobe, moments.vertex(v));
        self.divide(&spread.acc, out);
    }

    /// `out[i] = acc[i] / cosbar_i` (in f32, as the vertex resolve).
    fn divide(&self, acc: &[[f32; 4]], out: &mut [[f64; 3]]) {
        for ((o, a), inv) in out.iter_mut().zip(acc).zip(&self.inverse_mean_cosine) {
            let inv = *inv as f32;
            *o = [(a[0] * inv) as f64, (a[1] * inv) as f64, (a[2] * inv) as f64];
        }
    }
}

/// The working memory of [`PointResolve::resolve_lanes`]: the f32 lanes.
pub struct PointLanes {
    lanes: Lanes,
}

/// The working rows of [`resolve`] for one vertex, one f32 lane per bin (structure of arrays,
/// so that each step is one loop over the bins that the compiler vectorises).
struct Lanes {
    /// The vertex's moments as [`Spread::spread`] reads them ([`fill_block`]).
    block: Vec<f32>,
    spread: Spread,
}

/// The lanes one vertex's moments are spread through.
struct Spread {
    /// `n . D_{j,c}`, the bin's exact-cosine power per channel, and a zero fourth lane (so the
    /// scatter adds four-wide).
    power: Vec<[f32; 4]>,
    /// The luminance direction `D_j` in the vertex's local frame.
    local: [Vec<f32>; 3],
    /// Where each bin's power goes.
    cells: Cells,
    /// `sum_j w_i(D_j) (n . D_{j,c})`, before the division by `cosbar_i`.
    acc: Vec<[f32; 4]>,
}

/// Floats per bin of a vertex's block ([`fill_block`]).
const BLOCK_LANES: usize = 12;

/// One vertex's gathered rows (`rows[a][j][c]`: axis `a` of `D_{j,c}`) laid out as the spread
/// reads them, `M` floats a lane: lane `3 c + a` is `D_{j,c}` along axis `a` (nine lanes), lane
/// `9 + a` the luminance direction `sum_c Y_c D_{j,c}` along `a` (three). Each lane is read
/// front to back, so a vertex's moments stream through the cache in order.
fn fill_block(rows: [&[[f32; 3]]; 3], block: &mut [f32]) {
    let m = block.len() / BLOCK_LANES;
    let luminance = LUMINANCE.map(|y| y as f32);
    for (a, row) in rows.iter().enumerate() {
        for (j, d) in row[..m].iter().enumerate() {
            (0..3).for_each(|c| block[(3 * c + a) * m + j] = d[c]);
        }
    }
    let (moments, lum) = block.split_at_mut(9 * m);
    for (a, lum) in lum.chunks_exact_mut(m).enumerate() {
        let (r, g, b) = (&moments[a * m..][..m], &moments[(3 + a) * m..][..m], &moments[(6 + a) * m..][..m]);
        for j in 0..m {
            lum[j] = luminance[0] * r[j] + luminance[1] * g[j] + luminance[2] * b[j];
        }
    }
}

/// Every vertex's three gathered moments laid out once per light as the per-pixel resolve reads
/// them ([`fill_block`]: `12 M` floats a vertex, 48 bytes per row), so that each of a hit's
/// three resolves reads one contiguous block instead of gathering its rows from three arrays
/// and transposing them, and the luminance directions are formed once per vertex instead of
/// once per sample ([`PointResolve::resolve_prepared`]).
pub struct PointMoments {
    m: usize,
    blocks: Vec<f32>,
}

impl PointMoments {
    /// The blocks of `along` (the three gathers, same basis and vertex count: the caller's
    /// [`LocalRadiance`] checks).
    pub fn new(along: [&LocalRadiance; 3]) -> Self {
        let m = along[0].local_dirs();
        let mut blocks = vec![0.0f32; along[0].vertices() * m * BLOCK_LANES];
        blocks.par_chunks_mut(m * BLOCK_LANES).enumerate().for_each(|(v, block)| {
            fill_block([along[0].vertex(v), along[1].vertex(v), along[2].vertex(v)], block);
        });
        Self { m, blocks }
    }

    /// The bytes held per row of `L*` (the memory estimate charges them).
    pub const BYTES_PER_ROW: u64 = (BLOCK_LANES * std::mem::size_of::<f32>()) as u64;

    fn vertex(&self, v: usize) -> &[f32] {
        &self.blocks[v * self.m * BLOCK_LANES..][..self.m * BLOCK_LANES]
    }
}

impl Lanes {
    fn new(grid: HemisphereGrid) -> Self {
        let m = grid.len();
        let lanes = || [vec![0.0; m], vec![0.0; m], vec![0.0; m]];
        Self {
            block: vec![0.0; m * BLOCK_LANES],
            spread: Spread {
                power: vec![[0.0; 4]; m],
                local: lanes(),
                cells: Cells::new(grid),
                acc: vec![[0.0; 4]; m],
            },
        }
    }

    /// The sums of [`resolve`]'s redistribution (`acc`, before the division by `cosbar_i`) for
    /// the gathered rows of one vertex.
    fn redistribute(&mut self, grid: HemisphereGrid, frame: &VertexFrame, lobe: Lobe, rows: [&[[f32; 3]]; 3]) {
        fill_block(rows, &mut self.block);
        self.spread.spread(grid, frame, lobe, &self.block);
    }

    fn acc(&self) -> &[[f32; 4]] {
        &self.spread.acc
    }
}

impl Spread {
    /// [`redistribute`] in f32 for one vertex's `block` ([`fill_block`]), with the direction
    /// lookup done for all bins at once ([`Cells::locate`]) instead of one [`light_weights`]
    /// call per bin. The f32 sums round at the level of the gathered moments' own f32 storage
    /// (a few ulps of `|D_j|`), tested against the f64 form.
    ///
    /// Where the CPU has AVX2 the same loops run eight lanes wide instead of SSE2's four: no
    /// fused multiply-add is enabled, so every lane does the very IEEE operations of the
    /// four-wide build and the result is the same bit for bit (tested below); only the
    /// instruction width differs.
    fn spread(&mut self, grid: HemisphereGrid, frame: &VertexFrame, lobe: Lobe, block: &[f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the one feature the function enables was detected just above.
            return unsafe { self.spread_avx2(grid, frame, lobe, block) };
        }
        self.spread_lanes(grid, frame, lobe, block)
    }

    /// [`Self::spread`] compiled for AVX2 (no FMA: the same roundings).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn spread_avx2(&mut self, grid: HemisphereGrid, frame: &VertexFrame, lobe: Lobe, block: &[f32]) {
        self.spread_lanes(grid, frame, lobe, block)
    }

    /// The body of [`Self::spread`], inlined into each build of it.
    #[inline(always)]
    fn spread_lanes(&mut self, grid: HemisphereGrid, frame: &VertexFrame, lobe: Lobe, block: &[f32]) {
        let bins = grid.len();
        let lane = |k: usize| &block[k * bins..(k + 1) * bins];
        // The exact-cosine power in f64: near the horizon `n . D` is much smaller than `|D|`,
        // and an f32 sum would lose `eps |D| / |n . D|` of it.
        let n = frame.normal.as_dvec3();
        for c in 0..3 {
            let (dx, dy, dz) = (lane(3 * c), lane(3 * c + 1), lane(3 * c + 2));
            for (j, power) in self.power.iter_mut().enumerate() {
                power[c] = (n.x * dx[j] as f64 + n.y * dy[j] as f64 + n.z * dz[j] as f64) as f32;
            }
        }
        if lobe == Lobe::BinCentre || grid.m == 1 {
            // Every bin keeps its power; a one-bin grid has nowhere else to put it.
            self.acc.copy_from_slice(&self.power);
            return;
        }
        let (d0, d1, d2) = (lane(9), lane(10), lane(11));
        let [lx, ly, lz] = &mut self.local;
        let (t, bt, n) = (frame.tangent, frame.bitangent, frame.normal);
        for j in 0..bins {
            let d = [d0[j], d1[j], d2[j]];
            lx[j] = t.x * d[0] + t.y * d[1] + t.z * d[2];
            ly[j] = bt.x * d[0] + bt.y * d[1] + bt.z * d[2];
            lz[j] = n.x * d[0] + n.y * d[1] + n.z * d[2];
        }
        self.cells.locate(&self.local);
        self.acc.fill([0.0; 4]);
        let (m, cells) = (grid.m as usize, &self.cells);
        let [w0, w1, w2, w3] = &cells.weight;
        for (j, &power) in self.power.iter().enumerate() {
            // `corner` holds a whole number in [0, m^2 - m - 2].
            let corner = cells.corner[j] as i32 as usize;
            let acc = &mut self.acc[corner..corner + m + 2];
            for (i, w) in [(0, w0[j]), (1, w1[j]), (m, w2[j]), (m + 1, w3[j])] {
                let a = acc[i];
                acc[i] = [a[0] + w * power[0], a[1] + w * power[1], a[2] + w * power[2], a[3] + w * power[3]];
            }
        }
    }
}

/// The bilinear cell of every bin's mean direction in an `m x m` grid (`m >= 2`): the bin at
/// the cell's lower corner, and the weights of the corner, its right, upper and upper-right
/// neighbours (those of [`light_weights`]).
struct Cells {
    m: f32,
    /// Each bin's own grid coordinates, where a bin without a mean direction keeps its light.
    own: [Vec<f32>; 2],
    corner: Vec<f32>,
    weight: [Vec<f32>; 4],
}

impl Cells {
    fn new(grid: HemisphereGrid) -> Self {
        let n = grid.len();
        Self {
            m: grid.m as f32,
            own: [0, 1].map(|a| (0..grid.m * grid.m).map(|j| [j % grid.m, j / grid.m][a] as f32).collect()),
            corner: vec![0.0; n],
            weight: [vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        }
    }

    /// The cells of `local`'s directions, computed as [`HemisphereGrid::continuous_coords`]
    /// does but in f32, branch-free, with a polynomial arctangent ([`atan_unit`]), so the loop
    /// runs four or eight lanes at a time. Near the zenith the disk radius `sqrt(1 - z / |d|)`
    /// is taken as `sqrt(h^2 / (|d| (|d| + z)))` with `h^2 = x^2 + y^2`, which does not cancel.
    /// Against the f64 map the coordinates differ by a few f32 ulps of `m` (the arctangent's
    /// 1.1e-7 and rounding), tested below. A zero direction gets the bin's own coordinates
    /// (all its weight on itself), one that is not finite the zenith's.
    #[inline(always)]
    fn locate(&mut self, local: &[Vec<f32>; 3]) {
        let [w0, w1, w2, w3] = &mut self.weight;
        locate_lanes(
            self.m,
            [&local[0], &local[1], &local[2]],
            [&self.own[0], &self.own[1]],
            &mut self.corner,
            [w0, w1, w2, w3],
        );
    }
}

/// The loop of [`Cells::locate`], on slices passed as arguments: the compiler knows that
/// distinct `&mut` arguments do not overlap, so it vectorises without run-time overlap checks
/// (of which there would be too many for it across eleven arrays).
#[inline(always)]
fn locate_lanes(m: f32, local: [&[f32]; 3], own: [&[f32]; 2], corner: &mut [f32], weight: [&mut [f32]; 4]) {
    // Only arithmetic, comparisons and selects of values in the loop (no `clamp`, whose
    // assertion, and no float-to-int cast, whose saturation, keep it from vectorising; no
    // `f32::min` or `max`, whose NaN rules cost three instructions where one does: no lane
    // holds a NaN here).
    let lo = |a: f32, b: f32| if a < b { a } else { b };
    let hi = |a: f32, b: f32| if a > b { a } else { b };
    let top = m - 2.0;
    let n = corner.len();
    let (lx, ly, lz) = (&local[0][..n], &local[1][..n], &local[2][..n]);
    let (ox, oy) = (&own[0][..n], &own[1][..n]);
    let [w0, w1, w2, w3] = weight;
    let (w0, w1, w2, w3) = (&mut w0[..n], &mut w1[..n], &mut w2[..n], &mut w3[..n]);
    // The floor of `x` in `[0, 2^22]`: adding and removing 2^23 rounds it to an integer, one
    // less where that rounded up.
    let floor = |x: f32| {
        let r = (x + 8_388_608.0) - 8_388_608.0;
        r - if r > x { 1.0 } else { 0.0 }
    };
    for j in 0..n {
        let finite = (lx[j] * 0.0 == 0.0) & (ly[j] * 0.0 == 0.0) & (lz[j] * 0.0 == 0.0);
        let (x, y, z) = if finite { (lx[j], ly[j], lz[j]) } else { (0.0, 0.0, 1.0) };
        let (ax, ay) = (x.abs(), y.abs());
        let (big, small) = (hi(ax, ay), lo(ax, ay));
        // Scaled to a largest component of 1, so that squares neither overflow nor
        // underflow (moments of a sun can be large, those of a dim bin tiny).
        let largest = hi(big, z.abs());
        let scale = if largest > 0.0 { 1.0 / largest } else { 0.0 };
        let (x, y, z) = (x * scale, y * scale, z * scale);
        let h2 = x * x + y * y;
        let len = (h2 + z * z).sqrt();
        let r2 = if z > 0.0 { h2 / (len * (len + z)) } else { 1.0 };
        let r = lo(r2, 1.0).sqrt();
        let t = small / hi(big, f32::MIN_POSITIVE);
        // In the wedge |x| >= |y|: a = +-r, b = r sign(y) atan(|y| / |x|) / (pi / 4);
        // swapped in the other wedge. At the zenith (x = y = 0) both are 0, the centre. Both
        // are in [-1, 1].
        let s = r * atan_unit(t) * (4.0 / std::f32::consts::PI);
        let (a, b) = if ax >= ay { (r, s) } else { (s, r) };
        let (a, b) = if big > 0.0 { (a.copysign(x), b.copysign(y)) } else { (0.0, 0.0) };
        let coord = |a: f32| lo(hi((a + 1.0) * 0.5 * m - 0.5, 0.0), m - 1.0);
        let (own_x, own_y) = (ox[j], oy[j]);
        let k = if largest > 0.0 { 1.0 } else { 0.0 };
        let (x, y) = (k * coord(a) + (1.0 - k) * own_x, k * coord(b) + (1.0 - k) * own_y);
        // A cell starts at most at m - 2; the fractions are then in [0, 1].
        let (x0, y0) = (lo(floor(x), top), lo(floor(y), top));
        let (fx, fy) = (x - x0, y - y0);
        corner[j] = y0 * m + x0;
        w0[j] = (1.0 - fx) * (1.0 - fy);
        w1[j] = fx * (1.0 - fy);
        w2[j] = (1.0 - fx) * fy;
        w3[j] = fx * fy;
    }
}

/// `atan(t)` for `t` in `[0, 1]`: an odd polynomial of degree 15 fitted near-minimax on the
/// interval; its error with f32 evaluation is at most 1.2e-7 (tested against f64 `atan`).
#[inline(always)]
fn atan_unit(t: f32) -> f32 {
    const C: [f32; 8] = [
        0.999_999_34,
        -0.333_298_62,
        0.199_465_66,
        -0.139_086_3,
        0.096_421_994,
        -0.055_912_334,
        0.021_862_954,
        -0.004_054_564_5,
    ];
    let s = t * t;
    let mut p = C[7];
    for c in C[..7].iter().rev() {
        p = p * s + c;
    }
    t * p
}

/// Hand each bin's exact-cosine power `n . D` (`d(j, c)` = `D_{j,c}`, world space) to the light
/// bins around its mean direction, with [`light_weights`] in `frame`: `acc[i][c]` is
/// `sum_j w_i(D_j) (n . D_{j,c})`, before the division by `cosbar_i`. One direction per bin, the
/// luminance's (`D_j = sum_c Y_c D_{j,c}`, Rec. 709 weights), serves all three channels: a
/// bin's colours rarely come from directions a bilinear weight could tell apart, and one
/// lookup per bin instead of three keeps the resolve cheaper than the gather. A bin whose
/// luminance direction vanishes keeps its light (the bin-centre rule). This is the f64 form,
/// one [`light_weights`] call per bin, used by the reference [`exact_moments_product`];
/// [`resolve`] does the same with the lookup of all of a vertex's bins in f32 lanes
/// ([`Lanes::redistribute`]).
fn redistribute(
    grid: HemisphereGrid,
    frame: &VertexFrame,
    lobe: Lobe,
    d: impl Fn(usize, usize) -> DVec3,
    acc: &mut [[f64; 3]],
) {
    acc.fill([0.0; 3]);
    let n = frame.normal.as_dvec3();
    for j in 0..grid.len() {
        let d = [d(j, 0), d(j, 1), d(j, 2)];
        let power = d.map(|d| n.dot(d));
        if power == [0.0; 3] {
            continue;
        }
        if lobe == Lobe::BinCentre {
            acc[j] = power;
            continue;
        }
        let direction = d[0] * LUMINANCE[0] + d[1] * LUMINANCE[1] + d[2] * LUMINANCE[2];
        if direction == DVec3::ZERO {
            (0..3).for_each(|c| acc[j][c] += power[c]);
            continue;
        }
        for (i, w) in light_weights(grid, frame.to_local(direction.as_vec3())) {
            (0..3).for_each(|c| acc[i][c] += w as f64 * power[c]);
        }
    }
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
    gather_keeping_moments(compressor, form, moments, frames).map(|(lstar, _)| lstar)
}

/// [`gather_with_moments`], and the three gathered moments it resolved (what a per-pixel
/// resolve, `biscale_shading::cpu::shade_moments`, shades).
pub fn gather_keeping_moments(
    compressor: &dyn Compressor,
    form: &CompressedForm,
    moments: &LightMoments,
    frames: &[VertexFrame],
) -> std::result::Result<(LocalRadiance, [LocalRadiance; 3]), CompressError> {
    let [x, y, z] = &moments.along;
    let gathered = compressor.gather_three(form, [x, y, z])?;
    let lstar = resolve([&gathered[0], &gathered[1], &gathered[2]], frames, moments.lobe)
        .map_err(|e| CompressError::External(Box::new(e)))?;
    Ok((lstar, gathered))
}

/// Every row's exact-cosine light in f64: for every row `(v, j)`,
/// `sum_k T[j, k] L_k (n_v . d_k) / cosbar_j`, each texel with its own cosine, and without the
/// redistribution of [`resolve`]. `sum_j cosbar_j` times it is the irradiance at vertex `v`;
/// dotted with a Lambertian BTF it equals [`exact_moments_product`] (the weights sum to 1).
pub fn exact_cosine_product(t: &TransferMatrix, light: &LightVector, frames: &[VertexFrame]) -> Result<Vec<[f64; 3]>> {
    let grid = t_light_and_frames(t, light, frames)?;
    let directions = mean_directions(light)?;
    let inv = inverse_mean_cosines(&grid);
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
                let l = light.power[k];
                for c in 0..3 {
                    acc[c] += value as f64 * n.dot(directions[k][c]) * inv[j] * l[c] as f64;
                }
            }
            acc
        })
        .collect())
}

/// The f64 reference of [`resolve`] after the moments gather: every row's `D_{v,j}` summed in
/// f64 per texel straight from `T` (`sum_k T[j, k] L_k d_k`), then redistributed over the bins
/// around its direction as [`resolve`] does. Rows in `T`'s order.
pub fn exact_moments_product(
    t: &TransferMatrix,
    light: &LightVector,
    frames: &[VertexFrame],
    lobe: Lobe,
) -> Result<Vec<[f64; 3]>> {
    let grid = t_light_and_frames(t, light, frames)?;
    let directions = mean_directions(light)?;
    let inv = inverse_mean_cosines(&grid);
    let m = grid.len();
    let csr = t.csr();
    let mut out = vec![[0.0f64; 3]; csr.rows()];
    out.par_chunks_mut(m).zip(frames).enumerate().for_each(|(v, (out, frame))| {
        let sums: Vec<[DVec3; 3]> = (0..m)
            .map(|j| {
                let mut d = [DVec3::ZERO; 3];
                for (k, &value) in csr.outer_view(v * m + j).expect("row in range").iter() {
                    for c in 0..3 {
                        d[c] += value as f64 * light.power[k][c] as f64 * directions[k][c];
                    }
                }
                d
            })
            .collect();
        redistribute(grid, frame, lobe, |j, c| sums[j][c], out);
        for (i, o) in out.iter_mut().enumerate() {
            *o = o.map(|x| x * inv[i]);
        }
    });
    Ok(out)
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
        for m in [1, 4, 8] {
            resolved_moments_match_on_grid(&mut rng, Cubemap::new(8), HemisphereGrid::new(m));
        }
    }

    fn resolved_moments_match_on_grid(rng: &mut ChaCha8Rng, cube: Cubemap, grid: HemisphereGrid) {
        let frames = random_frames(40, rng);
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
            let fast = resolve([&gathered[0], &gathered[1], &gathered[2]], &frames, Lobe::MeanDirection).unwrap();
            let exact = exact_moments_product(&t, &light, &frames, Lobe::MeanDirection).unwrap();
            let err = relative_l2_error(fast.values(), &exact);
            // Per row the terms n . d_k have either sign (random T puts texels below the
            // horizon too), so cancellation can amplify rounding; the bilinear weights move by
            // about m times the direction's relative rounding. 1e-5 is 100 f32 ulps.
            assert!(err < 1e-5, "stiff {stiff}: relative error {err:e}");
            // Bin-centre lobe: every bin keeps its exact-cosine power, the per-texel product.
            let centre = resolve([&gathered[0], &gathered[1], &gathered[2]], &frames, Lobe::BinCentre).unwrap();
            let err = relative_l2_error(centre.values(), &exact_cosine_product(&t, &light, &frames).unwrap());
            assert!(err < 1e-5, "stiff {stiff}, bin-centre lobe: relative error {err:e}");
            // Lambertian invariant: the redistribution keeps every vertex's irradiance
            // `sum_i cosbar_i L*'_i`, the per-texel exact-cosine sum (weights sum to 1).
            let cosine = exact_cosine_product(&t, &light, &frames).unwrap();
            let m = grid.len();
            for v in 0..40 {
                for c in 0..3 {
                    let irradiance = |row: &dyn Fn(usize) -> f64| -> f64 {
                        (0..m).map(|j| grid.bin_mean_cosine(j as u32) * row(v * m + j)).sum()
                    };
                    let (a, b) = (irradiance(&|r| exact[r][c]), irradiance(&|r| cosine[r][c]));
                    let scale = (0..m).map(|j| cosine[v * m + j][c].abs()).sum::<f64>();
                    // The four f32 weights sum to 1 up to a few f32 roundings (4 ulps, 5e-7).
                    assert!((a - b).abs() <= 5e-7 * scale, "vertex {v} channel {c}: {a} vs {b}");
                }
            }
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

    /// A one-pixel sun 3 degrees above the horizon of an open vertex, splatted from a lat-long
    /// map: with the texel's mean direction the irradiance ([`exact_cosine_product`] summed
    /// over bins) is the sun's own, `P (n . s)` with `s` the pixel's direction, to the pixel's
    /// size; with the texel's centre (`with_centre_directions`) it is off by the centre's
    /// height above the horizon, tens of percent at this sun. The moments' resolve agrees with
    /// the f64 product either way.
    #[test]
    fn a_low_sun_off_its_texel_centre_gets_its_own_direction() {
        use crate::sampling::envmap::{latlong_direction, EnvMap};
        let (cube, grid) = (Cubemap::new(32), HemisphereGrid::new(8));
        let f = VertexFrame::from_normal(Vec3::Y);
        let t = open_sky_t(cube, grid, &f);
        let (w, h) = (2048, 1024);
        let mut env = EnvMap::constant(w, h, [0.0; 3]);
        // Row 494 of 1024: 3.5 degrees above the horizon, off its texel's centre.
        let (x, y) = (700, 494);
        env.pixels[y * w + x] = [5e4; 3];
        let light = LightVector::from_env(&env, cube, 0.0);
        let sun = latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
        let k = cube.texel_of(sun.as_vec3());
        let power = light.power[k][0] as f64;
        let irradiance = |l: &LightVector| {
            let e = exact_cosine_product(&t, l, &[f]).unwrap();
            (0..grid.len()).map(|j| grid.bin_mean_cosine(j as u32) * e[j][0]).sum::<f64>()
        };
        let want = power * sun.y;
        let (mean, centre) = (irradiance(&light), irradiance(&light.clone().with_centre_directions()));
        // The pixel spans 0.18 degrees: its sine at 3.5 degrees is known to about 3%.
        assert!((mean / want - 1.0).abs() < 0.03, "mean direction: {mean} against {want}");
        assert!((centre / want - 1.0).abs() > 0.1, "the centre must be off for this test: {centre} vs {want}");
        let moments = LightMoments::new(&light).unwrap();
        let along = moments.along.each_ref().map(|a| gather_dense(&t, a));
        let resolved = resolve([&along[0], &along[1], &along[2]], &[f], Lobe::BinCentre).unwrap();
        let reference = exact_moments_product(&t, &light, &[f], Lobe::BinCentre).unwrap();
        for (a, b) in resolved.values().iter().zip(&reference) {
            assert!((a[0] as f64 - b[0]).abs() <= 1e-4 * b[0].abs().max(1.0), "{a:?} vs {b:?}");
        }
    }

    /// `T L` in f32, by the plain CSR product (the gather every form reproduces).
    fn gather_dense(t: &TransferMatrix, light: &LightVector) -> LocalRadiance {
        LocalRadiance::from_f64(t.local_basis(), t.vertices(), &reference_product(t, light)).unwrap()
    }

    /// A single bright texel lights an open vertex: its bin's mean direction is the texel's own,
    /// so a BTF whose BRDF is linear in the grid coordinates, `f = a + b x + c y`, is
    /// interpolated exactly, and `sum_i b_i L*'_i` must equal `f(d_k) cos_k P` (bilinear weights
    /// reproduce linear functions). The bin-centre rule gives `f(d_j)` instead: the test
    /// checks the two differ, so it would notice a lobe left at the bin centre.
    #[test]
    fn the_lobe_is_evaluated_at_the_lights_direction() {
        let (cube, grid) = (Cubemap::new(32), HemisphereGrid::new(8));
        let f = VertexFrame::from_normal(Vec3::new(0.3, 1.0, -0.2).normalize());
        let t = open_sky_t(cube, grid, &f);
        let brdf = |x: f64, y: f64| 2.0 + 0.25 * x - 0.125 * y;
        let btf: Vec<f64> = (0..grid.len() as u32)
            .map(|i| brdf((i % grid.m) as f64, (i / grid.m) as f64) * grid.bin_mean_cosine(i))
            .collect();
        let (mut checked, mut moved) = (0, 0.0f64);
        for k in (0..cube.texel_count()).step_by(7) {
            let local = f.to_local(cube.texel_direction(k));
            let Some(j) = grid.bin_of(local) else { continue };
            let (x, y) = grid.continuous_coords(local);
            let (power, cos_k) = (3e5, cube.texel_direction_f64(k).dot(f.normal.as_dvec3()));
            let mut light = vec![[0.0f32; 3]; cube.texel_count()];
            light[k] = [power as f32; 3];
            let light = LightVector::new(LightBasis::Cubemap(cube), light).unwrap();
            let moments = LightMoments::new(&light).unwrap();
            let gathered = moments
                .along
                .clone()
                .map(|l| LocalRadiance::from_f64(LocalBasis::Bins(grid), 1, &reference_product(&t, &l)).unwrap());
            let lstar = resolve([&gathered[0], &gathered[1], &gathered[2]], &[f], Lobe::MeanDirection).unwrap();
            let shaded: f64 = (0..grid.len()).map(|i| btf[i] * lstar.values()[i][0] as f64).sum();
            let want = brdf(x as f64, y as f64) * cos_k * power;
            // f32 storage of the moments and of L*' (a few 1e-7 relative), the f32 grid
            // coordinates (1e-7 of 8) in the weights.
            assert!((shaded - want).abs() < 2e-6 * want, "texel {k}: {shaded} vs {want}");
            let j = j as f64;
            let centre = brdf(j % 8.0, (j / 8.0).floor()) * cos_k * power;
            moved = moved.max((centre - want).abs() / want);
            // The bin-centre lobe gives exactly that.
            let lstar = resolve([&gathered[0], &gathered[1], &gathered[2]], &[f], Lobe::BinCentre).unwrap();
            let shaded: f64 = (0..grid.len()).map(|i| btf[i] * lstar.values()[i][0] as f64).sum();
            assert!((shaded - centre).abs() < 2e-6 * centre, "texel {k}, bin centre: {shaded} vs {centre}");
            checked += 1;
        }
        assert!(checked > 100, "{checked} texels above the plane checked");
        assert!(moved > 0.05, "the bin centre's BRDF differs from the texel's by up to {moved}");
    }

    /// The polynomial arctangent against f64 `atan` on a dense grid of `[0, 1]`: the fit's own
    /// error is 3.8e-8 and the f32 Horner evaluation adds about one ulp of the result (6e-8
    /// below pi / 4), so 1.5e-7 bounds it (measured 1.12e-7).
    #[test]
    fn the_polynomial_arctangent_is_within_its_bound() {
        let worst = (0..=1 << 20)
            .map(|i| {
                let t = i as f32 / (1 << 20) as f32;
                (atan_unit(t) as f64 - (t as f64).atan()).abs()
            })
            .fold(0.0, f64::max);
        assert!(worst < 1.5e-7, "worst error {worst:e}");
    }

    /// The vectorised lookup of the resolve against [`light_weights`] (the f64 concentric map,
    /// rounded to f32 coordinates) on random directions, below the horizon too, and on the
    /// cases that need care: near the zenith, on the axes and the wedge diagonals, tiny and
    /// huge vectors (the lookup of their unit direction), a zero vector (which keeps its bin)
    /// and non-finite ones (the zenith, as `light_weights` takes them). Bound: the f32 chain
    /// loses a few ulps in the square point `(a, b)` (square roots, divisions) plus the
    /// arctangent's 1.5e-7, about 3e-7 in all, and
    /// the coordinates `(a + 1) m / 2` scale it by `m / 2`; the f64 path rounds its
    /// coordinates to f32 (6e-8 m). A bilinear weight moves by at most the sum of the two
    /// coordinates' errors, so `6e-7 m` bounds the difference of any weight.
    #[test]
    fn the_vectorised_lookup_matches_the_f64_one() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for m in [2u32, 3, 8, 16] {
            let grid = HemisphereGrid::new(m);
            let mut cells = Cells::new(grid);
            let n = grid.len();
            let special = [
                Vec3::Z,
                Vec3::new(1e-4, -2e-4, 1.0),
                Vec3::new(-3e-7, 1e-7, 0.5),
                Vec3::X,
                Vec3::new(0.0, -1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.3),
                Vec3::new(-1.0, 1.0, -0.3),
                Vec3::new(0.5, -0.5, 0.0),
                Vec3::new(1e-30, 2e-30, 3e-30),
                Vec3::new(-3e30, 1e30, 2e30),
                Vec3::new(0.0, 0.0, -1.0),
            ];
            let (mut checked, mut worst) = (0, 0.0f32);
            for round in 0..300 {
                let mut dirs: Vec<Vec3> = (0..n)
                    .map(|_| Vec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-0.3..1.0)))
                    .collect();
                if round == 0 {
                    for (d, s) in dirs.iter_mut().zip(special) {
                        *d = s;
                    }
                }
                if round == 1 {
                    dirs[0] = Vec3::ZERO;
                    dirs[n - 1] = Vec3::ZERO;
                    dirs[n / 2] = Vec3::new(f32::NAN, 0.0, 1.0);
                    dirs[1] = Vec3::new(0.0, f32::INFINITY, 1.0);
                }
                let local = [0, 1, 2].map(|a| dirs.iter().map(|d| d[a]).collect::<Vec<f32>>());
                cells.locate(&local);
                for (j, d) in dirs.iter().enumerate() {
                    let mut got = vec![0.0f32; n];
                    let c = cells.corner[j] as usize;
                    for (k, off) in [0, 1, m as usize, m as usize + 1].into_iter().enumerate() {
                        got[c + off] += cells.weight[k][j];
                    }
                    let mut want = vec![0.0f32; n];
                    if *d == Vec3::ZERO {
                        want[j] = 1.0;
                    } else {
                        // The unit direction: `light_weights` takes a vector whose square
                        // underflows as the zenith, the lanes scale it first.
                        let unit = if d.is_finite() { d.as_dvec3().normalize().as_vec3() } else { *d };
                        for (i, w) in light_weights(grid, unit) {
                            want[i] += w;
                        }
                    }
                    let e = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                    assert!(e <= 6e-7 * m as f32, "m {m}, direction {d}: weights {got:?} against {want:?}");
                    worst = worst.max(e);
                    checked += 1;
                }
            }
            assert!(checked == 300 * n, "{checked}");
            eprintln!("m {m}: worst weight difference {worst:e}");
        }
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

    /// The per-point resolve of a vertex's own moments at its own frame is the vertex resolve
    /// (f64 against f32 lanes: 1e-5 relative covers the lanes' rounding and their atan fit).
    #[test]
    fn a_point_resolve_at_a_vertex_is_the_vertex_resolve() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let basis = LocalBasis::bins(8).unwrap();
        let m = basis.len();
        let frames = random_frames(30, &mut rng);
        let along: Vec<LocalRadiance> = (0..3)
            .map(|_| {
                let values = (0..30 * m).map(|_| [0, 1, 2].map(|_| rng.gen_range(-1.0f32..1.0))).collect();
                LocalRadiance::new(basis, 30, values).unwrap()
            })
            .collect();
        let prepared = PointMoments::new([&along[0], &along[1], &along[2]]);
        for lobe in [Lobe::MeanDirection, Lobe::BinCentre] {
            let vertex = resolve([&along[0], &along[1], &along[2]], &frames, lobe).unwrap();
            let point = PointResolve::new(basis, lobe).unwrap();
            let mut lanes = point.lanes();
            let mut out = vec![[0.0f64; 3]; m];
            for (v, frame) in frames.iter().enumerate() {
                let rows: Vec<Vec<[f64; 3]>> =
                    along.iter().map(|a| a.vertex(v).iter().map(|x| x.map(f64::from)).collect()).collect();
                point.resolve(frame, [&rows[0], &rows[1], &rows[2]], &mut out);
                let scale = out.iter().flatten().fold(0.0f64, |a, x| a.max(x.abs())).max(1e-12);
                for (o, w) in out.iter().zip(vertex.vertex(v)) {
                    for c in 0..3 {
                        assert!((o[c] - w[c] as f64).abs() <= 1e-5 * scale, "{lobe:?} vertex {v}: {o:?} vs {w:?}");
                    }
                }
                // The lanes are the vertex resolve's own arithmetic: bit for bit, and so are the
                // moments laid out once per light.
                point.resolve_lanes(&mut lanes, frame, [0, 1, 2].map(|a| along[a].vertex(v)), &mut out);
                for (o, w) in out.iter().zip(vertex.vertex(v)) {
                    assert_eq!(o.map(|x| x as f32), *w, "{lobe:?} vertex {v}, lanes");
                }
                let mut again = vec![[0.0f64; 3]; m];
                point.resolve_prepared(&mut lanes, frame, &prepared, v, &mut again);
                assert_eq!(again, out, "{lobe:?} vertex {v}, prepared");
            }
        }
        assert!(PointResolve::new(LocalBasis::sh(3).unwrap(), Lobe::MeanDirection).is_err());
    }

    /// The lanes built for AVX2 (eight wide, no FMA) give the very bits of the SSE2 build's
    /// four, on random moments and on stiff ones (zero, tiny, huge, below the horizon, not
    /// finite), at grids 2 to 16: only the width differs.
    #[test]
    fn the_wide_lanes_give_the_same_bits_as_the_narrow_ones() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for m in [2u32, 3, 8, 16] {
            let grid = HemisphereGrid::new(m);
            let n = grid.len();
            let frames = random_frames(8, &mut rng);
            for (k, frame) in frames.iter().enumerate() {
                let rows: [Vec<[f32; 3]>; 3] = std::array::from_fn(|_| {
                    (0..n)
                        .map(|j| {
                            [0, 1, 2].map(|_| match (k + j) % 7 {
                                0 => 0.0,
                                1 => rng.gen_range(-1e-30f32..1e-30),
                                2 => rng.gen_range(-1e30f32..1e30),
                                3 if j % 5 == 0 => f32::NAN,
                                _ => rng.gen_range(-1.0f32..1.0),
                            })
                        })
                        .collect()
                });
                let rows = [&rows[0][..], &rows[1][..], &rows[2][..]];
                for lobe in [Lobe::MeanDirection, Lobe::BinCentre] {
                    let (mut wide, mut narrow) = (Lanes::new(grid), Lanes::new(grid));
                    wide.redistribute(grid, frame, lobe, rows);
                    fill_block(rows, &mut narrow.block);
                    narrow.spread.spread_lanes(grid, frame, lobe, &narrow.block);
                    let bits = |l: &Lanes| l.acc().iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&wide), bits(&narrow), "m = {m}, frame {k}, {lobe:?}");
                }
            }
        }
    }
}
