#!/usr/bin/env python3
"""Helper of scripts/gpu-check.sh (standard library only).

  derive SRC DST         copy the config SRC to DST with its `mesh` and `env_map` paths made
                         absolute (so DST may live anywhere) and the TOML on stdin appended
  adapter RUN_DIR        print the wgpu adapter a run's metrics.json records (exit 1: none)
  rows --out DIR ...     read the check's runs and gpu_bench log, write DIR/rows.md (Markdown
                         rows for BENCHMARKS.md) and DIR/figures.json, and fail (exit 1) when
                         an expected figure is missing, not finite or not positive

The figures, each from a run's metrics.json by one definition (`GpuRecord` in
tools/report/src/metrics.rs; the frame times as Table I's fps in
tools/pipeline/src/reproduce/facts.rs, with the GPU's gather and shade in place of the CPU's):

  gather                 a form's GPU gather `L* = T L` (gpu.gather_ms), one row per form
  moments gather+resolve the same form with runtime.light_moments = true: its three moment
                         gathers and the resolve pass, timed together (gpu.gather_ms)
  SH gather              a Sloan et al. method's GPU gather of its SH transfer matrices
  BTF shade              the paper's form (lossless biclustering) shaded per pixel (gpu.shade_ms)
  SH RTT shade           a Sloan et al. method's radiance-transfer-texture shading
  frame, view change     lossless biclustering, shade only: fps = 1000 / shade_ms
                         (Table I's "fps, fixed light, moving view")
  frame, light change    lossless biclustering, gather + shade: fps = 1000 / (gather + shade)
                         (Table I's "fps, moving light and view")
  per-pixel frames       a run with runtime.moments_resolve = "pixel" or "pixel_analytic":
                         the paper's form's three moment gathers + resolve (gpu.gather_ms),
                         its shade resolving the moments at every pixel (gpu.shade_ms), and
                         the view and light change frames from them; the frame-time model's
                         projected floor on an H100-class GPU (frame_model) in the check
                         column, a floor and never a measurement
  gpu_bench ...          gpu/examples/gpu_bench.rs's medians (its own scene: bunny.obj, a
                         random light, a Phong BTF), as a cross-check of the pipeline's
"""

import argparse
import datetime
import json
import math
import re
import sys
from pathlib import Path

FORM_KINDS = ["sparse", "bicluster", "cpca", "haar"]
BENCH_KINDS = ["sparse", "bicluster", "cpca", "haar"]


def derive(src: Path, dst: Path, extra: str) -> None:
    text = src.read_text()
    base = src.resolve().parent

    def absolute(match: re.Match) -> str:
        path = (base / match.group(3)).resolve()
        if not path.exists():
            sys.exit(f"gpu_check_rows: {src}: {match.group(2)} = {match.group(3)!r} does not exist ({path})")
        return f'{match.group(1)}"{path}"'

    text, n = re.subn(r'(?m)^(\s*(mesh|env_map)\s*=\s*)"([^"]+)"', absolute, text)
    if n == 0:
        sys.exit(f"gpu_check_rows: {src}: no mesh or env_map path to rewrite")
    header = f"# Written by scripts/gpu-check.sh from {src}: paths made absolute, entries appended.\n"
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text(header + text.rstrip("\n") + "\n\n# Appended by scripts/gpu-check.sh\n" + extra)


def gpu_records(metrics: dict):
    for c in metrics.get("compressors", []):
        yield c
    yield from metrics.get("methods", [])  # a method's record is flattened into it


def adapter_of(metrics: dict):
    for r in gpu_records(metrics):
        if r.get("gpu"):
            return r["gpu"]["adapter"]
    return None


def adapter_parts(adapter: str):
    """(name, details) of an adapter as the pipeline records it, `NAME ("Vulkan", DRIVER)`,
    or as gpu_bench prints it, `NAME (Vulkan, DEVICE_TYPE, DRIVER) (timestamps: BOOL)`."""
    a = re.sub(r" \(timestamps: \w+\)$", "", adapter.strip())
    m = re.match(r'^(.*) \("?(Vulkan|Metal|Dx12|Gl|BrowserWebGpu|Noop)"?, (.*)\)$', a)
    return (m.group(1), f"{m.group(2)}, {m.group(3)}") if m else (a, "")


