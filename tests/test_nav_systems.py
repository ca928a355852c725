"""The navigation-system interface: every system implements ``AbstractNavSystem``; one that
leaves a method out fails when its class is defined."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.states import StateLayout
from jaxnav.filter import ppp_only, systems

SYSTEMS = [systems.RissSystem(), systems.InsSystem(), ppp_only.GnssOnlySystem()]
INTERFACE = sorted(k for k in dir(systems.AbstractNavSystem)
                   if getattr(getattr(systems.AbstractNavSystem, k), "__isabstractmethod__",
                              False))


def test_the_interface_is_what_the_filters_call():
    assert INTERFACE == ["antenna", "dynamics", "euler", "feedback", "idle_inputs",
                         "initial_std", "layout", "llh", "predict_sensors", "propagate",
                         "vel_enu", "zero_sensors"]


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: type(s).__name__)
def test_every_system_implements_the_interface(system):
    assert isinstance(system, systems.AbstractNavSystem)
    assert isinstance(system.layout, StateLayout) and system.layout.has("pos")


def test_a_system_missing_a_method_fails_at_class_definition():
    with pytest.raises(TypeError, match="HalfSystem does not implement euler"):

        class HalfSystem(systems.AbstractNavSystem):
            layout = StateLayout((("pos", 3),))

            def propagate(self, nav, sensors, samples, dt):
                return nav, None

            def dynamics(self, nav, mean_inputs, sensors):
                return None

            def antenna(self, nav, mean_inputs, sensors, layout_full):
                return None

            def feedback(self, nav, sensors, dx, layout_full):
                return nav, sensors

            def predict_sensors(self, sensors, dt):
                return sensors

            def initial_std(self, nav, sig):
                return jnp.ones(3)

            def zero_sensors(self):
                return None

            def idle_inputs(self, nav):
                return None

            def llh(self, nav):
                return nav

            def vel_enu(self, nav):
                return jnp.zeros(3)


def test_a_system_without_sensors_refuses_a_static_calibration():
    g = ppp_only.GnssOnlySystem()
    with pytest.raises(TypeError, match="GnssOnlySystem has no sensors"):
        g.calibrate_static(None, None, 1.0)


def test_sensor_estimates_decay_as_their_gauss_markov_model():
    """Issue 16, defect 4. b' = -b / tau for a Gauss-Markov bias, so its estimate predicts as
    b_hat(t + dt) = exp(-dt / tau) b_hat(t) (x_hat <- Phi x_hat); the constant parts (start-up
    calibration, INS27's turn-on states) stay. Over dt = tau the filter's drift share falls to
    1/e exactly."""
    import math

    from jaxnav.core.states import INS27, RISS16
    from jaxnav.ins import errors

    model = errors.ImuErrorModel(
        accel_vrw_m_s_sqrt_s=1e-3, gyro_arw_rad_sqrt_s=1e-4, accel_bias_sigma_m_s2=1e-2,
        accel_bias_tau_s=300.0, gyro_bias_sigma_rad_s=1e-4, gyro_bias_tau_s=600.0,
    )
    ins = systems.InsSystem(INS27, model)
    calib = ins.zero_sensors()._replace(gyro_bias_rad_s=jnp.array([1e-3, 2e-3, -1e-3]))
    dx = jnp.zeros(INS27.size)
    dx = dx.at[INS27.sl("accel_bias")].set(jnp.array([0.02, -0.01, 0.03]))
    dx = dx.at[INS27.sl("accel_bias_ton")].set(jnp.array([0.1, 0.2, -0.1]))
    dx = dx.at[INS27.sl("gyro_bias")].set(jnp.array([1e-4, -2e-4, 3e-4]))
    est = errors.feedback_sensors(calib, dx, INS27)
    after = ins.predict_sensors(est, 300.0)
    e_a, e_g = math.exp(-1.0), math.exp(-0.5)
    np.testing.assert_allclose(after.accel_bias_m_s2,
                               np.array([0.1, 0.2, -0.1]) + e_a * np.array([0.02, -0.01, 0.03]))
    np.testing.assert_allclose(after.gyro_bias_rad_s,
                               np.array([1e-3, 2e-3, -1e-3]) + e_g * np.array([1e-4, -2e-4, 3e-4]))
    np.testing.assert_allclose(after.accel_bias_gm_m_s2, e_a * est.accel_bias_gm_m_s2)

    # INS15 lumps turn-on + drift in one block: its correction goes to the drift share by the
    # prior variances (a 50-mg turn-on estimate must not decay as 0.75-mg drift would)
    from jaxnav.core.states import INS15

    lumped = systems.InsSystem(INS15, eqx.tree_at(lambda m: m.accel_bias_ton_sigma_m_s2, model,
                                                  jnp.asarray(3e-2)))
    dx15 = jnp.zeros(INS15.size).at[INS15.sl("accel_bias")].set(jnp.array([0.1, 0.0, 0.2]))
    _, est15 = lumped.feedback(_ins_nav(), lumped.zero_sensors(), dx15, INS15)
    share = 1e-4 / (1e-4 + 9e-4)
    np.testing.assert_allclose(est15.accel_bias_gm_m_s2, share * np.array([0.1, 0.0, 0.2]))
    np.testing.assert_allclose(est15.accel_bias_m_s2, [0.1, 0.0, 0.2])
    # after a standstill calibration of T seconds the gyro's turn-on prior is ARW / sqrt(T)
    # (sensor_initial_std): the gyro correction is then mostly drift
    gyro = eqx.tree_at(lambda m: m.gyro_bias_ton_sigma_rad_s, model, jnp.asarray(1e-2))
    _, g_share = errors.gm_share(gyro, INS15, 30.0)
    want = 1e-8 / (1e-8 + 1e-8 / 30.0)
    np.testing.assert_allclose(g_share, want)
    calibrated = systems.InsSystem(INS15, gyro, gyro_calibration_s=30.0)
    dxg = jnp.zeros(INS15.size).at[INS15.sl("gyro_bias")].set(jnp.array([1e-4, 0.0, 0.0]))
    _, est_g = calibrated.feedback(_ins_nav(), calibrated.zero_sensors(), dxg, INS15)
    np.testing.assert_allclose(est_g.gyro_bias_gm_rad_s, [want * 1e-4, 0.0, 0.0])

    riss = systems.RissSystem(RISS16)
    p = riss.params
    base = riss.zero_sensors()._replace(gyro_bias_z_rad_s=jnp.asarray(0.03))  # calibrated
    dxr = jnp.zeros(RISS16.size).at[RISS16.i("gyro_bias_z")].set(-1e-4)
    dxr = dxr.at[RISS16.i("odo_accel")].set(0.05)
    _, est_r = riss.feedback(_riss_nav(), base, dxr, RISS16)
    dt = 1.0 / p.gyro_bias_beta_1_s
    after_r = riss.predict_sensors(est_r, dt)
    assert float(after_r.gyro_bias_z_rad_s) == pytest.approx(0.03 + 1e-4 * math.exp(-1.0))
    assert float(after_r.odo_accel_bias_m_s2) == pytest.approx(
        0.05 * math.exp(-p.odo_accel_beta_1_s * dt))
    assert float(after_r.odo_scale) == float(est_r.odo_scale)  # a random walk: no decay


def _ins_nav():
    from jaxnav.ins import strapdown

    state = strapdown.nav_state(jnp.array([0.9, 0.2, 50.0]), jnp.zeros(3), jnp.zeros(3))
    return strapdown.InsNav(state, strapdown.ImuIncrements(jnp.zeros(3), jnp.zeros(3)))


def _riss_nav():
    from jaxnav.ins import riss

    return riss.riss_state_from(jnp.array([0.9, 0.2, 50.0]), 0.3, 10.0)


@pytest.mark.parametrize("layout_name", ["RISS16", "RISS9"])
def test_output_velocity_covariance_is_the_one_the_velocity_rows_use(layout_name):
    """Issue 16. The RISS output velocity is re-derived from the odometer and the azimuth, so
    its error is dx[vel] + M dx: the covariance reported for it must be H P H^T with H the
    Jacobian the filter's own velocity rows use (the antenna velocity at zero lever arm), not
    P[vel, vel] (the earlier readout, which made the RISS velocity NEES ~1e6)."""
    from jaxnav import geodesy
    from jaxnav.core import states

    layout = getattr(states, layout_name)
    system = systems.RissSystem(layout)
    nav = _riss_nav()
    rng = np.random.default_rng(3)
    A = rng.normal(size=(layout.size, layout.size)) * 0.1
    P = jnp.asarray(A @ A.T + 0.01 * np.eye(layout.size))
    rx = system.antenna(nav, system.idle_inputs(nav), system.zero_sensors(), layout)
    H_enu = geodesy.C_l_e(nav.llh[0], nav.llh[1]).T @ rx.J_vel
    vel = layout.sl("vel")
    got = system.nav_covariance(nav, P, layout)[vel, vel]
    np.testing.assert_allclose(got, H_enu @ P @ H_enu.T, rtol=1e-10, atol=1e-14)
    assert not np.allclose(got, P[vel, vel], rtol=0.1)
