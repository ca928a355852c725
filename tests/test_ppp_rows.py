"""Every PPP mode's analytic H equals autodiff of its predicted observables (RISS and INS).

With dx = x_hat - x and feedback(x_hat, dx) = x, a row's prediction at the corrected state is
h(x_hat) - H dx to first order, so d(dz)/d(dx) of the rows evaluated at feedback(x_hat, dx)
must be -H.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.core.states import INS15
from jaxnav.filter import systems, tight
from jaxnav.gnss import models, ppp, signals
from jaxnav.gnss import modes as ppp_modes
from jaxnav.ins import errors as ins_errors
from jaxnav.ins import riss, strapdown

S = 6
LLH0 = jnp.array([0.77, -1.33, 95.0])


def _sky():
    """Six satellites around a receiver near LLH0 and a plausible epoch of observations."""
    from jaxnav import geodesy

    rx = geodesy.llh_to_ecef(LLH0)
    az = jnp.linspace(0.3, 5.9, S)
    el = jnp.array([0.3, 0.6, 0.9, 1.2, 0.45, 0.75])
    los_enu = jnp.stack([jnp.cos(el) * jnp.sin(az), jnp.cos(el) * jnp.cos(az), jnp.sin(el)], 1)
    C = geodesy.C_l_e(LLH0[0], LLH0[1])
    sat_pos = rx + 2.2e7 * los_enu @ C.T
    sat_vel = jnp.cross(jnp.array([0.0, 0.0, 1.4e-4]), sat_pos) + 300.0
    sat = models.SatEpoch(sat_pos, sat_vel, jnp.linspace(-30.0, 40.0, S), jnp.full(S, 0.01))
    rng = np.random.default_rng(0)
    code = jnp.asarray(2.2e7 + rng.normal(size=(S, 2)) * 5.0)
    obs = ppp.GnssObs(
        code_m=code,
        phase_m=code + jnp.asarray(rng.normal(size=(S, 2)) * 3.0),
        range_rate_m_s=jnp.asarray(rng.normal(size=S) * 100.0),
        available=jnp.ones(S, bool),
        slip=jnp.zeros(S, bool),
        code_bias_m=jnp.zeros((S, 2)),
        iono_model_l1_m=jnp.linspace(1.0, 4.0, S),
        sat=sat,
        doppler_ok=jnp.ones(S, bool),
        iono_model_ok=jnp.ones(S, bool),
    )
    f = signals.carrier_frequency_hz(jnp.zeros(S, jnp.int32), 0), signals.carrier_frequency_hz(
        jnp.zeros(S, jnp.int32), 1
    )
    slots = ppp.SlotInfo(jnp.array([0, 0, 0, 0, 2, 2]), f[0], f[1])
    return obs, slots


def _systems():
    lever = jnp.array([0.3, 1.2, 1.6])
    rs = systems.RissSystem(lever_b=lever)
    nav_r = riss.riss_state_from(LLH0, 0.7, 14.0, 0.03, -0.02)
    model = ins_errors.ImuErrorModel(
        accel_vrw_m_s_sqrt_s=1e-3, gyro_arw_rad_sqrt_s=1e-4, accel_bias_tau_s=300.0,
        accel_bias_sigma_m_s2=1e-3, gyro_bias_tau_s=300.0, gyro_bias_sigma_rad_s=1e-5,
    )
    ins = systems.InsSystem(INS15, model, lever)
    nav_i = strapdown.InsNav(
        strapdown.nav_state(LLH0, jnp.array([9.0, -5.0, 0.3]), jnp.array([0.02, -0.03, 2.1])),
        strapdown.ImuIncrements(jnp.zeros(3), jnp.zeros(3)),
    )
    mean_i = ins.idle_inputs(nav_i)._replace(f_b=jnp.array([0.3, 0.5, 9.8]),
                                             w_ib_b=jnp.array([0.01, -0.02, 0.15]))
    return [("riss", rs, nav_r, rs.idle_inputs(nav_r)), ("ins", ins, nav_i, mean_i)]


@pytest.mark.parametrize("mode", ppp_modes.MODES)
@pytest.mark.parametrize("bssd", [False, True])
def test_rows_match_autodiff(mode, bssd):
    if bssd and not ppp_modes.REGISTRY[mode].supports_bssd:
        pytest.skip(f"{mode} has no BSSD form")
    obs, slots = _sky()
    for name, system, nav, mean in _systems():
        cfg = ppp.PppConfig(
            mode=mode, n_slots=S, systems=(signals.SYS_GPS, signals.SYS_GAL), bssd=bssd,
            elevation_mask_rad=0.0, iono_constraint="epoch",  # epoch: check the GIM rows too
        )
        tf = tight.TightFilter(system, cfg, slots, 0.01, 1.0)
        layout = tf.layout
        sens = system.zero_sensors()
        rng = np.random.default_rng(1)
        gnss_est = jnp.asarray(rng.normal(size=layout.size))
        hatch = ppp.HatchState(obs.code_m[:, 0] * 0 + 2.2e7, obs.phase_m[:, 0], jnp.full(S, 5.0))
        n_sys = system.layout.size
        keep = jnp.ones(S, bool)

        def rows_at(dx, system=system, nav=nav, mean=mean, layout=layout, cfg=cfg, sens=sens,
                    gnss_est=gnss_est, hatch=hatch, n_sys=n_sys, keep=keep, name=name):
            nav_c, _ = system.feedback(nav, sens, dx, layout)
            if name == "ins":  # the true rates are the compensated ones minus their errors
                mean = mean._replace(f_b=mean.f_b - dx[layout.sl("accel_bias")],
                                     w_ib_b=mean.w_ib_b - dx[layout.sl("gyro_bias")])
            est = gnss_est - jnp.where(jnp.arange(layout.size) >= n_sys, dx, 0.0)
            if system.layout.has("clock_bias"):
                est = est - jnp.where(
                    jnp.isin(jnp.arange(layout.size),
                             jnp.array([layout.i("clock_bias"), layout.i("clock_drift")])),
                    dx, 0.0,
                )
            rx = system.antenna(nav_c, mean, sens, layout)
            rows, _ = ppp.measurement_rows(cfg, layout, slots, obs, rx, est, keep, hatch, 180.0,
                                           1.0)
            return rows.dz

        dx0 = jnp.zeros(layout.size)
        rows, _ = ppp.measurement_rows(
            cfg, layout, slots, obs, system.antenna(nav, mean, sens, layout), gnss_est, keep,
            hatch, 180.0, 1.0,
        )
        J = -jax.jit(jax.jacfwd(rows_at))(dx0)
        H = rows.H
        used = np.asarray(rows.mask)
        # Scale per column: position columns are in radians (1 rad ~ 6.4e6 m).
        col_scale = np.maximum(np.abs(np.asarray(J))[used].max(axis=0), 1e-9)
        err = np.abs(np.asarray(H - J))[used] / col_scale
        # Terms the analytic rows neglect: the range-rate's dependence on position through the
        # line of sight (|v_rel| / rho ~ 1e-4 of the velocity column) and the mapping functions'
        # dependence on position (~1e-6). Everything else is exact.
        worst = zip(layout.labels(), err.max(axis=0), strict=True)
        bad = {label: float(e) for label, e in worst if e > 2e-3}
        assert not bad, (name, mode, bssd, bad)


def test_ic_ppp_gim_is_a_reset_prior_by_default_and_a_row_per_epoch_on_request():
    """iono_constraint="prior": no ionosphere pseudo-observation rows; a restarted slot's slant
    ionosphere starts at the model value with the model's variance. "epoch" (S001 eq 6 as
    printed): one GIM row per usable slot."""
    obs, slots = _sky()
    _, system, nav, mean = _systems()[1]
    keep = jnp.ones(S, bool)
    hatch = ppp.HatchState.empty(S)
    kinds = {}
    for cons in ("prior", "epoch"):
        cfg = ppp.PppConfig(mode="ic_ppp", n_slots=S, systems=(signals.SYS_GPS, signals.SYS_GAL),
                            elevation_mask_rad=0.0, iono_constraint=cons)
        tf = tight.TightFilter(system, cfg, slots, 0.01, 1.0)
        rx = system.antenna(nav, mean, system.zero_sensors(), tf.layout)
        rows, el = ppp.measurement_rows(cfg, tf.layout, slots, obs, rx, jnp.zeros(tf.layout.size),
                                        keep, hatch, 180.0, 1.0)
        kinds[cons] = int(np.sum(np.asarray(rows.kind == ppp.KIND_IONO) & np.asarray(rows.mask)))
        restart = jnp.asarray(np.arange(S) % 2 == 0)
        P0 = jnp.eye(tf.layout.size) * 1e4
        est, P = tight._reset_slots(tf, tf.layout, jnp.zeros(tf.layout.size), P0, obs, restart,
                                    el)
        sl = tf.layout.sl("iono")
        var = np.diag(np.asarray(P))[sl]
        np.testing.assert_allclose(np.asarray(est[sl])[::2], np.asarray(obs.iono_model_l1_m)[::2])
        np.testing.assert_allclose(var[1::2], 1e4)  # not restarted: untouched
        if cons == "prior":
            expect = np.asarray(ppp.iono_model_var(cfg, obs.iono_model_l1_m, el))
            np.testing.assert_allclose(var[::2], expect[::2])
            assert np.all(var[::2] < cfg.iono_init_sigma_m**2)
        else:
            np.testing.assert_allclose(var[::2], cfg.iono_init_sigma_m**2)
    assert kinds["prior"] == 0 and kinds["epoch"] == int(np.sum(np.asarray(obs.available)))
    with pytest.raises(ValueError, match="iono_constraint"):
        ppp.PppConfig(mode="ic_ppp", iono_constraint="sometimes")


def test_ic_ppp_ambiguity_reset_includes_the_receiver_dcb():
    """Issue 16, defect 7. With the codes modelled as P_b = rho + g_b I + c_b DCB (c = beta,
    -alpha) and the phases as L_b = rho - g_b I + N_b, the reset N_b = L_b - P_b + 2 g_b I +
    c_b DCB makes a restarted slot's phase residual equal its code residual on each band, for
    any geometry and any current DCB estimate (without the DCB term they differ by c_b DCB)."""
    obs, slots = _sky()
    _, system, nav, mean = _systems()[1]
    cfg = ppp.PppConfig(mode="ic_ppp", n_slots=S, systems=(signals.SYS_GPS, signals.SYS_GAL),
                        elevation_mask_rad=0.0)
    tf = tight.TightFilter(system, cfg, slots, 0.01, 1.0)
    layout = tf.layout
    rx = system.antenna(nav, mean, system.zero_sensors(), layout)
    est0 = jnp.zeros(layout.size).at[layout.i("dcb")].set(1.7)
    keep, hatch = jnp.ones(S, bool), ppp.HatchState.empty(S)
    _, el = ppp.measurement_rows(cfg, layout, slots, obs, rx, est0, keep, hatch, 180.0, 1.0)
    est, _ = tight._reset_slots(tf, layout, est0, jnp.eye(layout.size), obs, jnp.ones(S, bool),
                                el)
    rows, _ = ppp.measurement_rows(cfg, layout, slots, obs, rx, est, keep, hatch, 180.0, 1.0)
    dz = np.asarray(rows.dz).reshape(-1, S)  # code 1, code 2, phase 1, phase 2 blocks
    kind = np.asarray(rows.kind).reshape(-1, S)[:, 0]
    assert list(kind[:4]) == [ppp.KIND_CODE, ppp.KIND_CODE, ppp.KIND_PHASE, ppp.KIND_PHASE]
    np.testing.assert_allclose(dz[2], dz[0], atol=1e-6)
    np.testing.assert_allclose(dz[3], dz[1], atol=1e-6)


@pytest.mark.parametrize("mode", ["sf_code", "sf_ppp", "ic_ppp", "float_ppp", "df_code"])
def test_missing_doppler_or_model_ionosphere_gives_no_row_never_a_zero(mode):
    """Issue 16, defect 2. A slot whose Doppler was not measured has no Doppler row (not a
    0 m/s one); a slot without a model ionosphere is not used by a mode that needs the model
    (its rows would take a zero delay: metres of error) and is used as before by one that
    does not."""
    obs, slots = _sky()
    _, system, nav, mean = _systems()[1]
    cfg = ppp.PppConfig(mode=mode, n_slots=S, systems=(signals.SYS_GPS, signals.SYS_GAL),
                        elevation_mask_rad=0.0, doppler=True)
    tf = tight.TightFilter(system, cfg, slots, 0.01, 1.0)
    rx = system.antenna(nav, mean, system.zero_sensors(), tf.layout)
    keep, hatch = jnp.ones(S, bool), ppp.HatchState.empty(S)
    lacking = jnp.asarray(np.arange(S) == 2)
    holes = obs._replace(doppler_ok=~lacking, iono_model_ok=~jnp.roll(lacking, 1))
    est = jnp.zeros(tf.layout.size)
    full, _ = ppp.measurement_rows(cfg, tf.layout, slots, obs, rx, est, keep, hatch, 180.0, 1.0)
    got, _ = ppp.measurement_rows(cfg, tf.layout, slots, holes, rx, est, keep, hatch, 180.0, 1.0)
    kind = np.asarray(got.kind).reshape(-1, S)[:, 0]
    m_full = np.asarray(full.mask).reshape(-1, S)
    m_got = np.asarray(got.mask).reshape(-1, S)
    assert np.all(m_full)  # every row of the complete sky is used
    dop = kind == ppp.KIND_DOPPLER
    assert dop.sum() == 1
    model_needed = ppp_modes.REGISTRY[mode].uses_iono_model
    want = np.ones_like(m_got)
    if model_needed:
        want[:, 3] = False  # the slot without a model ionosphere: none of its rows
    want[dop, 2] = False  # the slot without Doppler: no Doppler row, its other rows kept
    np.testing.assert_array_equal(m_got, want)


def test_bssd_doppler_rows_survive_a_reference_without_doppler():
    """BSSD: where the code / phase reference (highest GPS satellite) has no Doppler, the
    Doppler rows are differenced against the highest GPS satellite that has one, so every
    other satellite with a Doppler keeps its row (S - 2 here)."""
    obs, slots = _sky()
    _, system, nav, mean = _systems()[1]
    cfg = ppp.PppConfig(mode="df_code", n_slots=S, systems=(signals.SYS_GPS, signals.SYS_GAL),
                        elevation_mask_rad=0.0, bssd=True)
    tf = tight.TightFilter(system, cfg, slots, 0.01, 1.0)
    rx = system.antenna(nav, mean, system.zero_sensors(), tf.layout)
    keep, hatch = jnp.ones(S, bool), ppp.HatchState.empty(S)
    args = (tf.layout, slots)
    rows, el = ppp.measurement_rows(cfg, *args, obs, rx, jnp.zeros(tf.layout.size), keep, hatch,
                                    180.0, 1.0)
    ref = int(ppp.reference_slot(slots, el, keep))
    no_ref_doppler = obs._replace(doppler_ok=obs.doppler_ok.at[ref].set(False))
    rows, _ = ppp.measurement_rows(cfg, *args, no_ref_doppler, rx, jnp.zeros(tf.layout.size),
                                   keep, hatch, 180.0, 1.0)
    dop = np.asarray(rows.kind == ppp.KIND_DOPPLER) & np.asarray(rows.mask)
    assert dop.sum() == S - 2
    ref_dop = int(ppp.reference_slot(slots, el, no_ref_doppler.doppler_ok))
    assert ref_dop != ref
    assert not dop[np.isin(np.asarray(rows.slot), [ref, ref_dop])].any()
