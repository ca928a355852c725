"""3D RISS mechanization: odometer speed + one vertical gyro + two horizontal accelerometers.

Seeds: S000 §3.8 (continuous form, eqs 4.1-4.9, 200 Hz) and S002 §3.2.1 (discrete form,
eqs 3.6-3.14, IMU averaged to 1 Hz); SEED_SPEC §1.4.

Frames (jaxnav conventions): body b is right-forward-up (x transverse, y forward, z up), the
local-level frame l is ENU, azimuth A is clockwise from north, position is geodetic
``llh = (lat_rad, lon_rad, h_m)``.

Input contract. ``RissInput`` holds *rates*, one row per sample k covering (t_{k-1}, t_k]:
- ``f_x``, ``f_y`` [m/s^2]: interval-mean transverse / forward specific force = dv_b[k, 0:2] / dt,
- ``w_z`` [rad/s]: interval-mean vertical gyro rate = dtheta_b[k, 2] / dt,
- ``v_od`` [m/s]: odometer speed at t_k (a control input, S000/S002),
- ``a_od`` [m/s^2]: odometer acceleration (v_od[k] - v_od[k-1]) / dt, the backward difference of
  successive speeds. It is exactly the mean vehicle acceleration over the interval, i.e. the same
  average as the accelerometer increments, so f_y - a_od removes the motion term without a lag.
Rates (not raw increments) are used so that the same equations serve 200 Hz (S000) and the
1 Hz averaged data of S002; ``rates_from_increments`` and ``riss_inputs_from_imu`` convert the
shared increment contract, ``average_inputs`` decimates (S002: 100/200 Hz -> 1 Hz).

Mechanization order per sample (S002 eqs 3.6-3.14): pitch and roll from the accelerometers of
the same sample, azimuth integrated with the Earth and transport rates of the previous epoch,
velocity from the odometer speed, then height, latitude (with the new height) and longitude (with
the new height and latitude) by the trapezoidal rule. Because the accelerometer rates are
interval means, the pitch and roll of sample k are interval means too (they lag t_k by dt/2).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav.attitude import wrap_angle
from jaxnav.geodesy import OMEGA_E, normal_gravity, radii


class RissInput(NamedTuple):
    """One RISS sample (scalars) or a stack of samples (leading time axis); see module docstring."""

    f_x: Float[ArrayLike, "*N"]  # transverse specific force, interval mean [m/s^2]
    f_y: Float[ArrayLike, "*N"]  # forward specific force, interval mean [m/s^2]
    w_z: Float[ArrayLike, "*N"]  # vertical gyro rate, interval mean [rad/s]
    v_od: Float[ArrayLike, "*N"]  # odometer speed at t_k [m/s]
    a_od: Float[ArrayLike, "*N"]  # odometer acceleration over (t_{k-1}, t_k] [m/s^2]


class RissState(NamedTuple):
    """RISS navigation state at t_k."""

    llh: Float[Array, "3"]  # (lat_rad, lon_rad, h_m)
    vel_enu: Float[Array, "3"]  # (ve, vn, vu) [m/s]
    azimuth: Float[Array, ""]  # clockwise from north [rad], wrapped to (-pi, pi]
    pitch: Float[Array, ""]  # [rad]
    roll: Float[Array, ""]  # [rad]


class RissSensorErrors(NamedTuple):
    """Current estimates of the sensor errors removed from the raw inputs (closed loop).

    Each is subtracted from the raw measurement: w_z - gyro_bias_z_rad_s,
    (f_x, f_y) - accel_bias_xy_m_s2, a_od (1 - odo_scale) - odo_accel_bias_m_s2; the odometer
    speed is scaled, v_od (1 - odo_scale): a wheel odometer's error is a scale factor (tyre
    radius), so a standing vehicle (v_od = 0) stays at rest whatever the estimate.
    ``riss_errors.riss_feedback`` updates them; between updates the filter's Gauss-Markov
    shares (``*_gm``; the odometer-acceleration bias is one as a whole) decay as the model says
    (``riss_errors.decay_sensor_errors``), the start-up calibration stays.
    """

    gyro_bias_z_rad_s: Float[Array, ""]
    accel_bias_xy_m_s2: Float[Array, "2"]
    odo_scale: Float[Array, ""]  # relative error of the raw odometer speed (unitless)
    odo_accel_bias_m_s2: Float[Array, ""]
    gyro_bias_z_gm_rad_s: Float[Array, ""]  # Gauss-Markov share of gyro_bias_z_rad_s
    accel_bias_xy_gm_m_s2: Float[Array, "2"]  # Gauss-Markov share of accel_bias_xy_m_s2


def zero_sensor_errors() -> RissSensorErrors:
    """All sensor-error estimates zero (float64)."""
    z = jnp.zeros((), jnp.float64)
    z2 = jnp.zeros(2, jnp.float64)
    return RissSensorErrors(z, z2, z, z, z, z2)


def correct_input(inp: RissInput, sensor_errors: RissSensorErrors | None = None) -> RissInput:
    """Remove the estimated sensor errors from a raw input (no-op if ``sensor_errors`` is None)."""
    if sensor_errors is None:
        return inp
    b = sensor_errors
    return RissInput(
        f_x=inp.f_x - b.accel_bias_xy_m_s2[..., 0],
        f_y=inp.f_y - b.accel_bias_xy_m_s2[..., 1],
        w_z=inp.w_z - b.gyro_bias_z_rad_s,
        v_od=inp.v_od * (1.0 - b.odo_scale),
        a_od=inp.a_od * (1.0 - b.odo_scale) - b.odo_accel_bias_m_s2,
    )


# ---- input helpers ----------------------------------------------------------------------------


def rates_from_increments(
    dtheta_b: Float[ArrayLike, "*N 3"], dv_b: Float[ArrayLike, "*N 3"], dt: Float[ArrayLike, ""]
):
    """Interval-mean (f_x, f_y, w_z) = (dv_b[..., 0]/dt, dv_b[..., 1]/dt, dtheta_b[..., 2]/dt)."""
    return dv_b[..., 0] / dt, dv_b[..., 1] / dt, dtheta_b[..., 2] / dt


def odometer_acceleration(
    v_od: Float[ArrayLike, " N"], dt: Float[ArrayLike, ""], v_od_initial: Float[ArrayLike, ""]
) -> Float[Array, " N"]:
    """a_od[k] = (v_od[k] - v_od[k-1]) / dt with v_od[-1] = ``v_od_initial`` (speed at t_0).

    The backward difference is the exact mean acceleration over (t_{k-1}, t_k], matching the
    averaging of the accelerometer increments of the same sample.
    """
    v_prev = jnp.concatenate([jnp.atleast_1d(jnp.asarray(v_od_initial, v_od.dtype)), v_od[:-1]])
    return (v_od - v_prev) / dt


def riss_inputs_from_imu(
    dtheta_b: Float[ArrayLike, "N 3"],
    dv_b: Float[ArrayLike, "N 3"],
    v_od: Float[ArrayLike, " N"],
    dt: Float[ArrayLike, ""],
    v_od_initial: Float[ArrayLike, ""],
) -> RissInput:
    """Stacked ``RissInput`` from the shared increment contract (N, 3) and odometer speeds (N,)."""
    f_x, f_y, w_z = rates_from_increments(dtheta_b, dv_b, dt)
    return RissInput(f_x, f_y, w_z, v_od, odometer_acceleration(v_od, dt, v_od_initial))


def average_inputs(inputs: RissInput, factor: int) -> RissInput:
    """Decimate stacked inputs by an integer ``factor`` (S002: 100/200 Hz -> 1 Hz).

    f_x, f_y, w_z and a_od are averaged over each block of ``factor`` samples, which equals the
    mean over the long interval (sum of increments / long dt; the a_od mean telescopes to
    (v_end - v_start) / long dt). v_od keeps the last sample of the block, so it stays the speed
    at the end of the long interval (S002 does not say how it decimated the odometer).
    The new sample interval is ``factor * dt``.
    """
    n = inputs.v_od.shape[0]
    if n % factor:
        raise ValueError(
            f"average_inputs: {n} samples is not a multiple of the decimation factor {factor}"
        )

    def block_mean(x):
        return x.reshape(n // factor, factor).mean(axis=1)

    return RissInput(
        f_x=block_mean(inputs.f_x),
        f_y=block_mean(inputs.f_y),
        w_z=block_mean(inputs.w_z),
        v_od=inputs.v_od.reshape(n // factor, factor)[:, -1],
        a_od=block_mean(inputs.a_od),
    )


# ---- mechanization ----------------------------------------------------------------------------


def riss_pitch_roll(f_x, f_y, w_z, v_od, a_od, g):
    """Pitch and roll from the horizontal accelerometers (S000 eqs 4.2-4.3, S002 eqs 3.6-3.7).

    p = asin((f_y - a_od)/g) removes the forward vehicle acceleration; r = -asin((f_x + v_od w_z)
    / (g cos p)) removes the centripetal acceleration v_od w_z of a turn. ``w_z`` and the
    accelerometers must already be bias-corrected. The asin arguments are clipped to [-1, 1] so
    a spike cannot produce NaN. Neglected: Coriolis and transport terms, <= (3 we + 2 v/R) v.
    """
    pitch = jnp.arcsin(jnp.clip((f_y - a_od) / g, -1.0, 1.0))
    roll = -jnp.arcsin(jnp.clip((f_x + v_od * w_z) / (g * jnp.cos(pitch)), -1.0, 1.0))
    return pitch, roll


def riss_velocity(
    v_od: Float[ArrayLike, ""], azimuth: Float[ArrayLike, ""], pitch: Float[ArrayLike, ""]
) -> Float[Array, "3"]:
    """ENU velocity of the forward odometer speed (S000 eqs 4.4-4.6, S002 eqs 3.9-3.11)."""
    cp = jnp.cos(pitch)
    return jnp.stack(
        [v_od * jnp.sin(azimuth) * cp, v_od * jnp.cos(azimuth) * cp, v_od * jnp.sin(pitch)]
    )


def riss_state_from(
    llh: Float[ArrayLike, "3"],
    azimuth: Float[ArrayLike, ""],
    speed: Float[ArrayLike, ""],
    pitch: Float[ArrayLike, ""] = 0.0,
    roll: Float[ArrayLike, ""] = 0.0,
) -> RissState:
    """A consistent initial state: the velocity is the odometer speed along (azimuth, pitch)."""
    llh = jnp.asarray(llh, jnp.float64)
    azimuth, pitch, roll = (jnp.asarray(x, jnp.float64) for x in (azimuth, pitch, roll))
    return RissState(
        llh, riss_velocity(jnp.asarray(speed, jnp.float64), azimuth, pitch), azimuth, pitch, roll
    )


def _azimuth_rate(w_z_corr, lat, h, ve):
    """A' = -[(w_z - b_z) - we sin(lat) - ve tan(lat)/(R_N + h)] (S000 eq 4.28).

    S000 eq 4.1 prints we cos(lat) and R_N - h: typos (SEED_SPEC 4, S000 item 6); eq 4.28 and
    S002 eq 3.8 have the physically correct form used here (the l-frame's rotation about up).
    """
    _, r_n = radii(lat)
    return -(w_z_corr - OMEGA_E * jnp.sin(lat) - ve * jnp.tan(lat) / (r_n + h))


def riss_step(
    state: RissState,
    inp: RissInput,
    dt: Float[ArrayLike, ""],
    sensor_errors: RissSensorErrors | None = None,
) -> RissState:
    """One RISS epoch t_{k-1} -> t_k (S002 eqs 3.6-3.14; S000 eqs 4.1-4.9 discretised).

    Sensor errors (if given) are removed first. The azimuth is integrated with the Earth and
    transport rates of the previous epoch (S002 eq 3.8); positions use the trapezoidal rule on the
    previous and new velocities, in the order h, lat (with the new h), lon (new h and lat).
    """
    inp = correct_input(inp, sensor_errors)
    lat, lon, h = state.llh[0], state.llh[1], state.llh[2]
    ve0, vn0, vu0 = state.vel_enu[0], state.vel_enu[1], state.vel_enu[2]

    g = normal_gravity(lat, h)
    pitch, roll = riss_pitch_roll(inp.f_x, inp.f_y, inp.w_z, inp.v_od, inp.a_od, g)
    azimuth = wrap_angle(state.azimuth + _azimuth_rate(inp.w_z, lat, h, ve0) * dt)
    vel = riss_velocity(inp.v_od, azimuth, pitch)

    h_new = h + 0.5 * (vel[2] + vu0) * dt
    r_m, _ = radii(lat)  # the new latitude is not known yet (S002 eq 3.13)
    lat_new = lat + 0.5 * (vel[1] + vn0) * dt / (r_m + h_new)
    _, r_n_new = radii(lat_new)
    lon_new = lon + 0.5 * (vel[0] + ve0) * dt / ((r_n_new + h_new) * jnp.cos(lat_new))

    return RissState(jnp.stack([lat_new, lon_new, h_new]), vel, azimuth, pitch, roll)


def riss_run(
    state0: RissState,
    inputs: RissInput,
    dt: Float[ArrayLike, ""],
    sensor_errors: RissSensorErrors | None = None,
) -> tuple[RissState, RissState]:
    """Mechanize a stack of inputs with ``lax.scan``: returns (final state, history at t_1..t_N)."""

    def body(state, inp):
        new = riss_step(state, inp, dt, sensor_errors)
        return new, new

    return jax.lax.scan(body, state0, inputs)


# ---- continuous-time dynamics (for the error model's Jacobian check) ---------------------------


def riss_rate(
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    azimuth: Float[ArrayLike, ""],
    pitch: Float[ArrayLike, ""],
    odo_accel: Float[ArrayLike, ""],
    gyro_bias_z: Float[ArrayLike, ""],
    w_z: Float[ArrayLike, ""],
    pitch_rate: Float[ArrayLike, ""] = 0.0,
    radii_mn=None,
) -> tuple[Float[Array, "3"], Float[Array, "3"], Float[Array, ""]]:
    """Continuous RISS dynamics with the velocity as a state (the form S000/S002 linearise).

    lat' = vn/(R_M+h), lon' = ve/((R_N+h) cos lat), h' = vu (S000 eqs 4.7-4.9);
    A' = -[(w_z - b_z) - we sin lat - ve tan lat/(R_N+h)] (S000 eq 4.28);
    time derivative of v = v_od (sinA cosp, cosA cosp, sinp) with v_od' = a_od and v_od cosp
    written as ve sinA + vn cosA:
      ve' = a_od sinA cosp + vn A' - vu sinA p',
      vn' = a_od cosA cosp - ve A' - vu cosA p',
      vu' = a_od sinp + (ve sinA + vn cosA) p'.
    S002 (and S000) neglect the p' terms (SEED_SPEC 1.5.1); pass ``pitch_rate=0`` to match them.
    ``radii_mn = (R_M, R_N)`` freezes the radii (the seeds ignore dR/dlat); by default they are
    evaluated at ``llh[0]``. Returns (llh_dot, vel_enu_dot, azimuth_dot).
    """
    lat, h = llh[0], llh[2]
    ve, vn, vu = vel_enu[0], vel_enu[1], vel_enu[2]
    r_m, r_n = radii(lat) if radii_mn is None else radii_mn
    az_rate = -(w_z - gyro_bias_z - OMEGA_E * jnp.sin(lat) - ve * jnp.tan(lat) / (r_n + h))
    sa, ca = jnp.sin(azimuth), jnp.cos(azimuth)
    sp, cp = jnp.sin(pitch), jnp.cos(pitch)
    llh_dot = jnp.stack([vn / (r_m + h), ve / ((r_n + h) * jnp.cos(lat)), vu])
    vel_dot = jnp.stack(
        [
            odo_accel * sa * cp + vn * az_rate - vu * sa * pitch_rate,
            odo_accel * ca * cp - ve * az_rate - vu * ca * pitch_rate,
            odo_accel * sp + (ve * sa + vn * ca) * pitch_rate,
        ]
    )
    return llh_dot, vel_dot, az_rate
