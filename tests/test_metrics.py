"""Outage-study metrics against synthetic error histories with closed-form answers."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import geodesy
from jaxnav.study import metrics as m

LAT0, LON0, H0 = 45.0 * math.pi / 180.0, -75.0 * math.pi / 180.0, 100.0
R_M, R_N = (float(r) for r in geodesy.radii(LAT0))
M_PER_RAD_N = R_M + H0
M_PER_RAD_E = (R_N + H0) * math.cos(LAT0)


def _truth_east(T, speed_mps, dt):
    """Constant-latitude drive east at ``speed_mps``: lon advances by v dt / ((R_N+h) cos lat)."""
    t = np.arange(T) * dt
    llh = np.column_stack([np.full(T, LAT0), LON0 + speed_mps * t / M_PER_RAD_E, np.full(T, H0)])
    vel = np.tile([speed_mps, 0.0, 0.0], (T, 1))
    return llh, vel


def _apply_enu(llh_true, err_enu):
    """Estimated llh whose ENU error (east, north, up) at the truth is ``err_enu``."""
    d = np.column_stack([err_enu[:, 1] / M_PER_RAD_N, err_enu[:, 0] / M_PER_RAD_E, err_enu[:, 2]])
    return llh_true + d


# Positions are stored as llh: the longitude's float64 spacing is 1e-9 m at this latitude, so
# metre-level comparisons hold to ~1e-8 m absolute.
# A 40-epoch outage starting at epoch 30; 2D error 0.05 m before it, 0.05 + a tau^2 / 2 during it
# (tau = epochs since the last GNSS epoch), then decaying exponentially back to 0.05.
T, START, L, DT, SPEED = 160, 30, 40, 1.0, 15.0
ACC, ACC_UP, TAU_DECAY = 0.01, 0.004, 6.0
DIR = np.array([0.6, 0.8])  # horizontal error direction (east, north)


def _scenario(spike_at=None, pre_2d=0.05):
    t = np.arange(T)
    tau = t - START + 1
    grow = np.where((t >= START) & (t < START + L), 0.5 * ACC * tau**2, 0.0)
    peak = 0.5 * ACC * L**2
    after = t >= START + L
    grow = np.where(after, peak * np.exp(-(t - START - L) / TAU_DECAY), grow)
    e2 = pre_2d + grow
    if spike_at is not None:
        e2[spike_at] = 0.5
    up = 0.1 + np.where((t >= START) & (t < START + L), 0.5 * ACC_UP * tau**2, 0.0)
    err = np.column_stack([DIR[0] * e2, DIR[1] * e2, up])
    llh_t, vel_t = _truth_east(T, SPEED, DT)
    az_t = np.full(T, math.pi - 0.01)  # near the wrap: estimate on the other side
    az_e = az_t + np.where((t >= START) & (t < START + L), 0.001 * tau, 0.0)
    az_e = np.mod(az_e + math.pi, 2 * math.pi) - math.pi
    est = m.Track(jnp.asarray(_apply_enu(llh_t, err)), jnp.asarray(vel_t), jnp.asarray(az_e))
    true = m.Track(jnp.asarray(llh_t), jnp.asarray(vel_t), jnp.asarray(az_t))
    return est, true, e2, up


def test_enu_errors_including_across_the_antimeridian():
    llh_t = np.array([[LAT0, math.pi - 1e-7, H0], [LAT0, 0.3, H0]])
    llh_e = np.array([[LAT0 + 2e-7, -math.pi + 1e-7, H0 - 0.5], [LAT0, 0.3, H0 + 1.0]])
    err = np.asarray(m.enu_errors(jnp.asarray(llh_e), jnp.asarray(llh_t)))
    np.testing.assert_allclose(err[0], [2e-7 * M_PER_RAD_E, 2e-7 * M_PER_RAD_N, -0.5], rtol=1e-8)
    np.testing.assert_allclose(err[1], [0.0, 0.0, 1.0], atol=1e-12)


def test_window_metrics_on_quadratic_error_growth():
    est, true, e2, up = _scenario()
    w = m.window_metrics(est, true, None, START, L, DT)
    peak2 = 0.05 + 0.5 * ACC * L**2  # 8.05 m at the last outage epoch
    assert float(w.max_2d_m) == pytest.approx(peak2, rel=1e-9)
    assert float(w.end_2d_m) == pytest.approx(peak2, rel=1e-9)
    np.testing.assert_allclose(
        np.asarray(w.end_enu_m), [0.6 * peak2, 0.8 * peak2, 0.1 + 0.5 * ACC_UP * L**2], rtol=1e-9
    )
    # RMS of 0.05 + a tau^2/2, tau = 1..L, from the power sums
    s2 = L * (L + 1) * (2 * L + 1) / 6
    s4 = L * (L + 1) * (2 * L + 1) * (3 * L**2 + 3 * L - 1) / 30
    ms = 0.05**2 + 0.05 * ACC * s2 / L + 0.25 * ACC**2 * s4 / L
    assert float(w.rms_2d_m) == pytest.approx(math.sqrt(ms), rel=1e-9)
    assert float(w.max_3d_m) == pytest.approx(math.hypot(peak2, 0.1 + 0.5 * ACC_UP * L**2), 1e-9)
    assert float(w.distance_m) == pytest.approx(SPEED * L * DT, rel=1e-9)  # 600 m
    assert float(w.pct_of_distance) == pytest.approx(100 * peak2 / 600.0, rel=1e-9)
    assert float(w.max_azimuth_err_rad) == pytest.approx(0.001 * L, rel=1e-6)  # wrapped
    assert float(w.pre_2d_rms_m) == pytest.approx(0.05, abs=1e-8)
    # threshold max(0.2, 2 x 0.05) = 0.2: first n with 0.05 + peak e^(-n/tau) < 0.2
    assert float(w.reconv_threshold_m) == pytest.approx(0.2)
    n_star = math.floor(TAU_DECAY * math.log((peak2 - 0.05) / 0.15)) + 1  # 24 epochs
    assert bool(w.reconverged)
    assert float(w.reconv_s) == pytest.approx(n_star * DT)
    assert np.isnan(float(w.nees_pos))


def test_reconvergence_must_stay_below_and_scales_with_pre_outage_error():
    end = START + L
    est, true, *_ = _scenario(spike_at=end + 50)
    w = m.window_metrics(est, true, None, START, L, DT)
    assert float(w.reconv_s) == pytest.approx(51.0)  # the epoch after the spike
    # a converged error of 0.5 m (code PPP) sets the threshold to 2 x 0.5 = 1 m
    est, true, *_ = _scenario(pre_2d=0.5)
    w = m.window_metrics(est, true, None, START, L, DT)
    assert float(w.reconv_threshold_m) == pytest.approx(1.0, rel=1e-9)
    n_star = math.floor(TAU_DECAY * math.log(0.5 * ACC * L**2 / 0.5)) + 1
    assert float(w.reconv_s) == pytest.approx(n_star * DT)
    # a custom absolute threshold and no factor
    cfg = m.MetricConfig(reconv_threshold_m=1.0, reconv_factor=0.0)
    w = m.window_metrics(*_scenario()[:2], None, START, L, DT, cfg)
    n_star = math.floor(TAU_DECAY * math.log(0.5 * ACC * L**2 / 0.95)) + 1
    assert float(w.reconv_s) == pytest.approx(n_star * DT)
    # never back below the threshold before the record ends
    est, true, *_ = _scenario(spike_at=T - 1)
    w = m.window_metrics(est, true, None, START, L, DT)
    assert not bool(w.reconverged) and np.isnan(float(w.reconv_s))


def test_padding_beyond_n_valid_is_ignored_and_stops_give_nan_percent():
    est, true, *_ = _scenario()
    n_valid = 130
    ref = m.window_metrics(
        jax.tree.map(lambda a: a[:n_valid], est),
        jax.tree.map(lambda a: a[:n_valid], true),
        None,
        START,
        L,
        DT,
    )
    junk = est._replace(llh=est.llh.at[n_valid:, 0].add(1.0))  # 6000 km errors in the padding
    pad = m.window_metrics(junk, true, None, START, L, DT, n_valid=n_valid)
    for a, b in zip(ref, pad, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12)
    # standing still: no distance, the ratio is undefined
    still = true._replace(llh=jnp.tile(true.llh[:1], (T, 1)))
    w = m.window_metrics(est._replace(llh=still.llh), still, None, START, L, DT)
    assert float(w.distance_m) == 0.0 and np.isnan(float(w.pct_of_distance))


def _random_cov(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.diag(rng.uniform(0.1, 2.0, n))


def test_nees_is_exact_for_whitened_errors():
    """e = chol(P) z gives NEES = |z|^2 exactly; P is given in (rad, rad, m) units."""
    rng = np.random.default_rng(2)
    n_ep = 12
    llh_t, vel_t = _truth_east(n_ep, SPEED, DT)
    scale6 = np.array([M_PER_RAD_N, M_PER_RAD_E, 1.0, 1.0, 1.0, 1.0])
    P_nav, err_pos, err_vel, z2_pos, z2_all = [], [], [], [], []
    for _ in range(n_ep):
        P_m = _random_cov(rng, 6) * 0.01  # metres, m/s: decimetre-level
        C = np.linalg.cholesky(P_m)
        z = rng.normal(size=6)
        e = C @ z  # (north, east, up) metres, then velocity ENU
        P9 = np.eye(9) * 1e-4  # attitude block appended (ignored)
        P9[:6, :6] = P_m / scale6[:, None] / scale6[None, :]
        P_nav.append(P9)
        err_pos.append(e[:3])
        err_vel.append(e[3:])
        z2_pos.append(z[:3] @ z[:3])
        z2_all.append(z @ z)
    err_pos, err_vel = np.array(err_pos), np.array(err_vel)
    err_enu = np.column_stack([err_pos[:, 1], err_pos[:, 0], err_pos[:, 2]])
    est = m.Track(
        jnp.asarray(_apply_enu(llh_t, err_enu)), jnp.asarray(vel_t + err_vel), jnp.zeros(n_ep)
    )
    true = m.Track(jnp.asarray(llh_t), jnp.asarray(vel_t), jnp.zeros(n_ep))
    q_pos, q_all = m.nees(est, true, jnp.asarray(np.array(P_nav)))
    np.testing.assert_allclose(np.asarray(q_pos), z2_pos, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(q_all), z2_all, rtol=1e-8)
    w = m.window_metrics(est, true, jnp.asarray(np.array(P_nav)), 3, 5, DT)
    assert float(w.nees_pos) == pytest.approx(np.mean(z2_pos[3:8]), rel=1e-8)
    assert float(w.nees_posvel) == pytest.approx(np.mean(z2_all[3:8]), rel=1e-8)


def test_monte_carlo_nees_lies_in_the_chi2_interval():
    """Errors drawn from N(0, P): the mean NEES over 400 runs falls in the 99.9 % interval."""
    rng = np.random.default_rng(5)
    runs, n_ep = 400, 3
    llh_t, vel_t = _truth_east(n_ep, SPEED, DT)
    P_m = _random_cov(rng, 6)
    scale6 = np.array([M_PER_RAD_N, M_PER_RAD_E, 1.0, 1.0, 1.0, 1.0])
    P_rad = P_m / scale6[:, None] / scale6[None, :]
    e = rng.multivariate_normal(np.zeros(6), P_m, size=(runs, n_ep))
    est_llh = np.stack([_apply_enu(llh_t, np.column_stack([x[:, 1], x[:, 0], x[:, 2]])) for x in e])
    est = m.Track(jnp.asarray(est_llh), jnp.asarray(vel_t + e[..., 3:]), jnp.zeros((runs, n_ep)))
    true = m.Track(jnp.asarray(llh_t), jnp.asarray(vel_t), jnp.zeros(n_ep))
    P = jnp.asarray(np.tile(P_rad, (n_ep, 1, 1)))
    q_pos, q_all = jax.vmap(lambda s: m.nees(s, true, P))(est)
    for q, dof in ((q_pos, 3), (q_all, 6)):
        mean = np.asarray(q).mean(axis=0)  # per epoch, over runs
        lo, hi = m.chi2_interval(dof, runs, prob=0.999)
        assert np.all((mean > lo) & (mean < hi)), (mean, lo, hi)
    # and the interval is tight enough to catch a covariance 30 % too small
    q_bad, _ = jax.vmap(lambda s: m.nees(s, true, P * 0.7))(est)
    assert np.all(np.asarray(q_bad).mean(axis=0) > m.chi2_interval(3, runs, prob=0.999)[1])


def test_chi2_interval_against_tables():
    # chi-square tables: chi2(10) 2.5 % / 97.5 % = 3.2470 / 20.4832; chi2(3) 0.2158 / 9.3484
    lo, hi = m.chi2_interval(10)
    assert (lo, hi) == (pytest.approx(3.2470, abs=1e-4), pytest.approx(20.4832, abs=1e-4))
    lo, hi = m.chi2_interval(3)
    assert (lo, hi) == (pytest.approx(0.2158, abs=1e-4), pytest.approx(9.3484, abs=1e-4))
    # Bar-Shalom et al.: N = 50 runs of a 2-state NEES -> chi2(100)/50 = [1.48, 2.59]
    lo, hi = m.chi2_interval(2, 50)
    assert (lo, hi) == (pytest.approx(74.2219 / 50, abs=1e-4), pytest.approx(129.5612 / 50, 1e-6))


def test_run_rms_after_convergence_exclusion():
    dt, n_ep = 0.5, 2000
    llh_t, _ = _truth_east(n_ep, SPEED, dt)
    sign = np.where(np.arange(n_ep) % 2 == 0, 1.0, -1.0)[:, None]
    err = sign * np.array([0.3, 0.4, 1.2])
    err[:600] = 25.0  # the first 300 s (convergence) are excluded
    r = m.run_rms(jnp.asarray(_apply_enu(llh_t, err)), jnp.asarray(llh_t), dt, exclude_s=300.0)
    np.testing.assert_allclose(np.asarray(r.rms_enu_m), [0.3, 0.4, 1.2], atol=1e-8)
    assert float(r.rms_2d_m) == pytest.approx(0.5, rel=1e-9)
    assert float(r.rms_3d_m) == pytest.approx(1.3, rel=1e-9)
    assert float(r.max_2d_m) == pytest.approx(0.5, rel=1e-9)
    assert int(r.n_epochs) == n_ep - 600


def test_window_metrics_vmap_equals_loop():
    est, true, *_ = _scenario()
    rng = np.random.default_rng(3)
    n = 1000
    starts = jnp.asarray(rng.integers(12, 100, n))
    lengths = jnp.asarray(rng.integers(1, 50, n))
    P = jnp.asarray(np.tile(np.diag([1e-12, 1e-12, 1.0, 0.1, 0.1, 0.1, 1e-4]), (T, 1, 1)))
    f = jax.jit(jax.vmap(lambda s, n_: m.window_metrics(est, true, P, s, n_, DT)))
    batch = f(starts, lengths)
    for i in (0, 17, 999):
        one = m.window_metrics(est, true, P, int(starts[i]), int(lengths[i]), DT)
        for a, b in zip(batch, one, strict=True):
            np.testing.assert_allclose(np.asarray(a)[i], np.asarray(b), rtol=1e-12, atol=1e-15)
