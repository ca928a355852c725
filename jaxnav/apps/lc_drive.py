"""``jaxnav lc``'s drive: the IMU log and the RTKLIB GNSS track put on one epoch grid (the data
flow is in ``apps/lc.py``'s docstring)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav.apps.car_config import UG_M_S2, CarConfig
from jaxnav.filter import constraints as cons
from jaxnav.filter import loose
from jaxnav.ins import strapdown
from jaxnav.io import imu as imu_io
from jaxnav.io import pos as pos_io
from jaxnav.io.errors import InputError


# ----------------------------------------------------------------------------------------------
# The drive: IMU + GNSS on one epoch grid
# ----------------------------------------------------------------------------------------------
class Drive(NamedTuple):
    """A recorded drive on the filter's epoch grid (host arrays; E epochs of K IMU samples)."""

    t_imu0_gps_s: float  # first IMU sample time (origin of outage start times)
    t_init_gps_s: float  # time of the initial state (end of epoch -1)
    epoch_dt_s: float
    imu_dt_s: float
    time_gps_s: np.ndarray  # [E] epoch end times
    samples: strapdown.ImuIncrements  # [E, K, 3] body-frame increments
    fixes: loose.GnssFix  # [E] GNSS aiding (validity = file epoch present and finite)
    fix_init: loose.GnssFix  # the fix at t_init
    ref_llh: np.ndarray  # [E, 3] RTK reference (the .pos, antenna)
    ref_vel_enu: np.ndarray  # [E, 3]
    q: np.ndarray  # [E] the .pos quality (0 where the epoch is missing)
    ns: np.ndarray  # [E]
    level_f_b: np.ndarray  # [3] mean specific force of the levelling window
    level_f_var: float  # detector statistic max(var f_fwd, var |f|) there, epoch mean [m^2/s^4]
    start_speed_m_s: float  # GNSS horizontal speed at t_init
    gnss_speed_m_s: np.ndarray  # [E] horizontal speed of the fix (inf where no valid fix)

    @property
    def n_epochs(self) -> int:
        return int(self.time_gps_s.size)

    @property
    def time_rel_s(self) -> np.ndarray:
        """Epoch times relative to the first IMU sample (outage schedules use this origin)."""
        return self.time_gps_s - self.t_imu0_gps_s


def resample_increments(inc: imu_io.ImuIncrements, t0_gps_s: float, dt_s: float, n: int):
    """Increments over the grid (t0 + (j-1) dt, t0 + j dt], j = 1..n: differences of the linearly
    interpolated cumulative integrals (module docstring). Returns (dtheta [n, 3], dv [n, 3])."""
    t = np.concatenate([[inc.time_gps_s[0] - inc.dt_s[0]], inc.time_gps_s])
    grid = t0_gps_s + dt_s * np.arange(n + 1)
    if grid[0] < t[0] - 1e-9 or grid[-1] > t[-1] + 1e-9:
        raise ValueError(
            f"resampling grid [{grid[0]:.3f}, {grid[-1]:.3f}] leaves the IMU log "
            f"[{t[0]:.3f}, {t[-1]:.3f}] (GPS s)"
        )
    out = []
    for x in (inc.dtheta_b, inc.dv_b):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
        at = np.stack([np.interp(grid, t, cum[:, i]) for i in range(3)], axis=1)
        out.append(np.diff(at, axis=0))
    return out[0], out[1]


def gnss_fixes_from_pos(sol) -> loose.GnssFix:
    """``GnssFix`` epochs from an RTKLIB solution (``jaxnav.io.pos.PosSolution``).

    Outage epochs (Q = 7) and missing values are marked invalid (their values replaced by finite
    placeholders). Matching the solution epochs to the IMU epochs is the caller's job.
    """
    llh = np.asarray(sol.llh, np.float64)
    cov_p = pos_io.covariance_enu(sol.sd_neu_m, sol.sd_cross_m)
    vel = np.asarray(sol.vel_enu, np.float64)
    cov_v = pos_io.covariance_enu(sol.sd_vel_neu, sol.sd_vel_cross)
    ok_p = ~np.asarray(sol.outage) & np.isfinite(llh).all(-1) & np.isfinite(cov_p).all((-1, -2))
    ok_v = ~np.asarray(sol.outage) & np.isfinite(vel).all(-1) & np.isfinite(cov_v).all((-1, -2))
    eye = np.broadcast_to(np.eye(3), cov_p.shape)
    return loose.GnssFix(
        jnp.asarray(np.where(ok_p[:, None], llh, 0.0)),
        jnp.asarray(np.where(ok_p[:, None, None], cov_p, eye)),
        jnp.asarray(np.where(ok_v[:, None], vel, 0.0)),
        jnp.asarray(np.where(ok_v[:, None, None], cov_v, eye)),
        jnp.asarray(ok_p),
        jnp.asarray(ok_v),
    )


