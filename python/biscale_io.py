"""biscale_io: read and write the NumPy files of biscale (needs NumPy only).

`biscale export CONFIG [--out DIR]` writes a config's stage outputs as ``.npz`` archives
(``numpy.load`` reads them as they are); `biscale eval CONFIG --lstar FILE` or
``--form FILE`` renders and scores what you compute from them exactly as a run scores one of
its compressor settings. This module loads every kind into a small dataclass and writes the two
kinds ``biscale eval`` reads back (``save_lstar``, ``save_form``). It depends on NumPy alone;
``Transfer.to_scipy()`` uses SciPy when it is installed.

The kinds
---------

Every archive has, beside its arrays, the 0-d string array ``__biscale__``: one JSON object
with ``format`` ("biscale-npz"), ``version``, ``what`` (the kind), the experiment and config,
and the kind's own fields. The loaders return it as ``.meta`` (a dict).

``t.npz`` -- the transfer matrix T, ``load_t``
    T as CSR: ``indptr`` (int64, rows + 1), ``indices`` (int32 column of each non-zero),
    ``data`` (float32) and ``shape`` (int64 ``[rows, cols]``). ``rows = V * M``: vertex ``v``
    (the mesh's vertex order, as in ``export-matrix``'s ``mesh.obj``) owns rows
    ``v*M .. v*M + M``, row ``v*M + j`` being local direction ``j`` of the vertex's local
    basis (``meta["shape"]["local_basis"]``, e.g. ``"bins:8"``: 8 x 8 = 64 equal-solid-angle
    Shirley-Chiu bins of the upper hemisphere in the vertex's frame, +Z the normal). Column
    ``k`` is texel ``k = face*R*R + row*R + col`` of the ``6 x R x R`` cubemap
    (``"cubemap:32"``; faces +X, -X, +Y, -Y, +Z, -Z, +Y up). ``T[v*M+j, k]`` is the
    unoccluded fraction of texel ``k`` seen from vertex ``v`` through bin ``j``, in [0, 1].

``l.npz`` -- the light vector L, ``load_l``
    ``l`` (float32, N x 3, N = 6 R^2): linear RGB *power* per cubemap texel, i.e. the sky's
    radiance integrated over the texel's solid angle. ``directions`` (float32, N x 3) are the
    texel centres (world frame) and ``solid_angles`` (float64, N) their exact solid angles
    (they sum to 4 pi), so ``l / solid_angles[:, None]`` is the mean radiance.

``lstar.npz`` -- the local incident light L* = T L, ``load_lstar``
    ``lstar`` (float32, V*M x 3): row ``v*M + j`` is the RGB power that reaches vertex ``v``
    through local bin ``j``, every row accumulated in float64 and rounded to float32: the
    uncompressed L* a run renders and compares every compressor with. With
    ``[runtime] light_moments = true`` it is the light moments' L* instead (``meta["product"]``
    says ``"light_moments"`` instead of ``"paper"``), which is not T L. ``local_directions``
    (float32, M x 3) are the bins' centre directions (local frame, +Z the normal) and
    ``local_mean_cosines`` (float64, M) their mean cosines.

``form-<label>.npz`` -- one compressor setting's compressed form, ``load_form``
    Exactly biscale's ``CompressedForm``: every array under its own name at its stored type
    (uint8, int8, uint16, int16, uint32 or float32, all flat), and in the metadata ``kind``
    (``sparse``, ``bicluster``, ``cpca``, ``haar``), ``label`` (``cpca-k32-c8``), ``params``,
    ``shape`` (``vertices``, ``local_basis``, ``light_basis``, ``rows``, ``cols``), ``meta``
    (the small integers the gather reads), ``lossless``, ``flops_per_gather``,
    ``build_seconds`` and ``arrays`` (their order). What the arrays mean is the compressor's
    (``compressors/src/<kind>/``); ``sparse`` is T itself as ``row_ptr``, ``col_idx``,
    ``values``.

``btf-<material>.npz`` -- a material's dense BTF table, ``load_btf``
    ``data`` (float32, H x W x V x M x 3): ``data[ty, tx, view, j]`` is the outgoing linear
    RGB radiance of patch texel ``(tx, ty)`` towards view sample ``view`` under unit
    perpendicular irradiance from local bin ``j``, the bin's mean cosine included, so a pixel
    is ``sum_j data[..., j, :] * lstar[v*M + j, :]`` (interpolated over the triangle).
    ``light_directions`` (M x 3) and ``light_mean_cosines`` (M) describe the light bins (the
    rows ``j`` of L*); ``view_directions`` (V x 3) the view samples, bin centres of an
    ``m x m`` grid (``meta["view_grid"]``; a BTF without a view axis has V = 1 and no
    ``view_directions``).

Conventions: rows are ``v*M + j`` everywhere (vertex-major); channels are linear RGB, in that
order; light is power (radiance times solid angle), never radiance per steradian; every
float
array is float32 except the solid angles and mean cosines (float64).

Round trip
----------

>>> t, l = load_t("out/x-export/t.npz"), load_l("out/x-export/l.npz")
>>> lstar = t.matvec(l.l)                               # your L*, (V*M, 3)
>>> save_lstar("mine.npz", lstar, like=load_lstar("out/x-export/lstar.npz"))
$ biscale eval CONFIG --lstar mine.npz                   # metrics.json + images

Files are written atomically (a temporary file beside the target, then a rename).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from typing import Any, Dict, Optional

import numpy as np

META = "__biscale__"
"""Name of the metadata array (a 0-d string of JSON) in every archive."""

FORMAT_VERSION = 1

# A form's array types: NumPy dtype -> the element type name biscale uses.
FORM_DTYPES = {
    np.dtype(np.uint8): "u8",
    np.dtype(np.int8): "i8",
    np.dtype(np.uint16): "u16",
    np.dtype(np.int16): "i16",
    np.dtype(np.uint32): "u32",
    np.dtype(np.float32): "f32",
}


def _load(path, what: str):
    """Every array of an archive and its metadata; an error if it is another kind."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    raw = arrays.pop(META, None)
    meta = json.loads(str(raw[()])) if raw is not None else {}
    found = meta.get("what")
    if found is not None and found != what:
        raise ValueError(f"{path}: holds a '{found}' export, not '{what}'")
    return arrays, meta


