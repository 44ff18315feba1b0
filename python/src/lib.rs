//! `biscale._native`: the pipeline as a Python extension module (PyO3 + NumPy). The
//! pure-Python package `biscale` (`python/biscale/`) wraps it with the documented API; this
//! module holds only what needs Rust.
//!
//! * [`Experiment`]: a config loaded with its `--set` overrides; `plan`, `run` (with Python
//!   compressors beside the config's), `evaluate`, `light`, `light_moments`, `transfer`,
//!   `shade` (an `L*`'s image) and `reference` (the ground-truth image).
//! * [`Transfer`]: `T` with its bases and the vertex frames it was traced with; its CSR arrays
//!   and its f64 product `T L` (or, with light moments, the moments' product).
//! * [`Form`] and [`compress`]: a built-in kind's form of a `Transfer`, its gather (also with
//!   light moments), storage and flops, its arrays, and `save` (the `.npz` `eval --form` reads).
//! * [`read_image`]: an EXR the pipeline wrote, as an H x W x 3 array.
//! * [`HostedCompressor`]: a Python object with `compress(T, context)` run inside a pipeline
//!   run (registered as `biscale_compressors::hosted`): its form's `gather(L)` is called for
//!   every gather the run times, and what it returns is checked before it is scored.
//!
//! Every long call releases the GIL (`Python::detach`); errors are `biscale.BiscaleError`
//! (a config's located message as the CLI prints it is `biscale.ConfigError`); the pipeline's
//! progress goes to Python's `logging` (logger `biscale`, via `pyo3-log`).

use biscale::experiment::config::{CompressorSetting, Experiment as Exp};
use biscale::store::RunOptions;
use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor};
use biscale_core::gather::moments::{exact_moments_product, gather_with_moments, LightMoments, Lobe};
use biscale_core::gather::LocalRadiance;
use biscale_core::geometry::VertexFrame;
use biscale_core::sampling::LightVector;
use biscale_core::scene::HdrImage;
use biscale_core::transfer::TransferMatrix;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

pyo3::create_exception!(
    _native,
    BiscaleError,
    PyException,
    "An error of the biscale pipeline (bad input, a failed stage)."
);
pyo3::create_exception!(
    _native,
    ConfigError,
    BiscaleError,
    "A config error, located as the CLI prints it (`file:line:column: message`)."
);

/// An error of the pipeline as a Python exception, with the whole chain of causes.
fn err(e: impl std::error::Error) -> PyErr {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let line = s.to_string();
        if !text.contains(&line) {
            text += &format!(": {line}");
        }
        source = s.source();
    }
    BiscaleError::new_err(text)
}

fn options(out: Option<PathBuf>, cache_dir: Option<PathBuf>, no_cache: bool) -> RunOptions {
    RunOptions { out_dir: out, cache_dir, no_cache }
}

/// A config loaded as `biscale run` loads it.
#[pyclass(module = "biscale._native", frozen)]
struct Experiment {
    exp: Arc<Exp>,
}

#[pymethods]
impl Experiment {
    /// Load `path` with `overrides` (`KEY=VALUE` strings, as `--set` takes them).
    #[staticmethod]
    #[pyo3(signature = (path, overrides = Vec::new()))]
    fn load(py: Python<'_>, path: PathBuf, overrides: Vec<String>) -> PyResult<Self> {
        let exp = py.detach(|| Exp::load_with(&path, &overrides)).map_err(|e| ConfigError::new_err(e.to_string()))?;
        Ok(Self { exp: Arc::new(exp) })
    }

    /// The experiment's name (its output folder's default name).
    #[getter]
    fn name(&self) -> String {
        self.exp.name().to_string()
    }

    /// The config text as it runs (the file's, with the overrides applied).
    #[getter]
    fn source(&self) -> String {
        self.exp.source.clone()
    }

    /// The config's compressor settings, in run order: (label, kind, parameters as JSON text).
    #[getter]
    fn compressor_settings(&self) -> Vec<(String, String, String)> {
        self.exp.compressor_settings().iter().map(|s| (s.label.clone(), s.kind.clone(), s.params.to_string())).collect()
    }

    /// The experiment's seed (`seed`): what every compressor of a run is given.
    #[getter]
    fn seed(&self) -> u64 {
        self.exp.file.seed
    }

