"""Loosely coupled PPP/INS cascade (jaxnav.filter.cascade) on a simulated drive.

Scenario: the factory's 5-min mixed drive (60 s standstill, then driving), GPS, DF code PPP
(the cheapest mode to compile; the cascade's logic does not depend on the mode), SPAN-CPT-class
IMU, LC 15-state INS. One jitted ``run`` evaluates full availability and a 30-s outage keeping
0, 1, 2 or 3 satellites (a vmap over keep masks).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.filter import cascade, loose, tight
from jaxnav.study import config as sc
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study import sweep as sw
from jaxnav.study.factory import SimFactory

MODE, SYSTEM = "df_code", "lc_ins15"
SCENARIO = {"duration_s": 300, "ins_grade": "span_cpt"}
OUT_START, OUT_LEN = 170, 30  # epochs (1 s); after the 60 s standstill, in motion
CONVERGED = 90  # epochs excluded from the RMS (start-up)
N_KEEP = (-1, 0, 1, 2, 3)  # -1: no outage


def _h_err(llh, truth_llh):
    e = np.asarray(mt.enu_errors(llh, truth_llh))
    return np.hypot(e[..., 0], e[..., 1])


@pytest.fixture(scope="module")
def factory():
    return SimFactory(SCENARIO)


@pytest.fixture(scope="module")
def runs(factory):
    prob = factory.build(None, MODE, SYSTEM, 3)
    masks = jnp.stack([
        ot.keep_mask(prob.elevation, prob.available, ot.Outage(OUT_START, OUT_LEN, k))
        for k in N_KEEP
    ])

    @jax.jit
    def many(cf, carry0, inputs, masks):
        def one(mask):
            inp = inputs._replace(gnss=inputs.gnss._replace(keep=inputs.gnss.keep & mask))
            return cascade.run(cf, carry0, inp)[1]

        return jax.vmap(one)(masks)

    out = many(prob.tf, prob.carry0, prob.inputs, masks)
    ant_llh = jax.vmap(geodesy.ecef_to_llh)(factory.geo.ant_pos_ecef[1:])
    return factory, prob, out, ant_llh


def test_full_availability_lc_close_to_ppp_only(runs):
    """With every satellite the LC INS solution is as good as the PPP fixes it is built from
    (S003 Tables 1 and 3: LC 0.10/0.30 m vs PPP 0.10/0.32 m): horizontal RMS <= 1.5 x PPP's."""
    _, prob, out, ant_llh = runs
    sl = slice(CONVERGED, None)
    h_lc = _h_err(out.lc.llh[0], prob.truth.llh)[sl]
    h_ppp = _h_err(out.ppp.llh[0], ant_llh)[sl]  # the PPP filter estimates the antenna
    rms_lc, rms_ppp = np.sqrt(np.mean(h_lc**2)), np.sqrt(np.mean(h_ppp**2))
    print(f"horizontal RMS: LC {rms_lc:.3f} m, PPP-only {rms_ppp:.3f} m")
    assert rms_lc <= 1.5 * rms_ppp
    assert rms_lc < 2.0  # DF code PPP: metre level
    assert bool(np.all(np.asarray(out.fix.pos_valid[0]))) and bool(
        np.all(np.asarray(out.lc.applied.pos[0]))
    )


