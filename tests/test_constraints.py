"""Vehicle constraints: analytic H against autodiff, seed forms, rigid-body closed forms, detector.

The autodiff reference perturbs the truth with an error vector under the jaxnav conventions
(estimate = truth + dx, C_hat = exp(-[eps x]) C, compensated rate = true rate + b_g + diag(w) S_g,
odometer scale s_hat = s + ds) and differentiates the nonlinear measurement h(x_hat).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.core.states import INS15, INS27
from jaxnav.filter import constraints as cons
from jaxnav.filter import ekf
from jaxnav.sim import sensors
from jaxnav.sim import trajectory as tr

LAYOUT = INS27.extend(("odo_scale", 1))
LLH = jnp.array([math.radians(44.2312), math.radians(-76.486), 90.0])
VEL = jnp.array([11.0, -6.5, 0.4])
C = attitude.dcm_from_euler(jnp.array([0.04, -0.03, 2.1]))
W = jnp.array([0.012, -0.021, 0.31])  # compensated body rate [rad/s]
LEVER = jnp.array([0.35, -1.4, -0.45])  # IMU -> rear axle [m]
ODO_SCALE = 0.013


def _blk(dx, name):
    return dx[LAYOUT.sl(name)]


def _estimate(dx):
    """Estimated state from the truth above and the error vector dx."""
    llh = LLH + _blk(dx, "pos")
    vel = VEL + _blk(dx, "vel")
    C_hat = attitude.dcm_from_rotvec(-_blk(dx, "att")) @ C
    w = W + _blk(dx, "gyro_bias") + _blk(dx, "gyro_bias_ton") + W * _blk(dx, "gyro_scale")
    s = ODO_SCALE + dx[LAYOUT.i("odo_scale")]
    return llh, vel, C_hat, w, s


def _body_velocity(dx):
    llh, vel, C_hat, w, _ = _estimate(dx)
    w_ie = geodesy.earth_rate_enu(llh[0])
    # Rigid body: v_pt = v + w_eb x l in body axes, w_eb = w_ib - C^T w_ie (independent form).
    return C_hat.T @ vel + jnp.cross(w - C_hat.T @ w_ie, LEVER)


def _autodiff(h):
    return np.asarray(jax.jacfwd(h)(jnp.zeros(LAYOUT.size)))


def _assert_H(H, H_ref, scale):
    np.testing.assert_allclose(np.asarray(H), H_ref, rtol=0, atol=1e-9 * scale)


def test_nhc_H_equals_autodiff_with_lever_arm():
    rows = cons.nhc_rows(LAYOUT, LLH, VEL, C, W, LEVER, 1.0)
    H_ref = _autodiff(lambda dx: _body_velocity(dx)[jnp.array([0, 2])])
    _assert_H(rows.H, H_ref, 1e7)  # position columns are per radian
    np.testing.assert_allclose(rows.dz, _body_velocity(jnp.zeros(LAYOUT.size))[jnp.array([0, 2])])
    assert rows.H.shape == (2, LAYOUT.size) and bool(rows.mask.all())


def test_odometer_H_equals_autodiff_with_scale_state():
    speed = 13.0
    rows = cons.odometer_rows(LAYOUT, LLH, VEL, C, W, LEVER, speed, 0.1, True, ODO_SCALE)

    def h(dx):
        *_, s = _estimate(dx)
        return (1.0 + s) * _body_velocity(dx)[1:2]

    _assert_H(rows.H, _autodiff(h), 1e7)
    np.testing.assert_allclose(rows.dz, h(jnp.zeros(LAYOUT.size)) - speed, rtol=1e-14)
    assert float(rows.H[0, LAYOUT.i("odo_scale")]) == pytest.approx(
        float(_body_velocity(jnp.zeros(LAYOUT.size))[1])
    )


def test_zupt_and_zaru_H_equal_autodiff():
    zupt = cons.zupt_rows(LAYOUT, VEL, 0.02)
    _assert_H(zupt.H, _autodiff(lambda dx: _estimate(dx)[1]), 1.0)

    def zaru(dx):
        llh, _, C_hat, w, _ = _estimate(dx)
        return w - C_hat.T @ geodesy.earth_rate_enu(llh[0])

    rows = cons.zaru_rows(LAYOUT, LLH, C, W, 1e-4)
    _assert_H(rows.H, _autodiff(zaru), 1.0)
    np.testing.assert_allclose(rows.dz, zaru(jnp.zeros(LAYOUT.size)), rtol=1e-14)


def test_nhc_without_lever_is_corrected_s002_eq_4_29():
    """Lever 0: H = [0, r, -r [v x]] with r the i-th column of R_b^l (S002 4.29, up row fixed)."""
    rows = cons.nhc_rows(INS15, LLH, VEL, C, W, jnp.zeros(3), 1.0)
    R = np.asarray(C)
    ve, vn, vu = np.asarray(VEL)
    lateral = [R[0, 0], R[1, 0], R[2, 0],
               -vu * R[1, 0] + vn * R[2, 0], vu * R[0, 0] - ve * R[2, 0],
               -vn * R[0, 0] + ve * R[1, 0]]  # fmt: skip
    up = [R[0, 2], R[1, 2], R[2, 2],
          -vu * R[1, 2] + vn * R[2, 2], vu * R[0, 2] - ve * R[2, 2],
          -vn * R[0, 2] + ve * R[1, 2]]  # fmt: skip
    H = np.asarray(rows.H)
    np.testing.assert_allclose(H[:, INS15.sl("vel").start : INS15.sl("att").stop], [lateral, up],
                               atol=1e-12)  # fmt: skip
    assert np.all(H[:, INS15.sl("pos")] == 0.0) and np.all(H[:, INS15.sl("accel_bias")] == 0.0)


def test_lever_arm_rigid_body_closed_forms():
    """Level car turning left at yaw rate w with no slip at the IMU: a point L ahead slides
    right-to-left at -w L, a point d to the right runs faster by w d (outer wheel)."""
    llh = LLH
    az = 0.7
    C_lvl = attitude.dcm_from_euler(jnp.array([0.0, 0.0, az]))
    speed, w_z = 8.0, 0.25  # left turn (counter-clockwise about up)
    vel = speed * jnp.array([math.sin(az), math.cos(az), 0.0])
    w_il = geodesy.earth_rate_enu(llh[0]) + geodesy.transport_rate_enu(llh, vel)
    w_ib = C_lvl.T @ w_il + jnp.array([0.0, 0.0, w_z])
    ahead = cons.vehicle_velocity_b(llh, vel, C_lvl, w_ib, jnp.array([0.0, 2.5, 0.0]))
    side = cons.vehicle_velocity_b(llh, vel, C_lvl, w_ib, jnp.array([0.8, 0.0, 0.0]))
    # Transport rate (v/R ~ 1e-6 rad/s) is the only other body rotation: 1e-5 m/s tolerance.
    np.testing.assert_allclose(ahead, [-w_z * 2.5, speed, 0.0], atol=1e-5)
    np.testing.assert_allclose(side, [0.0, speed + w_z * 0.8, 0.0], atol=1e-5)
    nhc = cons.nhc_rows(INS15, llh, vel, C_lvl, w_ib, jnp.zeros(3))
    np.testing.assert_allclose(nhc.dz, 0.0, atol=1e-12)  # the IMU point itself does not slip


def test_masked_rows_with_nan_leave_the_filter_unchanged():
    rows = cons.stack_rows(
        cons.zupt_rows(INS15, jnp.full(3, jnp.nan), 0.02, False),
        cons.nhc_rows(INS15, LLH, VEL, C, W, LEVER, 1.0, False),
    )
    rows = cons.sanitize(rows)
    P = jnp.diag(jnp.linspace(1.0, 2.0, INS15.size))
    res = ekf.masked_update(jnp.zeros(INS15.size), P, rows.dz, rows.H, rows.R, rows.mask)
    assert bool(jnp.all(res.P == P)) and bool(jnp.all(res.x == 0.0)) and int(res.dof) == 0
    assert rows.R.shape == (5, 5) and np.all(np.isfinite(np.asarray(rows.R)))


# ---- stationarity detector -------------------------------------------------------------------
RATE = 100.0


@pytest.fixture(scope="module")
def stop_go_windows():
    """1 s windows: 40 s standing, 8 s accelerating to 10 m/s, 20 s cruising (LSM6DSL IMU)."""
    segs = [tr.stop(40.0), tr.speed_to(10.0, 8.0), tr.cruise(20.0)]
    truth = tr.generate_truth(tr.compile_profile(segs, azimuth0_deg=40.0), RATE)
    grade = sensors.lsm6dsl()
    _, dv, _ = sensors.simulate_imu(
        jax.random.PRNGKey(3), truth.dtheta_b[1:], truth.dv_b[1:], 1.0 / RATE, grade
    )
    k = int(RATE)
    n = dv.shape[0] // k
    windows = dv[: n * k].reshape(n, k, 3)
    stats = jax.vmap(lambda w: cons.stationarity_statistics(w, 1.0 / RATE))(windows)
    ref0 = grade.accel_vrw_m_s_sqrt_s**2 * RATE
    return stats, ref0


def test_detector_statistic_separates_standing_from_accelerating(stop_go_windows):
    stats, ref0 = stop_go_windows
    t = np.maximum(np.asarray(stats.var_forward), np.asarray(stats.var_norm)) / ref0
    det = cons.ZuptDetector()
    standing, accel, cruise = t[:40], t[41:47], t[49:]
    assert standing.max() < det.threshold and abs(np.mean(standing) - 1.0) < 0.1
    assert accel.min() > 3.0 * det.threshold
    # On a vibration-free road the variance cannot tell cruising from standing: the speed gate must.
    assert cruise.max() < det.threshold
    static, _, _ = jax.vmap(
        lambda s: cons.detect_stationary(s, ref0, ref0, jnp.asarray(False), det)
    )(cons.Stationarity(stats.var_forward[49:], stats.var_norm[49:]))
    assert not bool(static.any())


def test_detector_reference_adapts_to_the_true_noise(stop_go_windows):
    """Started at 2x the true at-rest variance, the reference converges to it on static windows."""
    stats, ref0 = stop_go_windows
    det = cons.ZuptDetector()

    def step(ref, s):
        static, ref, _ = cons.detect_stationary(s, ref, 2.0 * ref0, jnp.asarray(True), det)
        return ref, static

    standing = cons.Stationarity(stats.var_forward[:40], stats.var_norm[:40])
    ref, static = jax.lax.scan(step, jnp.asarray(2.0 * ref0), standing)
    assert bool(static.all())
    assert float(ref) / ref0 == pytest.approx(1.0, abs=0.1)
