"""Truth trajectories: consistency with the strapdown equations, kinematics and closed forms."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.sim import drives
from jaxnav.sim import trajectory as tr

RATE_HZ = 100.0
TEN_MIN = 600.0


def _enu_error(llh_a, llh_b):
    return np.asarray(jax.vmap(lambda a, b: geodesy.llh_error_to_enu(a - b, b))(llh_a, llh_b))


@pytest.fixture(scope="module")
def urban():
    """10 min of urban stop-and-go (sharp 90 deg turns, stops) at 100 Hz."""
    return tr.generate_truth(drives.random_drive(3, "urban", TEN_MIN), RATE_HZ, duration_s=TEN_MIN)


@pytest.fixture(scope="module")
def airborne():
    """10 min of seed-001-like flight (45-50 m/s, banked turns, climbs) at 100 Hz."""
    return tr.generate_truth(drives.random_airborne(1, TEN_MIN), RATE_HZ, duration_s=TEN_MIN)


@pytest.fixture(scope="module")
def scripted():
    """A short scripted drive: stop, accelerate, right turn R = 20 m, hill, curve, stop."""
    segs = [
        tr.stop(5.0),
        tr.speed_to_kmh(36.0, 8.0),
        tr.cruise(10.0),
        tr.turn(90.0, radius_m=20.0),
        tr.cruise(5.0),
        tr.grade_to(5.0, 6.0),
        tr.cruise(10.0),
        tr.turn(-30.0, radius_m=300.0, ramp_s=3.0),
        tr.grade_to(0.0, 6.0),
        tr.speed_to(0.0, 8.0),
        tr.stop(5.0),
    ]
    profile = tr.compile_profile(segs, azimuth0_deg=30.0)
    return segs, profile, tr.generate_truth(profile, RATE_HZ)


# ---- (a) strapdown reproduces the truth from perfect increments ---------------------------------
@pytest.mark.parametrize("case", ["urban", "airborne"])
def test_strapdown_reproduces_truth_within_1cm_over_10min(case, request):
    strapdown = pytest.importorskip("jaxnav.ins.strapdown")
    truth = request.getfixturevalue(case)
    nav0 = strapdown.NavState(truth.llh[0], truth.vel_enu[0], truth.q_b_l[0])
    imu = strapdown.ImuIncrements(truth.dtheta_b[1:], truth.dv_b[1:])
    prev = strapdown.ImuIncrements(truth.dtheta_b[0], truth.dv_b[0])  # covers (-dt, 0]
    _, hist = jax.jit(strapdown.mechanize)(nav0, imu, 1.0 / RATE_HZ, prev)
    err = np.linalg.norm(_enu_error(hist.llh, truth.llh[1:]), axis=1)
    verr = np.abs(np.asarray(hist.vel_enu - truth.vel_enu[1:])).max()
    eps = jax.vmap(
        lambda a, b: attitude.attitude_error(attitude.dcm_from_quat(a), attitude.dcm_from_quat(b))
    )(hist.q_b_l, truth.q_b_l[1:])
    print(
        f"{case}: max 3D position error {err.max() * 1e3:.3f} mm, velocity {verr * 1e6:.2f} um/s,"
        f" attitude {np.abs(np.asarray(eps)).max():.2e} rad over {TEN_MIN:.0f} s"
    )
    assert err.max() < 0.01


# ---- (b) truth velocity integrates to truth position -------------------------------------------
@pytest.mark.parametrize("case", ["urban", "airborne"])
def test_velocity_integrates_to_position(case, request):
    truth = request.getfixturevalue(case)
    rate = jax.vmap(lambda llh, v: geodesy.llh_rate_matrix(llh) @ v)(truth.llh, truth.vel_enu)
    rate = np.asarray(rate)
    dt = truth.dt
    # Composite Simpson over sample pairs (error O(dt^4)), from the sampled outputs only.
    simpson = dt / 3.0 * (rate[0:-2:2] + 4.0 * rate[1:-1:2] + rate[2::2])
    llh_int = np.asarray(truth.llh[0]) + np.cumsum(simpson, axis=0)
    err = np.linalg.norm(_enu_error(jnp.asarray(llh_int), truth.llh[2::2]), axis=1)
    print(f"{case}: Simpson-integrated velocity vs truth position: max {err.max() * 1e9:.2f} nm")
    assert err.max() < 1e-4


# ---- (c) odometer speed = forward body velocity, no slip ---------------------------------------
def test_odometer_speed_is_forward_body_velocity(urban, airborne):
    for truth in (urban, airborne):
        v_b = jax.vmap(lambda q, v: attitude.dcm_from_quat(q).T @ v)(truth.q_b_l, truth.vel_enu)
        v_b = np.asarray(v_b)
        np.testing.assert_allclose(v_b[:, 1], np.asarray(truth.odo_speed_mps), atol=1e-10)
        np.testing.assert_allclose(v_b[:, [0, 2]], 0.0, atol=1e-10)  # no lateral/vertical slip
        assert np.all(np.asarray(truth.odo_speed_mps) >= 0.0)
    # The odometer acceleration is the time derivative of the speed (central differences).
    s, a = np.asarray(urban.odo_speed_mps), np.asarray(urban.odo_accel_mps2)
    np.testing.assert_allclose((s[2:] - s[:-2]) / (2 * urban.dt), a[1:-1], atol=1e-3)


# ---- (d) RISS consistency ----------------------------------------------------------------------
def test_riss_pitch_and_roll_from_specific_force(urban, scripted):
    for truth in (urban, scripted[2]):
        f = np.asarray(truth.f_b)
        a_od = np.asarray(truth.odo_accel_mps2)
        g = np.asarray(jax.vmap(lambda llh: geodesy.normal_gravity(llh[0], llh[2]))(truth.llh))
        pitch = np.asarray(truth.euler[:, 1])
        # No slip and v || forward axis make f_y = dv/dt + g sin(p) exact (the Coriolis term
        # is normal to v): seed 000 section 3.8 / S002 3.2.1.
        p_riss = np.arcsin((f[:, 1] - a_od) / g)
        p_riss_g0 = np.arcsin((f[:, 1] - a_od) / 9.80665)
        # Roll: r = -asin((f_x + v w_z) / (g cos p)); exact but for Earth/transport-rate terms.
        w_z = np.asarray(truth.w_ib_b[:, 2])
        v = np.asarray(truth.odo_speed_mps)
        r_riss = -np.arcsin((f[:, 0] + v * w_z) / (g * np.cos(p_riss)))
        roll = np.asarray(truth.euler[:, 0])
        dp, dp0, dr = (np.abs(x).max() for x in (p_riss - pitch, p_riss_g0 - pitch, r_riss - roll))
        print(
            f"RISS pitch error {dp:.2e} rad (local g), {dp0:.2e} rad (g = 9.80665); "
            f"roll error {dr:.2e} rad (max |roll| {np.degrees(np.abs(roll).max()):.2f} deg)"
        )
        assert dp < 1e-10
        assert dr < 2e-4  # ~ v w_ie sin(lat) / g at 60 km/h
        assert dp0 < 2e-5


# ---- closed forms -----------------------------------------------------------------------------
def test_stationary_sensor_outputs_are_earth_rate_and_gravity(scripted):
    _, _, truth = scripted
    k = int(2.0 * RATE_HZ)  # standing still
    C = attitude.dcm_from_quat(truth.q_b_l[k])
    llh = truth.llh[k]
    w_expect = C.T @ geodesy.earth_rate_enu(llh[0])
    f_expect = -(C.T @ geodesy.gravity_enu(llh))
    np.testing.assert_allclose(np.asarray(truth.w_ib_b[k]), np.asarray(w_expect), atol=1e-16)
    np.testing.assert_allclose(np.asarray(truth.f_b[k]), np.asarray(f_expect), atol=1e-12)
    np.testing.assert_allclose(np.asarray(truth.dtheta_b[k]), np.asarray(w_expect) * truth.dt)
    assert truth.event[k] == tr.Event.STOP


def test_scripted_turn_geometry_and_lateral_force(scripted):
    segs, profile, truth = scripted
    az = np.degrees(np.unwrap(np.asarray(truth.euler[:, 2])))
    assert az[0] == pytest.approx(30.0, abs=1e-12)
    assert az[-1] == pytest.approx(30.0 + 90.0 - 30.0, abs=1e-9)
    # Hold part of the R = 20 m turn at 10 m/s: azimuth rate v / R and lateral specific force
    # v^2 / R (to the right, +x) plus the outward lean's gravity component.
    t = np.asarray(truth.time_s)
    mid = np.argmin(np.abs(t - (5.0 + 8.0 + 10.0 + 0.5 * (2.0 * 2.0 + math.pi / 2 * 2.0 - 2.0))))
    w_z = float(truth.w_ib_b[mid, 2])
    assert -w_z == pytest.approx(10.0 / 20.0, rel=1e-3)  # right turn = negative about up
    roll = float(truth.euler[mid, 0])
    assert np.degrees(roll) == pytest.approx(np.degrees(math.atan(-0.07 * 5.0 / 9.80665)), 1e-6)
    g = 9.80665
    f_x = float(truth.f_b[mid, 0])
    assert f_x == pytest.approx(5.0 * math.cos(roll) - g * math.sin(roll), rel=2e-3)
    # Hill: pitch = atan(5 %).
    k = int((5 + 8 + 10 + 2 * 2 + math.pi / 2 * 2 - 2 + 5 + 6 + 5) * RATE_HZ)
    assert float(truth.euler[k, 1]) == pytest.approx(math.atan(0.05), abs=1e-12)
    assert truth.event[k] == tr.Event.SLOPE
    assert float(truth.odo_speed_mps[-1]) == 0.0
    assert len(segs) == 11
    assert profile.duration_s == pytest.approx(float(truth.time_s[-1]), abs=0.5 / RATE_HZ)


def test_coordinated_turn_has_no_lateral_force(airborne):
    # k = 1 bank law: lateral specific force cancels up to Earth/transport-rate terms (1e-3).
    f_x = np.abs(np.asarray(airborne.f_b[:, 0]))
    roll = np.degrees(np.abs(np.asarray(airborne.euler[:, 0])))
    speed = np.asarray(airborne.odo_speed_mps)
    print(f"airborne: max |roll| {roll.max():.1f} deg, max |f_x| {f_x.max():.2e} m/s^2")
    assert roll.max() > 9.0 and roll.max() <= 20.0 + 1e-9
    assert f_x.max() < 0.02
    assert speed.min() >= 45.0 - 1e-9 and speed.max() <= 50.0 + 1e-9


def test_continuity_and_increments_across_rates(scripted):
    _, profile, t100 = scripted
    t200 = tr.generate_truth(profile, 2 * RATE_HZ)
    # The 100 Hz increment over (t_{k-1}, t_k] is the sum of the two 200 Hz ones (integrals).
    for a, b in ((t100.dtheta_b, t200.dtheta_b), (t100.dv_b, t200.dv_b)):
        a, b = np.asarray(a), np.asarray(b)
        np.testing.assert_allclose(a[1:], b[1:-1:2] + b[2::2], rtol=0, atol=1e-10)
    # Continuity: the largest sample-to-sample jump halves when the rate doubles.
    for name in ("f_b", "w_ib_b"):
        j100 = np.abs(np.diff(np.asarray(getattr(t100, name)), axis=0)).max()
        j200 = np.abs(np.diff(np.asarray(getattr(t200, name)), axis=0)).max()
        assert j200 == pytest.approx(0.5 * j100, rel=0.05)
    dpos = _enu_error(t100.llh, t200.llh[::2])
    assert np.abs(dpos).max() < 1e-6  # RK4 on dt/4 is converged (position offsets carried)


def test_angular_rate_matches_attitude_derivative(scripted):
    # w_lb^b from the closed form equals C^T dC/dt of the Euler DCM (autodiff).
    _, profile, _ = scripted
    for t in (24.0, 26.0, 39.0, 50.0):
        kin = tr.kinematics(profile, t)
        C = attitude.dcm_from_euler(kin.euler)
        dC = jax.jacfwd(lambda s: attitude.dcm_from_euler(tr.kinematics(profile, s).euler))(t)
        W = C.T @ dC
        w = tr.body_rate_from_euler_rates(kin.euler, kin.euler_rate)
        np.testing.assert_allclose(np.asarray([W[2, 1], W[0, 2], W[1, 0]]), w, atol=1e-13)


# ---- generators and helpers --------------------------------------------------------------------
def test_random_mixed_drive_is_s000_like():
    segs = drives.random_drive_segments(np.random.default_rng(0), "mixed", 2400.0)
    profile = tr.compile_profile(segs)
    truth = tr.generate_truth(profile, 10.0)  # coarse rate: only kinematics are checked here
    kmh = np.asarray(truth.odo_speed_mps) * 3.6
    h = np.asarray(truth.llh[:, 2])
    codes = set(np.unique(np.asarray(truth.event)).tolist())
    print(
        f"mixed drive: {profile.duration_s / 60:.1f} min, max {kmh.max():.0f} km/h, "
        f"{(kmh > 60).mean():.0%} > 60 km/h, height {h.min():.0f}..{h.max():.0f} m"
    )
    assert 2300.0 < profile.duration_s < 2600.0
    assert kmh.max() <= 100.0 + 1e-9 and (kmh > 60.0).mean() > 0.15
    assert codes == {int(e) for e in tr.Event}
    assert h.max() - h.min() < 100.0
    # Reproducible from the seed.
    again = drives.random_drive_segments(np.random.default_rng(0), "mixed", 2400.0)
    assert again == segs


def test_epochs_and_event_intervals(scripted):
    _, _, truth = scripted
    ep = tr.truth_at_epochs(truth, 1.0)
    t = np.asarray(ep.time_s)
    np.testing.assert_allclose(t, np.arange(t.size), atol=1e-9)
    np.testing.assert_array_equal(np.asarray(ep.dtheta_b[0]), 0.0)
    step = int(RATE_HZ)
    np.testing.assert_allclose(
        np.asarray(ep.dv_b[3]), np.asarray(truth.dv_b[2 * step + 1 : 3 * step + 1]).sum(0)
    )
    iv = tr.event_intervals(truth)
    assert iv[0].event == tr.Event.STOP and iv[-1].event == tr.Event.STOP
    assert iv[0].start_s == 0.0 and iv[-1].end_s == pytest.approx(float(truth.time_s[-1]))
    kinds = {x.event for x in tr.event_intervals(truth, min_duration_s=2.0)}
    assert {tr.Event.TURN, tr.Event.SLOPE, tr.Event.STOP, tr.Event.SPEED_CHANGE} <= kinds


def test_bad_segments_are_rejected():
    with pytest.raises(ValueError, match="stop needs zero speed"):
        tr.compile_profile([tr.speed_to(5.0, 2.0), tr.stop(3.0)])
    with pytest.raises(ValueError, match="cannot turn at zero speed"):
        tr.compile_profile([tr.turn(90.0, radius_m=10.0)])
    with pytest.raises(ValueError, match="exactly one"):
        tr.turn(90.0)


def test_the_circuit_drive_closes_and_stays_near_its_start():
    """Laps of a 400 m x 200 m rectangle: the track never leaves the circuit (the farthest
    point is the far corner, at most the diagonal plus the corners' offset), and it is flat."""
    llh0 = (math.radians(55.68), math.radians(8.49), 60.0)
    for seed in (0, 1, 2):
        truth = tr.generate_truth(drives.circuit_drive(seed, 3600.0, llh0=llh0), 10.0, 3600.0)
        ep = tr.truth_at_epochs(truth, 30.0)
        enu = np.asarray(jax.vmap(
            lambda llh: geodesy.enu_offset(geodesy.llh_to_ecef(llh), jnp.asarray(llh0)))(ep.llh))
        dist = np.hypot(enu[:, 0], enu[:, 1])
        assert dist.max() < math.hypot(400.0, 200.0) + 50.0
        assert dist[-1] < dist.max()  # it came back round, not off along a straight
        assert np.abs(enu[:, 2]).max() < 0.1
