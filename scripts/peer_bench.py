#!/usr/bin/env python3
"""biscale's gathers and CPCA side by side with the peers a researcher would reach for.

On one exported T and L (`biscale export CONFIG --what t,l`), in one run:

* SciPy CSR ``T @ L`` (float32; 1 channel and 3 channels; 1 thread, and 2 threads with T's
  rows split in two halves handed to a thread pool, SciPy's sparse product releasing the GIL),
  against biscale's RGB gathers of the sparse, bicluster, CPCA and Haar forms on 1 and 2
  rayon threads (``tools/pipeline/examples/peer_gather.rs``, which checks each gather against an f64
  ``T L`` before timing it);
* scikit-learn KMeans + PCA (32 clusters, 8 components: ``scripts/cpca_sklearn.py``'s fit)
  against biscale's CPCA build at the same K and C.

Medians of interleaved rounds; the load average before and after is printed, since these are
wall-clock times on a shared machine. Prints a Markdown table of times and ratios
(peer / biscale: above 1, biscale is faster). A benchmark, never a test dependency.

    bash scripts/setup-python.sh
    cargo build --release -p biscale --example peer_gather
    target/release/biscale export configs/bunny.toml --what t,l --out out/bunny-export
    .venv/bin/python scripts/peer_bench.py out/bunny-export [--rounds 21] [--no-sklearn]
"""
import argparse
import concurrent.futures
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import biscale_io as bio  # noqa: E402


def timed(f):
    s = time.perf_counter()
    f()
    return (time.perf_counter() - s) * 1e3


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("export", help="a `biscale export --what t,l` folder")
    ap.add_argument("--rounds", type=int, default=21)
    ap.add_argument("--no-sklearn", action="store_true", help="leave out KMeans + PCA (about a minute)")
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    ap.add_argument("--example", default=os.path.join(root, "target", "release", "examples", "peer_gather"),
                    help="the built peer_gather example")
    args = ap.parse_args()
    if not os.path.exists(args.example):
        sys.exit(f"{args.example} not found: cargo build --release -p biscale --example peer_gather")

    load_before = os.getloadavg()
    print(f"load average at start: {load_before[0]:.2f}, {os.cpu_count()} CPUs", file=sys.stderr)
    ours = json.loads(subprocess.run([args.example, args.export, "--rounds", str(args.rounds)],
                                     check=True, stdout=subprocess.PIPE, text=True).stdout)

    import scipy
    import scipy.sparse as sp

    t = bio.load_t(os.path.join(args.export, "t.npz")).to_scipy().astype(np.float32)
    light = np.ascontiguousarray(bio.load_l(os.path.join(args.export, "l.npz")).l, dtype=np.float32)
    one = np.ascontiguousarray(light[:, 0])
    half = t.shape[0] // 2
    halves = [t[:half], t[half:]]
    pool = concurrent.futures.ThreadPoolExecutor(2)

    def two_threads(x):
        list(pool.map(lambda m: m @ x, halves))

    # SciPy's result against the f64 product, so a wrong operand cannot be timed either.
    exact = t.astype(np.float64) @ light.astype(np.float64)
    err = np.linalg.norm(t @ light - exact) / np.linalg.norm(exact)
    assert err < 1e-5, f"SciPy T @ L is off by {err:.2e}"
    cases = {
        "scipy 1 ch 1t": lambda: t @ one,
        "scipy 3 ch 1t": lambda: t @ light,
        "scipy 1 ch 2t": lambda: two_threads(one),
        "scipy 3 ch 2t": lambda: two_threads(light),
    }
    samples = {k: [] for k in cases}
    for _ in range(args.rounds):
        for k, f in cases.items():
            samples[k].append(timed(f))
    scipy_ms = {k: statistics.median(v) for k, v in samples.items()}

    sk = None
    if not args.no_sklearn:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from cpca_sklearn import cpca  # noqa: E402

        *_, seconds, t_kmeans = cpca(t, 32, 8, 0)
        sk = (seconds, t_kmeans)
    load_after = os.getloadavg()

    import sklearn

    print(f"T: {ours['rows']} x {ours['cols']}, {ours['nnz']} non-zeros; {args.rounds} rounds; "
          f"SciPy {scipy.__version__}, scikit-learn {sklearn.__version__}, NumPy {np.__version__}; "
          f"load average {load_before[0]:.2f} at start, {load_after[0]:.2f} at end")
    print()
    print("| biscale RGB gather | threads | biscale ms | SciPy CSR T @ L, 3 ch, ms | SciPy / biscale | SciPy 1 ch ms |")
    print("|---|---|---|---|---|---|")
    for kind in ["sparse", "bicluster", "cpca", "haar"]:
        for n in [1, 2]:
            b = ours[kind][f"gather_ms_{n}t"]
            s3, s1 = scipy_ms[f"scipy 3 ch {n}t"], scipy_ms[f"scipy 1 ch {n}t"]
            print(f"| {kind} ({ours[kind]['bytes'] / 2**20:.1f} MiB) | {n} | {b:.2f} | {s3:.2f} | {s3 / b:.1f}x | {s1:.2f} |")
    if sk is not None:
        ours_s = ours["cpca"]["build_s"]
        print()
        print("| CPCA build, K = 32, C = 8 | seconds |")
        print("|---|---|")
        print(f"| biscale cpca (all cores) | {ours_s:.2f} |")
        print(f"| scikit-learn KMeans + PCA (its default threads) | {sk[0]:.2f} (KMeans {sk[1]:.2f}) |")
        print(f"| ratio scikit-learn / biscale | {sk[0] / ours_s:.2f}x |")


if __name__ == "__main__":
    main()