    /// What `biscale plan` prints: the stages, what is left out and why, memory estimates.
    #[pyo3(signature = (cache_dir = None, no_cache = false))]
    fn plan(&self, py: Python<'_>, cache_dir: Option<PathBuf>, no_cache: bool) -> PyResult<String> {
        let opts = options(None, cache_dir, no_cache);
        py.detach(|| biscale::plan::Plan::new(&self.exp).with_estimates(&self.exp, &opts))
            .map(|p| p.to_string())
            .map_err(err)
    }

    /// Run the experiment as `biscale run` does, with each object of `compressors` (see
    /// `biscale.PythonCompressor`) as one more compressor setting labelled by `labels`.
    /// Returns the output folder and `metrics.json`'s text.
    #[pyo3(signature = (out = None, cache_dir = None, no_cache = false, compressors = Vec::new(), labels = Vec::new()))]
    fn run(
        &self,
        py: Python<'_>,
        out: Option<PathBuf>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
        compressors: Vec<Py<PyAny>>,
        labels: Vec<String>,
    ) -> PyResult<(String, String)> {
        if compressors.len() != labels.len() {
            return Err(BiscaleError::new_err("one label per compressor"));
        }
        // A fresh parse of the same text: the settings added below stay out of `self`.
        let mut exp = Exp::parse(&self.exp.config_path, self.exp.source.clone())
            .map_err(|e| ConfigError::new_err(e.to_string()))?;
        exp.overrides = self.exp.overrides.clone();
        let mut registrations = vec![];
        for (obj, label) in compressors.into_iter().zip(labels) {
            static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
            let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let name = format!("python-{}-{n}-{label}", std::process::id());
            let hosted = Arc::new(HostedObject { obj, label: label.clone(), exp: self.exp.clone() });
            let factory: biscale_compressors::hosted::Factory =
                Arc::new(move || Box::new(HostedCompressor::new(hosted.clone())) as Box<dyn Compressor>);
            registrations.push(biscale_compressors::hosted::register(&name, factory).map_err(BiscaleError::new_err)?);
            let params = serde_json::json!({ "name": name, "label": label });
            exp.add_compressor(CompressorSetting {
                label,
                kind: biscale_compressors::hosted::KIND.name.into(),
                params,
            })
            .map_err(|e| ConfigError::new_err(e.to_string()))?;
        }
        let opts = options(out, cache_dir, no_cache);
        let (dir, metrics) = py.detach(|| biscale::run::run(&exp, &opts)).map_err(err)?;
        drop(registrations);
        let json = serde_json::to_string(&metrics).map_err(err)?;
        Ok((dir.display().to_string(), json))
    }

    /// Score an `L*` saved at `path` (`.npy`/`.npz`, as `biscale eval --lstar` reads it), or
    /// with `form` a form saved there (`eval --form`), as a run scores a compressor setting:
    /// images, errors, report. Returns the output folder and `metrics.json`'s text.
    #[pyo3(signature = (path, name = None, out = None, cache_dir = None, no_cache = false, form = false))]
    #[allow(clippy::too_many_arguments)]
    fn evaluate(
        &self,
        py: Python<'_>,
        path: PathBuf,
        name: Option<String>,
        out: Option<PathBuf>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
        form: bool,
    ) -> PyResult<(String, String)> {
        let input = match form {
            true => biscale::interop::EvalInput::Form(path),
            false => biscale::interop::EvalInput::Lstar(path),
        };
        self.evaluate_input(py, input, name, out, cache_dir, no_cache)
    }

    /// [`Self::evaluate`] of an `L*` handed over in memory (rows x 3, float64): no file is
    /// written anywhere but the run's own folder.
    #[pyo3(signature = (values, name = None, out = None, cache_dir = None, no_cache = false))]
    fn evaluate_values(
        &self,
        py: Python<'_>,
        values: PyReadonlyArray2<'_, f64>,
        name: Option<String>,
        out: Option<PathBuf>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
    ) -> PyResult<(String, String)> {
        let a = values.as_array();
        if a.ncols() != 3 {
            return Err(BiscaleError::new_err(format!("an L* is rows x 3 (RGB), got {:?}", a.shape())));
        }
        let rows = a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        self.evaluate_input(py, biscale::interop::EvalInput::Values(rows), name, out, cache_dir, no_cache)
    }

