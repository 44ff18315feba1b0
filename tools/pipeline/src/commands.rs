//! The smaller commands: `export-matrix` (Matrix Market files for SciPy and friends),
//! `diff` (image error between two EXR files), `btf` (synthesize a config's materials),
//! `generate`, `viz` and `view`.

use crate::error::{PipelineError, Result};
use crate::experiment::config::Experiment;
use crate::store::cache::StageCache;
use crate::store::shared::SharedFolder;
use crate::store::RunOptions;
use biscale_core::sampling::LightVector;
use biscale_core::scene::HdrImage;
use biscale_core::transfer::TransferMatrix;
use biscale_shading::image::{compare_exposed, error_image as error_image_of, resample, ImageMetrics, Resampling};
use std::path::Path;

/// Write `T.mtx` (coordinate, real, general; 1-based) and `L.mtx` (array N x 3, column-major)
/// into `dir`, both readable by `scipy.io.mmread`.
/// Other files in `dir` are left alone; one of these names that biscale did not write there is
/// an error before any work ([`SharedFolder`]).
pub fn export_matrix(exp: &Experiment, dir: &Path, opts: &RunOptions) -> Result<(TransferMatrix, LightVector)> {
    let about = format!("biscale export-matrix {}", exp.config_path.display());
    let names = ["T.mtx", "L.mtx", "mesh.obj", "view.json", "irradiance.csv"];
    let shared = SharedFolder::begin(dir, &about, &names)?;
    let staged = shared.path();
    let geometry = crate::stages::scene::load_geometry(exp)?;
    let lighting = crate::stages::scene::load_lighting(exp)?;
    let cache = StageCache::new(opts, dir);
    crate::estimate::check_transfer(exp, &geometry, cache.is_some(), "export-matrix")?;
    let t = crate::stages::transfer::transfer_matrix(exp, &geometry, cache.as_ref())?.into_whole("export-matrix")?;
    crate::interop::mtx::write_mtx(&t, &lighting.light, staged)?;
    write_scene(exp, &geometry, staged)?;
    write_irradiance(&t, &lighting.light, geometry.transfer.frames(), staged)?;
    shared.publish()?;
    Ok((t, lighting.light))
}

/// `irradiance.csv`: each vertex's direct irradiance from `T L` (RGB), with the paper's rule
/// (every texel of bin `j` weighted by `cosbar_j`: `sum_j cosbar_j L*_j`) and with each texel's
/// own cosine (`sum_k T L_k (n . d_k)`, `biscale_core::gather::moments`), both in f64: what an
/// external renderer's irradiance at the vertices is compared with.
fn write_irradiance(
    t: &TransferMatrix,
    light: &LightVector,
    frames: &[biscale_core::geometry::VertexFrame],
    dir: &Path,
) -> Result<()> {
    use std::fmt::Write as _;
    let Some(grid) = t.local_basis().grid() else { return Ok(()) };
    if light.cubemap().is_none() {
        return Ok(());
    }
    let paper = biscale_core::gather::reference_product(t, light);
    let exact = biscale_core::gather::moments::exact_cosine_product(t, light, frames)?;
    let m = grid.len();
    let cosbar = grid.mean_cosines();
    let mut csv = String::from("vertex,paper_r,paper_g,paper_b,exact_cosine_r,exact_cosine_g,exact_cosine_b\n");
    for v in 0..t.vertices() {
        let sum = |rows: &[[f64; 3]], c: usize| (0..m).map(|j| cosbar[j] * rows[v * m + j][c]).sum::<f64>();
        let _ = writeln!(
            csv,
            "{v},{:e},{:e},{:e},{:e},{:e},{:e}",
            sum(&paper, 0),
            sum(&paper, 1),
            sum(&paper, 2),
            sum(&exact, 0),
            sum(&exact, 1),
            sum(&exact, 2)
        );
    }
    biscale_core::io::write_atomic_bytes(&dir.join("irradiance.csv"), csv.as_bytes())?;
    Ok(())
}

