#!/usr/bin/env python3
"""A learned compressor in PyTorch, scored beside biclustering, CPCA and Haar in one biscale run.

    bash scripts/setup-python.sh --torch
    .venv/bin/python examples/python/learned_basis.py                    # the bunny comparison
    .venv/bin/python examples/python/learned_basis.py --quick            # the smoke config, seconds

The model: a *learned light basis*. Each row r of T (vertex v, local direction j) keeps k
coefficients c_r, and all rows share k basis functions over the cubemap's texels, B (k x N):

    T ~ C B,      L* = T L ~ C (B L)

so a gather is one small product B L (k x N x 3, once per light) and one k-term dot product per
row: a neural-PRT decoder whose last layer is linear in the light, which is what makes
relighting cheap (the per-row features never depend on the light). Why this and not a per-row
latent with a nonlinear decoder: a nonlinear decoder must be run per row per frame (or its
outputs stored, which is this model again), and biscale's comparison is at equal storage and
gather cost.

Training: initialized by a randomized SVD of T (the best rank-k fit to T itself), then trained
with Adam to fit T L over a set of *training lights* rather than T: the error that matters is
the error of L*, and a basis can spend its k functions where skies put their energy. The
training lights are the bundled skies other than the one the run is scored under, each at
several rotations about +Y; the scoring sky is held out, so the comparison with the
light-independent built-in compressors is fair. The loss is a mix of the L* error over the
training lights and the Frobenius error of T (the second keeps the basis from fitting the
training skies alone).

The run's report (report.md, metrics.json) then holds `learned-k<k>` rows beside the config's
built-in settings, in the storage/error table, the equal-storage and equal-quality comparisons;
the training time is the setting's build time. The script prints a summary and writes it as
JSON (`--summary`).
"""

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import torch

import biscale

ROOT = Path(__file__).resolve().parents[2]
# PyTorch's notice that sparse tensors are not checked by default (this one is, at creation).
warnings.filterwarnings("ignore", message="Sparse invariant checks")
SKIES = ["blender_courtyard", "blender_forest", "blender_studio", "blender_sunset", "pmndrs_apartment"]


def training_lights(config, held_out, rotations, overrides):
    """L (N x 3) of every bundled sky but `held_out`, at `rotations` angles about +Y."""
    lights = []
    for sky in SKIES:
        if sky == held_out:
            continue
        for r in range(rotations):
            exp = biscale.Experiment.load(
                config,
                set={**overrides, "lighting.env_map": f"../assets/envmaps/{sky}.exr", "lighting.rotation_degrees": 360.0 * r / rotations},
            )
            lights.append(exp.light())
    return lights


