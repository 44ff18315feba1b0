"""The `biscale` Python module against the CLI on configs/smoke.toml, a Python compressor in a
run, bad input from Python, and the GIL released during a long call.

Run by scripts/test-python.sh (scripts/test.sh, CI), which builds the module into .venv and
points BISCALE_BIN at the CLI built by the same `cargo test`. The smoke config's run takes
about two seconds; the tests share one stage cache (T traced once).
"""

import json
import os
import re
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import biscale

ROOT = Path(__file__).resolve().parents[2]
SMOKE = ROOT / "configs" / "smoke.toml"
QUICK = {"runtime.repeats": 1}


def cli():
    exe = os.environ.get("BISCALE_BIN") or str(ROOT / "target" / "debug" / "biscale")
    if not Path(exe).is_file():
        pytest.fail(f"no biscale CLI at {exe} (cargo build -p biscale-cli, or set BISCALE_BIN)")
    return exe


def run_cli(*args):
    p = subprocess.run([cli(), *map(str, args)], cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, f"biscale {' '.join(map(str, args))}:\n{p.stderr}"
    return p


@pytest.fixture(scope="session")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="session")
def exp():
    return biscale.Experiment.load(SMOKE, set=QUICK)


@pytest.fixture(scope="session")
def exported(tmp_path_factory, cache):
    """`biscale export` of T, L and the uncompressed L* (the CLI's own files)."""
    d = tmp_path_factory.mktemp("export")
    run_cli("export", SMOKE, "--set", "runtime.repeats=1", "--what", "t,l,lstar", "--out", d, "--cache-dir", cache)
    return {k: np.load(d / f"{k}.npz") for k in ("t", "l", "lstar")}


class DenseCsr:
    """A toy Python compressor: T's CSR arrays kept as they are, gathered with NumPy."""

    label = "py-csr"
    params = {"what": "T's CSR arrays, NumPy gather"}

    def __init__(self, lossless=True, mangle=None):
        self.lossless, self.mangle = lossless, mangle

    def compress(self, T, context):
        assert isinstance(T, biscale.Transfer) and isinstance(context["seed"], int)
        return CsrForm(T.indptr, T.indices, T.data, T.shape, self.lossless, self.mangle)


class CsrForm:
    def __init__(self, indptr, indices, data, shape, lossless, mangle):
        self.indptr, self.indices, self.data, self.shape = indptr, indices, data, shape
        self.arrays = {"indptr": indptr.astype(np.uint32), "indices": indices.astype(np.uint32), "data": data}
        self.flops_per_gather = 2 * len(data)
        self.lossless = lossless
        self.mangle = mangle

    def gather(self, L):
        rows = np.repeat(np.arange(self.shape[0]), np.diff(self.indptr))
        out = np.zeros((self.shape[0], 3))
        np.add.at(out, rows, self.data[:, None].astype(np.float64) * L[self.indices].astype(np.float64))
        return self.mangle(out) if self.mangle else out


# --- the API against the CLI ------------------------------------------------------------


def test_transfer_and_light_are_the_clis_bytes(exp, exported, cache):
    T = exp.transfer(cache_dir=cache)
    t = exported["t"]
    assert T.shape == tuple(t["shape"])
    for name in ("indptr", "indices", "data"):
        got, want = getattr(T, name), t[name]
        assert got.dtype == want.dtype and np.array_equal(got, want), name
    L = exp.light()
    assert L.dtype == np.float32 and L.shape == exported["l"]["l"].shape
    assert np.array_equal(L, exported["l"]["l"])


@pytest.fixture(scope="session")
def runs(tmp_path_factory, exp, cache):
    """The smoke config run by the CLI and by the module, into two folders."""
    d = tmp_path_factory.mktemp("runs")
    exp.transfer(cache_dir=cache)  # both runs load T (a traced T records its rays, a loaded one 0)
    run_cli("run", SMOKE, "--set", "runtime.repeats=1", "--out", d / "cli", "--cache-dir", cache)
    metrics = exp.run(out=d / "py", cache_dir=cache)
    return d / "cli", d / "py", metrics


