"""Full-IMU error model: analytic F against autodiff of the nonlinear model, feedback, sensors.

The reference for F is independent of errors.py: the rate of the error definition
err(x_hat, x) (error = estimated - true, C_hat = (I - [eps x]) C, geodetic position errors)
differentiated along the nonlinear dynamics ``strapdown.nav_rate`` of truth and estimate.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.linalg import expm

import jaxnav  # noqa: F401  (enables float64)
from jaxnav import attitude, geodesy
from jaxnav.core.states import INS15, INS21, INS27
from jaxnav.ins import errors, strapdown

MODEL = errors.ImuErrorModel(
    accel_vrw_m_s_sqrt_s=1e-3,
    gyro_arw_rad_sqrt_s=[1e-5, 2e-5, 3e-5],
    accel_bias_sigma_m_s2=1e-3,
    accel_bias_tau_s=3600.0,
    gyro_bias_sigma_rad_s=5e-6,
    gyro_bias_tau_s=[1800.0, 2000.0, 2500.0],
    accel_scale_sigma=1e-3,
    accel_scale_tau_s=7200.0,
    gyro_scale_sigma=2e-3,
    gyro_scale_tau_s=9000.0,
    accel_bias_ton_sigma_m_s2=5e-3,
    gyro_bias_ton_sigma_rad_s=1e-4,
)
LAYOUTS = {"INS15": INS15, "INS21": INS21, "INS27": INS27}


def _sensor_output_errors(dx, layout):
    """Output errors of the compensated IMU from the sensor blocks (each (3,) or zero)."""

    def blk(name):
        return dx[layout.sl(name)] if layout.has(name) else jnp.zeros(3)

    return (
        blk("accel_bias") + blk("accel_bias_ton"),
        blk("gyro_bias") + blk("gyro_bias_ton"),
        blk("accel_scale"),
        blk("gyro_scale"),
    )


def _perturb(llh, vel, C, dx, layout):
    """Estimated navigation state from the truth and an error vector (exact error definition)."""
    llh_hat = llh + dx[layout.sl("pos")]
    vel_hat = vel + dx[layout.sl("vel")]
    # attitude_error(C_hat, C) = -rotvec(C_hat C^T) = eps exactly for this C_hat.
    C_hat = attitude.dcm_from_rotvec(-dx[layout.sl("att")]) @ C
    return llh_hat, vel_hat, C_hat


def _error_rate(dx, layout, llh, vel, C, f_b, w_b):
    """d/dt err(x_hat(t), x(t)) at t = 0 for the nonlinear model."""
    llh_hat, vel_hat, C_hat = _perturb(llh, vel, C, dx, layout)
    db_a, db_g, ds_a, ds_g = _sensor_output_errors(dx, layout)
    f_hat = f_b + db_a + f_b * ds_a
    w_hat = w_b + db_g + w_b * ds_g
    r_dot, v_dot, C_dot = strapdown.nav_rate(llh, vel, C, f_b, w_b)
    rh_dot, vh_dot, Ch_dot = strapdown.nav_rate(llh_hat, vel_hat, C_hat, f_hat, w_hat)
    _, eps_dot = jax.jvp(
        lambda t: attitude.attitude_error(C_hat + t * Ch_dot, C + t * C_dot), (0.0,), (1.0,)
    )
    rate = jnp.zeros(layout.size)
    rate = rate.at[layout.sl("pos")].set(rh_dot - r_dot)
    rate = rate.at[layout.sl("vel")].set(vh_dot - v_dot)
    rate = rate.at[layout.sl("att")].set(eps_dot)
    # Sensor states follow their stated stochastic model (GM: x' = -x/tau; turn-on: x' = 0).
    taus = {
        "accel_bias": MODEL.accel_bias_tau_s,
        "gyro_bias": MODEL.gyro_bias_tau_s,
        "accel_scale": MODEL.accel_scale_tau_s,
        "gyro_scale": MODEL.gyro_scale_tau_s,
    }
    for name, tau in taus.items():
        if layout.has(name):
            rate = rate.at[layout.sl(name)].set(-dx[layout.sl(name)] / tau)
    return rate


def _random_states(n, seed=0):
    """Moving, turning, tilted states at mid latitudes of both hemispheres."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        lat = np.radians(rng.uniform(25.0, 65.0)) * rng.choice([-1.0, 1.0])
        llh = jnp.array([lat, np.radians(rng.uniform(-180, 180)), rng.uniform(-50, 3000)])
        vel = jnp.array(rng.normal(0.0, 25.0, 3) * np.array([1.0, 1.0, 0.2]))
        euler = jnp.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(-3, 3)])
        C = attitude.dcm_from_euler(euler)
        f_b = C.T @ jnp.array([0.0, 0.0, 9.8]) + jnp.array(rng.normal(0.0, 2.0, 3))
        w_b = jnp.array(rng.normal(0.0, 0.3, 3))
        out.append((llh, vel, C, f_b, w_b))
    return out