class LearnedBasis:
    """`compress(T, context)`: a k-term learned light basis (see the module's doc)."""

    def __init__(self, k, lights, epochs=200, lr=1e-2, frobenius_weight=0.1, threads=None):
        self.k, self.lights, self.epochs, self.lr, self.frobenius_weight = k, lights, epochs, lr, frobenius_weight
        self.threads = threads
        self.label = f"learned-k{k}"
        self.params = {
            "k": k,
            "epochs": epochs,
            "lr": lr,
            "frobenius_weight": frobenius_weight,
            "training_lights": len(lights),
            "model": "learned light basis: T ~ C B, trained on held-out skies",
        }
        self.history = []

    def compress(self, T, context):
        if self.threads:
            torch.set_num_threads(self.threads)
        torch.manual_seed(context["seed"])
        rows, n = T.shape
        k = min(self.k, n, rows)
        indptr = T.indptr
        coo = np.stack([np.repeat(np.arange(rows), np.diff(indptr)), T.indices.astype(np.int64)])
        A = torch.sparse_coo_tensor(torch.from_numpy(coo), torch.from_numpy(T.data), (rows, n), check_invariants=True).coalesce()
        # The best rank-k fit of T (randomized SVD on the sparse matrix) to start from.
        U, S, V = torch.svd_lowrank(A, q=k, niter=4)
        C = (U * S).clone().requires_grad_(True)  # rows x k
        B = V.T.contiguous().clone().requires_grad_(True)  # k x n
        Lm = torch.from_numpy(np.concatenate(self.lights, axis=1))  # n x 3m
        Y = torch.sparse.mm(A, Lm)  # rows x 3m: the training lights' exact L* (f32)
        y2 = (Y * Y).sum()
        t2 = (torch.from_numpy(T.data).double() ** 2).sum().float()
        # Steps in each factor's own units: U's columns and V's are unit vectors.
        opt = torch.optim.Adam(
            [{"params": [C], "lr": self.lr * float(S[0]) / np.sqrt(rows)}, {"params": [B], "lr": self.lr / np.sqrt(n)}]
        )
        for epoch in range(self.epochs):
            opt.zero_grad()
            lstar_err = ((C @ (B @ Lm) - Y) ** 2).sum() / y2
            # ||T - C B||^2 = ||T||^2 - 2 <T, C B> + ||C B||^2, without forming C B.
            cross = (C * torch.sparse.mm(A, B.T)).sum()
            gram = ((C.T @ C) * (B @ B.T)).sum()
            frob = (t2 - 2 * cross + gram) / t2
            loss = lstar_err + self.frobenius_weight * frob
            loss.backward()
            opt.step()
            if epoch % max(1, self.epochs // 10) == 0 or epoch == self.epochs - 1:
                self.history.append((epoch, lstar_err.item(), frob.item()))
        return LearnedForm(C.detach().numpy().astype(np.float32), B.detach().numpy().astype(np.float32))


class LearnedForm:
    """The form: coefficients C (rows x k) and basis B (k x n), float32."""

    def __init__(self, C, B):
        self.C, self.B = np.ascontiguousarray(C), np.ascontiguousarray(B)
        self.arrays = {"coefficients": self.C.ravel(), "basis": self.B.ravel()}
        k, n = self.B.shape
        # One multiply and one add per term: B L (k x n), then C y (rows x k), per channel.
        self.flops_per_gather = 2 * k * n + 2 * self.C.shape[0] * k

    def gather(self, L):
        return self.C @ (self.B @ L)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(ROOT / "configs" / "compare_bunny.toml"))
    ap.add_argument("--quick", action="store_true", help="the smoke config, few epochs: a check that it runs")
    ap.add_argument("--k", default="8,16,32,64", help="basis sizes to run (comma-separated)")
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--rotations", type=int, default=4, help="rotations of each training sky")
    ap.add_argument("--out", default=None, help="output folder (default out/<name>-learned)")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--summary", default=None, help="write the summary as JSON here")
    a = ap.parse_args()
    overrides = {}
    if a.quick:
        a.config = str(ROOT / "configs" / "smoke.toml")
        a.epochs, a.rotations, a.k = min(a.epochs, 30), 1, "4,8"
        overrides = {"runtime.repeats": 1}
    exp = biscale.Experiment.load(a.config, set=overrides)
    held_out = next((s for s in SKIES if s in exp.source), None)
    t0 = time.perf_counter()
    lights = training_lights(a.config, held_out, a.rotations, overrides)
    print(f"{len(lights)} training lights (bundled skies but {held_out}, {a.rotations} rotations each)"
          f" in {time.perf_counter() - t0:.1f} s")
    learned = [LearnedBasis(int(k), lights, epochs=a.epochs) for k in a.k.split(",")]
    out = a.out or str(ROOT / "out" / f"{exp.name}-learned")
    t0 = time.perf_counter()
    metrics = exp.run(out=out, cache_dir=a.cache_dir, compressors=learned)
    print(f"run in {time.perf_counter() - t0:.1f} s: {exp.out_dir}/report.md")
    rows = []
    for c in metrics["compressors"]:
        img = c.get("image", {}).get("vs_reference") or c.get("image", {}).get("vs_uncompressed")
        rows.append({
            "setting": c["name"], "kind": c["kind"], "MB": c["bytes"] / 1e6, "Mflop": c["flops_per_gather"] / 1e6,
            "build_s": c["build_seconds"], "gather_ms": c["gather_ms"], "rel_error_lstar": c["rel_error_lstar"],
            "image_rel_l2": img["rel_l2"] if img else None,
        })
    print(f"{'setting':24} {'MB':>8} {'Mflop':>8} {'build s':>8} {'gather ms':>9} {'L* err':>9} {'image err':>9}")
    for r in rows:
        ie = "" if r["image_rel_l2"] is None else f"{r['image_rel_l2']:9.4f}"
        print(f"{r['setting']:24} {r['MB']:8.2f} {r['Mflop']:8.2f} {r['build_s']:8.1f} {r['gather_ms']:9.2f} {r['rel_error_lstar']:9.4f} {ie}")
    for m in learned:
        print(f"{m.label}: training (epoch, L* error on the training lights, Frobenius error of T): {m.history[-1]}")
    if a.summary:
        Path(a.summary).write_text(json.dumps({"out": exp.out_dir, "rows": rows,
                                               "training": {m.label: m.history for m in learned}}, indent=1))


if __name__ == "__main__":
    main()
