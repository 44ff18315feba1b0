//! The SH method's run (Sloan et al. 2003): `M_p` traced and compressed, the light in SH, the
//! radiance transfer textures, and its record beside the all-frequency compressors'.
//! The parameters are [`crate::experiment::methods::sh::ShParams`].

use crate::error::{PipelineError, Result};
use crate::experiment::config::{Experiment, MethodSetting, Setting};
use crate::experiment::methods::sh::{ShParams, KIND};
use crate::metrics::{MethodRecord, RttRecord, ShRecord, ShTransferRecord};
use crate::stages::evaluate::{Evaluation, GpuBackend};
use crate::stages::scene::{Geometry, Lighting};
use crate::stages::transfer::{build_compressor, compressed_form, Transfer};
use crate::stages::view::{timed, Reference, View};
use crate::store::cache::{CacheKey, StageCache};
use crate::util::progress_bar;
use biscale_core::gather::reference_product;
use biscale_core::io::ContentHash;
use biscale_core::scene::{Material, Render, ShadeScene};
use biscale_core::sh::light::LIGHT_SUBTEXELS;
use biscale_core::sh::rtt::{irradiance_btf, radiance_transfer};
use biscale_core::sh::{clamped_cosine, ShOrder, ShProjection};
use biscale_core::transfer::sh::{
    add_bounces, build_sh, irradiance_transfer, sh_from_transfer_vertices, ShTransferSettings,
};
use biscale_core::transfer::TransferMatrix;
use biscale_shading::image::compare;

/// Every `FROM_T_STRIDE`-th vertex is projected from `T` to check the agreement of the methods.
pub const FROM_T_STRIDE: usize = 8;

/// What a method setting is measured with: the all-frequency run's scene, light, baseline
/// image, reference and view.
pub(crate) struct MethodInputs<'a> {
    pub exp: &'a Experiment,
    pub geometry: &'a Geometry,
    pub lighting: &'a Lighting,
    /// The all-frequency `T` (for the agreement check) and the scene on its local basis.
    pub t: &'a Transfer,
    pub scene: &'a ShadeScene,
    /// The uncompressed all-frequency image.
    pub baseline: &'a Render,
    pub view: &'a View<'a>,
    pub reference: Option<&'a Reference>,
    pub cache: Option<&'a StageCache>,
    pub repeats: usize,
    pub exposure: f32,
    pub out_dir: &'a std::path::Path,
}

/// What the method is built from: the all-frequency run's mesh, transfer scene and materials.
pub(crate) struct MethodScene<'a> {
    pub exp: &'a Experiment,
    pub geometry: &'a Geometry,
    /// The materials on `T`'s local basis (the method projects their BTFs).
    pub scene: &'a ShadeScene,
    pub cache: Option<&'a StageCache>,
}

impl<'a> MethodInputs<'a> {
    fn method_scene(&self) -> MethodScene<'a> {
        MethodScene { exp: self.exp, geometry: self.geometry, scene: self.scene, cache: self.cache }
    }
}

/// One SH setting built and ready to gather and shade: the compressed `M` (or the transfer
/// vectors of the diffuse case), the scene on the method's local basis and the records of the
/// build.
pub(crate) struct Prepared {
    pub params: ShParams,
    pub settings: ShTransferSettings,
    /// The transfer the form compresses (`M`, or `c^T M_p` per vertex when diffuse).
    pub matrix: TransferMatrix,
    pub transfer: ShTransferRecord,
    pub rtt: RttRecord,
    pub diffuse: bool,
    /// The setting as a compressor setting (label, kind, parameters) and its compressor.
    pub compressor_setting: Setting,
    pub compressor: Box<dyn biscale_core::compress::Compressor>,
    pub form: biscale_core::compress::CompressedForm,
    /// The form came from the cache.
    pub cached: bool,
    /// The mesh with the method's materials (radiance transfer textures or irradiance BTFs).
    pub scene: ShadeScene,
}

