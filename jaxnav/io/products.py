"""Precise products: readers of SP3 orbits, RINEX clock files and IONEX maps.

Readers run on the host (numpy) and return regular-grid tables with NaN where the file has no
sample; ``gnss/interp.py`` packs them into JAX tables and interpolates them (re-exported here).

- SP3 (a/c/d): several files are joined (e.g. the previous day's file for interpolation across
  midnight); bad positions (0.000000 km) and clocks (999999.999999 us) become NaN.
- RINEX clock (3.00/3.04, ``AS`` records): satellite clock bias [s] and its sigma.
- IONEX 1.0: VTEC maps [TECU] and their RMS, the shell height and base radius.
- CODE differential code biases (``P1C1yymm.DCB``): the satellites' P1-C1 biases [m].
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav.core.gpstime import datetime64_to_gps_seconds
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss.interp import (  # noqa: F401  (re-exported: the interpolators of these tables)
    ClockInterp,
    GridTable,
    IonexTable,
    clock_bias,
    clock_table,
    ionex_table,
    ionex_vtec,
    orbit_table,
    sp3_position,
    sp3_position_velocity,
)
from jaxnav.io.errors import InputError
from jaxnav.io.text import read_text

# Other GNSS time scales -> GPST [s] (GST/QZSST steered to GPST; BDT = GPST - 14 s).
_TIME_SYSTEM_TO_GPS_S = {"GPS": 0.0, "GAL": 0.0, "QZS": 0.0, "IRN": 0.0, "BDT": 14.0, "": 0.0}
# SP3 marks a bad or absent clock with 999999.999999 us and a bad position with 0.000000 km.
_SP3_BAD_CLOCK_US = 999999.0
# SP3-d system letters (GPS, GLONASS, Galileo, BeiDou, QZSS, NavIC, SBAS, LEO).
_SP3_SYSTEMS = "GRECJISL"
# Plausible orbit radii [km]: above the Earth's equatorial radius (6378 km; LEO satellites in
# SP3 fly at >= 6500 km) and below twice the geostationary radius (42164 km; the highest GNSS
# orbits, BeiDou GEO/IGSO and QZSS QZO, are at most ~42200 km).
_SP3_RADIUS_KM = (6378.137, 2 * 42164.0)
# A broadcast satellite clock offset cannot exceed the widest ICD field: Galileo af0, 31 bits at
# 2^-34 s (OS SIS ICD), +-2^-4 s = 62500 us.
_MAX_CLOCK_OFFSET_US = 62500.0
# RINEX clock data record types (3.04 Table A8) and the E19.12 value field.
_CLK_RECORD_TYPES = ("AR", "AS", "CR", "DR", "MS")
_CLK_VALUE = re.compile(r"[+-]?\d*\.\d+[EeDd][+-]?\d+")
# Relative tolerance for "on the sampling grid".
_GRID_TOL = 1e-6


def _open_text(path: Path, what: str) -> list[str]:
    return read_text(path, what).splitlines()


def _regular_grid(path, times: np.ndarray, interval: float, what: str):
    """Indices of ``times`` on the grid t0 + k * interval; InputError if off-grid."""
    k = (times - times[0]) / interval
    kr = np.round(k)
    off = np.abs(k - kr) > _GRID_TOL * max(1.0, float(np.max(np.abs(k))))
    if np.any(off):
        j = int(np.flatnonzero(off)[0])
        raise InputError(
            f"{what} epoch off the {interval:g} s grid",
            file=path,
            epoch=f"GPS {times[j]:.3f} s",
            expected=f"epochs every {interval:g} s",
        )
    return kr.astype(np.int64)


# ============================================================================================
# SP3


class Sp3Orbit(NamedTuple):
    """Precise orbit table on a regular grid (NaN where a satellite has no/bad sample)."""

    time_gps_s: np.ndarray  # [T] t0 + k * interval
    interval_s: float
    sv: np.ndarray  # [S] satellite ids, e.g. "G05"
    pos_ecef_m: np.ndarray  # [T, S, 3] ECEF (ITRF/IGS frame of the file) [m]
    clock_s: np.ndarray  # [T, S] satellite clock bias [s]
    frame: str  # coordinate frame label from the header, e.g. "IGb14"


def _sp3_header_satellites(path: Path, lines: list[str]) -> list[str]:
    """The satellites the '+' header lines list (SP3-c/d: count in cols 4-6, 17 IDs a line)."""
    plus = [ln for ln in lines[:60] if ln.startswith("+ ")]
    try:
        n = int(plus[0][3:6])
        ids = "".join(ln[9:60] for ln in plus)
        listed = [ids[3 * k : 3 * k + 3].replace(" ", "0") for k in range(n)]
    except (IndexError, ValueError) as exc:
        raise InputError("bad satellite list", file=path, line=3,
                         expected="'+' lines with the number of satellites and their IDs") from exc
    if len(listed) != n or len(set(listed)) != n or any(len(x) != 3 for x in listed):
        raise InputError(f"the '+' lines list {len(set(listed))} distinct IDs for {n} satellites",
                         file=path, line=3, expected="every satellite listed once")
    return listed


def _check_epoch_satellites(path: Path, i: int, epoch: str, listed: list[str], svs: list[str]):
    """An epoch has one position record per satellite of the header (SP3-c/d 'each epoch
    block has a record for every satellite'; a bad one is written as 0.000000)."""
    if sorted(svs) != sorted(listed):
        missing = sorted(set(listed) - set(svs))
        extra = sorted({s for s in svs if svs.count(s) > 1 or s not in listed})
        raise InputError(
            f"{len(svs)} position records for the {len(listed)} listed satellites"
            + (f" (missing {', '.join(missing[:5])})" if missing else "")
            + (f" (repeated or unlisted {', '.join(extra[:5])})" if extra else ""),
            file=path,
            line=i,
            epoch=epoch,
            expected="one record per satellite of the '+' header lines",
        )


def _check_sp3_record(path: Path, line: int, epoch: str, sv: str, xyz_km, clk_us: float):
    """Reject an impossible satellite ID, a non-finite value or a position off every orbit."""
    if sv[0] not in _SP3_SYSTEMS or sv[1:] == "00":
        raise InputError(
            f"impossible satellite ID {sv!r}",
            file=path,
            line=line,
            epoch=epoch,
            expected=f"a system letter of {_SP3_SYSTEMS!r} and a number 01-99",
        )
    if not (np.all(np.isfinite(xyz_km)) and np.isfinite(clk_us)):
        raise InputError(
            f"{sv}: non-finite position or clock",
            file=path,
            line=line,
            epoch=epoch,
            expected="finite numbers (0.000000 km / 999999.999999 us mark a bad sample)",
        )
    r_km = float(np.linalg.norm(xyz_km))
    if r_km != 0.0 and not _SP3_RADIUS_KM[0] <= r_km <= _SP3_RADIUS_KM[1]:
        raise InputError(
            f"{sv}: orbit radius {r_km:.6g} km",
            file=path,
            line=line,
            epoch=epoch,
            expected=f"a satellite between {_SP3_RADIUS_KM[0]:g} and {_SP3_RADIUS_KM[1]:g} km "
            "from the geocentre (0.000000 marks a bad position)",
        )
    if abs(clk_us) < _SP3_BAD_CLOCK_US and abs(clk_us) > _MAX_CLOCK_OFFSET_US:
        raise InputError(
            f"{sv}: clock offset {clk_us:.6g} us",
            file=path,
            line=line,
            epoch=epoch,
            expected=f"|clock| <= {_MAX_CLOCK_OFFSET_US:g} us (999999.999999 marks a bad clock)",
        )


def _read_sp3_one(path: Path):
    lines = _open_text(path, "SP3")
    if not lines or not lines[0].startswith("#") or lines[0][1:2] not in "abcd":
        raise InputError(
            "not an SP3 file", file=path, line=1, expected="a first line '#a', '#c' or '#d'"
        )
    try:
        n_epochs_hdr = int(lines[0][32:39])
        frame = lines[0][46:51].strip()
        interval = float(lines[1][24:38])
    except (ValueError, IndexError) as exc:
        raise InputError(
            "bad SP3 header lines 1-2",
            file=path,
            line=2,
            expected="number of epochs (cols 33-39) and epoch interval (line 2 cols 25-38)",
        ) from exc
    listed = _sp3_header_satellites(path, lines)
    tsys = "GPS"
    for line in lines[:40]:
        if line.startswith("%c"):
            tsys = line[9:12].strip().upper()
            tsys = "GPS" if tsys in ("CCC", "") else tsys
            break
    if tsys not in _TIME_SYSTEM_TO_GPS_S:
        raise InputError(
            f"time system {tsys!r} not supported",
            file=path,
            expected=f"one of {sorted(k for k in _TIME_SYSTEM_TO_GPS_S if k)}",
        )
    shift = _TIME_SYSTEM_TO_GPS_S[tsys]

    epochs: list[np.datetime64] = []
    recs: list[tuple[int, str, float, float, float, float]] = []
    ended = False
    epoch_svs: list[str] = []
    for i, line in enumerate(lines):
        if line.startswith("*"):
            if ended:
                raise InputError("data after EOF", file=path, line=i + 1, expected="nothing")
            if epochs:
                _check_epoch_satellites(path, i, str(epochs[-1]), listed, epoch_svs)
            epoch_svs = []
            try:
                parts = line[1:].split()
                y, mo, d, h, mi = (int(v) for v in parts[:5])
                sec = float(parts[5])
                t = np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}", "ns")
                t = t + np.timedelta64(int(round(sec * 1e9)), "ns")
            except (ValueError, IndexError) as exc:
                raise InputError(
                    f"unparsable epoch line {line[:40]!r}",
                    file=path,
                    line=i + 1,
                    expected="'*  yyyy mm dd hh mm ss.ssssssss'",
                ) from exc
            if epochs and t <= epochs[-1]:
                raise InputError(
                    "epoch not after the previous one",
                    file=path,
                    line=i + 1,
                    epoch=str(t),
                    expected="strictly increasing epochs",
                )
            epochs.append(t)
        elif line.startswith("P") and epochs:
            if len(line.rstrip()) < 46:
                raise InputError(
                    "truncated position record",
                    file=path,
                    line=i + 1,
                    epoch=str(epochs[-1]),
                    expected="'Psnn' + x, y, z [km] and clock [us] fields",
                )
            try:
                # SP3-a has no system letter: a blank means GPS.
                sv = (line[1].strip() or "G") + f"{int(line[2:4]):02d}"
                x, y_, z = (float(line[4 + 14 * k : 18 + 14 * k]) for k in range(3))
                clk_txt = line[46:60].strip()
                clk = float(clk_txt) if clk_txt else _SP3_BAD_CLOCK_US
            except ValueError as exc:
                raise InputError(
                    f"unparsable position record {line[:60]!r}",
                    file=path,
                    line=i + 1,
                    epoch=str(epochs[-1]),
                    expected="'Psnn' + 4 x F14.6 (x, y, z km, clock us)",
                ) from exc
            _check_sp3_record(path, i + 1, str(epochs[-1]), sv, (x, y_, z), clk)
            recs.append((len(epochs) - 1, sv, x, y_, z, clk))
            epoch_svs.append(sv)
        elif line.startswith("EOF"):
            if epochs and not ended:
                _check_epoch_satellites(path, i, str(epochs[-1]), listed, epoch_svs)
            ended = True
    if not epochs:
        raise InputError("no epochs", file=path, expected="'*' epoch records")
    if len(epochs) != n_epochs_hdr:
        raise InputError(
            f"{len(epochs)} epochs found but the header declares {n_epochs_hdr}",
            file=path,
            line=1,
            expected="the declared number of epochs (truncated file?)",
        )
    if not ended:
        raise InputError("no EOF line (truncated file?)", file=path, line=len(lines),
                         expected="the last line 'EOF'")
    t_gps = datetime64_to_gps_seconds(np.array(epochs, dtype="datetime64[ns]")) + shift
    return t_gps, interval, recs, frame


