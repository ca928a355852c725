"""Loosely coupled GNSS/INS: position and velocity fixes plus vehicle constraints, one EKF.

One GNSS epoch (S002 sec. 4.2, eq 4.20-4.29) = mechanize the epoch's IMU samples (inner
``lax.scan`` in ``InsSystem.propagate``), propagate the covariance, one masked update with every
configured row, closed-loop feedback. ``run`` scans it over the epochs; a batch of scenarios is a
``jax.vmap`` of ``run`` and an outage is only a mask (``GnssFix.pos_valid`` / ``vel_valid``).

Rows (each family switched by a static ``LooseConfig`` flag, each row also masked per epoch):

- GNSS position (S002 eq 4.23-4.24): the antenna position predicted through the lever arm
  (``InsSystem.antenna``) minus the fix, in local ENU metres,
  dz = [(R_N+h) cos(lat) d_lon, (R_M+h) d_lat, d_h] of (llh_ant_hat - llh_fix), with H the exact
  antenna Jacobian scaled to metres; R = the fix's ENU covariance times ``pos_cov_scale`` (S002
  scales R with DOP and satellite count but gives no numbers: one factor here).
- GNSS velocity: ENU antenna velocity (lever-arm rotation term included) minus the fix.
- Time-correlated fix errors (``fix_bias_tau_s``): a fix that is the output of another filter
  (PPP: ambiguities, ZWD and clock carry its error from epoch to epoch) is not an independent
  measurement each epoch, and weighting it as one makes the INS filter over-confident (position
  ANEES 16.9 in the realistic simulator, issue 16). With ``fix_bias_tau_s`` set, the fix's
  position error is a first-order Gauss-Markov process b (3 states ``fix_bias``, ENU metres):
  z = p_ant + b + w, b_k = rho b_k-1 + q_k, rho = exp(-dt / tau) (Groves 2013, sec. 14.3.1:
  time-correlated GNSS errors as states). Its steady variance follows the fix's own covariance
  C_k: the share ``fix_bias_share`` of C_k is b's, the rest is the white w. Where C_k is
  constant, b_k = rho b_k-1 + q_k with Var(q_k) = (1 - rho^2) C_k (stationary first-order GM).
  Where it shrinks, the upstream filter has learnt something and its error has moved: for a
  filter of constant states the new error is uncorrelated with the change of estimate, so
  cov(e_k, e_k-1) = C_k and e_k = C_k C_k-1^-1 e_k-1 + q_k. Both combine, per axis, into
  b_k = A b_k-1 + q_k, A = rho diag(min(1, C_k,ii / C_k-1,ii)), Var(q_k) = [C_k - A C_k-1 A]+
  (positive part): Var(b_k) follows C_k, and a sudden growth (a PPP restart after an outage)
  reaches b at once instead of over tau.
- NHC, odometer speed (optional scale-factor state ``odo_scale``), ZUPT + ZARU on detected
  standstill (``filter.constraints``). S002: ZUPT is not applied while a GNSS velocity is used
  (``zupt_without_gnss_vel``); the ZARU (gyro only) is.

Timing. Every row refers to the end of the epoch t_k. The lever-arm terms need the body rate at
t_k: the epoch-mean rate lags it by half an epoch, which in an urban turn entry (yaw acceleration
~0.5 rad/s^2) is a 0.25 rad/s error, i.e. 0.4 m/s at a 1.5 m lever; so the last compensated IMU
sample (rate at t_k - dt_imu / 2) is used instead. To run the constraints faster than the GNSS,
make the epochs shorter and mark the in-between GNSS fixes invalid.

Covariance propagation: F is evaluated ``cov_substeps`` times per epoch (on equal chunks of the
samples, each with its own mechanized state and mean inputs) and discretised with
``ekf.discretize`` (its third-order series; no squarings: the INS has ||F dt|| << 1 over a
substep); more substeps follow the attitude through sharp turns.

In-motion alignment (``align_from_gnss``): the heading is the course over ground of the GNSS
velocity, atan2(v_E, v_N), which assumes no side slip and the IMU forward axis along the vehicle's
(heading error ~ sigma_v / speed: 0.3 deg at 10 m/s with 0.05 m/s velocity noise); roll and pitch
come from levelling the mean specific force (valid at rest or at constant velocity: an
unmodelled acceleration a tilts them by ~a/g rad, and an accelerometer bias b by b/g) or,
without IMU data, roll = 0 and pitch = the velocity's flight-path angle atan2(v_U, v_H).

With ``align_in_motion`` the filter can start levelled but with an unknown heading (a MEMS IMU
cannot gyrocompass), e.g. at a standstill where ZUPT/ZARU calibrate the gyros. Until the first
fix faster than ``align_min_speed_m_s``: no row informs the heading (its H column is removed,
its error state keeps its prior variance without correlations and is not fed back: what an EKF
would learn about a heading tens of degrees off is nonlinear garbage), the position rows absorb
the unknown horizontal lever direction in R, and while moving only the vertical GNSS rows are
used (an INS running in a wrong heading frame would otherwise push its horizontal velocity
errors into the tilts and accelerometer biases). At that fix (``_align_in_motion``) heading,
velocity and position are re-initialised from the fix, the tilt-error covariance is turned with
the heading change, and the horizontal gyro-bias variance is widened by the Earth rate an unknown
heading could hide.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from jaxnav import attitude, geodesy
from jaxnav.core.states import StateLayout
from jaxnav.filter import constraints as cons
from jaxnav.filter import ekf, smoother
from jaxnav.filter.systems import InsSystem, NavSigmas
from jaxnav.ins import errors as ins_errors
from jaxnav.ins import strapdown

#: Names of the row families, in the order of ``Applied``.
ROW_FAMILIES = ("pos", "vel", "nhc", "odo", "zupt", "zaru")


class LooseConfig(eqx.Module):
    """What the loosely coupled filter uses. Flags are static (they set the shapes)."""

    use_pos: bool = eqx.field(static=True, default=True)
    use_vel: bool = eqx.field(static=True, default=True)
    use_nhc: bool = eqx.field(static=True, default=False)
    use_odometer: bool = eqx.field(static=True, default=False)
    estimate_odo_scale: bool = eqx.field(static=True, default=False)
    use_zupt: bool = eqx.field(static=True, default=False)
    use_zaru: bool = eqx.field(static=True, default=False)  # applied with ZUPT on static epochs
    zupt_without_gnss_vel: bool = eqx.field(static=True, default=True)  # S002 sec. 4.2
    cov_substeps: int = eqx.field(static=True, default=1)  # F evaluations per epoch
    # In-motion alignment inside the filter (module docstring); False: nav0 is already aligned.
    align_in_motion: bool = eqx.field(static=True, default=False)
    align_min_speed_m_s: float = 3.0  # chosen: course error sigma_v / v, 1 deg at 3 m/s
    align_sigma_floor_rad: float = 0.02  # chosen: slip / IMU-vehicle yaw misalignment
    align_prior_sigma_rad: float = float(np.pi / np.sqrt(3.0))  # unknown heading: uniform
    pos_cov_scale: float = 1.0  # R = scale * fix covariance (S002 4.24: DOP scaling, no numbers)
    vel_cov_scale: float = 1.0
    nhc_sigma_m_s: Float[ArrayLike, ""] = 1.0  # S003: 1 m/s (a 2-3 deg misalignment at 18-20 m/s)
    odo_sigma_m_s: float = 0.1  # chosen: OBD-II 1 km/h quantum (0.08 m/s rms) + noise
    odo_scale_sigma: float = 0.01  # chosen: 1 % initial scale-factor uncertainty (tyres)
    odo_scale_rw: float = 0.0  # random-walk PSD sqrt [1/sqrt(s)] of the scale (0 = constant)
    zupt_sigma_m_s: Float[ArrayLike, ""] = 0.02  # chosen: residual vibration of a stopped car
    zaru_sigma_rad_s: float | None = None  # None: gyro ARW / sqrt(epoch length)
    zupt_ref_var: float | None = None  # detector's initial reference: None = VRW^2 / dt_imu
    detector: cons.ZuptDetector = eqx.field(default_factory=cons.ZuptDetector)
    vehicle_lever_b: jax.Array = eqx.field(default_factory=lambda: jnp.zeros(3))  # IMU -> axle
    gate_chi2: float = float(np.inf)  # per-row innovation gate (ekf.masked_update)
    # Time-correlated fix position errors (module docstring): None = white (each fix independent)
    fix_bias_tau_s: float | None = eqx.field(static=True, default=None)
    fix_bias_share: float = 1.0  # share of the fix covariance that is correlated (the rest white)


class LooseFilter(eqx.Module):
    """A full-IMU ``InsSystem`` with a loose-coupling configuration."""

    system: InsSystem
    cfg: LooseConfig
    imu_dt_s: float
    epoch_dt_s: float

    @property
    def layout(self) -> StateLayout:
        extra = []
        if self.cfg.use_odometer and self.cfg.estimate_odo_scale:
            extra.append(("odo_scale", 1))
        if self.cfg.fix_bias_tau_s is not None:
            extra.append(("fix_bias", 3))
        return self.system.layout.extend(*extra) if extra else self.system.layout


class GnssFix(NamedTuple):
    """One GNSS solution epoch (PPP or RTK) at the antenna."""

    llh: jnp.ndarray  # [3] lat, lon [rad], h [m]
    cov_pos_enu: jnp.ndarray  # [3, 3] [m^2]
    vel_enu: jnp.ndarray  # [3] [m/s]
    cov_vel_enu: jnp.ndarray  # [3, 3] [m^2/s^2]
    pos_valid: jnp.ndarray  # bool: False withholds the position (outage)
    vel_valid: jnp.ndarray  # bool


class EpochInput(NamedTuple):
    """Everything one epoch consumes (build with ``epoch_inputs``)."""

    samples: strapdown.ImuIncrements  # raw IMU samples over (t_{k-1}, t_k], [K, 3] each
    gnss: GnssFix
    odo_speed_m_s: jnp.ndarray  # odometer reading at t_k
    odo_valid: jnp.ndarray  # bool
    nhc_valid: jnp.ndarray  # bool: False suspends the NHC (e.g. known slip)
    zupt_allowed: jnp.ndarray  # bool: False suspends ZUPT/ZARU even if static is detected


class Applied(NamedTuple):
    """Which row families entered this epoch's update (any of their rows used)."""

    pos: jnp.ndarray
    vel: jnp.ndarray
    nhc: jnp.ndarray
    odo: jnp.ndarray
    zupt: jnp.ndarray
    zaru: jnp.ndarray