    /// [`Self::evaluate`] of a built-in kind's form handed over in memory, as `eval --form`
    /// scores one read from a file (its flops counted from its arrays, its build time 0).
    #[pyo3(signature = (form, name, out = None, cache_dir = None, no_cache = false))]
    fn evaluate_form(
        &self,
        py: Python<'_>,
        form: PyRef<'_, Form>,
        name: String,
        out: Option<PathBuf>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
    ) -> PyResult<(String, String)> {
        let mut f = form.form.clone();
        f.flops_per_gather = biscale::interop::form_flops(&f).unwrap_or(0);
        f.build_seconds = 0.0;
        let read = biscale::interop::ReadForm {
            form: f,
            label: Some(name.clone()),
            params: Some(form.compressor.params()),
            claimed_flops: None,
        };
        let input = biscale::interop::EvalInput::Loaded(Box::new(read));
        self.evaluate_input(py, input, Some(name), out, cache_dir, no_cache)
    }

    /// The light vector `L` of the config's lighting: power per texel, N x 3 float32.
    fn light<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let lighting = py.detach(|| biscale::stages::scene::load_lighting(&self.exp)).map_err(err)?;
        rows3(py, lighting.light.power.as_flattened().to_vec())
    }

    /// The three direction moments of `L` (`runtime.light_moments`): 3 x N x 3 float32,
    /// `[a, k]` = `L_k d_k[a]` for the world axes `a` = x, y, z and `d_k` texel `k`'s direction
    /// (its centre; with `lighting.texel_directions = "mean"` its light's mean direction, per channel).
    fn light_moments<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let moments = py
            .detach(|| -> biscale::error::Result<LightMoments> {
                let lighting = biscale::stages::scene::load_lighting(&self.exp)?;
                Ok(LightMoments::new(&lighting.light)?)
            })
            .map_err(err)?;
        let n = moments.along[0].power.len();
        let flat: Vec<f32> = moments.along.iter().flat_map(|l| l.power.as_flattened().iter().copied()).collect();
        PyArray1::from_vec(py, flat).reshape([3, n, 3])
    }

    /// `T`, from the stage cache or traced, as `biscale run` gets it, with the vertex frames it
    /// was traced with.
    #[pyo3(signature = (cache_dir = None, no_cache = false))]
    fn transfer(&self, py: Python<'_>, cache_dir: Option<PathBuf>, no_cache: bool) -> PyResult<Transfer> {
        let opts = options(None, cache_dir, no_cache);
        let (t, frames) = py
            .detach(|| {
                let geometry = biscale::stages::scene::load_geometry(&self.exp)?;
                let cache = biscale::store::cache::StageCache::new(&opts, std::path::Path::new("."));
                let t = biscale::stages::transfer::transfer_matrix(&self.exp, &geometry, cache.as_ref())?;
                Ok::<_, biscale::error::PipelineError>((t.into_whole("Transfer")?, geometry.transfer.frames().to_vec()))
            })
            .map_err(err)?;
        Ok(Transfer { t: Arc::new(t), frames: Some(Arc::new(frames)), exp: self.exp.clone() })
    }

    /// The image `biscale run` renders of `lstar` (rows x 3 float32, rows `v*M + j`): H x W x 3
    /// float32, linear RGB, at the run's camera with its background.
    #[pyo3(signature = (lstar, cache_dir = None, no_cache = false))]
    fn shade<'py>(
        &self,
        py: Python<'py>,
        lstar: PyReadonlyArray2<'py, f32>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let shape = lstar.shape();
        if shape.len() != 2 || shape[1] != 3 {
            return Err(BiscaleError::new_err(format!("L* is {shape:?}; it is rows x 3 (float32)")));
        }
        let rows: Vec<[f32; 3]> = lstar.as_array().rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        let opts = options(None, cache_dir, no_cache);
        let render = py.detach(|| biscale::interop::images::shade_image(&self.exp, &rows, &opts)).map_err(err)?;
        image3(py, render.image)
    }

    /// The ground-truth reference image of a run (at `report.reference_downscale`, with the
    /// background), from the stage cache or traced: H x W x 3 float32, linear RGB.
    #[pyo3(signature = (cache_dir = None, no_cache = false))]
    fn reference<'py>(
        &self,
        py: Python<'py>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let opts = options(None, cache_dir, no_cache);
        let render = py.detach(|| biscale::interop::images::reference_image(&self.exp, &opts)).map_err(err)?;
        image3(py, render.image)
    }
}