/// `mesh.obj` and `view.json` beside the matrices, for an external renderer to see what biscale
/// sees: the mesh as every stage uses it (repaired, renumbered and placed; vertex `i` is T's
/// vertex `i`), each vertex's `vn` the normal T was traced with and faces `f a//a b//b c//c`,
/// so a reader that keeps indices needs no re-indexing; and the run's camera (full
/// resolution, in the mesh's coordinates) with the lighting's source.
fn write_scene(exp: &Experiment, geometry: &crate::stages::scene::Geometry, dir: &Path) -> Result<()> {
    use std::fmt::Write as _;
    let mesh = &geometry.mesh;
    let mut obj = String::from("# biscale's mesh: vertex i is T's vertex i, vn its traced normal\n");
    for p in &mesh.positions {
        let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
    }
    for f in geometry.transfer.frames() {
        let _ = writeln!(obj, "vn {} {} {}", f.normal.x, f.normal.y, f.normal.z);
    }
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i + 1);
        let _ = writeln!(obj, "f {a}//{a} {b}//{b} {c}//{c}");
    }
    let obj_path = dir.join("mesh.obj");
    biscale_core::io::write_atomic_bytes(&obj_path, obj.as_bytes())?;
    let cam = geometry.camera(exp, 1);
    let v3 = |v: glam::Vec3| [v.x, v.y, v.z];
    let l = &exp.file.lighting;
    let view = serde_json::json!({
        "camera": {
            "position": v3(cam.position),
            "target": v3(cam.target),
            "up": v3(cam.up),
            "fov_y_degrees": cam.fov_y_degrees,
            "width": cam.width,
            "height": cam.height,
            "pixel_centres": "ray through (x + 0.5, y + 0.5), row 0 at the top",
        },
        "env_map": exp.env_path.as_ref().map(|p| std::path::absolute(p).unwrap_or_else(|_| p.clone())),
        "constant": l.constant,
        "rotation_degrees": l.rotation_degrees,
        "sun_boost": l.sun_boost.as_ref().map(|b| *b.get_ref()),
        "placement": { "centre": [geometry.placement.centre.x, geometry.placement.centre.y, geometry.placement.centre.z], "scale": geometry.placement.scale },
    });
    let view_path = dir.join("view.json");
    let text = serde_json::to_string_pretty(&view).expect("plain JSON");
    biscale_core::io::write_atomic_bytes(&view_path, text.as_bytes())?;
    Ok(())
}

/// What `biscale diff` compares and writes besides the two images.
#[derive(Clone, Copy, Debug, Default)]
pub struct DiffOptions<'a> {
    /// Only the pixels where this PNG is white; it must have the reference's size.
    pub mask: Option<&'a Path>,
    /// Also write a false-colour error image (PNG) here: a new file, a PNG biscale wrote, or
    /// `-` for standard output ([`biscale_core::io::write_single_file`]).
    pub error_image: Option<&'a Path>,
    /// Replace a user's regular file at `error_image` (never a link, device, FIFO or folder,
    /// and never one of the images compared).
    pub force: bool,
    /// Exposure (stops) of the tone map the LDR figures are measured after.
    pub exposure: f32,
}

/// Compare two EXR images (`b` is the reference); optionally write a false-colour error image.
/// When the sizes differ, `a` is resampled to `b`'s ([`resample`]: a box filter when `a`'s
/// size is an integer multiple of `b`'s, else bilinear) and `warn` is told what was done; a
/// mask must still have the reference's size. `warn` also gets the files' read warnings.
pub fn diff(a: &Path, b: &Path, opts: DiffOptions<'_>, warn: &mut dyn FnMut(String)) -> Result<ImageMetrics> {
    if let Some(p) = opts.error_image {
        for input in [Some(a), Some(b), opts.mask].into_iter().flatten() {
            if biscale_core::io::same_file(p, input) {
                return Err(PipelineError::Core(biscale_core::CoreError::Refused {
                    path: p.into(),
                    message: format!("is {}, an input of this comparison; name another file", input.display()),
                }));
            }
        }
    }
    let (ia, wa) = HdrImage::read_exr(a)?;
    let (ib, wb) = HdrImage::read_exr(b)?;
    for w in wa.into_iter().chain(wb) {
        warn(w);
    }
    let mask = match opts.mask {
        Some(p) => {
            let (m, w, h) = biscale_core::scene::image::read_mask_png(p)?;
            if (w, h) != (ib.width, ib.height) {
                return Err(PipelineError::Mismatch {
                    path: p.to_path_buf(),
                    what: format!("the mask is {w}x{h}, the images {}x{} (the reference's size)", ib.width, ib.height),
                });
            }
            Some(m)
        }
        None => None,
    };
    let ia = match resample(&ia, ib.width, ib.height)? {
        (img, Resampling::None) => img,
        (img, how) => {
            warn(format!(
                "{} is {}x{}, the reference {} is {}x{}: {how} to {}x{} before comparing",
                a.display(),
                ia.width,
                ia.height,
                b.display(),
                ib.width,
                ib.height,
                ib.width,
                ib.height
            ));
            img
        }
    };
    let m = compare_exposed(&ia, &ib, mask.as_deref(), opts.exposure)?;
    if let Some(p) = opts.error_image {
        let (img, scale) = error_image_of(&ia, &ib, None)?;
        biscale_core::scene::image::write_rgb8_png_single(&img, p, opts.force)?;
        let to =
            if p.as_os_str() == "-" { "the error image to standard output".into() } else { p.display().to_string() };
        log::info!("wrote {to} (full scale = luminance error {scale:.4e})");
    }
    Ok(m)
}

