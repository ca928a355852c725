"""experiments/seed003_lc_vs_tc.py --quick runs end to end and writes its report and figures.

This is the suite's one experiment run as a user runs it, a subprocess with this interpreter (the
others run in-process through their ``main(argv)``): it checks that a script works from the
command line, with its own imports and ``sys.path``. Its quick form has no outages, so S003's
"tight beats loose with 2-3 satellites" is left to tests/test_tight_vs_loose.py; the claim it
can support is the NHC's: the constraint makes the azimuth observable and shrinks its error.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXP = Path(__file__).resolve().parents[1] / "experiments"


@pytest.mark.heavy
def test_seed003_quick_writes_report(tmp_path, goldens):
    proc = subprocess.run(
        [sys.executable, str(EXP / "seed003_lc_vs_tc.py"), "--quick", "--out", str(tmp_path)],
        cwd=EXP, capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = (tmp_path / "report.md").read_text()
    timings = ("run_s", "wall_s")
    goldens.check("seed003_quick",
                  goldens.numbers_in(tmp_path, skip=timings) | goldens.table_numbers(report))
    for heading in ("Seed figures", "Seed vs ours", "NHC gain", "Discussion"):
        assert f"## {heading}" in report
    assert (tmp_path / "attitude_errors.png").stat().st_size > 0
    assert (tmp_path / "attitude_rms.png").stat().st_size > 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    rms = summary["rms"]
    assert set(rms) == {"PPP", "TC", "TC+NHC", "LC", "LC+NHC"}
    # Full availability: every LC epoch has a valid PPP fix, and the solutions are sane
    # (metre-level DF-code positions, azimuth within a few degrees, NHC not harmful).
    assert min(summary["lc_fix_valid_fraction"].values()) == 1.0
    for lab in ("TC", "TC+NHC", "LC", "LC+NHC"):
        assert rms[lab]["lat_m"] < 5.0 and rms[lab]["az_deg"] < 20.0
    assert rms["LC+NHC"]["az_deg"] < rms["LC"]["az_deg"]
    assert rms["TC+NHC"]["az_deg"] < rms["TC"]["az_deg"]
