"""benchmarks/scaling.py and benchmarks/roofline.py: --quick runs end to end (subprocesses, both
at once), the final JSON line, RESULTS.md and plots at temporary paths, and the pieces with closed
forms (keep masks, LAPACK FLOP counts, saturation, the stall guard)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

import jaxnav

pytestmark = pytest.mark.heavy  # subprocesses that time themselves

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"
sys.path.insert(0, str(BENCH))

import roofline  # noqa: E402
import scaling  # noqa: E402

TIMEOUT_S = 600  # both --quick runs take ~40 s each on 2 idle cores; a shared machine is slower


@pytest.fixture(scope="module")
def quick_runs(tmp_path_factory):
    """Both scripts' --quick runs, started together: {name: (returncode, stdout, results.md)}."""
    tmp = tmp_path_factory.mktemp("bench")
    # The benchmarks measure jaxnav as a user runs it: XLA's default fusion emitters, not the
    # older ones this test session compiles with (conftest.py). With the older emitters the
    # INS15 buffers at width 16 were 24x those at width 1 (default emitters: within 8-20x).
    env = {k: v for k, v in os.environ.items() if k != "JAXNAV_XLA_FUSION_EMITTERS"}
    env["XLA_FLAGS"] = env.get("XLA_FLAGS", "").replace(jaxnav.OLDER_EMITTERS_FLAG, "").strip()
    procs = {}
    for name, extra in (("scaling", ["--plots", str(tmp / "plots")]), ("roofline", [])):
        results = tmp / f"{name}.md"
        cmd = [sys.executable, str(BENCH / f"{name}.py"), "--quick", "--results", str(results),
               *extra]
        procs[name] = (subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, cwd=ROOT, env=env), results)
    out = {}
    for name, (p, results) in procs.items():
        try:
            stdout, stderr = p.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            p.kill()
            stdout, stderr = p.communicate()
        out[name] = (p.returncode, stdout, stderr, results)
    out["plots"] = tmp / "plots"
    return out


def _final_json(run):
    rc, stdout, stderr, _ = run
    assert rc == 0, stderr[-2000:]
    return json.loads(stdout.strip().splitlines()[-1])


def test_scaling_quick_runs_and_reports(quick_runs):
    fig = _final_json(quick_runs["scaling"])
    for s in ("ins15", "riss"):
        for k in ("saturation_batch", "flat_after_saturation", "per_scenario_ms", "xla_mb"):
            assert any(key.startswith(f"{k}_{s}") for key in fig), (k, s)
    assert fig["quick"] is True and fig["batch_max"] == 32 and fig["chunk"] == 16
    text = quick_runs["scaling"][3].read_text()
    assert "## scaling (quick)" in text and "Command: `python benchmarks/scaling.py --quick" in text
    # the machine line names this process's cores and the versions that produced the numbers
    assert f"Machine: {len(os.sched_getaffinity(0))} cores, " in text
    assert f"jax {metadata.version('jax')}, " in text
    assert f"jaxnav {metadata.version('jaxnav')}" in text
    for name in ("scaling_batch.png", "scaling_outage.png", "scaling_state.png"):
        png = quick_runs["plots"] / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name


def test_scaling_quick_sanity(quick_runs):
    """Buffers grow linearly with the vmap width and stay flat once batches run as chunks; cost
    per scenario-epoch does not blow up with the window length; batching never costs much more
    than running scenarios one by one. The timing bounds are loose on purpose: on the shared
    machine single calls vary by ~3x with the other jobs' load; they catch a cost growing
    super-linearly with the batch or the window, not a few tens of per cent."""
    fig = _final_json(quick_runs["scaling"])
    for s in ("ins15", "riss"):
        ratio = fig[f"xla_mb_{s}_bmax"] / fig[f"xla_mb_{s}_b1"]  # width 16 vs width 1
        assert 8.0 < ratio < 20.0, (s, ratio)
        assert 0.2 < fig[f"us_per_epoch_{s}_longest_over_shortest"] < 5.0
    assert fig["per_scenario_ms_ins15_bmax"] < 2.0 * fig["per_scenario_ms_ins15_b1"]


