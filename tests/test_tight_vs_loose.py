"""Tightly coupled beats loosely coupled in partial outages (issue 4, seeds 000/003).

With 2 or 3 satellites kept, the PPP-only filter feeding the loosely coupled INS has fewer than
4 satellites and gives no fix, so the LC INS coasts; the tight filter still uses every kept
satellite's code, phase and Doppler. Same drive, IMU (Crista-class MEMS, S003), noise and
outages for both, through the sweep engine.
"""

from __future__ import annotations

import numpy as np

import jaxnav  # noqa: F401
from jaxnav.study import config as sc
from jaxnav.study import sweep as sw
from jaxnav.study.factory import SimFactory

SCENARIO = {"duration_s": 600, "ins_grade": "crista"}


def test_tight_beats_loose_with_two_or_three_satellites(tmp_path):
    cfg = sc.from_dict(
        {"study": {"name": "tc_lc", "modes": ["float_ppp"], "systems": ["ins15", "lc_ins15"],
                   "durations_s": [60], "satellites_kept": [2, 3], "realizations": 2,
                   "recovery_s": 10, "chunk_size": 8, "max_traces": 0},
         "placement": {"kind": "grid", "convergence_s": 300, "spacing_s": 70},
         "scenario": SCENARIO},
        modes=SimFactory.modes, systems=SimFactory.systems,
    )
    ds = sw.run_sweep(cfg, SimFactory(SCENARIO), tmp_path / "out", progress=False).dataset
    for k in (2, 3):
        tc = ds.max_2d_m.sel(system="ins15", satellites_kept=k).values.ravel()
        lc = ds.max_2d_m.sel(system="lc_ins15", satellites_kept=k).values.ravel()
        print(f"\n{k} satellites kept, 60-s outages ({tc.size}): max 2D error TC mean "
              f"{tc.mean():.2f} m (median {np.median(tc):.2f}), LC mean {lc.mean():.2f} m "
              f"(median {np.median(lc):.2f})")
        assert np.all(np.isfinite(tc)) and np.all(np.isfinite(lc))
        assert tc.mean() < 0.7 * lc.mean()
        assert np.median(tc) < np.median(lc)
