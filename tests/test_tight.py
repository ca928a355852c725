"""Tightly coupled PPP/RISS in simulation: mode ordering, outages as masks, partial availability.

One 15-minute drive (60 s static start) is shared by every test; realisations differ by key.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jaxnav  # noqa: F401
from jaxnav.filter import systems, tight
from jaxnav.gnss import modes as ppp_modes
from jaxnav.gnss import ppp
from jaxnav.sim import scenario, sensors
from jaxnav.study import metrics, outages

DURATION_S = 900.0
CONVERGENCE_S = 300.0
N_KEYS = 4


@pytest.fixture(scope="module")
def drive():
    cfg = scenario.ScenarioConfig(duration_s=DURATION_S)
    geo = scenario.build_geometry(cfg)
    system = systems.RissSystem.for_sensors(
        sensors.imu_grade(cfg.imu_grade),
        sensors.odometer(cfg.odometer),
        cfg.lever_b_m,
        1.0 / cfg.riss_rate_hz,
    )
    return cfg, geo, system


def _filter(drive, mode):
    cfg, geo, system = drive
    pcfg = ppp.PppConfig(
        mode=mode,
        n_slots=int(geo.slots.system.shape[0]),
        estimate_zwd=ppp_modes.get(mode).uses_phase,
    )
    return tight.TightFilter(system, pcfg, geo.slots, 1.0 / cfg.riss_rate_hz, 1.0)


def _start(drive, tf, real):
    cfg, geo, system = drive
    nav0 = scenario.initial_riss_state(geo)
    static = jax.tree.map(lambda x: x[:30].reshape(-1, *x.shape[2:]), real.riss_inputs.samples)
    sens0 = system.calibrate_static(nav0, static, 1.0 / cfg.riss_rate_hz)
    return tight.initial_carry(tf, nav0, real.obs0, sensors0=sens0)


_REALIZE = {}  # one jitted simulator per frequency plan for the module's drive (not one per call)


def _realizations(drive, keys, single_frequency=False):
    cfg, geo, _ = drive
    if single_frequency not in _REALIZE:
        _REALIZE[single_frequency] = jax.jit(
            jax.vmap(lambda k: scenario.realize(k, geo, cfg, single_frequency))
        )
    return _REALIZE[single_frequency](keys)


def _horizontal_rms(geo, llh):
    r = metrics.run_rms(llh, geo.truth_ep.llh[1:], 1.0, exclude_s=CONVERGENCE_S)
    return float(r.rms_2d_m)


def test_converged_rms_orders_as_the_seeds_report(drive):
    """S000 Table 5.1: code-carrier < (smoothed) DF code < SF code; here float PPP < smoothed IF
    code < IF code < SF code, averaged over 4 realisations after a 5-minute convergence. And
    S002 ch. 4: adding the L1 phase to the SF code (sf_ppp, same model ionosphere) beats SF
    code alone (its Table 4.3: decimetres kinematic with L1 phase)."""
    _, geo, _ = drive
    keys = jax.random.split(jax.random.PRNGKey(7), N_KEYS)
    rms = {}
    for mode in ("sf_code", "df_code", "sdf_code", "float_ppp", "sf_ppp"):
        reals = _realizations(drive, keys, single_frequency=ppp_modes.get(mode).single_frequency)
        tf = _filter(drive, mode)

        def one(real, tf=tf):
            _, out = tight.run(tf, _start(drive, tf, real), real.riss_inputs)
            return out.llh

        llh = jax.jit(jax.vmap(one))(reals)
        rms[mode] = np.mean([_horizontal_rms(geo, llh[i]) for i in range(N_KEYS)])
    print("converged horizontal RMS [m]:", {k: round(v, 3) for k, v in rms.items()})
    assert rms["float_ppp"] < rms["sdf_code"] < rms["df_code"] < rms["sf_code"]
    assert rms["df_code"] < 3.0 and rms["float_ppp"] < 1.0
    assert rms["sf_ppp"] < rms["sf_code"]


def test_epoch_without_satellites_is_mechanization_plus_covariance_propagation(drive):
    _, geo, system = drive
    tf = _filter(drive, "float_ppp")
    # The first of the 4 realisations the mode-ordering test uses (one batch shape compiled).
    real = _realizations(drive, jax.random.split(jax.random.PRNGKey(7), N_KEYS))
    real = jax.tree.map(lambda x: x[0], real)
    carry = _start(drive, tf, real)
    # Run 200 epochs with everything, then one epoch with every slot withheld.
    head = jax.tree.map(lambda x: x[:200], real.riss_inputs)
    carry, _ = jax.jit(lambda c, i: tight.run(tf, c, i))(carry, head)
    inp = jax.tree.map(lambda x: x[200], real.riss_inputs)
    inp = inp._replace(keep=jnp.zeros_like(inp.keep))
    new, out = jax.jit(lambda c, i: tight.epoch_step(tf, c, i))(carry, inp)
    assert int(out.dof) == 0

    nav, mean = system.propagate(carry.nav, carry.sensors, inp.samples, tf.imu_dt_s)
    P = tight._propagate_covariance(tf, tf.layout, carry, nav, mean, inp.obs)
    # the same computation compiled in two contexts: equal to round-off (no update happened)
    np.testing.assert_allclose(np.asarray(new.P), np.asarray(P), rtol=0,
                               atol=1e-12 * float(np.abs(np.asarray(P)).max()))
    np.testing.assert_allclose(new.nav.llh, nav.llh, rtol=0, atol=1e-15)
    np.testing.assert_allclose(new.nav.vel_enu, nav.vel_enu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(new.nav.azimuth, nav.azimuth, rtol=0, atol=1e-15)
    # sensor estimates: only the Gauss-Markov prediction x_hat <- Phi x_hat over the epoch
    want = system.predict_sensors(carry.sensors, tf.epoch_dt_s)
    for a, b in zip(jax.tree.leaves(new.sensors), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-15, atol=0)
    # Clock: the nominal bias integrates the drift, nothing else moves.
    L = tf.layout
    drift = carry.gnss_est[L.i("clock_drift")]
    assert float(new.gnss_est[L.i("clock_bias")]) == pytest.approx(
        float(carry.gnss_est[L.i("clock_bias")] + drift), abs=1e-9
    )


def test_one_to_three_satellites_reduce_outage_error_growth(drive):
    """60-s outages keeping 0..3 satellites (highest elevation): tight coupling still updates
    with fewer than 4 satellites; 3 satellites reduce the error growth and 1-2 never make it
    worse. (Measured with the algebraic RISS velocity model: 0/1/2/3 kept = 5.7 / 5.7 / 2.3 /
    3.3 m, so 2 satellites already help here, unlike S000 Table 5.2's "at 0-2 satellites all
    variants are about equal"; with the seeds' integrated velocity error it was 6.3 / 6.4 /
    7.1 / 5.5 m.) Per scenario, 3 kept is worse than 0 kept in 3 of the 6 (by 0.8-4.9 m): the
    mean gain is not significant at this size; noted for the consistency work (issue 16)."""
    _, geo, _ = drive
    tf = _filter(drive, "df_code")
    n_keys, length = 2, 60
    keys = jax.random.split(jax.random.PRNGKey(11), n_keys)
    reals = _realizations(drive, keys)
    T = geo.truth_ep.time_s.shape[0] - 1
    starts = np.array([360, 540, 720])

    def scenario_error(real, start, k):
        inputs = real.riss_inputs
        outage = outages.Outage(start, jnp.asarray(length), k, jnp.asarray(0))
        keep = outages.keep_mask(geo_elev, inputs.obs.available, outage, policy="highest")
        _, out = tight.run(tf, _start(drive, tf, real), inputs._replace(keep=keep))
        err = metrics.enu_errors(out.llh, geo.truth_ep.llh[1:])
        e2d = jnp.hypot(err[:, 0], err[:, 1])
        window = (jnp.arange(T) >= start) & (jnp.arange(T) < start + length)
        return jnp.max(jnp.where(window, e2d, 0.0)), jnp.sum(jnp.where(window, out.dof, 0))

    geo_elev = _elevations(geo, T)
    fn = jax.jit(jax.vmap(jax.vmap(jax.vmap(scenario_error, (None, None, 0)), (None, 0, None)),
                          (0, None, None)))
    max_err, dof = fn(reals, jnp.asarray(starts), jnp.arange(4))
    mean_err = np.asarray(max_err).mean(axis=(0, 1))  # per satellites kept
    print("average maximum 2D error by satellites kept 0..3 [m]:", np.round(mean_err, 2))
    dof = np.asarray(dof)
    assert np.all(dof[..., 0] == 0)  # nothing used with 0 kept
    assert np.all(dof[..., 1:] > 0)  # 1..3 satellites still update the tight filter
    assert mean_err[3] < 0.97 * mean_err[0]
    # "1-2 satellites never make it worse": paired over the 6 (realisation, placement)
    # scenarios, the mean increase over 0 kept is not significant at the one-sided 95 % level
    # (Student t, 5 dof). Measured per-scenario differences: 1 kept -0.27..+0.21 m, 2 kept
    # -9.8..+2.7 m.
    per = np.asarray(max_err).reshape(-1, 4)
    t95 = stats.t.ppf(0.95, per.shape[0] - 1)
    for k in (1, 2):
        d = per[:, k] - per[:, 0]
        assert d.mean() <= t95 * d.std(ddof=1) / np.sqrt(d.size), (k, d)


def _elevations(geo, T):
    from jaxnav.sim import constellation

    el, _ = constellation.elevations(
        geo.orbits, geo.truth_ep.time_s[1:], geo.ant_pos_ecef[1:]
    )
    idx = geo.slot_table.sat_index
    return jnp.where(geo.slot_table.occupied[None, :], el[:, idx], -jnp.pi / 2)


def test_covariance_steps_make_a_long_epoch_the_same_as_short_ones(drive):
    """A 30-s epoch without satellites, mechanized and propagated in 30 covariance steps, is
    the same as thirty 1-s epochs without satellites: the same navigation state and P (the
    steps compose as the epochs do). One step per 30-s epoch linearises F once, at the end
    state, and gives another P: the case the steps exist for (recorded 30-s data)."""
    _, geo, system = drive
    tf = _filter(drive, "float_ppp")
    real = _realizations(drive, jax.random.split(jax.random.PRNGKey(7), N_KEYS))
    real = jax.tree.map(lambda x: x[0], real)
    carry = _start(drive, tf, real)
    head = jax.tree.map(lambda x: x[:200], real.riss_inputs)
    carry, _ = jax.jit(lambda c, i: tight.run(tf, c, i))(carry, head)
    # zero sensor estimates: a Gauss-Markov decay per 1-s epoch would otherwise change the
    # mechanization of the later seconds, while the long epoch decays once, after it
    carry = carry._replace(sensors=jax.tree.map(jnp.zeros_like, carry.sensors))
    short = jax.tree.map(lambda x: x[200:230], real.riss_inputs)
    short = short._replace(keep=jnp.zeros_like(short.keep))
    want, _ = jax.jit(lambda c, i: tight.run(tf, c, i))(carry, short)

    samples = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), short.samples)  # [30, ...]
    long_inp = jax.tree.map(lambda x: x[-1], short)._replace(samples=samples)
    results = {}
    for steps in (30, 1):
        tf_long = tight.TightFilter(system, tf.cfg, tf.slots, 1.0, 30.0, covariance_steps=steps)
        results[steps], _ = jax.jit(lambda c, i, t=tf_long: tight.epoch_step(t, c, i))(
            carry, long_inp)
    got = results[30]
    scale = float(np.abs(np.asarray(want.P)).max())
    np.testing.assert_allclose(np.asarray(got.P), np.asarray(want.P), rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(got.nav.llh, want.nav.llh, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got.nav.azimuth, want.nav.azimuth, rtol=0, atol=1e-12)
    pos = tf.layout.sl("pos")
    one = np.asarray(results[1].P)[pos, pos]
    assert np.abs(one - np.asarray(want.P)[pos, pos]).max() > 1e-3 * np.abs(one).max()
