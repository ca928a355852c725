"""README's Python example runs as written (in a temporary folder) and its Dataset holds what
it prints: the mean maximum 2D error of complete outages per mode."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_example_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert len(blocks) == 1, "README holds one Python example"
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(blocks[0], "README.md", "exec"), scope)  # noqa: S102 (our own README)
    ds = scope["ds"]
    assert (tmp_path / "api-out" / "results.nc").is_file()
    assert list(ds["mode"].values) == ["df_code", "float_ppp"]
    means = ds.max_2d_m.sel(satellites_kept=0).mean(["realization", "placement"]).squeeze()
    assert np.all(np.isfinite(means.values)) and np.all(means.values > 0)
    assert "### Average maximum 2D error [m] by satellites kept x mode" in out.getvalue()
