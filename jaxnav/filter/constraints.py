"""Vehicle constraints and stationary updates for the full IMU: NHC, odometer, ZUPT, ZARU.

Every builder returns measurement ``Rows`` (``core/rows.py``, kind constraint) over a given
state layout, with the jaxnav conventions of ``core/states.py``: dz = h(x_hat) - z, error =
estimated - true, attitude error eps with C_hat = (I - [eps x]) C. They are pure functions of
the navigation quantities, so the filters stack them with the GNSS rows and run one
``ekf.masked_update``.

Vehicle point. The non-holonomic constraint and the odometer refer to the vehicle's no-slip
point (rear-axle centre, where the odometer speed is measured), at body offset ``lever_b`` from
the IMU. Its Earth-referenced velocity is that of a rigidly attached point,

    v_pt^l = v^l + C_b^l (w_ib^b x l^b) - w_ie^l x (C_b^l l^b)       (strapdown.antenna_vel_enu)
    v_pt^b = C_l^b v_pt^l = C_l^b v^l + (w_ib^b - C_l^b w_ie^l) x l^b,

so an IMU ahead of the rear axle sees a lateral velocity w_z l_y in a turn that the constraint
must not reject. With lever_b = 0 the rows reduce to S002 eq 4.28-4.29 (NHC) and S003 eq 8.

First-order error of a body-frame velocity (derived for our eps convention): C_hat^T =
C^T (I + [eps x]), hence

    d(v_pt^b) = C^T d(v_pt^l) + C^T [eps x] v_pt^l = C^T J_vel dx - C^T [v_pt^l x] eps,

with J_vel = d(v_pt^l)/d(dx) from ``ins.errors.antenna_vel_jacobian`` (velocity, attitude, Earth
rate through latitude, gyro bias and scale through the lever-arm term). For lever 0 the attitude
block is -C^T [v x], i.e. row i = -r_i [v x] with r_i the i-th row of C^T: exactly S002 eq 4.28
("delta v^b = R_l^b dv^l - R_l^b (v^l x) dpsi") and its corrected eq 4.29 (SEED_SPEC 4, S002
item 1: the up row uses the third column of R_b^l; (v^l x) is the skew of the velocity, not of
the velocity error). ``tests/test_constraints.py`` checks every H against ``jax.jacfwd`` of the
nonlinear measurement.

ZUPT (S002 eq 4.25-4.26): z = v^l = 0, H = I on velocity. At rest every point of the vehicle is
still, so the lever arm does not enter.

ZARU (zero angular-rate update; standard for land vehicles at standstill, e.g. Groves 2013
"Principles of GNSS, inertial and multisensor integrated navigation", 2nd ed., sec. 15.3.3; not
in the seeds): at rest the true body rate is the Earth rate, w_ib^b = C_l^b w_ie^l, so the mean
compensated gyro output over the epoch minus C_hat^T w_ie^l(lat_hat) observes the remaining
gyro bias (and scale error) directly:

    dz = mean(w_used) - C_hat^T w_ie(lat_hat),   H = I (gyro bias, turn-on), diag(w) (scale),
         C^T [w_ie x] (attitude), -C^T d(w_ie)/d(lat) (latitude).

Its noise is the angle random walk averaged over the window, ARW / sqrt(T). The same gyro noise
also drove the attitude random walk of that epoch, a process/measurement correlation the filter
ignores (the effect is of order ARW^2 T, negligible next to the bias uncertainty it removes).

Stationarity detector (S002 sec. 4.2: "the variance of the forward acceleration is compared with
a threshold that starts from a predefined value and is refined online"; the seed gives no
numbers, the details here are chosen). Over the epoch's K IMU samples, with f_k = dv_k / dt:

    T = max(var(f_forward), var(|f|)) / ref_var,       static if T < threshold (default 2.5),

where ref_var is the variance of the specific force at rest. At rest with white sensor noise of
variance s^2 per axis both sample variances are s^2 (1 +- sqrt(2/(K-1))), so T ~ 1; any
manoeuvre adds the variance of the true forward acceleration within the window. ref_var starts
at VRW^2 / dt (datasheet velocity random walk) and, whenever a window is declared static, moves
towards the measured variance (exponential forgetting, rate ``adapt_rate``), clipped to
[ref0 / ref_span, ref0 * ref_span] so that a misdetection cannot run away with it. Because a
vehicle cruising on a perfectly smooth road (and every simulated drive) has no vibration, the
variance test alone cannot tell cruising from standing; it is therefore combined with a speed
gate: the odometer reading <= ``odo_zero_m_s`` when an odometer is available, otherwise the INS
speed below ``max_ins_speed_m_s``.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp

from jaxnav import attitude, geodesy
from jaxnav.core.rows import (  # noqa: F401  (stack_rows, sanitize: for the filters)
    Rows,
    constraint_rows,
    sanitize,
    stack_rows,
)
from jaxnav.core.states import StateLayout
from jaxnav.ins import errors as ins_errors
from jaxnav.ins import strapdown

#: Body axes of the NHC rows: x = lateral (right), z = up (S002 eq 4.27; y is forward).
NHC_AXES = (0, 2)
FORWARD_AXIS = 1


# ---- body velocity of the vehicle point -------------------------------------------------------
def vehicle_velocity_b(llh, vel_enu, C_b_l, w_ib_b, lever_b):
    """Body-frame Earth-referenced velocity of the point at ``lever_b`` (module docstring):
    v_pt^b = C_l^b v^l + (w_ib^b - C_l^b w_ie^l) x l^b."""
    v_pt_l = strapdown.antenna_vel_enu(llh, vel_enu, C_b_l, w_ib_b, lever_b)
    return C_b_l.T @ v_pt_l


def vehicle_velocity_jacobian(layout: StateLayout, llh, vel_enu, C_b_l, w_ib_b, lever_b):
    """d(v_pt^b)/d(dx) = C^T J_vel - C^T [v_pt^l x] on the attitude block. Shape (3, n)."""
    v_pt_l = strapdown.antenna_vel_enu(llh, vel_enu, C_b_l, w_ib_b, lever_b)
    J_vel = ins_errors.antenna_vel_jacobian(layout, llh, vel_enu, C_b_l, w_ib_b, lever_b)
    H = C_b_l.T @ J_vel
    return H.at[:, layout.sl("att")].add(-C_b_l.T @ attitude.skew(v_pt_l))


def nhc_rows(
    layout: StateLayout, llh, vel_enu, C_b_l, w_ib_b, lever_b, sigma_m_s=1.0, enabled=True
) -> Rows:
    """Non-holonomic constraint (S002 eq 4.27-4.29 corrected, S003 eq 8): lateral and vertical
    body velocity of the vehicle point = 0, noise ``sigma_m_s`` (S003: 1 m/s). Two rows."""
    v_b = vehicle_velocity_b(llh, vel_enu, C_b_l, w_ib_b, lever_b)
    H = vehicle_velocity_jacobian(layout, llh, vel_enu, C_b_l, w_ib_b, lever_b)
    axes = jnp.array(NHC_AXES)
    sig = jnp.broadcast_to(jnp.asarray(sigma_m_s, jnp.float64), (2,))
    return constraint_rows(v_b[axes], H[axes], jnp.diag(sig**2), jnp.full(2, enabled))


def odometer_rows(
    layout: StateLayout,
    llh,
    vel_enu,
    C_b_l,
    w_ib_b,
    lever_b,
    speed_m_s,
    sigma_m_s=0.1,
    enabled=True,
    odo_scale=0.0,
) -> Rows:
    """Odometer speed: z = (1 + s) v_fwd + n, h = (1 + s_hat) v_pt,y^b. One row.

    ``odo_scale`` is the running estimate s_hat of the odometer scale-factor error; when the
    layout has an ``odo_scale`` block, its column is v_fwd (error ds = s_hat - s).
    """
    v_b = vehicle_velocity_b(llh, vel_enu, C_b_l, w_ib_b, lever_b)
    J = vehicle_velocity_jacobian(layout, llh, vel_enu, C_b_l, w_ib_b, lever_b)
    k = 1.0 + odo_scale
    dz = k * v_b[FORWARD_AXIS] - speed_m_s
    H = k * J[FORWARD_AXIS]
    if layout.has("odo_scale"):
        H = H.at[layout.i("odo_scale")].set(v_b[FORWARD_AXIS])
    sig = jnp.asarray(sigma_m_s, jnp.float64)
    return constraint_rows(jnp.reshape(dz, (1,)), H[None, :], jnp.reshape(sig**2, (1, 1)),
                           jnp.full(1, enabled))


def zupt_rows(layout: StateLayout, vel_enu, sigma_m_s=0.02, enabled=True) -> Rows:
    """Zero-velocity update (S002 eq 4.25-4.26): dz = v^l - 0, H = [0, I, 0]. Three rows."""
    H = jnp.zeros((3, layout.size), jnp.float64).at[:, layout.sl("vel")].set(jnp.eye(3))
    sig = jnp.broadcast_to(jnp.asarray(sigma_m_s, jnp.float64), (3,))
    return constraint_rows(vel_enu, H, jnp.diag(sig**2), jnp.full(3, enabled))


def zaru_rows(layout: StateLayout, llh, C_b_l, w_mean_b, sigma_rad_s, enabled=True) -> Rows:
    """Zero angular-rate update at standstill (module docstring): dz = mean(w_used) - C^T w_ie.

    ``w_mean_b`` is the mean compensated gyro rate over the stationary window. Three rows.
    """
    w_ie = geodesy.earth_rate_enu(llh[0])
    dz = w_mean_b - C_b_l.T @ w_ie
    # d(w_ie)/d(lat): [0, -we sin(lat), we cos(lat)] (longitude and height do not enter).
    dwie_dlat = geodesy.OMEGA_E * jnp.stack(
        [jnp.zeros_like(llh[0]), -jnp.sin(llh[0]), jnp.cos(llh[0])]
    )
    H = jnp.zeros((3, layout.size), jnp.float64)
    H = H.at[:, layout.sl("pos").start].set(-C_b_l.T @ dwie_dlat)
    H = H.at[:, layout.sl("att")].set(C_b_l.T @ attitude.skew(w_ie))
    for name in ("gyro_bias", "gyro_bias_ton"):
        if layout.has(name):
            H = H.at[:, layout.sl(name)].set(jnp.eye(3))
    if layout.has("gyro_scale"):
        H = H.at[:, layout.sl("gyro_scale")].set(jnp.diag(w_mean_b))
    sig = jnp.broadcast_to(jnp.asarray(sigma_rad_s, jnp.float64), (3,))
    return constraint_rows(dz, H, jnp.diag(sig**2), jnp.full(3, enabled))


# ---- stationarity detector --------------------------------------------------------------------
class ZuptDetector(eqx.Module):
    """Stationarity test parameters (module docstring; every number chosen, S002 gives none)."""

    threshold: float = 2.5  # T = sample variance / reference variance; ~1 at rest
    adapt_rate: float = 0.1  # forgetting factor of the reference variance on static windows
    ref_span: float = 4.0  # reference kept within [ref0 / span, ref0 * span]
    max_ins_speed_m_s: float = 1.0  # speed gate without odometer
    odo_zero_m_s: float = 0.05  # speed gate with odometer (a wheel at rest gives no pulses)


class Stationarity(NamedTuple):
    """Per-epoch detector statistics over the window."""

    var_forward: jnp.ndarray  # variance of the forward specific force [m^2/s^4]
    var_norm: jnp.ndarray  # variance of |f| [m^2/s^4]


def stationarity_statistics(dv_b, dt) -> Stationarity:
    """Sample variances of f_forward and |f| over the window's increments ``dv_b`` [K, 3]."""
    f = dv_b / dt
    f_norm = jnp.linalg.norm(f, axis=1)
    return Stationarity(jnp.var(f[:, FORWARD_AXIS], ddof=1), jnp.var(f_norm, ddof=1))


def detect_stationary(
    stat: Stationarity,
    ref_var,
    ref0_var,
    speed_gate_open,
    det: ZuptDetector,
):
    """Decide stationarity and adapt the reference variance.

    static = max(var_fwd, var_norm) / ref_var < threshold and the speed gate is open; on a static
    window ref_var <- ref_var + adapt_rate (measured - ref_var), clipped around ``ref0_var``.
    Returns (static, new ref_var, test statistic).
    """
    measured = jnp.maximum(stat.var_forward, stat.var_norm)
    t = measured / ref_var
    static = (t < det.threshold) & speed_gate_open
    adapted = ref_var + det.adapt_rate * (measured - ref_var)
    adapted = jnp.clip(adapted, ref0_var / det.ref_span, ref0_var * det.ref_span)
    return static, jnp.where(static, adapted, ref_var), t
