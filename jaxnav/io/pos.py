"""RTKLIB ``.pos`` solution files: read and write (position in latitude/longitude/height).

Format (RTKLIB ``outsolheads``/``outsols``, solution format "llh"): header lines start with
``%``; the last one names the columns::

    %  GPST  latitude(deg) longitude(deg) height(m) Q ns sdn(m) sde(m) sdu(m) sdne(m) sdeu(m)
       sdun(m) age(s) ratio [vn(m/s) ve(m/s) vu(m/s) sdvn sdve sdvu sdvne sdveu sdvun]

Time is either a calendar date and time (``2025/07/08 19:34:18.499``) or GPS week and time of
week; the time system is the column name (GPST, or UTC with ``leap_seconds`` given). RTKLIB
writes the off-diagonal terms as signed square roots: sdne = sign(Q_ne) sqrt(|Q_ne|).

Outage flag (RTKLIB compatible): epochs without GNSS aiding are written with **Q = 7**, RTKLIB's
``SOLQ_DR`` (dead reckoning), which rtkplot already shows as its own class; the reader sets
``outage = (q == 7)``. The writer therefore replaces the quality of outage epochs by 7.
"""

from __future__ import annotations

import warnings
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav.core.gpstime import (
    datetime64_to_gps_seconds,
    gps_seconds_to_datetime64,
    week_tow_to_gps_seconds,
)
from jaxnav.io.errors import InputError

Q_FIX, Q_FLOAT, Q_SBAS, Q_DGPS, Q_SINGLE, Q_PPP, Q_DR = 1, 2, 3, 4, 5, 6, 7  # RTKLIB SOLQ_*
Q_OUTAGE = Q_DR
# Plausibility bounds of a receiver's solution (values outside are damage, not positions):
# ellipsoidal heights from below the lowest land (Dead Sea shore -430 m MSL, geoid >= -107 m)
# to the edge of space (100 km); speeds up to the CoCom limit (1000 knots = 514 m/s) above
# which GNSS receivers stop giving solutions.
_HEIGHT_RANGE_M = (-1000.0, 100_000.0)
_MAX_SPEED_MPS = 1000 * 1852.0 / 3600.0

_BASE_COLS = (
    "lat", "lon", "height", "Q", "ns", "sdn", "sde", "sdu", "sdne", "sdeu", "sdun", "age", "ratio",
)  # fmt: skip
_VEL_COLS = ("vn", "ve", "vu", "sdvn", "sdve", "sdvu", "sdvne", "sdveu", "sdvun")
_HEADER_BASE = (
    "latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  "
    "sdeu(m)  sdun(m) age(s)  ratio"
)
_HEADER_VEL = (
    "    vn(m/s)    ve(m/s)    vu(m/s)      sdvn     sdve     sdvu    sdvne    sdveu    sdvun"
)


class PosSolution(NamedTuple):
    """An RTKLIB solution track in SI units (angles in rad inside jaxnav)."""

    time_gps_s: np.ndarray  # [N] GPS seconds
    llh: np.ndarray  # [N, 3] lat rad, lon rad, ellipsoidal height m
    q: np.ndarray  # [N] int quality (1 fix, 2 float, ..., 7 dead reckoning / outage)
    ns: np.ndarray  # [N] int number of satellites
    sd_neu_m: np.ndarray  # [N, 3] sdn, sde, sdu
    sd_cross_m: np.ndarray  # [N, 3] sdne, sdeu, sdun (signed square roots)
    age_s: np.ndarray  # [N] differential age
    ratio: np.ndarray  # [N] ambiguity ratio
    vel_enu: np.ndarray  # [N, 3] ve, vn, vu [m/s] (NaN when the file has no velocity columns)
    sd_vel_neu: np.ndarray  # [N, 3] sdvn, sdve, sdvu (NaN when absent)
    sd_vel_cross: np.ndarray  # [N, 3] sdvne, sdveu, sdvun (NaN when absent)

    @property
    def outage(self) -> np.ndarray:
        """Epochs flagged as GNSS outage (Q = 7, RTKLIB dead reckoning)."""
        return self.q == Q_OUTAGE

    @property
    def has_velocity(self) -> bool:
        return bool(np.any(np.isfinite(self.vel_enu)))


def _signed_square(s):
    return np.sign(s) * s * s


