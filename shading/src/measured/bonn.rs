//! Measured BTFs in the layout of the Bonn BTF Database (the UBO2003 release of the University
//! of Bonn, the measurements used by Müller et al.'s LPCA BTF compression and by the
//! biclustering paper), resampled onto a [`Btf`] table.
//!
//! # The layout
//!
//! A sample is one directory. Inside it, every view direction has its own sub-folder named
//! `tv{theta_v:03}_pv{phi_v:03}` (`tv000_pv000`, `tv015_pv060`, ...), and that folder holds one
//! rectified image of the sample per light direction, named
//! `{index:05} tl{theta_l:03} pl{phi_l:03} tv{theta_v:03} pv{phi_v:03}.{ext}`, for example
//! `00000 tl000 pl000 tv000 pv000.jpg` (the spaces belong to the name; the index is any run of
//! digits and is not used). Angles are whole degrees: `theta` is measured from the surface
//! normal (0..=90) and `phi` is the azimuth (0..=360), counted from the patch's +u (+X, the
//! tangent) axis towards +v (+Y), so a direction is
//! `(sin theta cos phi, sin theta sin phi, cos theta)` in biscale's local frame. The original
//! release has 81 view x 81 light directions and 256 x 256 JPEG images.
//!
//! Accepted images: `.jpg` / `.jpeg` and `.png` (8- or 16-bit, sRGB encoded: decoded with the
//! `image` crate and converted to linear values with the sRGB transfer function) and `.exr`
//! (linear, read with [`HdrImage::read_exr`]; a NaN or infinite pixel is an error). A build of
//! the `image` crate without the JPEG decoder (the workspace enables it) fails on the first
//! JPEG with a message saying so. Extensions are matched case-insensitively.
//!
//! What is ignored: anything in the sample directory that is not a folder named
//! `tvNNN_pvNNN` (calibration folders, notes, thumbnails), and in a view folder every entry that
//! is not a file named by the pattern above with one of the accepted extensions. What is an
//! error (each names the file or folder): a missing directory, no view folder, a view folder
//! with no image, an angle out of range (`theta > 90`, `phi > 360`), a file whose `tv`/`pv`
//! differ from its folder's, two views or two lights of one view with the same direction
//! (`theta = 0` at any `phi` is the normal), images of different sizes, a size that is not a
//! multiple of the output resolution, an image that cannot be decoded. Views may have different
//! light sets: each view interpolates its own.
//!
//! # What is computed
//!
//! The table follows docs/DESIGN.md section 3 (**BTF**): `b(u, e, d_j)` is the outgoing radiance
//! at texel `u` towards view `e` under unit perpendicular irradiance from bin `j`, *including*
//! the cosine, taken as the bin's exact mean cosine `cosbar_j`
//! ([`HemisphereGrid::bin_mean_cosine`]) times the rest of the reflectance at the bin centre
//! ([`HemisphereGrid::bin_direction`]). The photographs are taken under a light of fixed
//! perpendicular irradiance, so a pixel is `scale^-1 * ABRDF(l, e) * cos theta_l` (the
//! "apparent" BRDF, with meso-scale shadowing, masking and interreflection in it). The import:
//!
//! 1. **Spatial.** Every image is box-filtered to `resolution x resolution` texels: texel
//!    `(tx, ty)` is the mean of the pixel block `x / bw = tx`, `y / bh = ty` with
//!    `bw = width / resolution`, `bh = height / resolution` (both must divide exactly; images
//!    need not be square). Image row 0 (the top of the file) is texel row 0, so the patch's `v`
//!    runs down the image, as it does for [`HdrImage`]; `u` runs left to right.
//! 2. **Light axis.** Each block mean is divided by `max(cos theta_l, 1e-3)`, which gives the
//!    ABRDF (the clamp only matters for lights at the horizon, where the pixel is noise and the
//!    division would blow it up without bound; the Bonn lights stop at 75 degrees). For light
//!    bin `j`, the ABRDF of each measured view is interpolated at the bin centre from that
//!    view's measured light directions and multiplied by `cosbar_j * scale`.
//! 3. **View axis.** With `view_grid = m > 0`, each bin centre of
//!    [`view_grid(m)`](biscale_core::scene::btf::view_grid) is interpolated the same way from
//!    the measured views (their light-interpolated tables). With `view_grid = 0` the BTF is
//!    view-independent (`V = 1`): it is the measured view closest to the normal, alone.
//!
//! **Interpolation over scattered directions** (both axes): inverse-distance weighting of the
//! `k = 3` measured directions nearest to the target by angle, with weights `1 / angle^2`
//! normalised to sum to 1; a measured direction within 1e-6 rad of the target takes weight 1
//! alone (so a bin centre that was measured is reproduced exactly). For an ABRDF that is
//! `L`-Lipschitz in the direction (e.g. linear in its `x, y` components with slope `L`), the
//! error of one interpolation is at most `L * sum_i w_i angle_i <= (1 + sqrt 3) / 2 * L *
//! nearest angle` (the weighted mean of the three angles is largest, relative to the nearest,
//! when the other two are 0.366 times as close); light and view errors add.
//! [`BonnReport::max_interpolation_angle_deg`] is the largest nearest angle used anywhere
//! (over all light bins of every view read, all view bins, and with `view_grid = 0` the chosen
//! view's angle to the normal), so a user sees how far the grid lies from the measurements.
//!
//! Only the measured views some output view draws on are read (with `view_grid = 0`, one
//! folder); their images are decoded in parallel, one view at a time, and reduced to the output
//! resolution at once, so memory is the output table plus one view's filtered images. Sums are
//! f64; the output holds f32 ([`Rgb`]) and receives at most three view contributions per entry.
//! A request whose table (`resolution^2 * V * M * 12` bytes) exceeds 4 GiB is refused before
//! any file is read.