class Carry(NamedTuple):
    """Filter memory between epochs."""

    nav: Any  # InsSystem navigation state (NavState, last compensated sample)
    sensors: ins_errors.SensorErrors
    P: jnp.ndarray  # [n, n]
    odo_scale: jnp.ndarray  # running estimate of the odometer scale-factor error
    zupt_ref_var: jnp.ndarray  # detector's adaptive reference variance [m^2/s^4]
    aligned: jnp.ndarray  # bool: heading set (always True without in-motion alignment)
    fix_bias: jnp.ndarray  # [3] estimate of the fix's correlated position error (ENU m)
    fix_cov: jnp.ndarray  # [3, 3] correlated share C of the last valid fix's covariance (ENU m^2)


class EpochOutput(NamedTuple):
    """Per-epoch solution and diagnostics."""

    llh: jnp.ndarray  # [3] IMU position
    vel_enu: jnp.ndarray  # [3]
    euler: jnp.ndarray  # [3] roll, pitch, azimuth
    P_nav: jnp.ndarray  # [9, 9] covariance of pos (rad, rad, m), vel, att
    nis: jnp.ndarray  # normalised innovation squared of the used rows
    dof: jnp.ndarray  # number of used rows
    logdet: jnp.ndarray  # log det of the used rows' innovation covariance (jaxnav.filter.tune)
    applied: Applied
    static: jnp.ndarray  # stationarity detector decision
    zupt_stat: jnp.ndarray  # detector statistic T (variance ratio)
    aligned: jnp.ndarray  # heading initialised (in-motion alignment done)
    sensors: ins_errors.SensorErrors
    odo_scale: jnp.ndarray


