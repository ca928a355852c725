"""``jaxnav lc``'s filter: the loose filter built from the car configuration, its start and
inputs, the withheld-GNSS outages and their metrics, and the solution at the antenna."""

from __future__ import annotations

import argparse
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.apps.car_config import LAYOUTS, CarConfig, CarConfigError, imu_error_model, lever_arms_b
from jaxnav.apps.lc_drive import Drive
from jaxnav.core import states as st
from jaxnav.filter import constraints as cons
from jaxnav.filter import loose
from jaxnav.filter.systems import InsSystem, NavSigmas
from jaxnav.ins import strapdown
from jaxnav.io import pos as pos_io
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot


# ----------------------------------------------------------------------------------------------
# Filter set-up
# ----------------------------------------------------------------------------------------------
def build_filter(
    cfg: CarConfig, drive: Drive, *, nhc: bool | None = None, zupt: bool | None = None
) -> loose.LooseFilter:
    """The ``LooseFilter`` of the configuration (``nhc`` / ``zupt`` override the switches)."""
    lever_ant, lever_nhc = lever_arms_b(cfg)
    system = InsSystem(
        layout=LAYOUTS[cfg.imu_errors_states], model=imu_error_model(cfg),
        lever_b=jnp.asarray(lever_ant),
    )
    use_nhc = cfg.constraints_nhc if nhc is None else nhc
    use_zupt = cfg.constraints_zupt if zupt is None else zupt
    lcfg = loose.LooseConfig(
        use_pos=True,
        use_vel=cfg.gnss_use_velocity,
        use_nhc=use_nhc,
        use_zupt=use_zupt,
        use_zaru=use_zupt and cfg.constraints_zaru,
        zupt_without_gnss_vel=not cfg.constraints_zupt_with_gnss_vel,
        cov_substeps=cfg.filter_cov_substeps,
        align_in_motion=True,
        align_min_speed_m_s=cfg.alignment_min_speed_m_s,
        align_sigma_floor_rad=math.radians(cfg.alignment_heading_floor_deg),
        nhc_sigma_m_s=cfg.constraints_nhc_sigma_m_s,
        zupt_sigma_m_s=cfg.constraints_zupt_sigma_m_s,
        zupt_ref_var=(drive.level_f_var if cfg.constraints_zupt_ref_sigma_m_s2 == "start"
                      else cfg.constraints_zupt_ref_sigma_m_s2**2),
        detector=cons.ZuptDetector(
            threshold=cfg.constraints_zupt_threshold,
            max_ins_speed_m_s=cfg.constraints_zupt_max_speed_m_s,
        ),
        vehicle_lever_b=jnp.asarray(lever_nhc),
        gate_chi2=cfg.filter_gate_chi2,
    )
    K = drive.samples.dv_b.shape[1]
    if K % cfg.filter_cov_substeps:
        raise CarConfigError(
            f"[filter] cov_substeps = {cfg.filter_cov_substeps}: expected a divisor of the {K} "
            f"IMU samples per GNSS epoch"
        )
    return loose.LooseFilter(system, lcfg, drive.imu_dt_s, drive.epoch_dt_s)


def initial_carry(cfg: CarConfig, lf: loose.LooseFilter, drive: Drive) -> loose.Carry:
    """Levelled start at the first fix; heading from the course if already moving, else
    unknown until the in-motion alignment (module docstring)."""
    nav0, sig, moving = initial_state(cfg, lf, drive)
    carry = loose.initial_carry(lf, nav0, sig)
    return carry._replace(aligned=jnp.asarray(moving))


def initial_state(cfg: CarConfig, lf: loose.LooseFilter, drive: Drive):
    """(navigation state, its sigmas, moving at the start) of ``initial_carry``, on the host
    (``jaxnav tune`` builds the carry from them with traced noise parameters)."""
    fix = drive.fix_init
    moving = drive.start_speed_m_s > cfg.alignment_min_speed_m_s
    euler0 = np.array(loose.align_from_gnss(fix.vel_enu, drive.level_f_b))
    if not moving:
        euler0[2] = 0.0  # arbitrary: the in-motion alignment sets it
    lever_l = np.asarray(attitude.dcm_from_euler(jnp.asarray(euler0))) @ np.asarray(
        lf.system.lever_b
    )
    llh0 = np.asarray(fix.llh) - np.asarray(geodesy.llh_rate_matrix(jnp.asarray(fix.llh))) @ lever_l
    sd_pos = float(np.sqrt(np.max(np.diag(np.asarray(fix.cov_pos_enu)))))
    sig = NavSigmas(
        pos_m=max(sd_pos, 1e-3),
        vel_m_s=cfg.alignment_vel_sigma_m_s,
        roll_pitch_rad=math.radians(cfg.alignment_roll_pitch_sigma_deg),
        azimuth_rad=(math.radians(cfg.alignment_heading_floor_deg) if moving
                     else lf.cfg.align_prior_sigma_rad),
    )
    vel0 = np.asarray(fix.vel_enu) if moving else np.zeros(3)
    return loose.initial_nav(llh0, vel0, euler0), sig, bool(moving)