/// Build one SH setting: `M` (traced or cached, with its bounces), the method's materials and
/// the compressed form. With `t`, the direct `M` is also compared with `M` projected from `T`
/// (`transfer.from_t_difference`; NaN without).
pub(crate) fn prepare(setting: &MethodSetting, src: &MethodScene<'_>, t: Option<&Transfer>) -> Result<Prepared> {
    let label = &setting.label;
    let bad =
        |e: String| PipelineError::Mismatch { path: src.exp.config_path.clone(), what: format!("method {label}: {e}") };
    let params = ShParams::parse(&setting.params).map_err(bad)?;
    let settings = ShTransferSettings::new(params.order, params.rays, src.exp.file.seed)?;
    let order = settings.order();
    let (m, key, mut transfer) = sh_transfer(src, label, &settings)?;
    // The bridge to T is checked on the direct transfer (T has no interreflection).
    if let Some(t) = t {
        transfer.from_t_difference = from_t_difference(src, t, &m, order)?;
    }
    let (m, key) = match params.bounces {
        0 => (m, key),
        b => bounced(src, label, &settings, m, b, &mut transfer)?,
    };
    let (materials, rtt, diffuse) = method_materials(src.scene, order)?;
    // Diffuse: the transfer vectors t_p = c^T M_p stand in for the matrices.
    let (matrix, key) = match diffuse {
        true => (irradiance_transfer(&m)?, key.derived("irradiance transfer vectors c^T M_p")),
        false => (m, key),
    };
    if diffuse {
        log::info!("{label}: every material is Lambertian: shadowed diffuse PRT, a transfer vector per vertex");
    }
    let (ckind, cparams) = params.compressor();
    let compressor_setting = Setting { label: label.clone(), kind: ckind, params: cparams };
    let compressor = build_compressor(&compressor_setting)?;
    let (form, cached) =
        compressed_form(&compressor_setting, compressor.as_ref(), &matrix, &key, (src.exp.file.seed, None), src.cache)?;
    let scene = src.scene.with_materials(materials)?;
    Ok(Prepared {
        params,
        settings,
        matrix,
        transfer,
        rtt,
        diffuse,
        compressor_setting,
        compressor,
        form,
        cached,
        scene,
    })
}

/// The direct (shadowed) `M` for `settings`, ray traced or from the cache, its cache key and
/// its record.
fn sh_transfer(
    inp: &MethodScene<'_>,
    label: &str,
    settings: &ShTransferSettings,
) -> Result<(TransferMatrix, CacheKey, ShTransferRecord)> {
    let mesh = &inp.geometry.mesh;
    let key = crate::store::cache::sh_transfer_key(mesh, settings, 0, 0);
    let record = |m: &TransferMatrix, seconds: f64, rays_traced: u64, cached: bool| ShTransferRecord {
        seconds,
        rays_traced,
        cached,
        nnz: m.nnz(),
        from_t_difference: f64::NAN,
        from_t_stride: FROM_T_STRIDE,
    };
    if let Some(m) = cached_sh(inp, label, settings, &key) {
        let r = record(&m, 0.0, 0, true);
        return Ok((m, key, r));
    }
    let vertices = mesh.vertex_count();
    let pb = progress_bar(vertices as u64, &format!("{label} transfer"));
    let tick = |done: usize| pb.set_position(done as u64);
    let build = build_sh(&inp.geometry.transfer, settings, 0..vertices, Some(&tick))?;
    pb.finish_and_clear();
    log::info!(
        "{label}: SH transfer {} x {} ({} rays per vertex) in {:.2} s ({:.1} M rays/s)",
        build.matrix.rows(),
        build.matrix.cols(),
        settings.rays(),
        build.seconds,
        build.rays_traced as f64 / build.seconds.max(1e-12) / 1e6
    );
    if let Some(c) = inp.cache {
        c.put_with(&c.sh_transfer_path(&key, settings.order().n()), &key, || build.matrix.to_artifact());
    }
    let r = record(&build.matrix, build.seconds, build.rays_traced, false);
    Ok((build.matrix, key, r))
}

/// The SH transfer cached under `key`, if the cache has a usable one.
fn cached_sh(
    inp: &MethodScene<'_>,
    label: &str,
    settings: &ShTransferSettings,
    key: &CacheKey,
) -> Option<TransferMatrix> {
    let c = inp.cache?;
    let (local, light) = settings.bases();
    let shape = biscale_core::basis::TransferShape::new(inp.geometry.mesh.vertex_count(), local, light);
    let path = c.sh_transfer_path(key, settings.order().n());
    let accept = |m: &TransferMatrix| match m.shape() == shape {
        true => Ok(()),
        false => Err(format!("{}: holds {}, this run needs {shape}", path.display(), m.shape())),
    };
    let m = c.get(&path, key, TransferMatrix::from_artifact, accept)?;
    log::info!("{label}: SH transfer loaded from cache {}", path.display());
    Some(m)
}

