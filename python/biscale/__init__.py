"""biscale: all-frequency bi-scale precomputed radiance transfer, from Python.

The pipeline of the ``biscale`` command line as a module, with the same semantics: a config
loaded with the same overrides runs the same stages, writes the same output folder and
returns the same ``metrics.json`` record. Your own compressor (NumPy, PyTorch, ...) runs beside
the built-in ones in the same run, and is gathered, imaged, timed and reported like them::

    import biscale
    exp = biscale.Experiment.load("configs/smoke.toml", set={"runtime.repeats": 1})
    metrics = exp.run(out="out/smoke-py")              # the record metrics.json holds
    T, L = exp.transfer(), exp.light()                  # T (CSR arrays, .to_scipy()), L (N x 3)
    form = biscale.compress(T, "bicluster")             # a built-in kind's form
    lstar = form.gather(L)                              # L* = T L, rows x 3
    image = exp.shade(lstar)                            # H x W x 3, as the run renders it
    record = exp.evaluate(form, name="bc")              # scored as `biscale eval --form`

A Python compressor is any object with ``compress(T, context)`` that returns a form with
``gather(L)``, ``flops_per_gather`` and, for its storage, ``arrays`` (see
:class:`PythonCompressor`); pass it as ``exp.run(compressors=[obj])``.

Long calls release the GIL. Errors are :class:`BiscaleError` (a config's located message,
``configs/x.toml:14:1: unknown field ...``, is a :class:`ConfigError`). Progress goes to the
``logging`` logger ``biscale`` (``logging.basicConfig(level=logging.INFO)`` to see it).

``biscale_io`` (beside this package in the source tree) is the NumPy-only reader of the
``.npz`` files ``biscale export`` writes; it needs no compiled code.
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, Iterable, List, Mapping, Optional, Protocol, Sequence, Union, runtime_checkable

import numpy as np

from . import _native
from ._native import BiscaleError, ConfigError

__all__ = [
    "BiscaleError",
    "ConfigError",
    "Experiment",
    "Form",
    "PythonCompressor",
    "PythonForm",
    "Transfer",
    "compress",
    "read_image",
]
__version__ = _native.__version__

PathLike = Union[str, "os.PathLike[str]"]


def _toml_value(v: Any) -> str:
    """``v`` as a TOML value for ``--set KEY=VALUE``."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if f != f or f in (float("inf"), float("-inf")):
            raise ConfigError(f"{v!r}: a config value must be finite")
        return repr(f)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise ConfigError(f"{v!r}: a config value is a bool, number, string, list or dict, not {type(v).__name__}")


def _overrides(set: Optional[Mapping[str, Any]]) -> List[str]:
    if set is None:
        return []
    if not isinstance(set, Mapping):
        raise ConfigError("set= takes a dict of dotted keys to values, e.g. {'runtime.repeats': 1}")
    return [f"{k}={_toml_value(v)}" for k, v in set.items()]


def _opt_path(p: Optional[PathLike]) -> Optional[str]:
    """A path argument as the native calls take it (``None`` stays ``None``)."""
    return None if p is None else os.fspath(p)


def _float32(a: Any, what: str) -> np.ndarray:
    """``a`` as a C-contiguous float32 array (float64 is converted; anything else refused)."""
    a = np.asarray(a)
    if a.dtype != np.float32:
        if not np.issubdtype(a.dtype, np.floating):
            raise BiscaleError(f"{what} has dtype {a.dtype}; it is float32 (or float64, converted)")
        a = a.astype(np.float32)
    return np.ascontiguousarray(a)


def _light_array(L: Any) -> np.ndarray:
    """``L`` as the C-contiguous float32 N x 3 array the native calls take."""
    return _float32(L, "L")


def _lstar_rows(lstar: Any) -> np.ndarray:
    """An ``L*`` (rows x 3, or V x M x 3) as float32 rows x 3."""
    a = _float32(lstar, "L*")
    if a.ndim == 3 and a.shape[2] == 3:
        a = a.reshape(-1, 3)
    return a


def read_image(path: PathLike) -> np.ndarray:
    """An EXR image the pipeline wrote (a run's ``images/*.exr``) as H x W x 3 float32, linear RGB."""
    return _native.read_image(os.fspath(path))


