//! The transfer stage: `T` traced (or loaded from the cache, or stacked from shards, or left
//! in the shards' files and streamed) and each compressor's form of it.

use crate::error::{PipelineError, Result};
use crate::experiment::config::{CompressorSetting, Experiment};
use crate::metrics::*;
use crate::stages::scene::Geometry;
use crate::store::cache::{CacheKey, StageCache};
use crate::util::progress_bar;
use biscale_compressors::registry::{self};
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::transfer::{self, TransferMatrix, TransferParts, TransferSettings, TransferView};
use std::time::Instant;

/// `T` with its record and its cache key (which keys every output built from it).
pub struct Transfer {
    pub rows: TransferRows,
    pub metrics: TransferMetrics,
    pub key: CacheKey,
}

/// `T` as a run holds it: whole in memory, or (a sharded merge whose every step is
/// row-separable) left in the shards' files and read part by part.
pub enum TransferRows {
    Whole(TransferMatrix),
    Parts(TransferParts),
}

impl TransferRows {
    /// The view every pass over `T` takes.
    pub fn view(&self) -> TransferView<'_> {
        match self {
            TransferRows::Whole(t) => TransferView::Whole(t),
            TransferRows::Parts(p) => TransferView::Parts(p),
        }
    }
}

impl Transfer {
    /// The view every pass over `T` takes.
    pub fn view(&self) -> TransferView<'_> {
        self.rows.view()
    }

    /// `T` whole, for a step that needs all of it at once (`needs` names the step); an error
    /// when the run streams `T` from a sharded precompute's parts.
    pub fn whole(&self, needs: &str) -> Result<&TransferMatrix> {
        match &self.rows {
            TransferRows::Whole(t) => Ok(t),
            TransferRows::Parts(p) => Err(streamed(needs, p)),
        }
    }

    /// `T`, by value, when whole (see [`Self::whole`]).
    pub fn into_whole(self, needs: &str) -> Result<TransferMatrix> {
        match self.rows {
            TransferRows::Whole(t) => Ok(t),
            TransferRows::Parts(p) => Err(streamed(needs, &p)),
        }
    }
}

fn streamed(needs: &str, parts: &TransferParts) -> PipelineError {
    PipelineError::Core(biscale_core::CoreError::Invalid(format!(
        "{needs} needs all of T at once, but this run streams T from {} shard files (only row-separable steps \
         run in a streamed merge)",
        parts.len()
    )))
}

/// Build (or load from the cache) the transfer matrix with a progress bar.
pub fn transfer_matrix(exp: &Experiment, geometry: &Geometry, cache: Option<&StageCache>) -> Result<Transfer> {
    let settings = exp.transfer_settings();
    let key = crate::store::cache::transfer_key(&geometry.mesh, &settings);
    let shape = settings.shape(geometry.mesh.vertex_count());
    if let Some(c) = cache {
        let path = c.transfer_path(&key);
        let accept = |t: &TransferMatrix| match t.shape() == shape {
            true => Ok(()),
            false => Err(format!("{}: holds {}, this run needs {shape}", path.display(), t.shape())),
        };
        if let Some(matrix) = c.get(&path, &key, TransferMatrix::from_artifact, accept) {
            log::info!("transfer: loaded from cache {}", path.display());
            let metrics = transfer_metrics((&matrix).into(), 0.0, 0, 0.0, true, &settings)?;
            return Ok(Transfer { rows: TransferRows::Whole(matrix), metrics, key });
        }
    }
    let vertices = geometry.mesh.vertex_count();
    let pb = progress_bar(vertices as u64, "transfer");
    let tick = |done: usize| pb.set_position(done as u64);
    let start = Instant::now();
    let mut build = transfer::build_range(&geometry.transfer, &settings, 0..vertices, Some(&tick))?;
    // The scene was built with the geometry; count its time here too, as a whole build would.
    build.stats.seconds = start.elapsed().as_secs_f64();
    build.stats.rays_per_second = build.stats.rays_traced as f64 / build.stats.seconds.max(1e-12);
    pb.finish_and_clear();
    log::info!("transfer: {build}");
    if let Some(c) = cache {
        c.put_with(&c.transfer_path(&key), &key, || build.matrix.to_artifact());
    }
    let s = &build.stats;
    let metrics =
        transfer_metrics((&build.matrix).into(), s.seconds, s.rays_traced, s.rays_per_second, false, &settings)?;
    Ok(Transfer { rows: TransferRows::Whole(build.matrix), metrics, key })
}