def read_sp3(paths: str | PathLike | Sequence[str | PathLike]) -> Sp3Orbit:
    """Read and join SP3 files onto one regular grid: pos [m], clock [s], NaN if bad/absent.

    Files are ordered by first epoch. Epochs present in two files (a day boundary) keep the
    later file's sample (the one whose day it starts) with a warning if the two differ by more
    than 0.1 m; epochs missing inside the span become NaN rows with a warning.
    """
    if isinstance(paths, (str, PathLike)):
        paths = [paths]
    parts = [(Path(p), *_read_sp3_one(Path(p))) for p in paths]
    parts.sort(key=lambda r: r[1][0])
    interval = parts[0][2]
    for p, _, iv, _, _ in parts:
        if abs(iv - interval) > 1e-9:
            raise InputError(
                f"epoch interval {iv:g} s differs from {interval:g} s of {parts[0][0].name}",
                file=p,
                line=2,
                expected="files with the same sampling interval",
            )
    sv_all = sorted({r[1] for part in parts for r in part[3]})
    col = {s: k for k, s in enumerate(sv_all)}
    t_first = parts[0][1][0]
    t_last = max(part[1][-1] for part in parts)
    n_t = int(round((t_last - t_first) / interval)) + 1
    pos = np.full((n_t, len(sv_all), 3), np.nan)
    clk = np.full((n_t, len(sv_all)), np.nan)
    filled = np.zeros(n_t, bool)
    for p, t_gps, _, recs, _ in parts:
        rows = _regular_grid(p, np.concatenate([[t_first], t_gps]), interval, "SP3")[1:]
        overlap = filled[rows]
        if np.any(overlap):
            old = pos[rows[overlap]].copy()
        if recs:
            ep = np.array([r[0] for r in recs])
            cols = np.array([col[r[1]] for r in recs])
            xyz = np.array([r[2:5] for r in recs]) * 1e3
            c_us = np.array([r[5] for r in recs])
            bad_pos = np.all(xyz == 0.0, axis=1)
            xyz[bad_pos] = np.nan
            c_s = np.where(np.abs(c_us) >= _SP3_BAD_CLOCK_US, np.nan, c_us * 1e-6)
            pos[rows[ep], cols] = xyz
            clk[rows[ep], cols] = c_s
        if np.any(overlap):
            diff = np.nanmax(np.abs(pos[rows[overlap]] - old), initial=0.0)
            if diff > 0.1:
                warnings.warn(
                    f"{p}: {int(overlap.sum())} epoch(s) also in another file differ by up to "
                    f"{diff:.3f} m; keeping {p.name}",
                    stacklevel=2,
                )
        filled[rows] = True
    if not filled.all():
        warnings.warn(
            f"SP3: {int((~filled).sum())} missing epoch(s) on the {interval:g} s grid "
            "left as NaN (interpolation windows touching them are invalid)",
            stacklevel=2,
        )
    return Sp3Orbit(
        time_gps_s=t_first + interval * np.arange(n_t),
        interval_s=float(interval),
        sv=np.array(sv_all),
        pos_ecef_m=pos,
        clock_s=clk,
        frame=parts[-1][4],
    )


