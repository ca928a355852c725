"""The references the sweep engine is checked against: the brute-force run of the whole drive
with an outage mask, and one run with its error and sigma history (``single_run``)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.core.ops import FilterOps
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study.plan import Problem


# ----------------------------------------------------------------------------------------------
# Brute force (the reference the engine is tested against)
# ----------------------------------------------------------------------------------------------
def brute_force(
    problem: Problem,
    ops: FilterOps,
    outage: ot.Outage,
    *,
    epoch_dt_s: float,
    recovery_epochs: int,
    mcfg: mt.MetricConfig = mt.MetricConfig(),  # noqa: B008 (immutable NamedTuple)
    policy: str = ot.DEFAULT_POLICY,
    key=None,
    metric_window: str = "core",
):
    """Metrics of one outage from a run of the whole drive with the outage mask applied
    (no checkpoints): the definition the engine must reproduce. Returns (WindowMetrics,
    ENU error [T, 3] with NaN after the recovery period)."""
    T = problem.elevation.shape[0]
    mask = ot.keep_mask(
        problem.elevation, problem.available, outage, key, policy=policy,
        azimuth=problem.azimuth, elevation_mask_rad=problem.elevation_mask_rad,
    )
    inputs = ops.with_keep(problem.inputs, ops.get_keep(problem.inputs) & mask)
    _, out = jax.jit(ops.run)(problem.tf, problem.carry0, inputs)
    est, P_nav = ops.readout(out)
    start, length, ramp = (jnp.asarray(outage.start), jnp.asarray(outage.length),
                           jnp.asarray(outage.ramp))
    if metric_window == "with_ramp":
        m_start, m_len = start - ramp, length + 2 * ramp
    else:
        m_start, m_len = start, length
    n_valid = jnp.minimum(start + length + ramp + recovery_epochs, T)
    m = mt.window_metrics(est, problem.truth, P_nav, m_start, m_len, epoch_dt_s, mcfg, n_valid)
    err = mt.enu_errors(est.llh, problem.truth.llh)
    err = jnp.where((jnp.arange(T) < n_valid)[:, None], err, jnp.nan)
    return m, err


class SingleRun(NamedTuple):
    """One scenario, every epoch (``single_run``). Epoch k is drive epoch k + 1 (epoch 0 only
    initialises the filter), at ``time_s``."""

    time_s: np.ndarray  # [T] s since the drive start
    keep: np.ndarray  # [T, S] bool: satellites the filter was allowed to use
    estimate: mt.Track  # [T] the filter's navigation solution
    error_enu_m: np.ndarray  # [T, 3] estimate - truth, east / north / up
    sigma_enu_m: np.ndarray  # [T, 3] the filter's 1-sigma of the same, from P
    output: Any  # the filter's raw per-epoch output (``ops.run``)


def single_run(problem: Problem, ops: FilterOps, outage: ot.Outage | None = None, *,
               epoch_dt_s: float, policy: str = ot.DEFAULT_POLICY, key=None) -> SingleRun:
    """Run one problem over the whole drive with an optional outage mask and return the errors
    and the filter's own sigmas in metres: sigma_N = sqrt(P_lat) (R_M + h),
    sigma_E = sqrt(P_lon) (R_N + h) cos(lat), sigma_U = sqrt(P_h)."""
    mask = jnp.ones_like(problem.available)
    if outage is not None:
        mask = ot.keep_mask(
            problem.elevation, problem.available, outage, key, policy=policy,
            azimuth=problem.azimuth, elevation_mask_rad=problem.elevation_mask_rad,
        )
    keep = ops.get_keep(problem.inputs) & mask
    _, out = jax.jit(ops.run)(problem.tf, problem.carry0, ops.with_keep(problem.inputs, keep))
    est, P_nav = ops.readout(out)
    err = np.asarray(mt.enu_errors(est.llh, problem.truth.llh))
    var_llh = np.asarray(jnp.diagonal(P_nav, axis1=-2, axis2=-1)[..., :3])
    scale = np.asarray(jax.vmap(geodesy.metres_per_radian)(est.llh))  # north, east, up
    sd_neu = np.sqrt(np.maximum(var_llh, 0.0)) * scale
    T = err.shape[0]
    return SingleRun(
        time_s=epoch_dt_s * np.arange(1, T + 1), keep=np.asarray(keep),
        estimate=jax.tree.map(np.asarray, est), error_enu_m=err,
        sigma_enu_m=sd_neu[:, [1, 0, 2]], output=out,
    )