def test_roofline_quick_runs_and_reports(quick_runs):
    fig = _final_json(quick_runs["roofline"])
    for k in ("flops_per_epoch", "achieved_gflops", "dgemm_gflops", "fraction_of_peak"):
        assert fig[k] > 0, k
    # Covariance propagation alone is two n x n products (Phi P, then (Phi P) Phi^T): 4 n^3.
    n = fig["states"]
    assert fig["flops_per_epoch"] > 4 * n**3
    # XLA counts the 100 Hz inner loop once: the corrected count must be larger.
    assert fig["flops_per_epoch"] > fig["xla_flops_per_epoch_uncorrected"]
    assert fig["fraction_of_peak"] == pytest.approx(
        fig["achieved_gflops"] / fig["dgemm_gflops"], rel=0.02, abs=1e-4)
    shares = [fig[f"time_share_{k}"] for k in ("mechanization", "covariance", "update_rest")]
    assert all(0.0 <= x <= 1.0 for x in shares)
    assert "## roofline (quick)" in quick_runs["roofline"][3].read_text()


def test_keep_masks_closed_form():
    base = np.array([[True, False, True, True]] * 3 + [[True, True, False, True]])
    m = scaling.keep_masks(base, n_outage=3, batch=5)
    assert m.shape == (5, 4, 4)
    # scenario b keeps its first b % 4 available slots during the 3 outage epochs
    for b, n_keep in enumerate([0, 1, 2, 3, 0]):
        assert (m[b, :3].sum(axis=1) == min(n_keep, 3)).all()
        assert (m[b, 3] == base[3]).all()  # recovery: full availability
    assert not (m & ~base[None]).any()  # never keeps an unavailable slot


def test_lapack_flops_from_hlo_shapes():
    hlo = "\n".join([
        '%c = (f64[4,36,36]{1,2,0}, s32[4]{0}) custom-call(%a), '
        'custom_call_target="lapack_dpotrf_ffi", operand_layout_constraints={f64[4,36,36]{1,2,0}}',
        '%t = f64[4,36,30]{1,2,0} custom-call(%c, %b), custom_call_target="lapack_dtrsm_ffi", '
        'operand_layout_constraints={f64[4,36,36]{1,2,0}, f64[4,36,30]{1,2,0}}',
    ])
    flops, counts = roofline.lapack_flops(hlo)
    assert counts == {"potrf": 1, "trsm": 1, "max_n": 36}
    assert flops == pytest.approx(4 * 36**3 / 3 + 4 * 36**2 * 30)


def _pt(batch, ms):
    return scaling.Point("x", batch, min(batch, 64), 10, 12, 30, 0.0,
                         ms * min(batch, 64) / 1e3, ms * min(batch, 64) / 1e3, 1.0)


def test_saturation_finds_the_knee_and_flags_growth():
    flat = [_pt(1, 10.0), _pt(4, 4.0), _pt(16, 2.1), _pt(64, 2.0), _pt(256, 2.05)]
    assert scaling.saturation(flat)[:2] == (16, True)
    growing = [_pt(1, 10.0), _pt(4, 2.0), _pt(16, 2.1), _pt(64, 4.0), _pt(256, 8.0)]
    sat, is_flat, worst = scaling.saturation(growing)
    assert not is_flat and worst == pytest.approx(4.0)


def test_run_guarded_reports_a_stall_without_hanging():
    t0 = time.perf_counter()
    r = scaling.run_guarded([sys.executable, "-c", "import time; time.sleep(60)"], 2.0)
    assert r["status"] == "stalled" and time.perf_counter() - t0 < 30
    ok = scaling.run_guarded([sys.executable, "-c", "print('x'); print('{\"a\": 1}')"], 60.0)
    assert ok["status"] == "ok" and ok["a"] == 1
    bad = scaling.run_guarded([sys.executable, "-c", "raise SystemExit(3)"], 60.0)
    assert bad["status"] == "failed" and bad["returncode"] == 3
