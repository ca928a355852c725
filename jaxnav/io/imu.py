"""IMU CSV logs with RTKLIB time-tag files -> GPS-timed accelerometer and gyro samples.

Input format (rtklibexplorer GNSS_IMU data sets, one sample per line, no header):
``acc_x, acc_y, acc_z`` [g], ``gyro_x, gyro_y, gyro_z`` [deg/s by default], ``tick`` [ms of the
logging device's free-running millisecond counter]. The companion ``<file>.tag`` written by
RTKLIB's file stream (stream.c, ``openfile_``/``writefile``) holds a 64-byte header (60 bytes of
text "TIMETAG RTKLIB ..." + uint32 host tick at file open, ``tick_f``), the GPST at file open
(uint32 seconds since 1970 on the GPST scale + float64 fraction), then one record per write to
the data file: (uint32 ms since file open, uint32 data-file byte position *after* the write),
all little-endian.

Gyro unit, evidence (drive and walk data sets): at rest the gyro magnitudes are 0.1-0.3 units,
the source's own converter applies ``np.deg2rad`` to them, and the integrated vertical rate of the
moving car matches the heading rate of the RTK track with slope 0.996 in deg/s (see
``tests/test_io_imu_pos.py::test_drive_gyro_unit_and_latency``); read as rad/s it would be 57x
too large. Hence ``gyro_unit="deg/s"`` is the default.

Time mapping (documented choice; the sources are silent): each line's *arrival* time is the
time-tag record of the write that contained its last byte; the device tick is mapped to GPS time
by the *earliest-arrival* line: the least-squares line of (tick, arrival) after 5-MAD outlier
rejection (its slope is the device clock rate), lowered to touch the earliest inlier arrival
(a line cannot reach the disk before it was sampled). It is sample time + the minimum transport
latency. The remaining fixed latency (sensor filter group delay, serial buffering) is not
observable from the tag and is applied through ``time_offset_s``. On the drive data set,
cross-correlating the vertical gyro with the heading rate of the RTK track puts the best offset
at -0.10 to -0.14 s for this mapping (test_drive_gyro_unit_and_latency), consistent with the
-0.125 s the source's configuration uses.
No mounting rotation is applied by the reader; ``sensor_to_body_dcm`` and ``imu_increments``
do that separately.
"""

from __future__ import annotations

import struct
import warnings
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav.core.gpstime import GTIME_TO_GPS_SECONDS
from jaxnav.io.errors import InputError

# Conventional standard gravity (3rd CGPM, 1901): MEMS datasheets quote accelerations in this g.
STANDARD_GRAVITY = 9.80665
_TAG_TEXT_LEN = 60  # RTKLIB TIMETAGH_LEN (64) minus the trailing uint32 tick_f
_TAG_HEADER_LEN = 64 + 4 + 8  # text + tick_f, uint32 time, float64 sec
_N_FIELDS = 7
_FIELDS = "acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z,tick_ms"
_GYRO_UNITS = {"deg/s": np.pi / 180.0, "rad/s": 1.0}
_ACCEL_UNITS = ("g", "m/s^2")
# Device clocks are quartz or RC oscillators: a tick-rate error beyond 0.1 % means the tick is
# not in ms or the tag belongs to another file (chosen bound; the drive log shows 13 ppm).
_MAX_CLOCK_RATE_ERROR = 1e-3
# Full-scale ranges of vehicle IMUs: MEMS parts +-2..16 g and +-125..2000 deg/s, tactical units
# up to +-50 g. A reading past 100 g or 4000 deg/s is damage, not motion (chosen bounds, twice
# the widest full scale).
_MAX_ACCEL_G = 100.0
_MAX_GYRO_DEG_S = 4000.0
# A sample interval longer than this multiple of the median interval is reported as a gap.
_GAP_FACTOR = 1.5


class TimeTag(NamedTuple):
    """Contents of an RTKLIB ``.tag`` file (times in GPS seconds, see jaxnav.io.errors)."""

    header: str  # header text, e.g. "TIMETAG RTKLIB demo5"
    tick_f_ms: int  # host tick at file open (ms), used by RTKLIB to sync several streams
    start_gps_s: float  # GPST at file open
    tick_ms: np.ndarray  # [M] int64 ms since file open (uint32 wrap undone)
    file_pos: np.ndarray  # [M] int64 data-file byte position after each write