def _unit_scales(layout, llh):
    """Per-state scale turning each state into comparable units (metres for position)."""
    r_m, r_n = geodesy.radii(llh[0])
    s = np.ones(layout.size)
    s[layout.sl("pos")] = [float(r_m + llh[2]), float((r_n + llh[2]) * jnp.cos(llh[0])), 1.0]
    return s


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_F_equals_autodiff_of_nonlinear_error_propagation(name):
    layout = LAYOUTS[name]
    f_analytic = jax.jit(lambda *a: errors.error_dynamics(layout, *a, MODEL)[0])
    f_auto = jax.jit(lambda *a: jax.jacfwd(_error_rate)(jnp.zeros(layout.size), layout, *a))
    worst = 0.0
    for state in _random_states(6, seed=layout.size):
        F = np.asarray(f_analytic(*state))
        Fa = np.asarray(f_auto(*state))
        # Compare in metres for position so entries span a sensible dynamic range.
        s = _unit_scales(layout, state[0])
        Fs, Fas = F * s[:, None] / s[None, :], Fa * s[:, None] / s[None, :]
        scale = np.abs(Fas).max()
        # Entry-wise: 1e-9 relative, plus 1e-15 of the largest entry for round-off around 0.
        np.testing.assert_array_less(np.abs(Fs - Fas), 1e-9 * np.abs(Fas) + 1e-15 * scale)
        big = np.abs(Fas) > 1e-12 * scale
        worst = max(worst, (np.abs(Fs - Fas)[big] / np.abs(Fas)[big]).max())
        # Every non-zero of the autodiff F must be present, and nothing spurious elsewhere.
        assert np.array_equal(np.abs(Fas) > 1e-14 * scale, np.abs(Fs) > 1e-14 * scale)
    assert worst < 1e-9, f"{name}: worst relative entry error {worst:.2e}"


def test_gm_sensor_blocks_are_stationary_at_their_steady_state_sigma():
    # For a GM state P' = F P + P F^T + G Qc G^T must vanish at P = sigma^2 (stationarity).
    llh, vel, C, f_b, w_b = _random_states(1, seed=3)[0]
    F, G, Qc = errors.error_dynamics(INS27, llh, vel, C, f_b, w_b, MODEL)
    std = errors.sensor_initial_std(INS27, MODEL)
    for name in ("accel_bias", "gyro_bias", "accel_scale", "gyro_scale"):
        S = INS27.sl(name)
        P = jnp.diag(std[S] ** 2)
        dP = F[S, S] @ P + P @ F[S, S].T + (G @ Qc @ G.T)[S, S]
        np.testing.assert_allclose(dP, 0.0, atol=1e-12 * float(jnp.max(jnp.diag(P))))
    # Turn-on biases: no dynamics, no noise, std = turn-on sigma.
    for name, sig in (("accel_bias_ton", 5e-3), ("gyro_bias_ton", 1e-4)):
        S = INS27.sl(name)
        assert float(jnp.abs(F[S]).max()) == 0.0 and float(jnp.abs(G[S]).max()) == 0.0
        np.testing.assert_allclose(std[S], sig)
    # VRW / ARW enter velocity and attitude with unit gain: G Qc G^T = C diag(q) C^T.
    GQG = G @ Qc @ G.T
    np.testing.assert_allclose(GQG[INS27.sl("vel"), INS27.sl("vel")], 1e-6 * jnp.eye(3), atol=1e-18)
    np.testing.assert_allclose(
        GQG[INS27.sl("att"), INS27.sl("att")],
        C @ jnp.diag(jnp.array([1e-10, 4e-10, 9e-10])) @ C.T,
        atol=1e-22,
    )


