//! The directions every visibility query shares, and the per-point kernel that turns one
//! point's ray queries into its transfer entries (docs/DESIGN.md section 3).
//!
//! For a point with frame F and a coarse texel k whose centre `d_k` lies above F's tangent
//! plane, the kernel traces k's `s x s` children of the visibility cubemap and emits the
//! number that are unoccluded, with the local bin `j` of `F.to_local(d_k)`. Two ways decide
//! which children are occluded ([`Visibility`]), with the same answers:
//!
//! * **Coverage** (the default): per cube face (up to 64 x 64 fine texels), the children above
//!   the horizon are the open bits of a coverage mask, and the triangles the face can see are
//!   rasterised into it front to back with texel-centre sampling, skipping whatever is
//!   already covered (`SceneBvh::cover_tile`, `geometry::bvh::coverage`).
//! * **Rays**: rays are grouped in tiles of nearby texels (in Morton order within the tile): a
//!   tile below the horizon is skipped, and otherwise one cone query lists the triangles its
//!   rays could hit. A short list (usually none or a few) is tested eight triangles at a time;
//!   a tile with a long one traces its rays through the BVH in packets
//!   (`SceneBvh::occluded_packet`).

use crate::geometry::bvh::{Cone, CoverScratch, FaceTile, RayDir, TileTriangles, MAX_TILE, PACKET};
use crate::geometry::{SceneBvh, VertexFrame};
use crate::sampling::cubemap::face_point;
use crate::sampling::{Cubemap, HemisphereGrid};
use crate::transfer::{TransferSettings, Visibility};
use glam::{Vec3, Vec3A};

/// Directions shared by every point's visibility query: coarse texel centres, their
/// children in the visibility cubemap, and the local grid.
pub struct VisibilitySampler {
    pub settings: TransferSettings,
    pub cubemap: Cubemap,
    pub grid: HemisphereGrid,
    coarse_dirs: Vec<Vec3>,
    /// Children of coarse texel k: `fine_dirs[k * s^2 .. (k + 1) * s^2]`.
    fine_dirs: Vec<Vec3>,
    /// `fine_dirs` with reciprocals, as the BVH traversal wants them.
    fine_rays: Vec<RayDir>,
    s2: usize,
    /// Tiles of `TILE x TILE` coarse texels (ragged at face edges): a cone containing all
    /// their children's directions, and their texels in `tile_texels[range]`.
    tiles: Vec<(Cone, std::ops::Range<usize>)>,
    tile_texels: Vec<u32>,
    /// The longest candidate list a tile tests directly ([`BRUTE_FORCE_MAX`]); a longer one
    /// traces the tile's rays through the BVH. Both paths give the same answers: the tests
    /// set 0 or `usize::MAX` to send every tile with candidates down one of them.
    pub(crate) brute_force_max: usize,
    /// The coverage test's tiles (up to [`MAX_TILE`] fine texels square: a whole face at the
    /// reference settings; none when one coarse texel's children are wider): the face
    /// rectangle with its cone, and where its texels' `(coarse texel, fine ray)` and
    /// directions start in `raster_rays` and `raster_dirs` (row-major).
    raster: Vec<(FaceTile, usize)>,
    raster_rays: Vec<(u32, u32)>,
    raster_dirs: Vec<Vec3A>,
    /// How a tile's rays are answered: rasterised into its coverage mask
    /// ([`Visibility::Coverage`], the default) or traced ([`Visibility::Rays`]).
    pub visibility: Visibility,
}

/// Side of a tile in fine texels (about): tiles of `16 / s` coarse texels, 256 rays (at most
/// a cube face: its cone's half-angle, 54.7 degrees, keeps the cone test's `a + b < pi`).
const TILE_FINE: usize = 16;

/// A tile whose cone query returns more candidates than this traces its rays through the
/// BVH instead of testing the list. Tuned with the eight-lane list test
/// (`SceneBvh::occluded_in_tile`), 2 threads under load, interleaved: tiles of 8 fine
/// texels and a cap of 96 (the best before that test) against 16 and 192 took 70.6 / 66.0 s
/// against 58.9 / 62.5 s on the 30k-vertex bunny at the reference settings, 2.39 against
/// 2.01 s (1 thread) on the bunny; 16 with 96 and 384 were in between, and the tiny setting
/// (one tile per face) is the same either way. With the BVH path traced in packets, a cap of
/// 96 was slower again (24.6 / 26.4 s against 23.2 / 24.4 s on the 30k-vertex bunny).
pub(crate) const BRUTE_FORCE_MAX: usize = 192;