class ImuLog(NamedTuple):
    """IMU samples in the raw sensor axes (no mounting rotation), SI units, GPS time."""

    time_gps_s: np.ndarray  # [N] sample times (tick fit + time_offset_s)
    accel_mps2: np.ndarray  # [N, 3] specific force, sensor axes
    gyro_rad_s: np.ndarray  # [N, 3] angular rate, sensor axes
    tick_ms: np.ndarray  # [N] device tick as read (int64, wrap undone)
    arrival_gps_s: np.ndarray  # [N] GPST the line reached the disk (NaN after the last tag)
    line: np.ndarray  # [N] 1-based line numbers in the CSV
    clock_rate: float  # fitted d(GPS s)/d(device s)
    latency_spread_s: float  # 99.5 % quantile of the arrival delay above the envelope


class ImuIncrements(NamedTuple):
    """Shared IMU contract: sample k covers (t[k-1], t[k]]; integrals of w_ib^b and f^b."""

    time_gps_s: np.ndarray  # [N-1] end time t_k of each interval
    dt_s: np.ndarray  # [N-1] t_k - t_{k-1}
    dtheta_b: np.ndarray  # [N-1, 3] rad, body right-forward-up
    dv_b: np.ndarray  # [N-1, 3] m/s, body right-forward-up