def test_linear_model_predicts_mechanized_error_growth():
    # Stationary, tilted IMU with constant sensor errors and an initial navigation error:
    # the discrete nonlinear mechanization must follow expm(F t) dx0 (F constant at rest).
    layout = INS21
    model = errors.ImuErrorModel(1e-3, 1e-5, 1e-3, jnp.inf, 1e-5, jnp.inf, 1e-3, jnp.inf, 1e-3)
    llh0 = jnp.array([np.radians(45.0), np.radians(10.0), 200.0])
    truth = strapdown.nav_state(llh0, jnp.zeros(3), jnp.array([0.08, -0.05, 0.5]))
    C = truth.C_b_l
    dt, n = 0.02, 15000  # 300 s
    imu = strapdown.stationary_imu(llh0, C, dt)
    sensor = errors.SensorErrors(
        jnp.array([5e-4, -2.5e-4, 7.5e-4]),
        jnp.array([2.5e-6, -5e-6, 3.75e-6]),
        jnp.array([2.5e-4, -5e-4, 1.25e-4]),
        jnp.array([7.5e-4, 2.5e-4, -5e-4]),
        jnp.zeros(3),  # (the filter's Gauss-Markov shares: not used by corrupt / correct)
        jnp.zeros(3),
    )
    meas = errors.corrupt_imu(imu, sensor, dt)
    seq = strapdown.ImuIncrements(*(jnp.tile(a, (n, 1)) for a in meas))
    dx0 = jnp.zeros(layout.size)
    dx0 = dx0.at[layout.sl("pos")].set(jnp.array([2.5e-7, -5e-7, 0.375]))
    dx0 = dx0.at[layout.sl("vel")].set(jnp.array([0.0125, -0.0075, 0.005]))
    dx0 = dx0.at[layout.sl("att")].set(jnp.array([5e-5, -2.5e-5, 7.5e-4]))
    dx0 = dx0.at[layout.sl("accel_bias")].set(sensor.accel_bias_m_s2)
    dx0 = dx0.at[layout.sl("gyro_bias")].set(sensor.gyro_bias_rad_s)
    dx0 = dx0.at[layout.sl("accel_scale")].set(sensor.accel_scale)
    dx0 = dx0.at[layout.sl("gyro_scale")].set(sensor.gyro_scale)
    llh_h, vel_h, C_h = _perturb(truth.llh, truth.vel_enu, C, dx0, layout)
    nav_hat = strapdown.NavState(llh_h, vel_h, attitude.quat_from_dcm(C_h))
    _, hist = jax.jit(lambda a, b: strapdown.mechanize(a, b, dt))(nav_hat, seq)

    F, _, _ = errors.error_dynamics(
        layout, llh0, jnp.zeros(3), C, imu.dv_b / dt, imu.dtheta_b / dt, model
    )
    for k in (2999, 8999, 14999):
        t = (k + 1) * dt
        pred = expm(F * t) @ dx0
        got = jnp.concatenate(
            [
                hist.llh[k] - llh0,
                hist.vel_enu[k],
                attitude.attitude_error(attitude.dcm_from_quat(hist.q_b_l[k]), C),
            ]
        )
        s = _unit_scales(layout, llh0)[:9]
        p_m, g_m = pred[:9] * s, got * s
        # Errors reach 210 m, 2.2 m/s, 1.6 mrad at 300 s; the nonlinear remainder (measured
        # <= 0.064 %, halving with the perturbation) must stay below 0.2 % of each block's size.
        for blk in (slice(0, 3), slice(3, 6), slice(6, 9)):
            tol = 2e-3 * float(jnp.abs(p_m[blk]).max())
            np.testing.assert_allclose(g_m[blk], p_m[blk], atol=tol, err_msg=f"t={t}")


