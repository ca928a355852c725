"""The seed-001 and seed-002 reproduction scripts run end to end in their --quick form.

Each script writes report.md (with the seed-vs-jaxnav comparison table) and PNG figures into
the directory given by --out; the test runs them as a user would (a subprocess with this
interpreter) so that the scripts cannot rot silently.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


@pytest.mark.parametrize(
    "name, must_contain",
    [
        ("seed001_ic_ppp_ins", ["Table 2", "Table 3", "Table 5", "GIM"]),
        ("seed002_df_ppp_riss", ["Table 5.2", "Table 5.1", "< 1.5 m", "Table 4"]),
    ],
)
def test_quick_run_writes_report(tmp_path, name, must_contain):
    proc = subprocess.run(
        [sys.executable, str(EXPERIMENTS / f"{name}.py"), "--quick", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900, cwd=EXPERIMENTS,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = (tmp_path / "report.md").read_text()
    assert "| quantity | seed | jaxnav | ratio |" in text  # common.comparison_table header
    assert "--quick" in text
    for s in must_contain:
        assert s in text, f"{s!r} missing from {name} report"
    pngs = sorted(tmp_path.glob("*.png"))
    assert len(pngs) >= 3, pngs
    assert all(p.stat().st_size > 5000 for p in pngs)  # a real figure, not an empty canvas