@pytest.mark.parametrize("i", [1, 2, 3, 4])
def test_partial_outage_gives_the_lc_filter_no_fix(runs, i):
    """0-3 satellites kept for 30 s: the PPP update uses <= k satellites, so no fix is valid and
    the LC filter makes no GNSS position or velocity update; fixes resume after the outage."""
    _, prob, out, _ = runs
    k = N_KEEP[i]
    win = slice(OUT_START, OUT_START + OUT_LEN)
    n_sat = np.asarray(out.ppp.n_sat[i, win])
    assert n_sat.max() <= k
    assert not np.any(np.asarray(out.fix.pos_valid[i, win]))
    assert not np.any(np.asarray(out.lc.applied.pos[i, win]))
    assert not np.any(np.asarray(out.lc.applied.vel[i, win]))
    # Back with every satellite, the PPP filter's coarse pre-fit test (20 m, S002) rejects part
    # of them while its own constant-velocity prediction is still tens of metres off after a
    # 0-satellite outage in a turn: fixes resume within 2 epochs, with every epoch from +5 on.
    end_out = OUT_START + OUT_LEN
    assert np.any(np.asarray(out.lc.applied.pos[i, end_out : end_out + 2]))
    assert np.all(np.asarray(out.lc.applied.pos[i, end_out + 5 : end_out + 30]))
    # the outage does show up as INS drift: the error at the outage end exceeds the full run's
    end = OUT_START + OUT_LEN - 1
    h_out = _h_err(out.lc.llh[i, end], prob.truth.llh[end])
    h_full = _h_err(out.lc.llh[0, end], prob.truth.llh[end])
    print(f"k={k}: end-of-outage error {h_out:.2f} m vs {h_full:.2f} m without outage")
    assert h_out > h_full


def test_all_true_keep_equals_the_standalone_composition(runs):
    """PPP-only ``tight.run``, then ``loose.run`` with its fixes = the cascade's LC part."""
    _, prob, out, _ = runs
    cf, c0, inp = prob.tf, prob.carry0, prob.inputs
    _, ppp_out = jax.jit(tight.run)(cf.ppp, c0.ppp, inp.gnss)
    fixes = cascade.fix_from_ppp(cf.ppp, ppp_out)
    lc_in = loose.epoch_inputs(inp.imu, fixes)
    _, lc_out = jax.jit(loose.run)(cf.lc, c0.lc, lc_in)
    # keep all-true: the N_KEEP = -1 run had the full mask. Equal to rounding (the vmapped run
    # fuses differently): micrometres over 5 minutes.
    d = np.abs(np.asarray(mt.enu_errors(lc_out.llh, out.lc.llh[0])))
    print(f"max |LC composition - cascade|: {d.max():.2e} m")
    assert d.max() < 1e-6
    np.testing.assert_allclose(np.asarray(lc_out.vel_enu), np.asarray(out.lc.vel_enu[0]),
                               rtol=0, atol=1e-8)
    np.testing.assert_allclose(np.asarray(lc_out.euler), np.asarray(out.lc.euler[0]), rtol=0,
                               atol=1e-9)


def test_fix_covariance_is_the_ppp_covariance_in_metres(runs):
    """cov_pos_enu = T P_pos T^T: the east / north variances are the lon / lat variances times
    the squared metres per radian (closed form of geodesy's radii)."""
    _, _, out, _ = runs
    t = 200
    P = np.asarray(out.ppp.P_nav[0, t])
    llh = np.asarray(out.ppp.llh[0, t])
    a, e2 = 6378137.0, 6.69437999014e-3
    s2 = np.sin(llh[0]) ** 2
    r_n = a / np.sqrt(1 - e2 * s2)
    r_m = a * (1 - e2) / (1 - e2 * s2) ** 1.5
    m_e, m_n = (r_n + llh[2]) * np.cos(llh[0]), r_m + llh[2]
    cov = np.asarray(out.fix.cov_pos_enu[0, t])
    np.testing.assert_allclose(cov[0, 0], P[1, 1] * m_e**2, rtol=1e-9)
    np.testing.assert_allclose(cov[1, 1], P[0, 0] * m_n**2, rtol=1e-9)
    np.testing.assert_allclose(cov[2, 2], P[2, 2], rtol=1e-12)
    np.testing.assert_allclose(cov[0, 1], P[1, 0] * m_e * m_n, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(out.fix.cov_vel_enu[0, t]), P[3:6, 3:6], rtol=1e-12)