def test_run_gives_the_clis_results(exp, runs):
    cli_dir, py_dir, metrics = runs
    assert exp.out_dir == str(py_dir.resolve())
    assert metrics == json.loads((py_dir / "metrics.json").read_text())
    same = subprocess.run([sys.executable, str(ROOT / "scripts" / "same_results.py"), str(cli_dir), str(py_dir)], capture_output=True, text=True)
    assert same.returncode == 0, same.stdout + same.stderr


def test_product_is_the_clis_lstar(exp, exported, cache):
    T, L = exp.transfer(cache_dir=cache), exp.light()
    exact = T.product(L)
    want = exported["lstar"]["lstar"]
    # The CLI writes the f64 product rounded to f32.
    assert exact.shape == want.shape and exact.dtype == np.float64
    assert np.array_equal(exact.astype(np.float32), want)


def test_compress_builds_the_runs_forms(exp, runs, cache):
    """Each config setting compressed from Python (same kind, parameters and seed) has the run's
    storage and flops, and its gather the run's L* error."""
    T, L = exp.transfer(cache_dir=cache), exp.light()
    exact = T.product(L)
    records = {c["name"]: c for c in runs[2]["compressors"]}
    for s in exp.compressor_settings:
        form = biscale.compress(T, s["kind"], seed=exp.seed, **s["params"])
        r = records[s["label"]]
        assert (form.nbytes, form.flops_per_gather, form.lossless) == (r["bytes"], r["flops_per_gather"], r["lossless"]), s
        assert form.nbytes == sum(a.nbytes for a in form.arrays.values())
        lstar = form.gather(L)
        assert lstar.shape == exact.shape and lstar.dtype == np.float32
        rel = np.linalg.norm(lstar - exact) / np.linalg.norm(exact)
        # The same f32 L*; the two f64 norms differ by summation order only.
        assert rel == pytest.approx(r["rel_error_lstar"], rel=1e-9, abs=1e-12), s


def test_light_moments_are_the_clis(exp, exported, cache, tmp_path):
    """With light moments: the moments are L times the texel directions `biscale export` writes,
    the f64 moments product is the CLI's uncompressed L* to the bit, and a form's gather of the
    moments reproduces it (lossless: f32 rounding; lossy: the run's L* error)."""
    run_cli(
        "export", SMOKE, "--set", "runtime.repeats=1", "--set", "runtime.light_moments=true",
        "--what", "lstar", "--out", tmp_path / "m", "--cache-dir", cache,
    )
    want = np.load(tmp_path / "m" / "lstar.npz")["lstar"]
    T, L = exp.transfer(cache_dir=cache), exp.light()
    moments = exp.light_moments()
    l = exported["l"]
    assert moments.shape == (3,) + L.shape and moments.dtype == np.float32
    # f64 direction times f32 power, rounded once; the file's directions are those rounded to
    # f32, so the two differ by at most a few f32 ulps.
    expect = (l["directions"].T[:, :, None].astype(np.float64) * L[None].astype(np.float64))
    assert np.allclose(moments, expect, rtol=1e-6, atol=1e-30)
    exact = T.product(L, moments=True)
    assert np.array_equal(exact.astype(np.float32), want)
    assert not np.allclose(exact, T.product(L))  # the moments change L* (the sun's cosines)
    assert T.normals.shape == (T.vertices, 3)
    assert np.allclose(np.linalg.norm(T.normals, axis=1), 1.0, atol=1e-5)
    norm = np.linalg.norm(exact)
    sparse = biscale.compress(T, "sparse").gather_moments(L)
    # The moments gathered in f32 by the raw CSR, then resolved in f32: rounding only.
    assert np.linalg.norm(sparse - exact) / norm < 1e-5
    haar = biscale.compress(T, "haar", terms=8).gather_moments(L)
    # A lossy form's moments carry its error: more than rounding, far less than the signal.
    assert 1e-5 < np.linalg.norm(haar - exact) / norm < 0.5


