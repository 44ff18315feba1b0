#!/usr/bin/env python3
"""BENCHMARKS.md's headline table, generated from finished runs' metrics.json.

Every figure of the table is read from a `biscale run` output folder's `metrics.json` (the
schema is `struct Metrics` in the tools crates' metrics.rs; provenance in its `run` record,
`struct RunRecord` in provenance.rs): nothing is typed by hand. One row per figure, with
the command that reproduces it, the machine it was measured on (CPU model, logical cores and
rayon threads, load average at the start and end of the run), the date the run started (UTC)
and the commit biscale was built from (`-dirty` when tracked files differed from it).

Rows per run folder, in this order:

* the transfer stage (build of T) when the run traced it; a run that took T from the stage
  cache measured nothing there, so it gets no row;
* the uncompressed per-vertex render against the ground truth, when the reference was traced;
* a run without method settings: one row per compressor setting (storage, L* error, RGB
  gather and build time, image error against the ground truth);
* a run with method settings (the low- vs all-frequency comparison): one row per quantity
  across every setting, its compressors as the all-frequency method first, then the methods
  (image error against the ground truth with the share of SH pixels gone negative by
  ringing, storage, gather and shade time, and the SH transfer's build time where it was
  built, not taken from the cache);
* the whole run's wall time and peak resident memory.

The command column is the run's own command line (`run.command`) with the binary shown as
`biscale` and the flags that only place its files (`--out`, `--cache-dir`) left out; the
generated block's first line names the run folders and the full command lines.

    python3 scripts/benchmarks_table.py out/bunny out/low_vs_all_bunny
    python3 scripts/benchmarks_table.py out/bunny out/low_vs_all_bunny --write BENCHMARKS.md

With --write, only the text between the lines `<!-- headline:begin -->` and
`<!-- headline:end -->` of the file is replaced; the rest is left byte for byte. Python 3
standard library only.
"""
import argparse
import json
import os
import shlex
import sys

BEGIN = "<!-- headline:begin -->"
END = "<!-- headline:end -->"

# Flags of `biscale run` that only say where files go: left out of the command column.
PLACEMENT_FLAGS = ("--out", "--cache-dir")


class MetricsError(Exception):
    """A metrics.json that is missing, unreadable or lacks a field the table needs."""


def metrics_path(arg):
    """The metrics.json of a run folder (or the file itself when given)."""
    if os.path.isdir(arg):
        return os.path.join(arg, "metrics.json")
    return arg


def load(arg):
    path = metrics_path(arg)
    if not os.path.exists(arg):
        raise MetricsError(f"{arg}: no such folder or file")
    if not os.path.isfile(path):
        raise MetricsError(f"{path}: no such file (is {arg} a finished `biscale run` output folder?)")
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except json.JSONDecodeError as e:
        raise MetricsError(f"{path}: not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}") from e
    except (OSError, UnicodeDecodeError) as e:
        raise MetricsError(f"{path}: cannot be read: {e}") from e
    if not isinstance(data, dict):
        raise MetricsError(f"{path}: expected a JSON object at the top level, found {type(data).__name__}")
    return path, data


def within(where, prefix):
    """A location inside a metrics.json: (file, JSON path prefix such as `compressors[2].`)."""
    file, outer = where if isinstance(where, tuple) else (where, "")
    return file, outer + prefix


def need(data, where, *keys):
    """data[keys[0]][keys[1]]..., or a MetricsError naming the file and the missing field.
    `where` is the file, or (file, prefix) for a record inside it (see `within`)."""
    file, prefix = within(where, "")
    node = data
    for i, key in enumerate(keys):
        if not isinstance(node, dict) or key not in node or node[key] is None:
            field = prefix + ".".join(str(k) for k in keys[: i + 1])
            raise MetricsError(f"{file}: missing field `{field}` (written by an older biscale, or not a run's metrics.json?)")
        node = node[key]
    return node


def num(data, where, *keys):
    value = need(data, where, *keys)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        file, prefix = within(where, "")
        raise MetricsError(f"{file}: field `{prefix}{'.'.join(keys)}` is {value!r}, not a number")
    return value


def sig(x, digits=3):
    """x to `digits` significant digits, without exponent for ordinary magnitudes."""
    if x is None:
        return "n/a"
    if x == 0:
        return "0"
    if abs(x) < 1e-3 or abs(x) >= 1e6:
        return f"{x:.{digits - 1}e}"
    return f"{x:#.{digits}g}".rstrip(".") if abs(x) < 10 ** digits else f"{x:,.0f}"