def test_run_sweep_with_the_lc_system(tmp_path, runs):
    """The sweep engine drives the cascade through ``factory.ops_for``: a tiny study gives a
    Dataset with the LC system, equal to the brute-force whole-drive run of one outage."""
    factory = runs[0]
    cfg = sc.from_dict(
        {"study": {"name": "lc", "modes": [MODE], "systems": [SYSTEM], "durations_s": [30],
                   "satellites_kept": [0, "all"], "realizations": 1, "seed": 3,
                   "recovery_s": 20, "chunk_size": 4, "max_traces": 2},
         "placement": {"kind": "grid", "convergence_s": 150, "spacing_s": 60},
         "scenario": SCENARIO},
        modes=SimFactory.modes, systems=SimFactory.systems,
    )
    res = sw.run_sweep(cfg, factory, tmp_path / "out", progress=False)
    ds = res.dataset
    assert list(ds.system.values) == [SYSTEM]
    m0 = ds.max_2d_m.sel(mode=MODE, system=SYSTEM, satellites_kept=0).values.ravel()
    m_all = ds.max_2d_m.sel(mode=MODE, system=SYSTEM, satellites_kept=-1).values.ravel()
    print("sweep max 2D error: 0 sats", m0, "all", m_all)
    # (With this tactical-grade IMU a 30-s coast can beat metre-level DF-code fixes, so the two
    # levels are only required to differ.)
    assert np.all(np.isfinite(m0)) and np.all(np.isfinite(m_all)) and np.all(m0 != m_all)
    plan = sw.make_plan(cfg, factory.timeline(cfg))
    prob = factory.build(cfg, MODE, SYSTEM, int(plan.seeds[0]))
    outage = ot.Outage(int(plan.starts[0, 0]), int(plan.lengths[0, 0]), 0)
    ref, _ = sw.brute_force(prob, factory.ops_for(MODE, SYSTEM), outage, epoch_dt_s=1.0,
                            recovery_epochs=plan.recovery, mcfg=plan.mcfg)
    got = float(ds.max_2d_m.sel(mode=MODE, system=SYSTEM, satellites_kept=0).values.ravel()[0])
    np.testing.assert_allclose(got, float(ref.max_2d_m), rtol=1e-7)


def test_smoothed_cascade_bridges_the_outage_and_is_the_loose_smoother_of_its_fixes(runs):
    """``cascade.run_smoother``: its LC part is ``loose.run_smoother`` over the forward PPP fixes
    (to rounding), its covariance never exceeds the forward one, and a 0-satellite 30-s outage
    in motion is bridged better than by the forward filter (the smoother sees both ends)."""
    _, prob, _, _ = runs
    cf, c0, inp = prob.tf, prob.carry0, prob.inputs
    mask = ot.keep_mask(prob.elevation, prob.available, ot.Outage(OUT_START, OUT_LEN, 0))
    inp = inp._replace(gnss=inp.gnss._replace(keep=inp.gnss.keep & mask))
    fwd, smo = jax.jit(cascade.run_smoother)(cf, c0, inp)
    _, lc_smo = jax.jit(loose.run_smoother)(cf.lc, c0.lc, loose.epoch_inputs(inp.imu, fwd.fix))
    d = np.abs(np.asarray(mt.enu_errors(lc_smo.llh, smo.lc.llh)))
    assert d.max() < 1e-6
    # the PPP part and the fixes are the forward pass's
    np.testing.assert_array_equal(np.asarray(smo.ppp.llh), np.asarray(fwd.ppp.llh))
    P_f, P_s = np.asarray(fwd.lc.P_nav), np.asarray(smo.lc.P_nav)
    eig_gap = np.linalg.eigvalsh(P_f - P_s)  # P+ - P^s positive semi-definite
    assert eig_gap.min() >= -1e-9 * np.abs(P_f).max()
    win = slice(OUT_START, OUT_START + OUT_LEN)
    h_f = _h_err(fwd.lc.llh[win], prob.truth.llh[win]).max()
    h_s = _h_err(smo.lc.llh[win], prob.truth.llh[win]).max()
    print(f"30-s outage, max 2D: forward {h_f:.2f} m, smoothed {h_s:.2f} m")
    assert h_s < h_f


