"""The replay source: a static station's real observations moved onto a simulated circuit.

Synthetic (always run): a zero move leaves every observation bit for bit; a move changes code
and phase by exactly the model's range change and the Doppler by its range-rate change; bad
``[scenario]`` tables stop before any file is read, naming the key.

Real data (ESBC00DNK, skipped without ``../shared/data``), two hours from 01:00 GPST:
- zero-motion replay reproduces the station's prepared observations exactly;
- the moved observations keep the station's errors: their ionosphere-free code residual
  against the true antenna geometry equals the station's against its ITRF coordinate to 0.1 mm
  (a range without the Earth-rotation term, or a different one from the filter's, shifts it by
  ~3 mm at 500 m);
- tightly coupled float PPP / INS15 and / RISS16 on the moved observations, no outage, are as
  accurate as kinematic PPP on the station itself: horizontal RMS over the second hour within
  2x.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav import geodesy
from jaxnav.filter import ppp_only
from jaxnav.gnss import models, ppp, replay, signals
from jaxnav.gnss.ppp_data import GnssObs
from jaxnav.study.config import ConfigError
from jaxnav.study.reference import single_run
from jaxnav.study.sources import factory_for

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "esbc_static"
FILES = dict(
    obs=DATA / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz",
    nav=DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz",
    sp3=[DATA / "GRG0MGXFIN_20201760000_01D_15M_ORB.SP3.gz",
         DATA / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"],
    clk=DATA / "GRG0MGXFIN_20201770000_01D_30S_CLK.CLK.gz",
)
# ESBC's ITRF2014 coordinate moved to 2020-06-25 (tests/test_ppp_real.py says where from).
STATION = np.array([3582104.8458, 532590.0946, 5232755.0863]) + np.array(
    [-0.0153, 0.0166, 0.0090]) * (2020.482 - 2015.0)
needs_data = pytest.mark.skipif(
    not all(Path(p).exists() for v in FILES.values() for p in (v if isinstance(v, list) else [v])),
    reason=f"shared ESBC00DNK data not found under {DATA} (a fresh clone has no ../shared)",
)


def _table(**over):
    t = dict(source="replay", obs=str(FILES["obs"]), nav=str(FILES["nav"]),
             sp3=[str(p) for p in FILES["sp3"]], clk=str(FILES["clk"]),
             station_ecef_m=[float(v) for v in STATION], start="2020-06-25T01:00:00",
             duration_s=7200)
    t.update(over)
    return t


# ------------------------------------------------------------------------------------------------
# Synthetic
# ------------------------------------------------------------------------------------------------
def _synthetic_obs(T=4, S=5, seed=0):
    rng = np.random.default_rng(seed)
    sat_pos = rng.normal(size=(T, S, 3))
    sat_pos = 2.66e7 * sat_pos / np.linalg.norm(sat_pos, axis=-1, keepdims=True)
    sat_vel = rng.normal(0.0, 2000.0, (T, S, 3))
    sat = models.SatEpoch(jnp.asarray(sat_pos), jnp.asarray(sat_vel),
                          jnp.asarray(rng.normal(0, 1e4, (T, S))), jnp.zeros((T, S)))
    return GnssObs(
        code_m=jnp.asarray(rng.uniform(2e7, 2.5e7, (T, S, 2))),
        phase_m=jnp.asarray(rng.uniform(2e7, 2.5e7, (T, S, 2))),
        range_rate_m_s=jnp.asarray(rng.normal(0, 500, (T, S))),
        available=jnp.ones((T, S), bool), slip=jnp.zeros((T, S), bool),
        code_bias_m=jnp.zeros((T, S, 2)), iono_model_l1_m=jnp.zeros((T, S)), sat=sat,
        doppler_ok=jnp.ones((T, S), bool), iono_model_ok=jnp.ones((T, S), bool),
    )


def _assert_a_zero_move_is_exact(obs):
    T = obs.code_m.shape[0]
    moved = replay.move_observations(obs, jnp.asarray(STATION),
                                     jnp.broadcast_to(jnp.asarray(STATION), (T, 3)),
                                     jnp.zeros((T, 3)))
    for a, b in zip(jax.tree.leaves(obs), jax.tree.leaves(moved), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_zero_move_leaves_every_observation_bit_for_bit():
    _assert_a_zero_move_is_exact(_synthetic_obs())


def test_a_move_adds_the_models_range_and_range_rate_change():
    obs = _synthetic_obs()
    T = obs.code_m.shape[0]
    rng = np.random.default_rng(1)
    pos = jnp.asarray(STATION + rng.normal(0, 300.0, (T, 3)))
    vel = jnp.asarray(rng.normal(0, 10.0, (T, 3)))
    moved = replay.move_observations(obs, jnp.asarray(STATION), pos, vel)
    for k in range(T):
        s_k = jax.tree.map(lambda x, k=k: x[k], obs.sat)
        at_ant = models.geometry(pos[k], vel[k], s_k)
        at_sta = models.geometry(jnp.asarray(STATION), jnp.zeros(3), s_k)
        d_rho = np.asarray(at_ant.range_m - at_sta.range_m)
        d_rate = np.asarray(at_ant.range_rate_m_s - at_sta.range_rate_m_s)
        for band in range(2):
            np.testing.assert_allclose(moved.code_m[k, :, band] - obs.code_m[k, :, band],
                                       d_rho, atol=1e-6)
            np.testing.assert_allclose(moved.phase_m[k, :, band] - obs.phase_m[k, :, band],
                                       d_rho, atol=1e-6)
        np.testing.assert_allclose(moved.range_rate_m_s[k] - obs.range_rate_m_s[k], d_rate,
                                   atol=1e-9)
    # the antenna moved ~500 m: the ranges changed by hundreds of metres, not by nothing
    assert np.abs(np.asarray(moved.code_m - obs.code_m)).max() > 50.0


@pytest.mark.parametrize("key, value, words", [
    ("source", "recorded", "scenario.source"),
    ("obs", "no/such/file.crx.gz", "scenario.obs"),
    ("start", "25 June 2020", "scenario.start"),
    ("duration_s", 7215, "scenario.duration_s"),
    ("station_ecef_m", [0.0, 0.0, 0.0], "scenario.station_ecef_m"),
    ("drive_style", "urban", "scenario.drive_style"),
    ("constellations", ["galileo"], "scenario.constellations"),
    ("environment", "urban", "environment"),
])
def test_a_bad_replay_table_names_its_key_before_any_file_is_read(tmp_path, key, value, words):
    for name in ("o", "n", "s", "c"):
        (tmp_path / name).write_text("not read")
    table = _table(**{"obs": "o", "nav": "n", "sp3": ["s"], "clk": "c", key: value})
    with pytest.raises(ConfigError, match=words):
        factory_for(table, tmp_path)


def test_paths_are_relative_to_the_study_file(tmp_path):
    for name in ("o", "n", "s", "c"):
        (tmp_path / name).write_text("not read")
    f = factory_for(_table(obs="o", nav="n", sp3=["s"], clk="c"), tmp_path)
    assert f.paths["obs"] == (tmp_path / "o").resolve()
    assert f.cfg.epoch_interval_s == 30.0 and f.cfg.systems == (signals.SYS_GPS,)


# ------------------------------------------------------------------------------------------------
# Real data
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def factory():
    return factory_for(_table())


@needs_data
def test_zero_motion_replay_reproduces_the_recorded_observations(factory):
    obs = factory.station_obs(False)
    _assert_a_zero_move_is_exact(obs)
    prep = factory._prepared(False)
    assert int(np.asarray(obs.available).sum()) == int(np.asarray(prep.obs.available).sum())


def _if_code_residual(obs, slots, pos, vel):
    """IF code - (rho + sat clock), minus the per-epoch median of the used slots (the receiver
    clock and the common troposphere): what the real receiver's errors make of the code."""
    comb = jax.vmap(ppp.combos, in_axes=(None, 0))(slots, obs)
    rho = jax.vmap(lambda p, v, s: models.geometry(p, v, s).range_m)(pos, vel, obs.sat)
    res = np.asarray(comb.code_if_m - rho + obs.sat.clock_m)
    res = np.where(np.asarray(obs.available), res, np.nan)
    return res - np.nanmedian(res, axis=1, keepdims=True)