/// An image as an H x W x 3 NumPy array, without a copy.
fn image3(py: Python<'_>, image: HdrImage) -> PyResult<Bound<'_, PyArray3<f32>>> {
    let (w, h) = (image.width as usize, image.height as usize);
    PyArray1::from_vec(py, image.pixels.into_flattened()).reshape([h, w, 3])
}

/// An EXR image (as the pipeline writes them: `images/*.exr`) as H x W x 3 float32, linear RGB.
#[pyfunction]
fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (image, _) = py.detach(|| HdrImage::read_exr(&path)).map_err(err)?;
    image3(py, image)
}

/// `values` (3 per row) as a rows x 3 NumPy array, without a copy.
fn rows3(py: Python<'_>, values: Vec<f32>) -> PyResult<Bound<'_, PyArray2<f32>>> {
    let n = values.len() / 3;
    PyArray1::from_vec(py, values).reshape([n, 3])
}

/// A light from Python: an N x 3 float32 array in `t`'s light basis, every value finite.
fn light_of(l: &PyReadonlyArray2<'_, f32>, basis: biscale_core::basis::LightBasis, n: usize) -> PyResult<LightVector> {
    let shape = l.shape();
    if shape != [n, 3] {
        return Err(BiscaleError::new_err(format!("L is {shape:?}, this transfer needs [{n}, 3] (float32)")));
    }
    let flat: Vec<f32> = l.as_array().iter().copied().collect();
    if let Some(i) = flat.iter().position(|x| !x.is_finite()) {
        return Err(BiscaleError::new_err(format!(
            "L[{}, {}] is {}: every value must be finite",
            i / 3,
            i % 3,
            flat[i]
        )));
    }
    LightVector::new(basis, flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()).map_err(err)
}

impl Experiment {
    /// Score `input` as `biscale eval` does; the output folder and `metrics.json`'s text.
    fn evaluate_input(
        &self,
        py: Python<'_>,
        input: biscale::interop::EvalInput,
        name: Option<String>,
        out: Option<PathBuf>,
        cache_dir: Option<PathBuf>,
        no_cache: bool,
    ) -> PyResult<(String, String)> {
        let opts = options(out, cache_dir, no_cache);
        let (dir, metrics) =
            py.detach(|| biscale::interop::eval(&self.exp, &input, name.as_deref(), &opts)).map_err(err)?;
        let json = serde_json::to_string(&metrics).map_err(err)?;
        Ok((dir.display().to_string(), json))
    }
}

/// `T` with its bases: rows `v*M + j` (vertex `v`, local direction `j`), columns light texels.
#[pyclass(module = "biscale._native", frozen)]
struct Transfer {
    t: Arc<TransferMatrix>,
    /// The vertex frames `T` was traced with (light moments need the normals); `None` for the
    /// copy a Python compressor is handed inside a run.
    frames: Option<Arc<Vec<VertexFrame>>>,
    /// The experiment `T` is of (a saved form's metadata names it).
    exp: Arc<Exp>,
}

#[pymethods]
impl Transfer {
    /// (rows, cols).
    #[getter]
    fn shape(&self) -> (usize, usize) {
        (self.t.rows(), self.t.cols())
    }
    #[getter]
    fn nnz(&self) -> usize {
        self.t.nnz()
    }
    #[getter]
    fn vertices(&self) -> usize {
        self.t.vertices()
    }
    /// Local directions per vertex (`M`).
    #[getter]
    fn local_dirs(&self) -> usize {
        self.t.local_dirs()
    }
    /// The local basis, e.g. `bins:8`.
    #[getter]
    fn local_basis(&self) -> String {
        self.t.local_basis().to_string()
    }
    /// The light basis, e.g. `cubemap:32`.
    #[getter]
    fn light_basis(&self) -> String {
        self.t.light_basis().to_string()
    }
    /// CSR row pointers (int64, rows + 1).
    fn indptr<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        PyArray1::from_vec(py, self.t.csr().indptr().raw_storage().iter().map(|&x| x as i64).collect())
    }
    /// CSR column indices (int32, nnz).
    fn indices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i32>> {
        PyArray1::from_vec(py, self.t.csr().indices().iter().map(|&x| x as i32).collect())
    }
    /// CSR values (float32, nnz).
    fn data<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        PyArray1::from_vec(py, self.t.csr().data().to_vec())
    }
    /// The vertex normals `T` was traced with (V x 3 float32).
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        rows3(py, frames_of(&self.frames)?.iter().flat_map(|f| f.normal.to_array()).collect())
    }
    /// The exact product `T L` in f64 (rows x 3): what a lossless form's gather reproduces.
    /// With `moments`, the light-moments product (`runtime.light_moments`: every texel with
    /// its own cosine, the BRDF at each bin's mean direction), summed per texel in f64.
    #[pyo3(signature = (light, moments = false))]
    fn product<'py>(
        &self,
        py: Python<'py>,
        light: PyReadonlyArray2<'py, f32>,
        moments: bool,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let l = light_of(&light, self.t.light_basis(), self.t.cols())?;
        let frames = match moments {
            true => Some(frames_of(&self.frames)?),
            false => None,
        };
        let rows = py
            .detach(|| match frames {
                None => Ok(biscale_core::gather::reference_product(&self.t, &l)),
                Some(frames) => exact_moments_product(&self.t, &l, frames, Lobe::MeanDirection),
            })
            .map_err(err)?;
        let n = rows.len();
        PyArray1::from_vec(py, rows.into_flattened()).reshape([n, 3])
    }
}

