"""Strapdown mechanization against physics: rest, an independent integrator, Schuler, gyro-bias
closed forms, coning and sculling."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (enables float64)
from jaxnav import attitude, geodesy
from jaxnav.ins import errors, strapdown

LLH45 = jnp.array([math.radians(45.0), math.radians(7.0), 300.0])
GL_X, GL_W = np.polynomial.legendre.leggauss(8)


def _interval_integrals(fun, t0, dt):
    """Gauss-Legendre (8 nodes, exact to t^15) integral of fun(t) over (t0, t0 + dt] per t0."""
    nodes = t0[:, None] + 0.5 * dt * (jnp.asarray(GL_X)[None, :] + 1.0)
    vals = jax.vmap(jax.vmap(fun))(nodes)
    return jnp.einsum("k,nkj->nj", jnp.asarray(GL_W) * 0.5 * dt, vals)


def _tile(imu, n):
    return strapdown.ImuIncrements(jnp.tile(imu.dtheta_b, (n, 1)), jnp.tile(imu.dv_b, (n, 1)))


def _enu_error(llh_hat, llh):
    return geodesy.llh_error_to_enu(llh_hat - llh, llh)


def _clamped_height_run(nav0, imu, dt, n):
    """Mechanize a constant IMU sample with the height and vertical velocity reset to the truth
    (perfect height aiding) each step, to isolate the horizontal channels from the unstable
    vertical one. Returns the history."""
    h0 = nav0.llh[2]

    def body(nav, _):
        nav = strapdown.mechanize_step(nav, imu, imu, dt)
        nav = strapdown.NavState(nav.llh.at[2].set(h0), nav.vel_enu.at[2].set(0.0), nav.q_b_l)
        return nav, nav

    return jax.lax.scan(body, nav0, None, length=n)[1]


@pytest.mark.parametrize(
    "euler_deg", [(0.0, 0.0, 30.0), (12.0, -8.0, 200.0)], ids=["level", "tilted"]
)
def test_perfect_stationary_imu_stays_within_1mm_over_1h(euler_deg):
    nav0 = strapdown.nav_state(LLH45, jnp.zeros(3), jnp.radians(jnp.array(euler_deg)))
    dt, n = 0.01, 360_000  # 1 h at 100 Hz
    seq = _tile(strapdown.stationary_imu(LLH45, nav0.C_b_l, dt), n)
    nav, _ = jax.jit(lambda a, b: strapdown.mechanize(a, b, dt))(nav0, seq)
    pos_err = float(jnp.linalg.norm(_enu_error(nav.llh, LLH45)))
    # Measured 2e-7 m (level) and 1.2e-4 m (tilted): round-off (a 1e-11 rad tilt after 360 000
    # quaternion products), not truncation; at 50 Hz the tilted case gives 5e-6 m.
    assert pos_err < 1e-3, pos_err
    assert float(jnp.abs(nav.vel_enu).max()) < 1e-6
    assert float(jnp.linalg.norm(attitude.attitude_error(nav.C_b_l, nav0.C_b_l))) < 1e-9


def _motion_w_b(t):
    # Smooth body rates [rad/s]: rolling and pitching oscillations while turning.
    return jnp.stack(
        [
            0.05 * jnp.sin(0.7 * t),
            0.04 * jnp.cos(0.5 * t + 0.3),
            0.15 * jnp.sin(0.11 * t) + 0.02,
        ]
    )


def _motion_f_b(t):
    return jnp.stack(
        [0.8 * jnp.sin(0.4 * t), 1.5 * jnp.cos(0.13 * t), 9.81 + 0.3 * jnp.sin(0.9 * t)]
    )


def _rk4_truth(nav0, h, n):
    """Independent reference: classical RK4 on (llh, v, q) of the continuous model."""

    def rhs(t, y):
        llh, v, q = y[:3], y[3:6], y[6:]
        w_il = geodesy.earth_rate_enu(llh[0]) + geodesy.transport_rate_enu(llh, v)
        llh_dot, v_dot, _ = strapdown.nav_rate(
            llh, v, attitude.dcm_from_quat(q), _motion_f_b(t), _motion_w_b(t)
        )
        # q' = 1/2 q (x) [0, w_ib^b] - 1/2 [0, w_il^l] (x) q
        q_dot = 0.5 * attitude.quat_multiply(q, jnp.concatenate([jnp.zeros(1), _motion_w_b(t)]))
        q_dot = q_dot - 0.5 * attitude.quat_multiply(jnp.concatenate([jnp.zeros(1), w_il]), q)
        return jnp.concatenate([llh_dot, v_dot, q_dot])

    def step(carry, _):
        t, y = carry
        k1 = rhs(t, y)
        k2 = rhs(t + h / 2, y + h / 2 * k1)
        k3 = rhs(t + h / 2, y + h / 2 * k2)
        k4 = rhs(t + h, y + h * k3)
        return (t + h, y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)), None

    y0 = jnp.concatenate([nav0.llh, nav0.vel_enu, nav0.q_b_l])
    (_, y), _ = jax.lax.scan(step, (0.0, y0), None, length=n)
    return y


def test_perfect_imu_reproduces_independent_rk4_truth():
    # 10 min of tilting, turning, accelerating motion (speed reaches 150 m/s, 3 km descent):
    # exact IMU increments at 100 Hz must reproduce an RK4 (400 Hz) solution of the continuous
    # equations to the millimetre.
    dt, n, sub = 0.01, 60_000, 4
    nav0 = strapdown.nav_state(
        jnp.array([math.radians(40.0), math.radians(-3.0), 600.0]),
        jnp.array([3.0, 12.0, 0.1]),
        jnp.array([0.03, -0.02, 1.0]),
    )
    t0 = jnp.arange(-1, n) * dt  # sample -1 covers (-dt, 0]: the "previous" sample
    dtheta = _interval_integrals(_motion_w_b, t0, dt)
    dv = _interval_integrals(_motion_f_b, t0, dt)
    seq = strapdown.ImuIncrements(dtheta[1:], dv[1:])
    prev = strapdown.ImuIncrements(dtheta[0], dv[0])
    nav, _ = jax.jit(lambda a, b, c: strapdown.mechanize(a, b, dt, c))(nav0, seq, prev)
    y = jax.jit(lambda a: _rk4_truth(a, dt / sub, n * sub))(nav0)
    pos_err = _enu_error(nav.llh, y[:3])
    assert float(jnp.linalg.norm(pos_err)) < 1e-3, pos_err  # measured 4e-5 m
    assert float(jnp.abs(nav.vel_enu - y[3:6]).max()) < 1e-6  # measured 7e-8 m/s
    att = attitude.attitude_error(nav.C_b_l, attitude.dcm_from_quat(y[6:] / jnp.linalg.norm(y[6:])))
    assert float(jnp.linalg.norm(att)) < 1e-8  # measured 3e-10 rad


def test_schuler_period_of_north_velocity_error():
    # 0.01 m/s initial north velocity error, perfect IMU at 45 deg, height aided: the error
    # oscillates at the Schuler frequency sqrt(g / (R_M + h)) (north channel: meridian radius),
    # modulated by the Foucault frequency we sin(lat) (period 34 h, no extra zero crossing in 3 h).
    # The modes are ~ws +- wF with unequal weights in vn, so the zero crossings drift slightly:
    # the linear error model (exp(F t), eigenfrequencies 1.1894e-3 and 1.2925e-3 rad/s) puts them
    # at 1262.57, 3787.60, 6312.29, 8836.33 s (the mechanization: the same to 1e-3 s), i.e. an
    # apparent period 0.28 % below 2 pi / ws.
    dt, n = 0.1, 108_000  # 3 h at 10 Hz
    nav0 = strapdown.nav_state(
        LLH45, jnp.array([0.0, 0.01, 0.0]), jnp.radians(jnp.array([0, 0, 30.0]))
    )
    imu = strapdown.stationary_imu(LLH45, nav0.C_b_l, dt)
    hist = jax.jit(lambda a, b: _clamped_height_run(a, b, dt, n))(nav0, imu)
    vn = np.asarray(hist.vel_enu[:, 1])
    t = np.arange(1, n + 1) * dt
    i = np.nonzero(np.sign(vn[:-1]) != np.sign(vn[1:]))[0]
    t_zero = t[i] - vn[i] * dt / (vn[i + 1] - vn[i])  # linear interpolation
    assert len(t_zero) == 4
    period = 2.0 * float(np.mean(np.diff(t_zero)))
    r_m, _ = geodesy.radii(LLH45[0])
    g = float(geodesy.normal_gravity(LLH45[0], LLH45[2]))
    theory = 2.0 * math.pi * math.sqrt((float(r_m) + 300.0) / g)  # 5062 s
    # Measured 5049.2 s: -0.28 % against 2 pi sqrt(R/g) and -0.29 % against 84.4 min.
    assert abs(period / theory - 1.0) < 5e-3, (period, theory)
    assert abs(period / (84.4 * 60.0) - 1.0) < 1e-2
    # Amplitude: bounded oscillation of 0.01 m/s (no growth), first zero near T/4.
    assert float(np.abs(vn).max()) < 0.0101
    assert abs(t_zero[0] / (theory / 4) - 1.0) < 5e-3


def test_up_gyro_bias_gives_linear_heading_drift():
    # Level IMU at rest, constant up-axis gyro bias b: the computed body turns left at b, so the
    # azimuth (clockwise from north) error is -b t (S000 / S002: heading error = bias x time).
    b = math.radians(1.0) / 3600.0  # 1 deg/h
    dt, n = 0.02, 30_000  # 10 min
    nav0 = strapdown.nav_state(LLH45, jnp.zeros(3), jnp.radians(jnp.array([0, 0, 30.0])))
    imu = strapdown.stationary_imu(LLH45, nav0.C_b_l, dt)
    bias = errors.SensorErrors.zeros()._replace(gyro_bias_rad_s=jnp.array([0.0, 0.0, b]))
    seq = _tile(errors.corrupt_imu(imu, bias, dt), n)
    _, hist = jax.jit(lambda a, s: strapdown.mechanize(a, s, dt))(nav0, seq)
    az = jax.vmap(attitude.euler_from_quat)(hist.q_b_l)[:, 2]
    t = np.arange(1, n + 1) * dt
    dA = np.asarray(attitude.wrap_angle(az - attitude.euler_from_quat(nav0.q_b_l)[2]))
    closed = -b * t
    # Earth-rate coupling through the tilt it induces is ~(we t)^2/6 = 3e-4 relative at 10 min.
    assert float(np.abs(dA - closed).max()) < 2e-3 * b * t[-1]


def test_east_gyro_bias_gives_closed_form_north_error():
    # Level IMU at rest facing north; bias b on the east-pointing gyro: eps_E' = -b - dvn/R_M,
    # dvn' = g eps_E, hence dvn = -R b (1 - cos ws t) and dN = -R b (t - sin(ws t)/ws),
    # R = R_M + h, ws = sqrt(g / R). Checked over 20 min (ws t = 1.5 rad).
    b = math.radians(0.1) / 3600.0
    dt, n = 0.02, 60_000
    nav0 = strapdown.nav_state(LLH45, jnp.zeros(3), jnp.zeros(3))
    imu = strapdown.stationary_imu(LLH45, nav0.C_b_l, dt)
    bias = errors.SensorErrors.zeros()._replace(gyro_bias_rad_s=jnp.array([b, 0.0, 0.0]))
    seq = _tile(errors.corrupt_imu(imu, bias, dt), n)
    _, hist = jax.jit(lambda a, s: strapdown.mechanize(a, s, dt))(nav0, seq)
    r_m, _ = geodesy.radii(LLH45[0])
    R = float(r_m) + 300.0
    ws = math.sqrt(float(geodesy.normal_gravity(LLH45[0], LLH45[2])) / R)
    t = np.arange(1, n + 1) * dt
    north = np.asarray((hist.llh[:, 0] - LLH45[0]) * R)
    vn = np.asarray(hist.vel_enu[:, 1])
    north_cf = -R * b * (t - np.sin(ws * t) / ws)
    vn_cf = -R * b * (1.0 - np.cos(ws * t))
    # Foucault / Earth-rate cross-coupling enters at second order, (we sin(lat) t)^2 ~ 0.4 %.
    assert float(np.abs(north - north_cf).max()) < 1e-2 * abs(north_cf[-1])  # 1.2 km at 20 min
    assert float(np.abs(vn - vn_cf).max()) < 1e-2 * float(np.abs(vn_cf).max())


def _coning(a, omega):
    """Classical coning (body -> inertial): q = [cos(a/2), sin(a/2) cos wt, sin(a/2) sin wt, 0]."""

    def q(t):
        return jnp.stack(
            [
                jnp.cos(a / 2) * jnp.ones_like(t),
                jnp.sin(a / 2) * jnp.cos(omega * t),
                jnp.sin(a / 2) * jnp.sin(omega * t),
                jnp.zeros_like(t),
            ]
        )

    def dtheta(t0, t1):
        # w_ib^b = 2 q* (x) q' = [-w sin a sin wt, w sin a cos wt, -2 w sin^2(a/2)], integrated.
        return jnp.stack(
            [
                jnp.sin(a) * (jnp.cos(omega * t1) - jnp.cos(omega * t0)),
                jnp.sin(a) * (jnp.sin(omega * t1) - jnp.sin(omega * t0)),
                -2.0 * omega * jnp.sin(a / 2) ** 2 * (t1 - t0),
            ],
            axis=-1,
        )

    return q, dtheta


def test_coning_correction_removes_coning_drift():
    # A stationary IMU whose body cones at 5 Hz with 1 deg half-angle (about an inertially fixed
    # axis), sampled at 100 Hz for 60 s. Uncorrected (phi = dtheta) integration drifts along the
    # cone axis; the two-sample correction must remove it.
    a, omega = math.radians(1.0), 2.0 * math.pi * 5.0
    dt, n = 0.01, 6000
    q_cone, dtheta_cone = _coning(a, omega)
    C0 = attitude.dcm_from_euler(jnp.radians(jnp.array([5.0, -3.0, 40.0])))
    w_ie = geodesy.earth_rate_enu(LLH45[0])

    def C_b_l(t):  # the l-frame turns at w_ie relative to inertial space
        return attitude.dcm_from_rotvec(-w_ie * t) @ C0 @ attitude.dcm_from_quat(q_cone(t))

    def f_b(t):  # at rest: specific force is the gravity reaction
        return -(C_b_l(t).T @ geodesy.gravity_enu(LLH45))

    t0 = jnp.arange(-1, n) * dt
    dth = dtheta_cone(t0, t0 + dt)
    dv = _interval_integrals(f_b, t0, dt)
    seq = strapdown.ImuIncrements(dth[1:], dv[1:])
    prev = strapdown.ImuIncrements(dth[0], dv[0])
    nav0 = strapdown.NavState(LLH45, jnp.zeros(3), attitude.quat_from_dcm(C_b_l(0.0)))
    truth = C_b_l(n * dt)
    drift = {}
    for coning in (True, False):
        nav, _ = jax.jit(
            lambda a_, b_, c_, coning=coning: strapdown.mechanize(a_, b_, dt, c_, coning=coning)
        )(nav0, seq, prev)
        drift[coning] = float(jnp.linalg.norm(attitude.attitude_error(nav.C_b_l, truth)))
    # Closed forms per step (x = w dt, small a): uncorrected a^2 (x - sin x) / 2; the
    # two-sample correction adds a^2 sin^2(x/2) sin(x) / 3, leaving an O(x^5) residual.
    x = omega * dt
    uncorrected = n * math.sin(a) ** 2 * (x - math.sin(x)) / 2.0  # 4.70e-3 rad
    residual = uncorrected - n * math.sin(a) ** 2 * math.sin(x / 2) ** 2 * math.sin(x) / 3.0
    assert abs(drift[False] / uncorrected - 1.0) < 0.02, drift
    assert abs(drift[True] / residual - 1.0) < 0.02, (drift, residual)  # 9.2e-5 rad
    assert drift[True] < drift[False] / 50.0  # (x^2 / 20 ~ 1/51 of the uncorrected drift)


def test_sculling_correction_removes_rectified_velocity_error():
    # Classical sculling: roll oscillation theta(t) = a sin(wt) about body x with an in-phase
    # specific force A sin(wt) along body y. The rectified term sin(theta) f_y ~ aA/2 builds
    # a true vertical velocity; the body-frame increment integration must capture it.
    a, A, omega = math.radians(1.0), 2.0, 2.0 * math.pi * 5.0
    dt, n = 0.01, 1000  # 10 s
    t0 = jnp.arange(-1, n) * dt
    t1 = t0 + dt
    theta = lambda t: a * jnp.sin(omega * t)
    dth = jnp.stack([theta(t1) - theta(t0), 0 * t0, 0 * t0], axis=-1)
    dv = jnp.stack(
        [0 * t0, A / omega * (jnp.cos(omega * t0) - jnp.cos(omega * t1)), 0 * t0], axis=-1
    )
    # Truth: integral of C(t) f(t) = [0, cos(theta) f_y, sin(theta) f_y] in the fixed frame.
    cf = lambda t: jnp.stack(
        [
            0.0 * t,
            jnp.cos(theta(t)) * A * jnp.sin(omega * t),
            jnp.sin(theta(t)) * A * jnp.sin(omega * t),
        ]
    )
    v_true = _interval_integrals(cf, t0[1:], dt).sum(0)
    C_start = jax.vmap(lambda th: attitude.dcm_from_rotvec(jnp.array([th, 0.0, 0.0])))(
        theta(t0[1:])
    )
    prev = strapdown.ImuIncrements(dth[:-1], dv[:-1])
    cur = strapdown.ImuIncrements(dth[1:], dv[1:])
    err = {}
    for sculling in (True, False):
        dv_b = jax.vmap(lambda p, c, s=sculling: strapdown.sculling_dv(p, c, s))(prev, cur)
        v = jnp.einsum("nij,nj->i", C_start, dv_b)
        err[sculling] = float(jnp.linalg.norm(v - v_true))
    assert float(v_true[2]) > 0.1  # the rectified vertical velocity the algorithm must capture
    # Over whole periods the per-step errors average to the coning forms with a^2 -> aA/w
    # (Savage's coning/sculling equivalence): uncorrected aA/w (x - sin x)/2, corrected
    # residual aA/w [(x - sin x)/2 - sin^2(x/2) sin(x)/3], x = w dt (here 50 full periods).
    x, k = omega * dt, a * A / omega
    uncorrected = n * k * (x - math.sin(x)) / 2.0  # 2.86e-3 m/s
    residual = uncorrected - n * k * math.sin(x / 2) ** 2 * math.sin(x) / 3.0  # 5.6e-5 m/s
    assert abs(err[False] / uncorrected - 1.0) < 0.02, err
    assert abs(err[True] / residual - 1.0) < 0.02, (err, residual)
    assert err[True] < err[False] / 50.0