def _residual(kind, obs, slots, pos, vel):
    """Epoch-to-epoch change of the IF carrier - rho (``phase``) or range rate - model rate
    (``doppler``), minus the per-epoch median of the used slots (receiver clock, its drift)."""
    geo = jax.vmap(models.geometry)(pos, vel, obs.sat)
    if kind == "phase":
        comb = jax.vmap(ppp.combos, in_axes=(None, 0))(slots, obs)
        res = np.asarray(comb.phase_if_m - geo.range_m + obs.sat.clock_m)
        res = np.diff(np.where(np.asarray(obs.available), res, np.nan), axis=0)
    else:
        res = np.asarray(obs.range_rate_m_s - geo.range_rate_m_s + obs.sat.clock_rate_m_s)
        res = np.where(np.asarray(obs.available & obs.doppler_ok), res, np.nan)
    return res - np.nanmedian(res, axis=1, keepdims=True)


@needs_data
def test_moved_observations_keep_the_stations_errors(factory):
    """Issue 17: the observation model's residuals on replayed data have the real data's
    statistics - code, carrier and Doppler equal the station's own residuals."""
    geo = factory.geo
    obs = factory.station_obs(False)
    moved = replay.move_observations(obs, jnp.asarray(STATION), geo.ant_pos_ecef,
                                     geo.ant_vel_ecef)
    T = obs.code_m.shape[0]
    at_station = _if_code_residual(obs, geo.slots, jnp.broadcast_to(jnp.asarray(STATION), (T, 3)),
                                   jnp.zeros((T, 3)))
    at_antenna = _if_code_residual(moved, geo.slots, geo.ant_pos_ecef, geo.ant_vel_ecef)
    assert np.nanstd(at_station) > 0.1  # real errors are there (metre-level code multipath)
    np.testing.assert_allclose(at_antenna, at_station, atol=1e-4, equal_nan=True)
    # the carrier (epoch differences: the ambiguities cancel) and the Doppler keep them too
    for kind, tol in (("phase", 1e-4), ("doppler", 1e-6)):
        a = _residual(kind, moved, geo.slots, geo.ant_pos_ecef, geo.ant_vel_ecef)
        b = _residual(kind, obs, geo.slots, jnp.broadcast_to(jnp.asarray(STATION), (T, 3)),
                      jnp.zeros((T, 3)))
        np.testing.assert_allclose(a, b, atol=tol, equal_nan=True, err_msg=kind)
    # ... and they are the receiver's, not the simulator's: ESBC's Doppler residual is far below
    # the simulator's 0.1 m/s zenith sigma (S001 eq 11, sim/observations.py)
    dop = _residual("doppler", obs, geo.slots, jnp.broadcast_to(jnp.asarray(STATION), (T, 3)),
                    jnp.zeros((T, 3)))
    assert np.nanstd(dop) < 0.05
    far = np.linalg.norm(np.asarray(geo.ant_pos_ecef) - STATION, axis=1).max()
    assert 300.0 < far < 1000.0  # the antenna really went round the circuit


