//! Cube-map environments: a cross image (horizontal 4:3 or vertical 3:4) or six face files,
//! read into biscale's own cubemap layout ([`EnvLayout::Cube`]); their background lookup; and
//! their light vector, integrated exactly over every cubemap texel.
//!
//! **Convention read: OpenGL's** (the major-axis table of `GL_TEXTURE_CUBE_MAP`), a face
//! image's column 0 at `s = 0` and row 0 (the first row stored) at `t = 0`, as faces are
//! handed to `glTexImage2D` and as cmft and AMD CubeMapGen write them. With `sc = 2s - 1`,
//! `tc = 2t - 1`, the direction through `(s, t)` is
//! `+X (1, -tc, -sc)`, `-X (-1, -tc, sc)`, `+Y (sc, 1, tc)`, `-Y (sc, -1, -tc)`,
//! `+Z (sc, -tc, 1)`, `-Z (-sc, -tc, -1)`: exactly biscale's own layout (docs/DESIGN.md
//! section 3, column = s, row = t). So faces are taken over texel for texel, never resampled:
//! `px nx py ny pz nz` (+X -X +Y -Y +Z -Z) are biscale faces 0..5. (In +Y-up right-handed
//! world coordinates a face seen from inside the cube is mirrored, as in OpenGL itself.)
//!
//! Cross layouts, in cells of `F x F` texels (unused cells are ignored):
//! ```text
//!  horizontal, 4F x 3F       vertical, 3F x 4F
//!       +Y                        +Y
//!   -X  +Z  +X  -Z            -X  +Z  +X
//!       -Y                        -Y
//!                                 -Z   (turned 180 degrees)
//! ```
//! Six files: a file name holding `{face}` (`sky_{face}.exr`) names the six files with
//! `{face}` replaced by `px nx py ny pz nz`; they must be square and of one size.
//!
//! **The light vector.** `L_k`, the power through biscale texel `k`, is the integral of the
//! input's radiance over the texel. Input texels are constant over squares of the same face
//! plane, so each adds its radiance times the exact solid angle (the four-corner formula) of
//! its overlap with the texel: an exact integral for any two resolutions (when the input's is
//! a multiple of biscale's, an exact box average of whole input texels with their solid
//! angles). A rotated map no longer lines up with the texels, so it is splatted like a
//! lat-long one: each input texel cut into `s x s` sub-texels, each with its exact solid
//! angle, into the texel its rotated centre falls in.

use super::cubemap::{face_coords, face_point, rect_solid_angle, FACE_NAMES};
use super::envmap::{rotate_y, EnvLayout, EnvMap};
use super::Cubemap;
use crate::error::{CoreError, Result};
use crate::Rgb;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What `{face}` becomes in a face file name, in biscale's face order (+X -X +Y -Y +Z -Z).
pub const FACE_TAGS: [&str; 6] = ["px", "nx", "py", "ny", "pz", "nz"];

/// The placeholder of a six-file cube map's file name.
pub const FACE_PLACEHOLDER: &str = "{face}";

/// Cell `(column, row)` of each face (biscale order) in a horizontal and a vertical cross,
/// and whether the face is turned 180 degrees there.
const HORIZONTAL: [(usize, usize, bool); 6] =
    [(2, 1, false), (0, 1, false), (1, 0, false), (1, 2, false), (1, 1, false), (3, 1, false)];
const VERTICAL: [(usize, usize, bool); 6] =
    [(2, 1, false), (0, 1, false), (1, 0, false), (1, 2, false), (1, 1, false), (1, 3, true)];

/// The six face files of `pattern` when its file name holds [`FACE_PLACEHOLDER`].
pub fn face_paths(pattern: &Path) -> Option<[PathBuf; 6]> {
    let name = pattern.file_name()?.to_str()?;
    if !name.contains(FACE_PLACEHOLDER) {
        return None;
    }
    Some(FACE_TAGS.map(|tag| pattern.with_file_name(name.replace(FACE_PLACEHOLDER, tag))))
}

/// Whether a `width x height` image is a cross: 4:3 or 3:4.
pub fn is_cross(width: usize, height: usize) -> bool {
    3 * width == 4 * height || 4 * width == 3 * height
}

/// Where texel `i` of a cube map with `f x f` faces is, for messages.
pub(crate) fn texel_place(f: usize, i: usize) -> String {
    let f = f.max(1);
    format!("face {} texel (col {}, row {})", FACE_NAMES[(i / (f * f)).min(5)], i % f, (i / f) % f)
}

