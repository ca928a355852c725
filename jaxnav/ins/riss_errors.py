"""RISS error-state models: F, G, Qc for layouts RISS9 (S002) and RISS16 (S000), and feedback.

Error convention (core/states.py): dx = estimated - true. Position errors are geodetic
(rad, rad, m), velocity errors ENU [m/s], the azimuth error is in rad. The sensor states are the
errors of the *corrected* quantities the mechanization uses:
- ``gyro_bias_z``, ``accel_bias_x/y``: estimated bias - true bias (they are subtracted from the
  raw rates, so the used rate is wrong by -dx and A' gains +d b_z: F[azimuth, gyro_bias_z] = +1),
- ``odo_accel``, ``odo_speed``: used odometer acceleration / speed - true (F[vel, odo_accel] =
  (sinA cosp, cosA cosp, sinp), F[odo_speed, odo_accel] = 1),
- ``roll``, ``pitch``: estimated - true angle; ``clock_bias`` [m], ``clock_drift`` [m/s].

Continuous model: dx' = F dx + G w, E[w(t) w(s)^T] = Qc delta(t - s); G has one unit entry per
noise source (names in ``RISS9_NOISE`` / ``RISS16_NOISE``) and Qc is the diagonal of the sources'
PSDs in the driven state's units^2 / s. First-order Gauss-Markov states follow
x' = -beta x + sqrt(2 beta sigma^2) w (S000 eqs 4.30-4.31; SEED_SPEC 1.6), i.e. PSD 2 beta sigma^2.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav.attitude import wrap_angle
from jaxnav.core.states import RISS9, RISS16, StateLayout
from jaxnav.geodesy import C_LIGHT, OMEGA_E, normal_gravity, radii
from jaxnav.ins.riss import (
    RissInput,
    RissSensorErrors,
    RissState,
    correct_input,
    zero_sensor_errors,
)

_DEG = jnp.pi / 180.0
_MG = 9.80665e-3  # 1 milli-g [m/s^2]
_MIN_SCALE_SPEED_M_S = 1.0  # below this speed the odometer scale factor is not updated

# Receiver-clock Allan coefficients of S001 eq 16 (after Brown & Hwang) and its inflation K.
_CLOCK_H0 = 2.0e-19
_CLOCK_H_M2 = 2.0e-20
_CLOCK_K = 4.0

#: Noise sources (columns of G) of each layout, each driving the state of the same name.
RISS9_NOISE = ("odo_accel", "gyro_bias_z")
RISS16_NOISE = (
    "odo_accel",
    "gyro_bias_z",
    "clock_bias",
    "clock_drift",
    "roll",
    "pitch",
    "accel_bias_x",
    "accel_bias_y",
    "odo_speed",
)


class RissNoiseParams(eqx.Module):
    """Stochastic model of the RISS sensor-error states (GM: beta = 1/tau [1/s], sigma steady).

    No seed gives a number for any RISS GM state (SEED_SPEC 1.5.2, 1.6, "Not specified"); the
    defaults below are *chosen* for the MEMS RISS of S000 (Crossbow IMU300CC + OBD-II speed):
    - Vertical-gyro bias: sigma 0.01 deg/s, tau 1000 s. The +-2 deg/s turn-on bias (S000 Tab B.1,
      SEED_SPEC 4 item 18) is removed at start-up; what remains drifts in-run. S000's 60-s
      complete-outage drifts of 1-6 m at 60-80 km/h imply 0.5 v b t^2 with b ~ 0.005 deg/s, so a
      1-sigma of 0.01 deg/s covers them; tau is longer than S000's 250-400 s bias convergence,
      which only makes sense if the bias is nearly constant over that time.
    - Odometer-acceleration error: sigma 0.005 m/s^2, tau 10 s: about 0.5-1 % (a residual speed
      scale factor) of a 0.5-1 m/s^2 urban acceleration, correlated over one manoeuvre. Its
      integral (the speed error) then grows by ~0.17 m/s in 60 s.
    - Roll and pitch errors: sigma 0.5 deg, tau 5 s: suspension pitch/roll under braking and
      cornering, which the accelerometer formulas cannot tell from road slope and bank, is of
      order 0.5-1 deg and lasts one manoeuvre.
    - Horizontal accelerometer biases: sigma 1 mg, tau 1000 s: the +-30 mg turn-on range
      (S000 Tab B.1) is removed at start-up; about 1 mg in-run variation for MEMS of that grade.
    - Odometer-speed error (RISS16 state 16): random walk of PSD (0.01 m/s/sqrt(s))^2, i.e.
      0.08 m/s in 60 s, letting the speed-bias state follow slow scale-factor changes (tyre
      pressure, load). OBD-II 1 km/h quantization is white and is not part of this state.
    - Receiver clock: S001 eq 16, S_f = K c^2 h0 / 2 [m^2/s] and S_g = 2 K pi^2 c^2 h_-2 [m^2/s^3]
      with h0 = 2e-19, h_-2 = 2e-20, K = 4 (SEED_SPEC 1.6; 0.03595 and 0.14193).
    ``tactical()`` gives the S002 chapter 5 (SPAN-CPT / KVH1750) variant.
    """

    gyro_bias_beta_1_s: float = 1.0 / 1000.0
    gyro_bias_sigma_rad_s: float = 0.01 * _DEG
    odo_accel_beta_1_s: float = 1.0 / 10.0
    odo_accel_sigma_m_s2: float = 0.005
    roll_beta_1_s: float = 1.0 / 5.0
    roll_sigma_rad: float = 0.5 * _DEG
    pitch_beta_1_s: float = 1.0 / 5.0
    pitch_sigma_rad: float = 0.5 * _DEG
    accel_bias_beta_1_s: float = 1.0 / 1000.0
    accel_bias_sigma_m_s2: float = 1.0 * _MG
    odo_speed_rw_psd_m2_s3: float = 0.01**2
    clock_bias_psd_m2_s: float = _CLOCK_K * C_LIGHT**2 * _CLOCK_H0 / 2.0
    clock_drift_psd_m2_s3: float = 2.0 * _CLOCK_K * jnp.pi**2 * C_LIGHT**2 * _CLOCK_H_M2

    @classmethod
    def tactical(cls) -> RissNoiseParams:
        """S002 ch5 RISS from a SPAN-CPT / KVH1750 (tactical FOG gyro, MEMS accelerometers).

        Gyro-bias sigma 1 deg/h = the CPT bias stability S002 quotes, tau 1 h (chosen); accel
        bias sigma 0.75 mg = the CPT stability of S000 Tab B.2, tau 1 h (chosen); the odometer,
        roll/pitch and clock values are those of the default (same vehicle and receiver class).
        """
        return cls(
            gyro_bias_beta_1_s=1.0 / 3600.0,
            gyro_bias_sigma_rad_s=1.0 * _DEG / 3600.0,
            accel_bias_beta_1_s=1.0 / 3600.0,
            accel_bias_sigma_m_s2=0.75 * _MG,
        )


def _gm_psd(beta, sigma):
    """PSD of the white noise driving a first-order GM of steady-state sigma: 2 beta sigma^2."""
    return 2.0 * beta * sigma**2


def _nav_block(F, layout: StateLayout, state: RissState, w_z_corr, a_od_corr):
    """Fill the position, velocity and azimuth rows (S002 eqs 5.13-5.20, F1-F8).

    Linearization of riss_rate with the pitch-rate terms neglected (S002) and the radii of
    curvature held constant in latitude (all seeds). For S000 (4.17-4.29) this adds the
    corrections of SEED_SPEC 4: the delta-h columns (item 4, from S002's F1/F3/F6), the factor 2
    in F[vn, ve] (item 3, eq 4.25), the 1/((R_N+h) cos lat) coefficient of eq 4.19 (item 5).
    """
    lat, h = state.llh[0], state.llh[2]
    ve, vn = state.vel_enu[0], state.vel_enu[1]
    r_m, r_n = radii(lat)
    rm_h, rn_h = r_m + h, r_n + h
    t, c = jnp.tan(lat), jnp.cos(lat)
    sa, ca = jnp.sin(state.azimuth), jnp.cos(state.azimuth)
    sp, cp = jnp.sin(state.pitch), jnp.cos(state.pitch)

    az_rate = -w_z_corr + OMEGA_E * jnp.sin(lat) + ve * t / rn_h  # S000 eq 4.28
    daz_dlat = OMEGA_E * c + ve / (c * c * rn_h)  # we cos(lat) + ve sec^2(lat)/(R_N+h)
    daz_dh = -ve * t / rn_h**2
    daz_dve = t / rn_h

    lat_i, lon_i, h_i = (layout.sl("pos").start + k for k in range(3))
    ve_i, vn_i, vu_i = (layout.sl("vel").start + k for k in range(3))
    az_i, aod_i, bz_i = layout.i("azimuth"), layout.i("odo_accel"), layout.i("gyro_bias_z")

    entries = [
        # position rows (F1, F2)
        (lat_i, h_i, -vn / rm_h**2),
        (lat_i, vn_i, 1.0 / rm_h),
        (lon_i, lat_i, ve * t / (rn_h * c)),
        (lon_i, h_i, -ve / (rn_h**2 * c)),
        (lon_i, ve_i, 1.0 / (rn_h * c)),
        (h_i, vu_i, 1.0),
        # east velocity: ve' = a_od sinA cosp + vn A'  (F3, F4, F5)
        (ve_i, lat_i, vn * daz_dlat),
        (ve_i, h_i, vn * daz_dh),
        (ve_i, ve_i, vn * daz_dve),
        (ve_i, vn_i, az_rate),
        (ve_i, az_i, a_od_corr * ca * cp),
        (ve_i, aod_i, sa * cp),
        (ve_i, bz_i, vn),
        # north velocity: vn' = a_od cosA cosp - ve A'; F[vn, ve] carries 2 ve tan/(R_N+h)
        (vn_i, lat_i, -ve * daz_dlat),
        (vn_i, h_i, -ve * daz_dh),
        (vn_i, ve_i, -az_rate - ve * daz_dve),
        (vn_i, az_i, -a_od_corr * sa * cp),
        (vn_i, aod_i, ca * cp),
        (vn_i, bz_i, -ve),
        # up velocity: vu' = a_od sinp
        (vu_i, aod_i, sp),
        # azimuth (F6, F7, F8)
        (az_i, lat_i, daz_dlat),
        (az_i, h_i, daz_dh),
        (az_i, ve_i, daz_dve),
        (az_i, bz_i, 1.0),
    ]
    rows = jnp.array([e[0] for e in entries])
    cols = jnp.array([e[1] for e in entries])
    vals = jnp.stack([jnp.asarray(e[2], jnp.float64) for e in entries])
    return F.at[rows, cols].set(vals)


def _noise(layout: StateLayout, names, psds):
    """G (n x m) with a unit entry per source on its state's row, Qc = diag(psds) (m x m)."""
    G = jnp.zeros((layout.size, len(names)))
    G = G.at[jnp.array([layout.i(n) for n in names]), jnp.arange(len(names))].set(1.0)
    return G, jnp.diag(jnp.stack([jnp.asarray(q, jnp.float64) for q in psds]))


def riss9_dynamics(
    state: RissState,
    inp: RissInput,
    params: RissNoiseParams,
    sensor_errors: RissSensorErrors | None = None,
) -> tuple[Float[Array, "n n"], Float[Array, "n q"], Float[Array, "q q"]]:
    """(F, G, Qc) of layout RISS9 (S002 eqs 5.8, 5.12-5.21; SEED_SPEC 1.5.1).

    ``inp`` is the raw input of the latest mechanization step and ``sensor_errors`` the
    estimates removed from it (the F entries use the corrected w_z and a_od). F(8,8) = -gamma_aod
    and F(9,9) = -beta_Bz are first-order GM; both are driven by white noise of PSD 2 beta sigma^2.
    """
    inp = correct_input(inp, sensor_errors)
    layout = RISS9
    F = _nav_block(jnp.zeros((layout.size, layout.size)), layout, state, inp.w_z, inp.a_od)
    F = F.at[layout.i("odo_accel"), layout.i("odo_accel")].set(-params.odo_accel_beta_1_s)
    F = F.at[layout.i("gyro_bias_z"), layout.i("gyro_bias_z")].set(-params.gyro_bias_beta_1_s)
    G, Qc = _noise(
        layout,
        RISS9_NOISE,
        (
            _gm_psd(params.odo_accel_beta_1_s, params.odo_accel_sigma_m_s2),
            _gm_psd(params.gyro_bias_beta_1_s, params.gyro_bias_sigma_rad_s),
        ),
    )
    return F, G, Qc


def riss16_dynamics(
    state: RissState,
    inp: RissInput,
    params: RissNoiseParams,
    sensor_errors: RissSensorErrors | None = None,
) -> tuple[Float[Array, "n n"], Float[Array, "n q"], Float[Array, "q q"]]:
    """(F, G, Qc) of layout RISS16 (S000 eqs 4.15-4.43 in its F order, SEED_SPEC 1.5.2 and 4).

    Navigation rows as S002 (S000 items 3-5 corrected). GM states: odometer acceleration, gyro
    bias, roll, pitch, accelerometer biases; clock bias' = clock drift, both random walks;
    odo_speed' = odo_accel plus a small random walk. G follows the F order (S000 item 2: the
    printed G labels are permuted). As in S000, roll, pitch and the accelerometer biases are not
    coupled to the navigation rows (the pitch column of the velocity rows is neglected).
    """
    inp = correct_input(inp, sensor_errors)
    layout = RISS16
    p = params
    F = _nav_block(jnp.zeros((layout.size, layout.size)), layout, state, inp.w_z, inp.a_od)
    gm = (
        ("odo_accel", p.odo_accel_beta_1_s),
        ("gyro_bias_z", p.gyro_bias_beta_1_s),
        ("roll", p.roll_beta_1_s),
        ("pitch", p.pitch_beta_1_s),
        ("accel_bias_x", p.accel_bias_beta_1_s),
        ("accel_bias_y", p.accel_bias_beta_1_s),
    )
    for name, beta in gm:
        F = F.at[layout.i(name), layout.i(name)].set(-beta)
    F = F.at[layout.i("clock_bias"), layout.i("clock_drift")].set(1.0)  # S000 F(10,11)
    F = F.at[layout.i("odo_speed"), layout.i("odo_accel")].set(1.0)  # S000 F(16,8)
    psd = {
        "odo_accel": _gm_psd(p.odo_accel_beta_1_s, p.odo_accel_sigma_m_s2),
        "gyro_bias_z": _gm_psd(p.gyro_bias_beta_1_s, p.gyro_bias_sigma_rad_s),
        "clock_bias": p.clock_bias_psd_m2_s,
        "clock_drift": p.clock_drift_psd_m2_s3,
        "roll": _gm_psd(p.roll_beta_1_s, p.roll_sigma_rad),
        "pitch": _gm_psd(p.pitch_beta_1_s, p.pitch_sigma_rad),
        "accel_bias_x": _gm_psd(p.accel_bias_beta_1_s, p.accel_bias_sigma_m_s2),
        "accel_bias_y": _gm_psd(p.accel_bias_beta_1_s, p.accel_bias_sigma_m_s2),
        "odo_speed": p.odo_speed_rw_psd_m2_s3,
    }
    G, Qc = _noise(layout, RISS16_NOISE, tuple(psd[n] for n in RISS16_NOISE))
    return F, G, Qc


def along_track_unit(azimuth: Float[ArrayLike, ""], pitch: Float[ArrayLike, ""]
                     ) -> Float[Array, "3"]:
    """u(A, p) = (sinA cosp, cosA cosp, sinp): the ENU direction of the RISS velocity
    (S000 eqs 4.4-4.6, v = v_od u)."""
    cp = jnp.cos(pitch)
    return jnp.stack([jnp.sin(azimuth) * cp, jnp.cos(azimuth) * cp, jnp.sin(pitch)])


def mechanized_velocity_jacobian(layout: StateLayout, state: RissState) -> Float[Array, "3 n"]:
    """M (3 x n): the RISS velocity error the azimuth, odometer and pitch-source states imply.

    The RISS mechanization does not integrate its velocity: every input re-derives it as
    v = v_od u(A, p), u = (sinA cosp, cosA cosp, sinp) (S000 eqs 4.4-4.6), with the pitch itself
    re-derived as p = asin((f_y - a_od) / g) (S000 eq 4.2). Its error is therefore algebraic,
    dv = M dx:
    - dv/dA = v_od du/dA = (vn, -ve, 0), the cross-track error v dA of a heading error;
    - dv/d(odo speed) = u, when the layout has ``odo_speed``;
    - the pitch error dp = -(dx[accel_bias_y] + dx[odo_accel]) / (g cosp) (the used f_y is wrong
      by -dx[accel_bias_y], the used a_od by +dx[odo_accel]) tilts the velocity by
      v_od du/dp = v_od (-sinA sinp, -cosA sinp, cosp), when the layout has ``accel_bias_y``
      (RISS16). Without it the vertical velocity (and so the height) of the mechanization drifts
      with the accelerometer bias while the model keeps them unrelated.
    The ``pitch`` state is not in M: the mechanization overwrites a pitch correction at the next
    input, so only errors of its persistent sources (the biases) can be estimated and fed back.
    ``state`` must be a freshly mechanized state (vel_enu = v_od u).
    """
    M = jnp.zeros((3, layout.size))
    ve, vn = state.vel_enu[0], state.vel_enu[1]
    M = M.at[:, layout.i("azimuth")].set(jnp.stack([vn, -ve, jnp.zeros_like(ve)]))
    sa, ca = jnp.sin(state.azimuth), jnp.cos(state.azimuth)
    sp, cp = jnp.sin(state.pitch), jnp.cos(state.pitch)
    if layout.has("odo_speed"):
        M = M.at[:, layout.i("odo_speed")].set(along_track_unit(state.azimuth, state.pitch))
    if layout.has("accel_bias_y"):
        v_od = jnp.linalg.norm(state.vel_enu)
        g = normal_gravity(state.llh[0], state.llh[2])
        dv_dp = v_od * jnp.stack([-sa * sp, -ca * sp, cp])
        col = -dv_dp / (g * cp)
        M = M.at[:, layout.i("accel_bias_y")].set(col).at[:, layout.i("odo_accel")].set(col)
    return M


def odometer_scale_rate(state: RissState, inp: RissInput, dt_s: Float[ArrayLike, ""],
                        sensor_errors: RissSensorErrors | None = None) -> Float[Array, ""]:
    """F[odo_speed, odo_speed] = ln(v_k / v_{k-1}) / dt: a scale-factor speed error dk v_od.

    The mechanization scales the odometer, v_od (1 - k) (``riss.correct_input``), and never
    integrates a_od into the speed, so an unchanged scale error dk gives a speed error dk v_od
    that follows the speed: d/dt (dk v) = (a / v) (dk v). Over one epoch that is the factor
    v_k / v_{k-1} exactly; both speeds are floored at the 1 m/s below which the scale is not
    updated (``riss_feedback``), which bounds the rate when starting from rest.
    """
    inp = correct_input(inp, sensor_errors)
    v1 = jnp.maximum(jnp.linalg.norm(state.vel_enu), _MIN_SCALE_SPEED_M_S)
    v0 = jnp.maximum(jnp.linalg.norm(state.vel_enu) - inp.a_od * dt_s, _MIN_SCALE_SPEED_M_S)
    return jnp.log(v1 / v0) / dt_s


def algebraic_velocity_dynamics(
    F: Float[Array, "n n"],
    layout: StateLayout,
    state: RissState,
    read_beta_1_s: Float[ArrayLike, ""],
    odo_scale_rate_1_s: Float[ArrayLike, ""] = 0.0,
) -> Float[Array, "n n"]:
    """Recast a seed F (``riss9_dynamics`` / ``riss16_dynamics``) so that the velocity error is
    the algebraic dv_total = dx[vel] + M dx (``mechanized_velocity_jacobian``).

    Why: the seeds linearise a velocity that is integrated (v' = a_od u + v x A', S000 eqs
    4.17-4.29), so their velocity error only learns the heading error through F[vel, A] = a_od
    (the derivative of v dA). The mechanization re-derives v from v_od and A at every input,
    so after any update the true cross-track velocity error is v dA whatever the filter's
    velocity state says. With the seed F a constant-speed drive never relates the two (their
    correlation stays ~0), and under braking F[vel, A] = a_od < 0 builds the *opposite*
    correlation to the true +v: a cross-track Doppler residual v dA then pushes the azimuth
    estimate the wrong way, by about v / (v - v0) times the residual, and the heading runs away.

    Here the azimuth (and, for RISS16, the odometer-speed and pitch-source) errors enter the
    measurement and the position rows through M, and the ``vel`` states keep only what M does
    not carry:
    - with ``odo_speed`` (RISS16): the short-correlated odometer reading error (quantisation,
      white noise, pitch noise), a GM of rate ``read_beta_1_s`` (one input interval). The
      odometer speed error is a scale-factor error (the mechanization scales v_od and does not
      integrate a_od): F[odo_speed, odo_speed] = ``odo_scale_rate_1_s``
      (``odometer_scale_rate``) replaces S000's F(16,8) = 1, which would let an a_od error
      (here only a pitch error, through M) move the speed by 0.35 m/s per minute at constant
      speed, where a scale error cannot change it;
    - without it (RISS9): the along-track speed error of the seeds, driven by the odometer
      acceleration error and rotated with the heading (F[vel, odo_accel], F[ve, vn] = A').
    Rows that depend on the velocity (position; the azimuth's transport-rate term) get
    F[:, vel] M added, i.e. they see the total velocity error.
    """
    n = layout.size
    vel = layout.sl("vel")
    M = mechanized_velocity_jacobian(layout, state)
    F_vel_cols = F[:, vel]
    is_vel_row = (jnp.arange(n) >= vel.start) & (jnp.arange(n) < vel.stop)
    F_new = F + jnp.where(is_vel_row[:, None], 0.0, F_vel_cols @ M)
    rows = jnp.zeros((3, n))
    if layout.has("odo_speed"):
        rows = rows.at[:, vel].set(-read_beta_1_s * jnp.eye(3))
        i = layout.i("odo_speed")
        F_new = F_new.at[i, :].set(0.0).at[i, i].set(odo_scale_rate_1_s)
    else:
        az_rate = F[vel.start, vel.start + 1]  # the seed's F[ve, vn] = A' (rotation with A)
        rows = rows.at[0, vel.start + 1].set(az_rate).at[1, vel.start].set(-az_rate)
        rows = rows.at[:, layout.i("odo_accel")].set(along_track_unit(state.azimuth, state.pitch))
    return F_new.at[vel, :].set(rows)


def riss_feedback(
    state: RissState,
    dx: Float[Array, " n"],
    layout: StateLayout,
    sensor_errors: RissSensorErrors | None = None,
) -> tuple[RissState, RissSensorErrors]:
    """Closed-loop correction x = x_hat - dx (S002 §5.3, S000; SEED_SPEC 1.7).

    Works for any layout holding RISS blocks by name (RISS9, RISS16, or either extended with
    GNSS states). Returns (corrected RissState, corrected RissSensorErrors):
    - llh -= dx[pos]; vel_enu -= dx[vel]; azimuth = wrap(azimuth - dx[azimuth]); roll and pitch
      -= dx when the layout has them (they are recomputed from the accelerometers at the next
      step, so this correction only affects the current output).
    - gyro / accelerometer biases: b -= dx (dx is estimated - true bias);
    - odometer: dx[odo_accel] is an error of the corrected acceleration, so the subtracted bias
      grows by it; dx[odo_speed] is turned into a scale-factor correction at the current speed
      (held below 1 m/s). A layout without ``odo_speed`` (RISS9) attributes the
      along-track part of dx[vel] to the odometer speed: the next step recomputes the velocity
      from the odometer, so without this the velocity correction would not persist (the
      cross-track part is the azimuth error, corrected through dx[azimuth]).
    """
    b = zero_sensor_errors() if sensor_errors is None else sensor_errors
    dvel = dx[layout.sl("vel")]
    azimuth = wrap_angle(state.azimuth - dx[layout.i("azimuth")])
    roll = state.roll - dx[layout.i("roll")] if layout.has("roll") else state.roll
    pitch = state.pitch - dx[layout.i("pitch")] if layout.has("pitch") else state.pitch
    new_state = RissState(
        llh=state.llh - dx[layout.sl("pos")],
        vel_enu=state.vel_enu - dvel,
        azimuth=azimuth,
        pitch=pitch,
        roll=roll,
    )

    d_gyro = dx[layout.i("gyro_bias_z")] if layout.has("gyro_bias_z") else 0.0
    d_accel = (jnp.stack([dx[layout.i("accel_bias_x")], dx[layout.i("accel_bias_y")]])
               if layout.has("accel_bias_x") else jnp.zeros(2))
    gyro = b.gyro_bias_z_rad_s - d_gyro
    accel = b.accel_bias_xy_m_s2 - d_accel
    odo_accel = b.odo_accel_bias_m_s2
    if layout.has("odo_accel"):
        odo_accel = odo_accel + dx[layout.i("odo_accel")]
    if layout.has("odo_speed"):
        d_speed = dx[layout.i("odo_speed")]
    else:
        d_speed = along_track_unit(azimuth, pitch) @ dvel
    # The speed error becomes a scale-factor correction: v_od (1 - k') = v_od (1 - k) - d_speed.
    # Below 1 m/s the ratio is ill-conditioned (and at rest the odometer is exact), so k holds.
    speed = jnp.linalg.norm(state.vel_enu)
    moving = speed > _MIN_SCALE_SPEED_M_S
    d_scale = jnp.where(moving, d_speed * (1.0 - b.odo_scale) / jnp.where(moving, speed, 1.0), 0.0)
    new_errors = RissSensorErrors(
        gyro, accel, b.odo_scale + d_scale, odo_accel,
        b.gyro_bias_z_gm_rad_s - d_gyro, b.accel_bias_xy_gm_m_s2 - d_accel,
    )
    return new_state, new_errors


def decay_sensor_errors(b: RissSensorErrors, params: RissNoiseParams, layout: StateLayout,
                        dt: Float[ArrayLike, ""]) -> RissSensorErrors:
    """Predict the sensor estimates over dt as the model does: x_hat <- exp(-beta dt) x_hat for
    the Gauss-Markov states of ``layout`` (x' = -beta x, S000 eqs 4.30-4.31): the gyro and
    accelerometer biases' filter-estimated shares and the odometer-acceleration bias; the
    start-up calibration and the odometer scale (a random walk) stay."""
    def factor(name, beta):
        return jnp.exp(-beta * dt) if layout.has(name) else 1.0

    fg = factor("gyro_bias_z", params.gyro_bias_beta_1_s)
    fa = factor("accel_bias_x", params.accel_bias_beta_1_s)
    fo = factor("odo_accel", params.odo_accel_beta_1_s)
    return b._replace(
        gyro_bias_z_rad_s=b.gyro_bias_z_rad_s - (1.0 - fg) * b.gyro_bias_z_gm_rad_s,
        accel_bias_xy_m_s2=b.accel_bias_xy_m_s2 - (1.0 - fa) * b.accel_bias_xy_gm_m_s2,
        odo_accel_bias_m_s2=fo * b.odo_accel_bias_m_s2,
        gyro_bias_z_gm_rad_s=fg * b.gyro_bias_z_gm_rad_s,
        accel_bias_xy_gm_m_s2=fa * b.accel_bias_xy_gm_m_s2,
    )


__all__ = [
    "RISS9_NOISE",
    "RISS16_NOISE",
    "RissNoiseParams",
    "algebraic_velocity_dynamics",
    "along_track_unit",
    "mechanized_velocity_jacobian",
    "odometer_scale_rate",
    "riss9_dynamics",
    "riss16_dynamics",
    "decay_sensor_errors",
    "riss_feedback",
]