/// The bounce albedo of every triangle: its material's mean reflectance under uniform light
/// (`sum_j b_j omega_j` averaged over texels, views and RGB), at most 1.
fn bounce_albedo(scene: &ShadeScene) -> Vec<f32> {
    let per_material: Vec<f32> = scene
        .materials()
        .iter()
        .map(|m| {
            let Ok(btf) = m.btf.to_dense() else { return 0.0 };
            let omega = btf.local_basis().grid().map_or(0.0, |g| g.bin_solid_angle());
            let groups = (btf.data().len() / btf.light_count().max(1)).max(1);
            let total: f64 = btf.data().iter().flatten().map(|&x| x as f64 * omega).sum();
            (total / (3 * groups) as f64).clamp(0.0, 1.0) as f32
        })
        .collect();
    let triangles = scene.mesh().triangle_count();
    match scene.triangle_materials() {
        Some(ids) => ids.iter().map(|&i| per_material[i as usize]).collect(),
        None => vec![per_material[0]; triangles],
    }
}

/// `direct` with `bounces` bounces of interreflection (cached under its own key).
fn bounced(
    inp: &MethodScene<'_>,
    label: &str,
    settings: &ShTransferSettings,
    direct: TransferMatrix,
    bounces: u32,
    record: &mut ShTransferRecord,
) -> Result<(TransferMatrix, CacheKey)> {
    let albedo = bounce_albedo(inp.scene);
    let mut h = ContentHash::default();
    for a in &albedo {
        h.write(&a.to_le_bytes());
    }
    let key = crate::store::cache::sh_transfer_key(&inp.geometry.mesh, settings, bounces, h.finish128());
    if let Some(m) = cached_sh(inp, label, settings, &key) {
        return Ok((m, key));
    }
    let start = std::time::Instant::now();
    let m = add_bounces(&inp.geometry.transfer, &inp.geometry.mesh.triangles, settings, &direct, &albedo, bounces)?;
    let seconds = start.elapsed().as_secs_f64();
    log::info!("{label}: {bounces} interreflection bounce(s) in {seconds:.2} s");
    record.seconds += seconds;
    record.cached = false;
    record.nnz = m.nnz();
    if let Some(c) = inp.cache {
        c.put_with(&c.sh_transfer_path(&key, settings.order().n()), &key, || m.to_artifact());
    }
    Ok((m, key))
}

/// The scene's materials on the method's local basis, and whether the scene is diffuse: when
/// every BTF is Lambertian in shape, each becomes one value per texel in the irradiance basis
/// (shadowed diffuse PRT); otherwise each is projected onto local SH (its radiance transfer
/// texture).
fn method_materials(scene: &ShadeScene, order: ShOrder) -> Result<(Vec<Material>, RttRecord, bool)> {
    let diffuse: Option<Vec<Material>> = scene
        .materials()
        .iter()
        .map(|m| {
            Ok(irradiance_btf(&*m.btf.to_dense()?, order)?.map(|btf| Material { btf: btf.into(), tiling: m.tiling }))
        })
        .collect::<Result<Option<Vec<_>>>>()?;
    if let Some(materials) = diffuse {
        // The only loss is the clamped cosine's truncation: |c - P_n c| / |c|, |c|^2 = 2 pi / 3.
        let c2: f64 = clamped_cosine(order).iter().map(|c| c * c).sum();
        let projection_error = (1.0 - c2 / (2.0 * std::f64::consts::PI / 3.0)).max(0.0).sqrt();
        let bytes = materials.iter().map(|m| m.btf.bytes()).sum();
        return Ok((materials, RttRecord { bytes, projection_error, quadrature_error: 0.0 }, true));
    }
    let mut out = vec![];
    let mut rec = RttRecord { bytes: 0, projection_error: 0.0, quadrature_error: 0.0 };
    for m in scene.materials() {
        let (btf, report) = radiance_transfer(&m.btf, order)?;
        rec.bytes += btf.bytes();
        rec.projection_error = rec.projection_error.max(report.projection_error);
        rec.quadrature_error = rec.quadrature_error.max(report.quadrature_error);
        out.push(Material { btf, tiling: m.tiling });
    }
    Ok((out, rec, false))
}