# ---- inputs and initialisation ----------------------------------------------------------------
def gnss_fix(llh, vel_enu, sigma_pos_m, sigma_vel_m_s, pos_valid=True, vel_valid=True) -> GnssFix:
    """A fix with isotropic sigmas (broadcasts over leading epoch axes of ``llh``)."""
    llh = jnp.asarray(llh, jnp.float64)
    lead = llh.shape[:-1]
    eye = jnp.eye(3)
    return GnssFix(
        llh,
        jnp.broadcast_to(
            jnp.asarray(sigma_pos_m, jnp.float64)[..., None, None] ** 2 * eye, lead + (3, 3)
        ),
        jnp.asarray(vel_enu, jnp.float64),
        jnp.broadcast_to(
            jnp.asarray(sigma_vel_m_s, jnp.float64)[..., None, None] ** 2 * eye, lead + (3, 3)
        ),
        jnp.broadcast_to(jnp.asarray(pos_valid, bool), lead),
        jnp.broadcast_to(jnp.asarray(vel_valid, bool), lead),
    )


def epoch_inputs(
    samples: strapdown.ImuIncrements,
    gnss: GnssFix,
    odo_speed_m_s=None,
    odo_valid=None,
    nhc_valid=True,
    zupt_allowed=True,
) -> EpochInput:
    """Stack per-epoch inputs; ``samples`` are [E, K, 3]. Missing odometer = invalid."""
    n_ep = samples.dv_b.shape[0]
    if odo_speed_m_s is None:
        odo_speed_m_s = jnp.zeros(n_ep)
        odo_valid = False if odo_valid is None else odo_valid
    odo_valid = True if odo_valid is None else odo_valid
    return EpochInput(
        samples,
        gnss,
        jnp.broadcast_to(jnp.asarray(odo_speed_m_s, jnp.float64), (n_ep,)),
        jnp.broadcast_to(jnp.asarray(odo_valid, bool), (n_ep,)),
        jnp.broadcast_to(jnp.asarray(nhc_valid, bool), (n_ep,)),
        jnp.broadcast_to(jnp.asarray(zupt_allowed, bool), (n_ep,)),
    )


def align_from_gnss(vel_enu, f_b_mean=None):
    """In-motion alignment (module docstring): (roll, pitch, azimuth) from the GNSS velocity.

    azimuth = atan2(v_E, v_N) (course over ground); with ``f_b_mean`` (mean specific force over
    a quiet window) roll = atan2(-f_x, f_z), pitch = atan2(f_y, sqrt(f_x^2 + f_z^2)) (levelling:
    at rest f^b = C_l^b [0, 0, g], i.e. g times the third row of C_b_l = (-cp sr, sp, cp cr));
    otherwise roll = 0, pitch = atan2(v_U, |v_H|).
    """
    vel_enu = jnp.asarray(vel_enu, jnp.float64)
    azimuth = jnp.arctan2(vel_enu[0], vel_enu[1])
    if f_b_mean is None:
        roll = jnp.zeros_like(azimuth)
        pitch = jnp.arctan2(vel_enu[2], jnp.hypot(vel_enu[0], vel_enu[1]))
    else:
        f = jnp.asarray(f_b_mean, jnp.float64)
        roll = jnp.arctan2(-f[0], f[2])
        pitch = jnp.arctan2(f[1], jnp.hypot(f[0], f[2]))
    return jnp.stack([roll, pitch, azimuth])


def alignment_epoch(vel_enu, valid, min_speed_m_s=5.0):
    """First epoch whose valid GNSS horizontal speed exceeds ``min_speed_m_s`` (-1 if none)."""
    speed = jnp.hypot(vel_enu[..., 0], vel_enu[..., 1])
    ok = jnp.asarray(valid, bool) & (speed > min_speed_m_s)
    return jnp.where(jnp.any(ok), jnp.argmax(ok), -1)


