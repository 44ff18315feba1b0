"""README's Python blocks run as written (issue: its snippet once named a class it never
defined). Each ```python block of README.md is executed in order, in one namespace, from a
folder that holds the checkout's `configs` and `assets` (links), so its relative paths resolve
as in the checkout and its `out/` and stage cache land in the test's own folder."""

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_readme_python_blocks_run_as_written(tmp_path, monkeypatch):
    blocks = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), re.S | re.M)
    assert blocks, "README.md has no Python block"
    for name in ("configs", "assets"):
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    scope = {"__name__": "readme"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md python block {i + 1}", "exec"), scope)
    # The first block's run: the compressor it defines, scored beside the built-ins.
    metrics = scope["metrics"]
    mine = [c for c in metrics["compressors"] if c["name"] == "my-csr"]
    assert mine and mine[0]["lossless"] and mine[0]["rel_error_lstar"] < 1e-6, metrics["compressors"]
    assert (tmp_path / "out" / "smoke-py" / "metrics.json").is_file()
    assert scope["lstar"].shape == (scope["T"].shape[0], 3)