def fmt_ms(x) -> str:
    if x is None or not isinstance(x, (int, float)) or not math.isfinite(x):
        return "-"
    return f"{x:.3f}" if x < 10 else f"{x:.2f}" if x < 100 else f"{x:.1f}"


def timing_text(t, method) -> str:
    if not t:
        return ""
    return f"{fmt_ms(t['min_ms'])}-{fmt_ms(t['max_ms'])}, {t['repeats']} reps, {method}"


class Rows:
    def __init__(self):
        self.rows = []  # dicts
        self.missing = []  # (label, why)

    def expect(self, label: str, value, **row):
        """Record figure `label`: its row when `value` is finite and positive, else a miss."""
        ok = isinstance(value, (int, float)) and math.isfinite(value) and value > 0
        if not ok:
            self.missing.append((label, "absent" if value is None else f"value {value!r}"))
            return
        self.rows.append(dict(label=label, ms=float(value), **row))

    def miss(self, label: str, why: str):
        self.missing.append((label, why))


def load_metrics(run_dir: Path):
    p = run_dir / "metrics.json"
    if not p.is_file():
        return None, f"no {p} (the run failed or was not reached; see its log)"
    try:
        return json.loads(p.read_text()), None
    except (OSError, ValueError) as e:
        return None, f"{p}: {e}"


def size_of(metrics: dict):
    try:
        import tomllib

        rt = tomllib.loads(metrics["run"]["config_text"]).get("runtime", {})
        return f"{rt.get('width', 640)}x{rt.get('height', 480)}"
    except Exception:  # an older Python or no run record: the size is not checked
        return None


def method_of(metrics: dict, label: str):
    return next((x for x in metrics.get("methods", []) if x["name"] == label), None)


def paper_form(metrics: dict):
    return next((c for c in metrics["compressors"] if c["kind"] == "bicluster" and c["lossless"]), None)


def form_of(metrics: dict, kind: str):
    if kind == "bicluster":
        return paper_form(metrics)
    return next((c for c in metrics["compressors"] if c["kind"] == kind), None)


def main_run(rows: Rows, scene: str, size: str, run_dir: Path, with_gathers: bool, sh: list):
    what = f"{scene} {size}"
    m, why = load_metrics(run_dir)
    expected = []
    if with_gathers:
        expected += [f"{scene}: gather {k}" for k in FORM_KINDS]
        expected += [f"{scene}: SH gather {s}" for s in sh]
    expected += [f"{scene} {size}: {f}" for f in ("BTF shade", "frame, view change", "frame, light change")]
    expected += [f"{scene} {size}: SH RTT shade {s}" for s in sh]
    if m is None:
        for label in expected:
            rows.miss(label, why)
        return None
    got = size_of(m)
    if got is not None and got != size:
        for label in expected:
            rows.miss(label, f"{run_dir} ran at {got}, not {size}")
        return None
    common = dict(scene=scene, adapter=adapter_of(m), run=run_dir.name)
    if with_gathers:
        for kind in FORM_KINDS:
            c = form_of(m, kind)
            g = c and c.get("gpu")
            rows.expect(
                f"{scene}: gather {kind}",
                g and g["gather_ms"],
                figure="gather",
                setting=c["name"] if c else kind,
                size="-",
                timing=g and timing_text(g.get("gather_timing"), g["timing"]),
                cpu_ms=c and c["gather_ms"],
                check=g and f"L* rel. err. {g['rel_error_lstar']:.1e}",
                **common,
            )
        for s in sh:
            r = method_of(m, s)
            g = r and r.get("gpu")
            rows.expect(
                f"{scene}: SH gather {s}",
                g and g["gather_ms"],
                figure="SH gather",
                setting=s,
                size="-",
                timing=g and timing_text(g.get("gather_timing"), g["timing"]),
                cpu_ms=r and r["gather_ms"],
                check=g and f"L* rel. err. {g['rel_error_lstar']:.1e}",
                **common,
            )
    b = paper_form(m)
    g = b and b.get("gpu")
    pixels = g and f"{g['differing_pixels']:,} of {g['covered_pixels']:,} px off vs CPU"
    name = b["name"] if b else "bicluster (lossless)"
    rows.expect(
        f"{scene} {size}: BTF shade",
        g and g["shade_ms"],
        figure="BTF shade",
        setting=name,
        size=size,
        timing=g and timing_text(g.get("shade_timing"), g["timing"]),
        cpu_ms=b and b["shade_ms"],
        check=pixels,
        **common,
    )
    rows.expect(
        f"{scene} {size}: frame, view change",
        g and g["shade_ms"],
        figure="frame, view change (shade)",
        setting=name,
        size=size,
        fps=True,
        timing="= BTF shade",
        cpu_ms=b and b["shade_ms"],
        check="",
        **common,
    )
    rows.expect(
        f"{scene} {size}: frame, light change",
        g and g["gather_ms"] + g["shade_ms"],
        figure="frame, light change (gather + shade)",
        setting=name,
        size=size,
        fps=True,
        timing="gather + BTF shade",
        cpu_ms=b and b["gather_ms"] + b["shade_ms"],
        check="",
        **common,
    )
    for s in sh:
        r = method_of(m, s)
        g = r and r.get("gpu")
        rows.expect(
            f"{scene} {size}: SH RTT shade {s}",
            g and g["shade_ms"],
            figure="SH RTT shade",
            setting=s,
            size=size,
            timing=g and timing_text(g.get("shade_timing"), g["timing"]),
            cpu_ms=r and r["shade_ms"],
            check=g and f"{g['differing_pixels']:,} of {g['covered_pixels']:,} px off vs CPU",
            **common,
        )
    return m


