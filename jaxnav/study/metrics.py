"""Outage-study metrics: per-window errors, re-convergence, NEES, run RMS, chi-square bounds.

Everything except ``chi2_interval`` is pure JAX on fixed-shape [T, ...] histories, so a batch of
scenarios is a ``jax.vmap`` (start, length and ``n_valid`` may be traced ints).

Conventions (documented choices where the seeds are silent):

- Errors are estimate - truth, in local ENU metres at the true position (the geodetic error
  (d_lat, d_lon, d_h) scaled by ``geodesy.metres_per_radian``); 2D = horizontal (east, north),
  3D adds up.
- The outage window is the epochs [start, start + length) without (full) GNSS; its end error is
  the error at its last epoch start + length - 1 (the largest drift before GNSS returns). Pass
  the ramp epochs in the window if a degraded ramp should count as outage.
- Distance travelled: the truth's 3D path over the outage, summed 1-epoch chords from epoch
  start - 1 (the last GNSS epoch) to the window's last epoch (chord vs arc: relative error
  theta^2 / 24 for a heading change theta per epoch, 1e-5 for a 1 Hz, 20 m-radius turn at
  10 km/h). Error as % of distance = 100 max_2d / distance; NaN when the distance is below
  ``min_distance_m`` (a stop), where the ratio is meaningless.
- Re-convergence (S002 ch.5 measures the time to get back to 20 cm): threshold
  thr = max(reconv_threshold_m, reconv_factor * pre-outage 2D RMS), the pre-outage RMS over
  the ``pre_epochs`` epochs before the window. The factor term makes the metric meaningful for
  modes whose converged error is above 20 cm (SF / DF code: metres). The re-convergence time is
  t_e - t_end, t_end the first epoch after the window (GNSS back) and e the first epoch >= end
  after which the 2D error stays below thr up to the end of the record (``n_valid``). NaN (and
  ``reconverged`` False) when the last epoch is still above thr.
- NEES: e^T P^-1 e of the position (3 dof) and position + velocity (6 dof), with position in
  metres (e and P scaled by metres_per_radian; the value is unit-invariant, the scaling keeps
  P well conditioned: rad^2 variances are ~1e-14). The window's NEES is the mean over its
  epochs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.core import states
from jaxnav.core.track import Track, track  # noqa: F401  (this module's public names)

# P_nav (filter.tight.EpochOutput) is the leading navigation block: pos (d_lat, d_lon, d_h), vel
# ENU, then attitude / azimuth. Every layout in core.states starts that way.
_POS = states.INS15.sl("pos")
_VEL = states.INS15.sl("vel")
for _layout in (states.INS21, states.INS27, states.RISS16, states.RISS9):
    assert _layout.sl("pos") == _POS and _layout.sl("vel") == _VEL


class MetricConfig(NamedTuple):
    """Metric parameters (all chosen; reasons in the module docstring)."""

    reconv_threshold_m: float = 0.2  # S002 ch.5 re-convergence to 20 cm
    reconv_factor: float = 2.0  # chosen: back within 2x the pre-outage 2D RMS
    pre_epochs: int = 10  # chosen: 10 s at 1 Hz of pre-outage error to average
    min_distance_m: float = 1.0  # chosen: below this the % of distance is NaN (a stop)


class WindowMetrics(NamedTuple):
    """Per-scenario outage-window metrics (scalars, or [3] for end_enu_m)."""

    max_2d_m: jnp.ndarray
    rms_2d_m: jnp.ndarray
    max_3d_m: jnp.ndarray
    end_2d_m: jnp.ndarray
    end_enu_m: jnp.ndarray  # [3] east, north, up error at the window's last epoch (S001 Tab 3)
    distance_m: jnp.ndarray
    pct_of_distance: jnp.ndarray
    max_azimuth_err_rad: jnp.ndarray
    pre_2d_rms_m: jnp.ndarray
    reconv_threshold_m: jnp.ndarray
    reconv_s: jnp.ndarray
    reconverged: jnp.ndarray
    nees_pos: jnp.ndarray  # mean over the window, 3 dof
    nees_posvel: jnp.ndarray  # mean over the window, 6 dof


# Functions called on host arrays (tests, post-processing) are jitted: one compiled kernel per
# argument shape instead of one per primitive (inside another jit they are inlined).
@jax.jit
def wrap_angle(a):
    """Wrap an angle to [-pi, pi)."""
    return jnp.mod(a + jnp.pi, 2.0 * jnp.pi) - jnp.pi


@jax.jit
def _dllh(llh_a, llh_b):
    d = llh_a - llh_b
    return d.at[..., 1].set(wrap_angle(d[..., 1]))


@jax.jit
def enu_errors(llh_est, llh_true):
    """[T, 3] ENU error [m] of llh_est relative to llh_true (scaled at the truth)."""
    north, east, up = jnp.moveaxis(_dllh(llh_est, llh_true) * _mpr(llh_true), -1, 0)
    return jnp.stack([east, north, up], axis=-1)


@jax.jit
def _mpr(llh):
    """geodesy.metres_per_radian over a [T, 3] history: [T, 3] (north, east, up) scales."""
    return jnp.moveaxis(geodesy.metres_per_radian(jnp.moveaxis(llh, -1, 0)), 0, -1)


def _solve(A, b):
    """A^-1 b for small SPD A [..., n, n] by an unrolled Cholesky (L L^T) in plain array ops.

    Not jnp.linalg.solve: its LAPACK custom call, batched over scenarios x epochs, is where
    XLA:CPU deadlocked intermittently on this machine (every thread parked on a futex).
    """
    n = A.shape[-1]
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        d = A[..., j, j] - sum(L[j][k] ** 2 for k in range(j))
        L[j][j] = jnp.sqrt(d)
        for i in range(j + 1, n):
            L[i][j] = (A[..., i, j] - sum(L[i][k] * L[j][k] for k in range(j))) / L[j][j]
    y = []
    for i in range(n):  # L y = b
        y.append((b[..., i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i])
    x = [None] * n
    for i in reversed(range(n)):  # L^T x = y
        x[i] = (y[i] - sum(L[k][i] * x[k] for k in range(i + 1, n))) / L[i][i]
    return jnp.stack(x, axis=-1)


@jax.jit
def nees(est: Track, true: Track, P_nav):
    """Per-epoch NEES e^T P^-1 e: (position [T] 3 dof, position + velocity [T] 6 dof), position
    in metres (module docstring)."""
    s = _mpr(true.llh)  # [T, 3] metres per (d_lat, d_lon, d_h)
    e_pos = _dllh(est.llh, true.llh) * s
    e_vel = est.vel_enu - true.vel_enu
    scale = jnp.concatenate([s, jnp.ones_like(s)], axis=-1)  # [T, 6]
    idx = np.r_[np.arange(_POS.start, _POS.stop), np.arange(_VEL.start, _VEL.stop)]
    P6 = P_nav[:, idx[:, None], idx[None, :]] * scale[:, :, None] * scale[:, None, :]
    e6 = jnp.concatenate([e_pos, e_vel], axis=-1)
    n_pos = e_pos.shape[-1]
    q_pos = jnp.einsum("ti,ti->t", e_pos, _solve(P6[:, :n_pos, :n_pos], e_pos))
    q_all = jnp.einsum("ti,ti->t", e6, _solve(P6, e6))
    return q_pos, q_all


def _masked_max(x, m):
    return jnp.max(jnp.where(m, x, -jnp.inf))


def _masked_mean(x, m):
    return jnp.sum(jnp.where(m, x, 0.0)) / jnp.sum(m)


def window_metrics(
    est: Track,
    true: Track,
    P_nav,
    start,
    length,
    epoch_dt_s,
    cfg: MetricConfig = MetricConfig(),  # noqa: B008 (immutable NamedTuple)
    n_valid=None,
) -> WindowMetrics:
    """Metrics of the outage window [start, start + length) (module docstring: definitions).

    ``P_nav`` [T, k, k] the navigation-block covariance (pos rad/rad/m, vel ENU, ...), or None
    (NEES = NaN). Epochs >= ``n_valid`` (padding of fixed-length records) are ignored.
    """
    n_epochs = true.llh.shape[0]
    t = jnp.arange(n_epochs)
    n_valid = n_epochs if n_valid is None else n_valid
    valid = t < n_valid
    end = start + length
    win = (t >= start) & (t < end) & valid
    last = end - 1

    err = enu_errors(est.llh, true.llh)
    e2 = jnp.hypot(err[:, 0], err[:, 1])
    e3 = jnp.linalg.norm(err, axis=1)
    max_2d = _masked_max(e2, win)
    rms_2d = jnp.sqrt(_masked_mean(e2**2, win))
    end_enu = err[jnp.clip(last, 0, n_epochs - 1)]

    step = jnp.linalg.norm(enu_errors(true.llh[1:], true.llh[:-1]), axis=1)
    step = jnp.concatenate([jnp.zeros(1), step])  # step[t]: from epoch t-1 to t
    distance = jnp.sum(jnp.where(win & (t >= 1), step, 0.0))
    pct = jnp.where(distance >= cfg.min_distance_m, 100.0 * max_2d / distance, jnp.nan)

    daz = jnp.abs(wrap_angle(est.azimuth - true.azimuth))
    max_daz = _masked_max(daz, win)

    pre = (t >= start - cfg.pre_epochs) & (t < start) & valid
    pre_rms = jnp.where(jnp.any(pre), jnp.sqrt(_masked_mean(e2**2, pre)), 0.0)
    thr = jnp.maximum(cfg.reconv_threshold_m, cfg.reconv_factor * pre_rms)
    bad = (e2 >= thr) & (t >= end) & valid
    first_good = jnp.max(jnp.where(bad, t, end - 1)) + 1
    reconverged = first_good < n_valid
    reconv_s = jnp.where(reconverged, (first_good - end) * epoch_dt_s, jnp.nan)

    if P_nav is None:
        nees_pos = nees_all = jnp.nan
    else:
        q_pos, q_all = nees(est, true, P_nav)
        nees_pos, nees_all = _masked_mean(q_pos, win), _masked_mean(q_all, win)

    return WindowMetrics(
        max_2d_m=max_2d,
        rms_2d_m=rms_2d,
        max_3d_m=_masked_max(e3, win),
        end_2d_m=jnp.hypot(end_enu[0], end_enu[1]),
        end_enu_m=end_enu,
        distance_m=distance,
        pct_of_distance=pct,
        max_azimuth_err_rad=max_daz,
        pre_2d_rms_m=pre_rms,
        reconv_threshold_m=thr,
        reconv_s=reconv_s,
        reconverged=reconverged,
        nees_pos=jnp.asarray(nees_pos),
        nees_posvel=jnp.asarray(nees_all),
    )


class RunRms(NamedTuple):
    rms_enu_m: jnp.ndarray  # [3] east, north, up
    rms_2d_m: jnp.ndarray
    rms_3d_m: jnp.ndarray
    max_2d_m: jnp.ndarray
    n_epochs: jnp.ndarray  # epochs counted


def run_rms(llh_est, llh_true, epoch_dt_s, exclude_s=600.0, valid=None) -> RunRms:
    """RMS (and max 2D) position error over a whole run after a convergence exclusion: epochs
    with t - t_0 >= exclude_s (S002: 5 min in ch.4, 10 min in ch.5), optionally masked."""
    n_epochs = llh_true.shape[0]
    m = jnp.arange(n_epochs) * epoch_dt_s >= exclude_s - 1e-9 * epoch_dt_s
    if valid is not None:
        m = m & valid
    err = enu_errors(llh_est, llh_true)
    n = jnp.sum(m)
    ms = jnp.sum(jnp.where(m[:, None], err**2, 0.0), axis=0) / n
    e2 = jnp.hypot(err[:, 0], err[:, 1])
    return RunRms(
        jnp.sqrt(ms), jnp.sqrt(ms[0] + ms[1]), jnp.sqrt(jnp.sum(ms)), _masked_max(e2, m), n
    )


def chi2_interval(dof, n_runs: int = 1, prob: float = 0.95):
    """Two-sided ``prob`` interval of the mean of ``n_runs`` independent chi2(dof) values:
    [chi2.ppf((1 - prob)/2, N dof), chi2.ppf((1 + prob)/2, N dof)] / N (Bar-Shalom et al.,
    NEES / NIS consistency tests). For K NIS values with varying row counts and total dof D,
    their mean lies in chi2(D) / K: pass dof = D / K and n_runs = K.

    Host-side numpy (SciPy is a JAX dependency, so always installed).
    """
    from scipy.stats import chi2

    total = np.asarray(dof, float) * n_runs
    lo = chi2.ppf(0.5 * (1.0 - prob), total) / n_runs
    hi = chi2.ppf(0.5 * (1.0 + prob), total) / n_runs
    return lo, hi
