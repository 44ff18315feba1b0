#!/usr/bin/env python3
"""Do two `biscale run` folders hold the same results? Every image (`images/*.exr`, `*.png`)
byte for byte, and every number of `metrics.json` that is not a timing, a memory reading or
provenance, exactly. What a refactor must leave unchanged:

    python3 scripts/same_results.py out/before/bunny out/after/bunny

Exit status 0 when they agree, 1 with one line per difference otherwise, 2 on bad input.
Left out of the comparison: every key ending in `_ms`, `seconds` or `per_second`, and the
frame-time probe's measured `bandwidth_gb_s` and `peak_gflop_s` (`frame_model.machine`); every
`*_timing` record (a timed step's repeats: `gather_timing`, `shade_timing`); `cached`;
`timing`; `adapter`; the `run` (provenance), `memory` (measured peak) and `load` (the load
average around the timed steps) records; and the `figures` thumbnails' paths are compared like
any other string. A key left out may be present in one run and absent in the other (a run
made before the key existed). Python 3 standard library.
"""
import argparse
import json
import os
import sys

SKIP_KEYS = {"run", "memory", "load", "cached", "timing", "adapter"}


def skipped(key):
    return key in SKIP_KEYS or key.endswith(("_ms", "_timing", "seconds", "per_second", "_gb_s", "_gflop_s"))


def diff_json(a, b, path, out):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if skipped(k):
                continue
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'the second' if k not in a else 'the first'}")
                continue
            diff_json(a[k], b[k], f"{path}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: {len(a)} entries against {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            diff_json(x, y, f"{path}[{i}]", out)
    elif a != b:
        out.append(f"{path}: {a!r} against {b!r}")


def images(folder):
    root = os.path.join(folder, "images")
    found = {}
    for dirpath, _, files in os.walk(root):
        for f in files:
            if f.endswith((".exr", ".png")):
                p = os.path.join(dirpath, f)
                found[os.path.relpath(p, folder)] = p
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("first", help="a run folder (holding metrics.json and images/)")
    ap.add_argument("second", help="the run folder to compare it with")
    args = ap.parse_args()
    out = []
    try:
        ma, mb = (json.load(open(os.path.join(d, "metrics.json"))) for d in (args.first, args.second))
    except (OSError, ValueError) as e:
        sys.exit(f"same_results: error: {e}")
    diff_json(ma, mb, "metrics", out)
    ia, ib = images(args.first), images(args.second)
    for rel in sorted(set(ia) | set(ib)):
        if rel not in ia or rel not in ib:
            out.append(f"{rel}: only in {'the second' if rel not in ia else 'the first'}")
        elif open(ia[rel], "rb").read() != open(ib[rel], "rb").read():
            out.append(f"{rel}: the bytes differ")
    for line in out:
        print(line)
    print(f"{len(ia)} images and metrics.json compared: {'the same' if not out else f'{len(out)} differences'}")
    return 1 if out else 0


if __name__ == "__main__":
    sys.exit(main())