@pytest.fixture(scope="module")
def station_kinematic_rms(factory):
    """Horizontal RMS over the second hour of the station's own kinematic float PPP (as
    ``jaxnav ppp --mode kinematic --freq dual`` runs it) against its ITRF coordinate."""
    from jaxnav.apps.ppp import run_ppp

    prep = factory._prepared(False)
    cfg = ppp.PppConfig(mode="float_ppp", n_slots=len(prep.sv), doppler=False).for_recorded_data()
    _, out = run_ppp(prep, cfg, ppp_only.GnssOnlySystem(model="random_walk"), 30.0)
    ref_llh = geodesy.ecef_to_llh(jnp.asarray(STATION))
    enu = np.asarray(jax.vmap(lambda llh: geodesy.enu_offset(geodesy.llh_to_ecef(llh), ref_llh))(
        out.llh))
    t = prep.time_gps_s - prep.time_gps_s[0]
    return float(np.sqrt(np.mean(np.sum(enu[t >= 3600.0, :2] ** 2, axis=1))))


@needs_data
@pytest.mark.slow
@pytest.mark.parametrize("system", ["ins15", "riss"])
def test_tight_ppp_on_replay_is_as_accurate_as_kinematic_ppp_on_the_station(
        factory, station_kinematic_rms, system):
    """TC float PPP with the full INS and with RISS16 (1-s covariance steps in the 30-s epochs;
    with one step per epoch RISS16 diverged, docs/validation.md): horizontal RMS over the second
    hour within 2x the station's own kinematic PPP."""
    prob = factory.build(None, "float_ppp", system, 0)
    run = single_run(prob, factory.ops_for("float_ppp", system), epoch_dt_s=30.0)
    late = run.time_s >= 3600.0
    tc_rms = np.sqrt(np.mean(np.sum(run.error_enu_m[late, :2] ** 2, axis=1)))
    assert station_kinematic_rms < 0.5  # the station's PPP converged (decimetres)
    assert tc_rms <= 2.0 * station_kinematic_rms, (tc_rms, station_kinematic_rms)