/// The frames of a [`Transfer`], or the error of one handed to a compressor inside a run.
fn frames_of(frames: &Option<Arc<Vec<VertexFrame>>>) -> PyResult<&[VertexFrame]> {
    frames.as_deref().map(Vec::as_slice).ok_or_else(|| {
        BiscaleError::new_err(
            "this T is the copy a compressor is handed inside a run; it carries no vertex frames \
             (light moments need them: use Experiment.transfer())",
        )
    })
}

/// A built-in kind's form of a [`Transfer`], with the compressor that gathers it.
#[pyclass(module = "biscale._native", frozen)]
struct Form {
    form: CompressedForm,
    compressor: Box<dyn Compressor>,
    light_basis: biscale_core::basis::LightBasis,
    /// The frames of the `T` it compresses (for the gather with light moments).
    frames: Option<Arc<Vec<VertexFrame>>>,
    exp: Arc<Exp>,
}

/// Compress `t` with the kind `kind` and its parameters (`params`, JSON text): a built-in kind
/// or `plugin` (`path`, `params`); not `hosted` (a Python compressor is called from Python).
#[pyfunction]
#[pyo3(signature = (t, kind, params = "{}".to_string(), seed = 0))]
fn compress(py: Python<'_>, t: &Transfer, kind: &str, params: String, seed: u64) -> PyResult<Form> {
    let params: serde_json::Value = serde_json::from_str(&params).map_err(err)?;
    let offered = |k: &&biscale_compressors::registry::Kind| k.name != biscale_compressors::hosted::KIND.name;
    let entry = biscale_compressors::registry::find(kind).filter(offered).ok_or_else(|| {
        let names: Vec<_> = biscale_compressors::registry::KINDS.iter().filter(offered).map(|k| k.name).collect();
        BiscaleError::new_err(format!(
            "no compressor kind `{kind}` to compress with (kinds: {}; a Python compressor runs in \
                 Experiment.run(compressors=[...]))",
            names.join(", ")
        ))
    })?;
    (entry.check)(&params).map_err(|e| BiscaleError::new_err(format!("{kind}: {e}")))?;
    let compressor = (entry.build)(&params).map_err(|e| BiscaleError::new_err(format!("{kind}: {e}")))?;
    let tt = t.t.clone();
    let form = py
        .detach(|| compressor.compress(&tt, &CompressContext { seed, progress: None, sweep: None }))
        .map_err(|e| BiscaleError::new_err(format!("{kind}: {e}")))?;
    Ok(Form { form, compressor, light_basis: t.t.light_basis(), frames: t.frames.clone(), exp: t.exp.clone() })
}

