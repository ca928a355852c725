"""IMU CSV + RTKLIB time-tag reader, mounting helpers, and the RTKLIB .pos reader/writer."""

from __future__ import annotations

import re
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.gpstime import GTIME_TO_GPS_SECONDS, datetime64_to_gps_seconds
from jaxnav.geodesy import normal_gravity
from jaxnav.io import (
    GPS_EPOCH,
    InputError,
    PosSolution,
    covariance_enu,
    imu_increments,
    read_imu_csv,
    read_pos,
    read_timetag,
    sensor_to_body_dcm,
    write_pos,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DRIVE = DATA / "gnss_imu_drive"
WALK = DATA / "gnss_imu_walk"


def _need(path: Path):
    if not path.exists():
        pytest.skip(f"shared real data not present: {path} (only in the project workspace)")


# ------------------------------------------------------------------------------------------
# Synthetic time-tag + CSV


def _tag_bytes(start_gps_s: float, ticks, fpos, text=b"TIMETAG RTKLIB demo5", tick_f=12345):
    gtime = start_gps_s - GTIME_TO_GPS_SECONDS
    head = text.ljust(60, b"\0") + struct.pack("<I", tick_f)
    head += struct.pack("<Id", int(np.floor(gtime)), gtime - np.floor(gtime))
    body = b"".join(
        struct.pack("<II", int(t) % 2**32, int(p)) for t, p in zip(ticks, fpos, strict=True)
    )
    return head + body


def _synthetic_log(
    tmp_path: Path,
    n=20000,
    rate_hz=100.0,
    clock_ppm=40.0,
    tick0=261_906,
    keep_cr=True,
    seed=0,
    mutate=None,
):
    """IMU log written in chunks with random latency; returns (csv path, true times, meta).

    ``mutate`` edits the list of (line, true time, arrival time) before the log is "written".
    """
    rng = np.random.default_rng(seed)
    start = 1_436_038_461.854  # a GPST (2025-07-08 19:34:21.854)
    t_true = start + 0.05 + np.arange(n) / rate_hz  # sample instants (GPS)
    # device tick: ms counter running (1 + ppm) fast, read-out jitter, uint32 wrap
    dev_ms = tick0 + (t_true - t_true[0]) * 1e3 * (1 + clock_ppm * 1e-6)
    tick = np.floor(dev_ms + rng.uniform(0, 1.0, n)).astype(np.int64)
    acc = rng.normal([0.1, 0.02, 1.0], 0.01, (n, 3))
    gyr = rng.normal([0.2, -0.1, 0.3], 0.05, (n, 3))
    min_latency = 0.003
    arrive = t_true + min_latency + rng.uniform(0, 0.012, n)
    rows = [
        (f"{a[0]:.3f},{a[1]:.3f},{a[2]:.3f},{g[0]:.3f},{g[1]:.3f},{g[2]:.3f},{k % 2**32}", t, r)
        for a, g, k, t, r in zip(acc, gyr, tick, t_true, arrive, strict=True)
    ]
    if mutate is not None:
        rows = mutate(rows)
    lines = [r[0] for r in rows]
    arrive_w = np.array([r[2] for r in rows])
    logged = "".join(line + "\r\n" for line in lines).encode()
    ends = np.cumsum([len(line) + 2 for line in lines])
    # the logger writes every 15.5 ms the complete lines that have arrived
    ticks, fpos = [], []
    complete = np.maximum.accumulate(arrive_w)  # a line is written after all earlier ones
    for tw in np.arange(start + 0.06, arrive_w.max() + 0.03, 0.0155):
        done = np.searchsorted(complete, tw, side="right")
        pos = int(ends[done - 1]) if done else 0
        if pos == (fpos[-1] if fpos else 0):
            continue
        ticks.append(round((tw - start) * 1e3))
        fpos.append(pos)
    csv = tmp_path / "imu.csv"
    csv.write_bytes(logged if keep_cr else logged.replace(b"\r\n", b"\n"))
    (tmp_path / "imu.csv.tag").write_bytes(_tag_bytes(start, ticks, fpos))
    t_kept = np.array([r[1] for r in rows])
    return csv, t_kept, dict(min_latency=min_latency, acc=acc, gyr=gyr, tick=tick)


def test_timetag_header_records_and_wrap(tmp_path):
    start = 1_300_000_000.25
    ticks = [2**32 - 25, 2**32 - 15, 2**32 - 5, 2**32 + 7]  # the host tick wraps (uint32 ms)
    path = tmp_path / "x.tag"
    path.write_bytes(_tag_bytes(start, ticks, [5, 9, 30, 31]))
    tag = read_timetag(path)
    assert tag.header == "TIMETAG RTKLIB demo5"
    assert tag.tick_f_ms == 12345
    assert tag.start_gps_s == pytest.approx(start, abs=1e-6)
    np.testing.assert_array_equal(tag.tick_ms, ticks)
    np.testing.assert_array_equal(tag.file_pos, [5, 9, 30, 31])


def test_timetag_bad_input(tmp_path):
    p = tmp_path / "bad.tag"
    p.write_bytes(b"NOT A TAG" + b"\0" * 100)
    with pytest.raises(InputError, match="not an RTKLIB time-tag file"):
        read_timetag(p)
    good = _tag_bytes(1.3e9, [1, 2, 3], [4, 8, 12])
    p.write_bytes(good + b"\x01\x02\x03")  # partial trailing record: dropped with a warning
    with pytest.warns(UserWarning, match="truncated last time-tag record"):
        assert read_timetag(p).tick_ms.size == 3
    p.write_bytes(_tag_bytes(1.3e9, [1, 2, 3], [4, 12, 8]))
    with pytest.raises(InputError, match="record 2.*position decreases"):
        read_timetag(p)
    p.write_bytes(_tag_bytes(1.3e9, [1, 50, 3], [4, 8, 12]))
    with pytest.raises(InputError, match="goes backwards"):
        read_timetag(p)


@pytest.mark.parametrize("keep_cr", [True, False])
def test_synthetic_imu_time_mapping(tmp_path, keep_cr):
    csv, t_true, meta = _synthetic_log(tmp_path, keep_cr=keep_cr)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        log = read_imu_csv(csv)
    crlf_warned = any("CRLF" in str(w.message) for w in rec)
    assert crlf_warned == (not keep_cr)
    # earliest-arrival envelope = truth + minimum latency; within the 1 ms tick quantisation
    err = log.time_gps_s - (t_true + meta["min_latency"])
    assert np.max(np.abs(err)) < 1.0e-3, np.max(np.abs(err))  # measured 0.3 ms
    assert log.clock_rate == pytest.approx(1.0 / (1 + 40e-6), abs=2e-6)
    assert np.all(np.diff(log.time_gps_s) > 0)
    np.testing.assert_allclose(log.accel_mps2, np.round(meta["acc"], 3) * 9.80665)
    np.testing.assert_allclose(log.gyro_rad_s, np.deg2rad(np.round(meta["gyr"], 3)))
    # smoothing removed the +-1 ms read-out jitter of the tick
    assert np.std(np.diff(log.time_gps_s)) < 1e-5


def test_synthetic_device_tick_wraps(tmp_path):
    # a uint32 ms counter wrapping mid-log (49.7 days of uptime)
    csv, t_true, meta = _synthetic_log(tmp_path, tick0=2**32 - 80_000)
    assert meta["tick"].max() >= 2**32  # the file holds the wrapped values
    log = read_imu_csv(csv)
    assert np.all(np.diff(log.tick_ms) > 0) and log.tick_ms.max() >= 2**32
    assert np.max(np.abs(log.time_gps_s - t_true - meta["min_latency"])) < 1e-3


def _mutated(tmp_path, fn, **kw):
    return _synthetic_log(tmp_path, n=1000, mutate=fn, **kw)[0]


def test_imu_damaged_inputs(tmp_path):
    def truncate_mid(rows):
        rows[200] = (rows[200][0][:15], *rows[200][1:])
        return rows

    with pytest.raises(InputError, match=r"line 201.*malformed IMU record"):
        read_imu_csv(_mutated(tmp_path, truncate_mid))

    def nan_value(rows):
        parts = rows[100][0].split(",")
        parts[4] = "nan"
        rows[100] = (",".join(parts), *rows[100][1:])
        return rows

    with pytest.raises(InputError, match=r"line 101.*non-finite"):
        read_imu_csv(_mutated(tmp_path, nan_value))

    def swap(rows):
        rows[300], rows[301] = rows[301], rows[300]
        return rows

    with pytest.raises(InputError, match=r"line 302.*does not increase"):
        read_imu_csv(_mutated(tmp_path, swap))

    def duplicate(rows):
        return rows[:250] + [rows[249]] + rows[250:]

    with pytest.warns(UserWarning, match="dropping 1 duplicated line"):
        log = read_imu_csv(_mutated(tmp_path, duplicate))
    assert log.tick_ms.size == 1000

    def partial_ends(rows):
        first, last = rows[0], rows[-1]
        return [(first[0][8:], *first[1:])] + rows[1:-1] + [(last[0][:20], *last[1:])]

    with pytest.warns(UserWarning) as rec:
        log = read_imu_csv(_mutated(tmp_path, partial_ends))
    msgs = " ".join(str(w.message) for w in rec)
    assert "incomplete first line" in msgs and "incomplete last line" in msgs
    assert log.tick_ms.size == 998 and log.line[0] == 2

    def gap(rows):
        return rows[:100] + rows[150:]

    with pytest.warns(UserWarning, match="sampling gap"):
        log = read_imu_csv(_mutated(tmp_path, gap))
    d = np.diff(log.time_gps_s)
    assert d.max() == pytest.approx(0.51, abs=2e-3)  # the gap keeps its true length

    csv = _mutated(tmp_path, None)
    (tmp_path / "imu.csv.tag").unlink()
    with pytest.raises(InputError, match="time-tag file .* not found"):
        read_imu_csv(csv)


def test_imu_values_beyond_full_scale_and_tick_spikes_are_refused(tmp_path):
    """Issue 23: 1e300 g, 5000 deg/s and one tick set to 0xFFFFFFF0 (which looked like a counter
    wrap and moved every later sample by 2^32 ms) are refused with their line."""

    def field(k, value):
        def edit(rows):
            parts = rows[100][0].split(",")
            parts[k] = value
            rows[100] = (",".join(parts), *rows[100][1:])
            return rows

        return edit

    for k, value, why in (
        (1, "1e300", "acceleration"),
        (5, "-5000", "angular rate"),
        (6, str(0xFFFFFFF0), "tick jumps forward"),
    ):
        with pytest.raises(InputError, match=rf"line 101: {why}"):
            read_imu_csv(_mutated(tmp_path, field(k, value)))
    p = tmp_path / "spike.tag"
    p.write_bytes(_tag_bytes(1.3e9, [10, 20, 0xFFFFFFF0, 40, 50], [4, 8, 12, 16, 20]))
    with pytest.raises(InputError, match=r"record 2: time-tag tick jumps forward"):
        read_timetag(p)


def test_sensor_to_body_dcm_closed_forms():
    c = sensor_to_body_dcm(180.0, 0.0, 180.0)
    # (180, 0, 180) in Groves' FRD convention: x_frd = (-x_s, y_s, -z_s); RFU = (y_s, -x_s, z_s)
    np.testing.assert_allclose(c, [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-15)
    for rpy in [(10.0, -6.79, 5.35), (180.0, -6.79, 185.35), (-30.0, 45.0, 100.0)]:
        c = sensor_to_body_dcm(*rpy)
        np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(c) == pytest.approx(1.0)
    # a pure yaw of +90 deg: x_frd = R3(90) x_s = (y_s, -x_s, z_s): sensor y is body forward
    c = sensor_to_body_dcm(0.0, 0.0, 90.0)
    np.testing.assert_allclose(c @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(c @ [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], atol=1e-15)


def test_imu_increments_closed_form():
    from jaxnav.io import ImuLog

    t = 100.0 + np.cumsum(np.r_[0.0, np.full(9, 0.01)])
    w = np.tile([0.1, -0.2, 0.3], (10, 1))
    f = np.tile([0.0, 0.0, 9.8], (10, 1))
    w[:, 2] += 0.5 * (t - t[0])  # a ramp: the trapezoid integrates it exactly
    log = ImuLog(t, f, w, np.arange(10), t, np.arange(10), 1.0, 0.0)
    inc = imu_increments(log, sensor_to_body_dcm(180.0, 0.0, 180.0))
    assert inc.dtheta_b.shape == (9, 3)
    dt = np.diff(t)
    # RFU = (y_s, -x_s, z_s)
    np.testing.assert_allclose(inc.dtheta_b[:, 0], -0.2 * dt, rtol=1e-12)
    np.testing.assert_allclose(inc.dtheta_b[:, 1], -0.1 * dt, rtol=1e-12)
    exact_z = 0.3 * dt + 0.25 * ((t[1:] - t[0]) ** 2 - (t[:-1] - t[0]) ** 2)
    np.testing.assert_allclose(inc.dtheta_b[:, 2], exact_z, rtol=1e-12)
    np.testing.assert_allclose(inc.dv_b[:, 2], 9.8 * dt, rtol=1e-12)
    np.testing.assert_allclose(inc.time_gps_s, t[1:])


# ------------------------------------------------------------------------------------------
# Real data: the drive and the walk


@pytest.fixture(scope="module")
def drive():
    _need(DRIVE / "imu_1934.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the CRLF->LF note
        log = read_imu_csv(DRIVE / "imu_1934.csv")
    sol = read_pos(DRIVE / "gnss_1934_sf.pos")
    return log, sol


def test_drive_pos_file(drive):
    _, sol = drive
    assert sol.time_gps_s.size == 2197
    assert int(np.sum(sol.q == 1)) == 2189
    assert sol.has_velocity
    np.testing.assert_allclose(np.diff(sol.time_gps_s), 0.25, atol=1e-9)  # 4 Hz
    assert np.rad2deg(sol.llh[0, 0]) == pytest.approx(40.0966268)
    assert np.rad2deg(sol.llh[0, 1]) == pytest.approx(-105.1474483)
    # first epoch 2025/07/08 19:34:18.499 GPST
    t0 = datetime64_to_gps_seconds(np.datetime64("2025-07-08T19:34:18.499"))
    assert sol.time_gps_s[0] == pytest.approx(t0, abs=1e-6)
    # fixed RTK: cm-level sigmas
    assert np.median(sol.sd_neu_m[sol.q == 1]) < 0.02


def test_drive_imu_at_rest_and_timing(drive):
    log, sol = drive
    n = log.time_gps_s.size
    assert n == 54860
    dt = np.diff(log.time_gps_s)
    assert np.all(dt > 0)  # the tick -> GPS mapping is monotonic
    assert np.median(dt) == pytest.approx(0.010, abs=1e-4)  # ~100 Hz
    assert np.all(np.diff(log.arrival_gps_s[np.isfinite(log.arrival_gps_s)]) >= 0)
    assert abs(log.clock_rate - 1.0) < 1e-4  # measured: 13 ppm
    assert log.latency_spread_s < 0.03  # tag jitter (measured 17 ms)
    # both logs started within seconds of each other in GPST (a UTC/leap-second slip = 18 s)
    assert abs(log.time_gps_s[0] - sol.time_gps_s[0]) < 10.0
    assert log.time_gps_s[-1] == pytest.approx(sol.time_gps_s[-1], abs=10.0)
    # at rest (RTK speed < 5 cm/s over the first seconds): |f| ~ 1 g, small gyro
    speed = np.linalg.norm(sol.vel_enu[:, :2], axis=1)
    t_rest_end = sol.time_gps_s[np.argmax(speed > 0.05)]
    rest = log.time_gps_s < t_rest_end - 0.5
    assert rest.sum() > 100
    g_local = float(normal_gravity(sol.llh[0, 0], sol.llh[0, 2]))
    f_mean = np.linalg.norm(log.accel_mps2[rest].mean(axis=0))
    assert f_mean == pytest.approx(g_local, rel=0.03)  # measured 1.013 g
    # gyro bias at rest: a few tenths in file units; read as deg/s that is a MEMS-typical
    # 0.2 deg/s, read as rad/s it would be 11 deg/s, beyond consumer gyro specs (~0.5-3 deg/s)
    bias_deg_s = np.rad2deg(np.linalg.norm(log.gyro_rad_s[rest].mean(axis=0)))
    assert 0.01 < bias_deg_s < 1.0


def test_drive_gyro_unit_and_latency(drive):
    """Vertical gyro (body up) vs -d(heading)/dt of the RTK track: slope 1 in deg/s."""
    log, sol = drive
    # mounting from the source configuration: (180, 0, 180) + misalignment (0, -6.79, 5.35)
    c_s_b = sensor_to_body_dcm(180.0 + 0.0, 0.0 - 6.79, 180.0 + 5.35)
    w_up = (log.gyro_rad_s @ c_s_b.T)[:, 2]
    ve, vn = sol.vel_enu[:, 0], sol.vel_enu[:, 1]
    t = sol.time_gps_s
    heading_rate = np.gradient(np.unwrap(np.arctan2(ve, vn)), t)
    moving = (np.hypot(ve, vn) > 3.0) & (t > log.time_gps_s[0] + 1) & (t < log.time_gps_s[-1] - 1)
    x = -heading_rate[moving]  # counter-clockwise about up
    best = None
    for lag in np.arange(-0.40, 0.21, 0.01):
        y = np.interp(t[moving], log.time_gps_s + lag, w_up)
        r = np.corrcoef(x, y)[0, 1]
        if best is None or r > best[0]:
            best = (r, lag, (x @ y) / (x @ x))
    r, lag, slope = best
    print(f"gyro vs heading rate: corr {r:.4f}, slope {slope:.4f}, best time offset {lag:+.2f} s")
    assert r > 0.99
    assert slope == pytest.approx(1.0, abs=0.02)  # deg/s; rad/s would give 0.017
    assert -0.25 < lag < 0.0  # the fixed latency: ~-0.12 s (source config: -0.125 s)


def test_walk_partial_first_and_last_lines():
    _need(WALK / "imu_1730.csv")
    with pytest.warns(UserWarning) as rec:
        log = read_imu_csv(WALK / "imu_1730.csv")
    msgs = " ".join(str(w.message) for w in rec)
    assert "incomplete first line" in msgs and "incomplete last line" in msgs
    assert log.line[0] == 2 and log.time_gps_s.size == 20455
    assert np.all(np.diff(log.time_gps_s) > 0)
    sol = read_pos(WALK / "gnss_1730_sf.pos")
    assert abs(log.time_gps_s[0] - sol.time_gps_s[0]) < 10.0


# ------------------------------------------------------------------------------------------
# .pos writer / reader


def _fields_close(a: PosSolution, b: PosSolution):
    np.testing.assert_allclose(a.time_gps_s, b.time_gps_s, atol=5e-4)
    np.testing.assert_allclose(np.rad2deg(a.llh[:, :2]), np.rad2deg(b.llh[:, :2]), atol=6e-10)
    np.testing.assert_allclose(a.llh[:, 2], b.llh[:, 2], atol=6e-5)
    np.testing.assert_array_equal(a.ns, b.ns)
    np.testing.assert_allclose(a.sd_neu_m, b.sd_neu_m, atol=6e-5)
    np.testing.assert_allclose(a.sd_cross_m, b.sd_cross_m, atol=6e-5)
    np.testing.assert_allclose(a.age_s, b.age_s, atol=6e-3)
    np.testing.assert_allclose(a.ratio, b.ratio, atol=6e-2)
    np.testing.assert_allclose(a.vel_enu, b.vel_enu, atol=6e-6)
    np.testing.assert_allclose(a.sd_vel_neu, b.sd_vel_neu, atol=6e-6)


def _synthetic_solution(n=50, vel=True, seed=3):
    rng = np.random.default_rng(seed)
    t = datetime64_to_gps_seconds(np.datetime64("2020-06-25T23:59:50")) + 0.25 * np.arange(n)
    llh = np.c_[
        np.deg2rad(55.0 + rng.normal(0, 1e-4, n)),
        np.deg2rad(-12.0 + rng.normal(0, 1e-4, n)),
        40.0 + rng.normal(0, 1, n),
    ]
    nan3 = np.full((n, 3), np.nan)
    return PosSolution(
        t,
        llh,
        rng.integers(1, 6, n),
        rng.integers(4, 30, n),
        rng.uniform(0.001, 2, (n, 3)),
        rng.uniform(-0.5, 0.5, (n, 3)),
        rng.uniform(0, 5, n),
        rng.uniform(0, 50, n),
        rng.normal(0, 10, (n, 3)) if vel else nan3,
        rng.uniform(0, 1, (n, 3)) if vel else nan3,
        rng.uniform(-0.1, 0.1, (n, 3)) if vel else nan3,
    )


@pytest.mark.parametrize("vel", [True, False])
def test_pos_roundtrip_and_outage_flag(tmp_path, vel):
    sol = _synthetic_solution(vel=vel)
    outage = np.zeros(sol.q.size, bool)
    outage[10:20] = True
    path = tmp_path / "out.pos"
    write_pos(path, sol, outage=outage, comments=("test run",))
    back = read_pos(path)
    _fields_close(sol, back)
    np.testing.assert_array_equal(back.outage, outage)
    np.testing.assert_array_equal(back.q[~outage], sol.q[~outage])
    assert back.has_velocity == vel
    text = path.read_text().splitlines()
    n_head = next(i for i, line in enumerate(text) if not line.startswith("%"))
    assert n_head == 7 and text[n_head - 1].startswith("%  GPST")
    # RTKPOST's obs start / end lines: calendar time, GPS week and time of week (2020-06-25
    # is a Thursday of week 2111)
    assert text[1] == "% obs start : 2020/06/25 23:59:50.000 GPST (week2111 431990.000s)"
    assert text[2].startswith("% obs end   : 2020/06/26 ")
    # RTKLIB parses fixed fields: date, time, then whitespace-separated numbers
    first = text[n_head].split()
    assert first[0] == "2020/06/25" and first[1] == "23:59:50.000"
    assert len(first) == 2 + 13 + (9 if vel else 0)
    # across midnight the calendar rolls over
    assert text[n_head + 41].split()[:2] == ["2020/06/26", "00:00:00.250"]


def test_pos_real_file_roundtrip(tmp_path):
    _need(DRIVE / "gnss_1934_sf.pos")
    sol = read_pos(DRIVE / "gnss_1934_sf.pos")
    write_pos(tmp_path / "copy.pos", sol)
    _fields_close(sol, read_pos(tmp_path / "copy.pos"))


def test_pos_covariance_from_signed_roots():
    cov = covariance_enu([[2.0, 3.0, 4.0]], [[-1.0, 0.5, 2.0]])[0]
    # E, N, U order: var_e = sde^2, var_n = sdn^2, cov_ne = sign(sdne) sdne^2
    np.testing.assert_allclose(
        cov, [[9.0, -1.0, 0.25], [-1.0, 4.0, 4.0], [0.25, 4.0, 16.0]], atol=1e-15
    )


def test_pos_week_tow_and_utc(tmp_path):
    p = tmp_path / "w.pos"
    head = "%  GPST          latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n"  # noqa: E501
    row = "2111 345600.000   55.000000000  -12.000000000    40.0000   5   8   1.0000   1.0000   1.0000   0.0000   0.0000   0.0000   0.00    0.0\n"  # noqa: E501
    p.write_text(head + row)
    sol = read_pos(p)
    assert sol.time_gps_s[0] == 2111 * 604800.0 + 345600.0
    assert sol.time_gps_s[0] == datetime64_to_gps_seconds(np.datetime64("2020-06-25"))
    p.write_text(head.replace("GPST", "UTC ") + row)
    with pytest.raises(InputError, match="time system 'UTC'"):
        read_pos(p)
    assert read_pos(p, leap_seconds=18).time_gps_s[0] == sol.time_gps_s[0] + 18


def test_pos_damaged_inputs(tmp_path):
    src = _synthetic_solution(n=20)
    good = tmp_path / "good.pos"
    write_pos(good, src)
    lines = good.read_text().splitlines()
    n_head = sum(line.startswith("%") for line in lines)

    def damaged(fn):
        p = tmp_path / "bad.pos"
        p.write_text("\n".join(fn(list(lines))) + "\n")
        return p

    with pytest.raises(InputError, match="line 1.*missing column-header line"):
        read_pos(damaged(lambda ls: [x for x in ls if not x.startswith("%  GPST")]))
    trunc = n_head + 5
    with pytest.raises(InputError, match=rf"line {trunc + 1}: \d+ fields"):
        read_pos(damaged(lambda ls: ls[:trunc] + [ls[trunc][:70]] + ls[trunc + 1 :]))

    def nan_row(ls):
        parts = ls[n_head + 3].split()
        parts[4] = "nan"
        ls[n_head + 3] = " ".join(parts)
        return ls

    with pytest.raises(InputError, match=f"line {n_head + 4}: non-finite"):
        read_pos(damaged(nan_row))

    def swap(ls):
        ls[n_head + 7], ls[n_head + 8] = ls[n_head + 8], ls[n_head + 7]
        return ls

    with pytest.raises(InputError, match=f"line {n_head + 9}.*epoch.*strictly increasing"):
        read_pos(damaged(swap))
    with pytest.warns(UserWarning, match="dropping 1 repeated epoch"):
        back = read_pos(damaged(lambda ls: ls[: n_head + 4] + ls[n_head + 3 :]))
    assert back.time_gps_s.size == 20

    def ecef(ls):
        ls[n_head - 1] = ls[n_head - 1].replace(
            "latitude(deg) longitude(deg)", "x-ecef(m) y-ecef(m)"
        )
        return ls

    with pytest.raises(InputError, match="unsupported position format"):
        read_pos(damaged(ecef))


@pytest.mark.parametrize(
    ("field", "value", "why"),
    [
        (4, "2e5", "height"),  # fields after the two time fields: lat, lon, height, Q, ns...
        (5, "9", "quality flag Q"),
        (6, "-3", "number of satellites"),
        (8, "-0.5", "sdn/sde/sdu"),
        (16, "600", "velocity"),  # ve above the CoCom limit
        (19, "-1e300", "sdvn/sdve/sdvu"),
    ],
)
def test_pos_values_no_receiver_writes_are_refused(tmp_path, field, value, why):
    """Issue 23: a negative sigma, an impossible height, speed, Q or satellite count."""
    p = tmp_path / "x.pos"
    write_pos(p, _synthetic_solution(n=10))
    lines = p.read_text().splitlines()
    k = sum(line.startswith("%") for line in lines) + 4
    parts = lines[k].split()
    parts[field] = value
    lines[k] = " ".join(parts)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"line {k + 1}: {re.escape(why)}.*out of range"):
        read_pos(p)


def test_gps_epoch_constant():
    assert GPS_EPOCH == np.datetime64("1980-01-06T00:00:00")
    # RTKLIB gtime_t (1970 origin on GPST) vs GPS seconds: 3657 days
    assert GTIME_TO_GPS_SECONDS == -3657 * 86400.0