def initial_nav(llh, vel_enu, euler_rpa):
    """InsSystem navigation state: the NavState and a zero previous sample (coning/sculling)."""
    z = jnp.zeros(3, jnp.float64)
    return strapdown.InsNav(strapdown.nav_state(llh, vel_enu, euler_rpa),
                            strapdown.ImuIncrements(z, z))


def initial_carry(lf: LooseFilter, nav0, sigmas: NavSigmas | None = None, P0=None) -> Carry:
    """Carry at the start: zero sensor estimates, diagonal P from ``sigmas`` (or ``P0``)."""
    sigmas = NavSigmas() if sigmas is None else sigmas
    layout = lf.layout
    if P0 is None:
        std = jnp.zeros(layout.size)
        std = std.at[: lf.system.layout.size].set(lf.system.initial_std(nav0, sigmas))
        if layout.has("odo_scale"):
            std = std.at[layout.i("odo_scale")].set(lf.cfg.odo_scale_sigma)
        P0 = jnp.diag(std**2)
    return Carry(
        nav=nav0,
        sensors=lf.system.zero_sensors(),
        P=jnp.asarray(P0, jnp.float64),
        odo_scale=jnp.zeros(()),
        zupt_ref_var=jnp.asarray(_ref0_var(lf), jnp.float64),
        aligned=jnp.asarray(not lf.cfg.align_in_motion),
        fix_bias=jnp.zeros(3),
        fix_cov=jnp.zeros((3, 3)),
    )


def _ref0_var(lf: LooseFilter):
    if lf.cfg.zupt_ref_var is not None:
        return lf.cfg.zupt_ref_var
    vrw = jnp.max(jnp.broadcast_to(lf.system.model.accel_vrw_m_s_sqrt_s, (3,)))
    return vrw**2 / lf.imu_dt_s


def _zaru_sigma(lf: LooseFilter):
    if lf.cfg.zaru_sigma_rad_s is not None:
        return lf.cfg.zaru_sigma_rad_s
    arw = jnp.broadcast_to(lf.system.model.gyro_arw_rad_sqrt_s, (3,))
    return arw / jnp.sqrt(lf.epoch_dt_s)


# ---- the epoch step ---------------------------------------------------------------------------
def _propagate_covariance(lf: LooseFilter, layout, nav, mean_inputs, sensors, P, dt):
    """P <- Phi P Phi^T + Qd with the system's F, G, Qc (+ the odometer scale state).
    Returns (P, Phi)."""
    F_s, G_s, Qc_s = lf.system.dynamics(nav, mean_inputs, sensors)
    n_s, n = lf.system.layout.size, layout.size
    F, G, Qc = F_s, G_s, Qc_s
    if n != n_s:  # extension states: zero dynamics here (the fix bias is propagated exactly
        # in _propagate_fix_bias, once per epoch); the odometer scale is a random walk
        F = jnp.zeros((n, n)).at[:n_s, :n_s].set(F_s)
        m = G_s.shape[1]
        G = jnp.zeros((n, m + 1)).at[:n_s, :m].set(G_s)
        Qc = jnp.zeros((m + 1, m + 1)).at[:m, :m].set(Qc_s)
        if layout.has("odo_scale"):
            G = G.at[layout.i("odo_scale"), m].set(1.0)
            Qc = Qc.at[m, m].set(lf.cfg.odo_scale_rw**2)
    Phi, Qd = ekf.discretize(F, G, Qc, dt, squarings=0)  # INS: ||F dt|| << 1 per substep
    _, P = ekf.predict(jnp.zeros(n), P, Phi, Qd)
    return P, Phi


def _propagate_fix_bias(lf: LooseFilter, layout, P, carry: Carry, fix: GnssFix):
    """One epoch of the fix-bias process (module docstring): b <- A b with A = rho diag(min(1,
    C_k,ii / C_k-1,ii)), the rows and columns of b in P transformed with A, plus
    Q_k = [C_k - A C_k-1 A]+ (positive part), so that Var(b_k) follows C_k (held through
    invalid fixes). Returns (b, P, C_k, scale): ``scale`` the diagonal transition of the
    error state (A on the b block, 1 elsewhere)."""
    b = layout.sl("fix_bias")
    rho = jnp.exp(-lf.epoch_dt_s / lf.cfg.fix_bias_tau_s)
    C_prev = carry.fix_cov
    C_new = lf.cfg.fix_bias_share * lf.cfg.pos_cov_scale * fix.cov_pos_enu
    C_k = jnp.where(fix.pos_valid, C_new, C_prev)
    d_prev, d_now = jnp.diag(C_prev), jnp.diag(C_k)
    shrink = jnp.where(d_prev > d_now, d_now / jnp.where(d_prev > 0.0, d_prev, 1.0), 1.0)
    a = rho * shrink
    w, U = jnp.linalg.eigh(C_k - a[:, None] * C_prev * a[None, :])
    Q = (U * jnp.maximum(w, 0.0)) @ U.T
    scale = jnp.ones(layout.size).at[b].set(a)
    P = P * scale[:, None] * scale[None, :]
    P = P.at[b, b].add(Q)
    return a * carry.fix_bias, P, C_k, scale