class Transfer:
    """The transfer matrix ``T``: rows ``v*M + j`` (vertex ``v``, local direction ``j``),
    columns the light's cubemap texels. ``indptr``/``indices``/``data`` are its CSR arrays
    (copies); ``to_scipy()`` builds a ``scipy.sparse.csr_array``."""

    def __init__(self, native: "_native.Transfer") -> None:
        self._t = native

    shape = property(lambda self: self._t.shape, doc="(rows, cols)")
    nnz = property(lambda self: self._t.nnz, doc="stored non-zeros")
    vertices = property(lambda self: self._t.vertices, doc="mesh vertices V")
    local_dirs = property(lambda self: self._t.local_dirs, doc="local directions per vertex M")
    local_basis = property(lambda self: self._t.local_basis, doc="e.g. 'bins:8'")
    light_basis = property(lambda self: self._t.light_basis, doc="e.g. 'cubemap:32'")
    indptr = property(lambda self: self._t.indptr(), doc="int64, rows + 1")
    indices = property(lambda self: self._t.indices(), doc="int32, nnz")
    data = property(lambda self: self._t.data(), doc="float32, nnz")

    def product(self, L: Any, *, moments: bool = False) -> np.ndarray:
        """``T L`` in float64 (rows x 3): the exact product a lossless gather reproduces. With
        ``moments=True`` the light-moments product (``runtime.light_moments``: every texel with
        its own cosine, the BRDF at each bin's mean light direction), summed per texel in f64;
        what :meth:`Form.gather_moments` approximates."""
        return self._t.product(_light_array(L), moments)

    @property
    def normals(self) -> np.ndarray:
        """The vertex normals ``T`` was traced with (V x 3 float32)."""
        return self._t.normals()

    def to_scipy(self) -> Any:
        """``T`` as a ``scipy.sparse.csr_array`` (needs SciPy)."""
        import scipy.sparse

        return scipy.sparse.csr_array((self.data, self.indices, self.indptr), shape=self.shape)

    def __repr__(self) -> str:
        r, c = self.shape
        return f"<biscale.Transfer {r} x {c}, {self.nnz} non-zeros, {self.local_basis} x {self.light_basis}>"


class Form:
    """A built-in compressor's form of a :class:`Transfer` (:func:`compress`)."""

    def __init__(self, native: "_native.Form") -> None:
        self._f = native

    kind = property(lambda self: self._f.kind, doc="the compressor kind")
    nbytes = property(lambda self: self._f.nbytes, doc="storage of the form's arrays, bytes")
    flops_per_gather = property(lambda self: self._f.flops_per_gather, doc="flops of one monochrome gather")
    lossless = property(lambda self: self._f.lossless, doc="whether the gather reproduces T L up to rounding")
    build_seconds = property(lambda self: self._f.build_seconds, doc="seconds the compressor took")

    @property
    def arrays(self) -> Dict[str, np.ndarray]:
        """The form's arrays by name, at their stored widths (copies)."""
        return self._f.arrays()

    def gather(self, L: Any) -> np.ndarray:
        """``L*`` of the light ``L`` (N x 3): rows x 3 float32, the form's own CPU gather."""
        return self._f.gather(_light_array(L))

    def gather_moments(self, L: Any) -> np.ndarray:
        """``L*`` of ``L`` with light moments, as a run with ``runtime.light_moments = true``
        renders it: the form gathers the light's three direction moments
        (:meth:`Experiment.light_moments`) and each vertex's bins are resolved with the normal
        ``T`` was traced with. Rows x 3 float32; compare with ``T.product(L, moments=True)``."""
        return self._f.gather_moments(_light_array(L))

    def save(self, path: PathLike, *, label: Optional[str] = None, force: bool = False) -> None:
        """Write the form as ``biscale export`` writes ``form-<label>.npz`` (``label`` defaults
        to the kind): ``biscale eval --form`` scores it, ``biscale_io.load_form`` reads it. The
        file is written whole or not at all, at a new path or over a ``.npz`` biscale wrote:
        a file biscale did not write is refused (``BiscaleError``) unless ``force=True``, and a
        link, device node, FIFO or folder is refused always."""
        self._f.save(os.fspath(path), label or self.kind, force)

    def __repr__(self) -> str:
        return f"<biscale.Form {self.kind}, {self.nbytes} bytes, {self.flops_per_gather} flops/gather>"