# ---- the tight filter's optional NHC update (used by seed 003's TC+NHC) -----------------------
def test_tight_nhc_update_off_by_default_and_reduces_lateral_velocity(factory):
    """``TightFilter.nhc_sigma_m_s`` defaults to None (the step is the unchanged one: the same
    outputs bit for bit as an explicit None); with 1 m/s the NHC rows pull the body lateral and
    vertical velocity towards 0 (the simulated car has no side slip), so the RMS of the
    estimated body-frame lateral + vertical velocity while driving drops, and the azimuth error
    does not grow."""
    p_off = factory.build(None, MODE, "ins15", 3)
    p_on = factory.build(None, MODE, "ins15_nhc", 3)
    assert p_off.tf.nhc_sigma_m_s is None and p_on.tf.nhc_sigma_m_s == 1.0
    explicit = tight.TightFilter(p_off.tf.system, p_off.tf.cfg, p_off.tf.slots,
                                 p_off.tf.imu_dt_s, p_off.tf.epoch_dt_s, nhc_sigma_m_s=None)
    run = jax.jit(tight.run)
    _, o_off = run(p_off.tf, p_off.carry0, p_off.inputs)
    _, o_exp = run(explicit, p_off.carry0, p_off.inputs)
    for a, b in zip(jax.tree.leaves(o_off), jax.tree.leaves(o_exp), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    _, o_on = run(p_on.tf, p_on.carry0, p_on.inputs)

    def body_side_rms(o):
        C = jax.vmap(lambda e: attitude.dcm_from_euler(e))(o.euler)
        v_b = np.asarray(jnp.einsum("tji,tj->ti", C, o.vel_enu))
        moving = np.asarray(jnp.linalg.norm(p_off.truth.vel_enu, axis=1)) > 3.0
        return np.sqrt(np.mean(v_b[moving][:, [0, 2]] ** 2))

    def az_rms(o):
        d = np.asarray(attitude.wrap_angle(o.euler[:, 2] - p_off.truth.azimuth))
        return np.degrees(np.sqrt(np.mean(d[CONVERGED:] ** 2)))

    # one joint update (core.rows): the two NHC rows are counted in every epoch's dof, never in
    # the satellites or the per-kind GNSS counts (a slot-less row once marked the last slot)
    moving = np.asarray(jnp.linalg.norm(p_off.truth.vel_enu, axis=1)) > 3.0
    same_gnss = np.all(np.asarray(o_on.used_by_kind) == np.asarray(o_off.used_by_kind), axis=1)
    assert same_gnss[moving].mean() > 0.9
    np.testing.assert_array_equal(np.asarray(o_on.dof)[same_gnss],
                                  np.asarray(o_off.dof)[same_gnss] + 2)
    np.testing.assert_array_equal(np.asarray(o_on.n_sat)[same_gnss],
                                  np.asarray(o_off.n_sat)[same_gnss])
    s_off, s_on = body_side_rms(o_off), body_side_rms(o_on)
    print(f"body lateral/vertical velocity RMS: {s_off:.4f} -> {s_on:.4f} m/s; azimuth RMS "
          f"{az_rms(o_off):.3f} -> {az_rms(o_on):.3f} deg")
    assert s_on < s_off
    assert az_rms(o_on) <= 1.1 * az_rms(o_off)


def test_lc_zupt_system_detects_standstills_and_holds_the_velocity_in_an_outage(factory):
    """``lc_ins15_nhc_zupt``: the IMU variance detector fires during the 60-s standstill and not
    while driving; ZARU is applied there; ZUPT replaces the missing GNSS velocity in a complete
    outage at rest (S002 4.2), where it keeps the velocity error far below the plain LC's."""
    rest_out = ot.Outage(20, 35, 0)  # inside the standstill (epochs 1..60)
    res = {}
    for system in ("lc_ins15_nhc_zupt", "lc_ins15"):
        prob = factory.build(None, MODE, system, 3)
        keep = ot.keep_mask(prob.elevation, prob.available, rest_out)
        inp = prob.inputs._replace(gnss=prob.inputs.gnss._replace(keep=prob.inputs.gnss.keep
                                                                   & keep))
        _, out = jax.jit(cascade.run)(prob.tf, prob.carry0, inp)
        v_err = np.linalg.norm(np.asarray(out.lc.vel_enu) - np.asarray(prob.truth.vel_enu), axis=1)
        res[system] = (out, v_err)
    out, v_err = res["lc_ins15_nhc_zupt"]
    speed = np.hypot(*np.asarray(factory.geo.truth_ep.vel_enu[1:, :2]).T)
    static = np.asarray(out.lc.static)
    rest, moving = speed < 0.01, speed > 2.0
    w = slice(rest_out.start + 5, rest_out.start + rest_out.length)
    zupt = np.asarray(out.lc.applied.zupt)
    print(f"\ndetector: static at {static[rest].mean():.0%} of rest epochs, "
          f"{static[moving].mean():.1%} of moving ones; ZUPT in the outage {zupt[w].mean():.0%}; "
          f"max velocity error in the outage: ZUPT {v_err[w].max() * 100:.2f} cm/s, plain LC "
          f"{res['lc_ins15'][1][w].max() * 100:.2f} cm/s")
    assert static[rest][10:].mean() > 0.8  # the detector adapts its reference in a few epochs
    assert static[moving].mean() < 0.02
    assert np.asarray(out.lc.applied.zaru)[rest][10:].mean() > 0.8
    assert zupt[w].mean() > 0.8 and not zupt[moving].any()
    assert v_err[w].max() < 0.5 * res["lc_ins15"][1][w].max()


def test_fixes_resume_right_after_a_3_min_outage(factory):
    """After 180 s without satellites the PPP-only filter's constant-velocity prediction is
    tens to hundreds of metres off, so most residuals fail the 20-m pre-fit test; the lock-out
    guard (tight._prefit_mask) lets the chi-square gate decide, and fixes resume at once (before
    the guard this filter never fixed again: seed002's LC study, 1.9 km after the outage)."""
    prob = factory.build(None, MODE, SYSTEM, 3)
    start, length = 90, 180
    mask = ot.keep_mask(prob.elevation, prob.available, ot.Outage(start, length, 0))
    inp = prob.inputs._replace(gnss=prob.inputs.gnss._replace(keep=prob.inputs.gnss.keep & mask))
    _, out = jax.jit(cascade.run)(prob.tf, prob.carry0, inp)
    end = start + length
    ppp_err = _h_err(out.ppp.llh[end - 1], prob.truth.llh[end - 1])
    h = _h_err(out.lc.llh, prob.truth.llh)
    print(f"PPP-only prediction off by {ppp_err:.0f} m at the outage end; LC error at the end "
          f"{h[end - 1]:.1f} m, 10 s later {h[end + 10]:.2f} m")
    assert ppp_err > 50.0  # the case the guard is for (plain pre-fit test: no satellite passes)
    assert np.all(np.asarray(out.fix.pos_valid[end + 1 : end + 20]))
    assert h[end + 10] < 3.0


def test_prefit_test_removes_an_outlier_but_never_locks_the_filter_out():
    """Six code satellites: one 50-m outlier among consistent residuals is removed (S002's
    pre-fit test); residuals spread by hundreds of metres (a prediction far off) are all kept."""
    from jaxnav.gnss import ppp

    cfg = ppp.PppConfig(mode="df_code", n_slots=6)
    n = 6

    def rows(dz):
        return ppp.Rows(jnp.asarray(dz), jnp.zeros((n, 4)), jnp.eye(n), jnp.ones(n, bool),
                        jnp.arange(n), jnp.full(n, ppp.KIND_CODE))

    one_bad = np.asarray(tight._prefit_mask(cfg, rows([3.0, 1.0, 2.0, 52.0, 0.0, 1.5])))
    np.testing.assert_array_equal(one_bad, [True, True, True, False, True, True])
    spread = np.asarray(tight._prefit_mask(cfg, rows([-400.0, 250.0, 30.0, 600.0, -90.0, 0.0])))
    assert spread.all()
