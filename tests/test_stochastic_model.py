"""The PPP stochastic model of time-correlated errors (issue 16): closed forms, not tuning.

- ``models.white_equivalent_var`` is the sum over all lags of a first-order Gauss-Markov
  (AR(1)) autocovariance, so N times the variance of an N-epoch mean tends to it;
- the ambiguities' random walk has the products' low-lag PSD sum 2 sigma^2 / tau;
- sf_code's ionosphere-residual state is a first-order Gauss-Markov process whose discretised
  covariance converges to the model's variance and whose estimate decays with its tau.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.states import StateLayout
from jaxnav.filter import ekf
from jaxnav.gnss import models, ppp


@pytest.mark.parametrize(("tau_s", "dt_s"), [(30.0, 1.0), (30.0, 30.0), (1800.0, 1.0),
                                             (5.0, 30.0)])
def test_white_equivalent_var_is_the_sum_of_the_autocovariance(tau_s, dt_s):
    sigma = 0.2
    rho = np.exp(-dt_s / tau_s)
    lags = np.arange(1, 200_000)
    series = sigma**2 * (1.0 + 2.0 * np.sum(rho**lags))
    got = float(models.white_equivalent_var(sigma, tau_s, dt_s))
    assert got == pytest.approx(series, rel=1e-9)
    # N Var(mean of N) -> the same limit (closed form of the AR(1) mean's variance)
    n = 1e7
    var_mean = sigma**2 / n * ((1 + rho) / (1 - rho) - 2 * rho * (1 - rho**n) / (n * (1 - rho)**2))
    assert n * var_mean == pytest.approx(got, rel=1e-3)


def test_white_equivalent_var_limits():
    """dt >> tau: white (sigma^2); dt << tau: 2 tau / dt sigma^2."""
    assert float(models.white_equivalent_var(1.0, 1.0, 100.0)) == pytest.approx(1.0, rel=1e-12)
    assert float(models.white_equivalent_var(1.0, 1e4, 1.0)) == pytest.approx(2e4, rel=1e-8)


def test_zenith_sigmas_follow_the_update_interval():
    cfg = ppp.PppConfig()
    code_1s, phase_1s = cfg.zenith_sigmas(1.0)
    code_30s, _ = cfg.zenith_sigmas(30.0)
    rho = np.exp(-1.0 / cfg.multipath_tau_s)
    want = np.sqrt(cfg.code_sigma_m**2 + cfg.multipath_code_sigma_m**2 * (1 + rho) / (1 - rho))
    assert float(code_1s) == pytest.approx(want, rel=1e-12)
    assert float(code_30s) < float(code_1s)  # fewer, less correlated updates
    sf_code, _ = ppp.PppConfig(mode="sf_code").zenith_sigmas(1.0)
    assert float(sf_code) > float(code_1s)  # C/A white noise 0.3 m > P 0.2 m
    assert float(phase_1s) > cfg.phase_sigma_m


def _obs(iono_m):
    """The rows tests' synthetic sky (6 slots) with a uniform model ionosphere [m]."""
    from test_ppp_rows import S, _sky  # tests/ is on sys.path (pytest's prepend import mode)

    return _sky()[0]._replace(iono_model_l1_m=jnp.full(S, iono_m))


def test_ambiguity_random_walk_is_the_products_psd():
    cfg = ppp.PppConfig(mode="float_ppp", n_slots=6)
    layout = StateLayout(ppp.gnss_blocks(cfg))
    F, q = ppp.gnss_dynamics(cfg, layout, jnp.full(6, 0.5), _obs(0.0))
    want = (2 * cfg.orbit_sigma_m**2 / cfg.orbit_tau_s
            + 2 * cfg.sat_clock_sigma_m**2 / cfg.sat_clock_tau_s)
    np.testing.assert_allclose(np.asarray(q[layout.sl("amb")]), want, rtol=1e-12)
    assert want > 0
    assert np.all(np.asarray(F[layout.sl("amb")]) == 0.0)  # constants + the random walk


def test_sf_code_iono_residual_is_gauss_markov_with_the_model_variance():
    """Propagating P_k+1 = Phi P Phi^T + Qd from 0 converges to sigma^2 = iono_model_var (the
    stationary variance of dI' = -dI / tau + w, PSD 2 sigma^2 / tau)."""
    cfg = ppp.PppConfig(mode="sf_code", n_slots=6, estimate_zwd=False)
    layout = StateLayout(ppp.gnss_blocks(cfg))
    obs = _obs(5.0)
    el = jnp.array([0.2, 0.3, 0.6, 1.0, 1.2, 1.5])
    F, q = ppp.gnss_dynamics(cfg, layout, el, obs)
    sl = layout.sl("iono_res")
    dt = 30.0
    Phi, Qd = ekf.discretize(F, jnp.eye(layout.size), jnp.diag(q), dt, squarings=0)
    P = jnp.zeros((layout.size, layout.size))
    P = jax.lax.fori_loop(0, 2000, lambda _, P: Phi @ P @ Phi.T + Qd, P)  # 2000 x 30 s >> tau
    var = np.asarray(ppp.iono_model_var(cfg, obs.iono_model_l1_m, el))
    np.testing.assert_allclose(np.diag(np.asarray(P))[sl], var, rtol=1e-4)
    assert np.all(var >= (cfg.iono_model_residual_fraction * 5.0) ** 2)
    # the estimate decays with the same tau
    est = jnp.zeros(layout.size).at[sl].set(1.0)
    est = ppp.gnss_nominal_predict(cfg, layout, est, dt)
    np.testing.assert_allclose(np.asarray(est[sl]), np.exp(-dt / cfg.iono_model_residual_tau_s),
                               rtol=1e-12)