/// Relative Frobenius difference between `M` projected from the all-frequency `T` and the
/// traced `m`, over every `FROM_T_STRIDE`-th vertex.
fn from_t_difference(inp: &MethodScene<'_>, t: &Transfer, m: &TransferMatrix, order: ShOrder) -> Result<f64> {
    let vertices: Vec<usize> = (0..m.vertices()).step_by(FROM_T_STRIDE).collect();
    let projected = sh_from_transfer_vertices(t.whole("SH from T")?, inp.geometry.transfer.frames(), order, &vertices)?;
    let n = order.len();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (b, &v) in projected.iter().zip(&vertices) {
        for i in 0..n {
            let mut traced = vec![0.0f64; n];
            if let Some(row) = m.csr().outer_view(v * n + i) {
                for (j, &x) in row.iter() {
                    traced[j] = x as f64;
                }
            }
            for j in 0..n {
                num += (b[i * n + j] - traced[j]).powi(2);
                den += traced[j].powi(2);
            }
        }
    }
    Ok(biscale_core::stats::relative_l2(num, den))
}

/// Run one SH setting against the all-frequency run's inputs: its record.
pub(crate) fn evaluate(
    setting: &MethodSetting,
    inp: &MethodInputs<'_>,
    gpu: Option<&GpuBackend>,
    animate: bool,
) -> Result<(MethodRecord, biscale_core::scene::Render, Option<crate::stages::animation::Animated<'static>>)> {
    let label = &setting.label;
    let Prepared {
        params: p,
        settings,
        matrix: m,
        transfer,
        rtt,
        diffuse,
        compressor_setting: csetting,
        compressor,
        form,
        cached,
        scene: sh_scene,
    } = prepare(setting, &inp.method_scene(), Some(inp.t))?;
    let order = settings.order();
    let projection = ShProjection::new(inp.exp.transfer_settings().cubemap(), order, LIGHT_SUBTEXELS);
    let light = projection.project(&inp.lighting.light)?;
    let light_projection_error = projection.projection_error(&inp.lighting.light)?;
    let view = inp.view.with(&sh_scene, inp.view.camera, inp.view.background);
    let exact = reference_product(&m, &light);
    let mut gpu = match gpu {
        Some(g) => Some(g.for_scene(&sh_scene, &view.camera)?),
        None => None,
    };
    let eval = Evaluation {
        t: (&m).into(),
        light: &light,
        // SH light and local bases have no texels or bins to take moments of: the low-frequency
        // method shades as Sloan et al. do, with or without [runtime] light_moments.
        moments: None,
        resolve: crate::experiment::config::MomentsResolve::Vertex,
        exact: &exact,
        baseline: inp.baseline,
        view: &view,
        reference: inp.reference,
        repeats: inp.repeats,
        exposure: inp.exposure,
        out_dir: inp.out_dir,
        // The methods' error figures share one scale, drawn once they all are rendered.
        shared_error_scale: true,
    };
    let (mut record, render) = eval.record(&csetting, compressor.as_ref(), &form, cached, gpu.as_mut())?;
    record.kind = KIND.name.to_string();
    record.params = serde_json::to_value(&p).expect("plain struct serializes");
    let covered = render.mask.iter().filter(|&&c| c).count();
    let negative =
        render.image.pixels.iter().zip(&render.mask).filter(|(px, &c)| c && px.iter().any(|&x| x < 0.0)).count();
    let negative_pixels = negative as f64 / covered.max(1) as f64;
    log::info!(
        "{label}: light projection error {light_projection_error:.2e}, RTT projection error {:.2e}, M from T vs traced {:.2e}, {:.2}% negative pixels",
        rtt.projection_error,
        transfer.from_t_difference,
        100.0 * negative_pixels
    );
    let lpca = lpca_runtime(&sh_scene, compressor.as_ref(), &form, &light, &view, &render, inp.repeats, label)?;
    let sh = ShRecord {
        order: p.order,
        rays: settings.rays(),
        bounces: p.bounces,
        compressor: csetting.kind.clone(),
        light_projection_error,
        transfer,
        rtt,
        negative_pixels,
        diffuse,
        lpca,
    };
    let animated = animate.then(|| crate::stages::animation::Animated {
        name: label.clone(),
        source: crate::stages::animation::Source::Sh(Box::new(crate::stages::animation::ShSource {
            projection,
            compressor,
            form,
            scene: sh_scene,
        })),
    });
    Ok((MethodRecord { record, sh: Some(sh) }, render, animated))
}

