"""The simulated scenario factory: validation, grades per system, constellations, flights."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.core.states import INS15
from jaxnav.gnss import signals
from jaxnav.sim import scenario, sensors
from jaxnav.study import factory as fac
from jaxnav.study.factory import SimFactory


@pytest.mark.parametrize(
    "table, words",
    [
        ({"colour": "red"}, ["unknown key scenario.colour", "allowed keys"]),
        ({"constellations": ["beidou"]}, ["constellations", "beidou"]),
        ({"constellations": ["galileo"]}, ["constellations", "gps"]),
        ({"constellations": ["gps", "gps"]}, ["scenario.constellations[1]", "distinct"]),
        ({"slots": [12, 14]}, ["scenario.slots = [12, 14]", "a list of 3"]),
        ({"drive_style": "rally"}, ["drive_style", "rally", "airborne"]),
        ({"duration_s": "long"}, ["scenario.duration_s = 'long'", "a number of seconds > 0"]),
        ({"bssd": "yes"}, ["scenario.bssd = 'yes'", "true or false"]),
        ({"ins_grade": "nope"}, ["ins_grade", "nope", "span_cpt"]),
        # a module attribute is not a preset (it used to pass a hasattr check on sim.sensors)
        ({"imu_grade": "__name__"}, ["imu_grade", "__name__", "crossbow_imu300cc"]),
        ({"odometer": "math"}, ["odometer", "math", "obd2_odometer"]),
        ({"iono_model": "nequick"}, ["iono_model", "nequick", "gim"]),
    ],
)
def test_invalid_scenario_tables_are_rejected_with_the_key(table, words):
    with pytest.raises(ValueError) as err:
        SimFactory(table)
    for w in words:
        assert w in str(err.value)


def test_ins_systems_are_simulated_with_the_ins_grade():
    """The standstill gyro bias seen by an INS system is the INS grade's (SPAN-CPT: 20 deg/h
    turn-on), not the RISS MEMS's (IMU300CC: ~2 deg/s) — the bug that made ins15 diverge."""
    f = SimFactory({"duration_s": 240.0})
    real = fac._realize(f, 0, False, f.ins_grade)
    head = jax.tree.map(lambda x: np.asarray(x[:30]).reshape(-1, 3), real.ins_inputs.samples)
    nav0 = scenario.initial_ins_state(f.geo)
    tf = f.filter("df_code", "ins15")
    bias = np.asarray(tf.system.calibrate_static(nav0, head, tf.imu_dt_s).gyro_bias_rad_s)
    ton = sensors.span_cpt().gyro_bias_turn_on_rad_s
    mems = sensors.crossbow_imu300cc().gyro_bias_turn_on_rad_s
    print(f"\nstandstill gyro bias {np.degrees(bias) * 3600} deg/h; SPAN-CPT turn-on sigma "
          f"{np.degrees(ton) * 3600:.0f} deg/h, IMU300CC {np.degrees(mems) * 3600:.0f} deg/h")
    assert np.all(np.abs(bias) < 5.0 * ton)
    assert np.all(np.abs(bias) < 0.05 * mems)
    # and the RISS keeps its MEMS
    riss = fac._realize(f, 0, False, f.cfg.imu_grade).riss_inputs.samples
    assert not np.allclose(np.asarray(riss.w_z[:30]), 0.0)


def test_multi_gnss_slots_isb_states_and_bssd_reach_the_filter():
    f = SimFactory(
        {"duration_s": 240.0, "constellations": ["gps", "glonass", "galileo"],
         "slots": [12, 14, 13], "bssd": True}
    )
    system = np.asarray(f.geo.slots.system)
    assert [int(np.sum(system == s)) for s in range(3)] == [12, 14, 13]
    tf = f.filter("float_ppp", "ins15")
    assert tf.cfg.bssd and tf.cfg.systems == (signals.SYS_GPS, signals.SYS_GLO, signals.SYS_GAL)
    assert tf.layout.has("isb_glo") and tf.layout.has("isb_gal")
    # BSSD differences the receiver clock out: no clock states; ISBs, ZWD, ambiguities stay
    assert not tf.layout.has("clock_bias")
    assert tf.layout.size == INS15.size + 2 + 1 + 39
    occupied = np.asarray(f.geo.slot_table.occupied)
    assert occupied[system == signals.SYS_GLO].any() and occupied[system == signals.SYS_GAL].any()