def _save_npz(path, arrays: Dict[str, np.ndarray], meta: Dict[str, Any]) -> None:
    """Write ``arrays`` and ``meta`` as an .npz archive at exactly ``path``, atomically."""
    path = os.fspath(path)
    if META in arrays:
        raise ValueError(f"an array may not be called {META!r} (the metadata's name)")
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays, **{META: np.array(json.dumps(meta))})
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _header(what: str, like_meta: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    meta = {"format": "biscale-npz", "version": FORMAT_VERSION, "what": what, "written_by": "biscale_io.py"}
    for k in ("experiment", "config"):
        if like_meta and k in like_meta:
            meta[k] = like_meta[k]
    return meta


class _Shaped:
    """The shape fields of a file's metadata (``meta["shape"]``), for arrays with rows
    ``v*M + j``."""

    meta: Dict[str, Any]

    @property
    def vertices(self) -> int:
        return int(self.meta["shape"]["vertices"])

    @property
    def local_dirs(self) -> int:
        """M, the rows per vertex."""
        return int(self.meta["shape"]["local_dirs"])


@dataclass
class Transfer(_Shaped):
    """T as CSR (``t.npz``)."""

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray
    shape: tuple
    meta: Dict[str, Any] = field(default_factory=dict)

    @property
    def nnz(self) -> int:
        return int(self.indptr[-1])

    def row_of_nonzero(self) -> np.ndarray:
        """The row of every non-zero (COO row indices)."""
        return np.repeat(np.arange(self.shape[0], dtype=np.int64), np.diff(self.indptr))

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``T @ x`` for ``x`` of shape (cols,) or (cols, k), accumulated in float64."""
        x = np.asarray(x, dtype=np.float64)
        products = self.data.astype(np.float64).reshape((-1,) + (1,) * (x.ndim - 1)) * x[self.indices]
        out = np.zeros((self.shape[0],) + x.shape[1:], dtype=np.float64)
        np.add.at(out, self.row_of_nonzero(), products)
        return out

    def to_scipy(self):
        """T as ``scipy.sparse.csr_matrix`` (needs SciPy)."""
        import scipy.sparse as sp

        return sp.csr_matrix((self.data, self.indices, self.indptr), shape=self.shape)


def load_t(path) -> Transfer:
    """Read ``t.npz``: T as CSR with its metadata."""
    a, meta = _load(path, "t")
    shape = tuple(int(n) for n in a["shape"])
    t = Transfer(a["indptr"], a["indices"], a["data"], shape, meta)
    if t.indptr.shape != (shape[0] + 1,) or t.indices.shape != t.data.shape or t.nnz != t.data.size:
        raise ValueError(f"{path}: indptr, indices and data do not fit shape {shape}")
    return t


@dataclass
class Light:
    """The light vector L (``l.npz``)."""

    l: np.ndarray
    directions: Optional[np.ndarray]
    solid_angles: Optional[np.ndarray]
    meta: Dict[str, Any] = field(default_factory=dict)

    @property
    def radiance(self) -> np.ndarray:
        """Mean radiance per texel (power over solid angle), N x 3."""
        return self.l / self.solid_angles[:, None]


def load_l(path) -> Light:
    """Read ``l.npz`` (a bare ``l.npy`` also works: no directions, no metadata)."""
    if os.fspath(path).endswith(".npy"):
        return Light(np.load(path, allow_pickle=False), None, None, {})
    a, meta = _load(path, "l")
    return Light(a["l"], a.get("directions"), a.get("solid_angles"), meta)


@dataclass
class Lstar(_Shaped):
    """L*, rows ``v*M + j`` (``lstar.npz``)."""

    lstar: np.ndarray
    meta: Dict[str, Any] = field(default_factory=dict)
    local_directions: Optional[np.ndarray] = None
    local_mean_cosines: Optional[np.ndarray] = None

    def per_vertex(self) -> np.ndarray:
        """The same values as (V, M, 3)."""
        return self.lstar.reshape(self.vertices, self.local_dirs, 3)


def load_lstar(path) -> Lstar:
    """Read ``lstar.npz``."""
    a, meta = _load(path, "lstar")
    return Lstar(a["lstar"], meta, a.get("local_directions"), a.get("local_mean_cosines"))


def _shape_of(like) -> Optional[Dict[str, Any]]:
    """The ``shape`` metadata of ``like``: an Lstar, Transfer or Form, a metadata dict, or a
    path to any exported archive that has one."""
    if like is None:
        return None
    if isinstance(like, Form):
        return dict(like.shape)
    if isinstance(like, (str, os.PathLike)):
        with np.load(like, allow_pickle=False) as z:
            like = json.loads(str(z[META][()]))
    meta = like if isinstance(like, dict) else getattr(like, "meta", None)
    if not meta or "shape" not in meta:
        raise ValueError("`like` has no shape metadata (give an exported Lstar, Transfer, Form or its file)")
    return dict(meta["shape"])


def save_lstar(path, array, like=None, meta: Optional[Dict[str, Any]] = None) -> None:
    """Write an L* that ``biscale eval --lstar`` reads: ``array`` of shape (V*M, 3) or
    (V, M, 3), any float type (stored as float32; every value must be finite). ``like`` (an
    exported Lstar, Transfer or Form, or the path of one) gives the shape metadata, which is
    checked against the array, so ``biscale eval`` can say what does not match; ``meta`` adds
    fields of your own."""
    a = np.asarray(array)
    if a.dtype.kind != "f":
        raise TypeError(f"L* must be floating point, not {a.dtype}")
    if a.ndim == 3:
        a = a.reshape(-1, a.shape[-1])
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"L* must be (V*M, 3) or (V, M, 3) RGB rows, not {np.shape(array)}")
    if not np.all(np.isfinite(a)):
        row = int(np.argwhere(~np.isfinite(a))[0][0])
        raise ValueError(f"L* row {row} is not finite")
    shape = _shape_of(like)
    if shape is not None and a.shape[0] != int(shape["vertices"]) * int(shape["local_dirs"]):
        raise ValueError(
            f"L* has {a.shape[0]} rows, `like` has {shape['vertices']} vertices x {shape['local_dirs']} = "
            f"{int(shape['vertices']) * int(shape['local_dirs'])}"
        )
    like_meta = like.file_meta if isinstance(like, Form) else like if isinstance(like, dict) else getattr(like, "meta", None)
    header = _header("lstar", like_meta)
    if shape is not None:
        header["shape"] = shape
    header.update(meta or {})
    _save_npz(path, {"lstar": np.ascontiguousarray(a, dtype=np.float32)}, header)


@dataclass
class Form:
    """A compressed form (``form-<label>.npz``): biscale's ``CompressedForm``."""

    kind: str
    arrays: Dict[str, np.ndarray]
    meta: Dict[str, int]
    shape: Dict[str, Any]
    label: Optional[str] = None
    params: Optional[Dict[str, Any]] = None
    lossless: bool = False
    flops_per_gather: int = 0
    build_seconds: float = 0.0
    file_meta: Dict[str, Any] = field(default_factory=dict)

    @property
    def bytes(self) -> int:
        """Stored bytes over every array (what biscale reports)."""
        return sum(a.nbytes for a in self.arrays.values())


def load_form(path) -> Form:
    """Read ``form-<label>.npz``; the arrays keep their order and types."""
    a, meta = _load(path, "form")
    order = [x["name"] if isinstance(x, dict) else x for x in meta.get("arrays", list(a))]
    missing = [n for n in order if n not in a]
    if missing or set(a) != set(order):
        raise ValueError(f"{path}: arrays {sorted(a)} do not match the metadata's list {order}")
    return Form(
        kind=meta["kind"],
        arrays={n: a[n] for n in order},
        meta={k: int(v) for k, v in meta.get("meta", {}).items()},
        shape=dict(meta["shape"]),
        label=meta.get("label"),
        params=meta.get("params"),
        lossless=bool(meta.get("lossless", False)),
        flops_per_gather=int(meta.get("flops_per_gather", 0)),
        build_seconds=float(meta.get("build_seconds", 0.0)),
        file_meta=meta,
    )


def save_form(path, form: Form) -> None:
    """Write ``form`` as ``biscale eval --form`` reads it: every array flat, at one of the types
    biscale stores (uint8, int8, uint16, int16, uint32, float32; anything else is an error,
    never a silent cast). The shape must name ``vertices``, ``local_basis`` and
    ``light_basis`` (copy ``shape`` from a loaded form or ``t.npz``'s metadata)."""
    for k in ("vertices", "local_basis", "light_basis"):
        if k not in form.shape:
            raise ValueError(f"form.shape has no {k!r}")
    arrays, listing = {}, []
    for name, arr in form.arrays.items():
        arr = np.asarray(arr)
        if arr.dtype not in FORM_DTYPES:
            raise TypeError(f"array {name!r} is {arr.dtype}; a form's arrays are {', '.join(map(str, FORM_DTYPES))}")
        if not name or not all(c.isalnum() or c in "_.-" for c in name) or name.startswith("__"):
            raise ValueError(f"array name {name!r}: letters, digits, '_', '.', '-', not starting with '__'")
        arrays[name] = np.ascontiguousarray(arr.ravel())
        listing.append({"name": name, "dtype": FORM_DTYPES[arr.dtype]})
    header = _header("form", form.file_meta)
    header.update(
        {
            "kind": form.kind,
            "label": form.label,
            "params": form.params,
            "shape": form.shape,
            "meta": {k: int(v) for k, v in form.meta.items()},
            "lossless": bool(form.lossless),
            "flops_per_gather": int(form.flops_per_gather),
            "build_seconds": float(form.build_seconds),
            "bytes": int(sum(a.nbytes for a in arrays.values())),
            "arrays": listing,
        }
    )
    _save_npz(path, arrays, header)


@dataclass
class Btf:
    """A material's dense BTF (``btf-<material>.npz``): ``data[ty, tx, view, light, rgb]``."""

    data: np.ndarray
    light_directions: Optional[np.ndarray]
    light_mean_cosines: Optional[np.ndarray]
    view_directions: Optional[np.ndarray]
    meta: Dict[str, Any] = field(default_factory=dict)

    def shade(self, lstar_vertex: np.ndarray, tx: int = 0, ty: int = 0, view: int = 0) -> np.ndarray:
        """The RGB radiance of one texel and view sample under one vertex's L* (M x 3)."""
        return (self.data[ty, tx, view] * lstar_vertex).sum(axis=0)


def load_btf(path) -> Btf:
    """Read ``btf-<material>.npz``."""
    a, meta = _load(path, "btf")
    return Btf(a["data"], a.get("light_directions"), a.get("light_mean_cosines"), a.get("view_directions"), meta)