def test_shade_and_reference_are_the_runs_images(exp, exported, runs, cache):
    """The image of the CLI's uncompressed L* is the run's `uncompressed.exr`, and the reference
    is its `reference.exr`, bit for bit (both are f32 EXRs)."""
    cli_dir = runs[0]
    image = exp.shade(exported["lstar"]["lstar"], cache_dir=cache)
    want = biscale.read_image(cli_dir / "images" / "uncompressed.exr")
    assert image.dtype == np.float32 and image.ndim == 3 and image.shape[2] == 3
    assert np.array_equal(image, want)
    # V x M x 3 is the same L*.
    T = exp.transfer(cache_dir=cache)
    assert np.array_equal(exp.shade(exported["lstar"]["lstar"].reshape(T.vertices, T.local_dirs, 3), cache_dir=cache), want)
    ref = exp.reference(cache_dir=cache)
    assert np.array_equal(ref, biscale.read_image(cli_dir / "images" / "reference.exr"))
    assert ref.shape[0] < image.shape[0]  # report.reference_downscale = 2
    bad = exported["lstar"]["lstar"].copy()
    bad[3, 2] = np.inf
    with pytest.raises(biscale.BiscaleError, match=r"L\*\[3, 2\] is inf"):
        exp.shade(bad, cache_dir=cache)
    with pytest.raises(biscale.BiscaleError, match="rows"):
        exp.shade(bad[:-8], cache_dir=cache)
    # With the moments resolved per pixel a run's images shade the three gathers, not an L*.
    per_pixel = biscale.Experiment.load(SMOKE, set={"runtime.light_moments": True, "runtime.moments_resolve": "pixel"})
    with pytest.raises(biscale.BiscaleError, match="moments_resolve"):
        per_pixel.shade(exported["lstar"]["lstar"], cache_dir=cache)
    with pytest.raises(biscale.BiscaleError, match="cannot read OpenEXR|No such file"):
        biscale.read_image(cli_dir / "metrics.json")


def test_a_saved_form_is_the_clis_eval_form(exp, cache, tmp_path):
    """`form.save` writes what `biscale eval --form` reads, and `exp.evaluate(form)` scores it as
    the CLI does; a file is written whole or not at all."""
    T = exp.transfer(cache_dir=cache)
    form = biscale.compress(T, "cpca", clusters=4, components=3, seed=exp.seed)
    path = tmp_path / "form-mine.npz"
    form.save(path, label="mine")
    sys.path.insert(0, str(ROOT / "python"))  # the NumPy-only reader beside the package
    import biscale_io

    back = biscale_io.load_form(path)
    assert set(back.arrays) == set(form.arrays)
    assert all(np.array_equal(back.arrays[k], v) for k, v in form.arrays.items())
    run_cli("eval", SMOKE, "--set", "runtime.repeats=1", "--form", path, "--out", tmp_path / "cli", "--cache-dir", cache)
    ours = exp.evaluate(form, name="mine", out=tmp_path / "py", cache_dir=cache)
    same = subprocess.run([sys.executable, str(ROOT / "scripts" / "same_results.py"), str(tmp_path / "cli"), str(tmp_path / "py")], capture_output=True, text=True)
    assert same.returncode == 0, same.stdout + same.stderr
    rec = ours["compressors"][0]
    assert (rec["name"], rec["kind"], rec["bytes"]) == ("mine", "cpca", form.nbytes)
    with pytest.raises(biscale.BiscaleError):
        form.save(tmp_path / "no-such-dir" / "form.npz")
    assert not (tmp_path / "no-such-dir").exists()
    # Saved again over its own file; never over a user's file (unless force), a link or a FIFO.
    form.save(path, label="mine")
    mine = tmp_path / "notes.npz"
    mine.write_bytes(b"my own notes")
    with pytest.raises(biscale.BiscaleError, match="not a NumPy .npz archive biscale wrote"):
        form.save(mine)
    assert mine.read_bytes() == b"my own notes"
    form.save(mine, force=True)
    assert set(biscale_io.load_form(mine).arrays) == set(form.arrays)
    link = tmp_path / "link.npz"
    link.symlink_to(path)
    fifo = tmp_path / "fifo.npz"
    os.mkfifo(fifo)
    for special in (link, fifo):
        with pytest.raises(biscale.BiscaleError, match="is a (symbolic link|FIFO)"):
            form.save(special, force=True)
    assert link.is_symlink() and stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_warnings_and_progress_reach_logging(exp, cache, tmp_path, caplog, capfd):
    """The pipeline's warnings and notes are `logging` records of the logger `biscale`; the
    run's plan too, never printed to standard error behind the logger's back."""
    import logging

    caplog.set_level(logging.INFO, logger="biscale")
    c = DenseCsr(lossless=True, mangle=lambda out: out * 1.01)
    c.label = "py-logged"
    capfd.readouterr()
    exp.run(out=tmp_path / "run", cache_dir=cache, compressors=[c])
    assert "run   transfer" not in capfd.readouterr().err
    records = [(r.name, r.levelno, r.getMessage()) for r in caplog.records if r.name.startswith("biscale")]
    assert any(lvl == logging.INFO and "run   transfer" in m for _, lvl, m in records), records
    assert any(lvl == logging.WARNING and "claims to be lossless" in m for _, lvl, m in records), records
    assert any(lvl == logging.INFO and m.startswith("memory: estimated peak") for _, lvl, m in records), records


