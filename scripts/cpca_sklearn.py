#!/usr/bin/env python3
"""Clustered PCA with scikit-learn, the peer for biscale's CPCA (the CPCA benchmark in BENCHMARKS.md).

Reads T.mtx written by `biscale export-matrix`, clusters its rows with KMeans (K clusters,
k-means++), fits PCA with C components per cluster, and prints the build time and the
relative Frobenius error ||T - T~|| / ||T|| -- the number biscale's
`compressors/examples/lossy_bench.rs` prints as "err T" for its CPCA.

Note the algorithms differ: scikit-learn clusters by Euclidean distance to the centroid
once, then fits PCA; biscale (Sloan et al. 2003) iterates assignment by reconstruction
error and refitting.

    bash scripts/setup-python.sh
    cargo run --release -p biscale -- export-matrix configs/bunny.toml --out out/mtx
    .venv/bin/python scripts/cpca_sklearn.py out/mtx/T.mtx --clusters 32 --components 8
"""
import argparse
import time

import numpy as np
import scipy.io
import scipy.sparse as sp
from sklearn.cluster import KMeans
from sklearn.decomposition import PCA


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("matrix", help="T.mtx from biscale export-matrix")
    ap.add_argument("--clusters", type=int, default=32)
    ap.add_argument("--components", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    t = sp.csr_matrix(scipy.io.mmread(args.matrix), dtype=np.float32)
    total = float(sp.linalg.norm(t)) ** 2
    print(f"T: {t.shape[0]} x {t.shape[1]}, {t.nnz} non-zeros")
    start = time.perf_counter()
    km = KMeans(n_clusters=args.clusters, n_init=1, random_state=args.seed).fit(t)
    t_kmeans = time.perf_counter() - start
    err = 0.0
    for k in range(args.clusters):
        rows = t[km.labels_ == k].toarray()
        if rows.shape[0] == 0:
            continue
        c = min(args.components, rows.shape[0], rows.shape[1])
        pca = PCA(n_components=c, svd_solver="randomized", random_state=args.seed).fit(rows)
        approx = pca.inverse_transform(pca.transform(rows))
        err += float(((rows - approx) ** 2).sum())
    seconds = time.perf_counter() - start
    print(f"scikit-learn KMeans({args.clusters}) + PCA({args.components}): {seconds:.2f} s "
          f"(KMeans {t_kmeans:.2f} s), relative Frobenius error of T {np.sqrt(err / total):.4f}")


if __name__ == "__main__":
    main()