/// A cube map from a cross image `img` (4:3 or 3:4), checked as [`EnvMap::load`] says;
/// pixels are named by their place in the cross.
pub(crate) fn from_cross(img: &EnvMap, path: &Path) -> Result<(EnvMap, Vec<String>)> {
    let (w, h) = (img.width, img.height);
    let (f, cells, kind) = match (3 * w == 4 * h, 4 * w == 3 * h) {
        (true, _) => (w / 4, &HORIZONTAL, "horizontal"),
        (_, true) => (w / 3, &VERTICAL, "vertical"),
        _ => {
            return Err(CoreError::Input {
                path: path.into(),
                message: format!("a {w}x{h} image is not a cube-map cross (4:3 or 3:4)"),
            })
        }
    };
    // The cross pixel (x, y) of face texel (face, row, col).
    let source = |face: usize, row: usize, col: usize| {
        let (cx, cy, turned) = cells[face];
        let (r, c) = if turned { (f - 1 - row, f - 1 - col) } else { (row, col) };
        (cx * f + c, cy * f + r)
    };
    let mut pixels = Vec::with_capacity(6 * f * f);
    for face in 0..6 {
        for row in 0..f {
            for col in 0..f {
                let (x, y) = source(face, row, col);
                pixels.push(img.pixels[y * w + x]);
            }
        }
    }
    let mut env = EnvMap { width: f, height: 6 * f, pixels, layout: EnvLayout::Cube };
    let place = |i: usize| {
        let (x, y) = source(i / (f * f), (i / f) % f, i % f);
        format!("pixel (x={x}, y={y}) ({kind} cross, {})", texel_place(f, i))
    };
    let warnings = env.check_radiance(path, &place)?;
    Ok((env, warnings))
}

/// A cube map from six face files (`faces` in biscale's order, made from `pattern`).
pub(crate) fn load_faces(pattern: &Path, faces: &[PathBuf; 6]) -> Result<(EnvMap, Vec<String>)> {
    let mut pixels = Vec::new();
    let mut warnings = Vec::new();
    let mut size: Option<(usize, &Path)> = None;
    for (k, path) in faces.iter().enumerate() {
        let err = |message: String| CoreError::Input { path: path.clone(), message };
        if let Err(e) = crate::io::check_regular(path).map_err(|e| (e.kind(), e.to_string())) {
            if e.0 != std::io::ErrorKind::NotFound {
                return Err(err(format!("cube face {}: {}", FACE_NAMES[k], e.1)));
            }
            return Err(err(format!(
                "cube face {} (`{}` of {}) not found: a six-file cube map needs {}",
                FACE_NAMES[k],
                FACE_TAGS[k],
                pattern.display(),
                FACE_TAGS.join(", ")
            )));
        }
        let mut img = EnvMap::read_image(path)?;
        if img.width == 0 || img.width != img.height {
            return Err(err(format!("cube face {} must be square, got {}x{}", FACE_NAMES[k], img.width, img.height)));
        }
        match size {
            None => size = Some((img.width, path)),
            Some((f, first)) if f != img.width => {
                return Err(err(format!(
                    "cube face {} is {w}x{w} but face {} ({}) is {f}x{f}: the six faces must be of one size",
                    FACE_NAMES[k],
                    FACE_NAMES[0],
                    first.display(),
                    w = img.width
                )))
            }
            Some(_) => {}
        }
        let w = img.width;
        warnings.extend(img.check_radiance(path, &|i| format!("pixel (x={}, y={})", i % w, i / w))?);
        pixels.append(&mut img.pixels);
    }
    let f = size.map_or(0, |s| s.0);
    Ok((EnvMap { width: f, height: 6 * f, pixels, layout: EnvLayout::Cube }, warnings))
}

