"""IMU / odometer error models: statistics against their specifications, exact model checks."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.sim import sensors as se

DT = 0.01


def _only(**fields) -> se.ImuGrade:
    """A grade with every error off except ``fields`` (SI units)."""
    zero = se.ImuGrade.from_datasheet("test", "test", 1.0 / DT)
    names = tuple(fields)
    return eqx.tree_at(
        lambda g: tuple(getattr(g, n) for n in names), zero, tuple(fields[n] for n in names)
    )


# One compiled batch simulator, shared by every test (compiling the PRNG is the slow part).
_SIM = jax.jit(jax.vmap(se.simulate_imu, in_axes=(0, None, None, None, None)))


def _run(grade, n, n_keys, dtheta=None, dv=None, seed=0, keys=None):
    dtheta = jnp.zeros((n, 3)) if dtheta is None else dtheta
    dv = jnp.zeros((n, 3)) if dv is None else dv
    if keys is None:
        keys = jax.random.split(jax.random.PRNGKey(seed), n_keys)
    return _SIM(keys, dtheta, dv, DT, grade)


@pytest.fixture(scope="module")
def noise_and_gm_run():
    """192 runs x 4000 samples of white noise + a gyro GM bias (sigma 3e-4 rad/s, tau 2 s)."""
    grade = _only(
        gyro_arw_rad_sqrt_s=1e-3,
        accel_vrw_m_s_sqrt_s=2e-3,
        gyro_bias_gm_sigma_rad_s=3e-4,
        gyro_bias_gm_tau_s=2.0,
    )
    return grade, _run(grade, 4000, 192, seed=1)


def test_unit_conversions_closed_form():
    assert se.deg_h_to_rad_s(1.0) == pytest.approx(math.pi / 180 / 3600, rel=1e-15)
    assert se.deg_sqrt_h_to_rad_sqrt_s(1.0) == pytest.approx(2.908882086657216e-4, rel=1e-12)
    assert se.mg_to_m_s2(1.0) == pytest.approx(9.80665e-3, rel=1e-15)
    assert se.mgal_to_m_s2(1000.0) == pytest.approx(0.01, rel=1e-15)
    assert se.m_s_sqrt_h_to_m_s_sqrt_s(0.15) == pytest.approx(0.0025, rel=1e-15)
    assert se.ug_sqrt_hz_to_m_s_sqrt_s(100.0) == pytest.approx(9.80665e-4, rel=1e-15)
    # The Crossbow turn-on gyro bias is 2 deg/s (S000 text), not the table's 20 deg/s.
    assert se.crossbow_imu300cc().gyro_bias_turn_on_rad_s == pytest.approx(math.radians(2.0))
    assert se.hg1700().gyro_arw_rad_sqrt_s == pytest.approx(math.radians(0.125) / 60.0)


@pytest.mark.parametrize("name", sorted(se.IMU_GRADES))
def test_presets_are_complete(name):
    g = se.IMU_GRADES[name]()
    assert g.source and g.name and 100.0 <= g.rate_hz <= 200.0
    leaves = jax.tree_util.tree_leaves(g)
    assert all(np.isfinite(x) or x == math.inf for x in leaves)
    assert all(x >= 0.0 for x in leaves)
    assert g.gyro_arw_rad_sqrt_s > 0.0 and g.accel_vrw_m_s_sqrt_s > 0.0


def test_grades_are_ordered_by_gyro_quality():
    # MEMS >> tactical; the seeds' ordering of the sensors' in-run gyro bias.
    s = {k: f().gyro_bias_gm_sigma_rad_s for k, f in se.IMU_GRADES.items()}
    assert s["crista"] > s["crossbow_imu300cc"] > s["lsm6dsl"] > s["span_cpt"] > s["kvh1750"]


def test_white_noise_std_matches_arw_vrw(noise_and_gm_run):
    grade, (m_g, m_a, e) = noise_and_gm_run
    arw, vrw = grade.gyro_arw_rad_sqrt_s, grade.accel_vrw_m_s_sqrt_s
    # Gyro output = GM bias dt + white noise: remove the (returned) bias part.
    white_g = np.asarray(m_g) - np.asarray(e.gyro_bias_rad_s) * DT
    std_g = white_g.std() / math.sqrt(DT)
    std_a = float(jnp.std(m_a)) / math.sqrt(DT)
    print(f"ARW {std_g:.5e} vs {arw:.5e}; VRW {std_a:.5e} vs {vrw:.5e}")
    assert std_g == pytest.approx(arw, rel=0.05)
    assert std_a == pytest.approx(vrw, rel=0.05)
    np.testing.assert_allclose(white_g, np.asarray(e.gyro_noise_rad), rtol=0, atol=1e-15)
    # White: lag-1 autocorrelation ~ 0.
    x = np.asarray(e.gyro_noise_rad)
    rho1 = np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x)
    assert abs(rho1) < 0.01


def test_gauss_markov_steady_state_std_and_correlation_time(noise_and_gm_run):
    grade, (_, _, e) = noise_and_gm_run
    sigma, tau = grade.gyro_bias_gm_sigma_rad_s, grade.gyro_bias_gm_tau_s
    x = np.asarray(e.gyro_bias_gm_rad_s)  # (keys, N, 3), N = 40 tau
    std = x.std()
    # Stationary from the first sample: ensemble std at k = 0 and at the end.
    std0, std_end = x[:, 0].std(), x[:, -1].std()
    lag = int(tau / DT)
    rho = np.mean(x[:, lag:] * x[:, :-lag]) / np.mean(x * x)
    tau_hat = -lag * DT / math.log(rho)
    print(f"GM std {std:.4e} (k=0 {std0:.4e}, end {std_end:.4e}) vs {sigma:.4e}; ")
    print(f"tau {tau_hat:.3f} s vs {tau} s")
    assert std == pytest.approx(sigma, rel=0.05)
    assert std0 == pytest.approx(sigma, rel=0.1) and std_end == pytest.approx(sigma, rel=0.1)
    assert tau_hat == pytest.approx(tau, rel=0.10)
    # The turn-on part is off, so the total bias is the GM process.
    np.testing.assert_array_equal(np.asarray(e.gyro_bias_rad_s), x)


def test_turn_on_bias_and_scale_factor_spread_across_keys():
    sb, sa, ss = 1e-3, 0.05, 2e-3
    grade = _only(gyro_bias_turn_on_rad_s=sb, accel_bias_turn_on_m_s2=sa, accel_scale_turn_on=ss)
    dv = jnp.full((50, 3), 0.1)
    _, m_a, e = _run(grade, 50, 4000, dv=dv, seed=2)
    b = np.asarray(e.gyro_bias_rad_s)
    assert np.all(b == b[:, :1])  # constant in time
    to = np.asarray(e.gyro_bias_turn_on_rad_s)
    print(f"turn-on spread gyro {to.std():.4e} vs {sb}")
    assert to.std() == pytest.approx(sb, rel=0.05)
    assert np.asarray(e.accel_bias_turn_on_m_s2).std() == pytest.approx(sa, rel=0.05)
    assert abs(np.corrcoef(to[:, 0], to[:, 1])[0, 1]) < 0.05  # independent axes
    # Scale factor: (meas - bias dt) / true - 1, constant per run, spread ss across keys.
    ratio = (np.asarray(m_a) - np.asarray(e.accel_bias_m_s2) * DT) / 0.1 - 1.0
    assert ratio[:, 0].std() == pytest.approx(ss, rel=0.05)
    np.testing.assert_allclose(ratio, np.asarray(e.accel_scale), rtol=0, atol=1e-12)


def test_measurement_model_is_s001_eq12():
    n = 2000
    t = jnp.arange(n) * DT
    dth = jnp.stack([0.1 * jnp.sin(t), 0.2 * jnp.cos(0.5 * t), 0.3 + 0 * t], 1) * DT
    dv = jnp.stack([0.5 * jnp.sin(t), 1.0 + 0 * t, 9.8 + 0 * t], 1) * DT
    grade = se.crossbow_imu300cc()
    grade = eqx.tree_at(
        lambda g: (g.gyro_scale_gm_sigma, g.gyro_scale_gm_tau_s), grade, (1e-3, 50.0)
    )
    mg, ma, e = _run(grade, n, 3, dth, dv, seed=3)
    pred_g = (1 + e.gyro_scale) * dth + e.gyro_bias_rad_s * DT + e.gyro_noise_rad
    pred_a = (1 + e.accel_scale) * dv + e.accel_bias_m_s2 * DT + e.accel_noise_m_s
    np.testing.assert_allclose(np.asarray(mg), np.asarray(pred_g), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.asarray(ma), np.asarray(pred_a), rtol=0, atol=1e-15)
    # Scale factors really multiply: the scale part changes with the input, the bias does not.
    assert float(jnp.std(e.gyro_scale[:, :, 0])) > 0.0


def test_quantisation_keeps_the_running_sum():
    q = 1e-5
    n = 50000
    # Sub-quantum input: naive rounding would output 0 forever and lose 0.3 q per sample.
    dth = jnp.full((n, 3), 0.3 * q) + jnp.array([0.0, 1e-7, -4e-7])
    grade = _only(gyro_quantum_rad=q, gyro_arw_rad_sqrt_s=1e-5)
    m, _, e = _run(grade, n, 2, dtheta=dth, seed=5)
    m = np.asarray(m)
    units = m / q
    np.testing.assert_allclose(units, np.round(units), rtol=0, atol=1e-6)  # whole quanta
    ideal = np.asarray(dth)[None] + np.asarray(e.gyro_noise_rad)
    lost = np.cumsum(ideal - m, axis=1)  # = carried residual after each sample
    print(f"max |running-sum loss| {np.abs(lost).max() / q:.3f} quanta over {n} samples")
    assert np.abs(lost).max() <= 0.5 * q * (1 + 1e-6)
    np.testing.assert_allclose(lost, np.asarray(e.gyro_quant_residual_rad), atol=1e-12)
    # Without the carry the loss grows without bound (what the test guards against).
    naive = np.round(ideal / q) * q
    assert np.abs(np.cumsum(ideal - naive, axis=1)).max() > 1000 * q


def test_same_key_same_run_different_keys_differ():
    k7, k8 = jax.random.PRNGKey(7), jax.random.PRNGKey(8)
    m, _, _ = _run(se.lsm6dsl(), 2000, 3, keys=jnp.stack([k7, k7, k8]))
    m = np.asarray(m)
    np.testing.assert_array_equal(m[0], m[1])
    assert not np.allclose(m[0], m[2])


def test_riss_subset_channels():
    dth = jnp.array([[1.0, 2.0, 3.0]]) * DT
    dv = jnp.array([[4.0, 5.0, 6.0]]) * DT
    wz, fx, fy = se.riss_subset(dth, dv, DT)
    np.testing.assert_allclose([wz[0], fx[0], fy[0]], [3.0, 4.0, 5.0], rtol=1e-14)


# ---- odometer ----------------------------------------------------------------------------------
_ODO = jax.jit(jax.vmap(se.simulate_odometer, in_axes=(0, None, None, None)))
_SPEED = jnp.concatenate([jnp.zeros(100), jnp.linspace(0.0, 27.0, 900), jnp.full(1000, 20.0)])


def test_odometer_statistics_and_standstill():
    params = eqx.tree_at(lambda p: p.quantum_m_s, se.obd2_odometer(), 0.0)
    keys = jax.random.split(jax.random.PRNGKey(9), 1000)
    r, e = _ODO(keys, _SPEED, 0.1, params)
    r = np.asarray(r)
    assert np.all(r[:, :100] == 0.0)  # no pulses at rest
    noise = r[:, 1000:] - (1 + np.asarray(e.scale)[:, 1000:]) * 20.0
    print(f"odometer noise std {noise.std():.4f} m/s")
    assert noise.std() == pytest.approx(params.noise_std_m_s, rel=0.05)
    assert np.asarray(e.scale)[:, 0].std() == pytest.approx(params.scale_turn_on, rel=0.05)


def test_odometer_obd2_quantum():
    params = se.obd2_odometer()
    r, e = _ODO(jax.random.split(jax.random.PRNGKey(10), 1000), _SPEED, 0.1, params)
    kmh = np.asarray(r) * 3.6
    np.testing.assert_allclose(kmh, np.round(kmh), atol=1e-9)  # integer km/h
    assert np.all(kmh >= 0.0)
    # Rounded to the nearest quantum (not truncated): within q/2 of the unquantised reading.
    raw = (1 + np.asarray(e.scale)) * np.asarray(_SPEED) + np.asarray(e.noise_m_s)
    ok = (raw > 0.0) & (np.asarray(_SPEED) > 0.0)
    dev = np.abs(np.asarray(r) - raw)[ok]
    assert dev.max() <= 0.5 * params.quantum_m_s + 1e-12
    assert dev.max() > 0.4 * params.quantum_m_s  # the quantum is really applied