def read_timetag(path: str | PathLike, *, fpos_bytes: int = 4) -> TimeTag:
    """Read an RTKLIB time-tag file; t_record = t_open + tick_ms / 1000 (stream.c, readfile)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read time-tag file: {exc}", file=path) from exc
    if len(raw) < _TAG_HEADER_LEN or not raw.startswith(b"TIMETAG RTKLIB"):
        raise InputError(
            "not an RTKLIB time-tag file",
            file=path,
            record=0,
            expected=f'a {_TAG_HEADER_LEN}-byte header starting with "TIMETAG RTKLIB"',
        )
    if fpos_bytes not in (4, 8):
        raise ValueError("fpos_bytes must be 4 or 8 (RTKLIB option ::P=4 or ::P=8)")
    header = raw[:_TAG_TEXT_LEN].split(b"\0", 1)[0].decode("ascii", "replace")
    (tick_f,) = struct.unpack_from("<I", raw, _TAG_TEXT_LEN)
    time_s, time_frac = struct.unpack_from("<Id", raw, 64)
    if not 0.0 <= time_frac < 1.0:
        raise InputError(
            f"header time fraction {time_frac!r} out of range",
            file=path,
            record=0,
            expected="a fraction of a second in [0, 1)",
        )
    start = time_s + GTIME_TO_GPS_SECONDS + time_frac
    body = raw[_TAG_HEADER_LEN:]
    rec_len = 4 + fpos_bytes
    n_rec, rest = divmod(len(body), rec_len)
    if rest:
        # A logger killed mid-write leaves a partial last record: drop it (documented repair).
        warnings.warn(
            f"{path}: dropping a truncated last time-tag record ({rest} of {rec_len} bytes)",
            stacklevel=2,
        )
    if n_rec == 0:
        raise InputError("no time-tag records", file=path, expected="at least one record")
    dtype = np.dtype([("tick", "<u4"), ("fpos", "<u4" if fpos_bytes == 4 else "<u8")])
    rec = np.frombuffer(body[: n_rec * rec_len], dtype=dtype)
    tick = _unwrap_uint32(rec["tick"].astype(np.int64), path, "time-tag tick")
    fpos = rec["fpos"].astype(np.int64)
    bad = np.flatnonzero(np.diff(fpos) < 0)
    if bad.size:
        raise InputError(
            "data-file position decreases",
            file=path,
            record=int(bad[0]) + 1,
            expected="non-decreasing byte positions",
        )
    return TimeTag(header, int(tick_f), float(start), tick, fpos)


def _unwrap_counter(tick: np.ndarray, modulus: int) -> tuple[np.ndarray, int | None]:
    """Undo counter wrap-around: a step below -modulus/2 is a wrap.

    Returns the unwrapped ticks and the index of the first tick after an impossible forward jump
    (more than modulus/2, i.e. 24.8 days for a uint32 ms counter), or None. One damaged tick near
    the top of the range (0xFFFFFFF0) would otherwise look like a wrap and shift every later
    record by a whole modulus.
    """
    d = np.diff(tick)
    out = tick + modulus * np.concatenate([[0], np.cumsum(d < -modulus // 2)])
    jump = np.flatnonzero(np.diff(out) > modulus // 2)
    return out, (int(jump[0]) + 1 if jump.size else None)


def _unwrap_uint32(tick: np.ndarray, path, what: str, modulus: int = 2**32) -> np.ndarray:
    """Undo counter wrap-around (see ``_unwrap_counter``); decreases and jumps are errors."""
    out, jump = _unwrap_counter(tick, modulus)
    if jump is not None:
        raise InputError(
            f"{what} jumps forward by {int(out[jump] - out[jump - 1])} ({int(tick[jump - 1])} "
            f"-> {int(tick[jump])})",
            file=path,
            record=jump,
            expected=f"steps shorter than half the counter's range ({modulus // 2})",
        )
    bad = np.flatnonzero(np.diff(out) < 0)
    if bad.size:
        raise InputError(
            f"{what} goes backwards ({int(out[bad[0]])} -> {int(out[bad[0] + 1])})",
            file=path,
            record=int(bad[0]) + 1,
            expected="non-decreasing ticks",
        )
    return out


def _parse_lines(path: Path, raw: bytes):
    """Split the CSV into numeric rows; returns (values [N,7], line numbers, end byte offsets)."""
    chunks = raw.split(b"\n")
    nonblank = [i for i, c in enumerate(chunks) if c.strip()]
    if not nonblank:
        raise InputError("empty IMU file", file=path, expected="an IMU log")
    first_i, last_i = nonblank[0], nonblank[-1]
    rows, lines, ends = [], [], []
    offset = 0
    for i, chunk in enumerate(chunks):
        offset += len(chunk) + (1 if i < len(chunks) - 1 else 0)
        text = chunk.strip()
        if not text:
            continue
        parts = text.split(b",")
        values = None
        if len(parts) == _N_FIELDS:
            try:
                values = [float(p) for p in parts]
            except ValueError:
                values = None
        if values is None:
            if i in (first_i, last_i):
                # Logging started or stopped mid-line: the partial first/last line is dropped
                # (documented repair); a non-numeric first line is treated as a column header.
                where = "first" if i == first_i else "last"
                warnings.warn(
                    f"{path}: line {i + 1}: dropping incomplete {where} line {text[:60]!r}",
                    stacklevel=3,
                )
                continue
            raise InputError(
                f"malformed IMU record {text[:80]!r}",
                file=path,
                line=i + 1,
                expected=f"{_N_FIELDS} comma-separated numbers {_FIELDS}",
            )
        if not all(np.isfinite(values)):
            raise InputError(
                "non-finite value in IMU record",
                file=path,
                line=i + 1,
                expected="finite numbers",
            )
        rows.append(values)
        lines.append(i + 1)
        ends.append(offset)
    if len(rows) < 2:
        raise InputError("fewer than two IMU records", file=path, expected="an IMU log")
    return np.asarray(rows), np.asarray(lines), np.asarray(ends, dtype=np.int64)


def _line_end_offsets_for_tag(path, raw, ends, lines, tag: TimeTag):
    """Byte offsets of line ends in the file *as logged*.

    Files moved through git or text-mode copies may have lost their CR of CRLF line ends; the
    tag positions then run ahead by one byte per line. Pick the hypothesis (as stored, or one CR
    per line restored) under which more tag positions fall exactly on line ends.
    """
    if b"\r" in raw:
        return ends
    crlf = ends + lines  # line number k (1-based) has k newlines up to and including it
    tag_pos = tag.file_pos
    hits_lf = np.isin(tag_pos, ends).mean()
    hits_crlf = np.isin(tag_pos, crlf).mean()
    if hits_crlf > hits_lf:
        warnings.warn(
            f"{path}: time-tag positions match CRLF line ends ({hits_crlf:.0%} vs {hits_lf:.0%} "
            "for LF); the file was logged with CRLF and converted to LF, correcting offsets",
            stacklevel=3,
        )
        return crlf
    return ends


def _smooth_ticks(tick: np.ndarray) -> np.ndarray:
    """Replace ms-quantised, jittery ticks by a straight line over the sample index.

    Within a gap-free segment a fixed-rate sensor's samples are equally spaced; the device tick
    adds read-out jitter (drive log: 0.54 ms rms, 8-11 ms steps at 100 Hz). A segment is only
    smoothed if the line fits within half a median interval (no hidden dropped sample).
    """
    t = tick.astype(np.float64)
    d = np.diff(t)
    med = np.median(d)
    cuts = np.flatnonzero(d > _GAP_FACTOR * med) + 1
    out = t.copy()
    for seg in np.split(np.arange(t.size), cuts):
        if seg.size < 3:
            continue
        k = seg - seg[0]
        coef = np.polyfit(k, t[seg], 1)
        fit = np.polyval(coef, k)
        if np.max(np.abs(fit - t[seg])) < 0.5 * med:
            out[seg] = fit
    return out


def read_imu_csv(
    path: str | PathLike,
    tag_path: str | PathLike | None = None,
    *,
    gyro_unit: str = "deg/s",
    accel_unit: str = "g",
    g0: float = STANDARD_GRAVITY,
    time_offset_s: float = 0.0,
    tick_modulus: int = 2**32,
    smooth_ticks: bool = True,
    fpos_bytes: int = 4,
) -> ImuLog:
    """Read an IMU CSV + RTKLIB tag: t_gps(tick) = t_open + a + b (tick - tick_0)/1000 + offset.

    ``a, b`` fit the tag arrival times (earliest-arrival envelope, see module docstring), and
    ``latency_spread_s`` is the 99.5 % quantile of the arrival delay above that envelope;
    ``tick_modulus`` undoes device-counter wrap (2**32 ms = 49.7 days for a uint32 ms counter);
    ``time_offset_s`` is added to every time (the unobservable fixed latency; about -0.12 s for
    the drive data set, see the module docstring).
    Duplicate lines (same tick and values) are dropped with a warning; ticks that go backwards
    raise ``InputError``; gaps (> 1.5 median intervals) warn and keep their true times.
    """
    path = Path(path)
    tag_path = Path(str(path) + ".tag") if tag_path is None else Path(tag_path)
    if gyro_unit not in _GYRO_UNITS:
        raise ValueError(f"gyro_unit must be one of {sorted(_GYRO_UNITS)}")
    if accel_unit not in _ACCEL_UNITS:
        raise ValueError(f"accel_unit must be one of {sorted(_ACCEL_UNITS)}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read IMU file: {exc}", file=path) from exc
    if not tag_path.exists():
        raise InputError(
            f"time-tag file {tag_path} not found",
            file=path,
            expected="the RTKLIB .tag file written alongside the log (pass tag_path=)",
        )
    tag = read_timetag(tag_path, fpos_bytes=fpos_bytes)

    values, lines, ends = _parse_lines(path, raw)
    limits = (
        _MAX_ACCEL_G * (1.0 if accel_unit == "g" else g0),
        _MAX_GYRO_DEG_S * np.pi / 180.0 / _GYRO_UNITS[gyro_unit],
    )
    for cols, limit, what, unit in (
        (slice(0, 3), limits[0], "acceleration", accel_unit),
        (slice(3, 6), limits[1], "angular rate", gyro_unit),
    ):
        over = np.any(np.abs(values[:, cols]) > limit, axis=1)
        if over.any():
            k = int(np.flatnonzero(over)[0])
            raise InputError(
                f"{what} {values[k, cols].tolist()} {unit} beyond any IMU's full scale",
                file=path,
                line=int(lines[k]),
                expected=f"|{what}| <= {limit:g} {unit} per axis",
            )
    tick_raw = values[:, 6]
    if np.any(tick_raw != np.round(tick_raw)) or np.any(tick_raw < 0):
        k = int(np.flatnonzero((tick_raw != np.round(tick_raw)) | (tick_raw < 0))[0])
        raise InputError(
            f"tick {tick_raw[k]!r} is not a non-negative integer",
            file=path,
            line=int(lines[k]),
            expected="an integer millisecond tick",
        )
    # Undo the device counter wrap (a large negative step); then check ordering.
    tick, jump = _unwrap_counter(tick_raw.astype(np.int64), tick_modulus)
    if jump is not None:
        raise InputError(
            f"tick jumps forward by {int(tick[jump] - tick[jump - 1])} ms",
            file=path,
            line=int(lines[jump]),
            expected=f"steps shorter than half the counter's range ({tick_modulus // 2} ms)",
        )
    d = np.diff(tick)
    dup = np.flatnonzero((d == 0) & np.all(values[1:, :6] == values[:-1, :6], axis=1)) + 1
    if dup.size:
        warnings.warn(
            f"{path}: dropping {dup.size} duplicated line(s), first at line {int(lines[dup[0]])}",
            stacklevel=2,
        )
        keep = np.ones(tick.size, bool)
        keep[dup] = False
        values, lines, ends, tick = values[keep], lines[keep], ends[keep], tick[keep]
        d = np.diff(tick)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"tick {int(tick[k])} does not increase after {int(tick[k - 1])}",
            file=path,
            line=int(lines[k]),
            expected="strictly increasing millisecond ticks (out-of-order or repeated sample)",
        )
    med = float(np.median(d))
    gaps = np.flatnonzero(d > _GAP_FACTOR * med)
    if gaps.size:
        k = int(gaps[0]) + 1
        warnings.warn(
            f"{path}: {gaps.size} sampling gap(s) > {_GAP_FACTOR} x {med:g} ms, the first "
            f"{int(d[k - 1])} ms before line {int(lines[k])}; times stay correct",
            stacklevel=2,
        )

    # Arrival time of each line: the first tag record whose position covers the line's end.
    ends_logged = _line_end_offsets_for_tag(path, raw, ends, lines, tag)
    idx = np.searchsorted(tag.file_pos, ends_logged, side="left")
    covered = idx < tag.tick_ms.size
    arrival = np.full(tick.size, np.nan)
    arrival[covered] = tag.start_gps_s + tag.tick_ms[idx[covered]] * 1e-3
    if covered.sum() < 2:
        raise InputError(
            "time-tag file covers fewer than two IMU lines",
            file=tag_path,
            expected=f"a tag file written with {path.name}",
        )

    tick_s = (_smooth_ticks(tick) if smooth_ticks else tick.astype(np.float64)) * 1e-3
    x = tick_s - tick_s[0]
    y = arrival - tag.start_gps_s
    xs, ys = x[covered], y[covered]
    keep = np.ones(xs.size, bool)
    for _ in range(3):  # least squares with 5-MAD outlier rejection (stalled writes)
        b, a = np.polyfit(xs[keep], ys[keep], 1)
        res = ys - (a + b * xs)
        mad = np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res - np.median(res[keep])) <= 5.0 * 1.4826 * max(mad, 1e-4)
    if abs(b - 1.0) > _MAX_CLOCK_RATE_ERROR:
        raise InputError(
            f"device tick runs at {b:.6f} x GPS time",
            file=path,
            expected=f"millisecond ticks matching the tag clock to {_MAX_CLOCK_RATE_ERROR:g}",
        )
    # A line cannot reach the disk before it was sampled: arrival = sample + latency >= sample
    # + min latency, so the mapping is the *lower envelope* of (tick, arrival): the
    # least-squares slope (the device clock rate; error ~1e-7 over a 10-min log) with the
    # intercept lowered to the earliest inlier arrival.
    lat = res[keep] - np.min(res[keep])
    a = a + float(np.min(res[keep]))
    q_lo, q_hi = 0.0, float(np.quantile(lat, 0.995))
    time = tag.start_gps_s + a + b * x + time_offset_s

    accel_scale = g0 if accel_unit == "g" else 1.0  # "g" = g0 (standard gravity by default)
    return ImuLog(
        time_gps_s=time,
        accel_mps2=values[:, 0:3] * accel_scale,
        gyro_rad_s=values[:, 3:6] * _GYRO_UNITS[gyro_unit],
        tick_ms=tick,
        arrival_gps_s=arrival,
        line=lines,
        clock_rate=float(b),
        latency_spread_s=q_hi - q_lo,
    )


def _rot(axis: int, angle: float) -> np.ndarray:
    """Passive (coordinate) rotation matrix R_axis(angle) as in Groves (2013) eq 2.22-2.24."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i] = r[j, j] = c
    r[i, j], r[j, i] = s, -s
    return r


