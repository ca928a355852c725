"""How long the stand-alone PPP solution's error stays correlated, per mode (realistic simulator).

A loosely coupled INS filter takes the PPP solution as its position measurement. That solution
is the output of a filter whose slowly varying states (float ambiguities, ZWD, the ionosphere
residual, the clock-height correlation) carry its error from epoch to epoch, so the LC filter
must model the fix error as correlated (``filter.loose``: ``fix_bias_tau_s``). This script
measures the correlation time it needs: for each PPP mode, N realisations of the default drive
(every simulated error source on) run through the cascade's PPP filter alone
(``study.factory.PPP_ALONE``), and after the settling time

- the normalised autocorrelation of the ENU position error, rho(L) = E[e(t) e(t+L)] / E[e^2]
  (the mean is kept: a bias is correlation too), averaged over runs, epochs and the three axes;
- tau = the lag where rho first falls below 1/e, or, where it does not within the window,
  -L_max / ln(rho(L_max)) (first-order Gauss-Markov extrapolation);
- the position ANEES of the PPP filter itself (3 dof), which tells whether its covariance, the
  LC filter's measurement covariance, is true.

The last line printed is JSON ``{"<mode>": {"tau_s": .., "rho_10": .., "rho_60": ..,
"rho_300": .., "anees_pos": .., "runs": N}, ...}``; ``study.factory.LC_FIX_BIAS_TAU_S`` holds
the values of the committed run (benchmarks/RESULTS.md).

    python benchmarks/ppp_error_correlation.py              # 8 runs x 900 s, every mode
    python benchmarks/ppp_error_correlation.py --modes float_ppp --runs 4
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav.study import metrics as mt
from jaxnav.study.factory import PPP_ALONE, SimFactory

MODES = ("sf_code", "df_code", "sdf_code", "float_ppp", "ic_ppp", "sf_ppp")


def measure(factory: SimFactory, mode: str, runs: int, settle_s: float, max_lag_s: float):
    """(tau_s, rho [lags], ANEES) of one mode's PPP-only position error over seeds 0..runs-1."""
    ops = factory.ops_for(mode, PPP_ALONE)

    def one(tf, carry0, inputs, truth):
        est, P_nav = ops.readout(ops.run(tf, carry0, inputs)[1])
        return mt.enu_errors(est.llh, truth.llh), mt.nees(est, truth, P_nav)[0]

    run = jax.jit(one)
    errs, nees = [], []
    for seed in range(runs):
        prob = factory.build(None, mode, PPP_ALONE, seed)
        e, q = run(prob.tf, prob.carry0, prob.inputs, prob.truth)
        errs.append(np.asarray(e))
        nees.append(np.asarray(q))
    dt = factory.cfg.epoch_interval_s
    k0 = int(round(settle_s / dt))
    e, q = np.stack(errs)[:, k0:], np.stack(nees)[:, k0:]
    n_t = e.shape[1]
    lags = np.arange(min(n_t - 1, int(round(max_lag_s / dt)) + 1))
    power = np.mean(e**2)
    rho = np.array([np.mean(e[:, : n_t - L] * e[:, L:]) for L in lags]) / power
    below = np.flatnonzero(rho < np.exp(-1.0))
    if below.size:
        tau = float(lags[below[0]] * dt)
    else:
        tau = float(-lags[-1] * dt / np.log(max(rho[-1], 1e-9)))
    return tau, rho, float(q.mean())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--modes", default=",".join(MODES), help="comma-separated PPP modes")
    p.add_argument("--runs", type=int, default=8)
    p.add_argument("--duration", type=float, default=900.0, help="seconds per run")
    p.add_argument("--settle", type=float, default=300.0, help="seconds left out at the start")
    p.add_argument("--max-lag", type=float, default=300.0, help="longest lag evaluated [s]")
    a = p.parse_args(argv)
    modes = a.modes.split(",")
    bad = [m for m in modes if m not in MODES]
    if bad:
        p.error(f"--modes: unknown {bad}; allowed {list(MODES)}")
    if a.duration - a.settle <= a.max_lag:
        p.error(f"--duration {a.duration:g} must exceed --settle + --max-lag "
                f"({a.settle + a.max_lag:g} s)")
    factory = SimFactory({"duration_s": a.duration})
    dt = factory.cfg.epoch_interval_s
    res = {}
    print("| mode | tau [s] | rho(10 s) | rho(60 s) | rho(300 s) | PPP ANEES pos | s |")
    print("|---|---|---|---|---|---|---|")
    for mode in modes:
        t0 = time.perf_counter()
        tau, rho, anees = measure(factory, mode, a.runs, a.settle, a.max_lag)
        at = {L: float(rho[min(int(round(L / dt)), rho.size - 1)]) for L in (10, 60, 300)}
        res[mode] = {"tau_s": tau, "rho_10": at[10], "rho_60": at[60], "rho_300": at[300],
                     "anees_pos": anees, "runs": a.runs}
        print(f"| {mode} | {tau:.0f} | {at[10]:.2f} | {at[60]:.2f} | {at[300]:.2f} | "
              f"{anees:.2f} | {time.perf_counter() - t0:.0f} |", flush=True)
    print(json.dumps(res, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