/// Scenes `biscale generate` can write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GeneratedScene {
    /// A 6x6 grid plane (40x40 cells) with a unit sphere resting on it (1e-3 above, so no vertex is shared): the flat scene of the
    /// comparison (large coherent regions, one contact shadow).
    PlaneSphere,
    /// The grid plane alone (every vertex fully open: the largest biclusters).
    Plane,
    /// A temple of flat architectural pieces with five materials (`usemtl` ground, steps,
    /// columns, marble, roof) and planar texture coordinates: the several-BTF example.
    Temple,
    /// A chair on a wooden floor with three materials (`usemtl` floor, wood, fabric) and planar
    /// texture coordinates: Table I's "Chair" analogue in `biscale reproduce`.
    Chair,
}

/// Write a generated scene as OBJ ([`write_obj`]).
pub fn generate_scene(kind: GeneratedScene, out: &Path, force: bool) -> Result<biscale_core::geometry::Mesh> {
    use biscale_core::geometry::shapes;
    let mesh = match kind {
        GeneratedScene::PlaneSphere => shapes::merged(&[
            shapes::grid_plane(40, 6.0),
            shapes::uv_sphere(glam::Vec3::new(0.0, 1.001, 0.0), 1.0, 24, 48),
        ]),
        GeneratedScene::Plane => shapes::grid_plane(40, 6.0),
        GeneratedScene::Temple => crate::temple::build(&crate::temple::TempleOptions::default()),
        GeneratedScene::Chair => crate::chair::build(&crate::chair::ChairOptions::default()),
    };
    write_obj(&mesh, out, force)?;
    Ok(mesh)
}

/// Most triangles `generate subdivide` makes: 2^25 (about 1.2 GB in memory, counting the
/// triangles, the half as many vertices and the edge map of the last level).
pub const MAX_GENERATED_TRIANGLES: u64 = 1 << 25;

/// Write `levels` of midpoint subdivision of the OBJ or PLY `input` to `out` (an OBJ) (the scaling study's
/// denser meshes: same shape, about 4x the vertices per level), with `unweld` as a polygon
/// soup (`shapes::unweld`: three vertices per triangle, no shared edge). Refused up front
/// beyond [`MAX_GENERATED_TRIANGLES`] or when its memory estimate exceeds the available memory.
pub fn subdivide(
    input: &Path,
    levels: u32,
    unweld: bool,
    out: &Path,
    force: bool,
) -> Result<biscale_core::geometry::Mesh> {
    subdivide_within(input, levels, unweld, out, force, &crate::estimate::available()?)
}

/// [`subdivide`] with `available` bytes of memory: refused when
/// [`crate::estimate::subdivide_bytes`] is more.
pub fn subdivide_within(
    input: &Path,
    levels: u32,
    unweld: bool,
    out: &Path,
    force: bool,
    available: &crate::estimate::Available,
) -> Result<biscale_core::geometry::Mesh> {
    let mut mesh = biscale_core::geometry::Mesh::load(input)?.mesh;
    // Each level quadruples the triangles: refuse up front what would not fit, with the
    // estimate (a level too many took 15 GB before failing).
    let triangles = (mesh.triangle_count() as u128) << (2 * levels.min(40));
    if triangles > MAX_GENERATED_TRIANGLES as u128 {
        return Err(PipelineError::Core(biscale_core::CoreError::TooLarge(format!(
            "{}: {levels} levels of subdivision make {triangles} triangles (about {:.1} GB in memory), over the limit \
             of {MAX_GENERATED_TRIANGLES}; use fewer levels",
            input.display(),
            triangles as f64 * 36.0 / 1e9
        ))));
    }
    let estimate = crate::estimate::subdivide_bytes(
        mesh.triangle_count() as u64,
        mesh.vertex_count() as u64,
        mesh.uvs.is_some(),
        levels,
    ) + if unweld { crate::estimate::unweld_bytes(triangles as u64) } else { 0 };
    crate::estimate::refuse(
        &format!("{}: {levels} levels of subdivision", input.display()),
        estimate,
        &format!(" ({triangles} triangles and their OBJ text)"),
        available,
        "use fewer levels",
    )?;
    for _ in 0..levels {
        mesh = biscale_core::geometry::shapes::subdivide_midpoint(&mesh);
    }
    if unweld {
        mesh = biscale_core::geometry::shapes::unweld(&mesh);
    }
    write_obj(&mesh, out, force)?;
    Ok(mesh)
}