#[pymethods]
impl Form {
    #[getter]
    fn kind(&self) -> String {
        self.form.kind.clone()
    }
    /// Storage of the form's arrays, in bytes.
    #[getter]
    fn nbytes(&self) -> u64 {
        self.form.bytes()
    }
    /// Floating-point operations of one monochrome gather.
    #[getter]
    fn flops_per_gather(&self) -> u64 {
        self.form.flops_per_gather
    }
    #[getter]
    fn lossless(&self) -> bool {
        self.form.lossless
    }
    #[getter]
    fn build_seconds(&self) -> f64 {
        self.form.build_seconds
    }
    /// The form's arrays by name, as stored (copies).
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for a in &self.form.arrays {
            match &a.data {
                ArrayData::U8(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
                ArrayData::I8(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
                ArrayData::U16(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
                ArrayData::I16(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
                ArrayData::U32(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
                ArrayData::F32(v) => d.set_item(&a.name, PyArray1::from_slice(py, v))?,
            }
        }
        Ok(d)
    }
    /// `L*` of `light` (N x 3 float32): rows x 3 float32, the form's own CPU gather.
    fn gather<'py>(&self, py: Python<'py>, light: PyReadonlyArray2<'py, f32>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let l = light_of(&light, self.light_basis, self.form.cols())?;
        let lstar = py.detach(|| self.compressor.gather(&self.form, &l)).map_err(err)?;
        rows3(py, lstar.values().as_flattened().to_vec())
    }
    /// `L*` of `light` with light moments (`runtime.light_moments`): the form gathers the
    /// light's three direction moments, which are resolved with `T`'s vertex frames; rows x 3
    /// float32, what a run with light moments renders.
    fn gather_moments<'py>(
        &self,
        py: Python<'py>,
        light: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let l = light_of(&light, self.light_basis, self.form.cols())?;
        let frames = frames_of(&self.frames)?;
        let lstar = py
            .detach(|| {
                let moments = LightMoments::new(&l).map_err(|e| CompressError::External(Box::new(e)))?;
                gather_with_moments(self.compressor.as_ref(), &self.form, &moments, frames)
            })
            .map_err(err)?;
        rows3(py, lstar.values().as_flattened().to_vec())
    }
    /// Write the form to `path` as `biscale export` writes `form-<label>.npz` (read by
    /// `biscale eval --form` and `biscale_io.load_form`), written whole or not at all, and
    /// never over what biscale did not write (a user's file unless `force`; a link, device,
    /// FIFO or folder never).
    #[pyo3(signature = (path, label, force = false))]
    fn save(&self, py: Python<'_>, path: PathBuf, label: String, force: bool) -> PyResult<()> {
        let params = self.compressor.params();
        py.detach(|| biscale::interop::write_form(&self.exp, &self.form, &label, &params, &path, Some(force)))
            .map_err(err)
    }
}

/// A Python compressor object and the label of its setting.
struct HostedObject {
    /// The experiment of the run (the `T` it is handed names it).
    exp: Arc<Exp>,
    obj: Py<PyAny>,
    label: String,
}

/// A Python compressor inside a run: `compress` calls the object's `compress(T, context)`,
/// `gather` the returned form's `gather(L)`. The form's storage is what its `arrays` hold
/// (a claimed `nbytes` must agree), its flops its `flops_per_gather`.
struct HostedCompressor {
    hosted: Arc<HostedObject>,
    /// The Python form of the last `compress`.
    form: Mutex<Option<Py<PyAny>>>,
}

impl HostedCompressor {
    fn new(hosted: Arc<HostedObject>) -> Self {
        Self { hosted, form: Mutex::new(None) }
    }

    fn fail(&self, what: impl Into<String>) -> CompressError {
        CompressError::External(format!("Python compressor `{}`: {}", self.hosted.label, what.into()).into())
    }

    fn py_fail(&self, py: Python<'_>, e: PyErr) -> CompressError {
        let tb = e.traceback(py).and_then(|t| t.format().ok()).unwrap_or_default();
        self.fail(format!("{e}\n{tb}").trim_end().to_string())
    }

    /// Refuse an array whose elements are not all stored (a zero stride: a broadcast view such
    /// as `np.broadcast_to`, whose storage would be a claim, not bytes) and one whose copy would
    /// not fit in the memory there is, before a byte is copied.
    fn check_extent(&self, name: &str, shape: &[usize], strides: &[isize], width: usize) -> Result<(), CompressError> {
        if shape.iter().zip(strides).any(|(&n, &s)| n > 1 && s == 0) {
            return Err(self.fail(format!(
                "array `{name}` is a broadcast view (a zero stride): its {} elements are not stored; store the \
                 array itself (np.ascontiguousarray)",
                shape.iter().product::<usize>()
            )));
        }
        let bytes = shape.iter().try_fold(width as u64, |a, &n| a.checked_mul(n as u64)).unwrap_or(u64::MAX);
        let available = biscale::estimate::available().map_err(|e| self.fail(e.to_string()))?;
        if bytes > available.bytes {
            return Err(self.fail(format!(
                "array `{name}` ({}) would need {bytes} bytes to copy, more than the {} available ({})",
                shape.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(" x "),
                available.bytes,
                available.source
            )));
        }
        Ok(())
    }

    /// The arrays of a Python form (`arrays`, a dict of 1-d-able NumPy arrays).
    fn arrays_of(&self, form: &Bound<'_, PyAny>) -> Result<Vec<(String, ArrayData)>, CompressError> {
        let py = form.py();
        let Ok(arrays) = form.getattr("arrays") else { return Ok(vec![]) };
        let arrays = if arrays.is_callable() { arrays.call0().map_err(|e| self.py_fail(py, e))? } else { arrays };
        let dict = arrays.cast::<PyDict>().map_err(|_| self.fail("`arrays` must be a dict of NumPy arrays"))?;
        let mut out = vec![];
        for (k, v) in dict.iter() {
            let name: String = k.extract().map_err(|_| self.fail("`arrays` keys must be strings"))?;
            macro_rules! take {
                ($($t:ty => $variant:ident),*) => {{
                    $(if let Ok(a) = v.cast::<numpy::PyArrayDyn<$t>>() {
                        self.check_extent(&name, a.shape(), a.strides(), std::mem::size_of::<$t>())?;
                        let a = a.readonly();
                        out.push((name.clone(), ArrayData::$variant(a.as_array().iter().copied().collect())));
                        continue;
                    })*
                }};
            }
            take!(f32 => F32, u32 => U32, u16 => U16, i16 => I16, u8 => U8, i8 => I8);
            return Err(self.fail(format!(
                "array `{name}` is not a NumPy array of float32, uint32, uint16, int16, uint8 or int8 (store the form at the width it is kept)"
            )));
        }
        Ok(out)
    }
}

impl Compressor for HostedCompressor {
    fn kind(&self) -> &str {
        biscale_compressors::hosted::KIND.name
    }

    fn params(&self) -> serde_json::Value {
        Python::attach(|py| {
            let obj = self.hosted.obj.bind(py);
            let params = obj.getattr("params").ok().and_then(|p| {
                let json = py.import("json").ok()?;
                json.call_method1("dumps", (p,)).ok()?.extract::<String>().ok()
            });
            let class = obj.get_type().name().map(|n| n.to_string()).unwrap_or_default();
            let params = params.and_then(|p| serde_json::from_str(&p).ok()).unwrap_or(serde_json::Value::Null);
            let mut record = serde_json::json!({ "python_class": class, "params": params });
            // The series it is drawn and tabulated in (`compare::series_of`): its own label
            // unless the object declares a `family` shared with others.
            if let Some(family) = obj.getattr("family").ok().and_then(|f| f.extract::<String>().ok()) {
                record["family"] = serde_json::Value::String(family);
            }
            record
        })
    }

    fn compress(&self, t: &TransferMatrix, ctx: &CompressContext<'_>) -> Result<CompressedForm, CompressError> {
        let start = std::time::Instant::now();
        Python::attach(|py| {
            // The object sees a copy of `T` (the run keeps its own), as a `biscale.Transfer`.
            let native = Py::new(py, Transfer { t: Arc::new(t.clone()), frames: None, exp: self.hosted.exp.clone() })
                .map_err(|e| self.py_fail(py, e))?;
            let tt = py
                .import("biscale")
                .and_then(|m| m.getattr("Transfer"))
                .and_then(|w| w.call1((native,)))
                .map_err(|e| self.py_fail(py, e))?;
            let context = PyDict::new(py);
            context.set_item("seed", ctx.seed).map_err(|e| self.py_fail(py, e))?;
            let form =
                self.hosted.obj.bind(py).call_method1("compress", (tt, context)).map_err(|e| self.py_fail(py, e))?;
            if !form.getattr("gather").is_ok_and(|g| g.is_callable()) {
                return Err(self.fail("its compress returned an object without a gather(L) method"));
            }
            let flops: u64 = form
                .getattr("flops_per_gather")
                .and_then(|f| f.extract())
                .map_err(|_| self.fail("its form needs `flops_per_gather`, a non-negative int"))?;
            let lossless: bool = match form.getattr("lossless") {
                Ok(l) => l.extract().map_err(|_| self.fail("`lossless` must be a bool"))?,
                Err(_) => false,
            };
            let arrays = self.arrays_of(&form)?;
            let mut out = CompressedForm::new(self.kind(), t.shape());
            for (name, data) in arrays {
                out = out.with_array(name, data);
            }
            if let Ok(claimed) = form.getattr("nbytes") {
                let claimed: u64 = claimed.extract().map_err(|_| self.fail("`nbytes` must be a non-negative int"))?;
                if claimed != out.bytes() {
                    return Err(self.fail(format!(
                        "its form claims nbytes = {claimed}, but its arrays hold {} bytes (the storage biscale reports is what `arrays` holds)",
                        out.bytes()
                    )));
                }
            }
            out.flops_per_gather = flops;
            out.lossless = lossless;
            out.build_seconds = start.elapsed().as_secs_f64();
            *self.form.lock().unwrap_or_else(|e| e.into_inner()) = Some(form.unbind());
            Ok(out)
        })
    }

    fn gather(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, CompressError> {
        Python::attach(|py| {
            let guard = self.form.lock().unwrap_or_else(|e| e.into_inner());
            let Some(obj) = guard.as_ref() else { return Err(self.fail("gather before compress")) };
            let l = rows3(py, light.power.as_flattened().to_vec()).map_err(|e| self.py_fail(py, e))?;
            let got = obj.bind(py).call_method1("gather", (l,)).map_err(|e| self.py_fail(py, e))?;
            let rows = form.rows();
            let values: Vec<f32> = if let Ok(a) = got.cast::<PyArray2<f32>>() {
                check_rows(self, a.shape(), rows)?;
                a.readonly().as_array().iter().copied().collect()
            } else if let Ok(a) = got.cast::<PyArray2<f64>>() {
                check_rows(self, a.shape(), rows)?;
                a.readonly().as_array().iter().map(|&x| x as f32).collect()
            } else {
                return Err(self.fail(format!("gather(L) must return a NumPy array of {rows} x 3 float32 or float64")));
            };
            if let Some(i) = values.iter().position(|x| !x.is_finite()) {
                return Err(self.fail(format!("gather(L) returned {} at row {}", values[i], i / 3)));
            }
            form.lstar(values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        })
    }

    fn kernels(&self, _form: &CompressedForm) -> Result<biscale_kernels::KernelDesc, CompressError> {
        Err(self.fail("a Python compressor has no GPU gather"))
    }

    fn cacheable(&self) -> bool {
        false
    }

    fn has_kernels(&self) -> bool {
        false
    }
}

fn check_rows(c: &HostedCompressor, shape: &[usize], rows: usize) -> Result<(), CompressError> {
    match shape == [rows, 3] {
        true => Ok(()),
        false => Err(c.fail(format!("gather(L) returned an array of shape {shape:?}, the run needs [{rows}, 3]"))),
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // The pipeline's `log` records go to Python's logging (logger names follow the Rust
    // module paths, under `biscale`); a host that set up its own bridge keeps it.
    // Levels are not cached: `logging.basicConfig(level=logging.INFO)` after the first record
    // still shows the next ones (records are per stage and throttled progress lines, so asking
    // Python each time costs nothing that matters).
    let _ = pyo3_log::Logger::new(m.py(), pyo3_log::Caching::Loggers)?.install();
    // Warnings and progress lines as `log` records too, so they reach `logging` (no bars).
    biscale::util::report_through_log(true);
    m.add_class::<Experiment>()?;
    m.add_class::<Transfer>()?;
    m.add_class::<Form>()?;
    m.add_function(wrap_pyfunction!(compress, m)?)?;
    m.add_function(wrap_pyfunction!(read_image, m)?)?;
    m.add("BiscaleError", m.py().get_type::<BiscaleError>())?;
    m.add("ConfigError", m.py().get_type::<ConfigError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