/// Per-thread scratch state of [`VisibilitySampler::point_counts`], reset by every query (so
/// results never depend on which thread, or which earlier query, used it).
#[derive(Clone, Debug, Default)]
pub struct VisibilityScratch {
    /// Unoccluded children per coarse texel.
    visible: Vec<u16>,
    /// Candidate occluders of the current tile, and the same prepared for its rays.
    candidates: Vec<u32>,
    tile: TileTriangles,
    /// The current tile's rays above the horizon: (coarse texel, fine ray index).
    tile_rays: Vec<(u32, u32)>,
    /// The coverage walk's stack.
    cover: CoverScratch,
}

/// A cone containing every direction of `dirs`: the axis is their normalised mean, the
/// half-angle the largest angle to one of them, computed in f64 and widened by 1e-5 rad so
/// the f32 tests stay conservative.
fn bounding_cone(dirs: &[Vec3A]) -> Cone {
    let axis = dirs.iter().map(|d| glam::Vec3::from(*d).as_dvec3()).sum::<glam::DVec3>().normalize();
    let max_angle = dirs
        .iter()
        .map(|d| glam::Vec3::from(*d).as_dvec3().normalize().dot(axis).clamp(-1.0, 1.0).acos())
        .fold(0.0, f64::max)
        + 1e-5;
    Cone { axis: axis.as_vec3().into(), cos: max_angle.cos() as f32, sin: max_angle.sin() as f32 }
}

/// The Z-order index of `(row, col)`: their bits interleaved.
fn morton(row: usize, col: usize) -> u64 {
    (0..32).map(|b| ((row as u64 >> b & 1) << (2 * b + 1)) | ((col as u64 >> b & 1) << (2 * b))).sum()
}

impl VisibilitySampler {
    pub fn new(settings: &TransferSettings) -> Self {
        let cubemap = settings.cubemap();
        let fine = Cubemap::new(settings.visibility_resolution());
        let s = settings.supersampling() as usize;
        let coarse_dirs = (0..cubemap.texel_count()).map(|k| cubemap.texel_direction(k)).collect();
        let mut fine_dirs = Vec::with_capacity(fine.texel_count());
        for k in 0..cubemap.texel_count() {
            let (face, row, col) = cubemap.texel_coords(k);
            for a in 0..s {
                for b in 0..s {
                    fine_dirs.push(fine.texel_direction(fine.texel_index(face, row * s + a, col * s + b)));
                }
            }
        }
        // Tiles and their cones. The cone axis is the normalised mean of the children's
        // directions; the half-angle the largest angle to one of them, computed in f64 and
        // widened by 1e-5 rad so the f32 tests stay conservative.
        let r = cubemap.resolution as usize;
        let t = (TILE_FINE / s).max(1);
        let mut tiles = vec![];
        let mut tile_texels = vec![];
        for face in 0..6 {
            for r0 in (0..r).step_by(t) {
                for c0 in (0..r).step_by(t) {
                    let start = tile_texels.len();
                    let mut sum = glam::DVec3::ZERO;
                    for row in r0..(r0 + t).min(r) {
                        for col in c0..(c0 + t).min(r) {
                            let k = cubemap.texel_index(face, row, col);
                            tile_texels.push(k as u32);
                            sum +=
                                fine_dirs[k * s * s..(k + 1) * s * s].iter().map(|d| d.as_dvec3()).sum::<glam::DVec3>();
                        }
                    }
                    // Texels in Morton order within the tile, so consecutive texels (and the
                    // packets of rays the BVH path cuts from them) are compact blocks.
                    tile_texels[start..].sort_by_key(|&k| {
                        let (_, row, col) = cubemap.texel_coords(k as usize);
                        morton(row - r0, col - c0)
                    });
                    let dirs: Vec<Vec3A> = tile_texels[start..]
                        .iter()
                        .flat_map(|&k| &fine_dirs[k as usize * s * s..(k as usize + 1) * s * s])
                        .map(|&d| Vec3A::from(d))
                        .collect();
                    tiles.push((bounding_cone(&dirs), start..tile_texels.len()));
                }
            }
        }
        // Coverage tiles: blocks of up to MAX_TILE x MAX_TILE fine texels (a whole face at the
        // reference settings), whole coarse texels each; none when a coarse texel's children
        // alone are wider (the rays path serves those settings).
        let (mut raster, mut raster_rays, mut raster_dirs) = (vec![], vec![], vec![]);
        let tc = MAX_TILE / s;
        for face in (0..6).filter(|_| tc > 0) {
            let w = face_point(face, 0.0, 0.0);
            let (a, b) = (face_point(face, 1.0, 0.0) - w, face_point(face, 0.0, 1.0) - w);
            for r0 in (0..r).step_by(tc) {
                for c0 in (0..r).step_by(tc) {
                    let (rows, cols) = (((r0 + tc).min(r) - r0) * s, ((c0 + tc).min(r) - c0) * s);
                    let start = raster_rays.len();
                    for row in r0 * s..r0 * s + rows {
                        for col in c0 * s..c0 * s + cols {
                            let k = cubemap.texel_index(face, row / s, col / s);
                            let f = k * s * s + (row % s) * s + col % s;
                            raster_rays.push((k as u32, f as u32));
                            raster_dirs.push(Vec3A::from(fine_dirs[f]));
                        }
                    }
                    let tile = FaceTile {
                        cone: bounding_cone(&raster_dirs[start..]),
                        w: w.as_vec3().into(),
                        a: a.as_vec3().into(),
                        b: b.as_vec3().into(),
                        res: (r * s) as u32,
                        row0: (r0 * s) as u32,
                        col0: (c0 * s) as u32,
                        rows: rows as u32,
                        cols: cols as u32,
                    };
                    raster.push((tile, start));
                }
            }
        }
        Self {
            tiles,
            tile_texels,
            raster,
            raster_rays,
            raster_dirs,
            visibility: settings.visibility(),
            brute_force_max: BRUTE_FORCE_MAX,
            settings: *settings,
            cubemap,
            grid: settings.local_grid(),
            coarse_dirs,
            fine_rays: fine_dirs.iter().map(|d| RayDir::new(*d)).collect(),
            fine_dirs,
            s2: s * s,
        }
    }

