"""``sweep.single_run``: one scenario, every epoch, errors and the filter's sigmas in metres."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

import jaxnav  # noqa: F401  (float64)
from jaxnav.study import outages as ot
from jaxnav.study import sweep as sw
from jaxnav.study.factory import SimFactory


def test_single_run_matches_the_engine_definition_and_its_sigma_grows_in_an_outage():
    f = SimFactory({"duration_s": 240.0, "ins_grade": "span_cpt"})
    prob = f.build(None, "df_code", "ins15", 1)
    ops = f.ops_for("df_code", "ins15")
    outage = ot.Outage(150, 40, 0)
    run = sw.single_run(prob, ops, outage, epoch_dt_s=1.0)
    _, err_ref = sw.brute_force(prob, ops, outage, epoch_dt_s=1.0, recovery_epochs=40)
    ok = np.isfinite(np.asarray(err_ref)).all(axis=1)
    np.testing.assert_allclose(run.error_enu_m[ok], np.asarray(err_ref)[ok], atol=1e-9)
    assert run.time_s[0] == 1.0 and run.time_s.shape[0] == run.error_enu_m.shape[0]
    assert not run.keep[150:190].any() and run.keep[100].sum() >= 4
    h_sd = np.hypot(run.sigma_enu_m[:, 0], run.sigma_enu_m[:, 1])
    assert h_sd[189] > 3.0 * h_sd[149]  # dead reckoning: the filter knows it is drifting
    assert h_sd[220] < 0.5 * h_sd[189]  # and recovers with the satellites
    # the sigma is in metres: an honest filter's 2D error is of its order before the outage
    e2 = np.hypot(run.error_enu_m[60:150, 0], run.error_enu_m[60:150, 1])
    print(f"\n2D error RMS {np.sqrt(np.mean(e2**2)):.2f} m, filter 2D sigma "
          f"{np.sqrt(np.mean(h_sd[60:150] ** 2)):.2f} m; at the outage end "
          f"{np.hypot(*run.error_enu_m[189, :2]):.2f} m vs {h_sd[189]:.2f} m")
    # For a consistent filter E|e_2D|^2 = sigma_E^2 + sigma_N^2, so the ratio of the RMS is 1
    # up to sampling: if the error keeps one direction over the window (one realisation, the
    # widest case), ratio^2 ~ chi2(2) / 2; its two-sided 95 % band is 0.11-1.92 (measured 1.85).
    lo, hi = np.sqrt(chi2.ppf([0.025, 0.975], 2) / 2.0)
    assert lo < np.sqrt(np.mean(e2**2)) / np.sqrt(np.mean(h_sd[60:150] ** 2)) < hi