def covariance_enu(sd_neu_m, sd_cross_m) -> np.ndarray:
    """ENU covariance [N,3,3] from RTKLIB sigmas: Q_ab = sign(sd_ab) sd_ab^2 (signed sqrt)."""
    sd_neu_m = np.asarray(sd_neu_m, np.float64)
    sd_cross_m = np.asarray(sd_cross_m, np.float64)
    n, e, u = (sd_neu_m[..., i] ** 2 for i in range(3))
    ne, eu, un = (_signed_square(sd_cross_m[..., i]) for i in range(3))
    rows = [[e, ne, eu], [ne, n, un], [eu, un, u]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _find_header(path: Path, lines: list[str]):
    """Locate the column-header line; return (index of first data line, time system, vel?)."""
    header_i = None
    for i, line in enumerate(lines):
        if not line.startswith("%"):
            if line.strip():
                break
            continue
        if "latitude" in line or "x-ecef" in line or "e-baseline" in line:
            header_i = i
    if header_i is None:
        raise InputError(
            "missing column-header line",
            file=path,
            line=1,
            expected='a "%  GPST  latitude(deg) longitude(deg) height(m) Q ns ..." line',
        )
    cols = lines[header_i][1:].split()
    if "latitude(deg)" not in cols or "longitude(deg)" not in cols:
        raise InputError(
            f"unsupported position format {' '.join(cols[1:4])!r}",
            file=path,
            line=header_i + 1,
            expected="latitude(deg) longitude(deg) height(m) (RTKLIB solution format llh, deg)",
        )
    missing = [c for c in ("height(m)", "Q", "ns", "sdn(m)", "ratio") if c not in cols]
    if missing:
        raise InputError(
            f"column header lacks {missing}",
            file=path,
            line=header_i + 1,
            expected="the RTKLIB llh column set",
        )
    system = cols[0]
    has_vel = "vn(m/s)" in cols
    return header_i, system, has_vel


def _check_ranges(path: Path, data: np.ndarray, line_no: np.ndarray, has_vel: bool) -> None:
    """Refuse values no receiver writes: see the bounds' comments at the top of the module."""
    checks = [
        (data[:, 2], _HEIGHT_RANGE_M, "height [m]"),
        (data[:, 3], (0, Q_DR), "quality flag Q (RTKLIB 0-7)"),
        (data[:, 4], (0, 999), "number of satellites"),
        (data[:, 5:8], (0, np.inf), "sdn/sde/sdu [m]"),
        (data[:, 11], (0, np.inf), "age [s]"),
    ]
    if has_vel:
        checks += [
            (data[:, 13:16], (-_MAX_SPEED_MPS, _MAX_SPEED_MPS), "velocity [m/s]"),
            (data[:, 16:19], (0, np.inf), "sdvn/sdve/sdvu [m/s]"),
        ]
    for values, (lo, hi), what in checks:
        bad = (values < lo) | (values > hi)
        bad = bad.any(axis=1) if bad.ndim == 2 else bad
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            row = values[k] if values.ndim == 1 else values[k].tolist()
            raise InputError(
                f"{what} {row} out of range",
                file=path,
                line=int(line_no[k]),
                expected=f"{lo:g} <= {what} <= {hi:g}",
            )


def read_pos(path: str | PathLike, *, leap_seconds: float | None = None) -> PosSolution:
    """Read an RTKLIB llh ``.pos`` file; t_gps = t_file (GPST) or t_file + leap_seconds (UTC).

    Bad input raises ``InputError`` naming the line: missing header, wrong field count
    (truncated record), unparsable or non-finite values, epochs going backwards. An exactly
    repeated epoch line is dropped with a warning (documented repair).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read solution file: {exc}", file=path) from exc
    lines = text.splitlines()
    header_i, system, has_vel = _find_header(path, lines)
    if system == "GPST":
        shift = 0.0
    elif system == "UTC" and leap_seconds is not None:
        shift = float(leap_seconds)
    else:
        raise InputError(
            f"time system {system!r} not supported",
            file=path,
            line=header_i + 1,
            expected="GPST times (or UTC with leap_seconds= given)",
        )
    n_num = len(_BASE_COLS) + (len(_VEL_COLS) if has_vel else 0)

    times, rows, line_no = [], [], []
    calendar = None
    for i in range(header_i + 1, len(lines)):
        tok = lines[i].split()
        if not tok or lines[i].startswith("%"):
            continue
        if calendar is None:
            calendar = "/" in tok[0]
        if len(tok) != n_num + 2:
            raise InputError(
                f"{len(tok)} fields",
                file=path,
                line=i + 1,
                expected=f"{n_num + 2} fields (time as 2 fields + {n_num} numbers)",
            )
        try:
            if calendar:
                t = np.datetime64(tok[0].replace("/", "-") + "T" + tok[1], "ns")
            else:
                t = week_tow_to_gps_seconds(int(tok[0]), float(tok[1]))
            vals = [float(v) for v in tok[2:]]
        except ValueError as exc:
            raise InputError(
                f"unparsable record ({exc})",
                file=path,
                line=i + 1,
                expected="a date/time (or week tow) followed by numbers",
            ) from exc
        if not np.all(np.isfinite(vals)):
            raise InputError("non-finite value", file=path, line=i + 1, expected="finite numbers")
        times.append(t)
        rows.append(vals)
        line_no.append(i + 1)
    if not rows:
        raise InputError("no solution records", file=path, expected="at least one epoch")

    if calendar:
        t_gps = datetime64_to_gps_seconds(np.array(times, dtype="datetime64[ns]"))
    else:
        t_gps = np.asarray(times, dtype=np.float64)
    t_gps = t_gps + shift
    data = np.asarray(rows, dtype=np.float64)
    line_no = np.asarray(line_no)

    dt = np.diff(t_gps)
    dup = np.flatnonzero((dt == 0) & np.all(data[1:] == data[:-1], axis=1)) + 1
    if dup.size:
        warnings.warn(
            f"{path}: dropping {dup.size} repeated epoch line(s), first at line "
            f"{int(line_no[dup[0]])}",
            stacklevel=2,
        )
        keep = np.ones(t_gps.size, bool)
        keep[dup] = False
        t_gps, data, line_no = t_gps[keep], data[keep], line_no[keep]
        dt = np.diff(t_gps)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            "epoch not after the previous one"
            + (" (same time, different solution)" if dt[k - 1] == 0 else ""),
            file=path,
            line=int(line_no[k]),
            epoch=str(gps_seconds_to_datetime64(t_gps[k])),
            expected="strictly increasing epochs",
        )

    lat, lon = np.deg2rad(data[:, 0]), np.deg2rad(data[:, 1])
    if np.any(np.abs(data[:, 0]) > 90.0) or np.any(np.abs(data[:, 1]) > 360.0):
        k = int(np.flatnonzero((np.abs(data[:, 0]) > 90.0) | (np.abs(data[:, 1]) > 360.0))[0])
        raise InputError(
            "latitude/longitude out of range",
            file=path,
            line=int(line_no[k]),
            expected="|lat| <= 90 deg, |lon| <= 360 deg",
        )
    _check_ranges(path, data, line_no, has_vel)
    nan3 = np.full((t_gps.size, 3), np.nan)
    if has_vel:
        v = data[:, 13:22]
        vel_enu = v[:, [1, 0, 2]]
        sd_vel_neu, sd_vel_cross = v[:, 3:6], v[:, 6:9]
    else:
        vel_enu, sd_vel_neu, sd_vel_cross = nan3, nan3.copy(), nan3.copy()
    return PosSolution(
        time_gps_s=t_gps,
        llh=np.stack([lat, lon, data[:, 2]], axis=1),
        q=np.rint(data[:, 3]).astype(np.int64),
        ns=np.rint(data[:, 4]).astype(np.int64),
        sd_neu_m=data[:, 5:8],
        sd_cross_m=data[:, 8:11],
        age_s=data[:, 11],
        ratio=data[:, 12],
        vel_enu=vel_enu,
        sd_vel_neu=sd_vel_neu,
        sd_vel_cross=sd_vel_cross,
    )


def _format_time(t_gps_s: np.ndarray) -> list[str]:
    """GPST calendar strings 'YYYY/MM/DD HH:MM:SS.sss' rounded to the millisecond."""
    ms = np.round(np.asarray(t_gps_s) * 1000.0).astype(np.int64)
    dt64 = np.datetime64("1980-01-06T00:00:00", "ms") + ms.astype("timedelta64[ms]")
    out = []
    for s in np.datetime_as_string(dt64, unit="ms"):
        date, clock = s.split("T")
        out.append(f"{date.replace('-', '/')} {clock}")
    return out


def write_pos(
    path: str | PathLike,
    sol: PosSolution,
    *,
    outage: np.ndarray | None = None,
    comments: tuple[str, ...] = (),
    program: str = "jaxnav",
    info: tuple[tuple[str, str], ...] = (),
) -> None:
    """Write an RTKLIB llh ``.pos`` file (GPST calendar time, ms) readable by RTKLIB and read_pos.

    Precision: lat/lon 1e-9 deg (0.1 mm), height and sigmas 0.1 mm, velocities 1e-5 m/s, time
    1 ms. Epochs with ``outage`` True (or already Q = 7) are written with Q = 7 (see module
    docstring). Velocity columns are written when ``sol.vel_enu`` holds finite values.
    The header is RTKPOST's: ``% program``, the ``info`` (key, value) lines (``inp file``,
    ``pos mode``, ``freqs``, ``elev mask``, ...), ``% obs start`` / ``% obs end`` of the first
    and last epoch written, then ``comments`` and the column line.
    """
    path = Path(path)
    n = np.asarray(sol.time_gps_s).size
    q = np.asarray(sol.q, dtype=np.int64).copy()
    if outage is not None:
        outage = np.asarray(outage, dtype=bool)
        if outage.shape != (n,):
            raise ValueError(f"outage must have shape ({n},), got {outage.shape}")
        q[outage] = Q_OUTAGE
    has_vel = sol.has_velocity
    fields = [sol.time_gps_s, sol.llh, sol.sd_neu_m, sol.sd_cross_m, sol.age_s, sol.ratio]
    if has_vel:
        fields += [sol.vel_enu, sol.sd_vel_neu, sol.sd_vel_cross]
    if not all(np.all(np.isfinite(f)) for f in fields):
        raise ValueError("write_pos: non-finite values cannot be written in RTKLIB format")
    lat_deg = np.rad2deg(np.asarray(sol.llh)[:, 0])
    lon_deg = np.rad2deg(np.asarray(sol.llh)[:, 1])
    h = np.asarray(sol.llh)[:, 2]
    times = _format_time(sol.time_gps_s)
    head = [f"% program   : {program}"]
    head += [f"% {key:10s}: {value}" for key, value in info]
    if n:
        for key, t in (("obs start", sol.time_gps_s[0]), ("obs end", sol.time_gps_s[-1])):
            week, tow = divmod(float(t), 604800.0)
            head.append(f"% {key:10s}: {_format_time(np.asarray([t]))[0]} GPST "
                        f"(week{int(week):04d} {tow:.3f}s)")
    head += [f"% {c}" for c in comments]
    head.append(f"% outage    : Q={Q_OUTAGE} (RTKLIB dead reckoning) marks epochs without GNSS")
    head.append(
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,7:dr)"
    )
    head.append("%  GPST                  " + _HEADER_BASE + (_HEADER_VEL if has_vel else ""))
    out = head
    for k in range(n):
        sdn, sde, sdu = sol.sd_neu_m[k]
        sne, seu, sun = sol.sd_cross_m[k]
        row = (
            f"{times[k]} {lat_deg[k]:14.9f} {lon_deg[k]:14.9f} {h[k]:10.4f} {q[k]:3d} "
            f"{int(sol.ns[k]):3d} {sdn:8.4f} {sde:8.4f} {sdu:8.4f} {sne:8.4f} {seu:8.4f} "
            f"{sun:8.4f} {sol.age_s[k]:6.2f} {sol.ratio[k]:6.1f}"
        )
        if has_vel:
            ve, vn, vu = sol.vel_enu[k]
            svn, sve, svu = sol.sd_vel_neu[k]
            svne, sveu, svun = sol.sd_vel_cross[k]
            row += (
                f" {vn:10.5f} {ve:10.5f} {vu:10.5f} {svn:9.5f} {sve:9.5f} {svu:9.5f}"
                f" {svne:9.5f} {sveu:9.5f} {svun:9.5f}"
            )
        out.append(row)
    path.write_text("\n".join(out) + "\n", encoding="ascii")