def _align_fix_bias(layout, P, fix_bias, fix_cov, C_b, C_fix, llh_fix, now):
    """At the in-motion alignment the position is set from the fix, so its error is the fix's
    error: with b_hat = 0, the position error equals -db exactly. Var(b) = C_b (the new
    ``fix_cov``), the position-bias covariance -A C_b (A: ENU metres to the (lat, lon, h) error
    units), the position block the full A C_fix A^T; without the cross term the filter would
    take the two for independent and halve a variance it cannot reduce. Returns (b, P, C,
    reset): ``reset`` flags the re-initialised error states (position and b, when ``now``)."""
    b, pos = layout.sl("fix_bias"), layout.sl("pos")
    A = jnp.linalg.inv(geodesy.llh_error_to_enu_matrix(llh_fix))
    P_new = P.at[b, :].set(0.0).at[:, b].set(0.0).at[b, b].set(C_b)
    P_new = P_new.at[pos, b].set(-A @ C_b).at[b, pos].set(-(A @ C_b).T)
    P_new = P_new.at[pos, pos].set(A @ C_fix @ A.T)
    idx = jnp.arange(P.shape[0])
    reset = now & (((idx >= b.start) & (idx < b.stop)) | ((idx >= pos.start) & (idx < pos.stop)))
    return (jnp.where(now, 0.0, fix_bias), jnp.where(now, P_new, P),
            jnp.where(now, C_b, fix_cov), reset)


def _gnss_rows(lf: LooseFilter, layout, rx, fix: GnssFix):
    """Position (ENU metres) and velocity (ENU) rows of the antenna against the fix."""
    cfg = lf.cfg
    llh_ant = rx.llh
    # The antenna Jacobian w.r.t. dx in geodetic units: the system gives d(pos_ecef)/d(dx) =
    # L J_llh with L = geodesy.llh_to_ecef_jacobian, so J_llh = L^-1 J_pos exactly.
    L = geodesy.llh_to_ecef_jacobian(llh_ant)
    J_llh = jnp.linalg.solve(L, rx.J_pos)
    to_enu = geodesy.llh_error_to_enu_matrix(llh_ant)
    dllh = llh_ant - fix.llh
    dllh = dllh.at[1].set(attitude.wrap_angle(dllh[1]))
    white = 1.0 if cfg.fix_bias_tau_s is None else 1.0 - cfg.fix_bias_share
    pos = cons.constraint_rows(
        to_enu @ dllh, to_enu @ J_llh, white * cfg.pos_cov_scale * fix.cov_pos_enu,
        jnp.full(3, fix.pos_valid),
    )
    C_e_l = geodesy.C_l_e(llh_ant[0], llh_ant[1]).T
    vel = cons.constraint_rows(
        C_e_l @ rx.vel_ecef - fix.vel_enu, C_e_l @ rx.J_vel, cfg.vel_cov_scale * fix.cov_vel_enu,
        jnp.full(3, fix.vel_valid),
    )
    return pos, vel


def _align_in_motion(lf: LooseFilter, layout, nav, P, fix: GnssFix, aligned):
    """In-motion alignment, once the GNSS horizontal speed exceeds ``align_min_speed_m_s``.

    azimuth <- course over ground (roll and pitch kept); velocity <- the fix's; position <- the
    fix moved from the antenna to the IMU with the new attitude. The position, velocity and
    heading error states restart from the fix's variances and sigma_course^2 + floor^2 (course
    variance = horizontal velocity variance / speed^2), their correlations cleared; that epoch's
    fix is then not used again as a measurement. The tilt errors are carried over: the estimate
    turns about the up axis by M = C_new C_old^T, so the ENU tilt-error components turn with it
    (eps_new = M eps_old; the body-frame roll/pitch errors, and hence their correlation with the
    accelerometer biases learnt while levelling, are unchanged). The antenna velocity is taken
    for the IMU's (the lever-arm rotation term is neglected: the vehicle is starting off, not
    turning hard). Returns (nav, P, aligned, aligned_now, Phi): ``Phi`` the error state's
    transition through the alignment (the tilt rotation T, the rows of the restarted states
    zero; the identity on epochs without it).
    """
    state, prev = nav.state, nav.prev
    speed_h = jnp.hypot(fix.vel_enu[0], fix.vel_enu[1])
    do = ~aligned & fix.vel_valid & fix.pos_valid & (speed_h > lf.cfg.align_min_speed_m_s)
    euler = attitude.euler_from_quat(state.q_b_l)
    course = jnp.arctan2(fix.vel_enu[0], fix.vel_enu[1])
    q_new = attitude.quat_from_euler(euler.at[2].set(course))
    lever_l = attitude.dcm_from_quat(q_new) @ lf.system.lever_b
    llh_imu = fix.llh - geodesy.llh_rate_matrix(fix.llh) @ lever_l
    new_state = strapdown.NavState(llh_imu, fix.vel_enu, q_new)
    state = jax.tree.map(lambda a, b: jnp.where(do, b, a), state, new_state)

    m_north, m_east, _ = geodesy.metres_per_radian(fix.llh)
    var_pos = jnp.diag(fix.cov_pos_enu) / jnp.stack([m_east, m_north, 1.0]) ** 2  # E, N, U
    var_course = jnp.trace(fix.cov_vel_enu[:2, :2]) / jnp.maximum(speed_h, 1e-3) ** 2
    k = _heading_index(layout)
    pos, vel = layout.sl("pos"), layout.sl("vel")
    idx = jnp.arange(layout.size)
    flags = (idx == k) | ((idx >= pos.start) & (idx < vel.stop))  # pos and vel are adjacent
    var = jnp.zeros(layout.size).at[k].set(var_course + lf.cfg.align_sigma_floor_rad**2)
    var = var.at[pos].set(var_pos[jnp.array([1, 0, 2])])  # (lat, lon, h) order
    var = var.at[vel].set(jnp.diag(fix.cov_vel_enu))
    att = layout.sl("att")
    M = attitude.dcm_from_quat(q_new) @ attitude.dcm_from_quat(nav.state.q_b_l).T
    T = jnp.eye(layout.size).at[att, att].set(M)
    _, P_new = ekf.reset_states(jnp.zeros(layout.size), T @ P @ T.T, flags, var)
    # With the heading unknown, a horizontal gyro bias and the horizontal Earth rate projected
    # through the wrong heading were indistinguishable at standstill (ZARU, levelling): widen
    # the body x, y gyro-bias variance by (w_ie cos(lat))^2 to cover what was absorbed.
    name = "gyro_bias_ton" if layout.has("gyro_bias_ton") else "gyro_bias"
    if layout.has(name):
        w_h2 = (geodesy.OMEGA_E * jnp.cos(state.llh[0])) ** 2
        xy = jnp.arange(layout.sl(name).start, layout.sl(name).start + 2)
        P_new = P_new.at[xy, xy].add(w_h2)
    Phi = jnp.where(do, smoother.reset_rows(T, flags), jnp.eye(layout.size))
    return strapdown.InsNav(state, prev), jnp.where(do, P_new, P), aligned | do, do, Phi