def moments_run(rows: Rows, scene: str, run_dir: Path, plain):
    m, why = load_metrics(run_dir)
    if m is None:
        for kind in FORM_KINDS:
            rows.miss(f"{scene}: moments gather+resolve {kind}", why)
        return None
    if not m["uncompressed"].get("light_moments"):
        for kind in FORM_KINDS:
            rows.miss(f"{scene}: moments gather+resolve {kind}", f"{run_dir} ran without runtime.light_moments")
        return None
    common = dict(scene=scene, adapter=adapter_of(m), run=run_dir.name)
    for kind in FORM_KINDS:
        c = form_of(m, kind)
        g = c and c.get("gpu")
        base = plain and form_of(plain, kind)
        base_g = base and base.get("gpu")
        ratio = g and base_g and g["gather_ms"] / base_g["gather_ms"]
        rows.expect(
            f"{scene}: moments gather+resolve {kind}",
            g and g["gather_ms"],
            figure="light moments: 3 gathers + resolve",
            setting=c["name"] if c else kind,
            size="-",
            timing=g and timing_text(g.get("gather_timing"), g["timing"]),
            cpu_ms=c and c["gather_ms"],
            check=(f"{ratio:.2f}x the plain gather; " if ratio else "")
            + (f"L*' rel. err. {g['rel_error_lstar']:.1e}" if g else ""),
            **common,
        )
    return m


def pixel_run(rows: Rows, scene: str, size: str, run_dir: Path):
    """The per-pixel resolve's frame of the paper's form, `scene` at `size`."""
    m, why = load_metrics(run_dir)
    labels = ["gather+resolve", "shade", "frame, view change", "frame, light change"]
    resolve = m and m["uncompressed"].get("moments_resolve")
    what = f"{scene} {size} {resolve or 'per-pixel'}"
    if m is None:
        for label in labels:
            rows.miss(f"{what}: {label}", why)
        return None
    if resolve not in ("pixel", "pixel_analytic"):
        for label in labels:
            rows.miss(f"{what}: {label}", f"{run_dir} did not resolve per pixel ({resolve})")
        return None
    c = paper_form(m)
    g = c and c.get("gpu")
    model = m.get("frame_model") or {}
    fm = next((f for f in model.get("forms", []) if c and f["name"] == c["name"]), None)
    proj = model.get("projection", {}).get("name", "?")
    floors = fm and {
        "gather+resolve": fm["gather"]["projected_ms"],
        "shade": fm["shade"]["projected_ms"],
        "frame, view change": fm["shade"]["projected_ms"],
        "frame, light change": fm["gather"]["projected_ms"] + fm["shade"]["projected_ms"],
    }
    values = g and {
        "gather+resolve": (g["gather_ms"], c["gather_ms"]),
        "shade": (g["shade_ms"], c["shade_ms"]),
        "frame, view change": (g["shade_ms"], c["shade_ms"]),
        "frame, light change": (g["gather_ms"] + g["shade_ms"], c["gather_ms"] + c["shade_ms"]),
    }
    common = dict(scene=scene, adapter=adapter_of(m), run=run_dir.name, setting=c["name"] if c else "bicluster")
    for label in labels:
        v = values and values[label]
        ms = v and v[0]
        fps = f"{1000.0 / ms:.1f} fps; " if ms and label.startswith("frame") else ""
        floor = f"projected floor on {proj} {floors[label]:.4f} ms (a floor, not a measurement)" if floors else ""
        rows.expect(
            f"{what}: {label}",
            ms,
            figure=f"per-pixel resolve ({resolve}): {label}",
            size=size,
            timing=g and g["timing"],
            cpu_ms=v and v[1],
            check=fps + floor,
            **common,
        )
    return m