def _fix_covariances(sol: pos_io.PosSolution, cfg: CarConfig):
    cov_p = pos_io.covariance_enu(sol.sd_neu_m, sol.sd_cross_m)
    cov_v = pos_io.covariance_enu(sol.sd_vel_neu, sol.sd_vel_cross)
    eye = np.eye(3)
    cov_p = cov_p + cfg.gnss_pos_sigma_floor_m**2 * eye
    cov_v = cov_v + cfg.gnss_vel_sigma_floor_m_s**2 * eye
    return cov_p, cov_v


def load_drive(
    imu_path, tag_path, gnss_path, cfg: CarConfig, *, duration_s: float | None = None
) -> Drive:
    """Read the IMU log and the GNSS track and put them on the filter's epoch grid."""
    log = imu_io.read_imu_csv(
        imu_path, tag_path, gyro_unit=cfg.imu_gyro_unit, accel_unit=cfg.imu_accel_unit,
        time_offset_s=cfg.imu_time_offset_s,
    )
    sol = pos_io.read_pos(gnss_path)
    if not sol.has_velocity:
        raise InputError(
            "no velocity columns", file=gnss_path,
            expected="vn ve vu sdvn ... columns (RTKLIB output with velocity)",
        )
    rpy = np.add(cfg.imu_mounting_rpy_deg, cfg.imu_misalignment_rpy_deg)
    inc = imu_io.imu_increments(log, imu_io.sensor_to_body_dcm(*rpy))

    t_gnss = sol.time_gps_s
    dt_ep = round(float(np.median(np.diff(t_gnss))), 3)  # .pos times carry milliseconds
    k_f = dt_ep * cfg.imu_resample_hz
    K = int(round(k_f))
    if K < 1 or abs(k_f - K) > 1e-6:
        raise ValueError(
            f"GNSS epoch interval {dt_ep} s is not a whole number of IMU intervals at "
            f"[imu] resample_hz = {cfg.imu_resample_hz:g}"
        )
    t_imu0, t_imu1 = float(log.time_gps_s[0]), float(log.time_gps_s[-1])
    if duration_s is not None:
        t_imu1 = min(t_imu1, t_imu0 + float(duration_s))
    inside = np.flatnonzero((t_gnss >= t_imu0) & (t_gnss <= t_imu1))
    if inside.size < 2:
        raise InputError(
            f"fewer than two GNSS epochs inside the IMU log [{t_imu0:.3f}, {t_imu1:.3f}] GPS s",
            file=gnss_path, expected="a GNSS track overlapping the IMU log",
        )
    i0 = int(inside[0])
    t_init = float(t_gnss[i0])
    t_end = min(t_imu1, float(t_gnss[inside[-1]]))  # the last GNSS epoch inside the log
    n_ep = int(np.floor((t_end - t_init) / dt_ep + 1e-6))
    grid = t_init + dt_ep * np.arange(n_ep + 1)  # grid[0] = initial state, grid[1:] epochs
    # Map the file's epochs onto the grid (within 1 ms); missing grid epochs are invalid fixes.
    idx = np.rint((t_gnss - t_init) / dt_ep).astype(np.int64)
    on_grid = (idx >= 0) & (idx <= n_ep) & (np.abs(t_gnss - t_init - idx * dt_ep) < 1e-3)
    src = np.full(n_ep + 1, -1, np.int64)
    src[idx[on_grid]] = np.flatnonzero(on_grid)
    have = src >= 0
    s = np.where(have, src, 0)

    cov_p, cov_v = _fix_covariances(sol, cfg)
    llh = sol.llh[s]
    vel = sol.vel_enu[s]
    ok = have & np.isfinite(llh).all(1) & np.isfinite(vel).all(1) & (sol.q[s] != pos_io.Q_OUTAGE)
    eye = np.broadcast_to(np.eye(3), (n_ep + 1, 3, 3))
    fix_all = loose.GnssFix(
        np.where(ok[:, None], llh, 0.0),
        np.where(ok[:, None, None], cov_p[s], eye),
        np.where(ok[:, None], vel, 0.0),
        np.where(ok[:, None, None], cov_v[s], eye),
        ok,
        ok,  # the velocity rows are switched by LooseConfig.use_vel; the alignment needs it
    )
    if not ok[0]:
        raise InputError(
            "no valid GNSS fix at the first epoch inside the IMU log", file=gnss_path,
            epoch=f"{t_init:.3f} GPS s", expected="a fix to initialise the position",
        )
    # Reference for the metrics: the file's solution; missing epochs interpolated in time.
    ref_llh = np.stack([np.interp(grid, t_gnss, sol.llh[:, i]) for i in range(3)], 1)
    ref_vel = np.stack([np.interp(grid, t_gnss, sol.vel_enu[:, i]) for i in range(3)], 1)

    dth, dv = resample_increments(inc, t_init, dt_ep / K, n_ep * K)
    samples = strapdown.ImuIncrements(dth.reshape(n_ep, K, 3), dv.reshape(n_ep, K, 3))
    n_level = max(int(round(cfg.alignment_level_s * cfg.imu_resample_hz)), 1)
    level_f = dv.reshape(-1, 3)[:n_level].sum(0) / (n_level * dt_ep / K)
    n_lev_ep = min(max(int(round(cfg.alignment_level_s / dt_ep)), 1), n_ep)
    stat = jax.vmap(cons.stationarity_statistics, (0, None))(
        jnp.asarray(samples.dv_b[:n_lev_ep]), dt_ep / K
    )
    level_var = float(jnp.mean(jnp.maximum(stat.var_forward, stat.var_norm)))
    first = jax.tree.map(lambda a: a[0], fix_all)
    rest = jax.tree.map(lambda a: a[1:], fix_all)
    return Drive(
        t_imu0_gps_s=t_imu0, t_init_gps_s=t_init, epoch_dt_s=dt_ep, imu_dt_s=dt_ep / K,
        time_gps_s=grid[1:], samples=samples, fixes=rest, fix_init=first,
        ref_llh=ref_llh[1:], ref_vel_enu=ref_vel[1:],
        q=np.where(have, sol.q[s], 0)[1:], ns=np.where(have, sol.ns[s], 0)[1:],
        level_f_b=level_f, level_f_var=level_var,
        start_speed_m_s=float(np.hypot(*sol.vel_enu[s[0], :2])),
        gnss_speed_m_s=np.where(ok, np.hypot(vel[:, 0], vel[:, 1]), np.inf)[1:],
    )


def rest_noise(drive: Drive, max_speed_m_s: float = 0.1):
    """Installed IMU noise at the initial standstill: std of the epoch-mean rate and specific
    force x sqrt(epoch length), per body axis, over the epochs before the RTK speed first
    exceeds ``max_speed_m_s``. Returns (gyro [deg/s/sqrt(Hz)], accel [ug/sqrt(Hz)], seconds)
    or None when the standstill is shorter than 2 s. Uses the IMU alone (the GNSS only to
    find the standstill)."""
    speed = np.hypot(drive.ref_vel_enu[:, 0], drive.ref_vel_enu[:, 1])
    n = int(np.argmax(speed > max_speed_m_s)) if np.any(speed > max_speed_m_s) else speed.size
    if n * drive.epoch_dt_s < 2.0:
        return None
    dt = drive.epoch_dt_s
    w = drive.samples.dtheta_b[:n].sum(1) / dt
    f = drive.samples.dv_b[:n].sum(1) / dt
    scale = math.sqrt(dt)
    return np.degrees(w.std(0, ddof=1)) * scale, f.std(0, ddof=1) * scale / UG_M_S2, n * dt
