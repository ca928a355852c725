"""Noise parameters by maximum likelihood (jaxnav.filter.tune, ``jaxnav tune``; issue 20).

- The likelihood's terms are the filter's own: ``UpdateResult.logdet`` / ``.nis`` equal
  log det S_u and nu_u^T S_u^-1 nu_u computed directly for the used rows.
- ``fit`` on closed forms: a quadratic NLL in ln(theta) has its minimum and its sigma
  1/sqrt(curvature) exactly; a parameter the NLL does not see is flagged not identified.
- The gradient through a whole tight-filter run equals central finite differences.
- Recovery: in the matched white-noise simulator of tests/test_consistency.py (INS15 + float
  PPP, gates off: there are no outliers), starting from 2x / 0.5x / 2x the simulator's code,
  phase and Doppler sigmas, the fit returns each within 20 % (the issue's bound), identified.
  The suite runs 3 runs of 90 s; the issue's form (10 runs of a 15-min drive) is marked full.
- ``jaxnav tune`` on the car drive (skipped without ../shared/data): a tuned TOML that
  ``jaxnav lc`` loads, and one-line errors (exit code 2) for bad ``--params``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.filter import ekf, tight
from jaxnav.filter import tune as tn

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "gnss_imu_drive"
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "car_gnss_imu_drive.toml"
NAMES = ("code_sigma_m", "phase_sigma_m", "doppler_sigma_m_s")


def test_logdet_and_nis_are_the_used_rows_gaussian_terms():
    rng = np.random.default_rng(7)
    n, m = 6, 5
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    H = rng.normal(size=(m, n))
    B = rng.normal(size=(m, m))
    R = B @ B.T + 0.5 * np.eye(m)
    y = rng.normal(size=m) * 3.0
    mask = np.array([True, False, True, True, False])
    res = ekf.masked_update(jnp.zeros(n), jnp.asarray(P), jnp.asarray(y), jnp.asarray(H),
                            jnp.asarray(R), jnp.asarray(mask))
    u = mask
    S = H[u] @ P @ H[u].T + R[np.ix_(u, u)]
    np.testing.assert_allclose(float(res.logdet), np.linalg.slogdet(S)[1], rtol=1e-12)
    np.testing.assert_allclose(float(res.nis), y[u] @ np.linalg.solve(S, y[u]), rtol=1e-12)
    none = ekf.masked_update(jnp.zeros(n), jnp.asarray(P), jnp.asarray(y), jnp.asarray(H),
                             jnp.asarray(R), jnp.zeros(m, bool))
    assert float(none.logdet) == 0.0 and float(none.nis) == 0.0


def test_fit_closed_forms_and_an_unidentified_parameter():
    # NLL = 1/2 sum c_i (ln theta_i - ln t_i)^2 + (a term of theta_2 only through nothing)
    target = np.array([0.3, 7.0])
    curv = np.array([400.0, 25.0])

    def nll(theta):
        d = jnp.log(theta[:2]) - jnp.log(jnp.asarray(target))
        return 0.5 * jnp.sum(jnp.asarray(curv) * d**2) + 0.0 * theta[2]

    res = tn.fit(nll, np.array([1.0, 1.0, 2.0]), ("a", "b", "ignored"), start_factors=(1.0, 3.0))
    np.testing.assert_allclose(res.value[:2], target, rtol=1e-5)
    # the Cramer-Rao sigma of ln theta: 1 / sqrt(curvature)
    np.testing.assert_allclose(res.sigma_log[:2], 1.0 / np.sqrt(curv), rtol=1e-4)
    assert res.identified.tolist() == [True, True, False]
    assert math.isinf(res.sigma_log[2])
    # a flat direction is not moved from the start it began at (2, or 3 x 2)
    assert min(abs(res.value[2] - 2.0), abs(res.value[2] - 6.0)) < 1e-9
    with pytest.raises(ValueError, match="positive"):
        tn.fit(nll, np.array([1.0, -1.0, 1.0]), ("a", "b", "c"))


@functools.cache
def _sim(n_runs: int, duration_s: float):
    """The matched simulator of test_consistency (white errors the filter models exactly)."""
    sys.path.insert(0, str(Path(__file__).parent))  # also when run as a script
    import test_consistency as tc

    from jaxnav.sim import scenario
    from jaxnav.study.factory import SimFactory

    factory = SimFactory({"duration_s": duration_s, "ins_grade": "span_cpt_in_run"})
    factory.cfg = dataclasses.replace(factory.cfg, obs_params=tc.MATCHED_OBS)
    tf = tc._matched_filter(factory, "float_ppp")
    # no outliers in this world: the gates and post-fit test off (their decisions would make the
    # NLL piecewise, jaxnav/filter/tune.py)
    tf = eqx.tree_at(lambda t: t.cfg, tf, dataclasses.replace(
        tf.cfg, gate_chi2=float("inf"), postfit_sigma=None))
    geo = factory.geo
    cfg = dataclasses.replace(factory.cfg, imu_grade="span_cpt_in_run")
    keys = jax.random.split(jax.random.PRNGKey(20), (n_runs, 2))
    real = jax.jit(jax.vmap(lambda k: scenario.realize(k, geo, cfg, False)))(keys[:, 0])
    nav_true = scenario.initial_ins_state(geo)
    carry_keys = keys[:, 1]

    def nll(theta):
        # tree_at, not dataclasses.replace: the traced values become leaves without __init__'s
        # (type-checked) float fields seeing a tracer
        f = eqx.tree_at(lambda t: [getattr(t.cfg, n) for n in NAMES], tf, list(theta))

        def one(obs0, inputs, k):
            _, out = tight.run(f, tc._perturbed_carry(f, nav_true, obs0, k), inputs)
            return tn.innovation_nll(out.nis, out.logdet, out.dof)

        return jnp.sum(jax.vmap(one)(real.obs0, real.ins_inputs, carry_keys))

    return nll, np.array([getattr(tf.cfg, n) for n in NAMES])


def _in_fresh_process(check: str, *args) -> None:
    """Run ``check(*args)`` of this file in a subprocess with XLA:CPU's default emitters: the
    older fusion emitters the suite opts into (tests/conftest.py) crash (SIGSEGV) executing the
    reverse-mode gradient of the tight filter (measured on jaxlib 0.10; the library's default,
    which ``jaxnav tune`` uses, is unaffected)."""
    env = dict(os.environ, JAXNAV_XLA_FUSION_EMITTERS="1")
    env["XLA_FLAGS"] = env.get("XLA_FLAGS", "").replace(jaxnav.OLDER_EMITTERS_FLAG, "").strip()
    r = subprocess.run([sys.executable, __file__, check, *map(str, args)], env=env,
                       capture_output=True, text=True, timeout=1500)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]


def check_gradient(n_runs: str, duration_s: str) -> None:
    nll, true = _sim(int(n_runs), float(duration_s))
    u0 = jnp.log(jnp.asarray(true * np.array([1.5, 0.7, 1.2])))
    f = jax.jit(lambda u: nll(jnp.exp(u)))
    g = np.asarray(jax.jit(jax.grad(lambda u: nll(jnp.exp(u))))(u0))
    # central differences at h = 1e-3: truncation h^2 f''' / 6 ~ 1e-6 relative (measured: the
    # h = 1e-2 difference is 1e-4, scaling as h^2); the NLL's roundoff (~1e-7 of |f|, from the
    # Cholesky of S with phase variances of mm^2 beside restarted ambiguities) adds
    # ~1e-7 |f| / h ~ 1e-4 relative here. Smaller h is worse (1e-5: 1 %), as that predicts.
    h = 1e-3
    fd = np.array([(float(f(u0.at[i].add(h))) - float(f(u0.at[i].add(-h)))) / (2 * h)
                   for i in range(3)])
    np.testing.assert_allclose(g, fd, rtol=1e-3)


def test_gradient_through_the_filter_matches_finite_differences():
    _in_fresh_process("check_gradient", 2, 60.0)


def check_recovery(n_runs: str, duration_s: str) -> None:
    nll, true = _sim(int(n_runs), float(duration_s))
    res = tn.fit(nll, true * np.array([2.0, 0.5, 2.0]), NAMES, start_factors=(1.0,))
    assert res.converged
    assert res.identified.all(), res.table()
    np.testing.assert_allclose(res.value, true, rtol=0.2, err_msg=res.table())
    # the fit's own 1-sigma covers the error at 4 sigma (Cramer-Rao; three parameters)
    assert np.all(np.abs(np.log(res.value / true)) < 4.0 * res.sigma_log), res.table()


def test_recovers_the_simulators_gnss_noise():
    _in_fresh_process("check_recovery", 3, 90.0)


@pytest.mark.full
def test_recovers_the_simulators_gnss_noise_full():
    _in_fresh_process("check_recovery", 10, 900.0)


# ---- jaxnav tune on the car drive -------------------------------------------------------------
needs_drive = pytest.mark.skipif(not (DATA / "imu_1934.csv").exists(),
                                 reason=f"real data not present ({DATA})")


def _args(tmp_path, *extra):
    return ["tune", "--config", str(CONFIG), "--imu", str(DATA / "imu_1934.csv"),
            "--gnss", str(DATA / "gnss_1934_sf.pos"), "--out", str(tmp_path / "tuned.toml"),
            *extra]


@pytest.mark.parametrize("params, message", [
    ("gnss.nope", "cannot be tuned; allowed:"),
    ("constraints.nhc_sigma_m_s,constraints.nhc_sigma_m_s", "given twice"),
    ("", "at least one key"),
])
def test_tune_bad_params_are_one_line_errors(tmp_path, capsys, params, message):
    """Refused before any data is read: the logs here are empty stand-ins (the argument parser
    only checks that they exist), so the test needs no data set."""
    from jaxnav import cli

    imu, gnss = tmp_path / "imu.csv", tmp_path / "gnss.pos"
    imu.write_text("")
    gnss.write_text("")
    argv = ["tune", "--config", str(CONFIG), "--imu", str(imu), "--gnss", str(gnss),
            "--out", str(tmp_path / "tuned.toml"), "--params", params]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@needs_drive
def test_tune_writes_a_config_jaxnav_lc_loads(tmp_path, capsys):
    from jaxnav import cli
    from jaxnav.apps.car_config import load_config

    argv = _args(tmp_path, "--params", "gnss.pos_sigma_floor_m,constraints.nhc_sigma_m_s",
                 "--duration", "60", "--starts", "1", "--max-steps", "3")
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    tuned = load_config(tmp_path / "tuned.toml")
    base = load_config(CONFIG)
    assert tuned.gnss_pos_sigma_floor_m != base.gnss_pos_sigma_floor_m
    line = next(ln for ln in out.splitlines() if ln.startswith("constraints.nhc_sigma_m_s"))
    # the printed fit (5 digits) is what was written
    assert float(line.split()[2]) == pytest.approx(tuned.constraints_nhc_sigma_m_s, rel=1e-4)
    # everything else unchanged
    assert dataclasses.replace(tuned, gnss_pos_sigma_floor_m=base.gnss_pos_sigma_floor_m,
                               constraints_nhc_sigma_m_s=base.constraints_nhc_sigma_m_s) == base
    assert cli.main(argv) == 2  # --out exists: no overwrite without --overwrite
    assert "--overwrite" in capsys.readouterr().err


if __name__ == "__main__":  # _in_fresh_process: python tests/test_tune.py CHECK ARGS...
    globals()[sys.argv[1]](*sys.argv[2:])


def test_fit_table_prints_an_unbounded_factor_as_such():
    """A flat direction's 1-sigma factor exp(sigma) overflows: the table says '> 1e6' or 'inf',
    not a 140-digit number (seen on the car with --outage-grid)."""
    res = tn.FitResult(
        value=np.array([1.0, 2.0, 3.0]), start=np.ones(3), sigma_log=np.array([0.1, 400.0, np.inf]),
        identified=np.array([True, False, False]), names=("a", "b", "c"), nll=0.0, nll_start=1.0,
        steps=1, evaluations=1, converged=True, starts=((1.0, 0.0),),
        hessian_eigvals=np.ones(3))
    lines = res.table().splitlines()
    assert lines[2].split()[3] == ">" and lines[2].split()[4] == "1e6"
    assert lines[3].split()[3] == "inf"
    assert max(len(ln) for ln in lines) < 120


@needs_drive
def test_outage_grid_withholds_fixes_in_the_likelihood():
    """``jaxnav tune --outage-grid``: the NLL is that of the loose run with the grid's fixes
    withheld (the forward filter's own per-epoch NIS and log det over the aligned epochs), and
    differs from the all-fixes NLL."""
    from jaxnav.apps import lc_filter as lcf
    from jaxnav.apps import tune as app
    from jaxnav.apps.car_config import load_config
    from jaxnav.apps.lc_drive import load_drive

    cfg = load_config(CONFIG)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        drive = load_drive(str(DATA / "imu_1934.csv"), None, str(DATA / "gnss_1934_sf.pos"), cfg,
                           duration_s=120.0)
    keys = app.parse_params("constraints.nhc_sigma_m_s", cfg)
    _, slots = app._layout(keys, cfg)
    withheld = lcf.plan_outages(drive, lcf.grid_schedule(drive, 60.0, 20.0, 10.0)).withheld
    theta = jnp.asarray(app._values(cfg, slots))
    nll_out = float(jax.jit(app.drive_nll(cfg, drive, slots, withheld))(theta))
    nll_all = float(jax.jit(app.drive_nll(cfg, drive, slots))(theta))
    lf = lcf.build_filter(cfg, drive)
    _, out = lcf.run_filter(lf, lcf.initial_carry(cfg, lf, drive),
                            lcf.epoch_inputs(cfg, drive, withheld))
    on = np.asarray(out.aligned)
    ref = 0.5 * float(np.sum(np.asarray(out.nis)[on] + np.asarray(out.logdet)[on]
                             + np.asarray(out.dof)[on] * np.log(2 * np.pi)))
    assert nll_out == pytest.approx(ref, rel=1e-9)
    assert abs(nll_out - nll_all) > 1.0
