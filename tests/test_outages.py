"""Outage masks, selection policies, placements and schedule files (jaxnav.study.outages)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.sim.trajectory import Event
from jaxnav.study import outages as o

DEG = math.pi / 180.0
MASK = o.DEFAULT_ELEVATION_MASK_RAD


def _sky(T, S, seed=0, lo_deg=15.0, hi_deg=85.0):
    """Random elevations (all above the mask) and azimuths, slowly drifting over time."""
    rng = np.random.default_rng(seed)
    el0 = rng.uniform(lo_deg, hi_deg, S) * DEG
    az0 = rng.uniform(0.0, 2.0 * math.pi, S)
    drift = rng.uniform(-0.02, 0.02, S) * DEG
    t = np.arange(T)[:, None]
    el = np.clip(el0 + drift * t, lo_deg * DEG, hi_deg * DEG)
    return el, np.mod(az0 + 0.001 * t, 2 * math.pi)


def _mask(el, av, outage, policy, az=None, key=None):
    key = jax.random.key(7) if key is None else key
    return np.asarray(o.keep_mask(el, av, outage, key, policy=policy, azimuth=az))


@pytest.mark.parametrize("policy", o.POLICIES)
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_exactly_k_inside_all_available_outside(policy, k):
    T, S = 60, 12
    el, az = _sky(T, S, seed=k)
    rng = np.random.default_rng(100 + k)
    av = np.ones((T, S), bool)
    av[:15] = rng.random((15, S)) > 0.3  # outside the window: arbitrary availability
    av[45:] = rng.random((15, S)) > 0.3
    keep = _mask(el, av, o.Outage(20, 17, k), policy, az)
    inside = np.arange(T)
    inside = (inside >= 20) & (inside < 37)
    assert np.all(keep.sum(axis=1)[inside] == k)
    np.testing.assert_array_equal(keep[~inside], av[~inside])
    assert not np.any(keep & ~av)
    # the kept set is held: every window epoch keeps the same satellites
    assert np.all(keep[inside] == keep[20])


def test_highest_and_lowest_pick_the_obvious_sets_and_respect_the_mask():
    T = 10
    el_deg = np.array([70.0, 12.0, 45.0, 5.0, 30.0, 80.0, 20.0])  # slot 3 below the 10 deg mask
    el = np.tile(el_deg * DEG, (T, 1))
    av = np.ones_like(el, bool)
    av[:, 5] = False  # the highest is not tracked
    out = o.Outage(2, 5, 3)
    hi = _mask(el, av, out, "highest")[4]
    lo = _mask(el, av, out, "lowest")[4]
    np.testing.assert_array_equal(np.flatnonzero(hi), [0, 2, 4])  # 70, 45, 30
    np.testing.assert_array_equal(np.flatnonzero(lo), [1, 4, 6])  # 12, 30, 20 (not the 5 deg)


def test_kept_set_chosen_once_setting_satellites_not_replaced_rising_not_admitted():
    T, S = 40, 5
    # slot 0 sinks and slot 1 climbs: a per-epoch "highest 2" would switch from {0, 2} to {1, 2}
    t = np.arange(T)
    el = np.zeros((T, S))
    el[:, 0] = (60.0 - 1.5 * t) * DEG
    el[:, 1] = (20.0 + 1.5 * t) * DEG
    el[:, 2] = 75.0 * DEG
    el[:, 3] = 15.0 * DEG
    el[:, 4] = 50.0 * DEG
    av = np.ones((T, S), bool)
    av[:, 4] = t >= 15  # slot 4 rises (high) during the outage
    av[25:, 2] = False  # kept slot 2 sets at epoch 25
    keep = _mask(el, av, o.Outage(10, 20, 2), "highest")
    for e in range(10, 25):
        np.testing.assert_array_equal(np.flatnonzero(keep[e]), [0, 2])
    for e in range(25, 30):
        np.testing.assert_array_equal(np.flatnonzero(keep[e]), [0])  # not replaced
    np.testing.assert_array_equal(keep[30:], av[30:])  # after the outage: everything


def test_random_policy_is_uniform_and_key_driven():
    T, S, k, n = 8, 6, 2, 4000
    el = np.tile(np.linspace(20, 70, S) * DEG, (T, 1))
    av = np.ones((T, S), bool)
    keys = jax.random.split(jax.random.key(3), n)
    f = jax.jit(jax.vmap(lambda key: o.keep_mask(el, av, o.Outage(2, 4, k), key, policy="random")))
    keep = np.asarray(f(keys))[:, 3]  # an epoch inside the window
    assert np.all(keep.sum(axis=1) == k)
    freq = keep.mean(axis=0)
    p = k / S
    sigma = math.sqrt(p * (1 - p) / n)
    assert np.all(np.abs(freq - p) < 5 * sigma), freq
    # 15 pairs, each about 1/15 of the draws
    pairs = keep @ (1 << np.arange(S))
    counts = np.bincount(pairs)
    counts = counts[counts > 0]
    assert counts.size == 15
    assert np.all(np.abs(counts / n - 1 / 15) < 5 * math.sqrt((1 / 15) * (14 / 15) / n))


def test_geometry_measure_closed_forms():
    rng = np.random.default_rng(1)
    el = rng.uniform(0, 1.4, 3)
    az = rng.uniform(0, 6.28, 3)
    u = np.asarray(o.los_enu(el, az))
    # k = 2: det(I + G G^T) = 9 - (1 + cos a)^2
    m2 = np.array([True, True, False])
    c = u[0] @ u[1]
    assert float(o.geometry_measure(jnp.asarray(u), jnp.asarray(m2))) == pytest.approx(
        math.log(9.0 - (1.0 + c) ** 2), rel=1e-13
    )
    # k = 3: Sylvester, det(I_4 + G^T G) with G rows [u, 1]
    G = np.hstack([u, np.ones((3, 1))])
    ref = math.log(np.linalg.det(np.eye(4) + G.T @ G))
    got = float(o.geometry_measure(jnp.asarray(u), jnp.ones(3, bool)))
    assert got == pytest.approx(ref, rel=1e-13)
    # k = 1: det = 3 for every direction
    m1 = np.array([False, True, False])
    assert float(o.geometry_measure(jnp.asarray(u), jnp.asarray(m1))) == pytest.approx(
        math.log(3.0), rel=1e-14
    )


def test_geometry_policies_pick_spread_and_clustered_sets():
    T = 6
    # equal elevation: the pair angle is set by the azimuth difference
    az_deg = np.array([0.0, 15.0, 100.0, 170.0, 250.0, 300.0])
    el = np.full((T, 6), 30.0 * DEG)
    az = np.tile(az_deg * DEG, (T, 1))
    av = np.ones_like(el, bool)
    out2 = o.Outage(1, 3, 2)
    best = np.flatnonzero(_mask(el, av, out2, "best_geometry", az)[2])
    worst = np.flatnonzero(_mask(el, av, out2, "worst_geometry", az)[2])
    np.testing.assert_array_equal(best, [0, 3])  # 170 deg apart: the only pair within 10 of 180
    np.testing.assert_array_equal(worst, [0, 1])  # 15 deg apart: the closest pair
    # k = 3 at 120 deg spacing (slots 1, 3, 5) beats any set containing the clustered ones
    az3 = np.tile(np.array([5.0, 0.0, 10.0, 120.0, 12.0, 240.0]) * DEG, (T, 1))
    best3 = np.flatnonzero(_mask(el, av, o.Outage(1, 3, 3), "best_geometry", az3)[2])
    np.testing.assert_array_equal(best3, [1, 3, 5])
    worst3 = np.flatnonzero(_mask(el, av, o.Outage(1, 3, 3), "worst_geometry", az3)[2])
    np.testing.assert_array_equal(worst3, [0, 2, 4])  # within 7 deg of each other
    # k = 1: tie on D, broken by elevation (best = highest, worst = lowest above the mask)
    el1 = np.tile(np.array([30.0, 60.0, 8.0, 12.0, 45.0, 20.0]) * DEG, (T, 1))
    b1 = np.flatnonzero(_mask(el1, av, o.Outage(1, 3, 1), "best_geometry", az)[2])
    w1 = np.flatnonzero(_mask(el1, av, o.Outage(1, 3, 1), "worst_geometry", az)[2])
    np.testing.assert_array_equal(b1, [1])
    np.testing.assert_array_equal(w1, [3])


def test_ramp_counts_fall_and_rise_linearly_with_nested_sets():
    T, S = 40, 10
    el, az = _sky(T, S, seed=4)
    av = np.ones((T, S), bool)
    start, length, ramp = 15, 6, 4
    for policy in o.POLICIES:
        keep = _mask(el, av, o.Outage(start, length, 0, ramp), policy, az)
        counts = keep.sum(axis=1)
        # n(r) = k + round((N0 - k) r / (ramp + 1)) = 2 r epochs away from the window
        expected = np.full(T, S)
        expected[start - 4 : start] = [8, 6, 4, 2]
        expected[start : start + length] = 0
        expected[start + length : start + length + 4] = [2, 4, 6, 8]
        np.testing.assert_array_equal(counts, expected)
        for e in range(start - 4, start - 1):  # satellites leave one by one: nested sets
            assert np.all(keep[e] >= keep[e + 1])
        for e in range(start + length, start + length + 3):
            assert np.all(keep[e] <= keep[e + 1])
        np.testing.assert_array_equal(keep[start - 1], keep[start + length])  # same order back
    # with k = 2 the core pair is kept through the whole degraded period
    keep = _mask(el, av, o.Outage(start, length, 2, ramp), "highest", az)
    core = keep[start]
    assert core.sum() == 2
    assert np.all(keep[start - ramp : start + length + ramp][:, core])
    # the highest-2 at the selection epoch (start - ramp), not at the start
    np.testing.assert_array_equal(np.sort(np.argsort(-el[start - ramp])[:2]), np.flatnonzero(core))


def test_no_outage_cases_keep_everything_available():
    T, S = 20, 7
    el, az = _sky(T, S, seed=5)
    av = np.random.default_rng(5).random((T, S)) > 0.2
    for out in (o.Outage(5, 8, o.ALL, 2), o.Outage(5, 0, 1, 2)):
        np.testing.assert_array_equal(_mask(el, av, out, "highest"), av)


def test_vmap_over_1000_outages_equals_python_loop():
    T, S, n = 80, 12, 1000
    el, az = _sky(T, S, seed=6, lo_deg=5.0)
    av = np.random.default_rng(6).random((T, S)) > 0.15
    rng = np.random.default_rng(8)
    batch = o.Outage(
        start=jnp.asarray(rng.integers(0, T, n)),
        length=jnp.asarray(rng.integers(0, 40, n)),
        n_keep=jnp.asarray(rng.integers(-1, 4, n)),
        ramp=jnp.asarray(rng.integers(0, 6, n)),
    )
    keys = jax.random.split(jax.random.key(9), n)
    for policy in o.POLICIES:

        def one(out, key, policy=policy):
            return o.keep_mask(el, av, out, key, policy=policy, azimuth=az)

        masks = np.asarray(jax.jit(jax.vmap(one))(batch, keys))
        assert masks.shape == (n, T, S)
        for i in (0, 1, 137, 500, 999):
            single = np.asarray(one(jax.tree.map(lambda a, i=i: a[i], batch), keys[i]))
            np.testing.assert_array_equal(masks[i], single)
        assert not np.any(masks & ~av[None])


def test_policy_argument_errors():
    el = np.zeros((3, 2))
    av = np.ones((3, 2), bool)
    with pytest.raises(ValueError, match="allowed: highest"):
        o.keep_mask(el, av, o.Outage(0, 1, 1), policy="nearest")
    with pytest.raises(ValueError, match="PRNG key"):
        o.keep_mask(el, av, o.Outage(0, 1, 1), policy="random")
    with pytest.raises(ValueError, match="azimuth"):
        o.keep_mask(el, av, o.Outage(0, 1, 1), policy="best_geometry")


# ---- placements ------------------------------------------------------------------------------
def test_grid_starts():
    s = o.grid_starts(1800, 60, 100, convergence_epochs=300, tail_epochs=120)
    np.testing.assert_array_equal(s, np.arange(300, 1621, 100))
    assert s[-1] + 60 + 120 <= 1800 and s[-1] + 100 + 60 + 120 > 1800


def test_random_starts_spacing_bounds_and_seed():
    kw = dict(min_spacing=90, convergence_epochs=600, tail_epochs=60)
    a = o.random_starts(3600, 60, 25, seed=11, **kw)
    b = o.random_starts(3600, 60, 25, seed=11, **kw)
    c = o.random_starts(3600, 60, 25, seed=12, **kw)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(np.diff(a) >= 90)
    assert a[0] >= 600 and a[-1] + 60 + 60 <= 3600
    # the tightest packing fits exactly; one more epoch of spacing does not
    tight = o.random_starts(1000, 10, 10, seed=0, min_spacing=110)
    np.testing.assert_array_equal(tight, np.arange(0, 991, 110))
    with pytest.raises(ValueError, match="cannot place 10 outages"):
        o.random_starts(1000, 10, 10, seed=0, min_spacing=111)
    # uniform placement of a single outage: mean of starts over many seeds ~ middle
    single = np.array([o.random_starts(200, 10, 1, seed=s)[0] for s in range(3000)])
    assert single.min() == 0 and single.max() == 190
    assert abs(single.mean() - 95.0) < 5 * 55.0 / math.sqrt(3000)


def test_event_starts_overlap_their_events():
    labels = np.full(1000, int(Event.STRAIGHT), np.int8)
    labels[100:130] = Event.TURN  # inside the convergence exclusion: skipped
    labels[300:310] = Event.TURN  # short turn: the 60-s window covers it
    labels[400:600] = Event.STOP  # long stop: the window lies inside it
    labels[620:640] = Event.SLOPE  # its window would start 130 after the stop's
    labels[950:990] = Event.TURN  # window must be shifted left to fit the tail
    events = (Event.TURN, Event.STOP, Event.SLOPE)
    p = o.event_starts(labels, 60, events, min_spacing=150, convergence_epochs=200, tail_epochs=30)
    for s, a, b in zip(p.start, p.event_start, p.event_end, strict=True):
        assert s <= b and s + 60 - 1 >= a  # the window overlaps the event
        assert s >= 200 and s + 60 + 30 <= 1000
    assert np.all(np.diff(p.start) >= 150)
    got = dict(zip(p.event_start.tolist(), p.start.tolist(), strict=True))
    assert got[300] == 305 - 30  # centred on the short turn
    assert got[400] == 500 - 30  # centred in the stop
    assert 620 not in got  # too close to the stop's window
    assert got[950] == 1000 - 30 - 60  # shifted left, still overlapping the turn
    assert p.event[p.event_start == 300][0] == Event.TURN
    # straights are events too; one per kind when asked
    one = o.event_starts(labels, 60, min_spacing=0, convergence_epochs=200, max_per_event=1)
    assert sorted(one.event.tolist()) == sorted(
        {int(Event.TURN), int(Event.STRAIGHT), int(Event.STOP), int(Event.SLOPE)}
    )


def test_outage_grid_shape():
    g = o.outage_grid([10, 20, 30], [10, 60], [0, 1, 2, 3, o.ALL])
    assert g.start.shape == (3, 2, 5, 1)
    assert (
        g.length[1, 1, 2, 0] == 60 and g.n_keep[2, 0, 4, 0] == o.ALL and g.start[2, 0, 0, 0] == 30
    )


# ---- schedule files --------------------------------------------------------------------------
def test_schedule_round_trip(tmp_path):
    path = tmp_path / "sched.csv"
    ids = ["turn1", "stop", "7"]
    start = np.array([0.1 + 0.2, 1234.5, 600.0])  # 0.30000000000000004 must survive
    length = np.array([60.0, 10.0, 1e-3 * 3])
    o.write_schedule(path, ids, start, length)
    assert path.read_text().splitlines()[0] == "id,start_s,length_s"
    s = o.read_schedule(path)
    assert s.id == tuple(ids)
    np.testing.assert_array_equal(s.start_s, start)
    np.testing.assert_array_equal(s.length_s, length)
    with pytest.raises(FileExistsError):
        o.write_schedule(path, ids, start, length)
    o.write_schedule(path, ids[:1], start[:1], length[:1], overwrite=True)
    assert o.read_schedule(path).id == ("turn1",)


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("", r"bad\.csv:1: expected the header line 'id,start_s,length_s', got an empty file"),
        ("id,start,length\n", r"bad\.csv:1: expected the header line"),
        ("id,start_s,length_s\na,10,60\nb,abc,60\n", r"bad\.csv:3: start_s: expected a number"),
        ("id,start_s,length_s\na,10,-5\n", r"bad\.csv:2: length_s: expected a value > 0 s"),
        ("id,start_s,length_s\na,10,0\n", r"bad\.csv:2: length_s: expected a value > 0 s"),
        ("id,start_s,length_s\na,-1,5\n", r"bad\.csv:2: start_s: expected a value >= 0 s"),
        ("id,start_s,length_s\na,nan,5\n", r"bad\.csv:2: start_s: expected a finite number"),
        ("id,start_s,length_s\na,1,5,9\n", r"bad\.csv:2: expected 3 fields"),
        ("id,start_s,length_s\n,1,5\n", r"bad\.csv:2: id: expected a non-empty id"),
        ("id,start_s,length_s,satellites_kept\na,1,5\n", r"bad\.csv:2: expected 4 fields"),
        ("id,start_s,length_s,satellites_kept\na,1,5,-1\n",
         r"bad\.csv:2: satellites_kept: expected a whole number >= 0 of satellites, got '-1'"),
        ("id,start_s,length_s,satellites_kept\na,1,5,1.5\n", r"bad\.csv:2: satellites_kept"),
        ("id,start_s,length_s,kept\n", r"bad\.csv:1: expected the header line"),
        (
            "id,start_s,length_s\n# comment\na,1,5\n\nb,100,5\na,200,5\n",
            r"bad\.csv:6: id: expected unique ids, 'a' already used on line 3",
        ),
    ],
)
def test_schedule_bad_files(tmp_path, text, pattern):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(o.ScheduleError, match=pattern):
        o.read_schedule(path)


def test_schedule_satellites_kept_column(tmp_path):
    path = tmp_path / "kept.csv"
    path.write_text("id,start_s,length_s,satellites_kept\nz,10,15,0\nt,40,15,3\n")
    s = o.read_schedule(path)
    np.testing.assert_array_equal(s.satellites_kept, [0, 3])
    path.write_text("id,start_s,length_s\nz,10,15\n")
    assert o.read_schedule(path).satellites_kept is None  # complete outages


def test_schedule_overlap_and_epochs(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("id,start_s,length_s\na,100,60\nb,150,10\nc,400,30\n")
    assert o.read_schedule(path).id == ("a", "b", "c")  # independent scenarios may overlap
    with pytest.raises(o.ScheduleError, match=r"run\.csv:3: expected non-overlapping.*'b'"):
        o.read_schedule(path, allow_overlap=False)
    start, length = o.schedule_to_epochs(o.read_schedule(path), 0.5)
    np.testing.assert_array_equal(start, [200, 300, 800])
    np.testing.assert_array_equal(length, [120, 20, 60])
    with pytest.raises(ValueError, match="'c' ends at epoch 430"):
        o.schedule_to_epochs(o.read_schedule(path), 1.0, n_epochs=420)
    path.write_text("id,start_s,length_s\na,100.5,60\n")
    with pytest.raises(ValueError, match=r"'a': start_s = 100.5 s is not a whole number"):
        o.schedule_to_epochs(o.read_schedule(path), 1.0)