/// Write the OBJ or PLY `input`, as an OBJ, with cylindrical texture coordinates (about the vertical axis, in
/// world units; see `shapes::cylindrical_uvs`) to `out`, so patterned BTFs can tile on a mesh
/// that has none.
pub fn cylindrical_uv(input: &Path, out: &Path, force: bool) -> Result<biscale_core::geometry::Mesh> {
    let mesh = biscale_core::geometry::shapes::cylindrical_uvs(&biscale_core::geometry::Mesh::load(input)?.mesh);
    write_obj(&mesh, out, force)?;
    Ok(mesh)
}

/// Write `mesh` as an OBJ at a path the user names: a new file, an OBJ biscale wrote (its first
/// line is [`biscale_core::io::OBJ_MARK`]), a user's regular file only with `force`, or `-` for
/// standard output ([`biscale_core::io::write_single_file`]).
fn write_obj(mesh: &biscale_core::geometry::Mesh, out: &Path, force: bool) -> Result<()> {
    use biscale_core::io::{write_single_file, FileMark, OBJ_MARK};
    let text =
        format!("{OBJ_MARK} (biscale generate replaces this file only while this line leads it)\n{}", mesh.to_obj());
    Ok(write_single_file(out, FileMark::Obj, force, |f| {
        std::io::Write::write_all(f, text.as_bytes()).map_err(|e| e.to_string())
    })?)
}

/// `biscale viz`: the matrix-structure pictures of a config's scene (transfer matrix from the
/// cache when present, biclustered with default settings) written into `out`.
pub fn viz(
    exp: &Experiment,
    out: &Path,
    first: Option<usize>,
    count: usize,
    opts: &RunOptions,
) -> Result<Vec<std::path::PathBuf>> {
    use crate::viz::{self, HeatmapOptions, PatchLayout, PatchView};
    use biscale_compressors::bicluster::{analysis, Bicluster};
    let cerr = |source| PipelineError::Compress { name: biscale_compressors::bicluster::KIND.name.into(), source };
    use biscale_core::compress::{CompressContext, Compressor};
    let about = format!("biscale viz {}", exp.config_path.display());
    let names = VIZ_FILES.map(|(name, _)| name);
    let shared = SharedFolder::begin(out, &about, &names)?;
    let cache = StageCache::new(opts, out);
    let out = shared.path();
    let geometry = crate::stages::scene::load_geometry(exp)?;
    crate::estimate::check_transfer(exp, &geometry, cache.is_some(), "viz")?;
    let t = crate::stages::transfer::transfer_matrix(exp, &geometry, cache.as_ref())?.into_whole("viz")?;
    let form = Bicluster::default()
        .compress(&t, &CompressContext { seed: exp.file.seed, progress: None, sweep: None })
        .map_err(cerr)?;
    let count = count.clamp(1, t.vertices().max(1));
    let first = match first {
        Some(f) => f,
        None => analysis::most_shared_window(&form, count).map_err(cerr)?,
    };
    let panels = PatchView { first_vertex: first, vertices: count, layout: PatchLayout::CubemapPanels, cell: 4 };
    let mut written = vec![
        viz::write_sparsity(&t, &panels, &out.join("sparsity_panels.png"))?,
        viz::write_bicluster_patch(&t, &form, &panels, &out.join("biclusters_panels.png"))?,
        viz::write_bicluster_size_histograms(&form, &out.join("bicluster_sizes.png"))?,
        viz::write_value_histograms(&t, Some(&form), &out.join("values.png"))?,
    ];
    let camera = geometry.camera(exp, 1);
    let heat = HeatmapOptions::default();
    let cost = analysis::gather_cost_per_vertex(&form).map_err(cerr)?;
    let nnz = viz::nnz_per_vertex(&t);
    written.push(viz::write_vertex_heatmap(
        &geometry.mesh,
        &camera,
        &cost,
        "gather flops per vertex (biclusters)",
        &heat,
        &out.join("heat_gather_cost.png"),
    )?);
    written.push(viz::write_vertex_heatmap(
        &geometry.mesh,
        &camera,
        &nnz,
        "non-zeros of T per vertex",
        &heat,
        &out.join("heat_nnz.png"),
    )?);
    debug_assert!(written.iter().all(|p| names.iter().any(|n| p.ends_with(n))), "VIZ_FILES lists {written:?}");
    let published = shared.publish()?;
    Ok(written.iter().map(|p| published.path(p)).collect())
}