def test_antenna_jacobians_equal_autodiff():
    layout = INS27
    lever_b = jnp.array([0.4, 1.3, 1.6])
    for llh, vel, C, _f_b, w_b in _random_states(4, seed=11):

        def ant(dx, llh=llh, vel=vel, C=C, w_b=w_b):
            llh_h, vel_h, C_h = _perturb(llh, vel, C, dx, layout)
            _, db_g, _, ds_g = _sensor_output_errors(dx, layout)
            w_h = w_b + db_g + w_b * ds_g
            return (
                strapdown.antenna_llh(llh_h, C_h, lever_b),
                strapdown.antenna_vel_enu(llh_h, vel_h, C_h, w_h, lever_b),
            )

        Jp, Jv = jax.jacfwd(ant)(jnp.zeros(layout.size))
        Hp = errors.antenna_llh_jacobian(layout, llh, C, lever_b)
        Hv = errors.antenna_vel_jacobian(layout, llh, vel, C, w_b, lever_b)
        np.testing.assert_allclose(Hp, Jp, rtol=1e-10, atol=1e-18)
        np.testing.assert_allclose(Hv, Jv, rtol=1e-10, atol=1e-16)


def test_antenna_velocity_is_derivative_of_antenna_position():
    # Finite-difference the lever-arm position along the true motion (body rotating at w_ib).
    llh, vel, C, f_b, w_b = _random_states(1, seed=5)[0]
    lever_b = jnp.array([-0.3, 2.0, 1.2])

    def ecef_ant(t):
        llh_dot, _, _ = strapdown.nav_rate(llh, vel, C, f_b, w_b)
        w_il = geodesy.earth_rate_enu(llh[0]) + geodesy.transport_rate_enu(llh, vel)
        # Exact attitude flow for constant rates; position to first order in t (enough for d/dt).
        C_t = attitude.dcm_from_rotvec(-w_il * t) @ C @ attitude.dcm_from_rotvec(w_b * t)
        llh_t = llh + llh_dot * t
        return geodesy.llh_to_ecef(llh_t) + geodesy.enu_to_ecef(C_t @ lever_b, llh_t)

    v_ecef = jax.jvp(ecef_ant, (0.0,), (1.0,))[1]
    v_ant = strapdown.antenna_vel_enu(llh, vel, C, w_b, lever_b)
    np.testing.assert_allclose(geodesy.ecef_to_enu(v_ecef, llh), v_ant, atol=1e-9)


@pytest.mark.parametrize("layout", [INS15, INS27])
def test_feedback_recovers_truth_to_second_order(layout):
    llh, vel, C, _, _ = _random_states(1, seed=7)[0]
    euler = attitude.euler_from_dcm(C)
    truth = strapdown.NavState(llh, vel, attitude.quat_from_dcm(C))
    d_enu = jnp.array([3.0, -4.0, 2.0])  # m
    d_vel = jnp.array([0.3, -0.2, 0.1])
    d_eul = jnp.array([0.01, -0.02, 0.03])  # rad

    def residual(s):
        # Perturb in independent coordinates (ECEF offset, Euler angles) ...
        llh_h = geodesy.ecef_to_llh(geodesy.llh_to_ecef(llh) + geodesy.enu_to_ecef(s * d_enu, llh))
        C_h = attitude.dcm_from_euler(euler + s * d_eul)
        nav_hat = strapdown.NavState(llh_h, vel + s * d_vel, attitude.quat_from_dcm(C_h))
        # ... and estimate dx with the first-order relations only.
        r_m, r_n = geodesy.radii(llh[0])
        dpos = s * jnp.array(
            [d_enu[1] / (r_m + llh[2]), d_enu[0] / ((r_n + llh[2]) * jnp.cos(llh[0])), d_enu[2]]
        )
        eps = jax.jacfwd(lambda e: attitude.attitude_error(attitude.dcm_from_euler(e), C))(euler)
        dx = jnp.zeros(layout.size)
        dx = dx.at[layout.sl("pos")].set(dpos)
        dx = dx.at[layout.sl("vel")].set(s * d_vel)
        dx = dx.at[layout.sl("att")].set(eps @ (s * d_eul))
        fixed = errors.feedback(nav_hat, dx, layout)
        pos_res = jnp.linalg.norm(geodesy.llh_error_to_enu(fixed.llh - truth.llh, llh))
        vel_res = jnp.linalg.norm(fixed.vel_enu - truth.vel_enu)
        att_res = jnp.linalg.norm(attitude.attitude_error(fixed.C_b_l, C))
        return pos_res, vel_res, att_res

    p1, v1, a1 = residual(1.0)
    p2, v2, a2 = residual(0.5)
    assert float(v1) < 1e-14  # velocity is linear
    # Quadratic: halving the perturbation divides the residual by ~4.
    assert 3.5 < float(p1 / p2) < 4.5, (p1, p2)
    assert 3.5 < float(a1 / a2) < 4.5, (a1, a2)
    # ... and the residual is second-order small against the perturbation itself.
    assert float(p1) < 1e-5 * float(jnp.linalg.norm(d_enu))
    assert float(a1) < 0.05 * float(jnp.linalg.norm(d_eul))


