"""experiments/esbc_multipath_calibration.py: the multipath combination, the arc split, the
sigma0 / correlation estimators on a synthetic process of known parameters, and the ESBC
station (GPS, first 6 h) through the whole calibration (skipped without ../shared/data).

Tolerance of the synthetic test (how it is derived)
---------------------------------------------------
Residuals: r = sigma0 g(E) z per arc, z = sqrt(1 - w) x + sqrt(w) e with x a unit first-order
Gauss-Markov sequence (phi = exp(-dt / tau)) and e white, so rho(0) = 1 and
rho(k > 0) = (1 - w) phi^k; plus an arbitrary constant per arc, removed by the estimator.

- Expected values: removing each arc's mean biases the estimators slightly (by ~1/n_arc). The
  test computes that bias exactly: for one arc, z_hat = D^-1 P D z with D = diag(g(E_t)) and
  P = I - 11'/n, so Cov(z_hat) = M C M' (M = D^-1 P D, C = Cov(z)); the expected sigma0 is
  sigma0 sqrt(tr Cov / n) and the expected ACF is [sum_t Cov(t, t+k) / (n - k)] / [tr Cov / n];
  the expected (A, tau) are the estimator's fit applied to that expected ACF.
- Standard errors, for N = n_arcs n epochs of a Gaussian process: the sample variance has
  var(s^2) / sigma^4 = (2 / N) sum_m rho_m^2 (an effective number of independent samples
  N / sum_m rho_m^2), so SE(sigma0) / sigma0 = sqrt(sum_m rho_m^2 / (2 N)); the sample ACF has
  Bartlett's covariance (Box & Jenkins, eq. 2.1.13) and the fitted slope b = -1/tau and
  intercept ln A are linear in ln r_k, so their SEs follow by the delta method.
- Each estimate must lie within 4 SE of its expected value (two-sided probability 6e-5 for a
  correct estimator); the generator's seed is fixed, so the test is deterministic.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

EXP = Path(__file__).resolve().parents[1] / "experiments" / "esbc_multipath_calibration.py"
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "esbc_static"

DT_S = 30.0
N_ARCS, N_EPOCHS = 100, 720  # 100 arcs of 6 h
SIGMA0_M, TAU_S, WHITE = 0.25, 135.0, 0.3
N_SE = 4.0


@pytest.fixture(scope="module")
def mpcal():
    spec = importlib.util.spec_from_file_location("esbc_multipath_calibration", EXP)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------------------------
# Building blocks


def test_multipath_combination_leaves_multipath_plus_constant(mpcal):
    """Geometry, clocks and first-order ionosphere cancel; ambiguities leave a constant."""
    rng = np.random.default_rng(1)
    f1, f2 = 1575.42e6, 1227.60e6
    a = (f1 / f2) ** 2
    geom = 2.2e7 + 1e3 * np.cumsum(rng.normal(size=200))  # range + clocks + troposphere [m]
    iono = 5.0 + rng.normal(size=200).cumsum() * 0.01  # first-order delay on f1 [m]
    m1, m2 = rng.normal(0, 0.3, 200), rng.normal(0, 0.3, 200)
    b1, b2 = 123.4, -56.7  # ambiguities x wavelengths [m]
    p1, p2 = geom + iono + m1, geom + a * iono + m2
    l1, l2 = geom - iono + b1, geom - a * iono + b2
    for band, code, mp_true in ((0, p1, m1), (1, p2, m2)):
        c1, c2 = mpcal.mp_coefficients(f1, f2, band)
        left = mpcal.multipath_m(code, l1, l2, f1, f2, band) - mp_true
        assert np.ptp(left) < 1e-6
        assert left[0] == pytest.approx(c1 * b1 + c2 * b2, abs=1e-6)


def test_arcs_break_at_gaps_slips_and_gf_jumps(mpcal):
    t = 30.0 * np.arange(12)
    ok = np.ones((12, 2), bool)
    ok[4, 0] = False  # gap
    gf = np.zeros((12, 2))
    gf[8:, 0] = 0.06  # geometry-free jump at epoch 8 (> 0.05 m)
    gf[3:, 1] = 0.04  # a smaller one: no break
    slip = np.zeros((12, 2), bool)
    slip[6, 1] = True  # loss of lock
    lab = mpcal.arc_labels(ok, gf, slip, t)
    assert lab[:, 0].tolist() == [0, 0, 0, 0, -1, 1, 1, 1, 2, 2, 2, 2]
    assert lab[:, 1].tolist() == [3] * 6 + [4] * 6
    x = np.arange(24.0).reshape(2, 12).T
    res, kept = mpcal.remove_arc_means(x, lab, min_epochs=4)
    assert (kept[:, 0] == -1).sum() == 3 + 1  # the 3-epoch arc and the gap are dropped
    np.testing.assert_allclose(res[:4, 0], [-1.5, -0.5, 0.5, 1.5])
    np.testing.assert_allclose(np.nansum(res, axis=0), 0.0, atol=1e-12)


def test_main_exits_2_without_data(mpcal, tmp_path, capsys):
    missing = tmp_path / "no_such_folder"
    assert mpcal.main(["--data", str(missing)]) == 2
    err = capsys.readouterr().err.strip()
    assert str(missing) in err and len(err.splitlines()) == 1


# --------------------------------------------------------------------------------------------
# Synthetic Gauss-Markov + white residuals of known sigma0, tau, white fraction


def _rho(lag):
    lag = np.abs(np.asarray(lag))
    return np.where(lag == 0, 1.0, (1.0 - WHITE) * np.exp(-DT_S / TAU_S) ** lag)


def _synthetic(mpcal):
    rng = np.random.default_rng(20200625)
    t_s = DT_S * np.arange(N_EPOCHS)
    el_rad = np.radians(11.0 + 69.0 * np.sin(np.pi * (t_s + DT_S / 2) / (N_EPOCHS * DT_S)))
    phi = math.exp(-DT_S / TAU_S)
    x = np.empty((N_EPOCHS, N_ARCS))
    x[0] = rng.standard_normal(N_ARCS)
    for k in range(1, N_EPOCHS):
        x[k] = phi * x[k - 1] + math.sqrt(1.0 - phi**2) * rng.standard_normal(N_ARCS)
    z = math.sqrt(1.0 - WHITE) * x + math.sqrt(WHITE) * rng.standard_normal(x.shape)
    gain = mpcal.elevation_gain(el_rad)
    mp_m = SIGMA0_M * gain[:, None] * z + rng.uniform(-50.0, 50.0, N_ARCS)  # + arc constants
    el = np.repeat(el_rad[:, None], N_ARCS, axis=1)
    flat = np.zeros((N_EPOCHS, N_ARCS))
    return mp_m, flat, flat.astype(bool), el, t_s, gain


def _expected(mpcal, gain, lag_s):
    """Exact expectation of the estimators' numerators / denominators after arc-mean removal."""
    n = N_EPOCHS
    idx = np.arange(n)
    cov_z = _rho(idx[:, None] - idx[None, :])
    m = (np.eye(n) - 1.0 / n) * gain[None, :] / gain[:, None]  # D^-1 P D
    cov = m @ cov_z @ m.T
    c0 = np.trace(cov) / n
    k_max = lag_s.size - 1
    acf = np.array([np.trace(cov, offset=k) / (n - k) for k in range(k_max + 1)]) / c0
    amp, tau = mpcal.fit_gauss_markov(lag_s, acf)
    return SIGMA0_M * math.sqrt(c0), acf, amp, tau