/// Radiance of the cube map `env` in world direction `d`, the map rotated by `rotation`
/// radians about +Y: bilinear between texel centres within a face, clamped at its edges
/// (exact for a constant map).
pub(crate) fn radiance(env: &EnvMap, d: Vec3, rotation: f64) -> Rgb {
    let f = env.width;
    let (face, a, b) = face_coords(rotate_y(d.as_dvec3(), -rotation));
    let texel = |t: f64| ((t + 1.0) * 0.5 * f as f64 - 0.5).clamp(0.0, (f - 1) as f64);
    let (x, y) = (texel(a), texel(b));
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let (x1, y1) = ((x0 + 1).min(f - 1), (y0 + 1).min(f - 1));
    let p = |r: usize, c: usize| env.pixels[(face * f + r) * f + c];
    let (p00, p01, p10, p11) = (p(y0, x0), p(y0, x1), p(y1, x0), p(y1, x1));
    let lerp = |x: f32, y: f32, t: f32| x + (y - x) * t;
    std::array::from_fn(|i| lerp(lerp(p00[i], p01[i], fx), lerp(p10[i], p11[i], fx), fy))
}

/// Integral of the piecewise-constant cube map over the sphere, per channel.
pub(crate) fn total_power(env: &EnvMap) -> [f64; 3] {
    let cube = Cubemap::new(env.width as u32);
    let mut s = [0.0f64; 3];
    for (k, p) in env.pixels.iter().enumerate() {
        let w = cube.texel_solid_angle(k);
        for c in 0..3 {
            s[c] += p[c] as f64 * w;
        }
    }
    s
}

/// `L` (power per texel of `cubemap`, its order) of the cube map `env` rotated by `rotation`.
pub(crate) fn light_power(env: &EnvMap, cubemap: Cubemap, rotation: f64) -> Vec<Rgb> {
    let power = if rotation == 0.0 { exact_power(env, cubemap) } else { splat_power(env, cubemap, rotation) };
    power.iter().map(|p| p.map(|c| c as f32)).collect()
}

/// Exact overlap integration (no rotation: input and texels share their face planes).
fn exact_power(env: &EnvMap, cubemap: Cubemap) -> Vec<[f64; 3]> {
    let (f, r) = (env.width, cubemap.resolution as usize);
    // On an axis of `f * r` units, input texel i spans [i r, (i+1) r] and biscale texel j
    // spans [j f, (j+1) f]: their overlaps, found in integers, as face coordinates.
    let scale = 2.0 / (f * r) as f64;
    let spans: Vec<Vec<(usize, f64, f64)>> = (0..f)
        .map(|i| {
            let (lo, hi) = (i * r, (i + 1) * r);
            (lo / f..=(hi - 1) / f)
                .map(|j| (j, lo.max(j * f) as f64 * scale - 1.0, hi.min((j + 1) * f) as f64 * scale - 1.0))
                .collect()
        })
        .collect();
    let mut power = vec![[0.0f64; 3]; cubemap.texel_count()];
    power.par_chunks_mut(r * r).enumerate().for_each(|(face, out)| {
        let input = &env.pixels[face * f * f..(face + 1) * f * f];
        for (row, rows) in spans.iter().enumerate() {
            for (col, cols) in spans.iter().enumerate() {
                let p = input[row * f + col];
                if p == [0.0; 3] {
                    continue;
                }
                for &(tr, b0, b1) in rows {
                    for &(tc, a0, a1) in cols {
                        let w = rect_solid_angle(a0, a1, b0, b1);
                        let o = &mut out[tr * r + tc];
                        for c in 0..3 {
                            o[c] += p[c] as f64 * w;
                        }
                    }
                }
            }
        }
    });
    power
}