def compress(T: Transfer, kind: str, *, seed: int = 0, **params: Any) -> Form:
    """Compress ``T`` with the built-in kind ``kind`` (``sparse``, ``bicluster``, ``cpca``,
    ``haar``) or a plugin (``plugin``, with ``path`` its shared library and ``params`` its
    table), and its parameters as a config's ``[[compressors]]`` entry names them, e.g.
    ``compress(T, "cpca", clusters=8, components=4)`` or
    ``compress(T, "plugin", path="libquantized.so", params={"scale": 0.25})`` (a relative
    ``path`` is taken from the working directory)."""
    if not isinstance(T, Transfer):
        raise BiscaleError(f"compress takes a biscale.Transfer (Experiment.transfer()), not {type(T).__name__}")
    if kind == "plugin" and isinstance(params.get("path"), (str, os.PathLike)):
        params["path"] = os.path.abspath(os.fspath(params["path"]))
    return Form(_native.compress(T._t, kind, json.dumps(params), seed))


@runtime_checkable
class PythonForm(Protocol):
    """What a Python compressor's ``compress`` returns.

    ``gather(L)`` takes ``L`` (N x 3 float32, the light's power per texel) and returns ``L*``
    (rows x 3, float32 or float64, row ``v*M + j``); it is checked (shape, finite values) before
    it is scored. ``flops_per_gather`` is the flops of one monochrome gather (your count; the
    report shows it as given). ``arrays`` (a dict of NumPy arrays of float32, uint32, uint16,
    int16, uint8 or int8) is the form's storage: the bytes biscale reports are what it holds,
    and an ``nbytes`` attribute, if given, must agree. ``lossless = True`` is a claim biscale
    checks against the f64 product."""

    flops_per_gather: int

    def gather(self, L: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class PythonCompressor(Protocol):
    """A compressor written in Python: ``compress(T, context)`` with ``T`` a :class:`Transfer`
    (a copy of the run's) and ``context`` a dict (``seed``: the run's seed). Optional:
    ``label`` (the setting's label in the report; default the class name in lower case) and
    ``params`` (a JSON-able dict recorded in metrics.json)."""

    def compress(self, T: Any, context: Dict[str, Any]) -> PythonForm: ...


def _label(c: Any) -> str:
    label = getattr(c, "label", None) or type(c).__name__.lower()
    return str(label)


class Experiment:
    """A config, loaded as ``biscale run CONFIG --set KEY=VALUE ...`` loads it."""

    def __init__(self, native: "_native.Experiment") -> None:
        self._e = native
        self.out_dir: Optional[str] = None

    @staticmethod
    def load(path: PathLike, set: Optional[Mapping[str, Any]] = None) -> "Experiment":
        """Load the config at ``path`` with ``set`` applied (dotted keys to values, as ``--set``)."""
        return Experiment(_native.Experiment.load(os.fspath(path), _overrides(set)))

    name = property(lambda self: self._e.name, doc="the experiment's name")
    source = property(lambda self: self._e.source, doc="the config text as it runs")
    seed = property(lambda self: self._e.seed, doc="the seed every compressor of a run is given")

    @property
    def compressor_settings(self) -> List[Dict[str, Any]]:
        """The config's compressor settings in run order: ``{"label", "kind", "params"}`` each
        (``compress(T, s["kind"], seed=exp.seed, **s["params"])`` builds the run's form)."""
        return [{"label": l, "kind": k, "params": json.loads(p)} for l, k, p in self._e.compressor_settings]

    @property
    def compressor_labels(self) -> List[str]:
        """The labels of the config's compressor settings, in run order."""
        return [s["label"] for s in self.compressor_settings]

    def plan(self, *, cache_dir: Optional[PathLike] = None, no_cache: bool = False) -> str:
        """What ``biscale plan`` prints."""
        return self._e.plan(_opt_path(cache_dir), no_cache)

    def run(
        self,
        out: Optional[PathLike] = None,
        *,
        cache_dir: Optional[PathLike] = None,
        no_cache: bool = False,
        compressors: Sequence[PythonCompressor] = (),
    ) -> Dict[str, Any]:
        """Run the experiment (output folder ``out``, default ``out/<name>``) with each Python
        compressor in ``compressors`` as one more setting; returns the metrics record
        (``metrics.json``). ``self.out_dir`` is the folder written."""
        objs = list(compressors)
        for c in objs:
            if not callable(getattr(c, "compress", None)):
                raise BiscaleError(f"{c!r} has no compress(T, context) method (see biscale.PythonCompressor)")
        labels = [_label(c) for c in objs]
        out_dir, text = self._e.run(
            _opt_path(out),
            _opt_path(cache_dir),
            no_cache,
            objs,
            labels,
        )
        self.out_dir = out_dir
        return json.loads(text)

    def evaluate(
        self,
        lstar: Any,
        *,
        name: Optional[str] = None,
        out: Optional[PathLike] = None,
        cache_dir: Optional[PathLike] = None,
        no_cache: bool = False,
    ) -> Dict[str, Any]:
        """Score an ``L*`` you computed (rows x 3, float32 or float64; rows ``v*M + j``), or a
        built-in :class:`Form`, as a run scores a compressor: images against the uncompressed
        render and the reference, errors, a report in ``out`` (default
        ``out/<experiment>-eval-<name>``). Returns the record ``biscale eval`` writes.

        ``name`` labels the setting (default ``python`` for an array, the kind for a form).
        ``lstar`` may also be a path to a ``.npy``/``.npz`` file (as ``--lstar`` takes it); an
        array or a form is handed over in memory (nothing is written but the run's folder), a
        form scored as ``eval --form`` scores one (its flops counted again, its gather timed,
        its build time 0). A Python compressor's form is scored with its storage and timings
        by :meth:`run` instead."""

        def done(result) -> Dict[str, Any]:
            out_dir, text = result
            self.out_dir = out_dir
            return json.loads(text)

        if isinstance(lstar, Form):
            label = name or lstar.kind
            return done(self._e.evaluate_form(lstar._f, label, _opt_path(out), _opt_path(cache_dir), no_cache))
        if not isinstance(lstar, (str, os.PathLike, np.ndarray, list, tuple)) and callable(getattr(lstar, "gather", None)):
            raise BiscaleError(
                f"evaluate takes an L*, a path or a biscale.Form, not {type(lstar).__name__}: score a Python "
                "compressor's form with run(compressors=[...]), or evaluate(form.gather(exp.light()))"
            )
        name = name or "python"
        if isinstance(lstar, (str, os.PathLike)):
            # A file, as `biscale eval --lstar FILE` takes it.
            return done(self._e.evaluate(os.fspath(lstar), name, _opt_path(out), _opt_path(cache_dir), no_cache, False))
        a = np.asarray(lstar)
        if a.dtype not in (np.float32, np.float64):
            raise BiscaleError(f"L* has dtype {a.dtype}; it is float32 or float64")
        if a.ndim == 3:  # (V, M, 3), as a file may hold it
            a = a.reshape(-1, a.shape[-1])
        values = np.ascontiguousarray(a, dtype=np.float64)
        return done(self._e.evaluate_values(values, name, _opt_path(out), _opt_path(cache_dir), no_cache))

    def light(self) -> np.ndarray:
        """The light vector ``L``: power per cubemap texel, N x 3 float32."""
        return self._e.light()

    def light_moments(self) -> np.ndarray:
        """The light's three direction moments (``runtime.light_moments``): 3 x N x 3 float32,
        ``[a, k]`` is ``L[k] * d_k[a]`` for the world axes ``a`` = x, y, z and ``d_k`` the direction
        of texel ``k`` (its centre; with ``lighting.texel_directions = "mean"`` the mean direction
        of its light, per channel). A run with light moments gathers these three through the
        same form instead of ``L`` (:meth:`Form.gather_moments`)."""
        return self._e.light_moments()

    def shade(self, lstar: Any, *, cache_dir: Optional[PathLike] = None, no_cache: bool = False) -> np.ndarray:
        """The image a run renders of ``lstar`` (rows x 3 or V x M x 3): H x W x 3 float32,
        linear RGB, at the run's camera with its background (``images/*.exr`` hold the same)."""
        return self._e.shade(_lstar_rows(lstar), _opt_path(cache_dir), no_cache)

    def reference(self, *, cache_dir: Optional[PathLike] = None, no_cache: bool = False) -> np.ndarray:
        """The ground-truth reference image a run compares with (``images/reference.exr``: at
        ``report.reference_downscale``, with the background), from the stage cache or traced:
        H x W x 3 float32, linear RGB."""
        return self._e.reference(_opt_path(cache_dir), no_cache)

    def transfer(self, *, cache_dir: Optional[PathLike] = None, no_cache: bool = False) -> Transfer:
        """``T`` from the stage cache, or traced (as ``biscale run`` gets it)."""
        return Transfer(self._e.transfer(_opt_path(cache_dir), no_cache))

    def __repr__(self) -> str:
        return f"<biscale.Experiment {self.name!r}>"
