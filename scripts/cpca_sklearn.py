#!/usr/bin/env python3
"""Clustered PCA with scikit-learn, the peer of biscale's CPCA, as a NumPy round trip.

An example of the interop (not one of the tests): `biscale export` writes T and L, this script
clusters T's rows with KMeans (K clusters, k-means++) and fits PCA with C components per
cluster, then hands the result back to biscale two ways, which `biscale eval` renders and
scores exactly as a run scores its own compressor settings (metrics.json, images, the error
against the uncompressed render and the reference):

* ``sklearn-lstar.npz``: the L* the approximated T gives, ``T~ L`` (``biscale eval --lstar``);
* ``form-sklearn-k<K>-c<C>.npz``: the same approximation as a biscale ``cpca`` form (per
  cluster its mean and C components, per row its cluster and C coefficients), which
  ``biscale eval --form`` gathers with biscale's own CPCA gather.

It prints the build time and the relative Frobenius error ||T - T~|| / ||T||, the number
biscale's `compressors/examples/lossy_bench.rs` prints as "err T" for its CPCA. The algorithms
differ: scikit-learn clusters by Euclidean distance to the centroid once, then fits PCA;
biscale (Sloan et al. 2003) iterates assignment by reconstruction error and refitting.

    bash scripts/setup-python.sh
    cargo build --release -p biscale-cli
    target/release/biscale export configs/bunny.toml --what t,l,lstar --out out/bunny-export
    .venv/bin/python scripts/cpca_sklearn.py out/bunny-export --clusters 32 --components 8 \\
        --eval configs/bunny.toml          # runs the two `biscale eval` commands too

Given a ``T.mtx`` (``biscale export-matrix``, or ``export --format mtx``) instead of an export
folder it only prints the build time and error (the CPCA benchmark in BENCHMARKS.md).
"""
import argparse
import os
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp
from sklearn.cluster import KMeans
from sklearn.decomposition import PCA

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import biscale_io as bio  # noqa: E402


def cpca(t, clusters, components, seed):
    """KMeans + PCA of T's rows: labels, per cluster (mean, components (C x N)), per row the
    C coefficients, and the squared Frobenius error."""
    start = time.perf_counter()
    km = KMeans(n_clusters=clusters, n_init=1, random_state=seed).fit(t)
    t_kmeans = time.perf_counter() - start
    n = t.shape[1]
    bases = np.zeros((clusters, components + 1, n), dtype=np.float32)
    coeffs = np.zeros((t.shape[0], components), dtype=np.float32)
    err = 0.0
    for k in range(clusters):
        members = np.flatnonzero(km.labels_ == k)
        if members.size == 0:
            continue
        rows = t[members].toarray()
        c = min(components, rows.shape[0], rows.shape[1])
        pca = PCA(n_components=c, svd_solver="randomized", random_state=seed).fit(rows)
        w = pca.transform(rows)
        bases[k, 0] = pca.mean_
        bases[k, 1 : c + 1] = pca.components_
        coeffs[members, :c] = w
        approx = pca.inverse_transform(w)
        err += float(((rows - approx) ** 2).sum())
    seconds = time.perf_counter() - start
    return km.labels_, bases, coeffs, err, seconds, t_kmeans


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", help="a `biscale export` folder (t.npz, l.npz, lstar.npz), or a T.mtx")
    ap.add_argument("--clusters", type=int, default=32)
    ap.add_argument("--components", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="folder for the L* and the form (default: the export folder)")
    ap.add_argument("--eval", metavar="CONFIG", help="then run `biscale eval CONFIG` on both")
    ap.add_argument("--biscale", default=None, help="the biscale binary (default: target/release/biscale, else PATH)")
    args = ap.parse_args()

    if args.input.endswith(".mtx"):
        import scipy.io

        t = sp.csr_matrix(scipy.io.mmread(args.input), dtype=np.float32)
        transfer, light = None, None
    else:
        transfer = bio.load_t(os.path.join(args.input, "t.npz"))
        light = bio.load_l(os.path.join(args.input, "l.npz"))
        t = transfer.to_scipy()
    total = float(sp.linalg.norm(t)) ** 2
    print(f"T: {t.shape[0]} x {t.shape[1]}, {t.nnz} non-zeros")
    k, c = args.clusters, args.components
    labels, bases, coeffs, err, seconds, t_kmeans = cpca(t, k, c, args.seed)
    print(f"scikit-learn KMeans({k}) + PCA({c}): {seconds:.2f} s "
          f"(KMeans {t_kmeans:.2f} s), relative Frobenius error of T {np.sqrt(err / total):.4f}")
    if transfer is None:
        return

    out = args.out or args.input
    os.makedirs(out, exist_ok=True)
    # L* of the approximation: per row mean . L + sum_c w_c (component_c . L), in float64.
    projections = bases.astype(np.float64) @ light.l.astype(np.float64)  # (K, C + 1, 3)
    lstar = projections[labels, 0] + np.einsum("rc,rcx->rx", coeffs.astype(np.float64), projections[labels, 1:])
    lstar_path = os.path.join(out, "sklearn-lstar.npz")
    bio.save_lstar(lstar_path, lstar, like=transfer, meta={"source": f"scikit-learn KMeans({k}) + PCA({c})"})
    exact = transfer.matvec(light.l)
    print(f"L*: relative L2 error against T L {np.linalg.norm(lstar - exact) / np.linalg.norm(exact):.4e}")

    # The same as biscale's cpca form (rows as units): basis[(cluster * (C + 1) + v) * N + k],
    # v = 0 the mean, 1..C the components; one cluster id (uint16) and C coefficients per row.
    rows, n = t.shape
    form = bio.Form(
        kind="cpca",
        arrays={
            "basis": bases.reshape(-1),
            "cluster": labels.astype(np.uint16),
            "coeffs": coeffs.reshape(-1),
        },
        meta={"clusters": k, "components": c, "unit_rows": 1},
        shape=transfer.meta["shape"],
        label=f"sklearn-k{k}-c{c}",
        params={"clusters": k, "components": c},
        flops_per_gather=2 * k * (c + 1) * n + 2 * rows * c,
        build_seconds=seconds,
        file_meta=transfer.meta,
    )
    form_path = os.path.join(out, f"form-sklearn-k{k}-c{c}.npz")
    bio.save_form(form_path, form)
    print(f"wrote {lstar_path} and {form_path} ({form.bytes / 1e6:.2f} MB)")

    if args.eval:
        exe = args.biscale or ("target/release/biscale" if os.path.exists("target/release/biscale") else "biscale")
        for flag, path in (("--lstar", lstar_path), ("--form", form_path)):
            cmd = [exe, "eval", args.eval, flag, path]
            print("$", " ".join(cmd), flush=True)
            subprocess.run(cmd, check=True)
    else:
        print("score them:")
        print(f"  biscale eval CONFIG --lstar {lstar_path}")
        print(f"  biscale eval CONFIG --form {form_path}")


if __name__ == "__main__":
    main()