use crate::error::{Result, ShadingError};
use biscale_core::basis::LocalBasis;
use biscale_core::sampling::hemisphere::square_to_hemisphere;
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::btf::view_grid as make_view_grid;
use biscale_core::scene::{Btf, HdrImage};
use biscale_core::Rgb;
use glam::DVec3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// How to turn a Bonn sample into a [`Btf`] (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct BonnImport {
    /// The light axis: the local bins of `L*` the table is dotted with (must be a bin basis).
    pub local_basis: LocalBasis,
    /// Side `m` of the view grid ([`view_grid(m)`](biscale_core::scene::btf::view_grid),
    /// 1..=64); 0 = view-independent: the measured view closest to the normal, no view axis.
    pub view_grid: u32,
    /// Output texels per side; every image side must be a multiple of it.
    pub resolution: u32,
    /// Multiplies every value (image units to radiance per unit perpendicular irradiance).
    pub scale: f32,
    /// The BTF's name (empty: `bonn <directory>`).
    pub name: String,
}

/// What [`load_bonn`] found and how far it had to interpolate.
#[derive(Clone, Debug, PartialEq)]
pub struct BonnReport {
    /// Measured view directions (view folders with at least one image).
    pub views: usize,
    /// The most measured light directions of any one view.
    pub lights: usize,
    /// `[width, height]` of the images (all the same).
    pub image_size: [u32; 2],
    /// The largest angle, in degrees, between an interpolation target (a light bin centre, a
    /// view bin centre, or the normal with `view_grid = 0`) and its nearest measured direction.
    pub max_interpolation_angle_deg: f64,
}

/// The largest output table accepted: 4 GiB.
const MAX_TABLE_BYTES: u128 = 4 << 30;
/// Number of nearest measured directions blended.
const K_NEAREST: usize = 3;
/// A measured direction this close (radians) to the target is the target.
const EXACT_RAD: f64 = 1e-6;
/// Smallest cosine a pixel is divided by.
const MIN_COS: f64 = 1e-3;

/// A direction as named: whole degrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Angles {
    theta: u32,
    phi: u32,
}