def epoch_inputs(cfg: CarConfig, drive: Drive, withheld=None) -> loose.EpochInput:
    """Stacked filter inputs; ``withheld`` [E] bool removes the GNSS fix of those epochs.

    ZUPT/ZARU are allowed (``EpochInput.zupt_allowed``) where the GNSS is absent or its speed is
    below ``constraints.zupt_gnss_speed_m_s``: with GNSS a car moving off at walking pace, whose
    vibration is that of the idling engine, is not taken for standing (without GNSS velocity
    rows, S002's rule "no ZUPT while GNSS velocity is used" does not apply). A withheld fix
    says nothing, so the detector alone decides there (the sweep's ``with_keep`` does the same).
    """
    fix = jax.tree.map(jnp.asarray, drive.fixes)
    slow = drive.gnss_speed_m_s < cfg.constraints_zupt_gnss_speed_m_s
    allowed = ~fix.pos_valid | jnp.asarray(slow)
    if withheld is not None:
        keep = ~jnp.asarray(withheld, bool)
        fix = fix._replace(pos_valid=fix.pos_valid & keep, vel_valid=fix.vel_valid & keep)
        allowed = allowed | ~keep
    samples = jax.tree.map(jnp.asarray, drive.samples)
    return loose.epoch_inputs(samples, fix, zupt_allowed=allowed)


def antenna_track(lever_b, out: loose.EpochOutput):
    """Antenna llh [.., 3] of the filter outputs (IMU position + C_b^l l^b, estimated attitude)."""

    def one(llh, euler):
        return strapdown.antenna_llh(llh, attitude.dcm_from_euler(euler), lever_b)

    f = one
    for _ in range(out.llh.ndim - 1):
        f = jax.vmap(f)
    return f(out.llh, out.euler)


@jax.jit
def _antenna_outputs(lever_b, out: loose.EpochOutput, dtheta_last_b, imu_dt_s):
    """Antenna llh, ENU velocity and ENU position / velocity sigmas per epoch."""

    def one(llh, vel, euler, P, bias, scale, dth):
        C = attitude.dcm_from_euler(euler)
        w_b = (dth / imu_dt_s - bias) / (1.0 + scale)  # compensated rate of the last sample
        llh_a = strapdown.antenna_llh(llh, C, lever_b)
        vel_a = strapdown.antenna_vel_enu(llh, vel, C, w_b, lever_b)
        m = geodesy.metres_per_radian(llh)  # north, east, up per (lat, lon, h)
        S = jnp.array([[0.0, m[1], 0.0], [m[0], 0.0, 0.0], [0.0, 0.0, 1.0]])  # -> E, N, U
        pos, vel_sl = st.INS15.sl("pos"), st.INS15.sl("vel")
        P_pos = S @ P[pos, pos] @ S.T
        return llh_a, vel_a, P_pos, P[vel_sl, vel_sl]

    return jax.vmap(one)(
        out.llh, out.vel_enu, out.euler, out.P_nav, out.sensors.gyro_bias_rad_s,
        out.sensors.gyro_scale, dtheta_last_b,
    )


@eqx.filter_jit
def run_filter(lf: loose.LooseFilter, carry: loose.Carry, inputs: loose.EpochInput):
    """``loose.run`` compiled (one trace per filter configuration and drive length)."""
    return loose.run(lf, carry, inputs)


@eqx.filter_jit
def run_smoothed(lf: loose.LooseFilter, carry: loose.Carry, inputs: loose.EpochInput):
    """``loose.run_smoother`` compiled: (forward EpochOutput, RTS-smoothed EpochOutput)."""
    return loose.run_smoother(lf, carry, inputs)


# ----------------------------------------------------------------------------------------------
# Outages
# ----------------------------------------------------------------------------------------------
class OutagePlan(NamedTuple):
    ids: tuple[str, ...]
    start_s: np.ndarray  # requested start after the first IMU sample [s]
    length_s: np.ndarray
    start_epoch: np.ndarray  # first withheld epoch
    n_epochs: np.ndarray  # withheld epochs
    withheld: np.ndarray  # [E] bool


def parse_grid(text: str) -> tuple[float, float, float]:
    """START:STEP:LENGTH in seconds (STEP > LENGTH > 0, START >= 0)."""
    try:
        start, step, length = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--outage-grid takes START:STEP:LENGTH in seconds, got {text!r}"
        ) from None
    if not (start >= 0 and length > 0 and step > length):
        raise argparse.ArgumentTypeError(
            f"--outage-grid {text!r}: expected START >= 0 and STEP > LENGTH > 0 (outages of one "
            f"run must not touch)"
        )
    return start, step, length