    /// Transfer entries of one shading point at `origin` (already offset off the surface)
    /// with frame `frame`: calls `emit(j, k, value)` for every non-zero, in increasing `k`.
    /// Returns the number of rays traced.
    pub fn point_entries(
        &self,
        bvh: &SceneBvh,
        origin: Vec3,
        frame: &VertexFrame,
        mut emit: impl FnMut(u32, u32, f32),
    ) -> u64 {
        let inv = 1.0 / self.s2 as f32;
        let mut scratch = VisibilityScratch::default();
        self.point_counts(bvh, origin, frame, &mut scratch, |j, k, c| emit(j, k, c as f32 * inv))
    }

    /// [`Self::point_entries`] with the number of unoccluded children (`1..=s^2`) instead of
    /// the fraction, and caller-owned scratch.
    pub fn point_counts(
        &self,
        bvh: &SceneBvh,
        origin: Vec3,
        frame: &VertexFrame,
        scratch: &mut VisibilityScratch,
        mut emit: impl FnMut(u32, u32, u32),
    ) -> u64 {
        // Same answers as `point_entries_reference`: each path adds every coarse texel's
        // unoccluded children above the horizon to `visible`.
        scratch.visible.clear();
        scratch.visible.resize(self.coarse_dirs.len(), 0);
        let n = frame.normal;
        let rays = if self.visibility == Visibility::Coverage && !self.raster.is_empty() {
            self.cover_counts(bvh, origin.into(), n, scratch)
        } else {
            self.trace_counts(bvh, origin.into(), n, scratch)
        };
        let visible = &scratch.visible;
        for (k, &count) in visible.iter().enumerate() {
            if count == 0 {
                continue;
            }
            let Some(j) = self.grid.bin_of(frame.to_local(self.coarse_dirs[k])) else {
                continue;
            };
            emit(j, k as u32, count as u32);
        }
        rays
    }

    /// Is fine ray `f` of coarse texel `k` one the point with normal `n` decides? Both it and
    /// its coarse texel's centre must be above the tangent plane (the rule of
    /// `point_entries_reference`); both fast paths ask this one question.
    #[inline]
    fn above_horizon(&self, k: usize, f: usize, n: Vec3) -> bool {
        self.coarse_dirs[k].dot(n) > 0.0 && self.fine_dirs[f].dot(n) > 0.0
    }

