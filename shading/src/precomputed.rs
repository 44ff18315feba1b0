//! Shading LPCA BTFs under a fixed light from precomputed dot products (Müller et al. 2004,
//! carried over to the all-frequency `L*`).
//!
//! An LPCA BTF's value for view sample `e_v` of texel `u` is `sum_c a_c E_kc(e_v)` (cluster `k`
//! of the unit, `a = (1, weights)`, [`LpcaBtf`]). The pixel integral is linear in `L*`, and `L*`
//! is interpolated barycentrically from the triangle's vertices `p_i`, so
//!
//! `B = sum_v w_v sum_c a_c sum_i beta_i (E_kc(e_v) . L*_{p_i})`.
//!
//! For a fixed light the dot products `lambda(p, k, c, s) = E_kc[s] . L*_p` (per channel; `s`
//! the segment of the clustered vector holding the view: the view itself for per-texel units,
//! 0 for per-view units) are computed once per vertex ([`LightDots::new`]); a pixel then costs
//! `3 x 4 x (C + 1)` multiply-adds whatever the number of light bins `M`, against `3 M` to
//! interpolate `L*` plus `4 M (C + 1)` to evaluate the BTF directly.
//!
//! The table has `vertices x K x (C + 1) x S` RGB entries per material, `S = V` for per-texel
//! units and `S = 1` per view: per-view units keep it small (the dot products do not depend on
//! the view), per-texel units make it `V` times larger. [`LightDots::bytes_needed`] says how
//! big it is before anything is allocated, and [`LightDots::new`] refuses a request above
//! its limit with that estimate. Only the vertices of a material's own triangles get rows.
//! Dense materials in the same scene are shaded directly ([`crate::cpu::shade_point`]).
//!
//! Precision: the dot products accumulate in f64 and are stored in f32 (one rounding each);
//! the pixel sum accumulates in f64.

use crate::cpu::{interpolate_lstar, render_rows, shade_point, SurfacePoint};
use crate::error::{Result, ShadingError};
use biscale_core::gather::LocalRadiance;
use biscale_core::scene::{BtfRepresentation, Camera, LpcaBtf, Render, ShadeScene};
use biscale_core::Rgb;
use rayon::prelude::*;

/// No row: the vertex is not on a triangle of the material.
const NO_ROW: u32 = u32::MAX;

/// The dot products of one LPCA material (module docs).
#[derive(Debug)]
struct MaterialDots {
    /// Row of each scene vertex, or [`NO_ROW`].
    rows: Vec<u32>,
    /// `[row][k][c][s]`, RGB.
    dots: Vec<[f32; 3]>,
    clusters: usize,
    components: usize,
    segments: usize,
}

/// The precomputed dot products of every LPCA material of a scene for one `L*` (module docs).
#[derive(Debug)]
pub struct LightDots {
    /// One per scene material; `None` for a dense one.
    materials: Vec<Option<MaterialDots>>,
}

/// For each material, whether each scene vertex lies on one of its triangles.
fn material_vertices(scene: &ShadeScene) -> Vec<Vec<bool>> {
    let n = scene.mesh().vertex_count();
    let mut used = vec![vec![false; n]; scene.materials().len()];
    for (t, tri) in scene.mesh().triangles.iter().enumerate() {
        let i = scene.material_index(t as u32);
        for &v in tri {
            used[i][v as usize] = true;
        }
    }
    used
}

/// RGB entries of one vertex's row of an LPCA material.
fn row_entries(l: &LpcaBtf) -> u64 {
    (l.clusters() * (l.components() + 1) * l.segments_per_unit()) as u64
}

impl LightDots {
    /// Bytes the tables of `scene` take (12 per RGB entry, plus 4 per vertex and LPCA material
    /// for the row index), before anything is computed.
    pub fn bytes_needed(scene: &ShadeScene) -> u64 {
        let used = material_vertices(scene);
        let n = scene.mesh().vertex_count() as u64;
        scene
            .materials()
            .iter()
            .zip(&used)
            .map(|(m, u)| match &m.btf {
                BtfRepresentation::Dense(_) => 0,
                BtfRepresentation::Lpca(l) => {
                    let rows = u.iter().filter(|&&x| x).count() as u64;
                    rows.saturating_mul(row_entries(l)).saturating_mul(12).saturating_add(4 * n)
                }
            })
            .fold(0u64, u64::saturating_add)
    }

