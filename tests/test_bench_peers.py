"""benchmarks/peers.py: runs, agrees with its peers to its stated tolerance, reports, skips.

The quick run is a subprocess (as a user runs it) writing its RESULTS section to a temporary
file; the skip path (a peer not installed) runs in-process on a tiny tracking problem with the
peer packages hidden from the import system.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.heavy  # a timing subprocess

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benchmarks" / "peers.py"
KEYS = {
    "mode", "lg_T", "lg_B", "lg_jaxnav_compile_s", "lg_jaxnav_ms_per_track", "lg_ratio_numpy",
    "lg_ratio_filterpy", "lg_ratio_dynamax", "lg_max_diff_sigma", "lg_tol_sigma",
    "ins_duration_s", "ins_B", "ins_jaxnav_compile_s", "ins_jaxnav_ms_per_run",
    "ins_ratio_numpy", "ins_ratio_filterpy", "ins_max_diff_sigma", "ins_max_pos_diff_m",
    "ins_tol_sigma", "ins_sim_s", "total_s", "peak_rss_mb",
}  # fmt: skip


def _installed(name):
    return importlib.util.find_spec(name) is not None


def _load_peers():
    spec = importlib.util.spec_from_file_location("bench_peers", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_quick_run_agrees_and_reports(tmp_path):
    results = tmp_path / "RESULTS.md"
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick", "--results", str(results)],
        cwd=ROOT, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    print(proc.stdout[-3000:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    figs = json.loads(proc.stdout.strip().splitlines()[-1])
    assert KEYS <= set(figs), KEYS - set(figs)
    assert figs["mode"] == "quick"
    # Agreement of every implementation that ran with jaxnav, in sigmas of the filter's P.
    assert figs["lg_tol_sigma"] == 1e-8 and figs["ins_tol_sigma"] == 1e-6
    assert 0.0 <= figs["lg_max_diff_sigma"] < figs["lg_tol_sigma"]
    assert 0.0 <= figs["ins_max_diff_sigma"] < figs["ins_tol_sigma"]
    assert figs["ins_max_pos_diff_m"] < 1e-6
    # The NumPy loops always run; a peer that is installed must have produced a ratio.
    assert figs["lg_ratio_numpy"] > 0 and figs["ins_ratio_numpy"] > 0
    assert (figs["lg_ratio_filterpy"] is not None) == _installed("filterpy")
    assert (figs["ins_ratio_filterpy"] is not None) == _installed("filterpy")
    assert (figs["lg_ratio_dynamax"] is not None) == _installed("dynamax")
    assert figs["lg_jaxnav_ms_per_track"] > 0 and figs["ins_jaxnav_ms_per_run"] > 0
    # The section went to the temporary file, with the table and the same JSON figures.
    text = results.read_text()
    assert "## Peers (quick)" in text and "| jaxnav loose.run (jit, vmap) |" in text
    assert "dynamax | skipped: no INS mechanization" in text
    block = text.split("```json")[-1].split("```")[0]
    assert json.loads(block) == figs


def test_absent_peers_are_skipped_with_a_reason(monkeypatch):
    peers = _load_peers()
    # None in sys.modules makes ``import x`` raise ImportError, as if x were not installed.
    for name in ("filterpy", "filterpy.kalman", "dynamax", "dynamax.linear_gaussian_ssm"):
        monkeypatch.setitem(sys.modules, name, None)
    rows = peers.run_tracking(dict(lg_T=30, lg_B=8, lg_fp=2), repeats=1)
    skipped = {r["impl"]: r["skipped"] for r in rows if "skipped" in r}
    assert set(skipped) == {"FilterPy KalmanFilter", "dynamax lgssm_filter"}
    assert all("not importable" in why for why in skipped.values())
    md = peers.table(rows, "track")
    assert md.count("| skipped: ") == 2
    assert peers._ratio(rows, "filterpy") is None and peers._ratio(rows, "dynamax") is None
    # The rows that did run still agree (jaxnav vs the NumPy loop).
    ran = [r for r in rows if "skipped" not in r]
    assert len(ran) == 2 and ran[1]["diff"] < peers.TOL_LG


def test_sigma_scaled_difference_detects_a_real_discrepancy():
    """The agreement measure is not blind: a filter run with half the process noise is flagged."""
    peers = _load_peers()
    F, Q, H, R, P0 = peers.lg_model()
    x0, zs = peers.lg_simulate(50, 4)
    xs, Ps = peers.lg_numpy(x0, zs, F, Q, H, R, P0)
    xs_bad, Ps_bad = peers.lg_numpy(x0, zs, F, 0.5 * Q, H, R, P0)
    ok = max(peers.sigma_scaled_diff(xs, Ps, *peers.lg_numpy(x0, zs, F, Q, H, R, P0)))
    bad = max(peers.sigma_scaled_diff(xs, Ps, xs_bad, Ps_bad))
    assert ok == 0.0
    assert bad > 1e-2
    assert np.isfinite(bad)


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-v"]))