BENCH_LINE = re.compile(r"^GPU (gather \((\w+)\)|shade \(visibility \+ shade\)): median ([0-9.eE+-]+) ms over (\d+) reps \((\w+)\)")


def bench(rows: Rows, log: Path):
    labels = [f"gpu_bench: gather {k}" for k in BENCH_KINDS] + ["gpu_bench: shade"]
    if not log.is_file():
        for label in labels:
            rows.miss(label, f"no {log}")
        return None
    text = log.read_text(errors="replace")
    adapter = next((ln[len("adapter: ") :] for ln in text.splitlines() if ln.startswith("adapter: ")), None)
    shade_size = re.search(r"^shade (\d+x\d+):", text, re.M)
    found, cpu = {}, {}
    for ln in text.splitlines():
        mt = re.match(r"^CPU gather \(sparse, rayon\): median ([0-9.]+) ms", ln) or re.match(
            r"^(\w+): [0-9.]+ MB, built in .*; CPU gather ([0-9.]+) ms \(one run\)", ln
        )
        if mt:
            cpu["gather " + (mt.group(1) if mt.lastindex == 2 else "sparse")] = float(mt.group(mt.lastindex))
        mt = BENCH_LINE.match(ln)
        if mt:
            key = f"gather {mt.group(2)}" if mt.group(2) else "shade"
            found[key] = (float(mt.group(3)), int(mt.group(4)), mt.group(5))
    for label in labels:
        key = label.split(": ", 1)[1]
        v = found.get(key)
        rows.expect(
            label,
            v and v[0],
            scene="bench",
            adapter=adapter,
            run="gpu_bench",
            figure="gpu_bench " + ("gather" if key.startswith("gather") else "shade (visibility + shade)"),
            setting=key.split(" ", 1)[1] if key.startswith("gather") else "Phong BTF",
            size=(shade_size.group(1) if shade_size else "?") if key == "shade" else "-",
            timing=v and f"median of {v[1]} reps, {v[2]}",
            cpu_ms=cpu.get(key),
            check="",
        )
    return adapter


def cell(s) -> str:
    return str(s).replace("|", "\\|").replace("\n", " ")