/// One setting's compressed form of `t` (whose cache key is `t_key`), built or loaded from the
/// cache (`true` when loaded). A form from the cache keeps the build time it was measured with.
/// `sweep`: what the settings of the caller's sweep share (the compress context's).
pub fn compressed_form(
    setting: &CompressorSetting,
    compressor: &dyn Compressor,
    t: &TransferMatrix,
    t_key: &CacheKey,
    (seed, sweep): (u64, Option<&biscale_core::compress::Sweep>),
    cache: Option<&StageCache>,
) -> Result<(CompressedForm, bool)> {
    let name = &setting.label;
    // A compressor whose code biscale cannot identify (a hosted one) is never cached.
    let cached = cache
        .filter(|_| compressor.cacheable())
        .zip(crate::store::cache::form_key(t_key, compressor, seed))
        .map(|(c, key)| (c, c.form_path(&key, name), key));
    if let Some((c, path, key)) = &cached {
        let accept = |f: &CompressedForm| match f.kind == compressor.kind() && f.shape() == t.shape() {
            true => Ok(()),
            false => Err(format!(
                "{}: holds a {} form of {}, this run needs {}",
                path.display(),
                f.kind,
                f.shape(),
                t.shape()
            )),
        };
        if let Some(form) = c.get(path, key, CompressedForm::from_artifact, accept) {
            log::info!("{name}: loaded from cache {}", path.display());
            return Ok((form, true));
        }
    }
    let pb = progress_bar(1000, name);
    let progress = |f: f64| pb.set_position((f.clamp(0.0, 1.0) * 1000.0) as u64);
    let ctx = CompressContext { seed, progress: Some(&progress), sweep };
    let form = compressor.compress(t, &ctx).map_err(|source| PipelineError::Compress { name: name.clone(), source })?;
    pb.finish_and_clear();
    if let Some((c, path, key)) = &cached {
        c.put(path, key, &form.to_artifact());
    }
    Ok((form, false))
}

/// `T`'s record: one pass over its parts (the value histogram, the vertices without sky).
fn transfer_metrics(
    t: TransferView<'_>,
    seconds: f64,
    rays: u64,
    rays_per_second: f64,
    cached: bool,
    settings: &TransferSettings,
) -> Result<TransferMetrics> {
    let mut hist = std::collections::BTreeMap::<u32, u64>::new();
    let mut without_sky = 0;
    t.for_each_part(|_, part| -> Result<()> {
        for v in part.csr().data() {
            *hist.entry(v.to_bits()).or_default() += 1;
        }
        without_sky += vertices_without_sky(part);
        Ok(())
    })?;
    let mut value_histogram: Vec<ValueCount> =
        hist.into_iter().map(|(b, count)| ValueCount { value: f32::from_bits(b), count }).collect();
    value_histogram.sort_by(|a, b| a.value.total_cmp(&b.value));
    Ok(TransferMetrics {
        rows: t.rows(),
        cols: t.cols(),
        nnz: t.nnz(),
        local_dirs: t.local_dirs(),
        visibility_resolution: settings.visibility_resolution(),
        visibility: Some(settings.visibility()),
        value_histogram,
        build_seconds: seconds,
        rays_traced: rays,
        rays_per_second,
        cached,
        vertices_without_sky: without_sky,
    })
}

/// Vertices whose M rows of `t` are all zero.
pub fn vertices_without_sky(t: &TransferMatrix) -> usize {
    let ip = t.csr().indptr();
    let ip = ip.raw_storage();
    let m = t.local_dirs().max(1);
    (0..t.vertices()).filter(|&v| ip[v * m] == ip[(v + 1) * m]).count()
}

/// A warning when at least half of the vertices see no sky: the likely causes, so a black
/// image with exit 0 does not go unexplained.
pub fn sky_warning(t: &TransferMetrics, vertices: usize) -> Option<String> {
    let n = t.vertices_without_sky;
    (vertices > 0 && 2 * n >= vertices).then(|| {
        format!(
            "{:.0}% of the vertices ({n} of {vertices}) see no sky: every row of T is zero there, so they render \
             black. Is the mesh inside out (faces wound clockwise, normals pointing into the solid) or closed \
             around the camera?",
            100.0 * n as f64 / vertices as f64
        )
    })
}