def _bartlett_cov(lags, n_total):
    """Bartlett's large-sample covariance of the sample ACF at integer ``lags``."""
    v = np.arange(-3000, 3001)
    out = np.empty((len(lags), len(lags)))
    for a, i in enumerate(lags):
        for b, j in enumerate(lags):
            terms = (
                _rho(v) * _rho(v + j - i)
                + _rho(v + j) * _rho(v - i)
                + 2 * _rho(i) * _rho(j) * _rho(v) ** 2
                - 2 * _rho(i) * _rho(v) * _rho(v - j)
                - 2 * _rho(j) * _rho(v) * _rho(v - i)
            )
            out[a, b] = terms.sum() / n_total
    return out


def _fit_standard_errors(lag_s, acf_expected, amp):
    """Delta-method SEs of tau and A of the log-linear fit over the lags the estimator uses."""
    lead = np.cumprod(acf_expected[1:] >= amp / math.e)
    n_fit = max(3, int(lead.sum()))
    k = np.arange(1, n_fit + 1)
    x = lag_s[k]
    w_slope = (x - x.mean()) / np.sum((x - x.mean()) ** 2)
    w_icpt = 1.0 / n_fit - x.mean() * w_slope
    cov_r = _bartlett_cov(k, N_ARCS * N_EPOCHS)
    r = _rho(k)
    cov_log = cov_r / np.outer(r, r)
    slope = -1.0 / TAU_S
    se_tau = math.sqrt(w_slope @ cov_log @ w_slope) / slope**2
    se_amp = amp * math.sqrt(w_icpt @ cov_log @ w_icpt)
    return se_tau, se_amp