def fixed(x, places):
    return f"{x:,.{places}f}"


def command_of(run, path):
    argv = need(run, path, "command")
    if not isinstance(argv, list) or not argv:
        raise MetricsError(f"{within(path, '')[0]}: field `run.command` is not a non-empty list")
    shown = ["biscale"]
    i = 1
    while i < len(argv):
        a = str(argv[i])
        if a in PLACEMENT_FLAGS:
            i += 2
            continue
        if any(a.startswith(f + "=") for f in PLACEMENT_FLAGS):
            i += 1
            continue
        shown.append(a)
        i += 1
    return "`" + " ".join(shlex.quote(a) for a in shown) + "`"


def machine_of(run, path):
    cpu = need(run, path, "cpu_model")
    cores = num(run, path, "cores")
    threads = num(run, path, "threads")
    text = f"{cpu}, {cores} cores / {threads} threads"
    start, end = run.get("load_average_start"), run.get("load_average_end")
    if start and end:
        text += f", load {start[0]:.1f} to {end[0]:.1f}"
    return text


def commit_of(run):
    commit = run.get("git_commit")
    if not commit:
        return "unknown"
    short = commit[:10]
    return short + ("-dirty" if run.get("git_dirty") else "")


def image_vs_reference(record):
    ref = (record.get("image") or {}).get("vs_reference")
    if ref is None or ref.get("rel_l2") is None:
        return None
    return ref["rel_l2"]


def compressor_value(rec, path):
    name = need(rec, path, "name") + (" (lossless)" if rec.get("lossless") else "")
    parts = [
        f"{fixed(num(rec, path, 'bytes') / 1e6, 2)} MB",
        f"L* rel. error {sig(num(rec, path, 'rel_error_lstar'), 2)}",
        f"gather {fixed(num(rec, path, 'gather_ms'), 2)} ms",
        f"build {fixed(num(rec, path, 'build_seconds'), 2)} s" + (" (cached)" if rec.get("cached") else ""),
    ]
    ref = image_vs_reference(rec)
    if ref is not None:
        parts.append(f"image rel. L2 vs ground truth {sig(ref, 3)}")
    return name, "; ".join(parts)


def method_label(rec, path):
    """`SH order 5`, or `SH order 5 with cpca M` when its transfer is compressed; else the label."""
    name = need(rec, path, "name")
    sh = rec.get("sh")
    if not isinstance(sh, dict) or sh.get("order") is None:
        return name
    comp = sh.get("compressor")
    return f"SH order {sh['order']}" + (f" with {comp} `M`" if comp and comp != "sparse" else "")


def settings_line(settings, value):
    """`label value; label value; ...` over (label, record, where) triples."""
    return "; ".join(f"{label} {value(rec, where)}" for label, rec, where in settings)


def comparison_rows(m, path, add):
    """A run with method settings: one row per quantity across all its settings, compressors
    first (the all-frequency method), then the methods in config order."""
    settings = [
        (f"all-frequency {need(r, w, 'name')}", r, w)
        for i, r in enumerate(need(m, path, "compressors"))
        for w in [within(path, f"compressors[{i}].")]
    ]
    settings += [
        (method_label(r, w), r, w) for i, r in enumerate(m.get("methods") or []) for w in [within(path, f"methods[{i}].")]
    ]
    def error(r, _):
        text = sig(image_vs_reference(r), 3)
        negative = (r.get("sh") or {}).get("negative_pixels")
        if negative:
            text += f" ({fixed(100 * negative, 1)}% of pixels negative)"
        return text

    if any(image_vs_reference(r) is not None for _, r, _ in settings):
        add("image rel. L2 vs ground truth, all-frequency against low-frequency settings", settings_line(settings, error))
    add("storage MB per setting", settings_line(settings, lambda r, w: fixed(num(r, w, "bytes") / 1e6, 2)))
    add(
        "gather / shade ms per setting (medians)",
        settings_line(settings, lambda r, w: f"{fixed(num(r, w, 'gather_ms'), 2)} / {fixed(num(r, w, 'shade_ms'), 0)}"),
    )
    built = []
    for label, r, _ in settings:
        st = (r.get("sh") or {}).get("transfer") or {}
        if st and not st.get("cached") and st.get("seconds") is not None:
            built.append((label, st["seconds"]))
    if built:
        add("SH transfer `M` build s per setting", "; ".join(f"{label} {fixed(s, 2)}" for label, s in built))