/// Müller et al.'s runtime for a scene with LPCA BTFs lit by SH: per light, gather `M_p l` and
/// take its dot products with every eigen-BRDF's SH projection per vertex
/// (`biscale_shading::precomputed`; this equals the paper's eq. 3 table of
/// `lambda(view, BTF cluster, matrix cluster, component)` contracted with each vertex's CPCA
/// weights, and is smaller here because a vertex needs only its own matrix), then shade from
/// them; and the same with fewer components per cluster (the paper drops components while the
/// light rotates). `None` without LPCA materials or when the tables do not fit.
#[allow(clippy::too_many_arguments)]
fn lpca_runtime(
    scene: &ShadeScene,
    compressor: &dyn biscale_core::compress::Compressor,
    form: &biscale_core::compress::CompressedForm,
    light: &biscale_core::sampling::LightVector,
    view: &View<'_>,
    direct: &biscale_core::scene::Render,
    repeats: usize,
    label: &str,
) -> Result<Option<crate::metrics::ShLpcaRecord>> {
    use biscale_core::scene::BtfRepresentation;
    use biscale_shading::precomputed::{shade_precomputed, LightDots};
    let most = scene
        .materials()
        .iter()
        .filter_map(|m| match &m.btf {
            BtfRepresentation::Lpca(l) => Some(l.components()),
            BtfRepresentation::Dense(_) => None,
        })
        .max();
    let Some(most) = most else { return Ok(None) };
    let limit = crate::stages::btf_study::MAX_PRECOMPUTED_BYTES;
    if LightDots::bytes_needed(scene) > limit {
        log::info!("{label}: LPCA dot products over {} MB, not measured", limit >> 20);
        return Ok(None);
    }
    let cerr = |source| PipelineError::Compress { name: label.to_string(), source };
    let camera = &view.camera;
    // One scene per component count (1..most; `most` is the scene itself).
    let truncated = |n: usize| -> Result<ShadeScene> {
        let materials = scene
            .materials()
            .iter()
            .map(|m| match &m.btf {
                BtfRepresentation::Lpca(l) if l.components() > n => {
                    Ok(biscale_core::scene::Material { btf: l.truncated(n)?.into(), tiling: m.tiling })
                }
                _ => Ok(m.clone()),
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(scene.with_materials(materials)?)
    };
    let mut runs = vec![];
    for n in (1..=most).rev() {
        let s = if n == most { None } else { Some(truncated(n)?) };
        let s = s.as_ref().unwrap_or(scene);
        let ((lstar, dots), relight) = timed(repeats, || {
            let lstar = compressor.gather(form, light).map_err(cerr)?;
            let dots = LightDots::new(s, &lstar, limit)?;
            Ok((lstar, dots))
        })?;
        let (render, shade) = timed(repeats, || {
            Ok(shade_precomputed(s, &dots, &lstar, camera)?.with_background(camera, &view.background))
        })?;
        runs.push((n, relight.median_ms, shade.median_ms, render, dots.bytes()));
    }
    let (_, relight_ms, shade_ms, full, bytes) = &runs[0];
    let vs_direct = compare(&full.image, &direct.image, Some(&direct.mask))?.rel_l2;
    let precomputed =
        crate::metrics::PrecomputedRecord { bytes: *bytes, precompute_ms: *relight_ms, shade_ms: *shade_ms, vs_direct };
    let mut adaptive = vec![];
    for (n, relight_ms, shade_ms, render, _) in runs.iter().rev() {
        let vs_all_components = compare(&render.image, &full.image, Some(&full.mask))?.rel_l2;
        adaptive.push(crate::metrics::AdaptiveRecord {
            components: *n,
            relight_ms: *relight_ms,
            shade_ms: *shade_ms,
            vs_all_components,
        });
    }
    log::info!(
        "{label}: LPCA lit by SH from precomputed dot products: relight {relight_ms:.1} ms, shade {shade_ms:.1} ms, vs direct {vs_direct:.1e}; fewer components: {}",
        adaptive
            .iter()
            .map(|a| format!("{} ({:.1} + {:.1} ms, {:.2}%)", a.components, a.relight_ms, a.shade_ms, 100.0 * a.vs_all_components))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(Some(crate::metrics::ShLpcaRecord { relight_ms: *relight_ms, precomputed, adaptive }))
}