/// The files `biscale viz` writes, with what each shows.
pub const VIZ_FILES: [(&str, &str); 6] = [
    ("sparsity_panels.png", "T's non-zeros over a window of vertices, as cube-map panels"),
    ("biclusters_panels.png", "the same window, coloured by bicluster"),
    ("bicluster_sizes.png", "histograms of bicluster rows and columns"),
    ("values.png", "histograms of T's values and the biclusters' values"),
    ("heat_gather_cost.png", "gather flops per vertex, on the mesh"),
    ("heat_nnz.png", "non-zeros of T per vertex, on the mesh"),
];

/// The viewer's starting exposure: `[report] exposure`, or 0 stops for `"auto"`, which a run
/// resolves from its uncompressed render (the viewer's +/- keys change it).
#[cfg(feature = "viewer")]
fn viewer_exposure(exp: &Experiment) -> f32 {
    exp.file.report.exposure.stops().unwrap_or_else(|| {
        log::info!(
            "view: `[report] exposure = \"auto\"` is chosen by a run; the viewer starts at 0 stops (+/- change it)"
        );
        0.0
    })
}

/// `biscale view`: open the interactive viewer on a config's scene with every compressor it
/// names (feature `viewer`), or with the `[[methods]]` setting labelled `method` (the
/// low-frequency method: the sky is rotated in SH). `screenshot` renders a few frames into a
/// PNG and exits.
#[cfg(feature = "viewer")]
pub fn view(
    exp: &Experiment,
    method: Option<&str>,
    screenshot: Option<std::path::PathBuf>,
    opts: &RunOptions,
) -> Result<()> {
    use biscale_gpu::{Screenshot, ViewerForm, ViewerSetup};
    let plan = crate::plan::Plan::new(exp);
    let method = match method {
        Some(label) => {
            let settings = exp.method_settings();
            let Some(setting) = settings.iter().find(|m| m.label == label) else {
                let names: Vec<&str> = settings.iter().map(|m| m.label.as_str()).collect();
                return Err(PipelineError::Mismatch {
                    path: exp.config_path.clone(),
                    what: format!("no [[methods]] setting is labelled {label}; this config has {names:?}"),
                });
            };
            Some(setting)
        }
        None => None,
    };
    let out = opts.out_dir.clone().unwrap_or_else(|| Path::new("out").join(exp.name()));
    let geometry = crate::stages::scene::load_geometry(exp)?;
    let lighting = crate::stages::scene::load_lighting(exp)?;
    let cache = StageCache::new(opts, &out);
    crate::estimate::check_transfer(exp, &geometry, cache.is_some(), "view")?;
    let t = crate::stages::transfer::transfer_matrix(exp, &geometry, cache.as_ref())?;
    let (scene, materials) = crate::stages::scene::shade_scene(exp, &geometry, t.view().local_basis(), cache.as_ref())?;
    let mut forms = vec![];
    let (scene, light_basis) = match method {
        Some(setting) => {
            let src = crate::stages::sh::MethodScene { exp, geometry: &geometry, scene: &scene, cache: cache.as_ref() };
            let p = crate::stages::sh::prepare(setting, &src, None)?;
            let kernels = p
                .compressor
                .kernels(&p.form)
                .map_err(|source| PipelineError::Compress { name: setting.label.clone(), source })?;
            let basis = p.matrix.light_basis();
            forms.push(ViewerForm { label: setting.label.clone(), form: p.form, kernels });
            (p.scene, basis)
        }
        None => (scene, t.view().light_basis()),
    };
    for setting in plan.compressors.iter().filter(|_| method.is_none()) {
        let c = crate::stages::transfer::build_compressor(setting)?;
        let (form, _) = crate::stages::transfer::compressed_form(
            setting,
            c.as_ref(),
            t.whole("the viewer's forms")?,
            &t.key,
            (exp.file.seed, None),
            cache.as_ref(),
        )?;
        let kernels =
            c.kernels(&form).map_err(|source| PipelineError::Compress { name: setting.label.clone(), source })?;
        forms.push(ViewerForm { label: setting.label.clone(), form, kernels });
    }
    let setup = ViewerSetup {
        title: format!("biscale: {}", exp.name()),
        camera: geometry.camera(exp, 1),
        scene,
        forms,
        initial_form: 0,
        env: lighting.env,
        light_basis,
        env_rotation: lighting.rotation,
        sun_boost: exp.file.lighting.sun_boost.as_ref().map(|b| *b.get_ref()),
        exposure: viewer_exposure(exp),
        background: exp.file.report.background,
        screenshot: screenshot.map(|path| Screenshot { path, frames: 5 }),
        continuous: false,
        // As a run: the compressors' forms resolve the light's moments, the SH methods (no
        // texels, no bins) ignore them.
        light_moments: exp.file.runtime.light_moments && method.is_none(),
        // The config's resolve (key M cycles); the SH methods resolve nothing.
        moments_resolve: match method {
            None => exp.file.runtime.moments_resolve().unwrap_or_default(),
            Some(_) => Default::default(),
        },
        analytic: match method {
            None => materials.analytic,
            Some(_) => vec![],
        },
    };
    Ok(biscale_gpu::run_viewer(setup)?)
}