def _heading_index(layout: StateLayout) -> int:
    """Index of eps_up, the heading error for small tilt (third element of the att block)."""
    return layout.sl("att").start + 2


def _unknown_heading_rows(lf: LooseFilter, layout, rows: cons.Rows, aligned):
    """Before the alignment no row may inform the (arbitrary) heading: its column is removed,
    and the GNSS position rows absorb the unknown horizontal direction of the antenna lever
    (variance |l_h|^2 added to the east and north rows, which come first)."""
    k = _heading_index(layout)
    H = rows.H.at[:, k].set(jnp.where(aligned, rows.H[:, k], 0.0))
    lever_h2 = jnp.sum(lf.system.lever_b[:2] ** 2)  # horizontal part for a near-level body
    if not lf.cfg.use_pos:
        return rows._replace(H=H)
    extra = jnp.zeros(rows.size).at[:2].set(jnp.where(aligned, 0.0, lever_h2))
    return rows._replace(H=H, R=rows.R + jnp.diag(jnp.where(rows.mask, extra, 0.0)))


def _forget_heading(lf: LooseFilter, layout, res: ekf.UpdateResult, aligned):
    """Before the alignment the heading estimate is not corrected and its error state keeps the
    prior variance without correlations (what the filter could learn about it is nonlinear)."""
    k = _heading_index(layout)
    flags = jnp.arange(layout.size) == k
    var = jnp.where(flags, lf.cfg.align_prior_sigma_rad**2, 0.0)
    x_f, P_f = ekf.reset_states(res.x, res.P, flags, var)
    return res._replace(x=jnp.where(aligned, res.x, x_f), P=jnp.where(aligned, res.P, P_f))