def test_airborne_flight_starts_moving_without_a_static_calibration():
    f = SimFactory({"duration_s": 240.0, "drive_style": "airborne", "ins_grade": "hg1700"})
    speed = np.hypot(*np.asarray(f.geo.truth_ep.vel_enu[0, :2]))
    assert 40.0 < speed < 55.0  # S001 flight at 45-50 m/s from the first epoch
    tf = f.filter("float_ppp", "ins15")
    real = fac._realize(f, 0, False, f.ins_grade)
    carry, _ = f.start(tf, "ins15", real)
    assert np.all(np.asarray(carry.sensors.gyro_bias_rad_s) == 0.0)


def test_standstill_calibration_sets_the_gyro_bias_prior_it_earns():
    """After the 30-s standstill calibration the gyro-bias sigma is in-run (+) ARW/sqrt(30 s),
    not the turn-on sigma: with the uncalibrated prior a Crista filter learned a wrong bias at
    rest (-4.3 vs -1.9 deg/s) and its azimuth drifted to -150 deg within a minute (seed 003)."""
    f = SimFactory({"duration_s": 240.0, "ins_grade": "crista"})
    tf = f.filter("df_code", "ins15")
    carry, _ = f.start(tf, "ins15", fac._realize(f, 0, False, f.ins_grade))
    sd = np.sqrt(np.diag(np.asarray(carry.P))[INS15.sl("gyro_bias")])
    model = tf.system.model
    expect = np.hypot(model.gyro_bias_sigma_rad_s, model.gyro_arw_rad_sqrt_s / np.sqrt(30.0))
    np.testing.assert_allclose(sd, expect, rtol=1e-12)
    assert np.all(sd < 0.2 * float(model.gyro_bias_ton_sigma_rad_s))
    # the LC cascade's INS starts the same way
    lc = f.filter("df_code", "lc_ins15")
    carry_lc, _ = f.start(lc, "lc_ins15", fac._realize(f, 0, False, f.ins_grade))
    sd_lc = np.sqrt(np.diag(np.asarray(carry_lc.lc.P))[INS15.sl("gyro_bias")])
    np.testing.assert_allclose(sd_lc, expect, rtol=1e-12)


def test_ppp_alone_is_a_gnss_only_receiver_scored_at_the_antenna():
    """``ppp_alone`` (S002 ch. 5's "DF-PPP alone"): the tight filter's PPP rows on a GNSS-only
    constant-velocity receiver that starts at, and is scored against, the true antenna (the
    other systems are scored at the IMU, 1-2 m away by the lever arm)."""
    from jaxnav import geodesy
    from jaxnav.filter import ppp_only
    from jaxnav.study import config

    f = SimFactory({"duration_s": 240.0})
    assert fac.PPP_ALONE in f.systems
    cfg = config.from_dict(
        {"study": {"name": "x", "modes": ["df_code"], "systems": [fac.PPP_ALONE],
                   "durations_s": [10], "satellites_kept": [0]},
         "placement": {"kind": "grid", "convergence_s": 60, "spacing_s": 60}},
        modes=f.modes, systems=f.systems,
    )
    prob = f.build(cfg, "df_code", fac.PPP_ALONE, 0)
    assert isinstance(prob.tf.system, ppp_only.GnssOnlySystem)
    assert prob.tf.system.model == fac.PPP_ALONE_MODEL
    llh_ant = np.asarray(jax.vmap(geodesy.ecef_to_llh)(f.geo.ant_pos_ecef))
    np.testing.assert_allclose(np.asarray(prob.truth.llh), llh_ant[1:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(prob.carry0.nav.llh), llh_ant[0], rtol=0, atol=1e-12)
    imu_h = np.asarray(f.geo.truth_ep.llh[1:, 2])
    assert np.abs(llh_ant[1:, 2] - imu_h).max() > 0.5  # the antenna really is elsewhere


def test_a_pickled_factory_carries_its_drive():
    """Dask workers receive the factory pickled: the simulated drive travels with it, bit for
    bit (not re-simulated there; problems are built from it and the seed)."""
    import pickle

    f = SimFactory({"duration_s": 60.0})
    fresh = pickle.loads(pickle.dumps(f))
    assert "geo" not in fresh.__dict__  # nothing simulated yet, nothing sent
    jax.block_until_ready(f.geo)
    g = pickle.loads(pickle.dumps(f))
    assert "geo" in g.__dict__ and g.fingerprint() == f.fingerprint()
    for a, b in zip(jax.tree.leaves(f.geo), jax.tree.leaves(g.geo), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