    /// The dot products of every LPCA material with `lstar` (module docs). Errors when `L*`
    /// does not fit the scene, or when the tables would take more than `max_bytes`
    /// (the message gives the estimate and the setting that makes it).
    pub fn new(scene: &ShadeScene, lstar: &LocalRadiance, max_bytes: u64) -> Result<Self> {
        scene.check_lstar(lstar)?;
        let need = Self::bytes_needed(scene);
        if need > max_bytes {
            let lpca: Vec<String> = scene
                .materials()
                .iter()
                .filter_map(|m| match &m.btf {
                    BtfRepresentation::Lpca(l) => Some(format!(
                        "'{}': {} clusters x {} vectors x {} segment(s)",
                        l.name(),
                        l.clusters(),
                        l.components() + 1,
                        l.segments_per_unit()
                    )),
                    BtfRepresentation::Dense(_) => None,
                })
                .collect();
            return Err(ShadingError::Invalid(format!(
                "precomputed LPCA dot products need {:.1} MB ({}; per vertex of each material), over the limit of {:.1} MB; \
                 per-view units (unit = \"view\") need one segment instead of one per view",
                need as f64 * 1e-6,
                lpca.join(", "),
                max_bytes as f64 * 1e-6
            )));
        }
        let used = material_vertices(scene);
        let m = lstar.local_dirs();
        let values = lstar.values();
        let materials = scene
            .materials()
            .iter()
            .zip(&used)
            .map(|(mat, used)| {
                let BtfRepresentation::Lpca(l) = &mat.btf else { return None };
                let mut rows = vec![NO_ROW; used.len()];
                let mut vertices = vec![];
                for (v, _) in used.iter().enumerate().filter(|(_, &u)| u) {
                    rows[v] = vertices.len() as u32;
                    vertices.push(v);
                }
                let (k, c, s) = (l.clusters(), l.components(), l.segments_per_unit());
                let per_row = k * (c + 1) * s;
                let mut dots = vec![[0.0f32; 3]; vertices.len() * per_row];
                dots.par_chunks_mut(per_row.max(1)).zip(&vertices).for_each(|(row, &v)| {
                    let lv = &values[v * m..(v + 1) * m];
                    for (i, out) in row.iter_mut().enumerate() {
                        let (kk, cc, ss) = (i / ((c + 1) * s), (i / s) % (c + 1), i % s);
                        let e = l.segment(kk, cc, ss);
                        let mut acc = [0.0f64; 3];
                        for (ej, lj) in e.chunks_exact(3).zip(lv) {
                            for ch in 0..3 {
                                acc[ch] += ej[ch] as f64 * lj[ch] as f64;
                            }
                        }
                        *out = acc.map(|x| x as f32);
                    }
                });
                Some(MaterialDots { rows, dots, clusters: k, components: c, segments: s })
            })
            .collect();
        Ok(Self { materials })
    }

    /// Bytes the tables hold.
    pub fn bytes(&self) -> u64 {
        self.materials.iter().flatten().map(|d| (d.dots.len() * 12 + d.rows.len() * 4) as u64).sum()
    }

    /// `B` at one shading point of an LPCA material `material` from the dot products; `None`
    /// for a dense material (shade it directly).
    pub fn shade_point(&self, scene: &ShadeScene, material: usize, p: &SurfacePoint) -> Option<Rgb> {
        let dots = self.materials[material].as_ref()?;
        let mat = &scene.materials()[material];
        let BtfRepresentation::Lpca(l) = &mat.btf else { return None };
        let texel = mat.btf.texel_of(p.uv * mat.tiling);
        let (c1, s) = (dots.components + 1, dots.segments);
        let mut acc = [0.0f64; 3];
        for (view, wv) in biscale_core::scene::btf::view_weights(l.view_grid(), p.view_local) {
            if wv == 0.0 {
                continue;
            }
            let (unit, seg) = l.unit_of(texel, view);
            let Some(k) = l.cluster_of(unit) else { continue };
            let w = l.unit_weights(unit);
            for (&v, &beta) in p.vertices.iter().zip(&p.weights) {
                let row = dots.rows[v as usize];
                if row == NO_ROW {
                    continue;
                }
                let base = ((row as usize * dots.clusters + k) * c1) * s + seg;
                let scale = wv as f64 * beta as f64;
                for c in 0..c1 {
                    let a = if c == 0 { 1.0 } else { w[c - 1] as f64 };
                    let d = dots.dots[base + c * s];
                    for ch in 0..3 {
                        acc[ch] += scale * a * d[ch] as f64;
                    }
                }
            }
        }
        Some(acc.map(|x| x as f32))
    }
}

/// Shade the scene from the precomputed dot products of `dots` (LPCA materials) and `lstar`
/// (dense materials, shaded directly): the same image as [`crate::cpu::shade`] up to the
/// rounding of the stored dot products.
pub fn shade_precomputed(
    scene: &ShadeScene,
    dots: &LightDots,
    lstar: &LocalRadiance,
    camera: &Camera,
) -> Result<Render> {
    camera.validate()?;
    scene.check_lstar(lstar)?;
    if dots.materials.len() != scene.materials().len() {
        return Err(ShadingError::Invalid(format!(
            "dot products of {} materials for a scene of {}",
            dots.materials.len(),
            scene.materials().len()
        )));
    }
    Ok(render_rows(scene, camera, &|| {}, &|p, acc, scratch| {
        let material = scene.material_index(p.triangle);
        if let Some(b) = dots.shade_point(scene, material, p) {
            return b;
        }
        interpolate_lstar(p, lstar, acc);
        shade_point(scene.material(p.triangle), p.uv, p.view_local, acc, scratch)
    }))
}

#[cfg(test)]
mod tests;