def test_synthetic_sigma0_tau_white_fraction_recovered(mpcal):
    mp_m, gf_m, slip, el, t_s, gain = _synthetic(mpcal)
    res = mpcal.calibrate_code(mp_m, gf_m, slip, el, t_s, DT_S)
    assert res["n_arcs"] == N_ARCS and res["n_epochs"] == N_ARCS * N_EPOCHS

    sigma_exp, acf_exp, amp_exp, tau_exp = _expected(mpcal, gain, res["lag_s"])
    # the estimators are nearly unbiased: the arc-mean bias is below 1 % (sigma0) / 5 % (tau)
    assert sigma_exp == pytest.approx(SIGMA0_M, rel=0.01)
    assert tau_exp == pytest.approx(TAU_S, rel=0.05)
    assert 1.0 - amp_exp == pytest.approx(WHITE, abs=0.02)

    sum_rho2 = 1.0 + 2.0 * np.sum(_rho(np.arange(1, 3000)) ** 2)
    n_eff = N_ARCS * N_EPOCHS / sum_rho2
    se_sigma = SIGMA0_M / math.sqrt(2.0 * n_eff)
    se_tau, se_amp = _fit_standard_errors(res["lag_s"], acf_exp, amp_exp)
    print(
        f"sigma0 {res['sigma0_m']:.4f} (expected {sigma_exp:.4f} +- {se_sigma:.4f}); "
        f"tau {res['tau_s']:.1f} s ({tau_exp:.1f} +- {se_tau:.1f}); white "
        f"{res['white_fraction']:.3f} ({1 - amp_exp:.3f} +- {se_amp:.3f}); N_eff {n_eff:.0f}"
    )
    assert abs(res["sigma0_m"] - sigma_exp) < N_SE * se_sigma
    assert abs(res["tau_s"] - tau_exp) < N_SE * se_tau
    assert abs(res["white_fraction"] - (1.0 - amp_exp)) < N_SE * se_amp
    # the tolerances are tight enough to mean something
    assert N_SE * se_sigma < 0.03 * SIGMA0_M and N_SE * se_tau < 0.25 * TAU_S
    # every lag of the ACF, not only the fit
    se_r = np.sqrt(np.diag(_bartlett_cov(np.arange(1, 41), N_ARCS * N_EPOCHS)))
    assert np.all(np.abs(res["acf"][1:] - acf_exp[1:]) < N_SE * se_r)


# --------------------------------------------------------------------------------------------
# Real data: ESBC, GPS, first 6 h


@pytest.fixture(scope="module")
def esbc_gps(mpcal):
    if not (DATA / mpcal.OBS_FILE).is_file():
        pytest.skip(f"shared ESBC data not present: {DATA} (only in the project workspace)")
    return mpcal.calibrate(DATA, systems=("G",), hours=6.0)


def test_esbc_gps_multipath_is_physical(esbc_gps):
    assert set(esbc_gps) == {"G/C1C", "G/C1W", "G/C2W"}
    r = esbc_gps["G/C1C"]
    assert r["n_arcs"] >= 10
    assert 0.05 < r["sigma0_m"] < 2.0
    acf = r["acf"]
    assert acf[0] == pytest.approx(1.0, abs=1e-12)
    assert 1.0 > acf[1] > acf[2] > acf[3]
