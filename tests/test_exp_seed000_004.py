"""The seed-000 and seed-004 reproduction scripts run end to end in their --quick form.

Each script runs in this process through its ``main(argv)`` (``conftest.run_quick_experiment``),
so the scripts never rot: a report.md holding the seed-vs-jaxnav comparison table with finite
numbers, every PNG it links present and a real PNG file, and the study's qualitative claim that
the quick form is large enough to support, read from the sweep's Dataset.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from jaxnav.study import sweep

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


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


def _check_report(text: str, out: Path, expected_figures: set[str], quantity: str):
    assert "--quick: reduced run" in text
    rows = {r[0]: r for r in _comparison_rows(text)}
    assert quantity in rows, sorted(rows)
    _, seed, ours, ratio = rows[quantity]
    seed, ours, ratio = float(seed), float(ours), float(ratio)
    assert math.isfinite(ours) and ours > 0.0
    assert ratio == pytest.approx(ours / seed, rel=0.02, abs=0.006)
    linked = set(re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", text))
    assert expected_figures <= linked, f"missing figure links: {expected_figures - linked}"
    for name in linked:
        path = out / name
        assert path.is_file(), name
        assert path.read_bytes()[:8] == PNG_MAGIC, name
        assert path.stat().st_size > 5000, name  # a drawn figure, not an empty canvas


def _max_2d(out: Path, sweep_dir: str, **sel) -> float:
    """Mean maximum 2D error of one cell of a sweep the script wrote (resumable directory)."""
    ds = sweep.load_results(out / sweep_dir / sweep.RESULTS_FILE)
    return float(ds["max_2d_m"].sel(**sel).mean())


def test_seed000_quick(run_quick_experiment, tmp_path, goldens):
    text = run_quick_experiment("seed000_ppp_riss_outages", tmp_path)
    goldens.check("seed000_quick", goldens.numbers_in(tmp_path) | goldens.table_numbers(text))
    _check_report(text, tmp_path,
                  {"error_growth_suburban.png", "dist_by_satellites_suburban.png",
                   "error_growth_urban.png", "dist_by_satellites_urban.png", "seed_vs_ours.png"},
                  "Table 5.2 CC, 0 kept [m]")
    # S000 Tables 5.2 / 5.3: with code + carrier, keeping 3 satellites through a 60-s outage
    # bounds the error growth below that of a complete outage, on both drives. (The quick form
    # has one placement and one realisation per drive: the claim is about every outage, so one
    # each is a fair, if small, sample.)
    for drive in ("suburban", "urban"):
        zero = _max_2d(tmp_path, f"sweep-{drive}", mode="float_ppp", satellites_kept=0)
        three = _max_2d(tmp_path, f"sweep-{drive}", mode="float_ppp", satellites_kept=3)
        print(f"\n{drive}: float PPP max 2D, 0 kept {zero:.2f} m, 3 kept {three:.2f} m")
        assert three < zero, drive


def test_seed004_quick(run_quick_experiment, tmp_path, goldens):
    text = run_quick_experiment("seed004_multignss", tmp_path)
    goldens.check("seed004_quick", goldens.numbers_in(tmp_path) | goldens.table_numbers(text))
    _check_report(text, tmp_path,
                  {"error_growth.png", "dist_by_duration.png", "rms_full_availability.png"},
                  "max 2D, 10-s outage, GPS UD vs 'decimetre level' (<= 1 m) [m]")
    # S004: through complete outages the error of the tactical-grade INS grows with the outage
    # length (decimetres at 10 s, metres at 60 s), for the undifferenced and the BSSD filter
    # alike. What the quick form cannot support, and so does not check: the absolute "decimetre
    # level" at 10 s (its one placement comes 150 s after the start, not 300 s: measured 1.49 m
    # there, 0.65 m mean in the full run) and "GPS + GLONASS + Galileo beats GPS" (it runs only
    # the two GPS scenarios; the 27-slot multi-GNSS filter is left to the full run for its
    # compile time).
    for label in ("gps-ud", "gps-bssd"):
        ten = _max_2d(tmp_path, f"sweep-{label}", duration=10.0)
        thirty = _max_2d(tmp_path, f"sweep-{label}", duration=30.0)
        print(f"\n{label}: max 2D 10-s outage {ten:.2f} m, 30-s outage {thirty:.2f} m")
        assert ten < thirty, label