/// Splatting of sub-texels with exact solid angles (a rotated map).
fn splat_power(env: &EnvMap, cubemap: Cubemap, rotation: f64) -> Vec<[f64; 3]> {
    let (f, n) = (env.width, cubemap.texel_count());
    // Sub-texels small against a biscale texel (a sixteenth of its edge, or the input texel).
    let s = (16 * cubemap.resolution as usize).div_ceil(f).max(1);
    let step = 2.0 / (f * s) as f64;
    (0..6 * f)
        .into_par_iter()
        .fold(
            || vec![[0.0f64; 3]; n],
            |mut acc, face_row| {
                let (face, row) = (face_row / f, face_row % f);
                for col in 0..f {
                    let p = env.pixels[(face * f + row) * f + col];
                    if p == [0.0; 3] {
                        continue;
                    }
                    for sy in 0..s {
                        let b0 = (row * s + sy) as f64 * step - 1.0;
                        for sx in 0..s {
                            let a0 = (col * s + sx) as f64 * step - 1.0;
                            let omega = rect_solid_angle(a0, a0 + step, b0, b0 + step);
                            let d: DVec3 = rotate_y(face_point(face, a0 + 0.5 * step, b0 + 0.5 * step), rotation);
                            let o = &mut acc[cubemap.texel_of(d.as_vec3())];
                            for c in 0..3 {
                                o[c] += p[c] as f64 * omega;
                            }
                        }
                    }
                }
                acc
            },
        )
        .reduce(|| vec![[0.0f64; 3]; n], super::envmap::add_power)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::envmap::latlong_direction;
    use crate::sampling::LightVector;
    use std::f64::consts::PI;

    /// The test sky: smooth, and asymmetric in every axis, so a mirrored or turned face shows.
    fn sky(d: DVec3) -> Rgb {
        let f = (1.0 + d.x + 2.0 * d.y * d.y) as f32;
        [f, 2.0 * f, 0.5 * f]
    }
    /// Bounds of [`sky`]'s first channel: its largest value (`x + 2 y^2` peaks at 2.125, at
    /// `x = 1/4`) and its largest gradient, `|(1, 4y, 0)| <= sqrt(17)`.
    const SKY_MAX: f64 = 3.125;
    const SKY_GRADIENT: f64 = 4.123_105_625_617_661;

    /// The direction through `(s, t)` of a face, written out from the OpenGL specification's
    /// cube map table (independently of biscale's own `face_point`).
    fn gl_direction(face: usize, s: f64, t: f64) -> DVec3 {
        let (sc, tc) = (2.0 * s - 1.0, 2.0 * t - 1.0);
        match FACE_TAGS[face] {
            "px" => DVec3::new(1.0, -tc, -sc),
            "nx" => DVec3::new(-1.0, -tc, sc),
            "py" => DVec3::new(sc, 1.0, tc),
            "ny" => DVec3::new(sc, -1.0, -tc),
            "pz" => DVec3::new(sc, -tc, 1.0),
            _ => DVec3::new(-sc, -tc, -1.0),
        }
        .normalize()
    }

    fn latlong(h: usize, fun: impl Fn(DVec3) -> Rgb) -> EnvMap {
        let w = 2 * h;
        let pixels = (0..w * h)
            .map(|i| fun(latlong_direction(((i % w) as f64 + 0.5) / w as f64, ((i / w) as f64 + 0.5) / h as f64)))
            .collect();
        EnvMap { width: w, height: h, pixels, layout: EnvLayout::LatLong }
    }

    /// A face image of `f x f` texels, sampled at texel centres.
    fn face_image(face: usize, f: usize, fun: &impl Fn(DVec3) -> Rgb) -> Vec<Rgb> {
        (0..f * f)
            .map(|i| fun(gl_direction(face, ((i % f) as f64 + 0.5) / f as f64, ((i / f) as f64 + 0.5) / f as f64)))
            .collect()
    }

    /// A cross image as a file holds it; the cells no face uses are filled with `-7`.
    fn cross(f: usize, vertical: bool, fun: impl Fn(DVec3) -> Rgb) -> EnvMap {
        let (w, h) = if vertical { (3 * f, 4 * f) } else { (4 * f, 3 * f) };
        let mut pixels = vec![[-7.0; 3]; w * h];
        // The layouts as drawn in the module docs, by face tag.
        let cells: [(&str, usize, usize); 6] = match vertical {
            false => [("py", 1, 0), ("nx", 0, 1), ("pz", 1, 1), ("px", 2, 1), ("nz", 3, 1), ("ny", 1, 2)],
            true => [("py", 1, 0), ("nx", 0, 1), ("pz", 1, 1), ("px", 2, 1), ("ny", 1, 2), ("nz", 1, 3)],
        };
        for (tag, cx, cy) in cells {
            let face = FACE_TAGS.iter().position(|t| *t == tag).unwrap();
            let img = face_image(face, f, &fun);
            for row in 0..f {
                for col in 0..f {
                    // -Z below -Y in the vertical cross is turned 180 degrees.
                    let (r, c) = if vertical && tag == "nz" { (f - 1 - row, f - 1 - col) } else { (row, col) };
                    pixels[(cy * f + r) * w + cx * f + c] = img[row * f + col];
                }
            }
        }
        EnvMap { width: w, height: h, pixels, layout: EnvLayout::LatLong }
    }

    fn cube_of(img: &EnvMap) -> EnvMap {
        let (env, warnings) = from_cross(img, Path::new("cross.exr")).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        env
    }

    /// `L_k` of [`sky`] by fine quadrature: 32 x 32 sub-squares of each texel, each its exact
    /// solid angle times the value at its centre (error about `(1/(32 R))^2`, negligible here).
    fn sky_integral(cubemap: Cubemap) -> Vec<f64> {
        let (r, n) = (cubemap.resolution as usize, 32usize);
        let step = 2.0 / (r * n) as f64;
        (0..cubemap.texel_count())
            .map(|k| {
                let (face, row, col) = cubemap.texel_coords(k);
                let mut s = 0.0;
                for i in 0..n {
                    for j in 0..n {
                        let (a0, b0) = ((col * n + j) as f64 * step - 1.0, (row * n + i) as f64 * step - 1.0);
                        let d = face_point(face, a0 + 0.5 * step, b0 + 0.5 * step).normalize();
                        s += sky(d)[0] as f64 * rect_solid_angle(a0, a0 + step, b0, b0 + step);
                    }
                }
                s
            })
            .collect()
    }

    /// A cross of the analytic sky gives the light vector of the lat-long map of the same sky,
    /// texel by texel, within a tolerance derived from the two discretisations: each map is
    /// the sky sampled at pixel centres, so it is within `G rho` of the sky everywhere (`G`
    /// the sky's largest gradient, `rho` the largest angular radius of a pixel: `sqrt(2)/F` for
    /// a cube texel of `2/F` face units, `pi/(sqrt(2) H)` for a lat-long pixel). The cube map is
    /// integrated exactly over each texel: its error is at most `Omega_k G rho_F`. The lat-long
    /// map is splatted in sub-pixels of radius `delta = pi/(sqrt(2) H s)`; those within
    /// `delta` of the texel's border (perimeter at most `8/R`) may land on the wrong side, at
    /// most `max f (2 delta P + 4 pi delta^2)` more. Both are checked against the sky's own
    /// integral, and so against each other.
    #[test]
    fn a_cross_gives_the_light_vector_of_the_latlong_map_of_the_same_sky() {
        let (r, f, h) = (8usize, 32usize, 512usize);
        let cubemap = Cubemap::new(r as u32);
        let truth = sky_integral(cubemap);
        let ll = LightVector::from_env(&latlong(h, sky), cubemap, 0.0);
        let s = 4usize.max((16 * r).div_ceil(h)) as f64;
        let (rho_f, rho_h) = (2f64.sqrt() / f as f64, PI / (2f64.sqrt() * h as f64));
        let delta = rho_h / s;
        let band = SKY_MAX * (2.0 * delta * 8.0 / r as f64 + 4.0 * PI * delta * delta);
        for vertical in [false, true] {
            let cube = LightVector::from_env(&cube_of(&cross(f, vertical, sky)), cubemap, 0.0);
            let (mut worst_cube, mut worst_ll) = (0f64, 0f64);
            for k in 0..cubemap.texel_count() {
                let omega = cubemap.texel_solid_angle(k);
                let tol_cube = omega * SKY_GRADIENT * rho_f;
                let tol_ll = omega * SKY_GRADIENT * rho_h + band;
                let (c, l) = (cube.power[k][0] as f64, ll.power[k][0] as f64);
                assert!((c - truth[k]).abs() <= tol_cube, "texel {k}: cross {c} vs {} (tol {tol_cube})", truth[k]);
                assert!((l - truth[k]).abs() <= tol_ll, "texel {k}: lat-long {l} vs {} (tol {tol_ll})", truth[k]);
                assert!((c - l).abs() <= tol_cube + tol_ll, "texel {k}: cross {c} vs lat-long {l}");
                // The channels keep their ratios (2 and 0.5).
                assert!((cube.power[k][1] as f64 - 2.0 * c).abs() <= 1e-5 * c.abs().max(1e-6), "texel {k}");
                worst_cube = worst_cube.max((c - truth[k]).abs() / tol_cube);
                worst_ll = worst_ll.max((l - truth[k]).abs() / tol_ll);
            }
            // The bounds are first order; the errors are second order, far inside them (about
            // 0.6% and 5% of them).
            assert!(worst_cube < 0.1 && worst_ll < 0.5, "used {worst_cube} and {worst_ll} of the tolerances");
        }
    }

    /// Total power: the light vector holds exactly the cube map's integral (the texels
    /// partition every input texel), and that converges to the sky's analytic integral
    /// `4 pi (1 + 2/3)` at second order (pixel-centre sampling is a midpoint rule): four times
    /// the resolution, at least eight times closer.
    #[test]
    fn total_power_is_the_integral_of_the_sky() {
        let exact = 4.0 * PI * (1.0 + 2.0 / 3.0);
        let mut errors = vec![];
        for f in [8, 32] {
            let env = cube_of(&cross(f, false, sky));
            let total = env.total_power();
            for r in [4u32, 6, 8] {
                let l = LightVector::from_env(&env, Cubemap::new(r), 0.0).total();
                for c in 0..3 {
                    assert!((l[c] - total[c]).abs() <= 1e-6 * total[c], "F={f} R={r}: {l:?} vs {total:?}");
                }
            }
            // First order bound (as in the texel test), then the measured error.
            let error = (total[0] - exact).abs();
            assert!(error <= 4.0 * PI * SKY_GRADIENT * 2f64.sqrt() / f as f64, "F={f}: {} vs {exact}", total[0]);
            errors.push(error);
        }
        assert!(errors[1] * 8.0 < errors[0], "not second order: {errors:?}");
        assert!(errors[1] < 1e-3 * exact, "{errors:?}");
    }

    /// A small bright spot lands in the same texel from a cross (either), a lat-long map and
    /// six faces, and a rotation moves it to where the rotated direction falls.
    #[test]
    fn a_bright_spot_lands_in_its_texel() {
        let d0 = DVec3::new(0.35, 0.55, -0.76).normalize();
        let spot = move |d: DVec3| if d.dot(d0) > (2.0f64).to_radians().cos() { [1000.0; 3] } else { [0.0; 3] };
        let cubemap = Cubemap::new(8);
        let brightest =
            |l: &LightVector| (0..l.len()).max_by(|&a, &b| l.power[a][0].total_cmp(&l.power[b][0])).unwrap();
        let want = cubemap.texel_of(d0.as_vec3());
        let ll = latlong(1024, spot);
        for (name, env) in [
            ("latlong", ll.clone()),
            ("h-cross", cube_of(&cross(64, false, spot))),
            ("v-cross", cube_of(&cross(64, true, spot))),
        ] {
            for rotation in [0.0, 0.7, -2.0] {
                let l = LightVector::from_env(&env, cubemap, rotation);
                let at = cubemap.texel_of(rotate_y(d0, rotation).as_vec3());
                assert_eq!(brightest(&l), at, "{name} rotated by {rotation}");
                // The spot's power (2 pi (1 - cos 2 deg) 1000, about 3.83) is all there.
                let cap = 2.0 * PI * (1.0 - 2f64.to_radians().cos()) * 1000.0;
                assert!((l.total()[0] - cap).abs() < 0.05 * cap, "{name}: {} vs {cap}", l.total()[0]);
            }
            assert_eq!(brightest(&LightVector::from_env(&env, cubemap, 0.0)), want);
        }
    }

    #[test]
    fn six_faces_equal_the_cross_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let f = 12;
        for (k, tag) in FACE_TAGS.iter().enumerate() {
            let img = crate::scene::HdrImage { width: f as u32, height: f as u32, pixels: face_image(k, f, &sky) };
            img.write_exr(&dir.path().join(format!("sky_{tag}.exr"))).unwrap();
        }
        let (faces, warnings) = EnvMap::load(&dir.path().join("sky_{face}.exr")).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!((faces.width, faces.height, faces.layout), (f, 6 * f, EnvLayout::Cube));
        for vertical in [false, true] {
            let img = cross(f, vertical, sky);
            let path = dir.path().join(format!("cross-{vertical}.exr"));
            let file =
                crate::scene::HdrImage { width: img.width as u32, height: img.height as u32, pixels: img.pixels };
            file.write_exr(&path).unwrap();
            let (crossed, warnings) = EnvMap::load(&path).unwrap();
            assert!(warnings.is_empty(), "the unused cells are never read: {warnings:?}");
            assert_eq!(crossed.pixels, faces.pixels, "vertical {vertical}");
            assert_eq!(crossed.layout, EnvLayout::Cube);
            for (r, rotation) in [(8, 0.0), (5, 0.0), (4, 1.1)] {
                let cubemap = Cubemap::new(r);
                assert_eq!(
                    LightVector::from_env(&crossed, cubemap, rotation),
                    LightVector::from_env(&faces, cubemap, rotation)
                );
            }
        }
    }

    #[test]
    fn bad_cube_inputs_are_refused_with_what_and_where() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, w: u32, h: u32| {
            let path = dir.path().join(name);
            crate::scene::HdrImage::new(w, h).write_exr(&path).unwrap();
            path
        };
        let err = |path: &Path| EnvMap::load(path).unwrap_err().to_string();
        // Neither 2:1 nor 4:3 nor 3:4.
        let e = err(&write("odd.exr", 10, 8));
        assert!(e.contains("odd.exr") && e.contains("4:3") && e.contains("got 10x8"), "{e}");
        // Six faces: one missing, one of another size, one not square.
        for tag in FACE_TAGS {
            write(&format!("a_{tag}.exr"), 8, 8);
        }
        std::fs::remove_file(dir.path().join("a_ny.exr")).unwrap();
        let e = err(&dir.path().join("a_{face}.exr"));
        assert!(e.contains("a_ny.exr") && e.contains("cube face -Y") && e.contains("not found"), "{e}");
        write("a_ny.exr", 4, 4);
        let e = err(&dir.path().join("a_{face}.exr"));
        assert!(e.contains("a_ny.exr: cube face -Y is 4x4 but face +X") && e.contains("a_px.exr) is 8x8"), "{e}");
        write("a_ny.exr", 8, 6);
        let e = err(&dir.path().join("a_{face}.exr"));
        assert!(e.contains("a_ny.exr: cube face -Y must be square, got 8x6"), "{e}");
        // A NaN in a cross is named by its place in the image and its face.
        let mut img = cross(4, false, sky);
        img.pixels[5 * 16 + 9] = [0.0, f32::NAN, 0.0];
        let e = from_cross(&img, Path::new("c.exr")).unwrap_err().to_string();
        assert!(
            e.contains("c.exr: pixel (x=9, y=5) (horizontal cross, face +X texel (col 1, row 1)) channel G"),
            "{e}"
        );
        // Negative radiance is clamped with a warning, as in a lat-long map.
        let mut img = cross(4, true, sky);
        img.pixels[4 * 12 + 5] = [-1.0, 0.0, 0.0];
        let (env, warnings) = from_cross(&img, Path::new("c.exr")).unwrap();
        assert_eq!(warnings, ["c.exr: clamped 1 negative channel values to 0"]);
        assert!(env.pixels.iter().flatten().all(|&c| c >= 0.0));
    }

    #[test]
    fn background_lookup_is_bilinear_within_a_face() {
        let f = 16;
        let env = cube_of(&cross(f, false, sky));
        let cube = Cubemap::new(f as u32);
        // Exact at texel centres, with the map's rotation undone.
        for k in [0, 37, 2 * f * f + 5, 6 * f * f - 1] {
            let d = cube.texel_direction_f64(k);
            assert_eq!(env.radiance(d.as_vec3(), 0.0), env.pixels[k], "texel {k}");
            for rotation in [0.4, -1.3] {
                let got = env.radiance(rotate_y(d, rotation).as_vec3(), rotation);
                assert!((0..3).all(|c| (got[c] - env.pixels[k][c]).abs() < 1e-4), "texel {k}: {got:?}");
            }
        }
        // Close to the sky between texel centres, and exactly constant for a constant map.
        for d in [DVec3::new(0.3, -0.9, 0.2), DVec3::new(-0.5, 0.1, -0.8), DVec3::Y] {
            let (got, want) = (env.radiance(d.as_vec3(), 0.0)[0], sky(d.normalize())[0]);
            assert!((got - want).abs() < 0.05, "{d}: {got} vs {want}");
        }
        let constant = EnvMap { width: 3, height: 18, pixels: vec![[0.1, 0.2, 0.3]; 54], layout: EnvLayout::Cube };
        assert_eq!(constant.radiance(Vec3::new(0.3, -0.2, 0.7).normalize(), 0.7), [0.1, 0.2, 0.3]);
        // The lat-long view (the GPU background) looks the cube map up at its pixel centres.
        let view = env.latlong_view();
        assert_eq!((view.width, view.height, view.layout), (4 * f, 2 * f, EnvLayout::LatLong));
        let d = latlong_direction(10.5 / (4 * f) as f64, 7.5 / (2 * f) as f64);
        assert_eq!(view.pixels[7 * 4 * f + 10], env.radiance(d.as_vec3(), 0.0));
    }
}