def rows_cmd(a):
    out = Path(a.out)
    rows = Rows()
    by_scene = {}
    for scene, role, size, run_dir in a.run:
        by_scene.setdefault(scene, []).append((role, size, Path(run_dir)))
    sh = [s for s in a.sh.split(",") if s]
    first = None
    for scene, runs in by_scene.items():
        plain = None
        for role, size, run_dir in runs:
            if role == "main":
                m = main_run(rows, scene, size, run_dir, with_gathers=plain is None, sh=sh)
                plain = plain or m or {}
                first = first or m
        for role, size, run_dir in runs:
            if role == "moments":
                moments_run(rows, scene, run_dir, plain or None)
            if role == "pixel":
                pixel_run(rows, scene, size, run_dir)
    if a.bench:
        bench(rows, Path(a.bench))

    adapters = sorted({r["adapter"] for r in rows.rows if r.get("adapter")})
    devices = {}  # name -> the longest details seen (gpu_bench's carry the device type)
    for x in adapters:
        name, details = adapter_parts(x)
        devices[name] = max(devices.get(name, ""), details, key=len)
    run = (first or {}).get("run") or {}
    commit = run.get("git_commit") or a.commit or "unknown"
    commit = commit[:10] + ("-dirty" if run.get("git_dirty") else "")
    date = a.date or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d")

    header = (
        "| device | commit | date | scene | figure | setting | size | GPU ms (median) | GPU fps "
        "| GPU min-max, repeats, timing | CPU ms | check |"
    )
    lines = [header, "|" + "---|" * header.count(" | ") + "---|"]
    for r in rows.rows:
        device = adapter_parts(r["adapter"])[0] if r.get("adapter") else "?"
        fps = f"{1000.0 / r['ms']:.1f}" if r.get("fps") else ""
        lines.append(
            "| "
            + " | ".join(
                cell(x)
                for x in (
                    device,
                    commit,
                    date,
                    r["scene"],
                    r["figure"],
                    r["setting"],
                    r["size"],
                    fmt_ms(r["ms"]),
                    fps,
                    r.get("timing") or "",
                    fmt_ms(r.get("cpu_ms")),
                    r.get("check") or "",
                )
            )
            + " |"
        )
    cpu_adapter = any(re.search(r"llvmpipe|lavapipe|softpipe|swiftshader", x, re.I) for x in adapters)
    notes = [
        f"<!-- scripts/gpu-check.sh {a.mode}: {len(rows.rows)} figures, {len(rows.missing)} missing -->",
        "Device (as wgpu reports it): "
        + ("; ".join(f"{n} ({d})" if d else n for n, d in devices.items()) or "none")
        + f". Commit {commit}, {date}, "
        f"`scripts/gpu-check.sh{' --small' if a.mode == 'small' else ''}`.",
    ]
    if cpu_adapter:
        notes.append("**A CPU adapter (lavapipe), not a GPU: these are not GPU figures.**")
    if a.mode == "small":
        notes.append("Small sizes (CI check of the script): coarse transfer and BTFs, tiny images; not the paper's figures.")
    text = "\n".join(notes) + "\n\n" + "\n".join(lines) + "\n"
    if rows.missing:
        text += "\nMissing figures:\n\n" + "".join(f"* {label}: {why}\n" for label, why in rows.missing)
    (out / "rows.md").write_text(text)
    (out / "figures.json").write_text(
        json.dumps(
            {
                "mode": a.mode,
                "commit": commit,
                "date": date,
                "adapters": adapters,
                "devices": devices,
                "figures": rows.rows,
                "missing": [{"figure": label, "why": why} for label, why in rows.missing],
            },
            indent=1,
        )
        + "\n"
    )
    print(text, end="")
    if rows.missing:
        print(f"gpu_check_rows: {len(rows.missing)} expected figure(s) missing or not positive", file=sys.stderr)
        return 1
    return 0


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("derive")
    d.add_argument("src")
    d.add_argument("dst")
    ad = sub.add_parser("adapter")
    ad.add_argument("run_dir")
    r = sub.add_parser("rows")
    r.add_argument("--out", required=True)
    r.add_argument("--mode", default="full")
    r.add_argument(
        "--run", nargs=4, action="append", default=[], metavar=("SCENE", "ROLE", "SIZE", "DIR"),
        help="ROLE: main (forms and SH methods at SIZE), moments (runtime.light_moments) or pixel (a "
        "per-pixel runtime.moments_resolve)",
    )
    r.add_argument("--sh", default="", help="comma-separated SH method labels expected in the main runs")
    r.add_argument("--bench", help="gpu_bench's log (its figures are then expected)")
    r.add_argument("--commit", help="fallback when no run records its commit")
    r.add_argument("--date")
    a = p.parse_args()
    if a.cmd == "derive":
        derive(Path(a.src), Path(a.dst), sys.stdin.read())
        return 0
    if a.cmd == "adapter":
        m, why = load_metrics(Path(a.run_dir))
        adapter = m and adapter_of(m)
        if not adapter:
            print(why or "no GPU record in the run", file=sys.stderr)
            return 1
        print(adapter)
        return 0
    return rows_cmd(a)


if __name__ == "__main__":
    sys.exit(main())
