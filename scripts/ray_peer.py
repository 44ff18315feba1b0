#!/usr/bin/env python3
"""biscale's ray tracer side by side with Mitsuba 3's on the same mesh and the same rays.

``tools/pipeline/examples/ray_peer.rs`` writes the transfer stage's visibility rays as arrays (from
every vertex, offset along its normal, one ray per texel centre of a 6 x R x R direction
cube above the tangent plane, in the BVH's normalised space) and times them through biscale's
BVH on 1 and 2 threads, and the transfer stage itself. This script traces the same rays with
Mitsuba's ``Scene.ray_test`` (Embree under its LLVM variant), in batches of whole vertices, on
1 and 2 Dr.Jit threads, checks that both tracers find the same fraction occluded, and prints
rays per second and the ratio. Wall-clock times on a shared machine: the load average before
and after is printed. A benchmark, never a test dependency.

    bash scripts/setup-python.sh --mitsuba
    cargo build --release -p biscale --example ray_peer
    .venv/bin/python scripts/ray_peer.py assets/meshes/bunny.obj [--resolution 64] [--rounds 3]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh", help="an OBJ or PLY mesh")
    ap.add_argument("--resolution", type=int, default=64, help="direction cube resolution (visibility resolution)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batch-rays", type=int, default=4_000_000, help="rays per Mitsuba batch (whole vertices)")
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    ap.add_argument("--example", default=os.path.join(root, "target", "release", "examples", "ray_peer"))
    args = ap.parse_args()
    if not os.path.exists(args.example):
        sys.exit(f"{args.example} not found: cargo build --release -p biscale --example ray_peer")

    import drjit as dr
    import mitsuba as mi

    for variant in ["llvm_ad_rgb", "scalar_rgb"]:
        try:
            mi.set_variant(variant)
            break
        except Exception as e:
            print(f"ray_peer: variant {variant} unavailable ({e})", file=sys.stderr)
    if mi.variant() != "llvm_ad_rgb":
        sys.exit("ray_peer: needs Mitsuba's llvm_ad_rgb variant (scripts/setup-python.sh --mitsuba installs libllvm19)")

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        ours = json.loads(subprocess.run([args.example, args.mesh, tmp, "--resolution", str(args.resolution),
                                          "--rounds", str(args.rounds)], check=True, stdout=subprocess.PIPE,
                                         text=True).stdout)
        a = {n: np.load(os.path.join(tmp, f"{n}.npy")) for n in
             ["positions", "triangles", "origins", "normals", "directions"]}

    mesh = mi.Mesh("m", vertex_count=len(a["positions"]), face_count=len(a["triangles"]))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(a["positions"].ravel())
    params["faces"] = mi.UInt(a["triangles"].ravel().astype(np.uint32))
    params.update()
    scene = mi.load_dict({"type": "scene", "m": mesh})

    # The rays, vertex by vertex: directions above the tangent plane, origins moved along
    # the ray by biscale's ray start (1e-4), since Mitsuba's rays start at t = 0.
    tmin = 1e-4
    dirs = a["directions"]
    batches, current, count = [], ([], []), 0
    for o, n in zip(a["origins"], a["normals"]):
        # n . d in float32, term by term in biscale's order (glam's Vec3::dot), so the same
        # directions pass the horizon test (a matrix product rounds differently).
        d = dirs[(dirs[:, 0] * n[0] + dirs[:, 1] * n[1]) + dirs[:, 2] * n[2] > np.float32(0.0)]
        current[0].append(np.broadcast_to(o, d.shape) + tmin * d)
        current[1].append(d)
        count += len(d)
        if count >= args.batch_rays:
            batches.append(tuple(np.concatenate(c).astype(np.float32) for c in current))
            current, count = ([], []), 0
    if count:
        batches.append(tuple(np.concatenate(c).astype(np.float32) for c in current))
    rays = sum(len(b[0]) for b in batches)
    if rays != ours["rays"]:
        sys.exit(f"ray_peer: {rays} rays here, {ours['rays']} in biscale's list")
    # Each batch goes to the Dr.Jit side before the clock starts (one batch at a time, so a
    # big mesh does not hold every ray at once): only ray_test and its count are timed.
    def trace():
        hits, seconds = 0, 0.0
        for o, d in batches:
            ray = mi.Ray3f(mi.Point3f(o.T), mi.Vector3f(d.T))
            dr.eval(ray)
            s = time.perf_counter()
            hits += int(dr.count(scene.ray_test(ray))[0])
            seconds += time.perf_counter() - s
        return hits, seconds

    seconds = {1: [], 2: []}
    hits = 0
    for _ in range(args.rounds):
        for n in (1, 2):
            dr.set_thread_count(n)
            hits, t = trace()
            seconds[n].append(t)
    load_after = os.getloadavg()
    ours_frac, theirs_frac = ours["occluded"] / ours["rays"], hits / rays
    print(f"{args.mesh}: {ours['vertices']} vertices, {ours['triangles']} triangles; {rays} rays "
          f"(6x{args.resolution}x{args.resolution} cube above each vertex); Mitsuba {mi.__version__} {mi.variant()}; "
          f"load average {load_before[0]:.2f} at start, {load_after[0]:.2f} at end")
    print(f"occluded: biscale {ours_frac:.5f}, Mitsuba {theirs_frac:.5f} (difference {abs(ours_frac - theirs_frac):.2e})")
    print()
    print("| threads | biscale BVH M rays/s | Mitsuba ray_test M rays/s | biscale / Mitsuba |")
    print("|---|---|---|---|")
    for n in (1, 2):
        b = rays / ours[f"bvh_seconds_{n}t"] / 1e6
        m = rays / statistics.median(seconds[n]) / 1e6
        print(f"| {n} | {b:.2f} | {m:.2f} | {b / m:.2f}x |")
    mitsuba_2t = rays / statistics.median(seconds[2]) / 1e6
    print()
    print("biscale's transfer stage at this visibility resolution, deciding the same rays "
          "(medians; not the same work as the plain ray list):")
    print()
    print("| transfer.visibility | rays decided | seconds | threads | M rays/s | / Mitsuba 2 threads |")
    print("|---|---|---|---|---|---|")
    for key in ("transfer_stage", "transfer_stage_rays"):
        st = ours.get(key)
        if st is None:
            continue
        rate = st["rays_traced"] / st["seconds"] / 1e6
        print(f"| {st.get('visibility', 'rays')} | {st['rays_traced']} | {st['seconds']:.2f} | {st['threads']} | "
              f"{rate:.2f} | {rate / mitsuba_2t:.2f}x |")


if __name__ == "__main__":
    main()