impl Angles {
    /// Unit direction in the local frame (+Z the normal, phi from +X towards +Y).
    fn direction(self) -> DVec3 {
        let (t, p) = ((self.theta as f64).to_radians(), (self.phi as f64).to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    /// An error naming `path` unless theta is in 0..=90 and phi in 0..=360.
    fn check(self, what: &str, path: &Path) -> Result<Self> {
        if self.theta > 90 || self.phi > 360 {
            return Err(ShadingError::File {
                path: path.into(),
                message: format!(
                    "{what} direction theta {} phi {} is out of range (theta 0..=90 from the normal, phi 0..=360)",
                    self.theta, self.phi
                ),
            });
        }
        Ok(self)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ImageKind {
    Jpeg,
    Png,
    Exr,
}

/// `{prefix}NNN` with exactly three decimal digits.
fn three_digits(s: &str, prefix: &str) -> Option<u32> {
    let d = s.strip_prefix(prefix)?;
    if d.len() == 3 && d.bytes().all(|b| b.is_ascii_digit()) {
        d.parse().ok()
    } else {
        None
    }
}

/// The view angles of a folder named `tvNNN_pvNNN`.
fn parse_view_folder(name: &str) -> Option<Angles> {
    let (t, p) = name.split_once('_')?;
    Some(Angles { theta: three_digits(t, "tv")?, phi: three_digits(p, "pv")? })
}

/// Light angles, view angles and kind of an image named
/// `{index} tlNNN plNNN tvNNN pvNNN.{jpg,jpeg,png,exr}`.
fn parse_image_name(name: &str) -> Option<(Angles, Angles, ImageKind)> {
    let (stem, ext) = name.rsplit_once('.')?;
    let kind = match ext.to_ascii_lowercase().as_str() {
        "jpg" | "jpeg" => ImageKind::Jpeg,
        "png" => ImageKind::Png,
        "exr" => ImageKind::Exr,
        _ => return None,
    };
    let parts: Vec<&str> = stem.split(' ').collect();
    let [index, tl, pl, tv, pv] = parts.as_slice() else { return None };
    if index.is_empty() || !index.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let light = Angles { theta: three_digits(tl, "tl")?, phi: three_digits(pl, "pl")? };
    let view = Angles { theta: three_digits(tv, "tv")?, phi: three_digits(pv, "pv")? };
    Some((light, view, kind))
}

/// One measured light direction of a view: its image.
#[derive(Debug)]
struct MeasuredLight {
    dir: DVec3,
    cos: f64,
    path: PathBuf,
    kind: ImageKind,
}

/// One measured view direction: its folder and lights (sorted by file name).
#[derive(Debug)]
struct MeasuredView {
    dir: DVec3,
    folder: PathBuf,
    lights: Vec<MeasuredLight>,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ShadingError + '_ {
    move |source| ShadingError::Io { path: path.into(), source }
}

/// The UTF-8 names of a directory's entries, sorted (read_dir's order is arbitrary).
fn sorted_entries(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut out = vec![];
    for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
        let entry = entry.map_err(io_err(dir))?;
        if let Ok(name) = entry.file_name().into_string() {
            out.push((name, entry.path()));
        }
    }
    out.sort();
    Ok(out)
}

/// Angle between two unit vectors, accurate near 0 and pi.
fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// Index of the first of `dirs` within [`EXACT_RAD`] of `dirs[i]`, before `i`.
fn duplicate_of(dirs: &[DVec3], i: usize) -> Option<usize> {
    (0..i).find(|&k| angle_between(dirs[k], dirs[i]) < EXACT_RAD)
}

/// Read the directory structure (no image is decoded).
fn scan(dir: &Path) -> Result<Vec<MeasuredView>> {
    let meta = std::fs::metadata(dir).map_err(io_err(dir))?;
    if !meta.is_dir() {
        return Err(ShadingError::File {
            path: dir.into(),
            message: "not a directory (expected a Bonn BTF sample)".into(),
        });
    }
    let mut views: Vec<MeasuredView> = vec![];
    for (name, folder) in sorted_entries(dir)? {
        let Some(angles) = parse_view_folder(&name) else { continue };
        if !folder.is_dir() {
            continue;
        }
        let angles = angles.check("view", &folder)?;
        let mut lights: Vec<MeasuredLight> = vec![];
        for (file, path) in sorted_entries(&folder)? {
            let Some((light, view, kind)) = parse_image_name(&file) else { continue };
            if !path.is_file() {
                continue;
            }
            if view != angles {
                return Err(ShadingError::File {
                    path,
                    message: format!(
                        "the name says view tv{:03} pv{:03}, but the file is in the folder of view tv{:03} pv{:03}",
                        view.theta, view.phi, angles.theta, angles.phi
                    ),
                });
            }
            let light = light.check("light", &path)?;
            let dir = light.direction();
            lights.push(MeasuredLight { dir, cos: dir.z, path, kind });
        }
        if lights.is_empty() {
            return Err(ShadingError::File {
                path: folder,
                message: "view folder without light images (expected files named like \
                          `00000 tl000 pl000 tv000 pv000.png`, .jpg, .jpeg or .exr)"
                    .into(),
            });
        }
        let dirs: Vec<DVec3> = lights.iter().map(|l| l.dir).collect();
        for i in 0..dirs.len() {
            if let Some(k) = duplicate_of(&dirs, i) {
                return Err(ShadingError::File {
                    path: lights[i].path.clone(),
                    message: format!("same light direction as {}", lights[k].path.display()),
                });
            }
        }
        views.push(MeasuredView { dir: angles.direction(), folder, lights });
    }
    if views.is_empty() {
        return Err(ShadingError::File {
            path: dir.into(),
            message: "no view folder (expected sub-folders named like tv000_pv000 holding the images)".into(),
        });
    }
    let dirs: Vec<DVec3> = views.iter().map(|v| v.dir).collect();
    for i in 0..dirs.len() {
        if let Some(k) = duplicate_of(&dirs, i) {
            return Err(ShadingError::File {
                path: views[i].folder.clone(),
                message: format!("same view direction as {}", views[k].folder.display()),
            });
        }
    }
    Ok(views)
}

/// Inverse-distance weights (`1 / angle^2`) of the [`K_NEAREST`] of `dirs` nearest to `target`,
/// and the nearest angle. A direction within [`EXACT_RAD`] takes weight 1 alone. Ties keep
/// the earlier direction.
fn idw(target: DVec3, dirs: &[DVec3]) -> (Vec<(usize, f64)>, f64) {
    let mut best: Vec<(f64, usize)> = Vec::with_capacity(K_NEAREST + 1);
    for (i, d) in dirs.iter().enumerate() {
        let a = angle_between(target, *d);
        let pos = best.partition_point(|&(b, _)| b <= a);
        if pos < K_NEAREST {
            best.insert(pos, (a, i));
            best.truncate(K_NEAREST);
        }
    }
    let Some(&(nearest, first)) = best.first() else { return (vec![], 0.0) };
    if nearest < EXACT_RAD {
        return (vec![(first, 1.0)], nearest);
    }
    let total: f64 = best.iter().map(|(a, _)| 1.0 / (a * a)).sum();
    (best.iter().map(|&(a, i)| (i, 1.0 / (a * a) / total)).collect(), nearest)
}

/// Unit direction through the centre of bin `j`, in f64.
fn bin_centre(grid: HemisphereGrid, j: u32) -> DVec3 {
    let (u, v) = grid.bin_centre_uv(j);
    square_to_hemisphere(u, v)
}

/// The sRGB decoding function (IEC 61966-2-1) of a value in [0, 1].
fn srgb_to_linear(x: f64) -> f64 {
    if x <= 0.04045 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

/// A decoded image's pixels, row-major RGB.
enum Pixels {
    Linear(Vec<Rgb>),
    Srgb8(Vec<u8>),
    Srgb16(Vec<u16>),
}

/// Decode one image: `(width, height, pixels)`.
fn decode(path: &Path, kind: ImageKind) -> Result<(u32, u32, Pixels)> {
    let format = match kind {
        ImageKind::Exr => {
            let (img, _warnings) = HdrImage::read_exr(path)?;
            if let Some((count, first)) = img.non_finite() {
                return Err(ShadingError::NonFinite { what: path.display().to_string(), count, first });
            }
            return Ok((img.width, img.height, Pixels::Linear(img.pixels)));
        }
        ImageKind::Png => image::ImageFormat::Png,
        ImageKind::Jpeg => image::ImageFormat::Jpeg,
    };
    if !format.reading_enabled() {
        return Err(ShadingError::File {
            path: path.into(),
            message: format!(
                "{format:?} decoding is not compiled in (the workspace's `image` dependency lacks the feature); \
                 convert the sample to PNG or enable the feature"
            ),
        });
    }
    biscale_core::io::check_regular(path).map_err(io_err(path))?;
    let reader = image::ImageReader::open(path).map_err(io_err(path))?.with_guessed_format().map_err(io_err(path))?;
    let img = reader
        .decode()
        .map_err(|e| ShadingError::File { path: path.into(), message: format!("cannot decode image: {e}") })?;
    let (w, h) = (img.width(), img.height());
    let color = img.color();
    let pixels = if color.bytes_per_pixel() / color.channel_count().max(1) >= 2 {
        Pixels::Srgb16(img.to_rgb16().into_raw())
    } else {
        Pixels::Srgb8(img.to_rgb8().into_raw())
    };
    Ok((w, h, pixels))
}

/// Box filter a `w x h` image to `res x res` block means, each times `factor`.
fn box_filter(w: usize, h: usize, res: usize, factor: f64, px: impl Fn(usize) -> [f64; 3]) -> Vec<[f64; 3]> {
    let (bw, bh) = (w / res, h / res);
    let mut out = vec![[0.0f64; 3]; res * res];
    for y in 0..h {
        let row = &mut out[(y / bh) * res..(y / bh + 1) * res];
        for x in 0..w {
            let p = px(y * w + x);
            let o = &mut row[x / bw];
            for c in 0..3 {
                o[c] += p[c];
            }
        }
    }
    let norm = factor / (bw * bh) as f64;
    for o in &mut out {
        for c in o.iter_mut() {
            *c *= norm;
        }
    }
    out
}

/// The image size every file of the sample must have, and the file it was first seen in.
struct Reference {
    size: [u32; 2],
    path: PathBuf,
}

/// An error unless `size` divides into `res x res` blocks.
fn check_divisible(size: [u32; 2], res: u32, path: &Path) -> Result<()> {
    if size.iter().any(|&s| s == 0 || !s.is_multiple_of(res)) {
        return Err(ShadingError::File {
            path: path.into(),
            message: format!(
                "image is {}x{}, which does not divide into {res}x{res} texels (each side must be a multiple of \
                 the resolution)",
                size[0], size[1]
            ),
        });
    }
    Ok(())
}

/// Decode one light image, check its size, and reduce it to the ABRDF block means.
fn load_light(light: &MeasuredLight, reference: &Reference, res: u32) -> Result<Vec<[f64; 3]>> {
    let (w, h, pixels) = decode(&light.path, light.kind)?;
    if [w, h] != reference.size {
        return Err(ShadingError::File {
            path: light.path.clone(),
            message: format!(
                "image is {w}x{h}, but {} is {}x{} (every image of a sample must have the same size)",
                reference.path.display(),
                reference.size[0],
                reference.size[1]
            ),
        });
    }
    let (w, h, res) = (w as usize, h as usize, res as usize);
    let factor = 1.0 / light.cos.max(MIN_COS);
    Ok(match pixels {
        Pixels::Linear(p) => box_filter(w, h, res, factor, |i| p[i].map(|x| x as f64)),
        Pixels::Srgb8(p) => {
            let lut: Vec<f64> = (0..256).map(|b| srgb_to_linear(b as f64 / 255.0)).collect();
            box_filter(w, h, res, factor, |i| {
                [lut[p[3 * i] as usize], lut[p[3 * i + 1] as usize], lut[p[3 * i + 2] as usize]]
            })
        }
        Pixels::Srgb16(p) => {
            box_filter(w, h, res, factor, |i| [0, 1, 2].map(|c| srgb_to_linear(p[3 * i + c] as f64 / 65535.0)))
        }
    })
}

/// Import a measured BTF stored in the Bonn BTF Database layout (see the module docs): the
/// sample directory `dir`, resampled onto `opts`'s light bins, view grid and resolution.
/// Errors name the file or folder at fault; no input makes it panic.
pub fn load_bonn(dir: &Path, opts: &BonnImport) -> Result<(Btf, BonnReport)> {
    // The request first: nothing is read for one that cannot be met.
    let light_grid = opts.local_basis.grid().ok_or_else(|| {
        ShadingError::Invalid(format!("a measured BTF needs a bin basis for its lights, not {}", opts.local_basis))
    })?;
    let out_grid = if opts.view_grid == 0 { None } else { Some(make_view_grid(opts.view_grid)?) };
    if opts.resolution == 0 {
        return Err(ShadingError::Invalid("BTF resolution must be at least 1 texel per side".into()));
    }
    if !(opts.scale.is_finite() && opts.scale >= 0.0) {
        return Err(ShadingError::Invalid(format!("BTF scale must be finite and non-negative, got {}", opts.scale)));
    }
    let res = opts.resolution;
    let m = light_grid.len();
    let v_count = out_grid.map_or(1, |g| g.len());
    let texels = res as u128 * res as u128;
    let bytes = texels * v_count as u128 * m as u128 * 12;
    if bytes > MAX_TABLE_BYTES {
        return Err(ShadingError::Invalid(format!(
            "the BTF table would be {res}x{res} texels x {v_count} views x {m} lights x 12 bytes = {:.2} GiB, over \
             the limit of 4 GiB: lower the resolution, the view grid or the local basis",
            bytes as f64 / (1u64 << 30) as f64
        )));
    }
    let texels = texels as usize;

    let views = scan(dir)?;
    let view_dirs: Vec<DVec3> = views.iter().map(|v| v.dir).collect();
    let mut max_angle = 0.0f64;

    // Which measured views feed which output view, with what weight.
    let mut feeds: Vec<Vec<(usize, f64)>> = vec![vec![]; views.len()];
    match out_grid {
        None => {
            let (w, nearest) = idw(DVec3::Z, &view_dirs);
            max_angle = max_angle.max(nearest);
            // The nearest view alone (first on a tie), whatever the other weights.
            if let Some(&(i, _)) = w.first() {
                feeds[i].push((0, 1.0));
            }
        }
        Some(g) => {
            for v in 0..g.len() {
                let (w, nearest) = idw(bin_centre(g, v as u32), &view_dirs);
                max_angle = max_angle.max(nearest);
                for (i, wi) in w {
                    feeds[i].push((v, wi));
                }
            }
        }
    }

    let light_centres: Vec<DVec3> = (0..m as u32).map(|j| bin_centre(light_grid, j)).collect();
    let cosbar = light_grid.mean_cosines();
    let scale = opts.scale as f64;
    let mut data: Vec<Rgb> = vec![[0.0; 3]; texels * v_count * m];
    let mut reference: Option<Reference> = None;
    for (view, feed) in views.iter().zip(&feeds) {
        if feed.is_empty() {
            continue;
        }
        if reference.is_none() {
            // The first image read sets the size every other must have.
            let first = &view.lights[0];
            let (w, h, _) = decode(&first.path, first.kind)?;
            check_divisible([w, h], res, &first.path)?;
            reference = Some(Reference { size: [w, h], path: first.path.clone() });
        }
        let Some(size_of) = reference.as_ref() else { continue };
        let light_dirs: Vec<DVec3> = view.lights.iter().map(|l| l.dir).collect();
        let light_weights: Vec<Vec<(usize, f64)>> = light_centres
            .iter()
            .map(|c| {
                let (w, nearest) = idw(*c, &light_dirs);
                max_angle = max_angle.max(nearest);
                w
            })
            .collect();
        let abrdf: Vec<Vec<[f64; 3]>> =
            view.lights.par_iter().map(|l| load_light(l, size_of, res)).collect::<Result<_>>()?;
        data.par_chunks_mut(v_count * m).enumerate().for_each_init(
            || vec![[0.0f64; 3]; m],
            |g, (t, texel_out)| {
                for (j, lw) in light_weights.iter().enumerate() {
                    let mut s = [0.0f64; 3];
                    for &(i, w) in lw {
                        let p = abrdf[i][t];
                        for c in 0..3 {
                            s[c] += w * p[c];
                        }
                    }
                    g[j] = s;
                }
                for &(v, wv) in feed {
                    let row = &mut texel_out[v * m..(v + 1) * m];
                    for j in 0..m {
                        let f = wv * scale * cosbar[j];
                        for c in 0..3 {
                            row[j][c] += (f * g[j][c]) as f32;
                        }
                    }
                }
            },
        );
    }

    let report = BonnReport {
        views: views.len(),
        lights: views.iter().map(|v| v.lights.len()).max().unwrap_or(0),
        image_size: reference.map_or([0, 0], |r| r.size),
        max_interpolation_angle_deg: max_angle.to_degrees(),
    };
    let name = if opts.name.is_empty() { format!("bonn {}", dir.display()) } else { opts.name.clone() };
    let btf = Btf::new([res, res], opts.local_basis, out_grid, data, name)?;
    Ok((btf, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A direction from whole degrees, as the layout defines it.
    fn dir(theta: u32, phi: u32) -> DVec3 {
        let (t, p) = ((theta as f64).to_radians(), (phi as f64).to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    /// The test lights: the normal, six at 30 degrees and six at 60 (13 in all).
    fn lights13() -> Vec<(u32, u32)> {
        let mut l = vec![(0, 0)];
        l.extend((0..6).map(|k| (30, 60 * k)));
        l.extend((0..6).map(|k| (60, 30 + 60 * k)));
        l
    }

    const VIEWS5: [(u32, u32); 5] = [(0, 0), (30, 0), (30, 90), (30, 180), (30, 270)];

    fn folder_name(v: (u32, u32)) -> String {
        format!("tv{:03}_pv{:03}", v.0, v.1)
    }

    fn image_name(i: usize, l: (u32, u32), v: (u32, u32), ext: &str) -> String {
        format!("{i:05} tl{:03} pl{:03} tv{:03} pv{:03}.{ext}", l.0, l.1, v.0, v.1)
    }

    /// A sample of EXR images: `pixel(x, y, light, view)` in linear units.
    fn write_exr_sample(
        root: &Path,
        views: &[(u32, u32)],
        lights: &[(u32, u32)],
        size: [u32; 2],
        pixel: impl Fn(u32, u32, DVec3, DVec3) -> [f64; 3],
    ) {
        for &v in views {
            let folder = root.join(folder_name(v));
            std::fs::create_dir_all(&folder).unwrap();
            for (i, &l) in lights.iter().enumerate() {
                let mut img = HdrImage::new(size[0], size[1]);
                for y in 0..size[1] {
                    for x in 0..size[0] {
                        img.pixels[(y * size[0] + x) as usize] =
                            pixel(x, y, dir(l.0, l.1), dir(v.0, v.1)).map(|c| c as f32);
                    }
                }
                img.write_exr(&folder.join(image_name(i, l, v, "exr"))).unwrap();
            }
        }
    }

    /// An 8-bit PNG whose bytes are `byte(x, y, c)`.
    fn write_png(path: &Path, w: u32, h: u32, byte: impl Fn(u32, u32, usize) -> u8) {
        let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([0, 1, 2].map(|c| byte(x, y, c))));
        img.save(path).unwrap();
    }

    fn opts(m: u32, view_grid: u32, resolution: u32, scale: f32) -> BonnImport {
        BonnImport { local_basis: LocalBasis::bins(m).unwrap(), view_grid, resolution, scale, name: "test".into() }
    }

    /// Angle between unit vectors (the definition the loader documents).
    fn angle(a: DVec3, b: DVec3) -> f64 {
        a.cross(b).length().atan2(a.dot(b))
    }

    /// Inverse-distance weights written out independently: sort all directions by
    /// (angle, index), keep three, `1 / angle^2`, an exact hit alone.
    fn idw_reference(target: DVec3, dirs: &[DVec3]) -> Vec<(usize, f64)> {
        let mut a: Vec<(f64, usize)> = dirs.iter().enumerate().map(|(i, d)| (angle(target, *d), i)).collect();
        a.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        if a[0].0 < 1e-6 {
            return vec![(a[0].1, 1.0)];
        }
        let top = &a[..a.len().min(3)];
        let total: f64 = top.iter().map(|(t, _)| t.powi(-2)).sum();
        top.iter().map(|&(t, i)| (i, t.powi(-2) / total)).collect()
    }

    fn centre(grid: HemisphereGrid, j: usize) -> DVec3 {
        let (u, v) = grid.bin_centre_uv(j as u32);
        square_to_hemisphere(u, v)
    }

    /// Largest angle from any of `targets` to its nearest of `dirs`.
    fn max_nearest(targets: &[DVec3], dirs: &[DVec3]) -> f64 {
        targets.iter().map(|t| dirs.iter().map(|d| angle(*t, *d)).fold(f64::INFINITY, f64::min)).fold(0.0, f64::max)
    }

    #[test]
    fn constant_abrdf_is_exact_and_texels_are_block_means() {
        // An ABRDF that does not depend on the directions but differs in every pixel, so a
        // texel must be the mean of exactly its block. 8x4 images to 4x4 texels: blocks of
        // 2 wide x 1 high.
        let p =
            |x: u32, y: u32, c: usize| 0.2 + 0.05 * x as f64 + 0.11 * y as f64 + 0.3 * c as f64 + 0.01 * (x * y) as f64;
        let tmp = tempfile::tempdir().unwrap();
        write_exr_sample(tmp.path(), &VIEWS5, &lights13(), [8, 4], |x, y, l, _| [0, 1, 2].map(|c| p(x, y, c) * l.z));
        let (btf, report) = load_bonn(tmp.path(), &opts(3, 3, 4, 2.5)).unwrap();
        assert_eq!((report.views, report.lights, report.image_size), (5, 13, [8, 4]));
        assert_eq!((btf.spatial(), btf.view_count(), btf.light_count()), ([4, 4], 9, 9));
        assert_eq!(btf.name(), "test");
        let grid = HemisphereGrid::new(3);
        for ty in 0..4u32 {
            for tx in 0..4u32 {
                for v in 0..9 {
                    for j in 0..9 {
                        let got = btf.data()[(((ty * 4 + tx) as usize) * 9 + v) * 9 + j];
                        for c in 0..3 {
                            let mean = (p(2 * tx, ty, c) + p(2 * tx + 1, ty, c)) / 2.0;
                            let expect = 2.5 * grid.bin_mean_cosine(j as u32) * mean;
                            // Interpolation weights sum to 1, so only rounding is left: the
                            // f32 pixels (2^-24 relative), f64 sums, and at most three f32
                            // additions into the table (a few 2^-24): below 1e-6 relative.
                            let err = (got[c] as f64 - expect).abs();
                            assert!(
                                err <= 1e-6 * expect,
                                "texel ({tx},{ty}) v={v} j={j} c={c}: {} vs {expect}",
                                got[c]
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn linear_abrdf_is_interpolated_within_the_idw_bound() {
        // ABRDF f = a + b . l_xy + g . e_xy per channel, coefficients varying per pixel.
        let coeffs = |x: u32, y: u32, c: usize| {
            let (x, y, c) = (x as f64, y as f64, c as f64);
            (
                0.6 + 0.03 * x + 0.02 * y + 0.1 * c,
                [0.15 + 0.01 * x, -0.1 + 0.015 * y + 0.02 * c],
                [0.08 - 0.01 * y, 0.05 + 0.005 * x * c],
            )
        };
        let f = |x: u32, y: u32, c: usize, l: DVec3, e: DVec3| {
            let (a, b, g) = coeffs(x, y, c);
            a + b[0] * l.x + b[1] * l.y + g[0] * e.x + g[1] * e.y
        };
        let tmp = tempfile::tempdir().unwrap();
        let lights = lights13();
        write_exr_sample(tmp.path(), &VIEWS5, &lights, [8, 8], |x, y, l, e| [0, 1, 2].map(|c| f(x, y, c, l, e) * l.z));
        let light_dirs: Vec<DVec3> = lights.iter().map(|l| dir(l.0, l.1)).collect();
        let view_dirs: Vec<DVec3> = VIEWS5.iter().map(|v| dir(v.0, v.1)).collect();
        let (lg, vg) = (HemisphereGrid::new(3), HemisphereGrid::new(3));
        let lc: Vec<DVec3> = (0..9).map(|j| centre(lg, j)).collect();
        let vc: Vec<DVec3> = (0..9).map(|v| centre(vg, v)).collect();
        // Bin 4 of a 3x3 grid is centred on the normal, which is measured as a light and a view.
        assert_eq!((lc[4], vc[4]), (DVec3::Z, DVec3::Z));
        // (1 + sqrt 3) / 2: the most `sum w_i angle_i` can exceed the nearest angle, for
        // weights 1 / angle^2 over three directions (module docs).
        let k_idw = (1.0 + 3f64.sqrt()) / 2.0;

        // Block means of the coefficients: the ABRDF is linear in them, so the filtered
        // texel is the same linear function with the means.
        let texel = |tx: u32, ty: u32, c: usize| {
            let (mut a, mut b, mut g) = (0.0, [0.0; 2], [0.0; 2]);
            for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (ai, bi, gi) = coeffs(2 * tx + x, 2 * ty + y, c);
                a += ai / 4.0;
                for k in 0..2 {
                    b[k] += bi[k] / 4.0;
                    g[k] += gi[k] / 4.0;
                }
            }
            (a, b, g)
        };
        let at = |a: f64, b: [f64; 2], g: [f64; 2], l: DVec3, e: DVec3| {
            a + b[0] * l.x + b[1] * l.y + g[0] * e.x + g[1] * e.y
        };
        let norm = |v: [f64; 2]| v[0].hypot(v[1]);

        // With a view axis.
        let (btf, report) = load_bonn(tmp.path(), &opts(3, 3, 4, 1.0)).unwrap();
        let theta = max_nearest(&lc, &light_dirs).max(max_nearest(&vc, &view_dirs));
        assert!((report.max_interpolation_angle_deg - theta.to_degrees()).abs() < 1e-9, "{report:?} vs {theta}");
        let theta = report.max_interpolation_angle_deg.to_radians();
        for ty in 0..4 {
            for tx in 0..4 {
                for v in 0..9 {
                    for j in 0..9 {
                        let got = btf.data()[(((ty * 4 + tx) as usize) * 9 + v) * 9 + j];
                        let cb = lg.bin_mean_cosine(j as u32);
                        for c in 0..3 {
                            let (a, b, g) = texel(tx, ty, c);
                            let got = got[c] as f64;
                            // The IDW computed independently: light weights per measured view
                            // (all share the light set), then view weights.
                            let lw = idw_reference(lc[j], &light_dirs);
                            let idw: f64 = idw_reference(vc[v], &view_dirs)
                                .iter()
                                .map(|&(i, wv)| {
                                    wv * lw
                                        .iter()
                                        .map(|&(k, w)| w * at(a, b, g, light_dirs[k], view_dirs[i]))
                                        .sum::<f64>()
                                })
                                .sum();
                            assert!((got - cb * idw).abs() <= 1e-6 * cb * idw, "v={v} j={j}: {got} vs {}", cb * idw);
                            // Against the exact value: the IDW error bound.
                            let exact = cb * at(a, b, g, lc[j], vc[v]);
                            let bound = cb * k_idw * (norm(b) + norm(g)) * theta + 1e-6 * exact;
                            assert!((got - exact).abs() <= bound, "v={v} j={j}: {got} vs {exact}, bound {bound}");
                            if (v, j) == (4, 4) {
                                // Measured light and view: reproduced to rounding.
                                assert!((got - exact).abs() <= 1e-6 * exact, "normal: {got} vs {exact}");
                            }
                        }
                    }
                }
            }
        }

        // Without a view axis: the measured view at the normal, light interpolation only.
        let (btf, report) = load_bonn(tmp.path(), &opts(3, 0, 4, 1.0)).unwrap();
        assert_eq!(btf.view_count(), 1);
        assert!(btf.view_grid().is_none());
        let theta_l = max_nearest(&lc, &light_dirs);
        assert!((report.max_interpolation_angle_deg - theta_l.to_degrees()).abs() < 1e-9);
        for t in 0..16u32 {
            for j in 0..9 {
                let cb = lg.bin_mean_cosine(j as u32);
                for c in 0..3 {
                    let (a, b, g) = texel(t % 4, t / 4, c);
                    let got = btf.data()[t as usize * 9 + j][c] as f64;
                    let exact = cb * at(a, b, g, lc[j], DVec3::Z);
                    let bound = cb * k_idw * norm(b) * theta_l + 1e-6 * exact;
                    assert!((got - exact).abs() <= bound, "t={t} j={j}: {got} vs {exact}, bound {bound}");
                }
            }
        }
    }

    #[test]
    fn png_is_srgb_decoded_and_other_entries_are_ignored() {
        let tmp = tempfile::tempdir().unwrap();
        let folder = tmp.path().join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let byte = |x: u32, y: u32, c: usize| (10 + 37 * x + 61 * y + 80 * c as u32) as u8;
        write_png(&folder.join("00000 tl000 pl000 tv000 pv000.png"), 4, 4, byte);
        // Never read: they are not images by the pattern (garbage bytes would fail to decode).
        for junk in
            ["notes.txt", "00001 tl000 pl000.png", "00002 tl030 pl000 tv000 pv000.bmp", "x tl030 pl000 tv000 pv000.png"]
        {
            std::fs::write(folder.join(junk), b"junk").unwrap();
        }
        for dir_junk in ["calibration", "tv000_pv000_old", "tv15_pv000"] {
            std::fs::create_dir_all(tmp.path().join(dir_junk)).unwrap();
            std::fs::write(tmp.path().join(dir_junk).join("00000 tl000 pl000 tv000 pv000.png"), b"junk").unwrap();
        }
        std::fs::write(tmp.path().join("readme.txt"), b"junk").unwrap();
        let (btf, report) = load_bonn(tmp.path(), &opts(2, 0, 2, 0.5)).unwrap();
        assert_eq!((report.views, report.lights, report.image_size), (1, 1, [4, 4]));
        // One light: every bin takes it; the nearest-angle is that of the bin centres
        // (all four at z = 3/4 for a 2x2 grid) to the normal.
        assert!((report.max_interpolation_angle_deg - 0.75f64.acos().to_degrees()).abs() < 1e-9, "{report:?}");
        // IEC 61966-2-1, written out here.
        let lin = |b: u8| {
            let s = b as f64 / 255.0;
            if s <= 0.04045 {
                s / 12.92
            } else {
                ((s + 0.055) / 1.055).powf(2.4)
            }
        };
        let grid = HemisphereGrid::new(2);
        for ty in 0..2 {
            for tx in 0..2 {
                for j in 0..4 {
                    for c in 0..3 {
                        let mean = [(0, 0), (1, 0), (0, 1), (1, 1)]
                            .iter()
                            .map(|&(x, y)| lin(byte(2 * tx + x, 2 * ty + y, c)))
                            .sum::<f64>()
                            / 4.0;
                        let expect = 0.5 * grid.bin_mean_cosine(j as u32) * mean;
                        let got = btf.data()[(ty * 2 + tx) as usize * 4 + j][c] as f64;
                        assert!((got - expect).abs() <= 1e-6 * expect, "({tx},{ty}) j={j} c={c}: {got} vs {expect}");
                    }
                }
            }
        }
    }

    /// The original release's format: a uniform 8-bit JPEG decodes to its grey level (JPEG
    /// codes a flat 8x8 block by its DC term alone, exact up to one level of rounding).
    #[test]
    fn jpeg_images_decode() {
        let tmp = tempfile::tempdir().unwrap();
        let folder = tmp.path().join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let img = image::RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128]));
        img.save_with_format(folder.join("00000 tl000 pl000 tv000 pv000.jpg"), image::ImageFormat::Jpeg).unwrap();
        let (btf, _) = load_bonn(tmp.path(), &opts(1, 0, 2, 1.0)).unwrap();
        let grid = HemisphereGrid::new(2);
        for (j, v) in btf.data().iter().enumerate() {
            let abrdf = v[0] as f64 / grid.bin_mean_cosine(j as u32);
            let (lo, hi) = (srgb_to_linear(127.0 / 255.0), srgb_to_linear(129.0 / 255.0));
            assert!((lo..=hi).contains(&abrdf), "bin {j}: {abrdf} outside [{lo}, {hi}]");
        }
    }

    /// The error message of a failing import, which must name `path`.
    fn error_naming(dir: &Path, o: &BonnImport, path: &Path) -> String {
        let e = load_bonn(dir, o).expect_err("import should fail").to_string();
        assert!(e.contains(&path.display().to_string()), "'{e}' does not name {}", path.display());
        e
    }

    #[test]
    fn bad_samples_are_errors_naming_the_path() {
        let o = opts(2, 0, 2, 1.0);
        let tmp = tempfile::tempdir().unwrap();
        let root = |name: &str| {
            let r = tmp.path().join(name);
            std::fs::create_dir_all(&r).unwrap();
            r
        };
        let grey = |_: u32, _: u32, _: usize| 128u8;

        // Missing directory.
        let missing = tmp.path().join("missing");
        error_naming(&missing, &o, &missing);

        // No view folder.
        let empty = root("empty");
        std::fs::create_dir_all(empty.join("calibration")).unwrap();
        error_naming(&empty, &o, &empty);

        // A view folder without images.
        let r = root("nolights");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        std::fs::write(folder.join("notes.txt"), b"x").unwrap();
        error_naming(&r, &o, &folder);

        // Images of different sizes: the second file (in name order) is the odd one.
        let r = root("sizes");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        write_png(&folder.join("00000 tl000 pl000 tv000 pv000.png"), 8, 8, grey);
        let odd = folder.join("00001 tl030 pl000 tv000 pv000.png");
        write_png(&odd, 4, 4, grey);
        let e = error_naming(&r, &o, &odd);
        assert!(e.contains("4x4") && e.contains("8x8"), "{e}");

        // A resolution that does not divide the size.
        let r = root("divide");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let file = folder.join("00000 tl000 pl000 tv000 pv000.png");
        write_png(&file, 8, 8, grey);
        let e = error_naming(&r, &opts(2, 0, 3, 1.0), &file);
        assert!(e.contains("3x3"), "{e}");
        assert!(load_bonn(&r, &opts(2, 0, 4, 1.0)).is_ok());

        // The file's view angles differ from its folder's.
        let r = root("mismatch");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        write_png(&folder.join("00000 tl000 pl000 tv000 pv000.png"), 4, 4, grey);
        let file = folder.join("00001 tl030 pl000 tv015 pv000.png");
        write_png(&file, 4, 4, grey);
        error_naming(&r, &o, &file);

        // Two lights with one direction (theta 0 is the normal at any phi).
        let r = root("duplicate");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let first = folder.join("00000 tl000 pl000 tv000 pv000.png");
        write_png(&first, 4, 4, grey);
        let second = folder.join("00001 tl000 pl090 tv000 pv000.png");
        write_png(&second, 4, 4, grey);
        let e = error_naming(&r, &o, &second);
        assert!(e.contains(&first.display().to_string()), "{e}");

        // A light beyond the horizon.
        let r = root("horizon");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let file = folder.join("00000 tl095 pl000 tv000 pv000.png");
        write_png(&file, 4, 4, grey);
        error_naming(&r, &o, &file);

        // A file that does not decode.
        let r = root("corrupt");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let file = folder.join("00000 tl000 pl000 tv000 pv000.png");
        std::fs::write(&file, b"not a png").unwrap();
        error_naming(&r, &o, &file);

        // A NaN in an EXR.
        let r = root("nan");
        let folder = r.join("tv000_pv000");
        std::fs::create_dir_all(&folder).unwrap();
        let file = folder.join("00000 tl000 pl000 tv000 pv000.exr");
        let mut img = HdrImage::new(4, 4);
        img.pixels[5] = [f32::NAN, 0.0, 0.0];
        img.write_exr(&file).unwrap();
        let e = error_naming(&r, &o, &file);
        assert!(e.contains("non-finite"), "{e}");

        // A table over 4 GiB is refused before the directory is even looked at.
        let e = load_bonn(&missing, &opts(64, 64, 4096, 1.0)).unwrap_err().to_string();
        assert!(e.contains("GiB") && !e.contains("missing"), "{e}");
        // And the other bad requests.
        for bad in [opts(2, 0, 0, 1.0), opts(2, 65, 2, 1.0), opts(2, 0, 2, f32::NAN)] {
            assert!(load_bonn(&r, &bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn names_parse_by_the_pattern() {
        assert_eq!(parse_view_folder("tv015_pv060"), Some(Angles { theta: 15, phi: 60 }));
        for bad in ["tv15_pv060", "tv015-pv060", "tv015_pv0600", "tvabc_pv000", "tv015_pv060_x", ""] {
            assert_eq!(parse_view_folder(bad), None, "{bad}");
        }
        let (l, v, k) = parse_image_name("00042 tl075 pl345 tv030 pv090.JPG").unwrap();
        assert_eq!((l, v, k), (Angles { theta: 75, phi: 345 }, Angles { theta: 30, phi: 90 }, ImageKind::Jpeg));
        assert_eq!(parse_image_name("1 tl000 pl000 tv000 pv000.exr").map(|r| r.2), Some(ImageKind::Exr));
        for bad in [
            "00042 tl075 pl345 tv030 pv090",
            "00042 tl075 pl345 tv030 pv090.tif",
            "00042  tl075 pl345 tv030 pv090.png",
            "00042 tl75 pl345 tv030 pv090.png",
            "00042 pl345 tl075 tv030 pv090.png",
            "a0042 tl075 pl345 tv030 pv090.png",
            "00042 tl075 pl345 tv030 pv090 x.png",
        ] {
            assert_eq!(parse_image_name(bad), None, "{bad}");
        }
    }
}