# ============================================================================================
# RINEX clock files


class ClockTable(NamedTuple):
    """Satellite clocks on a regular grid (NaN where the file has no sample)."""

    time_gps_s: np.ndarray  # [T]
    interval_s: float
    sv: np.ndarray  # [S]
    clock_s: np.ndarray  # [T, S] clock bias [s]
    sigma_s: np.ndarray  # [T, S] clock bias sigma [s] (NaN if not given)


def read_clk(path: str | PathLike, *, systems: set[str] | None = None) -> ClockTable:
    """Read satellite clocks (``AS`` records) of a RINEX clock file onto its sampling grid.

    The interval is the most common spacing of the AS epochs. Records are checked: truncated
    or unparsable lines, and a satellite's epochs going backwards, raise ``InputError``; an
    exactly repeated record is dropped with a warning.
    """
    path = Path(path)
    lines = _open_text(path, "clock")
    end = None
    tsys = "GPS"
    for i, line in enumerate(lines):
        label = line[60:80].strip()
        if i == 0 and (label != "RINEX VERSION / TYPE" or line[20:21] != "C"):
            raise InputError(
                "not a RINEX clock file",
                file=path,
                line=1,
                expected="'RINEX VERSION / TYPE' with type C",
            )
        if label == "TIME SYSTEM ID":
            tsys = line[3:6].strip().upper()
        if label == "END OF HEADER":
            end = i
            break
    if end is None:
        raise InputError("no END OF HEADER", file=path, expected="a RINEX clock header")
    if tsys not in _TIME_SYSTEM_TO_GPS_S:
        raise InputError(
            f"time system {tsys!r} not supported",
            file=path,
            expected=f"one of {sorted(k for k in _TIME_SYSTEM_TO_GPS_S if k)}",
        )

    svs, t_list, vals, sigs, line_no = [], [], [], [], []
    epoch_cache: dict[str, float] = {}
    shift = _TIME_SYSTEM_TO_GPS_S[tsys]
    unknown: list[int] = []
    i = end
    while i + 1 < len(lines):
        i += 1
        line = lines[i]
        kind = line[:2]
        if kind in _CLK_RECORD_TYPES and line[2:3].isspace():
            parts = line.split()
            n_val = int(parts[8]) if len(parts) > 8 and parts[8].isdigit() else 0
            if n_val > 2 and i + 1 < len(lines):  # values 3-6 are on a continuation line
                i += 1
                parts = parts + lines[i].split()
        elif line.strip():
            unknown.append(i + 1)
            continue
        else:
            continue
        if kind != "AS":
            continue
        try:
            sv = parts[1]
            if systems is not None and sv[0] not in systems:
                continue
            key = " ".join(parts[2:8])
            t = epoch_cache.get(key)
            if t is None:  # each epoch is parsed once, not once per satellite
                y, mo, d, h, mi = (int(v) for v in parts[2:7])
                ns = int(round(float(parts[7]) * 1e9))
                t64 = np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}", "ns")
                t = float(datetime64_to_gps_seconds(t64 + np.timedelta64(ns, "ns"))) + shift
                epoch_cache[key] = t
            n_val = int(parts[8])
            if len(parts) != 9 + n_val or not 1 <= n_val <= 6:
                raise ValueError(f"{n_val} values declared, {len(parts) - 9} present")
            bad = [v for v in parts[9:] if not _CLK_VALUE.fullmatch(v)]
            if bad:  # a line cut inside a value still parses as a (wrong) number
                raise ValueError(f"value {bad[0]!r} is not in E19.12 form")
            bias = float(parts[9].replace("D", "E"))
            sig = float(parts[10].replace("D", "E")) if n_val >= 2 else np.nan
        except (ValueError, IndexError, OverflowError) as exc:
            raise InputError(
                f"bad AS record {line[:60]!r} ({exc})",
                file=path,
                line=i + 1,
                expected="'AS sat yyyy mm dd hh mm ss.ssssss n bias [sigma]'",
            ) from exc
        limit_s = _MAX_CLOCK_OFFSET_US * 1e-6
        if not (abs(bias) <= limit_s and (np.isnan(sig) or 0 <= sig <= limit_s)):
            raise InputError(
                f"{sv} clock {bias:.6g} s, sigma {sig:.6g} s",
                file=path,
                line=i + 1,
                expected=f"|bias| <= {limit_s:g} s (the widest broadcast clock field) "
                "and 0 <= sigma <= that",
            )
        svs.append(sv)
        t_list.append(t)
        vals.append(bias)
        sigs.append(sig)
        line_no.append(i + 1)
    if unknown:
        warnings.warn(
            f"{path}: ignoring {len(unknown)} line(s) of no clock record type "
            f"{'/'.join(_CLK_RECORD_TYPES)}, first at line {unknown[0]}",
            stacklevel=2,
        )
    if not svs:
        raise InputError("no satellite clock (AS) records", file=path, expected="AS records")
    t_gps = np.array(t_list)
    svs_a = np.array(svs)
    vals_a, sigs_a, line_a = np.array(vals), np.array(sigs), np.array(line_no)

    sv_all = np.unique(svs_a)
    keep = np.ones(svs_a.size, bool)
    for s in sv_all:  # per-satellite ordering and duplicates
        idx = np.flatnonzero(svs_a == s)
        dt = np.diff(t_gps[idx])
        back = np.flatnonzero(dt < 0)
        if back.size:
            k = idx[back[0] + 1]
            raise InputError(
                f"{s} clock epoch goes backwards",
                file=path,
                line=int(line_a[k]),
                epoch=f"GPS {t_gps[k]:.3f} s",
                expected="increasing epochs per satellite",
            )
        same = np.flatnonzero(dt == 0)
        for r in same:
            a, b = idx[r], idx[r + 1]
            if vals_a[a] != vals_a[b]:
                raise InputError(
                    f"{s} has two different clocks at one epoch",
                    file=path,
                    line=int(line_a[b]),
                    epoch=f"GPS {t_gps[b]:.3f} s",
                    expected="one AS record per satellite and epoch",
                )
            keep[b] = False
    if not keep.all():
        warnings.warn(f"{path}: dropping {int((~keep).sum())} repeated AS record(s)", stacklevel=2)
        svs_a, t_gps, vals_a, sigs_a = svs_a[keep], t_gps[keep], vals_a[keep], sigs_a[keep]

    ut = np.unique(t_gps)
    if ut.size > 1:
        d, counts = np.unique(np.round(np.diff(ut), 6), return_counts=True)
        interval = float(d[np.argmax(counts)])
    else:
        interval = 1.0
    rows = _regular_grid(path, np.concatenate([[ut[0]], t_gps]), interval, "clock")[1:]
    n_t = int(rows.max()) + 1
    col = np.searchsorted(sv_all, svs_a)
    clock = np.full((n_t, sv_all.size), np.nan)
    sigma = np.full((n_t, sv_all.size), np.nan)
    clock[rows, col] = vals_a
    sigma[rows, col] = sigs_a
    return ClockTable(ut[0] + interval * np.arange(n_t), interval, sv_all, clock, sigma)


