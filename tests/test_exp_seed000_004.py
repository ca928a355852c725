"""The seed-000 and seed-004 reproduction scripts run end to end in their --quick form.

Each script is executed as the user runs it (``python experiments/<name>.py --quick --out DIR``,
a subprocess with this interpreter), so the scripts never rot: exit code 0, a report.md holding
the seed-vs-jaxnav comparison table with finite numbers, and every PNG it links present and a
real PNG file.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# Generous: the quick runs take ~1 min on an idle 2-core machine, several under heavy load.
TIMEOUT_S = 1500


def _run(name: str, out: Path) -> str:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / f"{name}.py"), "--quick", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    report = out / "report.md"
    assert report.is_file()
    return report.read_text()


def _comparison_rows(text: str) -> list[list[str]]:
    """Rows of the '| quantity | seed | jaxnav | ratio |' table."""
    lines = text.splitlines()
    head = lines.index("| quantity | seed | jaxnav | ratio |")
    rows = []
    for line in lines[head + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


def _check_figures(text: str, out: Path, expected: set[str]):
    linked = set(re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", text))
    assert expected <= linked, f"missing figure links: {expected - linked}"
    for name in linked:
        path = out / name
        assert path.is_file(), name
        assert path.read_bytes()[:8] == PNG_MAGIC, name
        assert path.stat().st_size > 5000, name  # a drawn figure, not an empty canvas


@pytest.mark.parametrize(
    "name, figures, quantity",
    [
        ("seed000_ppp_riss_outages",
         {"error_growth_suburban.png", "dist_by_satellites_suburban.png",
          "error_growth_urban.png", "dist_by_satellites_urban.png", "seed_vs_ours.png"},
         "Table 5.2 CC, 0 kept [m]"),
        ("seed004_multignss",
         {"error_growth.png", "dist_by_duration.png", "rms_full_availability.png"},
         "max 2D, 10-s outage, GPS UD vs 'decimetre level' (<= 1 m) [m]"),
    ],
)
def test_quick_run_writes_report_and_figures(tmp_path, name, figures, quantity):
    text = _run(name, tmp_path)
    assert "--quick: reduced run" in text
    rows = {r[0]: r for r in _comparison_rows(text)}
    assert quantity in rows, sorted(rows)
    _, seed, ours, ratio = rows[quantity]
    seed, ours, ratio = float(seed), float(ours), float(ratio)
    assert math.isfinite(ours) and ours > 0.0
    assert ratio == pytest.approx(ours / seed, rel=0.02, abs=0.006)
    _check_figures(text, tmp_path, figures)
    # The sweep is resumable: its directory holds the manifest and the assembled results.
    sweeps = list(tmp_path.glob("sweep-*/results.nc"))
    assert sweeps, "no sweep results written"