/// One file written by [`btf`].
pub struct BtfWritten {
    pub label: String,
    pub path: std::path::PathBuf,
    pub preview: Option<std::path::PathBuf>,
    pub origin: crate::stages::materials::Origin,
    pub bytes: u64,
    /// With `preview`, one sheet per compressed representation of the material: dense,
    /// compressed and |error| side by side.
    pub comparisons: Vec<Comparison>,
}

/// A written comparison sheet ([`biscale_shading::synth::comparison_sheet`]).
pub struct Comparison {
    pub path: std::path::PathBuf,
    /// The representation's label.
    pub representation: String,
    /// How much brighter the error panel is drawn than the others.
    pub error_gain: f32,
    /// Relative RMS error of the whole table.
    pub relative_rms_error: f64,
}

/// `biscale btf`: build the BTF of each material of `exp` (or only the one named `only`):
/// synthesized ones are ray traced or taken from the cache; write each as `<out>/<label>.btf`
/// (its configured encoding; f32 for analytic ones) and, with `preview`, a contact sheet
/// `<out>/<label>_preview.png` (rows: views from overhead to grazing; columns: lights from
/// overhead to grazing, from the +X side) and, for every compressed representation the entry
/// lists, `<out>/<label>_<representation>_compare.png`: dense, compressed and |error| sheets
/// side by side.
pub fn btf(
    exp: &Experiment,
    out: &Path,
    only: Option<&str>,
    preview: bool,
    opts: &RunOptions,
) -> Result<Vec<BtfWritten>> {
    use crate::experiment::config::MaterialConfig;
    use biscale_shading::synth::{contact_sheet, save_btf, BtfEncoding};
    let configs = exp.materials();
    let chosen: Vec<&MaterialConfig> = configs.iter().filter(|c| only.is_none_or(|n| c.name() == Some(n))).collect();
    if chosen.is_empty() {
        let named: Vec<_> = configs.iter().map(|c| c.label()).collect();
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!("no material named {:?} (materials: {})", only.unwrap_or_default(), named.join(", ")),
        });
    }
    let about = format!("biscale btf {}", exp.config_path.display());
    let names: Vec<String> =
        chosen.iter().map(|c| format!("{}.btf", crate::interop::material_stem(&c.label()))).collect();
    let shared = SharedFolder::begin(out, &about, &names.iter().map(String::as_str).collect::<Vec<_>>())?;
    let cache = StageCache::new(opts, out);
    let out = shared.path();
    let local_basis = exp.transfer_settings().local_basis();
    let mut written = vec![];
    let mut taken = Default::default();
    for cfg in chosen {
        let label = cfg.label();
        let stem = crate::interop::material_stem(&label);
        let path = out.join(format!("{stem}.btf"));
        crate::interop::claim_stem(&mut taken, &stem, &label, &path)?;
        let (btf, origin) = crate::stages::materials::material_btf(cfg, local_basis, cache.as_ref(), &label)?;
        let encoding = match cfg {
            MaterialConfig::Synthesized(s) => BtfEncoding::from_name(&s.encoding)?,
            _ => BtfEncoding::F32,
        };
        save_btf(&btf, &path, encoding)?;
        let light_grid = btf.local_basis().grid();
        let lights = light_grid.map_or(vec![0], |g| sweep_bins(&g));
        let views = btf.view_grid().as_ref().map_or(vec![0], sweep_bins);
        let labels = SheetLabels::of(&btf, &lights, &views);
        let mut comparisons = vec![];
        let preview_path = if preview {
            let p = out.join(format!("{stem}_preview.png"));
            let sheet = contact_sheet(&btf, &lights, &views)?;
            let title = format!("{label}: texels by light (columns) and view (rows), brightest value white");
            labels.write(&sheet, 1, &title, &[], &p)?;
            for &repr in cfg.representations().all() {
                if repr == crate::experiment::config::RepresentationSetting::Dense {
                    continue;
                }
                let (r, record) =
                    crate::stages::materials::represent(&btf, repr, exp.file.seed, cache.as_ref(), &label)?;
                let decoded = r.to_dense()?;
                let (img, error_gain) = biscale_shading::synth::comparison_sheet(&btf, &decoded, &lights, &views)?;
                let path = out.join(format!("{stem}_{}_compare.png", record.representation));
                let title = format!(
                    "{label}: dense, {} and their difference (x {error_gain:.1}), table rel. RMS error {:.2}%",
                    record.representation,
                    100.0 * record.relative_rms_error
                );
                let panels =
                    ["dense".to_string(), record.representation.clone(), format!("|difference| x {error_gain:.1}")];
                labels.write(&img, 3, &title, &panels, &path)?;
                comparisons.push(Comparison {
                    path,
                    representation: record.representation,
                    error_gain,
                    relative_rms_error: record.relative_rms_error,
                });
            }
            Some(p)
        } else {
            None
        };
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        written.push(BtfWritten { label, path, preview: preview_path, origin, bytes, comparisons });
    }
    let published = shared.publish()?;
    for w in &mut written {
        w.path = published.path(&w.path);
        w.preview = w.preview.as_deref().map(|p| published.path(p));
        for c in &mut w.comparisons {
            c.path = published.path(&c.path);
        }
    }
    Ok(written)
}