# ============================================================================================
# IONEX


class IonexMaps(NamedTuple):
    """IONEX VTEC maps (single layer). Latitudes/longitudes as in the file's grid."""

    time_gps_s: np.ndarray  # [T] map epochs
    lat_deg: np.ndarray  # [NLat] LAT1 + k DLAT
    lon_deg: np.ndarray  # [NLon] LON1 + k DLON
    tec_tecu: np.ndarray  # [T, NLat, NLon] VTEC [TECU], NaN where 9999
    rms_tecu: np.ndarray | None  # same shape, or None if no RMS maps
    height_km: float  # single-layer height HGT1
    base_radius_km: float


_IONEX_REQUIRED = (
    "EPOCH OF FIRST MAP",
    "# OF MAPS IN FILE",
    "HGT1 / HGT2 / DHGT",
    "LAT1 / LAT2 / DLAT",
    "LON1 / LON2 / DLON",
    "BASE RADIUS",
    "MAP DIMENSION",
)


def _triple(text: str) -> tuple[float, float, float]:
    return tuple(float(text[2 + 6 * k : 8 + 6 * k]) for k in range(3))


def _grid_axis(a, b, d):
    n = int(round((b - a) / d)) + 1
    return a + d * np.arange(n)


def read_ionex(path: str | PathLike) -> IonexMaps:
    """Read a 2-D IONEX 1.0 file: TEC = value * 10^EXPONENT [TECU] (9999 = missing -> NaN)."""
    path = Path(path)
    lines = _open_text(path, "IONEX")
    hdr: dict[str, str] = {}
    end = None
    for i, line in enumerate(lines):
        label = line[60:80].strip()
        if i == 0 and label != "IONEX VERSION / TYPE":
            raise InputError(
                "not an IONEX file", file=path, line=1, expected="'IONEX VERSION / TYPE'"
            )
        if label == "END OF HEADER":
            end = i
            break
        hdr.setdefault(label, line[:60])
    if end is None:
        raise InputError("no END OF HEADER", file=path, expected="an IONEX header")
    missing = [k for k in _IONEX_REQUIRED if k not in hdr]
    if missing:
        raise InputError(
            f"header lacks {missing}", file=path, line=end + 1, expected="IONEX 1.0 header"
        )
    try:
        n_maps = int(hdr["# OF MAPS IN FILE"][:6])
        dim = int(hdr["MAP DIMENSION"][:6])
        # 2X,3F6.1: fixed columns (adjacent negative numbers have no blank between them)
        h1, h2, _ = _triple(hdr["HGT1 / HGT2 / DHGT"])
        lat1, lat2, dlat = _triple(hdr["LAT1 / LAT2 / DLAT"])
        lon1, lon2, dlon = _triple(hdr["LON1 / LON2 / DLON"])
        radius = float(hdr["BASE RADIUS"][:8])
        exponent0 = int(hdr.get("EXPONENT", "    -1")[:6])
    except ValueError as exc:
        raise InputError(
            f"unparsable header value ({exc})", file=path, expected="IONEX 1.0 header formats"
        ) from exc
    if dim != 2 or h1 != h2:
        raise InputError(
            f"{dim}-D maps / height range {h1}-{h2} km not supported",
            file=path,
            expected="2-D single-layer maps (HGT1 == HGT2)",
        )
    if dlat == 0.0 or dlon == 0.0:
        raise InputError("zero grid spacing", file=path, expected="DLAT, DLON != 0")
    lat = _grid_axis(lat1, lat2, dlat)
    lon = _grid_axis(lon1, lon2, dlon)
    n_val_lines = -(-lon.size // 16)

    maps: dict[str, list[tuple[np.datetime64, np.ndarray]]] = {"TEC": [], "RMS": []}
    i = end + 1
    kind = None
    exponent = exponent0
    cur = None
    t_map = None
    while i < len(lines):
        line = lines[i]
        label = line[60:80].strip()
        if label in ("START OF TEC MAP", "START OF RMS MAP"):
            kind = label.split()[2]
            cur = np.full((lat.size, lon.size), np.nan)
            t_map = None
            exponent = exponent0
            seen = np.zeros(lat.size, bool)
        elif label == "START OF HEIGHT MAP":
            kind = "HEIGHT"
        elif label == "EXPONENT" and kind in ("TEC", "RMS"):
            exponent = int(line[:6])
        elif label == "EPOCH OF CURRENT MAP" and kind in ("TEC", "RMS"):
            v = [int(x) for x in line[:36].split()]
            t_map = np.datetime64(
                f"{v[0]:04d}-{v[1]:02d}-{v[2]:02d}T{v[3]:02d}:{v[4]:02d}:{v[5]:02d}", "ns"
            )
        elif label == "LAT/LON1/LON2/DLON/H" and kind in ("TEC", "RMS"):
            try:
                la, lo1, lo2, dlo, _ = (float(line[2 + 6 * k : 8 + 6 * k]) for k in range(5))
            except ValueError as exc:
                raise InputError(
                    "unparsable LAT/LON1/LON2/DLON/H record",
                    file=path,
                    line=i + 1,
                    expected="2X,5F6.1",
                ) from exc
            row = int(round((la - lat1) / dlat))
            if not 0 <= row < lat.size or (lo1, lo2, dlo) != (lon1, lon2, dlon):
                raise InputError(
                    f"latitude band {la} / longitudes {lo1}..{lo2} off the header grid",
                    file=path,
                    line=i + 1,
                    expected=f"lat on {lat1}:{lat2}:{dlat}, lon {lon1}..{lon2} step {dlon}",
                )
            vals: list[str] = []
            for k in range(n_val_lines):
                j = i + 1 + k
                # a value line is digits and blanks (16I5 fills all 80 columns); letters
                # mean a record label, i.e. this band is short
                if j >= len(lines) or any(ch.isalpha() for ch in lines[j]):
                    raise InputError(
                        f"latitude band {la} has {len(vals)} of {lon.size} values",
                        file=path,
                        line=j + 1,
                        expected=f"{lon.size} values in 16I5 lines (truncated map?)",
                    )
                vals += [lines[j][5 * m : 5 * m + 5] for m in range(len(lines[j]) // 5)]
            vals = [v for v in vals if v.strip()]
            if len(vals) != lon.size:
                raise InputError(
                    f"latitude band {la} has {len(vals)} of {lon.size} values",
                    file=path,
                    line=i + 1,
                    expected=f"{lon.size} values (16I5)",
                )
            try:
                ints = np.array([int(v) for v in vals], dtype=np.float64)
            except ValueError as exc:
                raise InputError(
                    f"non-integer map value ({exc})",
                    file=path,
                    line=i + 2,
                    expected="16I5 integers",
                ) from exc
            cur[row] = np.where(ints == 9999, np.nan, ints * 10.0**exponent)
            seen[row] = True
            i += n_val_lines
        elif label in ("END OF TEC MAP", "END OF RMS MAP") and kind in ("TEC", "RMS"):
            if t_map is None or not seen.all():
                raise InputError(
                    f"{kind} map incomplete ({int(seen.sum())} of {lat.size} latitude bands"
                    + ("" if t_map is not None else ", no EPOCH OF CURRENT MAP")
                    + ")",
                    file=path,
                    line=i + 1,
                    expected="a full map",
                )
            maps[kind].append((t_map, cur))
            kind = None
        elif label == "END OF HEIGHT MAP":
            kind = None
        i += 1
    tec = maps["TEC"]
    if len(tec) != n_maps:
        raise InputError(
            f"{len(tec)} TEC maps found, header declares {n_maps}",
            file=path,
            expected="the declared number of maps (truncated file?)",
        )
    t = np.array([m[0] for m in tec], dtype="datetime64[ns]")
    if np.any(np.diff(t) <= np.timedelta64(0, "ns")):
        k = int(np.flatnonzero(np.diff(t) <= np.timedelta64(0, "ns"))[0]) + 1
        raise InputError(
            "TEC map epochs not increasing",
            file=path,
            epoch=str(t[k]),
            expected="maps in time order",
        )
    rms = None
    if maps["RMS"]:
        by_t = {m[0]: m[1] for m in maps["RMS"]}
        rms = np.stack([by_t.get(tt, np.full((lat.size, lon.size), np.nan)) for tt in t])
    return IonexMaps(
        time_gps_s=datetime64_to_gps_seconds(t),
        lat_deg=lat,
        lon_deg=lon,
        tec_tecu=np.stack([m[1] for m in tec]),
        rms_tecu=rms,
        height_km=h1,
        base_radius_km=radius,
    )


_NS_TO_M = C_LIGHT * 1e-9


def read_code_dcb(path: str | PathLike) -> dict[str, float]:
    """Satellite differential code biases of a CODE ``.DCB`` file [m], e.g. ``{"G01": -0.21}``.

    The file's ``VALUE (NS)`` column times c (CODE convention DCB = b_P1 - b_C1, so a C/A code
    becomes P1 as C1 + DCB, as RTKLIB applies it). Station rows (a letter and a station name) are
    skipped; any other non-blank row after the ``***`` ruler is an ``InputError``.
    """
    path = Path(path)
    lines = _open_text(path, "CODE DCB file")
    start = next((i + 1 for i, ln in enumerate(lines) if ln.startswith("***")), None)
    if start is None:
        raise InputError("no '***' column ruler", file=path,
                         expected="a CODE DCB file ('PRN / STATION NAME  VALUE (NS)  RMS (NS)')")
    out: dict[str, float] = {}
    for i in range(start, len(lines)):
        text = lines[i].rstrip()
        if not text.strip():
            continue
        head, fields = text[:26], text[26:].split()
        sv = head[:3].strip()
        if len(sv) == 1 and head[3:].strip():
            continue  # a station's bias: absorbed by the receiver clock
        try:
            if len(sv) != 3 or sv[0] not in "GREC" or not sv[1:].isdigit() or head[3:].strip():
                raise ValueError
            value_ns = float(fields[0])
        except (ValueError, IndexError):
            raise InputError(f"unreadable row {text!r}", file=path, line=i + 1,
                             expected="'G01' then the value and RMS in ns") from None
        if sv in out:
            raise InputError(f"{sv} listed twice", file=path, line=i + 1,
                             expected="one row per satellite")
        out[sv] = value_ns * _NS_TO_M
    if not out:
        raise InputError("no satellite rows", file=path, expected="rows such as 'G01  -0.716'")
    return out