/// The compressor of one setting (a plugin loads its library here).
pub fn build_compressor(setting: &CompressorSetting) -> Result<Box<dyn Compressor>> {
    registry::build(&setting.kind, &setting.params)
        .map_err(|source| PipelineError::Build { name: setting.label.clone(), source })
}

/// What a sharded precompute hands the pipeline (`crate::shard::merge`): `T` stacked from the
/// shards or left in their files, the merged forms of the separable compressors by label, and
/// the shards' record.
pub struct Precomputed {
    pub rows: TransferRows,
    /// Rays and seconds summed over the shards.
    pub rays_traced: u64,
    pub transfer_seconds: f64,
    pub forms: std::collections::BTreeMap<String, CompressedForm>,
    /// `merge_seconds` is filled in when the merge writes its record (from `started`).
    pub sharded: ShardedMetrics,
    /// When the merge began (checking the shards).
    pub started: Instant,
}

impl Precomputed {
    /// With `T` left in the shards' files: the vertices of the largest part, all of `T` the
    /// merge holds at once (the memory estimate's streamed phase).
    pub fn streamed_part_vertices(&self) -> Option<usize> {
        match &self.rows {
            TransferRows::Whole(_) => None,
            TransferRows::Parts(p) => Some(p.largest_part()),
        }
    }
}

/// `T` from a sharded precompute, checked against the geometry and, when stacked, put in the
/// cache as a single build would have (so a later `biscale run` of the config finds it).
pub(crate) fn precomputed_transfer(
    rows: TransferRows,
    rays: u64,
    seconds: f64,
    exp: &Experiment,
    geometry: &Geometry,
    cache: Option<&StageCache>,
) -> Result<Transfer> {
    let settings = exp.transfer_settings();
    let shape = settings.shape(geometry.mesh.vertex_count());
    let key = crate::store::cache::transfer_key(&geometry.mesh, &settings);
    let view = rows.view();
    if view.shape() != shape {
        return Err(PipelineError::Mismatch {
            path: exp.config_path.clone(),
            what: format!("the shards' T is {}, this config's mesh and settings need {shape}", view.shape()),
        });
    }
    if let (Some(c), TransferRows::Whole(matrix)) = (cache, &rows) {
        c.put_with(&c.transfer_path(&key), &key, || matrix.to_artifact());
    }
    let metrics = transfer_metrics(view, seconds, rays, rays as f64 / seconds.max(1e-12), false, &settings)?;
    let how = match &rows {
        TransferRows::Whole(_) => "stacked from the shards".to_string(),
        TransferRows::Parts(p) => format!("left in {} shard files, streamed", p.len()),
    };
    log::info!("transfer: {} x {} {how}, {} non-zeros", view.rows(), view.cols(), view.nnz());
    Ok(Transfer { rows, metrics, key })
}

#[cfg(test)]
mod tests {
    use super::*;
    use biscale_core::geometry::shapes::uv_sphere;

    fn transfer_of(mesh: &biscale_core::geometry::Mesh) -> TransferMetrics {
        let settings = TransferSettings::new(8, 16, 4).unwrap();
        let t = transfer::build(mesh, &settings, None).unwrap().matrix;
        transfer_metrics((&t).into(), 0.0, 0, 0.0, false, &settings).unwrap()
    }

    #[test]
    fn an_inside_out_mesh_is_warned_about() {
        // Regression (hostile input): a closed sphere with every face flipped traced T with
        // no non-zeros and rendered black with exit 0 and no word.
        let sphere = uv_sphere(glam::Vec3::ZERO, 1.0, 8, 12);
        let vertices = sphere.vertex_count();
        let ok = transfer_of(&sphere);
        assert_eq!(ok.vertices_without_sky, 0);
        assert!(sky_warning(&ok, vertices).is_none());
        let mut flipped = sphere.clone();
        for t in &mut flipped.triangles {
            t.swap(1, 2);
        }
        let bad = transfer_of(&flipped);
        assert_eq!((bad.nnz, bad.vertices_without_sky), (0, vertices));
        let w = sky_warning(&bad, vertices).expect("a warning");
        assert!(w.starts_with("100% of the vertices") && w.contains("inside out"), "{w}");
    }
}