# Body forward-right-down -> body right-forward-up (jaxnav's body frame).
_FRD_TO_RFU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def sensor_to_body_dcm(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """C_s_b (sensor -> body right-forward-up) from a Groves-style mounting (roll, pitch, yaw).

    The rtklibexplorer configs give the mounting as Euler angles in Groves' convention with a
    forward-right-down body: x_frd = R1(roll) R2(pitch) R3(yaw) x_sensor (Groves eq 2.24, his
    Euler_to_CTM); we then reorder to right-forward-up: x_b = [[0,1,0],[1,0,0],[0,0,-1]] x_frd.
    Misalignments listed as extra angles are simply added to the angles, as the source does.
    """
    r, p, y = np.deg2rad([roll_deg, pitch_deg, yaw_deg])
    c_frd_s = _rot(0, r) @ _rot(1, p) @ _rot(2, y)
    return _FRD_TO_RFU @ c_frd_s


def imu_increments(log: ImuLog, C_s_b: np.ndarray | None = None) -> ImuIncrements:
    """Trapezoidal increments: dtheta_k = C_s_b (w_{k-1} + w_k)/2 (t_k - t_{k-1}), same for dv.

    Sample rates are point samples, so the integral over (t_{k-1}, t_k] is approximated by the
    trapezoid (second order); the first sample only opens the first interval.
    """
    c = np.eye(3) if C_s_b is None else np.asarray(C_s_b, dtype=np.float64)
    t = np.asarray(log.time_gps_s, dtype=np.float64)
    dt = np.diff(t)
    w = log.gyro_rad_s @ c.T
    f = log.accel_mps2 @ c.T
    dtheta = 0.5 * (w[1:] + w[:-1]) * dt[:, None]
    dv = 0.5 * (f[1:] + f[:-1]) * dt[:, None]
    return ImuIncrements(t[1:], dt, dtheta, dv)