def test_a_plugin_compresses_from_python(exp, cache):
    """`compress(T, "plugin", ...)` loads a plugin library as a config's setting does: the
    example quantized plugin at scale 1/4 stores T's box-filtered values exactly (lossless),
    3 bytes per non-zero and 4 per row."""
    lib = ROOT / "target" / "debug" / "libbiscale_plugin_quantized.so"
    if not lib.is_file():
        pytest.fail(f"no {lib} (cargo build -p biscale-plugin-quantized; scripts/test-python.sh builds it)")
    T, L = exp.transfer(cache_dir=cache), exp.light()
    form = biscale.compress(T, "plugin", path=lib, params={"scale": 0.25})
    exact = T.product(L)
    assert form.lossless and np.linalg.norm(form.gather(L) - exact) / np.linalg.norm(exact) < 1e-6
    assert form.nbytes == 3 * T.nnz + 4 * (T.shape[0] + 1) + 4  # codes, columns, row pointers, the scale
    with pytest.raises(biscale.BiscaleError, match="hosted"):
        biscale.compress(T, "hosted")
    with pytest.raises(biscale.BiscaleError, match="no-such.so"):
        biscale.compress(T, "plugin", path="no-such.so")


def test_evaluate_is_the_clis_eval(exp, exported, cache, tmp_path):
    """An L* scored from Python gives the record `biscale eval --lstar` writes for the same
    array; the exact product scores as the uncompressed render."""
    T, L = exp.transfer(cache_dir=cache), exp.light()
    lstar = (T.product(L) * 0.9).astype(np.float32)
    path = tmp_path / "lstar.npy"
    np.save(path, lstar)
    run_cli("eval", SMOKE, "--set", "runtime.repeats=1", "--lstar", path, "--name", "darker", "--out", tmp_path / "cli", "--cache-dir", cache)
    ours = exp.evaluate(path, name="darker", out=tmp_path / "py", cache_dir=cache)
    assert exp.evaluate(lstar, name="darker", out=tmp_path / "array", cache_dir=cache)["compressors"][0]["image"] == ours["compressors"][0]["image"]
    same = subprocess.run([sys.executable, str(ROOT / "scripts" / "same_results.py"), str(tmp_path / "cli"), str(tmp_path / "py")], capture_output=True, text=True)
    assert same.returncode == 0, same.stdout + same.stderr
    rec = ours["compressors"][0]
    assert rec["rel_error_lstar"] == pytest.approx(0.1, rel=1e-5)
    exact = exp.evaluate(T.product(L), out=tmp_path / "exact", cache_dir=cache)["compressors"][0]
    assert exact["rel_error_lstar"] < 1e-7 and exact["image"]["vs_uncompressed"]["rel_l2"] < 1e-6
    # An array or a form is handed over in memory: no temporary file is made on the way (each
    # way of making one raises here), and the array's record is the file's.
    import tempfile

    def no_temporary(*args, **kwargs):
        raise AssertionError("evaluate made a temporary file")

    with pytest.MonkeyPatch.context() as mp:
        for f in ("TemporaryDirectory", "NamedTemporaryFile", "mkstemp", "mkdtemp", "TemporaryFile"):
            mp.setattr(tempfile, f, no_temporary)
        in_memory = exp.evaluate(lstar, name="darker", out=tmp_path / "array2", cache_dir=cache)
        form = exp.evaluate(biscale.compress(T, "sparse"), out=tmp_path / "form2", cache_dir=cache)
    assert in_memory["compressors"][0]["image"] == ours["compressors"][0]["image"]
    assert form["compressors"][0]["kind"] == "sparse" and form["compressors"][0]["rel_error_lstar"] < 1e-6
    with pytest.raises(biscale.BiscaleError, match="dtype"):
        exp.evaluate(lstar.astype(np.int32), out=tmp_path / "bad")
    with pytest.raises(biscale.BiscaleError):
        exp.evaluate(lstar[:100], out=tmp_path / "short")
    assert not (tmp_path / "bad").exists() and not (tmp_path / "short").exists()


