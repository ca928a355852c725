"""Full-IMU strapdown mechanization in the local-level ENU frame with quaternion attitude.

Continuous model (SEED_SPEC 1.2, S002 eq 3.3), position geodetic, velocity ENU:

    llh'   = D^-1 v^l
    v^l'   = C_b^l f^b - (2 w_ie^l + w_el^l) x v^l + g^l
    C_b^l' = C_b^l [w_ib^b x] - [w_il^l x] C_b^l,       w_il^l = w_ie^l + w_el^l

Discrete algorithm (one IMU sample per attitude/velocity/position update, after Savage,
"Strapdown inertial navigation integration algorithm design", JGCD 21(1-2), 1998, and
Titterton & Weston, ch. 11), driven by the increments of the shared IMU data contract
(sample k integrates w_ib^b and f^b over (t_{k-1}, t_k]):

- Body attitude: rotation vector phi = dtheta_k + (1/12) dtheta_{k-1} x dtheta_k (two-sample,
  "previous-sample" coning correction, exact to third order for a linearly varying rate).
- Navigation-frame rotation: zeta = w_il^l(mid) dt, so q_b_l <- q(-zeta) (x) q_b_l (x) q(phi).
- Specific-force increment in the body frame at t_{k-1}:
  dv_sf^b = dv_k + 1/2 dtheta_k x dv_k + 1/6 dtheta_k x (dtheta_k x dv_k)   (rotation)
          + 1/12 (dtheta_{k-1} x dv_k + dv_{k-1} x dtheta_k)   (previous-sample sculling),
  then dv_sf^l = C_b^l(t_{k-1}) dv_sf^b plus the l-frame rotation terms in zeta to second
  order (``_velocity_position``).
- Velocity: v_k = v_{k-1} + dv_sf^l + (g^l - (2 w_ie^l + w_el^l) x v^l)(mid) dt.
- Position: trapezoidal in the velocity (local error O(dt^3)), h first, then latitude and
  longitude with the radii at mid-interval.
"mid" values (position, velocity at t_{k-1/2}) come from one predictor pass with the
start-of-interval values, which makes the gravity/Coriolis/transport terms second-order accurate.
Accuracy with exact increments (tests/test_strapdown.py): at rest, < 2e-7 m (level) in 1 h at
100 Hz; for 10 min of aggressive 3D motion (up to 150 m/s), 4e-5 m / 8e-8 m/s / 3e-10 rad against
an independent RK4 solution of the continuous equations, converging faster than O(dt^2).

Everything is a pure function over NamedTuples of float64 arrays: ``mechanize`` is one
``lax.scan``; ``jax.vmap`` over it for Monte-Carlo batches.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav import attitude, geodesy


class NavState(NamedTuple):
    """Navigation state: geodetic position, ENU velocity, attitude quaternion body -> ENU."""

    llh: Float[Array, "3"]  # (lat [rad], lon [rad], h [m])
    vel_enu: Float[Array, "3"]  # (v_east, v_north, v_up) [m/s]
    q_b_l: Float[Array, "4"]  # Hamilton scalar-first unit quaternion, v^l = q (x) v^b (x) q*

    @property
    def C_b_l(self) -> Float[Array, "3 3"]:
        """DCM body -> ENU of ``q_b_l``."""
        return attitude.dcm_from_quat(self.q_b_l)


class ImuIncrements(NamedTuple):
    """IMU sample(s): integrals of w_ib^b and f^b over (t_{k-1}, t_k]; shape (3,) or (N, 3)."""

    dtheta_b: Float[Array, "*N 3"]  # [rad], body right-forward-up axes
    dv_b: Float[Array, "*N 3"]  # [m/s], body right-forward-up axes


class InsNav(eqx.Module):
    """The full INS's navigation state between epochs: the strapdown state and the last corrected
    IMU sample (the next step's coning / sculling and trapezoidal terms read it)."""

    state: NavState
    prev: ImuIncrements


def nav_state(
    llh: Float[ArrayLike, "3"], vel_enu: Float[ArrayLike, "3"], euler_rpa: Float[ArrayLike, "3"]
) -> NavState:
    """Build a NavState from (roll, pitch, azimuth) [rad] (attitude.py conventions)."""
    return NavState(
        jnp.asarray(llh, jnp.float64),
        jnp.asarray(vel_enu, jnp.float64),
        attitude.quat_from_euler(jnp.asarray(euler_rpa, jnp.float64)),
    )


def nav_rate(
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    C_b_l: Float[ArrayLike, "3 3"],
    f_b: Float[ArrayLike, "3"],
    w_ib_b: Float[ArrayLike, "3"],
) -> tuple[Float[Array, "3"], Float[Array, "3"], Float[Array, "3 3"]]:
    """Continuous INS dynamics (S002 eq 3.3): returns (llh', v^l', C_b^l').

    llh' = D^-1 v; v' = C f - (2 w_ie + w_el) x v + g; C' = C [w_ib x] - [w_il x] C, which is
    C (W_ib - W_il^b) with W_il^b = C^T [w_il x] C.
    """
    w_ie = geodesy.earth_rate_enu(llh[0])
    w_el = geodesy.transport_rate_enu(llh, vel_enu)
    llh_dot = geodesy.llh_rate_matrix(llh) @ vel_enu
    vel_dot = C_b_l @ f_b - jnp.cross(2.0 * w_ie + w_el, vel_enu) + geodesy.gravity_enu(llh)
    C_dot = C_b_l @ attitude.skew(w_ib_b) - attitude.skew(w_ie + w_el) @ C_b_l
    return llh_dot, vel_dot, C_dot


def coning_rotvec(prev_imu: ImuIncrements, imu: ImuIncrements, coning: bool = True):
    """Body rotation vector over the sample: phi = dth_k + (1/12) dth_{k-1} x dth_k (Savage)."""
    phi = imu.dtheta_b
    if coning:
        phi = phi + jnp.cross(prev_imu.dtheta_b, imu.dtheta_b) / 12.0
    return phi


def sculling_dv(prev_imu: ImuIncrements, imu: ImuIncrements, sculling: bool = True):
    """Body-frame (at t_{k-1}) specific-force increment with rotation and sculling terms.

    dv_sf = dv_k + 1/2 dth_k x dv_k + 1/6 dth_k x (dth_k x dv_k)          (rotation compensation)
          + 1/12 (dth_{k-1} x dv_k + dv_{k-1} x dth_k)   (Savage's previous-sample sculling).
    The second-order rotation term is the small-angle series of Savage's exact constant-rate
    form ((1 - sin a / a) / a^2 with a = |dth|); without it a vehicle turning at 0.05 rad/s
    about a horizontal axis accrues ~4e-7 m/s^2 of vertical acceleration error at 100 Hz.
    ``sculling=False`` drops only the 1/12 sculling term; it exists to quantify the correction.
    """
    rot = jnp.cross(imu.dtheta_b, imu.dv_b)
    dv = imu.dv_b + 0.5 * rot + jnp.cross(imu.dtheta_b, rot) / 6.0
    if sculling:
        dv = (
            dv
            + (jnp.cross(prev_imu.dtheta_b, imu.dv_b) + jnp.cross(prev_imu.dv_b, imu.dtheta_b))
            / 12.0
        )
    return dv


def _wrap_lon(lon):
    # One conditional shift keeps lon in (-pi, pi] without the round-off of atan2(sin, cos).
    return jnp.where(
        lon > jnp.pi, lon - 2.0 * jnp.pi, jnp.where(lon <= -jnp.pi, lon + 2.0 * jnp.pi, lon)
    )


def _velocity_position(
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    C_b_l: Float[Array, "3 3"],
    imu: ImuIncrements,
    dv_sf_b: Float[Array, "3"],
    dt: Float[ArrayLike, ""],
    llh_mid: Float[ArrayLike, "3"],
    vel_mid: Float[ArrayLike, "3"],
) -> tuple[Float[Array, "3"], Float[Array, "3"], Float[Array, "3"]]:
    """Velocity and trapezoidal position update with gravity/Coriolis evaluated at mid-interval."""
    w_ie = geodesy.earth_rate_enu(llh_mid[0])
    w_el = geodesy.transport_rate_enu(llh_mid, vel_mid)
    zeta = (w_ie + w_el) * dt
    # The l-frame turns by zeta over the interval. For constant rates the exact increment is
    # int_0^1 exp(-s[zeta x]) C exp(s[dth x]) dv ds; its zeta terms to second order are
    # -1/2 zeta x u - 1/3 zeta x C(dth x dv) + 1/6 zeta x (zeta x u), u = C dv, which makes a
    # body at rest in the l-frame (C dth = zeta) integrate exactly C dv.
    u = C_b_l @ imu.dv_b
    u_rot = C_b_l @ jnp.cross(imu.dtheta_b, imu.dv_b)
    dv_sf_l = (
        C_b_l @ dv_sf_b
        - 0.5 * jnp.cross(zeta, u)
        - jnp.cross(zeta, u_rot) / 3.0
        + jnp.cross(zeta, jnp.cross(zeta, u)) / 6.0
    )
    dv_cor = (geodesy.gravity_enu(llh_mid) - jnp.cross(2.0 * w_ie + w_el, vel_mid)) * dt
    vel_new = vel_enu + dv_sf_l + dv_cor

    v_avg = 0.5 * (vel_enu + vel_new)
    h_new = llh[2] + v_avg[2] * dt
    h_mid = 0.5 * (llh[2] + h_new)
    r_m, _ = geodesy.radii(llh_mid[0])
    lat_new = llh[0] + v_avg[1] * dt / (r_m + h_mid)
    lat_mid = 0.5 * (llh[0] + lat_new)
    _, r_n = geodesy.radii(lat_mid)
    lon_new = llh[1] + v_avg[0] * dt / ((r_n + h_mid) * jnp.cos(lat_mid))
    return jnp.stack([lat_new, lon_new, h_new]), vel_new, zeta


def mechanize_step(
    nav: NavState,
    prev_imu: ImuIncrements,
    imu: ImuIncrements,
    dt: Float[ArrayLike, ""],
    *,
    coning: bool = True,
    sculling: bool = True,
) -> NavState:
    """One strapdown update over (t_{k-1}, t_k] from sample ``imu`` (module docstring).

    ``prev_imu`` is sample k-1 (feeds the coning and sculling corrections). ``coning`` and
    ``sculling`` are static switches used to quantify the corrections; keep them on.
    """
    C_old = attitude.dcm_from_quat(nav.q_b_l)
    phi_b = coning_rotvec(prev_imu, imu, coning)
    dv_sf_b = sculling_dv(prev_imu, imu, sculling)

    # Predictor: start-of-interval Earth/transport rate and gravity -> rough end state.
    llh_p, vel_p, _ = _velocity_position(
        nav.llh, nav.vel_enu, C_old, imu, dv_sf_b, dt, nav.llh, nav.vel_enu
    )
    llh_mid = nav.llh + 0.5 * (llh_p - nav.llh)
    vel_mid = 0.5 * (nav.vel_enu + vel_p)
    # Corrector: mid-interval values (second order in dt).
    llh_new, vel_new, zeta = _velocity_position(
        nav.llh, nav.vel_enu, C_old, imu, dv_sf_b, dt, llh_mid, vel_mid
    )

    q_new = attitude.quat_multiply(
        attitude.quat_multiply(attitude.quat_from_rotvec(-zeta), nav.q_b_l),
        attitude.quat_from_rotvec(phi_b),
    )
    llh_new = llh_new.at[1].set(_wrap_lon(llh_new[1]))
    return NavState(llh_new, vel_new, attitude.quat_normalize(q_new))


def mechanize(
    nav0: NavState,
    imu_seq: ImuIncrements,
    dt: Float[ArrayLike, ""] | Float[ArrayLike, " N"],
    prev_imu0: ImuIncrements | None = None,
    *,
    coning: bool = True,
    sculling: bool = True,
):
    """Run ``mechanize_step`` over stacked samples (N, 3) with ``lax.scan``.

    ``dt`` is a scalar or an (N,) array of sample intervals. ``prev_imu0`` is the sample before
    ``imu_seq[0]``; by default the first sample itself (i.e. rates assumed constant before the
    start, which makes both corrections vanish on the first step). Returns ``(nav_final,
    nav_history)`` with the history stacked along axis 0 (state after each sample).
    """
    n = imu_seq.dtheta_b.shape[0]
    dt_seq = jnp.broadcast_to(jnp.asarray(dt, jnp.float64), (n,))
    if prev_imu0 is None:
        prev_imu0 = ImuIncrements(imu_seq.dtheta_b[0], imu_seq.dv_b[0])

    def body(carry, inputs):
        nav, prev = carry
        imu, dt_k = inputs
        nav_new = mechanize_step(nav, prev, imu, dt_k, coning=coning, sculling=sculling)
        return (nav_new, imu), nav_new

    (nav_final, _), history = jax.lax.scan(body, (nav0, prev_imu0), (imu_seq, dt_seq))
    return nav_final, history


def stationary_imu(
    llh: Float[ArrayLike, "3"], C_b_l: Float[ArrayLike, "3 3"], dt: Float[ArrayLike, ""]
) -> ImuIncrements:
    """Exact increments of a perfect IMU at rest on the Earth: w_ib^b = C^T w_ie^l, f^b = -C^T g^l.

    Both are constant in the body frame (the body is fixed in the l-frame, which turns at w_ie
    about a fixed axis), so the interval integrals are rate * dt exactly.
    """
    w_ib_b = C_b_l.T @ geodesy.earth_rate_enu(llh[0])
    f_b = -(C_b_l.T @ geodesy.gravity_enu(llh))
    return ImuIncrements(w_ib_b * dt, f_b * dt)


def antenna_llh(
    llh: Float[ArrayLike, "3"], C_b_l: Float[ArrayLike, "3 3"], lever_b: Float[ArrayLike, "3"]
) -> Float[Array, "3"]:
    """Geodetic position of a point at body offset ``lever_b`` [m]: llh + D^-1 C_b^l l^b.

    First order in |l|/R (S001 eq 10, L_p = C_b^n l^b); the neglected curvature term is below
    |l|^2 / R, i.e. < 1 micrometre for levers up to 2.5 m.
    """
    return llh + geodesy.llh_rate_matrix(llh) @ (C_b_l @ lever_b)


def antenna_vel_enu(
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    C_b_l: Float[ArrayLike, "3 3"],
    w_ib_b: Float[ArrayLike, "3"],
    lever_b: Float[ArrayLike, "3"],
) -> Float[Array, "3"]:
    """ENU velocity (Earth-referenced) of the point at body offset ``lever_b``.

    v_ant = v + C_b^l (w_eb^b x l^b) with w_eb^b = w_ib^b - C_l^b w_ie^l, the body rate relative
    to the Earth (the time derivative of C_b^e l^b): exact for the Earth-fixed velocity GNSS
    measures. Written as v + C_b^l (w_ib^b x l^b) - w_ie^l x (C_b^l l^b). (The textbook
    w_lb^b form, S001/SEED_SPEC 1.2, drops w_el x C l, which is < 1e-5 m/s for land vehicles.)
    """
    lever_l = C_b_l @ lever_b
    w_ie = geodesy.earth_rate_enu(llh[0])
    return vel_enu + C_b_l @ jnp.cross(w_ib_b, lever_b) - jnp.cross(w_ie, lever_l)
