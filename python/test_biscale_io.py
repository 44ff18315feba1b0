#!/usr/bin/env python3
"""Round trip of biscale's NumPy files through biscale_io (plain asserts; NumPy only).

    python3 python/test_biscale_io.py DIR

DIR is a `biscale export` folder (every kind: t, l, lstar, forms, btf). The test loads each
kind, checks shapes, types and metadata against each other, checks that T @ L is the exported
L* to float tolerance, and writes into DIR/py/ what `biscale eval` reads back (the Rust test
`tools/cli/tests/cli/interop.rs` evaluates them):

* ``lstar_half.npz``   -- 0.5 x the exported L* (save_lstar, like=the export)
* ``lstar_same.npy``   -- the exported L* as a bare (V, M, 3) float64 .npy
* ``form-<label>.npz`` -- each exported sparse and bicluster form, loaded and saved again
"""

import glob
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import biscale_io as bio  # noqa: E402


def check_meta(meta, what):
    assert meta["format"] == "biscale-npz", meta
    assert meta["version"] == bio.FORMAT_VERSION, meta
    assert meta["what"] == what, meta


def main(folder):
    out = os.path.join(folder, "py")
    os.makedirs(out, exist_ok=True)

    t = bio.load_t(os.path.join(folder, "t.npz"))
    check_meta(t.meta, "t")
    rows, cols = t.shape
    v, m = t.vertices, t.local_dirs
    assert rows == v * m and cols == t.meta["shape"]["cols"], (t.shape, t.meta["shape"])
    assert t.indptr.dtype == np.int64 and t.indices.dtype == np.int32 and t.data.dtype == np.float32
    assert t.indptr[0] == 0 and np.all(np.diff(t.indptr) >= 0) and t.nnz == t.meta["nnz"]
    assert t.indices.min() >= 0 and t.indices.max() < cols
    assert np.all(t.data > 0) and np.all(t.data <= 1)
    assert t.meta["shape"]["local_basis"].startswith("bins:") and t.meta["shape"]["light_basis"].startswith("cubemap:")
    print(f"t: {rows} x {cols}, {t.nnz} non-zeros, {v} vertices x {m}")

    light = bio.load_l(os.path.join(folder, "l.npz"))
    check_meta(light.meta, "l")
    assert light.l.shape == (cols, 3) and light.l.dtype == np.float32
    assert light.directions.shape == (cols, 3)
    assert np.allclose(np.linalg.norm(light.directions, axis=1), 1, atol=1e-5)
    assert abs(light.solid_angles.sum() - 4 * np.pi) < 1e-9, light.solid_angles.sum()
    assert np.allclose(light.l.astype(np.float64).sum(axis=0), light.meta["total_power"], rtol=1e-5)
    assert np.all(light.radiance >= 0)
    print(f"l: {cols} x 3, total power {light.meta['total_power']}")

    ls = bio.load_lstar(os.path.join(folder, "lstar.npz"))
    check_meta(ls.meta, "lstar")
    assert ls.lstar.shape == (rows, 3) and ls.lstar.dtype == np.float32
    assert ls.meta["shape"] == t.meta["shape"], (ls.meta["shape"], t.meta["shape"])
    assert ls.per_vertex().shape == (v, m, 3)
    assert ls.local_directions.shape == (m, 3) and np.all(ls.local_directions[:, 2] > 0)
    assert ls.local_mean_cosines.shape == (m,)
    # sum_j cosbar_j * 2 pi / M = pi (docs/DESIGN.md section 3).
    assert abs(ls.local_mean_cosines.sum() * 2 * np.pi / m - np.pi) < 1e-9
    if ls.meta["product"] == "paper":
        tl = t.matvec(light.l)
        scale = max(1.0, float(np.abs(tl).max()))
        err = float(np.abs(tl - ls.lstar).max())
        assert err <= 1e-6 * scale, f"T @ L differs from lstar by {err}"
        print(f"lstar: T @ L matches to {err:.2e} (largest value {scale:.3g})")
        try:
            import scipy  # noqa: F401

            assert np.allclose(t.to_scipy() @ light.l.astype(np.float64), tl, rtol=1e-6, atol=1e-6 * scale)
            print("lstar: scipy's T @ L matches too")
        except ImportError:
            pass

    half = 0.5 * ls.lstar
    bio.save_lstar(os.path.join(out, "lstar_half.npz"), half, like=ls, meta={"note": "0.5 x the export's L*"})
    back = bio.load_lstar(os.path.join(out, "lstar_half.npz"))
    assert np.array_equal(back.lstar, half) and back.meta["shape"] == ls.meta["shape"]
    np.save(os.path.join(out, "lstar_same.npy"), ls.per_vertex().astype(np.float64))
    try:
        bio.save_lstar(os.path.join(out, "bad.npz"), ls.lstar[:-1], like=ls)
        raise AssertionError("a short L* was saved")
    except ValueError as e:
        assert "rows" in str(e), e
    assert not os.path.exists(os.path.join(out, "bad.npz"))

    forms = sorted(glob.glob(os.path.join(folder, "form-*.npz")))
    assert forms, "no forms exported"
    for path in forms:
        f = bio.load_form(path)
        check_meta(f.file_meta, "form")
        assert f.kind in ("sparse", "bicluster", "cpca", "haar"), f.kind
        assert f.shape == t.meta["shape"], (f.shape, t.meta["shape"])
        assert f.bytes == f.file_meta["bytes"], (f.bytes, f.file_meta["bytes"])
        for entry in f.file_meta["arrays"]:
            a = f.arrays[entry["name"]]
            assert a.ndim == 1 and bio.FORM_DTYPES[a.dtype] == entry["dtype"], (entry, a.dtype)
        if f.kind == "sparse":
            assert np.array_equal(f.arrays["row_ptr"], t.indptr)
            assert np.array_equal(f.arrays["col_idx"], t.indices)
            assert np.array_equal(f.arrays["values"], t.data)
        if f.kind in ("sparse", "bicluster"):
            again = os.path.join(out, os.path.basename(path))
            bio.save_form(again, f)
            g = bio.load_form(again)
            assert (g.kind, g.label, g.meta, g.shape, g.lossless) == (f.kind, f.label, f.meta, f.shape, f.lossless)
            assert list(g.arrays) == list(f.arrays)
            assert all(np.array_equal(g.arrays[n], f.arrays[n]) and g.arrays[n].dtype == f.arrays[n].dtype for n in f.arrays)
        print(f"{os.path.basename(path)}: {f.kind}, {len(f.arrays)} arrays, {f.bytes} bytes, meta {f.meta}")
    try:
        bad = bio.load_form(forms[0])
        bad.arrays[next(iter(bad.arrays))] = np.zeros(3, dtype=np.float64)
        bio.save_form(os.path.join(out, "bad-form.npz"), bad)
        raise AssertionError("a float64 form array was saved")
    except TypeError as e:
        assert "float64" in str(e), e

    btfs = sorted(glob.glob(os.path.join(folder, "btf-*.npz")))
    assert btfs, "no BTFs exported"
    for path in btfs:
        b = bio.load_btf(path)
        check_meta(b.meta, "btf")
        w, h = b.meta["spatial"]
        views = b.meta["views"]
        assert b.data.shape == (h, w, views, m, 3) and b.data.dtype == np.float32, b.data.shape
        assert np.all(np.isfinite(b.data)) and np.all(b.data >= 0)
        assert np.allclose(b.light_directions, ls.local_directions) and np.allclose(b.light_mean_cosines, ls.local_mean_cosines)
        if b.meta["view_grid"] is None:
            assert views == 1 and b.view_directions is None
        else:
            assert b.view_directions.shape == (views, 3) == (b.meta["view_grid"] ** 2, 3)
        assert b.shade(ls.per_vertex()[0]).shape == (3,)
        print(f"{os.path.basename(path)}: {b.data.shape}, view grid {b.meta['view_grid']}")

    json.dumps(t.meta)
    print("biscale_io round trip: ok")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