def test_plan_is_the_clis(exp, runs, cache):
    # The same text but for what is measured as it runs: the estimate's seconds, free memory.
    seconds = lambda plan: re.sub(r"\d+\.\d+ (s\b|GiB available)", r"<x> \1", plan)
    theirs = run_cli("plan", SMOKE, "--set", "runtime.repeats=1", "--no-cache").stdout
    assert seconds(exp.plan(no_cache=True)) == seconds(theirs)
    # With the cache: T is shared (its key is the inputs'), the forms are not: a form's key
    # holds the code that built it, and the module is not the CLI's executable (a module
    # rebuilt with changed code must not load its old forms).
    ours, theirs = exp.plan(cache_dir=cache), run_cli("plan", SMOKE, "--set", "runtime.repeats=1", "--cache-dir", cache).stdout
    forms = lambda plan: {w for w in plan.split() if w.startswith("form-")}
    transfers = lambda plan: {w for w in plan.split() if w.startswith("transfer-")}
    assert transfers(ours) == transfers(theirs) != set()
    assert forms(ours) and forms(theirs) and not forms(ours) & forms(theirs)
    assert ours.count("load  compress") == len(exp.compressor_settings), ours  # the module's run cached them


# --- a Python compressor in a run -------------------------------------------------------


def test_a_python_compressor_is_scored_and_reported_beside_the_builtins(exp, cache, tmp_path):
    out = tmp_path / "run"
    metrics = exp.run(out=out, cache_dir=cache, compressors=[DenseCsr()])
    rows = {c["name"]: c for c in metrics["compressors"]}
    assert list(rows)[: len(exp.compressor_labels)] == exp.compressor_labels
    mine, raw = rows["py-csr"], rows["sparse"]
    assert mine["kind"] == "hosted" and mine["params"]["python_class"] == "DenseCsr"
    # The storage is what its arrays hold: the raw CSR's bytes; its L* is T L (lossless, checked).
    assert mine["bytes"] == raw["bytes"] and mine["lossless"] is True
    assert mine["rel_error_lstar"] < 1e-6
    assert mine["cached"] is False and mine["gather_ms"] > 0
    # The same image as the raw matrix's, to f32 rounding.
    assert abs(mine["image"]["vs_uncompressed"]["rel_l2"] - raw["image"]["vs_uncompressed"]["rel_l2"]) < 1e-5
    report = (out / "report.md").read_text()
    assert "py-csr" in report
    assert (out / "images" / "py-csr.exr").is_file()
    # Two unrelated Python compressors are two series (not one "hosted" sweep); a declared
    # family joins objects into one.
    other = DenseCsr()
    other.label = "py-other"
    metrics = exp.run(out=tmp_path / "two", cache_dir=cache, compressors=[DenseCsr(), other])
    quality = (tmp_path / "two" / "report.md").read_text().split("## Equal quality")[1]
    assert "| py-csr |" in quality and "| py-other |" in quality and "| hosted |" not in quality, quality
    fam = DenseCsr()
    fam.family = "mine"
    metrics = exp.run(out=tmp_path / "fam", cache_dir=cache, compressors=[fam])
    assert {c["name"]: c for c in metrics["compressors"]}["py-csr"]["params"]["family"] == "mine"
    # Registrations end with the run: the config alone runs without it.
    assert "py-csr" not in exp.compressor_labels