def grid_schedule(drive: Drive, start: float, step: float, length: float) -> ot.Schedule:
    """Outages START + i STEP, LENGTH long, whose window ends inside the drive."""
    end = float(drive.time_rel_s[-1])
    starts = np.arange(start, end - length + 1e-9, step)
    if starts.size == 0:
        raise ValueError(f"--outage-grid: no {length:g} s outage fits after {start:g} s in the "
                         f"{end:.1f} s drive")
    return ot.Schedule(tuple(f"g{i:03d}" for i in range(starts.size)), starts,
                       np.full(starts.size, float(length)))


def plan_outages(drive: Drive, sched: ot.Schedule) -> OutagePlan:
    """Withheld epochs of a schedule: start <= t_rel < start + length (module docstring)."""
    t = drive.time_rel_s
    withheld = np.zeros(t.size, bool)
    first, count = [], []
    for oid, s0, n in zip(sched.id, sched.start_s, sched.length_s, strict=True):
        w = (t >= s0 - 1e-6) & (t < s0 + n - 1e-6)
        if not w.any():
            raise ValueError(
                f"outage {oid!r} ({s0:g} s + {n:g} s) holds no GNSS epoch of the drive "
                f"(epochs at {t[0]:.2f} ... {t[-1]:.2f} s after the first IMU sample)"
            )
        if s0 + n > t[-1] + drive.epoch_dt_s + 1e-6:
            raise ValueError(
                f"outage {oid!r} ends at {s0 + n:g} s, after the drive's last epoch "
                f"({t[-1]:.2f} s after the first IMU sample)"
            )
        idx = np.flatnonzero(w)
        first.append(int(idx[0]))
        count.append(int(idx.size))
        withheld |= w
    return OutagePlan(tuple(sched.id), np.asarray(sched.start_s), np.asarray(sched.length_s),
                      np.asarray(first), np.asarray(count), withheld)


def outage_metrics(drive: Drive, llh_ant, out: loose.EpochOutput, plan: OutagePlan):
    """window_metrics of every outage against the RTK track (vmapped over the outages)."""
    est = mt.Track(jnp.asarray(llh_ant), out.vel_enu, out.euler[:, 2])
    truth = reference_track(drive)

    def one(s, n):
        return mt.window_metrics(est, truth, out.P_nav, s, n, drive.epoch_dt_s)

    return jax.jit(jax.vmap(one))(jnp.asarray(plan.start_epoch), jnp.asarray(plan.n_epochs))


def reference_track(drive: Drive) -> mt.Track:
    """The RTK track as metrics truth; its azimuth is the course over ground (meaningless at a
    standstill, so the sweep's azimuth metric is not reported)."""
    v = drive.ref_vel_enu
    return mt.Track(jnp.asarray(drive.ref_llh), jnp.asarray(v),
                    jnp.asarray(np.arctan2(v[:, 0], v[:, 1])))


# ----------------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------------
def _signed_root(x):
    return np.sign(x) * np.sqrt(np.abs(x))


def solution_pos(drive: Drive, lf, out: loose.EpochOutput, withheld) -> pos_io.PosSolution:
    """The antenna solution as an RTKLIB ``PosSolution`` (Q of the fix, Q = 7 in outages)."""
    llh, vel, P_pos, P_vel = (
        np.asarray(a) for a in _antenna_outputs(
            lf.system.lever_b, out, jnp.asarray(drive.samples.dtheta_b[:, -1]), lf.imu_dt_s
        )
    )
    withheld = np.asarray(withheld, bool)
    # E, N, U covariance -> RTKLIB sdn, sde, sdu and signed roots of ne, eu, un
    def neu(P):
        sd = np.sqrt(np.stack([P[:, 1, 1], P[:, 0, 0], P[:, 2, 2]], 1))
        cross = _signed_root(np.stack([P[:, 1, 0], P[:, 0, 2], P[:, 2, 1]], 1))
        return sd, cross

    sd_p, cr_p = neu(P_pos)
    sd_v, cr_v = neu(P_vel)
    aided = np.asarray(drive.fixes.pos_valid) & ~withheld
    q = np.where(aided, drive.q, pos_io.Q_OUTAGE)
    n = drive.n_epochs
    return pos_io.PosSolution(
        time_gps_s=drive.time_gps_s, llh=llh, q=q.astype(np.int64),
        ns=np.where(aided, drive.ns, 0).astype(np.int64), sd_neu_m=sd_p, sd_cross_m=cr_p,
        age_s=np.zeros(n), ratio=np.zeros(n), vel_enu=vel, sd_vel_neu=sd_v, sd_vel_cross=cr_v,
    )
