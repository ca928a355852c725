"""The user tutorial (jaxnav/apps/notebooks/outage_study.py) as a user gets it and runs it.

``jaxnav tutorial --out DIR`` copies the notebook out of the package (script and .ipynb), then the
copy runs in this process (``runpy``) from inside DIR with the command line a user types,
``--quick`` and no ``--out``, so the tutorial cannot rot: it completes, writes its results into
``tutorial_results/`` of the current folder (never the project's committed rendering), a sweep
Dataset with the study's axes and physically sensible numbers, a report whose table and
single-run check agree with that Dataset, and every figure it links drawn.
"""

from __future__ import annotations

import math
import os
import re
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav import cli
from jaxnav.apps import tutorial
from jaxnav.study import sweep

SCRIPT = tutorial.NOTEBOOKS / "outage_study.py"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# (dist_by_duration.png only for studies of two or more durations: the full tutorial, not the
# quick form the tests run)
FIGURES = {"drive.png", "error_growth.png", "dist_by_satellites.png", "single_run.png"}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tutorial")
    assert cli.main(["tutorial", "--out", str(folder)]) == 0
    argv, cwd = sys.argv, os.getcwd()
    sys.argv = [str(folder / "outage_study.py"), "--quick"]
    os.chdir(folder)
    try:
        runpy.run_path(sys.argv[0], run_name="__main__")
    finally:
        sys.argv = argv
        os.chdir(cwd)
    out = folder / "tutorial_results"
    sweeps = list(out.glob("sweep-*/results.nc"))
    assert len(sweeps) == 1, sweeps
    return out, (out / "report.md").read_text(), sweeps[0]


def test_tutorial_command_writes_the_script_and_the_notebook(tmp_path, capsys):
    nbformat = pytest.importorskip("nbformat", reason="jupytext (the notebook extra) absent")
    out = tmp_path / "new" / "tut"
    assert cli.main(["tutorial", "--out", str(out)]) == 0
    assert (out / "outage_study.py").read_text() == SCRIPT.read_text()
    nb = nbformat.read(out / "outage_study.ipynb", as_version=4)
    nbformat.validate(nb)
    kinds = [c.cell_type for c in nb.cells]
    text = SCRIPT.read_text()
    assert kinds.count("markdown") == text.count("# %% [markdown]")
    assert kinds.count("code") == text.count("\n# %%\n")
    assert "run_sweep" in "".join(c.source for c in nb.cells if c.cell_type == "code")
    assert str(out / "outage_study.ipynb") in capsys.readouterr().out
    # A second call changes nothing without --overwrite: exit 2, one line naming the file.
    (out / "outage_study.py").write_text("# my edits\n")
    assert cli.main(["tutorial", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "outage_study.py exists; pass --overwrite" in err and "Traceback" not in err
    assert (out / "outage_study.py").read_text() == "# my edits\n"
    assert cli.main(["tutorial", "--out", str(out), "--overwrite"]) == 0
    assert (out / "outage_study.py").read_text() == SCRIPT.read_text()


def test_tutorial_command_without_jupytext_writes_the_script(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(tutorial, "_jupytext", lambda: None)
    assert cli.main(["tutorial", "--out", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outage_study.py"]
    assert 'pip install "jaxnav[notebook]"' in capsys.readouterr().out


def test_tutorial_command_rejects_a_file_as_folder(tmp_path, capsys):
    (tmp_path / "f").write_text("")
    assert cli.main(["tutorial", "--out", str(tmp_path / "f")]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    # a folder where the notebook goes, even with --overwrite: one line, exit 2
    (tmp_path / "d" / "outage_study.py").mkdir(parents=True)
    assert cli.main(["tutorial", "--out", str(tmp_path / "d"), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"jaxnav tutorial: cannot write into {tmp_path / 'd'}: ")
    assert "outage_study.py" in err and "Traceback" not in err and err.count("\n") == 1


def test_editing_a_notebook_keeps_the_source_hash(tmp_path, monkeypatch):
    """Stored sweeps and prepared-observation caches are keyed by the source hash: the tutorial
    notebooks are documents, so their edits must not change it; any module's edit must."""
    import shutil

    copy = tmp_path / "jaxnav"
    shutil.copytree(Path(jaxnav.__file__).parent, copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(jaxnav, "__file__", str(copy / "__init__.py"))
    digest = sweep.source_hash.__wrapped__
    before = digest()
    (copy / "apps" / "notebooks" / "outage_study.py").write_text("# edited prose\n")
    assert digest() == before
    (copy / "apps" / "tutorial.py").write_text("# edited code\n")
    assert digest() != before


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