def rows_of(arg):
    path, m = load(arg)
    exp = need(m, path, "experiment")
    run = need(m, path, "run")
    rw = within(path, "run.")
    common = (command_of(run, rw), machine_of(run, rw), need(run, rw, "started_at"), commit_of(run))
    rows = []

    def add(figure, value):
        rows.append((f"{exp}: {figure}", value) + common)

    t = need(m, path, "transfer")
    tw = within(path, "transfer.")
    if not need(t, tw, "cached"):
        scene = m.get("scene") or {}
        add(
            "transfer stage (build of `T`)",
            f"{fixed(num(t, tw, 'build_seconds'), 2)} s, {fixed(num(t, tw, 'rays_per_second') / 1e6, 1)} M rays/s; "
            f"{num(t, tw, 'nnz'):,} non-zeros"
            + (f", {scene['vertices']:,} vertices" if isinstance(scene.get("vertices"), int) else ""),
        )

    ref = m.get("reference")
    if ref:
        e = need(ref, within(path, "reference."), "uncompressed_vs_reference", "rel_l2")
        add("uncompressed `T` (per-vertex render) vs ground truth", f"image rel. L2 {sig(e, 3)}")

    if m.get("methods"):
        comparison_rows(m, path, add)
    else:
        for i, rec in enumerate(need(m, path, "compressors")):
            add(*compressor_value(rec, within(path, f"compressors[{i}].")))

    wall = run.get("wall_seconds")
    if wall:
        value = f"{fixed(wall, 1)} s wall"
        cpu = run.get("cpu_seconds")
        if cpu:
            value += f", {fixed(cpu, 1)} CPU-s"
        peak = (m.get("memory") or {}).get("peak_rss_bytes")
        if peak:
            value += f"; peak RSS {fixed(peak / 2**20, 0)} MiB"
        add("whole run", value)
    return path, run, rows


def table(runs):
    out = [
        "| figure | value | command | machine | date (UTC) | commit |",
        "|---|---|---|---|---|---|",
    ]
    for _, _, rows in runs:
        for row in rows:
            out.append("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |")
    return "\n".join(out)


def block(runs, invocation):
    sources = "; ".join(
        f"`{p}` (`{' '.join(shlex.quote(str(a)) for a in run['command'])}`)" for p, run, _ in runs
    )
    return (
        f"Generated by `{invocation}` from {sources}. "
        "Commands are shown without `--out` and `--cache-dir`.\n\n" + table(runs)
    )


def write(target, text):
    try:
        with open(target, encoding="utf-8") as f:
            doc = f.read()
    except OSError as e:
        raise MetricsError(f"{target}: cannot be read: {e}") from e
    b, e = doc.find(BEGIN), doc.find(END)
    if b < 0 or e < 0 or e < b or doc.count(BEGIN) != 1 or doc.count(END) != 1:
        raise MetricsError(f"{target}: needs exactly one `{BEGIN}` line followed by one `{END}` line")
    new = doc[: b + len(BEGIN)] + "\n" + text + "\n" + doc[e:]
    with open(target, "w", encoding="utf-8") as f:
        f.write(new)


def main(argv=None):
    p = argparse.ArgumentParser(
        description="Print BENCHMARKS.md's headline table (Markdown) from finished runs' metrics.json: "
        "one row per figure with its command, machine, date and commit.",
        epilog="Example: python3 scripts/benchmarks_table.py out/bunny out/low_vs_all_bunny --write BENCHMARKS.md",
    )
    p.add_argument("runs", nargs="+", metavar="RUN", help="a `biscale run` output folder (or its metrics.json)")
    p.add_argument(
        "--write",
        metavar="FILE",
        help=f"replace the text between `{BEGIN}` and `{END}` in FILE (e.g. BENCHMARKS.md) instead of printing",
    )
    args = p.parse_args(argv)
    invocation = "python3 scripts/benchmarks_table.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    try:
        runs = [rows_of(r) for r in args.runs]
        text = block(runs, invocation)
        if args.write:
            write(args.write, text)
            print(f"wrote {sum(len(r[2]) for r in runs)} rows into {args.write}", file=sys.stderr)
        else:
            print(text)
    except MetricsError as e:
        print(f"benchmarks_table: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