/// The column (light bin) and row (view sample) labels of a BTF's contact sheets: each bin's
/// index and elevation above the surface.
struct SheetLabels {
    columns: Vec<String>,
    rows: Vec<String>,
}

impl SheetLabels {
    fn of(btf: &biscale_core::scene::Btf, lights: &[usize], views: &[usize]) -> Self {
        let label = |what: &str, grid: Option<biscale_core::sampling::HemisphereGrid>, bins: &[usize]| {
            (bins.iter())
                .map(|&b| match grid {
                    Some(g) => {
                        let up = g.bin_direction(b as u32).z.clamp(-1.0, 1.0).asin().to_degrees();
                        format!("{what} {b}\n{up:.0}° up")
                    }
                    None => format!("{what} {b}"),
                })
                .collect()
        };
        SheetLabels {
            columns: label("light", btf.local_basis().grid(), lights),
            rows: match btf.view_grid() {
                Some(g) => label("view", Some(g), views),
                None => vec!["any view".to_string()],
            },
        }
    }

    /// `sheet` (`panels` contact sheets side by side, [`COMPARISON_GAP`] apart) labelled and
    /// written as a PNG at `path`.
    ///
    /// [`COMPARISON_GAP`]: biscale_shading::synth::COMPARISON_GAP
    fn write(&self, sheet: &image::RgbImage, panels: u32, title: &str, names: &[String], path: &Path) -> Result<()> {
        let layout = crate::plots::SheetLayout {
            panels,
            panel_gap: biscale_shading::synth::COMPARISON_GAP,
            rows: self.rows.len() as u32,
            columns: self.columns.len() as u32,
        };
        let img =
            crate::plots::labelled_sheet(sheet, layout, title, names, &self.columns, &self.rows).map_err(|what| {
                PipelineError::Mismatch { path: path.to_path_buf(), what: format!("contact sheet: {what}") }
            })?;
        Ok(biscale_core::scene::image::write_rgb8_png(&img, path)?)
    }
}

/// Up to four distinct bins of `grid` from overhead to grazing along +X (elevations 90, 60,
/// 35 and 12 degrees): the rows and columns of a contact sheet.
fn sweep_bins(grid: &biscale_core::sampling::HemisphereGrid) -> Vec<usize> {
    let mut bins: Vec<usize> = vec![];
    for elevation in [90.0f32, 60.0, 35.0, 12.0] {
        let e = elevation.to_radians();
        let d = glam::Vec3::new(e.cos(), 0.0, e.sin());
        let best = (0..grid.len() as u32)
            .max_by(|&a, &b| grid.bin_direction(a).dot(d).total_cmp(&grid.bin_direction(b).dot(d)))
            .unwrap_or(0) as usize;
        if !bins.contains(&best) {
            bins.push(best);
        }
    }
    bins
}

#[cfg(test)]
mod tests {
    #[test]
    fn subdividing_past_the_triangle_limit_is_refused_up_front() {
        // Regression (hostile input): `generate subdivide --levels 9` ran to 15 GB.
        let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/bunny.obj");
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("dense.obj");
        let e = super::subdivide(&bunny, 9, false, &out, false).unwrap_err().to_string();
        // 3,674 triangles x 4^9.
        assert!(e.contains("963117056 triangles") && e.contains("fewer levels"), "{e}");
        assert!(!out.exists());
        let mesh = super::subdivide(&bunny, 1, false, &out, false).unwrap();
        assert_eq!(mesh.triangle_count(), 4 * 3674);
        // The soup keeps three vertices per triangle through the welding loader.
        let soup = super::subdivide(&bunny, 0, true, &out, false).unwrap();
        assert_eq!((soup.vertex_count(), soup.triangle_count()), (3 * 3674, 3674));
        let loaded = biscale_core::geometry::Mesh::load(&out).unwrap().mesh;
        assert_eq!(loaded.vertex_count(), 3 * 3674);
    }