    /// [`Visibility::Rays`]'s answers for the point at `o` with normal `n`, tile by tile: a
    /// tile whose cone lies below the horizon is skipped; otherwise one cone query lists the
    /// triangles its rays could hit (above the tangent plane, inside the cone), usually none
    /// or a few, and its rays are tested against that list (or through the BVH if it is
    /// long). Adds each coarse texel's unoccluded children above the horizon to
    /// `scratch.visible`; returns the rays traced.
    fn trace_counts(&self, bvh: &SceneBvh, o: Vec3A, n: Vec3, scratch: &mut VisibilityScratch) -> u64 {
        let n_a = Vec3A::from(n);
        let VisibilityScratch { visible, candidates, tile, tile_rays, .. } = scratch;
        let mut rays = 0u64;
        let mut cache = u32::MAX;
        for (cone, texels) in &self.tiles {
            // All directions of the tile are within its cone.
            if cone.below(n_a) {
                continue;
            }
            // The tile's rays above the horizon: (coarse texel, fine ray).
            tile_rays.clear();
            for &k in &self.tile_texels[texels.clone()] {
                let k = k as usize;
                for f in k * self.s2..(k + 1) * self.s2 {
                    if self.above_horizon(k, f, n) {
                        tile_rays.push((k as u32, f as u32));
                    }
                }
            }
            if tile_rays.is_empty() {
                continue;
            }
            candidates.clear();
            let brute = bvh.cone_candidates(o, n_a, cone, candidates, self.brute_force_max);
            rays += tile_rays.len() as u64;
            if brute {
                bvh.prepare_tile(o, candidates, tile);
                if tile.is_empty() {
                    for &(k, _) in tile_rays.iter() {
                        visible[k as usize] += 1;
                    }
                    continue;
                }
                for &(k, f) in tile_rays.iter() {
                    let occluded = bvh.occluded_in_tile(o, &self.fine_rays[f as usize], tile, &mut cache);
                    visible[k as usize] += !occluded as u16;
                }
            } else {
                for packet in tile_rays.chunks(PACKET) {
                    let dirs: [&RayDir; PACKET] =
                        std::array::from_fn(|i| &self.fine_rays[packet[i.min(packet.len() - 1)].1 as usize]);
                    let occluded = bvh.occluded_packet(o, &dirs[..packet.len()], &mut cache);
                    for (i, &(k, _)) in packet.iter().enumerate() {
                        visible[k as usize] += (occluded >> i & 1 == 0) as u16;
                    }
                }
            }
        }
        rays
    }

    /// [`Visibility::Coverage`]'s answers for the point at `o` with normal `n`: adds each
    /// coarse texel's unoccluded children above the horizon to `scratch.visible`; returns the
    /// rays decided (those above the horizon).
    fn cover_counts(&self, bvh: &SceneBvh, o: Vec3A, n: Vec3, scratch: &mut VisibilityScratch) -> u64 {
        let n_a = Vec3A::from(n);
        let VisibilityScratch { visible, cover, .. } = scratch;
        let mut rays = 0u64;
        for (tile, start) in &self.raster {
            if tile.cone.below(n_a) {
                continue;
            }
            // The tile's rays above the horizon are its open texels; what stays open after
            // the coverage test is unoccluded.
            let (rows, cols) = (tile.rows as usize, tile.cols as usize);
            let texel_rays = &self.raster_rays[*start..start + rows * cols];
            let mut open = [0u64; MAX_TILE];
            if tile.cone.above(n_a) {
                // Every direction of the tile (coarse centres included: each lies in the
                // cone of its children) is above the horizon.
                open[..rows].fill(u64::MAX >> (64 - cols));
            } else {
                for (row, mask) in open[..rows].iter_mut().enumerate() {
                    for (col, &(k, f)) in texel_rays[row * cols..(row + 1) * cols].iter().enumerate() {
                        *mask |= (self.above_horizon(k as usize, f as usize, n) as u64) << col;
                    }
                }
            }
            let count: u32 = open[..rows].iter().map(|m| m.count_ones()).sum();
            if count == 0 {
                continue;
            }
            rays += count as u64;
            let dirs = &self.raster_dirs[*start..start + rows * cols];
            bvh.cover_tile(o, n_a, tile, dirs, &mut open[..rows], cover);
            for (row, &mask) in open[..rows].iter().enumerate() {
                let mut bits = mask;
                while bits != 0 {
                    let col = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    visible[texel_rays[row * cols + col].0 as usize] += 1;
                }
            }
        }
        rays
    }

    /// The plain definition, kept as the reference the fast paths are tested against
    /// (rays start at `geometry::bvh::RAY_TMIN`, see there).
    #[cfg(test)]
    pub(crate) fn point_entries_reference(
        &self,
        bvh: &SceneBvh,
        origin: Vec3,
        frame: &VertexFrame,
        mut emit: impl FnMut(u32, u32, f32),
    ) -> u64 {
        let n = frame.normal;
        let mut rays = 0u64;
        let inv = 1.0 / self.s2 as f32;
        for (k, d) in self.coarse_dirs.iter().enumerate() {
            if d.dot(n) <= 0.0 {
                continue;
            }
            let Some(j) = self.grid.bin_of(frame.to_local(*d)) else {
                continue;
            };
            let mut visible = 0u32;
            for c in &self.fine_dirs[k * self.s2..(k + 1) * self.s2] {
                if c.dot(n) <= 0.0 {
                    continue;
                }
                rays += 1;
                if !bvh.occluded(origin, *c, crate::geometry::bvh::RAY_TMIN, f32::INFINITY) {
                    visible += 1;
                }
            }
            if visible > 0 {
                emit(j, k as u32, visible as f32 * inv);
            }
        }
        rays
    }
}
