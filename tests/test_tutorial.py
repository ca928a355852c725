"""The user tutorial (experiments/tutorial_outage_study.py) runs end to end in its --quick form.

The script form of the notebook runs in this process (``runpy``, with the command line a user
types, ``--quick --out DIR``), so the tutorial cannot rot: it completes, writes a sweep Dataset
with the study's axes and physically sensible numbers, a report whose table and single-run check
agree with that Dataset, and every figure it links drawn.
"""

from __future__ import annotations

import math
import re
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.study import sweep

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "tutorial_outage_study.py"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# (dist_by_duration.png only for studies of two or more durations: the full tutorial, not the
# quick form the tests run)
FIGURES = {"drive.png", "error_growth.png", "dist_by_satellites.png", "single_run.png"}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tutorial")
    argv = sys.argv
    sys.argv = [str(SCRIPT), "--quick", "--out", str(out)]
    try:
        runpy.run_path(str(SCRIPT), run_name="__main__")
    finally:
        sys.argv = argv
    sweeps = list(out.glob("sweep-*/results.nc"))
    assert len(sweeps) == 1, sweeps
    return out, (out / "report.md").read_text(), sweeps[0]


def test_outputs_match_their_golden(quick_run, goldens):
    """Refactors keep the numbers (tests/goldens/outputs.py)."""
    goldens.check("tutorial_quick",
                  goldens.numbers_in(quick_run[0]) | goldens.table_numbers(quick_run[1]))


def test_script_is_a_jupytext_percent_notebook():
    text = SCRIPT.read_text()
    assert text.startswith("# ---\n# jupyter:\n#   jupytext:\n")
    assert "formats: py:percent" in text.split("# ---", 2)[1]
    assert text.count("# %% [markdown]") >= 6 and text.count("\n# %%\n") >= 6


def test_dataset_has_the_study_axes_and_sensible_errors(quick_run):
    _, _, results = quick_run
    ds = sweep.load_results(results)
    assert ds["mode"].values.tolist() == ["df_code"]
    assert ds["system"].values.tolist() == ["riss"]
    assert ds.sizes["realization"] == 2
    assert sorted(ds["satellites_kept"].values.tolist()) == [-1, 0]
    assert ds.sizes["placement"] >= 1
    err = ds["max_2d_m"].values
    assert np.all(np.isfinite(err)) and np.all(err > 0.0)
    # Withholding every satellite cannot help on average: the complete-outage maximum error is
    # at least the no-outage error over the same windows (pooled over noise and placements).
    mean = ds["max_2d_m"].mean(["realization", "placement", "policy", "ramp"]).squeeze()
    zero, ref = float(mean.sel(satellites_kept=0)), float(mean.sel(satellites_kept=-1))
    print(f"\nmean max 2D: 0 satellites {zero:.2f} m, all {ref:.2f} m")
    assert zero >= ref
    # The 3D error bounds the 2D one, scenario by scenario.
    assert np.all(ds["max_3d_m"].values >= err - 1e-12)


def test_report_table_matches_the_dataset(quick_run):
    _, text, results = quick_run
    ds = sweep.load_results(results)
    assert "| satellites kept | df_code |" in text
    for level, k in (("0", 0), ("all", -1)):
        row = re.search(rf"^\| {level} \| ([0-9.]+) \(", text, re.MULTILINE)
        assert row, f"no table row for {level}"
        want = float(ds["max_2d_m"].sel(satellites_kept=k).mean())
        assert float(row.group(1)) == pytest.approx(want, abs=0.006)
    assert "Interpretation (computed)" in text and "times)" in text


def test_single_run_reproduces_the_sweep_cell(quick_run):
    """The whole-drive sweep.single_run with the outage mask gives the sweep's number for that cell,
    although the sweep ran only the outage window from a checkpoint."""
    _, text, _ = quick_run
    m = re.search(r"outage ([0-9.]+) m from a whole-drive `sweep.single_run`, ([0-9.]+) m from "
                  r"the\s+sweep", text)
    assert m, "single-run line missing"
    single, cell = float(m.group(1)), float(m.group(2))
    assert math.isfinite(single) and single > 0.0
    assert single == pytest.approx(cell, rel=1e-3, abs=1e-3)


def test_figures_are_written_and_linked(quick_run):
    out, text, _ = quick_run
    linked = set(re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", text))
    assert FIGURES <= linked, f"missing figure links: {FIGURES - linked}"
    assert "dist_by_duration.png" not in linked  # one duration in the quick form
    for name in linked:
        data = (out / name).read_bytes()
        assert data[:8] == PNG_MAGIC, name
        assert len(data) > 5000, name  # a drawn figure, not an empty canvas