def test_a_false_lossless_claim_is_reported_as_lossy(exp, cache, tmp_path):
    c = DenseCsr(lossless=True, mangle=lambda out: out * 1.01)
    c.label = "py-liar"
    rows = {r["name"]: r for r in exp.run(out=tmp_path / "run", cache_dir=cache, compressors=[c])["compressors"]}
    assert rows["py-liar"]["lossless"] is False
    assert 5e-3 < rows["py-liar"]["rel_error_lstar"] < 2e-2


# --- bad input --------------------------------------------------------------------------


def test_bad_lights_are_clear_errors(exp, cache):
    T, L = exp.transfer(cache_dir=cache), exp.light()
    form = biscale.compress(T, "sparse")
    with pytest.raises(biscale.BiscaleError, match="dtype"):
        form.gather(L.astype(np.int32))
    with pytest.raises(biscale.BiscaleError, match=r"\[384, 3\]"):
        form.gather(L[:10])
    with pytest.raises(biscale.BiscaleError, match=r"\[384, 3\]"):
        form.gather(L.T.copy())
    bad = L.copy()
    bad[7, 1] = np.nan
    with pytest.raises(biscale.BiscaleError, match=r"L\[7, 1\] is NaN"):
        T.product(bad)
    # Non-contiguous and float64 lights are taken as their values.
    strided = np.zeros((L.shape[0], 6), np.float32)[:, ::2]
    strided[:] = L
    assert np.array_equal(form.gather(strided), form.gather(L))
    assert np.array_equal(form.gather(L.astype(np.float64)), form.gather(L))
    with pytest.raises(biscale.BiscaleError, match="no compressor kind `nope` to compress with"):
        biscale.compress(T, "nope")
    with pytest.raises(biscale.BiscaleError, match="cpca"):
        biscale.compress(T, "cpca", clusters=0)


def test_config_errors_are_located(tmp_path):
    with pytest.raises(biscale.ConfigError, match=r"--set nonexistent\.key: unknown field"):
        biscale.Experiment.load(SMOKE, set={"nonexistent.key": 1})
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE.read_text().replace("[transfer]", "[transfer]\nlocal_gird = 4", 1))
    with pytest.raises(biscale.ConfigError, match=r"bad\.toml:\d+:1: unknown field `local_gird`"):
        biscale.Experiment.load(bad)
    with pytest.raises(biscale.ConfigError, match="finite"):
        biscale.Experiment.load(SMOKE, set={"lighting.rotation_degrees": float("nan")})


class Raises:
    label = "py-raises"

    def compress(self, T, context):
        raise RuntimeError("my model diverged")


class Garbage:
    def __init__(self, label, form):
        self.label, self.form = label, form

    def compress(self, T, context):
        return self.form(T)


class WrongShape(CsrForm):
    def gather(self, L):
        return np.zeros((5, 3))


