"""Loosely coupled GNSS/INS with vehicle constraints, in simulation against the simulator's truth.

Scenario (seed 002 ch. 4 style): a consumer MEMS IMU (``sensors.lsm6dsl``, 2 deg/s gyro and
40 mg accelerometer turn-on biases) and a wheel odometer on a 6.7 min drive that starts with a
30 s standstill (ZUPT/ZARU calibrate the gyros, heading unknown), sets off (in-motion alignment
from the GNSS course), turns, stops for 42 s and drives on. GNSS fixes at the antenna (lever
0.2/0.8/1.4 m) with white noise 0.5 m (position) and 0.05 m/s (velocity) per axis at 1 Hz.

Every Monte-Carlo run draws its own IMU errors, odometer scale and GNSS noise; all runs and all
outage variants are one ``vmap`` of one compiled ``run``. Outage variants differ only inside the
withheld window (which aids are switched on there), so each comparison is paired by key.
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.apps import lc
from jaxnav.core.states import INS27
from jaxnav.filter import loose
from jaxnav.filter.systems import InsSystem, NavSigmas
from jaxnav.ins import strapdown
from jaxnav.io import pos as pos_io
from jaxnav.sim import sensors
from jaxnav.sim import trajectory as tr

RATE_HZ = 100.0
K = 100  # IMU samples per 1 Hz epoch
SIGMA_POS_M, SIGMA_VEL_M_S = 0.5, 0.05
LEVER_ANT_B = jnp.array([0.2, 0.8, 1.4])
N_FULL = 24  # Monte-Carlo runs with full GNSS (accuracy, NEES)
N_OUT = 12  # runs per outage variant
CONVERGED = 90  # epochs after which the aligned filter has converged (turns at 57-63, 118-129)
OUTAGE_TURN = (276, 306)  # 30 s: 90 deg turn at R = 25 m, 12 m/s (0.6 g) 282-285, straight
OUTAGE_STRAIGHT = (295, 325)  # 30 s on the straight 286-326
OUTAGE_STOP = (205, 250)  # deceleration 208-214, standstill 215-257
SEGMENTS = [
    tr.stop(30.0), tr.speed_to(10.0, 6.0), tr.cruise(20.0), tr.turn(90.0, radius_m=40.0),
    tr.cruise(25.0), tr.speed_to(15.0, 8.0), tr.cruise(20.0), tr.turn(-60.0, radius_m=150.0),
    tr.cruise(20.0), tr.grade_to(3.0, 5.0), tr.cruise(20.0), tr.grade_to(0.0, 5.0),
    tr.turn(120.0, radius_m=30.0), tr.cruise(20.0), tr.speed_to(0.0, 10.0), tr.stop(40.0),
    tr.speed_to(12.0, 10.0), tr.cruise(15.0), tr.turn(-90.0, radius_m=25.0), tr.cruise(40.0),
    tr.turn(45.0, radius_m=100.0), tr.cruise(30.0), tr.turn(-100.0, radius_m=40.0),
    tr.cruise(30.0),
]  # fmt: skip

# (outage window, NHC, odometer, ZUPT/ZARU inside the window). Every run uses GNSS and ZUPT/ZARU
# (on detected standstill) outside its window; NHC and odometer, when on, are used throughout
# (the odometer scale factor is calibrated with the GNSS before the outage).
VARIANTS = {
    "full": (None, False, False, True),
    "straight_free": (OUTAGE_STRAIGHT, False, False, False),
    "straight_nhc": (OUTAGE_STRAIGHT, True, False, False),
    "straight_nhc_odo": (OUTAGE_STRAIGHT, True, True, False),
    "turn_free": (OUTAGE_TURN, False, False, False),
    "turn_nhc": (OUTAGE_TURN, True, False, False),
    "turn_nhc_odo": (OUTAGE_TURN, True, True, False),
    "stop_free": (OUTAGE_STOP, False, False, False),
    "stop_zupt": (OUTAGE_STOP, False, False, True),
}


def _enu_errors(llh_hat, llh_true):
    return jax.vmap(lambda a, b: geodesy.llh_error_to_enu(a - b, b))(llh_hat, llh_true)


@pytest.fixture(scope="module")
def sim():
    profile = tr.compile_profile(SEGMENTS, azimuth0_deg=30.0)
    truth = tr.generate_truth(profile, RATE_HZ, duration_s=math.floor(profile.duration_s))
    ep = tr.truth_at_epochs(truth, 1.0)
    C = jax.vmap(attitude.dcm_from_quat)(ep.q_b_l)
    llh_ant = jax.vmap(strapdown.antenna_llh, (0, 0, None))(ep.llh, C, LEVER_ANT_B)
    vel_ant = jax.vmap(strapdown.antenna_vel_enu, (0, 0, 0, 0, None))(
        ep.llh, ep.vel_enu, C, ep.w_ib_b, LEVER_ANT_B
    )
    return truth, ep, C, llh_ant, vel_ant


def _run_from_rest(lf, samples, fix, inputs, sig, smooth=False):
    """Start levelled from the first second's mean specific force, heading unknown (0),
    position from the first fix (antenna lever rotated with that attitude), at rest; run
    (``smooth``: ``loose.run_smoother``, returning (forward, smoothed) outputs)."""
    euler0 = loose.align_from_gnss(jnp.zeros(3), samples.dv_b[0].sum(0)).at[2].set(0.0)
    lever_l = attitude.dcm_from_euler(euler0) @ LEVER_ANT_B
    llh0 = fix.llh[0] - geodesy.llh_rate_matrix(fix.llh[0]) @ lever_l
    carry = loose.initial_carry(lf, loose.initial_nav(llh0, jnp.zeros(3), euler0), sig)
    if smooth:
        return loose.run_smoother(lf, carry, inputs)
    return loose.run(lf, carry, inputs)[1]


def _filter():
    grade = sensors.lsm6dsl()
    system = InsSystem(layout=INS27, model=loose.imu_error_model(grade), lever_b=LEVER_ANT_B)
    cfg = loose.LooseConfig(
        use_nhc=True,
        use_odometer=True,
        estimate_odo_scale=True,
        use_zupt=True,
        use_zaru=True,
        cov_substeps=10,
        align_in_motion=True,
        odo_sigma_m_s=0.02,  # the simulated wheel odometer's noise
        odo_scale_sigma=0.005,  # its 0.5 % scale factor
    )
    return grade, loose.LooseFilter(system, cfg, 1.0 / RATE_HZ, 1.0)


@pytest.fixture(scope="module")
def runs(sim):
    truth, ep, _, llh_ant, vel_ant = sim
    grade, lf = _filter()
    odo_params = sensors.wheel_odometer()
    n_ep = ep.time_s.shape[0] - 1
    # Tilt prior: levelling with a 40 mg accelerometer bias is off by up to ~2.3 deg per axis.
    sig = NavSigmas(pos_m=SIGMA_POS_M, vel_m_s=SIGMA_VEL_M_S, roll_pitch_rad=0.05)

    def one_run(key, pos_valid, nhc_valid, odo_valid, zupt_allowed, smooth=False):
        k_imu, k_odo, k_pos, k_vel = jax.random.split(key, 4)
        dth, dv, imu_err = sensors.simulate_imu(
            k_imu, truth.dtheta_b[1:], truth.dv_b[1:], 1.0 / RATE_HZ, grade
        )
        odo, _ = sensors.simulate_odometer(k_odo, ep.odo_speed_mps[1:], 1.0, odo_params)
        m_n, m_e, _ = jax.vmap(geodesy.metres_per_radian)(llh_ant[1:]).T
        noise_enu = SIGMA_POS_M * jax.random.normal(k_pos, (n_ep, 3))
        dllh = jnp.stack([noise_enu[:, 1] / m_n, noise_enu[:, 0] / m_e, noise_enu[:, 2]], -1)
        vel_noise = SIGMA_VEL_M_S * jax.random.normal(k_vel, (n_ep, 3))
        fix = loose.gnss_fix(
            llh_ant[1:] + dllh, vel_ant[1:] + vel_noise, SIGMA_POS_M, SIGMA_VEL_M_S,
            pos_valid, pos_valid,
        )  # fmt: skip
        samples = strapdown.ImuIncrements(dth.reshape(n_ep, K, 3), dv.reshape(n_ep, K, 3))
        inputs = loose.epoch_inputs(samples, fix, odo, odo_valid, nhc_valid, zupt_allowed)
        out = _run_from_rest(lf, samples, fix, inputs, sig, smooth)
        return out, imu_err.gyro_bias_rad_s[K - 1 :: K]

    t = np.arange(1, n_ep + 1)
    keys, pos_valid, nhc, odo, zupt, names = [], [], [], [], [], []
    for i, (name, (window, use_nhc, use_odo, use_zupt)) in enumerate(VARIANTS.items()):
        n = N_FULL if name == "full" else N_OUT
        inside = np.zeros(n_ep, bool) if window is None else (t > window[0]) & (t <= window[1])
        for key in jax.random.split(jax.random.PRNGKey(100 + (i > 0)), n):
            keys.append(key)
            pos_valid.append(~inside)
            nhc.append(np.full(n_ep, use_nhc))
            odo.append(np.full(n_ep, use_odo))
            zupt.append(~inside | use_zupt)
            names.append(name)
    out, gyro_bias = jax.jit(jax.vmap(one_run))(
        jnp.stack(keys), *(jnp.asarray(np.stack(a)) for a in (pos_valid, nhc, odo, zupt))
    )
    names = np.array(names)
    err = np.asarray(jax.vmap(_enu_errors, (0, None))(out.llh, ep.llh[1:]))
    C_hat = jax.vmap(jax.vmap(attitude.dcm_from_euler))(out.euler)
    eps = jax.vmap(jax.vmap(attitude.attitude_error), (0, None))(C_hat, sim[2][1:])
    inputs = dict(keys=jnp.stack(keys), pos_valid=np.stack(pos_valid), nhc=np.stack(nhc),
                  odo=np.stack(odo), zupt=np.stack(zupt))
    return dict(
        out=out, names=names, t=t, err_enu=err, eps=np.asarray(eps), gyro_bias=gyro_bias, ep=ep,
        one_run=one_run, inputs=inputs,
    )


def _sel(runs, name):
    return runs["names"] == name


def test_converged_position_rms_matches_gnss_noise(runs):
    """After convergence the integrated position is better than the 0.5 m fixes it is fed."""
    sel = _sel(runs, "full")
    e = runs["err_enu"][sel][:, CONVERGED:]
    rms = np.sqrt(np.mean(e**2, axis=(0, 1)))
    print(f"LC position RMS E/N/U after {CONVERGED} s: {rms.round(3)} m (fixes 0.5 m/axis)")
    assert np.all(rms < 0.3) and np.all(rms > 0.05)  # ~0.15 m measured; > 0.05: no leak of truth
    assert bool(np.all(np.asarray(runs["out"].aligned)[sel][:, 40:]))


def test_heading_from_course_then_converges_in_turns(runs):
    out, sel, t = runs["out"], _sel(runs, "full"), runs["t"]
    aligned = np.asarray(out.aligned)[sel]
    first = aligned.argmax(axis=1)
    # Sets off at t = 30 s; aligned at the first fix faster than 3 m/s (t = 33 s, 5 m/s).
    assert np.all(t[first] == 33)
    head = np.degrees(runs["eps"][sel][..., 2])
    sig = np.degrees(np.sqrt(np.asarray(out.P_nav)[sel][..., 8, 8]))
    i0 = first[0]
    at_align = head[np.arange(head.shape[0]), first]
    # Before: the arbitrary start heading (30 deg off, plus the gyro drift until ZARU).
    assert np.all(np.abs(head[:, i0 - 1]) > 20.0)
    # After: the course over ground (sigma_v / v ~ 0.6 deg at 5 m/s, + 1.1 deg floor).
    assert np.sqrt(np.mean(at_align**2)) < 1.5
    # Heading sigma shrinks in the turns (57-63, 118-129 s), not on the straights before them.
    s = sig.mean(axis=0)
    straight = s[t == 56][0] / s[t == 45][0]
    turn1 = s[t == 64][0] / s[t == 56][0]
    late = np.sqrt(np.mean(head[:, t >= 130] ** 2))
    print(
        f"heading: rms at alignment {np.sqrt(np.mean(at_align**2)):.2f} deg; sigma ratio over "
        f"straight 45-56 s {straight:.2f}, over turn 56-64 s {turn1:.2f}; rms after 130 s "
        f"{late:.2f} deg"
    )
    assert turn1 < 0.8 < straight
    assert late < 0.6


def _ensemble_position_nees(llh, P_nav, ep):
    """Per-epoch ensemble-mean position NEES after CONVERGED of runs [R, T] against the truth,
    with its two-sided 95 % band chi2(3R)/R (Wilson-Hilferty, within 0.1 % of the exact
    quantiles) and the share of epochs inside it: (avg, R, lo, hi, inside)."""
    dllh = np.asarray(llh) - np.asarray(ep.llh)[None, 1:]
    dllh[..., 1] = (dllh[..., 1] + np.pi) % (2 * np.pi) - np.pi
    P = np.asarray(P_nav)[..., :3, :3]
    nees = np.einsum("rti,rtij,rtj->rt", dllh, np.linalg.inv(P), dllh)[:, CONVERGED:]
    avg = nees.mean(axis=0)
    n = nees.shape[0]
    lo, hi = (_chi2_quantile(3 * n, z) / n for z in (-1.959964, 1.959964))
    return avg, n, lo, hi, np.mean((avg > lo) & (avg < hi))


def test_position_nees_within_chi_square_band(runs):
    """Ensemble-averaged position NEES (3 dof, N runs) against chi2(3N)/N, 95 % two-sided."""
    out, sel = runs["out"], _sel(runs, "full")
    avg, n, lo, hi, inside = _ensemble_position_nees(np.asarray(out.llh)[sel],
                                                     np.asarray(out.P_nav)[sel], runs["ep"])
    print(
        f"position NEES over {n} runs, epochs {CONVERGED}-{avg.size + CONVERGED}: mean "
        f"{avg.mean():.2f} (3 expected), {100 * inside:.0f} % of epochs in [{lo:.2f}, {hi:.2f}]"
    )
    assert 2.5 < avg.mean() < 3.6
    assert inside > 0.85


def _chi2_quantile(dof, z):
    return dof * (1.0 - 2.0 / (9.0 * dof) + z * math.sqrt(2.0 / (9.0 * dof))) ** 3


def _outage_metrics(runs, name, window):
    t = runs["t"]
    inside = (t > window[0]) & (t <= window[1])
    e = runs["err_enu"][_sel(runs, name)][:, inside]
    az = np.asarray(runs["ep"].euler)[1:, 2][inside]
    fwd = np.stack([np.sin(az), np.cos(az)], -1)
    right = np.stack([np.cos(az), -np.sin(az)], -1)
    along = np.einsum("rti,ti->rt", e[..., :2], fwd)
    cross = np.einsum("rti,ti->rt", e[..., :2], right)
    max2d = np.linalg.norm(e[..., :2], axis=-1).max(axis=1).mean()
    return max2d, np.abs(along).max(axis=1).mean(), np.abs(cross).max(axis=1).mean()


def _outage_nees(runs, name, window):
    """Ensemble-mean horizontal position NEES (2 dof) at the end of the outage."""
    sel, t = _sel(runs, name), runs["t"]
    k = np.nonzero(t == window[1])[0][0]
    dllh = np.asarray(runs["out"].llh)[sel][:, k, :2] - np.asarray(runs["ep"].llh)[k + 1, :2]
    P = np.asarray(runs["out"].P_nav)[sel][:, k, :2, :2]
    return np.einsum("ri,rij,rj->r", dllh, np.linalg.inv(P), dllh).mean()


@pytest.mark.parametrize("where", ["straight", "turn"])
def test_nhc_and_odometer_reduce_outage_drift(runs, where):
    """30 s withheld GNSS: free inertial vs NHC (1 m/s, S003) vs NHC + odometer (paired keys)."""
    window = OUTAGE_STRAIGHT if where == "straight" else OUTAGE_TURN
    free, nhc, odo = (
        _outage_metrics(runs, f"{where}_{v}", window) for v in ("free", "nhc", "nhc_odo")
    )
    for label, m, v in (("free", free, "free"), ("NHC", nhc, "nhc"), ("NHC+odo", odo, "nhc_odo")):
        nees = _outage_nees(runs, f"{where}_{v}", window)
        print(f"{where} {label:8s} max 2D {m[0]:.2f} m, along {m[1]:.2f}, cross {m[2]:.2f}; "
              f"2D NEES at end {nees:.1f}")  # fmt: skip
    print(f"{where}: ratios to free, 2D: NHC {nhc[0] / free[0]:.2f}, NHC+odo "
          f"{odo[0] / free[0]:.2f}; cross: NHC {nhc[2] / free[2]:.2f}; along: NHC+odo "
          f"{odo[1] / free[1]:.2f}")  # fmt: skip
    assert free[0] > 2.0  # a consumer MEMS drifts metres in 30 s
    assert nhc[2] < 0.75 * free[2]  # the NHC bounds the lateral (cross-track) drift
    assert odo[1] < 0.2 * free[1]  # the odometer removes most of the along-track drift
    if where == "straight":
        assert nhc[0] < 0.9 * free[0] and odo[0] < 0.5 * free[0]
    else:  # the 0.6 g turn leaves attitude errors the constraints only partly observe
        assert nhc[0] < free[0] and odo[0] < 0.8 * free[0]


def test_zupt_holds_velocity_and_position_at_a_stop(runs):
    """GNSS withheld from 205 s through the standstill (215-250 s): ZUPT/ZARU vs free inertial."""
    t, ep = runs["t"], runs["ep"]
    still = (t >= 220) & (t <= OUTAGE_STOP[1])
    res = {}
    for name in ("stop_free", "stop_zupt"):
        sel = _sel(runs, name)
        v_err = np.asarray(runs["out"].vel_enu)[sel][:, still] - np.asarray(ep.vel_enu)[1:][still]
        e = runs["err_enu"][sel][:, still, :2]
        drift = np.linalg.norm(e[:, -1] - e[:, 0], axis=-1).mean()
        res[name] = (np.sqrt(np.mean(v_err**2)), drift)
        print(f"{name}: velocity error rms {res[name][0]:.4f} m/s, 2D drift over 30 s "
              f"{res[name][1]:.3f} m")  # fmt: skip
    assert res["stop_zupt"][0] < 0.02  # the ZUPT noise level (0.02 m/s)
    assert res["stop_zupt"][1] < 0.25  # ~0.09 m measured
    assert res["stop_free"][1] > 20 * res["stop_zupt"][1]
    applied = np.asarray(runs["out"].applied.zupt)[_sel(runs, "stop_zupt")]
    assert np.all(applied[:, still])


def test_zupt_waits_for_missing_gnss_velocity_but_zaru_does_not(runs):
    """S002: no ZUPT while a GNSS velocity is used; the gyro-only ZARU still runs at rest."""
    out, sel, t = runs["out"], _sel(runs, "full"), runs["t"]
    stop = (t >= 217) & (t <= 255)
    static = np.asarray(out.static)[sel]
    assert np.all(static[:, stop]) and not np.any(static[:, (t > 40) & (t < 200)])
    assert not np.any(np.asarray(out.applied.zupt)[sel])
    assert np.all(np.asarray(out.applied.zaru)[sel][:, stop])
    # ZARU calibrated the z gyro during the first 30 s (2 deg/s turn-on bias) to < 50 deg/h.
    gz_err = (
        np.asarray(out.sensors.gyro_bias_rad_s)[sel][:, 29, 2]
        - np.asarray(runs["gyro_bias"])[sel][:, 29, 2]
    )
    print(f"z gyro bias error after the 30 s standstill: {np.degrees(gz_err).std() * 3600:.1f}"
          " deg/h rms")  # fmt: skip
    assert np.degrees(np.abs(gz_err)).max() * 3600 < 50.0


# ---- time-correlated fixes (fix_bias_tau_s) ----------------------------------------------------
FIX_TAU_S = 60.0  # truth and filter: the fix error is a first-order Gauss-Markov process
N_GM = 64


@pytest.fixture(scope="module")
def gm_runs(sim):
    """Full-GNSS runs whose fixes carry a GM position error (tau 60 s, 0.5 m per axis) and report
    its steady sigma: once with the filter's fix-bias states, once weighting the fixes as white.
    Same keys (paired)."""
    truth, ep, _, llh_ant, vel_ant = sim
    grade, lf_white = _filter()
    lf_gm = loose.LooseFilter(lf_white.system, dataclasses.replace(
        lf_white.cfg, fix_bias_tau_s=FIX_TAU_S), lf_white.imu_dt_s, 1.0)
    n_ep = ep.time_s.shape[0] - 1
    sig = NavSigmas(pos_m=SIGMA_POS_M, vel_m_s=SIGMA_VEL_M_S, roll_pitch_rad=0.05)
    rho = math.exp(-1.0 / FIX_TAU_S)

    def one_run(lf, key):
        k_imu, k_gm0, k_gm, k_vel = jax.random.split(key, 4)
        dth, dv, _ = sensors.simulate_imu(
            k_imu, truth.dtheta_b[1:], truth.dv_b[1:], 1.0 / RATE_HZ, grade)
        # e_k = rho e_k-1 + sqrt(1 - rho^2) sigma n_k, stationary from the first epoch
        e0 = SIGMA_POS_M * jax.random.normal(k_gm0, (3,))
        drive = math.sqrt(1.0 - rho**2) * SIGMA_POS_M * jax.random.normal(k_gm, (n_ep, 3))
        _, noise_enu = jax.lax.scan(lambda e, q: (rho * e + q, rho * e + q), e0, drive)
        m_n, m_e, _ = jax.vmap(geodesy.metres_per_radian)(llh_ant[1:]).T
        dllh = jnp.stack([noise_enu[:, 1] / m_n, noise_enu[:, 0] / m_e, noise_enu[:, 2]], -1)
        vel_noise = SIGMA_VEL_M_S * jax.random.normal(k_vel, (n_ep, 3))
        fix = loose.gnss_fix(llh_ant[1:] + dllh, vel_ant[1:] + vel_noise, SIGMA_POS_M,
                             SIGMA_VEL_M_S, True, True)
        samples = strapdown.ImuIncrements(dth.reshape(n_ep, K, 3), dv.reshape(n_ep, K, 3))
        inputs = loose.epoch_inputs(samples, fix, None, None, True, True)
        return _run_from_rest(lf, samples, fix, inputs, sig)

    keys = jax.random.split(jax.random.PRNGKey(7), N_GM)
    res = {}
    for name, lf in (("white", lf_white), ("gm_states", lf_gm)):
        out = jax.jit(jax.vmap(lambda k, lf=lf: one_run(lf, k)))(keys)
        dllh = np.asarray(out.llh) - np.asarray(ep.llh)[None, 1:]
        P = np.asarray(out.P_nav)[..., :3, :3]
        res[name] = np.einsum("rti,rtij,rtj->rt", dllh, np.linalg.inv(P), dllh)[:, CONVERGED:]
    return res


def test_time_correlated_fixes_keep_the_position_nees_in_its_band(gm_runs):
    """Fixes with a 60 s Gauss-Markov error: with the fix-bias states (Groves 14.3.1) the
    ensemble-mean position NEES is 3 within the chi-square band of N runs, as the white-fix filter
    is for white fixes (test_position_nees_within_chi_square_band); weighting the correlated fixes
    as white makes it over-confident (the cascade's issue-16 defect)."""
    n = N_GM
    lo, hi = (_chi2_quantile(3 * n, z) / n for z in (-1.959964, 1.959964))
    avg = {k: v.mean(axis=0) for k, v in gm_runs.items()}
    for k, a in avg.items():
        print(f"{k}: position NEES mean {a.mean():.2f}, {100 * np.mean((a > lo) & (a < hi)):.0f} "
              f"% of epochs in [{lo:.2f}, {hi:.2f}]")
    assert lo < avg["gm_states"].mean() < hi
    assert np.mean((avg["gm_states"] > lo) & (avg["gm_states"] < hi)) > 0.85
    assert avg["white"].mean() > hi  # the defect the states remove


@pytest.fixture(scope="module")
def smoothed(runs):
    """The "full" and "turn_free" runs again through ``loose.run_smoother`` (same keys)."""
    sel = np.isin(runs["names"], ["full", "turn_free"])
    inp = runs["inputs"]
    (fwd, smo), _ = jax.jit(jax.vmap(lambda *a: runs["one_run"](*a, smooth=True)))(
        inp["keys"][sel], *(jnp.asarray(inp[k][sel]) for k in ("pos_valid", "nhc", "odo", "zupt"))
    )
    ep = runs["ep"]
    err = {k: np.asarray(jax.vmap(_enu_errors, (0, None))(o.llh, ep.llh[1:]))
           for k, o in (("forward", fwd), ("smoothed", smo))}
    return dict(fwd=fwd, smo=smo, err=err, sel=sel, names=runs["names"][sel])


def test_smoother_forward_pass_is_the_filter(runs, smoothed):
    """Recording what the smoother needs does not change the forward filter: positions and
    covariances equal those of ``loose.run`` to 1e-8 of a sigma (a different vmap batch may
    round differently, which the closed loop carries along; measured 0 to ~1e-9)."""
    fwd, ref = smoothed["fwd"], jax.tree.map(lambda a: np.asarray(a)[smoothed["sel"]],
                                             runs["out"])
    P = ref.P_nav
    sd = np.sqrt(np.diagonal(P, axis1=-2, axis2=-1))
    assert np.max(np.abs(np.asarray(fwd.llh) - ref.llh) / sd[..., :3]) < 1e-8
    assert np.max(np.abs(np.asarray(fwd.P_nav) - P) / (sd[..., :, None] * sd[..., None, :])) < 1e-8


def test_smoothed_position_nees_within_chi_square_band(runs, smoothed):
    """Full GNSS: ensemble-mean position NEES of the smoothed solution (3 dof, N runs) in the
    95 % chi-square band on average and at >= 85 % of the epochs (as the forward filter's in
    test_position_nees_within_chi_square_band), and its position sigma below the forward one
    at every epoch."""
    full = smoothed["names"] == "full"
    smo, fwd = smoothed["smo"], smoothed["fwd"]
    avg, n, lo, hi, inside = _ensemble_position_nees(np.asarray(smo.llh)[full],
                                                     np.asarray(smo.P_nav)[full], runs["ep"])
    print(f"smoothed position NEES over {n} runs: mean {avg.mean():.2f}, {100 * inside:.0f} % "
          f"of epochs in [{lo:.2f}, {hi:.2f}]")
    assert lo < avg.mean() < hi
    assert inside > 0.85
    var_s = np.diagonal(np.asarray(smo.P_nav), axis1=-2, axis2=-1)
    var_f = np.diagonal(np.asarray(fwd.P_nav), axis1=-2, axis2=-1)
    assert np.all(var_s <= var_f * (1.0 + 1e-9))


def test_smoothing_bridges_the_outage(runs, smoothed):
    """30 s free-inertial outage through the turn: the smoother, which also sees the fixes after
    it, ends far below the forward drift, and its horizontal NEES at mid-outage (2 dof, N runs)
    lies in the 99 % chi-square band."""
    t = runs["t"]
    turn = smoothed["names"] == "turn_free"
    inside = (t > OUTAGE_TURN[0]) & (t <= OUTAGE_TURN[1])
    max2d = {k: np.linalg.norm(e[turn][:, inside, :2], axis=-1).max(axis=1).mean()
             for k, e in smoothed["err"].items()}
    k = int(np.nonzero(t == (OUTAGE_TURN[0] + OUTAGE_TURN[1]) // 2)[0][0])
    smo = smoothed["smo"]
    dllh = np.asarray(smo.llh)[turn][:, k, :2] - np.asarray(runs["ep"].llh)[k + 1, :2]
    P = np.asarray(smo.P_nav)[turn][:, k, :2, :2]
    nees = np.einsum("ri,rij,rj->r", dllh, np.linalg.inv(P), dllh).mean()
    n = int(turn.sum())
    lo, hi = (_chi2_quantile(2 * n, z) / n for z in (-2.575829, 2.575829))
    print(f"turn outage, mean max 2D error: forward {max2d['forward']:.2f} m, smoothed "
          f"{max2d['smoothed']:.2f} m; smoothed mid-outage NEES {nees:.2f} in [{lo:.2f}, {hi:.2f}]")
    assert max2d["smoothed"] < 0.5 * max2d["forward"]
    assert lo < nees < hi


# ---- helpers (no filter run) ------------------------------------------------------------------
def test_levelling_and_course_closed_form():
    euler = jnp.array([0.03, -0.05, 2.5])
    C = attitude.dcm_from_euler(euler)
    f_b = C.T @ jnp.array([0.0, 0.0, 9.81])  # at rest: f^b = C_l^b (-g^l)
    vel = 12.0 * jnp.array([math.sin(2.5), math.cos(2.5), 0.0])
    np.testing.assert_allclose(loose.align_from_gnss(vel, f_b), euler, atol=1e-12)
    no_imu = loose.align_from_gnss(jnp.array([3.0, -4.0, 0.5]))
    np.testing.assert_allclose(no_imu, [0.0, math.atan2(0.5, 5.0), math.atan2(3.0, -4.0)])
    speeds = jnp.array([[0.0, 0.1, 0.0], [2.0, 2.0, 0.0], [4.0, 3.0, 0.0], [9.0, 0.0, 0.0]])
    assert int(loose.alignment_epoch(speeds, jnp.array([True, True, False, True]))) == 3


def test_gnss_fixes_from_rtklib_solution():
    n = 3
    sol = pos_io.PosSolution(
        time_gps_s=np.arange(n, dtype=float),
        llh=np.array([[0.7, -1.3, 90.0]] * n),
        q=np.array([6, pos_io.Q_OUTAGE, 6]),
        ns=np.array([8, 0, 8]),
        sd_neu_m=np.array([[0.3, 0.2, 0.5]] * n),
        sd_cross_m=np.array([[0.1, 0.0, -0.1]] * n),
        age_s=np.zeros(n),
        ratio=np.zeros(n),
        vel_enu=np.array([[1.0, 2.0, 0.0], [1.0, 2.0, 0.0], [np.nan] * 3]),
        sd_vel_neu=np.full((n, 3), 0.05),
        sd_vel_cross=np.zeros((n, 3)),
    )
    fix = lc.gnss_fixes_from_pos(sol)
    assert np.array_equal(fix.pos_valid, [True, False, True])
    assert np.array_equal(fix.vel_valid, [True, False, False])
    # ENU covariance: E = sde^2, N = sdn^2, EN = sign(sdne) sdne^2, NU = -sdun^2.
    np.testing.assert_allclose(
        fix.cov_pos_enu[0], [[0.04, 0.01, 0.0], [0.01, 0.09, -0.01], [0.0, -0.01, 0.25]]
    )
    assert np.all(np.isfinite(np.asarray(fix.vel_enu)))