def test_sensor_feedback_and_imu_compensation():
    rng = np.random.default_rng(1)
    dt = 0.005
    true_imu = strapdown.ImuIncrements(
        jnp.array(rng.normal(0, 0.5, (50, 3))) * dt, jnp.array(rng.normal(0, 5.0, (50, 3))) * dt
    )
    raw = errors.SensorErrors(
        jnp.array([0.02, -0.01, 0.05]),
        jnp.array([1e-3, -2e-3, 5e-4]),
        jnp.array([0.01, -0.02, 0.005]),
        jnp.array([-0.01, 0.03, 0.002]),
        jnp.zeros(3),
        jnp.zeros(3),
    )
    meas = errors.corrupt_imu(true_imu, raw, dt)
    # Inverse model recovers the true increments.
    back = errors.correct_imu(meas, raw, dt)
    np.testing.assert_allclose(back.dtheta_b, true_imu.dtheta_b, rtol=0, atol=1e-16)
    np.testing.assert_allclose(back.dv_b, true_imu.dv_b, rtol=0, atol=1e-15)

    # A wrong estimate leaves output errors f_used - f = db + diag(f) dS; measure db, dS by a
    # per-axis straight-line fit of the compensated output error against the true rate.
    est = errors.SensorErrors(
        jnp.array([0.015, 0.0, 0.04]),
        jnp.array([0.0, -1e-3, 1e-3]),
        jnp.array([0.0, -0.01, 0.0]),
        jnp.array([-0.02, 0.0, 0.001]),
        jnp.zeros(3),
        jnp.zeros(3),
    )
    used = errors.correct_imu(meas, est, dt)

    def fit(x, y):
        A = np.stack([np.ones_like(x), x], axis=1)
        return np.linalg.lstsq(A, y, rcond=None)[0]

    db_a, ds_a, db_g, ds_g = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    for i in range(3):
        f, w = np.asarray(true_imu.dv_b[:, i]) / dt, np.asarray(true_imu.dtheta_b[:, i]) / dt
        db_a[i], ds_a[i] = fit(f, np.asarray(used.dv_b[:, i]) / dt - f)
        db_g[i], ds_g[i] = fit(w, np.asarray(used.dtheta_b[:, i]) / dt - w)
    for layout in (INS21, INS27):
        dx = jnp.zeros(layout.size)
        if layout.has("accel_bias_ton"):  # split the bias between drift and turn-on blocks
            dx = dx.at[layout.sl("accel_bias")].set(0.3 * db_a)
            dx = dx.at[layout.sl("accel_bias_ton")].set(0.7 * db_a)
            dx = dx.at[layout.sl("gyro_bias")].set(0.6 * db_g)
            dx = dx.at[layout.sl("gyro_bias_ton")].set(0.4 * db_g)
        else:
            dx = dx.at[layout.sl("accel_bias")].set(db_a)
            dx = dx.at[layout.sl("gyro_bias")].set(db_g)
        dx = dx.at[layout.sl("accel_scale")].set(ds_a)
        dx = dx.at[layout.sl("gyro_scale")].set(ds_g)
        new = errors.feedback_sensors(est, dx, layout)
        for got, want in zip(new[:4], raw[:4], strict=True):  # the total errors
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-13)
        # the Gauss-Markov shares take the drift blocks' part only (the one errors.decay decays)
        share_a, share_g = (0.3, 0.6) if layout.has("accel_bias_ton") else (1.0, 1.0)
        np.testing.assert_allclose(new.accel_bias_gm_m_s2, share_a * (raw.accel_bias_m_s2
                                   - est.accel_bias_m_s2), rtol=1e-9, atol=1e-13)
        np.testing.assert_allclose(new.gyro_bias_gm_rad_s, share_g * (raw.gyro_bias_rad_s
                                   - est.gyro_bias_rad_s), rtol=1e-9, atol=1e-13)