def epoch_step(lf: LooseFilter, carry: Carry, inp: EpochInput, record: bool = False):
    """One epoch: mechanize, propagate P, detect standstill, masked update, feed back.

    Returns (carry, EpochOutput), or with ``record`` (static) (carry, (EpochOutput,
    smoother.Record)): the epoch's error transition, P-, P+, correction and nominal state for
    the RTS smoother (``run_smoother``)."""
    cfg, system, layout = lf.cfg, lf.system, lf.layout
    n_sub = cfg.cov_substeps
    k = inp.samples.dv_b.shape[0]
    if k % n_sub:
        raise ValueError(f"{k} IMU samples per epoch do not split into {n_sub} substeps")
    chunks = jax.tree.map(lambda a: a.reshape(n_sub, k // n_sub, *a.shape[1:]), inp.samples)
    dt_sub = lf.imu_dt_s * (k // n_sub)

    def substep(c, chunk):
        nav, P, Phi = c
        nav, mean = system.propagate(nav, carry.sensors, chunk, lf.imu_dt_s)
        P, Phi_sub = _propagate_covariance(lf, layout, nav, mean, carry.sensors, P, dt_sub)
        return (nav, P, Phi_sub @ Phi if record else None), mean

    Phi0 = None
    if record:  # a heading forgotten after the last update restarts here (smoother docstring)
        Phi0 = jnp.eye(layout.size)
        if cfg.align_in_motion:
            forgot = (jnp.arange(layout.size) == _heading_index(layout)) & ~carry.aligned
            Phi0 = smoother.reset_rows(Phi0, forgot)
    (nav, P, Phi), means = jax.lax.scan(substep, (carry.nav, carry.P, Phi0), chunks)
    # x_hat <- Phi x_hat for the sensor estimates: Gauss-Markov shares decay (issue 16, defect 4)
    carry = carry._replace(sensors=system.predict_sensors(carry.sensors, dt_sub * n_sub))
    f_mean_b, w_mean_b = means.f_b.mean(0), means.w_ib_b.mean(0)  # epoch means (equal chunks)
    state, last = nav.state, nav.prev
    w_now_b = last.dtheta_b / lf.imu_dt_s  # rate at t_k - dt/2 for the lever-arm terms
    C = state.C_b_l
    lever = cfg.vehicle_lever_b

    # Standstill detection on the raw samples (a bias does not change a variance).
    stat = cons.stationarity_statistics(inp.samples.dv_b, lf.imu_dt_s)
    gate = jnp.where(
        inp.odo_valid & cfg.use_odometer,
        inp.odo_speed_m_s <= cfg.detector.odo_zero_m_s,
        jnp.linalg.norm(state.vel_enu) < cfg.detector.max_ins_speed_m_s,
    )
    static, ref_var, t_stat = cons.detect_stationary(
        stat, carry.zupt_ref_var, _ref0_var(lf), gate, cfg.detector
    )
    zaru_on = static & inp.zupt_allowed  # the gyro information is independent of the GNSS
    zupt_on = zaru_on
    if cfg.zupt_without_gnss_vel and cfg.use_vel:
        zupt_on = zupt_on & ~inp.gnss.vel_valid
    aligned, gnss_ok = carry.aligned, jnp.ones(3, bool)
    if cfg.align_in_motion:
        nav, P, aligned, now, Phi_align = _align_in_motion(lf, layout, nav, P, inp.gnss, aligned)
        Phi = Phi_align @ Phi if record else None
        state = nav.state
        C = state.C_b_l
        # Before the alignment a moving INS runs in an arbitrary heading frame: horizontal GNSS
        # rows would be explained by tilt and accelerometer biases, so only the vertical ones
        # are used (and none at the alignment epoch, whose fix initialised the state).
        gnss_ok = jnp.stack([aligned | static, aligned | static, jnp.asarray(True)]) & ~now

    last_in = jax.tree.map(lambda a: a[-1], means)._replace(f_b=f_mean_b, w_ib_b=w_now_b)
    rx = system.antenna(nav, last_in, carry.sensors, layout)
    pos_rows, vel_rows = _gnss_rows(lf, layout, rx, inp.gnss)
    fix_bias, fix_cov = carry.fix_bias, carry.fix_cov
    if layout.has("fix_bias"):
        # predicted fix = antenna + b_hat, so dz gains b_hat and H gains I on the b block (a
        # floor keeps R regular when the whole fix covariance is b's)
        fix_bias, P, fix_cov, scale = _propagate_fix_bias(lf, layout, P, carry, inp.gnss)
        Phi = scale[:, None] * Phi if record else None
        if cfg.align_in_motion:
            C_fix = cfg.pos_cov_scale * inp.gnss.cov_pos_enu
            fix_bias, P, fix_cov, reset = _align_fix_bias(
                layout, P, fix_bias, fix_cov, cfg.fix_bias_share * C_fix, C_fix, inp.gnss.llh, now
            )
            Phi = smoother.reset_rows(Phi, reset) if record else None
        pos_rows = pos_rows._replace(
            dz=pos_rows.dz + fix_bias,
            H=pos_rows.H.at[:, layout.sl("fix_bias")].set(jnp.eye(3)),
            R=pos_rows.R + 1e-6 * jnp.eye(3),
        )
    families = {
        "pos": pos_rows._replace(mask=pos_rows.mask & gnss_ok & cfg.use_pos),
        "vel": vel_rows._replace(mask=vel_rows.mask & gnss_ok & cfg.use_vel),
    }
    if cfg.use_nhc:
        families["nhc"] = cons.nhc_rows(
            layout,
            state.llh,
            state.vel_enu,
            C,
            w_now_b,
            lever,
            cfg.nhc_sigma_m_s,
            inp.nhc_valid,
        )
    if cfg.use_odometer:
        families["odo"] = cons.odometer_rows(
            layout,
            state.llh,
            state.vel_enu,
            C,
            w_now_b,
            lever,
            inp.odo_speed_m_s,
            cfg.odo_sigma_m_s,
            inp.odo_valid,
            carry.odo_scale,
        )
    if cfg.use_zupt:
        families["zupt"] = cons.zupt_rows(layout, state.vel_enu, cfg.zupt_sigma_m_s, zupt_on)
        if cfg.use_zaru:
            families["zaru"] = cons.zaru_rows(
                layout, state.llh, C, w_mean_b, _zaru_sigma(lf), zaru_on
            )
    names = list(families)
    rows = cons.sanitize(cons.stack_rows(*families.values()))
    if cfg.align_in_motion:
        rows = _unknown_heading_rows(lf, layout, rows, aligned)
    res = ekf.masked_update(
        jnp.zeros(layout.size), P, rows.dz, rows.H, rows.R, rows.mask, cfg.gate_chi2
    )
    res_update = res
    if cfg.align_in_motion:
        res = _forget_heading(lf, layout, res, aligned)

    nav, sensors = system.feedback(nav, carry.sensors, res.x, layout)
    odo_scale = carry.odo_scale
    if layout.has("odo_scale"):
        odo_scale = odo_scale - res.x[layout.i("odo_scale")]
    if layout.has("fix_bias"):
        fix_bias = fix_bias - res.x[layout.sl("fix_bias")]

    applied, start = {}, 0
    for name in names:
        size = families[name].size
        applied[name] = jnp.any(res.used[start : start + size])
        start += size
    applied = Applied(*(applied.get(f, jnp.zeros((), bool)) for f in ROW_FAMILIES))
    n_nav = layout.sl("att").stop
    out = EpochOutput(
        llh=system.llh(nav),
        vel_enu=system.vel_enu(nav),
        euler=system.euler(nav),
        P_nav=res.P[:n_nav, :n_nav],
        nis=res.nis,
        dof=res.dof,
        logdet=res.logdet,
        applied=applied,
        static=static,
        zupt_stat=t_stat,
        aligned=aligned,
        sensors=sensors,
        odo_scale=odo_scale,
    )
    new = Carry(nav, sensors, res.P, odo_scale, ref_var, aligned, fix_bias, fix_cov)
    if record:
        rec = smoother.Record(Phi, P, res_update.P, res.x, nav, sensors,
                              x_post=res_update.x - res.x)
        return new, (out, rec)
    return new, out


def run(lf: LooseFilter, carry: Carry, inputs: EpochInput):
    """Scan ``epoch_step`` over stacked epochs; returns (final carry, stacked EpochOutput)."""
    return jax.lax.scan(lambda c, i: epoch_step(lf, c, i), carry, inputs)


def run_smoother(lf: LooseFilter, carry: Carry, inputs: EpochInput, n_valid=None):
    """Forward filter and RTS smoother (``jaxnav.filter.smoother``) over stacked epochs.

    Returns (forward EpochOutput, smoothed EpochOutput): the smoothed one has the forward
    nominal of each epoch with the smoothed error dx^s fed back (position, velocity, attitude,
    sensor estimates, odometer scale) and P_nav from P^s; its NIS, dof, applied rows and
    detector outputs are the forward pass's (a smoother has no innovations of its own).
    Memory: the forward pass keeps 3 n^2 + O(n) float64 per epoch (smoother module docstring).
    """
    _, (out, rec) = jax.lax.scan(lambda c, i: epoch_step(lf, c, i, record=True), carry, inputs)
    return out, smoothed_outputs(lf, out, rec, n_valid)


def smoothed_outputs(lf: LooseFilter, out: EpochOutput, rec: smoother.Record,
                     n_valid=None) -> EpochOutput:
    """The forward outputs with the RTS-smoothed states and covariances in place (``n_valid``:
    ``smoother.error_state``)."""
    layout = lf.layout
    dx_s, P_s = smoother.error_state(rec, n_valid)
    n_nav = layout.sl("att").stop

    def one(nav, sensors, dx):
        nav_s, sensors_s = lf.system.feedback(nav, sensors, dx, layout)
        return lf.system.llh(nav_s), lf.system.vel_enu(nav_s), lf.system.euler(nav_s), sensors_s

    llh, vel, euler, sensors = jax.vmap(one)(rec.nav, rec.sensors, dx_s)
    odo_scale = out.odo_scale
    if layout.has("odo_scale"):
        odo_scale = odo_scale - dx_s[:, layout.i("odo_scale")]
    return out._replace(llh=llh, vel_enu=vel, euler=euler, P_nav=P_s[:, :n_nav, :n_nav],
                        sensors=sensors, odo_scale=odo_scale)


# ---- helpers for simulation studies -----------------------------------------------------------
def imu_error_model(grade) -> ins_errors.ImuErrorModel:
    """The filter's ``ImuErrorModel`` matching a simulator ``ImuGrade`` (``jaxnav.sim.sensors``).

    Bias drifts are the grade's GM parts, turn-on biases its random constants. The filter has one
    scale-factor state per triad: its sigma is the root-sum-square of the grade's constant and
    GM parts, with the GM correlation time when there is a GM part (else a random constant).
    Used with INS27 the filter's model is the simulator's exactly (INS15/21 lump the turn-on
    bias into the GM state, see ``ins.errors.sensor_initial_std``).
    """

    def scale(ton, gm, tau):
        sigma = float(np.hypot(ton, gm))
        return sigma, (float(tau) if gm > 0.0 else float(np.inf))

    g = grade
    sa, ta = scale(g.accel_scale_turn_on, g.accel_scale_gm_sigma, g.accel_scale_gm_tau_s)
    sg, tg = scale(g.gyro_scale_turn_on, g.gyro_scale_gm_sigma, g.gyro_scale_gm_tau_s)
    return ins_errors.ImuErrorModel(
        accel_vrw_m_s_sqrt_s=grade.accel_vrw_m_s_sqrt_s,
        gyro_arw_rad_sqrt_s=grade.gyro_arw_rad_sqrt_s,
        accel_bias_sigma_m_s2=grade.accel_bias_gm_sigma_m_s2,
        accel_bias_tau_s=grade.accel_bias_gm_tau_s,
        gyro_bias_sigma_rad_s=grade.gyro_bias_gm_sigma_rad_s,
        gyro_bias_tau_s=grade.gyro_bias_gm_tau_s,
        accel_scale_sigma=sa,
        accel_scale_tau_s=ta,
        gyro_scale_sigma=sg,
        gyro_scale_tau_s=tg,
        accel_bias_ton_sigma_m_s2=grade.accel_bias_turn_on_m_s2,
        gyro_bias_ton_sigma_rad_s=grade.gyro_bias_turn_on_rad_s,
    )