    #[test]
    fn subdividing_past_the_available_memory_is_refused_up_front() {
        use crate::estimate::{subdivide_bytes, Available};
        let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/bunny.obj");
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("dense.obj");
        // Three levels (235,136 triangles) are well under the triangle limit; with less memory
        // than their estimate they are refused, naming the estimate and what to change.
        let needed = subdivide_bytes(3674, 1839, false, 3);
        let short = Available { bytes: needed - 1, source: "test" };
        let e = super::subdivide_within(&bunny, 3, false, &out, false, &short).unwrap_err().to_string();
        assert!(e.contains("3 levels of subdivision needs about") && e.contains("235136 triangles"), "{e}");
        assert!(e.contains("available (test); use fewer levels"), "{e}");
        assert!(!out.exists());
        let enough = Available { bytes: needed, source: "test" };
        assert_eq!(
            super::subdivide_within(&bunny, 3, false, &out, false, &enough).unwrap().triangle_count(),
            64 * 3674
        );
        // The written file is within the estimate's text and mesh allowance.
        assert!(std::fs::metadata(&out).unwrap().len() < needed);
        // Unwelding adds three vertices, uvs and their text per triangle: what was enough for
        // the welded mesh is refused, the estimate with the soup's share is not.
        let soup = dir.path().join("soup.obj");
        let e = super::subdivide_within(&bunny, 3, true, &soup, false, &enough).unwrap_err().to_string();
        assert!(e.contains("3 levels of subdivision needs about"), "{e}");
        assert!(!soup.exists());
        let needed_soup = needed + crate::estimate::unweld_bytes(64 * 3674);
        let soup_enough = Available { bytes: needed_soup, source: "test" };
        let mesh = super::subdivide_within(&bunny, 3, true, &soup, false, &soup_enough).unwrap();
        assert_eq!(mesh.vertex_count(), 3 * 64 * 3674);
        assert!(std::fs::metadata(&soup).unwrap().len() < needed_soup);
    }

    #[test]
    fn diff_resamples_a_larger_image_and_refuses_a_mask_of_another_size() {
        use super::{diff, DiffOptions};
        use biscale_core::scene::HdrImage;
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
        let pixels = (0..60).map(|i| [i as f32 * 0.02, (i % 7) as f32 * 0.1, 1.0 / (1 + i) as f32]).collect();
        let reference = HdrImage { width: 10, height: 6, pixels };
        // A 2x nearest upsample: the 2x2 box filter gives the reference back exactly.
        let up = HdrImage {
            width: 20,
            height: 12,
            pixels: (0..240).map(|i| reference.pixels[(i / 20 / 2) * 10 + (i % 20) / 2]).collect(),
        };
        up.write_exr(&a).unwrap();
        reference.write_exr(&b).unwrap();
        let mut warnings = vec![];
        let m = diff(&a, &b, DiffOptions::default(), &mut |w| warnings.push(w)).unwrap();
        assert_eq!((m.rmse, m.ssim, m.ldr_psnr, m.flip, m.pixels), (0.0, 1.0, f64::INFINITY, 0.0, 60));
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("is 20x12, the reference") && warnings[0].contains("2x2 pixel blocks"),
            "{warnings:?}"
        );
        // Not a multiple: bilinear, said so.
        let mut odd = up.clone();
        (odd.width, odd.height, odd.pixels) = (15, 9, up.pixels[..135].to_vec());
        odd.write_exr(&a).unwrap();
        warnings.clear();
        diff(&a, &b, DiffOptions::default(), &mut |w| warnings.push(w)).unwrap();
        assert!(warnings[0].contains("is 15x9") && warnings[0].contains("bilinearly"), "{warnings:?}");
        // A mask must have the reference's size, even at the first image's.
        let mask = dir.path().join("mask.png");
        image::GrayImage::from_pixel(15, 9, image::Luma([255])).save(&mask).unwrap();
        let opts = DiffOptions { mask: Some(&mask), ..Default::default() };
        let e = diff(&a, &b, opts, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains("mask.png") && e.contains("the mask is 15x9, the images 10x6"), "{e}");
        image::GrayImage::from_pixel(10, 6, image::Luma([255])).save(&mask).unwrap();
        assert_eq!(diff(&a, &b, opts, &mut |_| {}).unwrap().pixels, 60);
    }

    use std::path::Path;
}