def test_unmodelled_scale_factors_drive_the_bias_of_a_layout_without_them():
    """INS15 on an IMU with scale errors: the bias absorbs b + S f, whose change over a step T
    is S f' T, so the bias PSD gains sigma_S^2 f'^2 T (errors.unmodelled_scale_psd); INS21
    estimates S and gains nothing."""
    llh, vel, C = jnp.array([0.9, 0.1, 50.0]), jnp.array([3.0, 4.0, 0.0]), jnp.eye(3)
    f_b, w_b = jnp.array([0.5, 0.0, 9.8]), jnp.array([0.0, 0.0, 0.2])
    rates = errors.InputRates(jnp.array([0.25, 0.0, 0.01]), jnp.array([0.0, 0.0, 0.04]),
                              jnp.asarray(1.0))
    for layout, extra in ((INS15, True), (INS21, False)):
        _, _, Q0 = errors.error_dynamics(layout, llh, vel, C, f_b, w_b, MODEL)
        _, _, Q1 = errors.error_dynamics(layout, llh, vel, C, f_b, w_b, MODEL, rates)
        noise = errors.noise_layout(layout)
        d = np.diag(np.asarray(Q1 - Q0))
        if extra:
            np.testing.assert_allclose(d[noise.sl("accel_bias")],
                                       1e-3**2 * np.array([0.25, 0.0, 0.01]), rtol=1e-12)
            np.testing.assert_allclose(d[noise.sl("gyro_bias")],
                                       2e-3**2 * np.array([0.0, 0.0, 0.04]), rtol=1e-12)
        else:
            assert np.all(d == 0.0)


def test_input_rates_recover_a_ramp_and_discount_white_noise():
    """InsSystem's input rates: the least-squares slope of a noise-free ramp f = f0 + a t is a
    (squared, to round-off); on white noise of the model's VRW alone the debiased square is
    below the raw slope's variance (the noise share is removed)."""
    from jaxnav.filter import loose
    from jaxnav.filter.systems import InsSystem
    from jaxnav.sim.sensors import span_cpt

    model = loose.imu_error_model(span_cpt())
    system = InsSystem(INS15, model)
    dt, K = 0.01, 100
    t = (jnp.arange(K) + 0.5) * dt
    a = jnp.array([0.3, -0.1, 0.0])
    dv = (jnp.array([0.2, 0.1, 9.8]) + t[:, None] * a) * dt
    inc = strapdown.ImuIncrements(jnp.zeros((K, 3)), dv)
    r = system._input_rates(inc, dt)
    vrw2 = float(jnp.broadcast_to(model.accel_vrw_m_s_sqrt_s, (3,))[0]) ** 2
    noise_var = vrw2 / dt / float(jnp.sum((t - t.mean()) ** 2))
    np.testing.assert_allclose(np.asarray(r.f_rate2_b), np.maximum(np.asarray(a) ** 2 - noise_var,
                                                                     0.0), rtol=1e-9, atol=1e-15)
    assert float(r.span_s) == pytest.approx(K * dt)
    rng = np.random.default_rng(0)
    white = jnp.asarray(rng.normal(size=(4000, K, 3)) * np.sqrt(vrw2 * dt))
    tc = t - t.mean()
    raw = jax.vmap(lambda x: (tc @ (x / dt) / jnp.sum(tc**2)) ** 2)(white)
    deb = jax.vmap(lambda x: system._input_rates(strapdown.ImuIncrements(x, x), dt).f_rate2_b
                   )(white)
    assert float(raw.mean()) == pytest.approx(noise_var, rel=0.05)  # the slope's noise variance
    assert float(deb.mean()) < 0.6 * noise_var  # E[max(0, chi2_1 - 1)] = 0.48
