"""Full-IMU error-state model (F, G, Qc for INS15/21/27), closed-loop feedback, IMU compensation.

Conventions (``jaxnav.core.states``): error = estimated - true; position errors geodetic
(d_lat [rad], d_lon [rad], d_h [m]); velocity errors ENU [m/s]; attitude error eps (ENU, rad) with
C_hat_b_l = (I - [eps x]) C_b_l.

Sensor-error blocks hold the errors remaining in the *compensated* IMU output used by the
mechanization (S003 eq 3, S001 eq 12 sign): f_used - f_true = b_a + diag(f^b) S_a and
w_used - w_true = b_g + diag(w_ib^b) S_g, with b = GM drift (+ turn-on bias in INS27) and S the
scale-factor error. Closed loop, ``feedback_sensors`` folds an estimate of them into the running
``SensorErrors`` that ``correct_imu`` removes from the raw increments.

Error dynamics (SEED_SPEC 1.3 "recommended explicit ENU error model", derived here for every
first-order term, including the latitude derivatives of R_M, R_N and of normal gravity, so that
F is the exact Jacobian of the continuous model in ``strapdown.nav_rate``):

    d(llh)' = dD^-1/d(lat, h) v + D^-1 dv
    dv'     = [f^l x] eps + C dfb - (2 w_ie + w_el) x dv - (2 dw_ie + dw_el) x v + dg
    eps'    = -w_il x eps + dw_ie + dw_el - C dwb
    b'      = -b / tau (first-order Gauss-Markov, S001 eq 13), turn-on biases b' = 0

dw_ie, dw_el are the first-order changes of w_ie^l(lat) and w_el^l(lat, h, v), and
dg = [0, 0, -(dg/dlat) d_lat - (dg/dh) d_h]. The vertical term -(dg/dh) d_h is the "+2g/R d_h"
of SEED_SPEC 1.3 evaluated with the WGS-84 normal-gravity gradient (3.0855e-6 s^-2 at sea level
and 45 deg; 2g/R gives 3.075e-6 to 3.080e-6 depending on the radius chosen, i.e. within 0.4 %).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav import attitude, geodesy
from jaxnav.core.states import StateLayout
from jaxnav.ins.strapdown import ImuIncrements, NavState

# Sensor blocks this module knows; any other block of a layout (e.g. GNSS clock, ZWD,
# ambiguities appended by the tight coupling) gets zero rows/columns here for the caller to fill.
_GM_BLOCKS = ("accel_bias", "gyro_bias", "accel_scale", "gyro_scale")
_TON_BLOCKS = ("accel_bias_ton", "gyro_bias_ton")


def _f64(x):
    return jnp.asarray(x, dtype=jnp.float64)


class ImuErrorModel(eqx.Module):
    """Stochastic IMU error parameters (per triad; scalars broadcast to the three axes).

    Values come from the caller (grade presets live in ``jaxnav.sim.sensors``). A GM state has
    x' = -x/tau + sqrt(2 sigma^2/tau) w (S001 eq 13; S000/S004 write beta = 1/tau); tau = inf
    gives a random constant with sigma its initial standard deviation.
    """

    accel_vrw_m_s_sqrt_s: jax.Array = eqx.field(converter=_f64)  # velocity random walk
    gyro_arw_rad_sqrt_s: jax.Array = eqx.field(converter=_f64)  # angle random walk
    accel_bias_sigma_m_s2: jax.Array = eqx.field(converter=_f64)  # GM bias-drift steady std
    accel_bias_tau_s: jax.Array = eqx.field(converter=_f64)  # GM bias-drift correlation time
    gyro_bias_sigma_rad_s: jax.Array = eqx.field(converter=_f64)
    gyro_bias_tau_s: jax.Array = eqx.field(converter=_f64)
    accel_scale_sigma: jax.Array = eqx.field(default=0.0, converter=_f64)  # unitless (1 = 100 %)
    accel_scale_tau_s: jax.Array = eqx.field(default=jnp.inf, converter=_f64)
    gyro_scale_sigma: jax.Array = eqx.field(default=0.0, converter=_f64)
    gyro_scale_tau_s: jax.Array = eqx.field(default=jnp.inf, converter=_f64)
    accel_bias_ton_sigma_m_s2: jax.Array = eqx.field(default=0.0, converter=_f64)  # turn-on
    gyro_bias_ton_sigma_rad_s: jax.Array = eqx.field(default=0.0, converter=_f64)


def _triad(x):
    return jnp.broadcast_to(x, (3,))


def _gm_params(model: ImuErrorModel, name: str):
    """(tau [s], steady-state sigma) of a GM sensor block, each (3,)."""
    tau, sigma = {
        "accel_bias": (model.accel_bias_tau_s, model.accel_bias_sigma_m_s2),
        "gyro_bias": (model.gyro_bias_tau_s, model.gyro_bias_sigma_rad_s),
        "accel_scale": (model.accel_scale_tau_s, model.accel_scale_sigma),
        "gyro_scale": (model.gyro_scale_tau_s, model.gyro_scale_sigma),
    }[name]
    return _triad(tau), _triad(sigma)


def noise_layout(layout: StateLayout) -> StateLayout:
    """Layout of the white-noise vector w driving ``layout`` (columns of G, rows of Qc).

    accel_noise (VRW, body axes), gyro_noise (ARW, body axes), then one driving block per GM
    sensor block present in ``layout`` (same name, same order). Turn-on biases have no noise.
    """
    blocks = [("accel_noise", 3), ("gyro_noise", 3)]
    blocks += [(name, 3) for name in layout.names if name in _GM_BLOCKS]
    return StateLayout(tuple(blocks))


def _radius_derivatives(lat):
    """dR_M/dlat = 3 R_M e^2 s c / W, dR_N/dlat = R_N e^2 s c / W with W = 1 - e^2 s^2."""
    r_m, r_n = geodesy.radii(lat)
    s, c = jnp.sin(lat), jnp.cos(lat)
    k = geodesy.E2_WGS84 * s * c / (1.0 - geodesy.E2_WGS84 * s * s)
    return r_m, r_n, 3.0 * r_m * k, r_n * k


def _nav_partials(llh, vel_enu):
    """Partials of D^-1 v, w_ie^l and w_el^l w.r.t. (lat, lon, h) and v (3x3 each)."""
    lat, h = llh[0], llh[2]
    ve, vn = vel_enu[0], vel_enu[1]
    r_m, r_n, dr_m, dr_n = _radius_derivatives(lat)
    rho_m, rho_n = r_m + h, r_n + h
    s, c, t = jnp.sin(lat), jnp.cos(lat), jnp.tan(lat)
    z = jnp.zeros_like(lat)
    we = geodesy.OMEGA_E

    # Position rates: lat' = vn / rho_m, lon' = ve / (rho_n cos lat), h' = vu.
    F_rr = jnp.array(
        [
            [-vn * dr_m / rho_m**2, z, -vn / rho_m**2],
            [ve * (t / (rho_n * c) - dr_n / (rho_n**2 * c)), z, -ve / (rho_n**2 * c)],
            [z, z, z],
        ]
    )
    F_rv = geodesy.llh_rate_matrix(llh)
    # Earth rate [0, we c, we s] and transport rate [-vn/rho_m, ve/rho_n, ve t/rho_n].
    dwie_dr = jnp.array([[z, z, z], [-we * s, z, z], [we * c, z, z]])
    dwel_dr = jnp.array(
        [
            [vn * dr_m / rho_m**2, z, vn / rho_m**2],
            [-ve * dr_n / rho_n**2, z, -ve / rho_n**2],
            [ve / (c * c * rho_n) - ve * t * dr_n / rho_n**2, z, -ve * t / rho_n**2],
        ]
    )
    dwel_dv = jnp.array([[z, -1.0 / rho_m, z], [1.0 / rho_n, z, z], [t / rho_n, z, z]])
    return F_rr, F_rv, dwie_dr, dwel_dr, dwel_dv


def _gravity_partials(llh):
    """d(g^l)/d(lat, lon, h): only the up row, -[dg/dlat, 0, dg/dh] (exact normal-gravity slope)."""
    dg_dlat, dg_dh = jax.grad(geodesy.normal_gravity, argnums=(0, 1))(llh[0], llh[2])
    z = jnp.zeros_like(dg_dlat)
    return jnp.array([[z, z, z], [z, z, z], [-dg_dlat, z, -dg_dh]])


class InputRates(NamedTuple):
    """Squared rates of change of the compensated inputs over one covariance step, with the
    sensor noise's share removed (``InsSystem.propagate``), and the step's length."""

    f_rate2_b: Float[Array, "3"]  # (df_b/dt)^2 [m^2/s^6]
    w_rate2_b: Float[Array, "3"]  # (dw_ib_b/dt)^2 [rad^2/s^4]
    span_s: Float[Array, ""]


def unmodelled_scale_psd(layout: StateLayout, model: ImuErrorModel, rates: InputRates
                         ) -> dict[str, Float[Array, "3"]]:
    """Extra bias-drift PSD for scale factors a layout does not estimate (INS15 on an IMU with
    scale errors; a Schmidt-style consider term without the states).

    With a constant scale error S ~ N(0, sigma_S^2) the bias state absorbs b + S f, which moves
    by S df when the input changes: over a step of length T its variance grows by
    sigma_S^2 (f' T)^2, i.e. a driving PSD sigma_S^2 f'^2 T on the bias block (the same for the
    gyro with w'). Successive increments are treated as independent, so an input that swings
    back and forth is over-counted (conservative) and a ramp split into many steps is
    under-counted by the number of steps. Without it INS15 on the SPAN-CPT (4000 / 1500 ppm)
    claims velocity sigmas 1.5-2x too small with carrier phase (issue 16). The over-count is
    large for periodic motion: a walker's 2-Hz steps at 1 % scale error drove the hand-held walk's
    complete 15-s outages from 11.6 to 48 m (docs/validation.md); estimate the scale factors
    (INS21/27) there."""
    out = {}
    for bias, scale, sigma, rate2 in (
        ("accel_bias", "accel_scale", model.accel_scale_sigma, rates.f_rate2_b),
        ("gyro_bias", "gyro_scale", model.gyro_scale_sigma, rates.w_rate2_b),
    ):
        if layout.has(bias) and not layout.has(scale):
            out[bias] = _triad(sigma) ** 2 * rate2 * rates.span_s
    return out


def error_dynamics(
    layout: StateLayout,
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    C_b_l: Float[ArrayLike, "3 3"],
    f_b: Float[ArrayLike, "3"],
    w_ib_b: Float[ArrayLike, "3"],
    model: ImuErrorModel,
    rates: InputRates | None = None,
) -> tuple[Float[Array, "n n"], Float[Array, "n q"], Float[Array, "q q"]]:
    """Continuous error model dx' = F dx + G w, E[w w^T] = Qc delta(t) (module docstring).

    ``f_b`` [m/s^2] and ``w_ib_b`` [rad/s] are the compensated body specific force and angular
    rate (e.g. increments / dt). ``layout`` must contain pos, vel, att; it may contain any of
    accel_bias, gyro_bias (GM drifts), accel_bias_ton, gyro_bias_ton (random constants),
    accel_scale, gyro_scale (GM); other blocks get zero rows. ``rates``: the inputs' rates of
    change over the step, for the scale factors the layout leaves out
    (``unmodelled_scale_psd``). Returns F (n, n), G (n, m), Qc (m, m) with the noise ordered by
    ``noise_layout(layout)``.
    """
    n = layout.size
    P, V, E = layout.sl("pos"), layout.sl("vel"), layout.sl("att")
    w_ie = geodesy.earth_rate_enu(llh[0])
    w_el = geodesy.transport_rate_enu(llh, vel_enu)
    F_rr, F_rv, dwie_dr, dwel_dr, dwel_dv = _nav_partials(llh, vel_enu)
    v_x = attitude.skew(vel_enu)
    f_l = C_b_l @ f_b

    F = jnp.zeros((n, n), jnp.float64)
    F = F.at[P, P].set(F_rr)
    F = F.at[P, V].set(F_rv)
    # -(2 dw_ie + dw_el) x v = [v x](2 dw_ie + dw_el)
    F = F.at[V, P].set(v_x @ (2.0 * dwie_dr + dwel_dr) + _gravity_partials(llh))
    F = F.at[V, V].set(-attitude.skew(2.0 * w_ie + w_el) + v_x @ dwel_dv)
    F = F.at[V, E].set(attitude.skew(f_l))
    F = F.at[E, P].set(dwie_dr + dwel_dr)
    F = F.at[E, V].set(dwel_dv)
    F = F.at[E, E].set(-attitude.skew(w_ie + w_el))

    # Sensor errors enter through C dfb (velocity) and -C dwb (attitude).
    into = {
        "accel_bias": (V, C_b_l),
        "accel_bias_ton": (V, C_b_l),
        "accel_scale": (V, C_b_l * f_b[None, :]),
        "gyro_bias": (E, -C_b_l),
        "gyro_bias_ton": (E, -C_b_l),
        "gyro_scale": (E, -C_b_l * w_ib_b[None, :]),
    }
    for name, (rows, block) in into.items():
        if layout.has(name):
            F = F.at[rows, layout.sl(name)].set(block)

    noise = noise_layout(layout)
    G = jnp.zeros((n, noise.size), jnp.float64)
    G = G.at[V, noise.sl("accel_noise")].set(C_b_l)
    G = G.at[E, noise.sl("gyro_noise")].set(-C_b_l)
    qc = jnp.zeros(noise.size, jnp.float64)
    qc = qc.at[noise.sl("accel_noise")].set(_triad(model.accel_vrw_m_s_sqrt_s) ** 2)
    qc = qc.at[noise.sl("gyro_noise")].set(_triad(model.gyro_arw_rad_sqrt_s) ** 2)
    for name in _GM_BLOCKS:
        if layout.has(name):
            tau, sigma = _gm_params(model, name)
            S = layout.sl(name)
            F = F.at[S, S].set(jnp.diag(-1.0 / tau))
            G = G.at[S, noise.sl(name)].set(jnp.eye(3))
            qc = qc.at[noise.sl(name)].set(2.0 * sigma**2 / tau)
    if rates is not None:
        for name, psd in unmodelled_scale_psd(layout, model, rates).items():
            qc = qc.at[noise.sl(name)].add(psd)
    return F, G, jnp.diag(qc)


def _turn_on_sigmas(model: ImuErrorModel, gyro_calibration_s: Float[ArrayLike, ""] | None
                    ) -> dict[str, Float[Array, "3"]]:
    """Turn-on bias sigmas by drift block: the model's, the gyro's ARW / sqrt(T) after a
    standstill calibration of T seconds (the mean of T seconds of white rate noise)."""
    gyro_ton = _triad(model.gyro_bias_ton_sigma_rad_s)
    if gyro_calibration_s is not None:
        gyro_ton = _triad(model.gyro_arw_rad_sqrt_s) / jnp.sqrt(gyro_calibration_s)
    return {"accel_bias": _triad(model.accel_bias_ton_sigma_m_s2), "gyro_bias": gyro_ton}


def sensor_initial_std(layout: StateLayout, model: ImuErrorModel,
                       gyro_calibration_s: Float[ArrayLike, ""] | None = None
                       ) -> Float[Array, " n"]:
    """Initial standard deviations of the sensor blocks (zeros for every other block).

    GM blocks start at their steady-state sigma; turn-on blocks at their turn-on sigma. In a
    layout without turn-on blocks (INS15, INS21) the single bias block also carries the turn-on
    bias, so its sigma is sqrt(sigma_drift^2 + sigma_ton^2). After a standstill gyro
    calibration of ``gyro_calibration_s`` seconds the turn-on part is known to
    ARW / sqrt(T) instead (the mean of T seconds of white rate noise).
    """
    std = jnp.zeros(layout.size, jnp.float64)
    ton = _turn_on_sigmas(model, gyro_calibration_s)
    for name in _GM_BLOCKS:
        if layout.has(name):
            _, sigma = _gm_params(model, name)
            if name in ton and not layout.has(name + "_ton"):
                sigma = jnp.sqrt(sigma**2 + ton[name] ** 2)
            std = std.at[layout.sl(name)].set(sigma)
    for name in _TON_BLOCKS:
        if layout.has(name):
            std = std.at[layout.sl(name)].set(ton[name.removesuffix("_ton")])
    return std


# ---- closed-loop feedback -------------------------------------------------------------------


class SensorErrors(NamedTuple):
    """Running estimate of the raw IMU errors: meas = (1 + S) true + b (elementwise, S001 eq 12).

    ``accel_bias_m_s2`` / ``gyro_bias_rad_s`` are the total biases removed; ``*_gm`` is the part
    of them the filter estimated into its Gauss-Markov drift states, which ``decay`` lets decay
    as the model says (the rest, start-up calibration and turn-on states, is constant).
    """

    accel_bias_m_s2: Float[Array, "3"]
    gyro_bias_rad_s: Float[Array, "3"]
    accel_scale: Float[Array, "3"]  # unitless
    gyro_scale: Float[Array, "3"]  # unitless
    accel_bias_gm_m_s2: Float[Array, "3"]  # Gauss-Markov share of accel_bias_m_s2
    gyro_bias_gm_rad_s: Float[Array, "3"]  # Gauss-Markov share of gyro_bias_rad_s

    @classmethod
    def zeros(cls) -> SensorErrors:
        z = jnp.zeros(3, jnp.float64)
        return cls(z, z, z, z, z, z)


def feedback(nav: NavState, dx: Float[Array, " n"], layout: StateLayout) -> NavState:
    """Remove the estimated navigation errors: x <- x_hat - dx, C <- exp([eps x]) C_hat.

    The attitude correction is ``attitude.correct_attitude`` written with quaternions:
    q <- q(eps) (x) q_hat. The caller resets dx to zero afterwards.
    """
    llh = nav.llh - dx[layout.sl("pos")]
    vel = nav.vel_enu - dx[layout.sl("vel")]
    q = attitude.quat_multiply(attitude.quat_from_rotvec(dx[layout.sl("att")]), nav.q_b_l)
    return NavState(llh, vel, attitude.quat_normalize(q))


def _block(dx, layout, name):
    return dx[layout.sl(name)] if layout.has(name) else jnp.zeros(3, dx.dtype)


def gm_share(model: ImuErrorModel, layout: StateLayout,
             gyro_calibration_s: Float[ArrayLike, ""] | None = None,
             ) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
    """Fraction of an accel / gyro bias-block correction that is Gauss-Markov drift.

    1 where the layout has the turn-on block beside it (INS27: the split is estimated). A layout
    without it (INS15, INS21) lumps turn-on + drift into one block (``sensor_initial_std``);
    its correction is split by the prior variances, sigma_gm^2 / (sigma_gm^2 + sigma_ton^2),
    the best linear split of one innovation between two states observed alike, so that a
    tactical IMU's 50-mg turn-on estimate is not decayed as if it were 0.75-mg drift. After a
    standstill gyro calibration the gyro's turn-on prior is ARW / sqrt(T), as in
    ``sensor_initial_std``.
    """
    out = []
    for name, ton in _turn_on_sigmas(model, gyro_calibration_s).items():
        _, sigma = _gm_params(model, name)
        ton = 0.0 if layout.has(name + "_ton") else ton
        var = sigma**2 + ton**2
        out.append(jnp.where(var > 0.0, sigma**2 / jnp.where(var > 0.0, var, 1.0), 1.0))
    return out[0], out[1]


def feedback_sensors(
    sensor: SensorErrors, dx: Float[Array, " n"], layout: StateLayout,
    share: tuple[Float[ArrayLike, "3"], Float[ArrayLike, "3"]] = (1.0, 1.0),
) -> SensorErrors:
    """Fold estimated output errors (bias drift + turn-on, scale) into the raw-error estimate.

    With compensation f_used = (f_meas - b_hat) / (1 + S_hat), the output error is
    f_used - f = [(S - S_hat) f + (b - b_hat)] / (1 + S_hat) =: diag(f) dS + db, so the raw
    errors are S = S_hat + (1 + S_hat) dS and b = b_hat + (1 + S_hat) db (exact, not only to
    first order). Blocks missing from ``layout`` contribute zero. ``share`` (``gm_share``) is
    the part of the drift blocks' correction kept in the Gauss-Markov shares that ``decay``
    decays.
    """
    gm_a = share[0] * _block(dx, layout, "accel_bias")
    gm_g = share[1] * _block(dx, layout, "gyro_bias")
    db_a = _block(dx, layout, "accel_bias") + _block(dx, layout, "accel_bias_ton")
    db_g = _block(dx, layout, "gyro_bias") + _block(dx, layout, "gyro_bias_ton")
    ka = 1.0 + sensor.accel_scale
    kg = 1.0 + sensor.gyro_scale
    return SensorErrors(
        sensor.accel_bias_m_s2 + ka * db_a,
        sensor.gyro_bias_rad_s + kg * db_g,
        sensor.accel_scale + ka * _block(dx, layout, "accel_scale"),
        sensor.gyro_scale + kg * _block(dx, layout, "gyro_scale"),
        sensor.accel_bias_gm_m_s2 + ka * gm_a,
        sensor.gyro_bias_gm_rad_s + kg * gm_g,
    )


def decay(sensor: SensorErrors, model: ImuErrorModel, layout: StateLayout,
          dt: Float[ArrayLike, ""]) -> SensorErrors:
    """Predict the sensor estimates over dt as the error model does: x_hat <- exp(-dt/tau) x_hat
    for each Gauss-Markov block of ``layout`` (b' = -b/tau, S001 eq 13); the constant parts
    (calibration, turn-on states, tau = inf) stay. Without it the true bias decays while its
    estimate holds, and the error e = b_hat - b gains the unmodelled drift b_hat / tau."""
    def factor(name):
        tau, _ = _gm_params(model, name)
        return jnp.exp(-dt / tau) if layout.has(name) else jnp.ones(3)

    fa, fg = factor("accel_bias"), factor("gyro_bias")
    gm_a, gm_g = sensor.accel_bias_gm_m_s2, sensor.gyro_bias_gm_rad_s
    return SensorErrors(
        sensor.accel_bias_m_s2 - (1.0 - fa) * gm_a,
        sensor.gyro_bias_rad_s - (1.0 - fg) * gm_g,
        sensor.accel_scale * factor("accel_scale"),
        sensor.gyro_scale * factor("gyro_scale"),
        fa * gm_a,
        fg * gm_g,
    )


def correct_imu(
    imu: ImuIncrements, sensor: SensorErrors, dt: Float[ArrayLike, ""] | Float[ArrayLike, " N"]
) -> ImuIncrements:
    """Invert S001 eq 12: dtheta = (dtheta_meas - b_g dt) / (1 + S_g); dv likewise. (3,)/(N, 3)."""
    dt = jnp.asarray(dt, jnp.float64)[..., None]
    return ImuIncrements(
        (imu.dtheta_b - sensor.gyro_bias_rad_s * dt) / (1.0 + sensor.gyro_scale),
        (imu.dv_b - sensor.accel_bias_m_s2 * dt) / (1.0 + sensor.accel_scale),
    )


def corrupt_imu(
    imu: ImuIncrements, sensor: SensorErrors, dt: Float[ArrayLike, ""] | Float[ArrayLike, " N"]
) -> ImuIncrements:
    """S001 eq 12 forward: dtheta_meas = (1 + S_g) dtheta + b_g dt; dv likewise with S_a, b_a."""
    dt = jnp.asarray(dt, jnp.float64)[..., None]
    return ImuIncrements(
        (1.0 + sensor.gyro_scale) * imu.dtheta_b + sensor.gyro_bias_rad_s * dt,
        (1.0 + sensor.accel_scale) * imu.dv_b + sensor.accel_bias_m_s2 * dt,
    )


# ---- lever-arm Jacobians (for strapdown.antenna_llh / antenna_vel_enu) -------------------------


def antenna_llh_jacobian(
    layout: StateLayout,
    llh: Float[ArrayLike, "3"],
    C_b_l: Float[ArrayLike, "3 3"],
    lever_b: Float[ArrayLike, "3"],
) -> Float[Array, "3 n"]:
    """d(llh_ant)/d(dx) for llh_ant = llh + D^-1 C l: I + d(D^-1 u)/dr on pos, D^-1 [u x] on att.

    u = C_b^l l^b; the attitude column follows from C_hat l = u + u x eps. Shape (3, n).
    """
    u = C_b_l @ lever_b
    lat, h = llh[0], llh[2]
    r_m, r_n, dr_m, dr_n = _radius_derivatives(lat)
    rho_m, rho_n = r_m + h, r_n + h
    c, t = jnp.cos(lat), jnp.tan(lat)
    z = jnp.zeros_like(lat)
    # d(D^-1 u)/d(lat, lon, h) with u_E, u_N the east and north lever components.
    dDu = jnp.array(
        [
            [-u[1] * dr_m / rho_m**2, z, -u[1] / rho_m**2],
            [u[0] * (t / (rho_n * c) - dr_n / (rho_n**2 * c)), z, -u[0] / (rho_n**2 * c)],
            [z, z, z],
        ]
    )
    H = jnp.zeros((3, layout.size), jnp.float64)
    H = H.at[:, layout.sl("pos")].set(jnp.eye(3) + dDu)
    H = H.at[:, layout.sl("att")].set(geodesy.llh_rate_matrix(llh) @ attitude.skew(u))
    return H


def antenna_vel_jacobian(
    layout: StateLayout,
    llh: Float[ArrayLike, "3"],
    vel_enu: Float[ArrayLike, "3"],
    C_b_l: Float[ArrayLike, "3 3"],
    w_ib_b: Float[ArrayLike, "3"],
    lever_b: Float[ArrayLike, "3"],
) -> Float[Array, "3 n"]:
    """d(antenna ENU velocity)/d(dx) for v_ant = v + C (w_ib x l) - w_ie x (C l). Shape (3, n).

    Terms: I on vel; [(C (w x l)) x] - [w_ie x][u x] on att (u = C l); [u x] dw_ie/dlat on pos;
    -C [l x] on the gyro bias (drift and turn-on) and -C [l x] diag(w) on the gyro scale factor.
    """
    u = C_b_l @ lever_b
    w_ie = geodesy.earth_rate_enu(llh[0])
    _, _, dwie_dr, _, _ = _nav_partials(llh, vel_enu)
    H = jnp.zeros((3, layout.size), jnp.float64)
    H = H.at[:, layout.sl("vel")].set(jnp.eye(3))
    H = H.at[:, layout.sl("pos")].set(attitude.skew(u) @ dwie_dr)
    H = H.at[:, layout.sl("att")].set(
        attitude.skew(C_b_l @ jnp.cross(w_ib_b, lever_b)) - attitude.skew(w_ie) @ attitude.skew(u)
    )
    dv_dw = -C_b_l @ attitude.skew(lever_b)
    for name in ("gyro_bias", "gyro_bias_ton"):
        if layout.has(name):
            H = H.at[:, layout.sl(name)].set(dv_dw)
    if layout.has("gyro_scale"):
        H = H.at[:, layout.sl("gyro_scale")].set(dv_dw * w_ib_b[None, :])
    return H