@pytest.mark.parametrize(
    "compressor, message",
    [
        (Raises(), "my model diverged"),
        (Garbage("py-none", lambda T: None), "without a gather"),
        (Garbage("py-noflops", lambda T: type("F", (), {"gather": lambda s, L: L})()), "flops_per_gather"),
        (
            Garbage("py-shape", lambda T: WrongShape(T.indptr, T.indices, T.data, T.shape, False, None)),
            r"shape \[5, 3\], the run needs \[29424, 3\]",
        ),
        (
            Garbage("py-nan", lambda T: CsrForm(T.indptr, T.indices, T.data, T.shape, False, lambda o: o * np.nan)),
            "returned NaN",
        ),
        (
            Garbage(
                "py-f64",
                lambda T: type("F", (), {"arrays": {"x": np.zeros(3)}, "flops_per_gather": 1, "gather": lambda s, L: L})(),
            ),
            "array `x` is not a NumPy array of float32",
        ),
        (
            Garbage(
                "py-broadcast",
                lambda T: type(
                    "F", (), {"arrays": {"x": np.broadcast_to(np.float32(1), (10**12,))}, "flops_per_gather": 1, "gather": lambda s, L: L}
                )(),
            ),
            "array `x` is a broadcast view",
        ),
        (
            Garbage(
                "py-nbytes",
                lambda T: type(
                    "F", (), {"arrays": {"x": np.zeros(3, np.float32)}, "nbytes": 1, "flops_per_gather": 1, "gather": lambda s, L: L}
                )(),
            ),
            "claims nbytes = 1, but its arrays hold 12 bytes",
        ),
    ],
    ids=lambda v: getattr(v, "label", None) if not isinstance(v, str) else None,
)
def test_a_failing_python_compressor_fails_the_run_cleanly(exp, cache, tmp_path, compressor, message):
    out = tmp_path / "run"
    with pytest.raises(biscale.BiscaleError, match=message):
        exp.run(out=out, cache_dir=cache, compressors=[compressor])
    # Nothing half-written: no output folder, no staging folder beside it.
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_labels_are_checked(exp, cache, tmp_path):
    c = DenseCsr()
    c.label = "sparse"
    with pytest.raises(biscale.ConfigError, match="taken"):
        exp.run(out=tmp_path / "a", cache_dir=cache, compressors=[c])
    c.label = "../escape"
    with pytest.raises(biscale.ConfigError, match="label"):
        exp.run(out=tmp_path / "b", cache_dir=cache, compressors=[c])
    # The run's own image names are reserved for every kind: a Python compressor called
    # `reference` would have replaced the ground truth.
    for reserved in ("uncompressed", "reference", "mask", "reference_mask", "uncompressed_paper"):
        c.label = reserved
        with pytest.raises(biscale.ConfigError, match="reserved for every kind"):
            exp.run(out=tmp_path / "b", cache_dir=cache, compressors=[c])
    with pytest.raises(biscale.BiscaleError, match="compress"):
        exp.run(out=tmp_path / "c", cache_dir=cache, compressors=[object()])
    assert not any(tmp_path.iterdir())


# --- the GIL -----------------------------------------------------------------------------


def test_the_gil_is_released_during_a_run(exp, cache, tmp_path):
    done = threading.Event()
    errors = []

    def work():
        try:
            exp.run(out=tmp_path / "run", cache_dir=cache)
        except Exception as e:  # reported below
            errors.append(e)
        finally:
            done.set()

    t = threading.Thread(target=work)
    start = time.perf_counter()
    t.start()
    spins = 0
    while not done.is_set():
        spins += 1  # pure Python: runs only while the run's thread does not hold the GIL
    t.join()
    assert not errors, errors
    elapsed = time.perf_counter() - start
    # Python counts about 10^7 per second on one core; a held GIL would allow ~0 (a
    # thread switch every 5 ms hands it back only if the holder waits for it).
    assert spins > 100_000 * elapsed, (spins, elapsed)
