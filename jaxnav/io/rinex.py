"""RINEX 2/3 observation and navigation files -> fixed-slot arrays (through georinex).

Files may be plain, gzipped and/or Hatanaka-compressed (``.crx``/``.??d``); they are expanded in
memory with the ``hatanaka`` package, checked structurally by a fast scan of the epoch records
(so truncated records, epochs out of order and unparsable values give an ``InputError`` with the
line number *of the expanded RINEX text*; georinex itself silently drops or misplaces such
records), and only then parsed by georinex with ``use=`` / ``meas=`` / ``tlim=`` so that only
what is needed is loaded. georinex's xarray FutureWarnings are filtered.

Fixed slots (DESIGN invariant 2): constellation ``sys`` has ``SLOTS[sys] = (first_prn, n)``
slots and satellite PRN p lives in slot ``p - first_prn`` for the whole file. Every requested
signal becomes a ``[T, S]`` float64 array with NaN where missing plus a boolean mask.

Signal selection: a request is either an exact RINEX 3 code (``"C1W"``) or a generic
type+band (``"C1"``) resolved per constellation through ``DEFAULT_PRIORITY`` (first tracking
attribute in the list that the file's header declares). The choice made is reported in
``SystemObs.codes``. Default priority rationale (chosen): band-1 civil codes first (what
single-frequency users and the seeds' SF modes use: GPS C/A ``C``, Galileo E1 pilot ``C``);
GPS/GLONASS band 2 P(Y)/P first (``W``, ``P``) because IGS/MGEX precise clocks refer to the
P1/P2 ionosphere-free combination (SEED_SPEC 2.8); E5a/E5b/L5 pilots (``Q``) first.

Units are RINEX's: code [m], phase [cycles], Doppler [Hz], SNR [dB-Hz]. Times are GPS seconds.
RINEX 2 type names are mapped to RINEX 3 codes with ``RINEX2_TO_3`` (documented assumptions:
GPS L1 phase = C/A tracking, L2 phase = P(Y) tracking, C2 = L2C as in RINEX 2.11).
"""

from __future__ import annotations

import datetime as _dt
import io
import math
import re
import warnings
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav.core.gpstime import datetime64_to_gps_seconds
from jaxnav.io.errors import InputError
from jaxnav.io.text import read_text as _read_text

# (first PRN, number of slots) per constellation: GPS PRN 1-32, GLONASS slots 1-27 (24 + spares),
# Galileo 1-36, BeiDou 1-63, QZSS 1-10, SBAS PRN 120-158 (RINEX S20-S58), NavIC 1-14.
SLOTS: dict[str, tuple[int, int]] = {
    "G": (1, 32),
    "R": (1, 27),
    "E": (1, 36),
    "C": (1, 63),
    "J": (1, 10),
    "S": (20, 39),
    "I": (1, 14),
}

# Valid tracking attributes per constellation and band (RINEX 3.05 Table A2-A11); codes outside
# these are unknown and rejected.
VALID_ATTRIBUTES: dict[str, dict[str, str]] = {
    "G": {"1": "CSLXPWYMNR", "2": "CDSLXPWYMNR", "5": "IQX"},
    "R": {"1": "CP", "2": "CP", "3": "IQX", "4": "ABX", "6": "ABX"},
    "E": {"1": "ABCXZ", "5": "IQX", "7": "IQX", "8": "IQX", "6": "ABCXZ"},
    "C": {"2": "IQX", "1": "DPXANSLZ", "5": "DPX", "7": "IQXDPZ", "8": "DPX", "6": "IQXADPZ"},
    "J": {"1": "CSLXZEB", "2": "SLX", "5": "IQXDPZ", "6": "SLXEZ"},
    "S": {"1": "C", "5": "IQX"},
    "I": {"5": "ABCX", "9": "ABCX", "1": "DPX"},
}

# Default tracking-attribute priority per constellation and band (see module docstring).
DEFAULT_PRIORITY: dict[str, dict[str, str]] = {
    "G": {"1": "CWPXSLYMN", "2": "WPLSXCDYMN", "5": "QXI"},
    "R": {"1": "CP", "2": "PC", "3": "QXI", "4": "BXA", "6": "BXA"},
    "E": {"1": "CXBAZ", "5": "QXI", "7": "QXI", "8": "QXI", "6": "CXBAZ"},
    "C": {"2": "IXQ", "7": "IXQDPZ", "6": "IXQA", "1": "PXDA", "5": "PXD", "8": "PXD"},
    "J": {"1": "CXSLZB", "2": "LXS", "5": "QXIDPZ", "6": "LXSEZ"},
    "S": {"1": "C", "5": "QXI"},
    "I": {"5": "AXBC", "9": "AXBC"},
}

# Default request: dual-frequency GPS (L1 C/A, L2 P(Y)) and Galileo (E1, E5a) code, phase,
# Doppler and SNR on band 1, code and phase on band 2 / 5.
DEFAULT_SIGNALS: dict[str, tuple[str, ...]] = {
    "G": ("C1", "L1", "D1", "S1", "C2", "L2"),
    "E": ("C1", "L1", "D1", "S1", "C5", "L5"),
}

# RINEX 2 observation types -> RINEX 3 codes per constellation (assumptions in module docstring).
RINEX2_TO_3: dict[str, dict[str, str]] = {
    "G": {
        "C1": "C1C", "P1": "C1W", "L1": "L1C", "D1": "D1C", "S1": "S1C",
        "C2": "C2X", "P2": "C2W", "L2": "L2W", "D2": "D2W", "S2": "S2W",
        "C5": "C5X", "L5": "L5X", "D5": "D5X", "S5": "S5X",
    },
    "R": {
        "C1": "C1C", "P1": "C1P", "L1": "L1C", "D1": "D1C", "S1": "S1C",
        "C2": "C2C", "P2": "C2P", "L2": "L2P", "D2": "D2P", "S2": "S2P",
    },
    "E": {
        "C1": "C1X", "L1": "L1X", "D1": "D1X", "S1": "S1X",
        "C5": "C5X", "L5": "L5X", "D5": "D5X", "S5": "S5X",
        "C7": "C7X", "L7": "L7X", "D7": "D7X", "S7": "S7X",
        "C8": "C8X", "L8": "L8X", "D8": "D8X", "S8": "S8X",
        "C6": "C6X", "L6": "L6X", "D6": "D6X", "S6": "S6X",
    },
    "S": {"C1": "C1C", "L1": "L1C", "D1": "D1C", "S1": "S1C", "C5": "C5X", "L5": "L5X"},
    "J": {
        "C1": "C1C", "L1": "L1C", "D1": "D1C", "S1": "S1C", "C2": "C2X", "L2": "L2X",
        "C5": "C5X", "L5": "L5X",
    },
}  # fmt: skip

# Offsets of other GNSS time scales to GPST [s]: GST and QZSST are steered to GPST, BDT = GPST
# - 14 s. GLONASS time (UTC(SU) + 3 h) needs leap seconds and is not supported.
_TIME_SYSTEM_TO_GPS_S = {"GPS": 0.0, "GAL": 0.0, "QZS": 0.0, "IRN": 0.0, "BDT": 14.0, "": 0.0}
_CODE_RE = re.compile(r"^[CLDS][1-9][A-Z]$")
_GENERIC_RE = re.compile(r"^[CLDS][1-9]$")


class SystemObs(NamedTuple):
    """Observations of one constellation in fixed PRN slots."""

    sv: np.ndarray  # [S] satellite id of each slot, e.g. "G01"
    obs: dict[str, np.ndarray]  # request -> [T, S] float64, NaN where missing
    mask: dict[str, np.ndarray]  # request -> [T, S] bool, True where a value is present
    lli: dict[str, np.ndarray]  # phase request -> [T, S] int8 loss-of-lock indicator (0 absent)
    codes: dict[str, str]  # request -> RINEX 3 code actually read


class RinexObs(NamedTuple):
    """A RINEX observation file as fixed-shape arrays."""

    time_gps_s: np.ndarray  # [T] epochs (GPS seconds)
    epoch_present: np.ndarray  # [T] bool, False for epochs inserted to fill gaps
    systems: dict[str, SystemObs]
    interval_s: float
    approx_pos_ecef: np.ndarray  # [3] header APPROX POSITION XYZ (NaN if absent)
    header: dict


# --------------------------------------------------------------------------------------------
# Reading and structural checks


def _header(path: Path, lines: list[str]) -> tuple[dict, int]:
    """Parse header labels (cols 61-80) into {label: [contents...]}; return it and END index."""
    hdr: dict[str, list[str]] = {}
    end_i = None
    for k, line in enumerate(lines):
        label = line[60:80].strip()
        if label == "END OF HEADER":
            end_i = k
            break
        hdr.setdefault(label, []).append(line[:60])
    if end_i is None:
        raise InputError("no END OF HEADER", file=path, expected="a RINEX header")
    if "RINEX VERSION / TYPE" not in hdr:
        raise InputError("missing RINEX VERSION / TYPE", file=path, line=1, expected="a RINEX file")
    return hdr, end_i


def _version_type(path: Path, hdr: dict) -> tuple[float, str]:
    first = hdr["RINEX VERSION / TYPE"][0]
    try:
        version = float(first[:9])
    except ValueError as exc:
        raise InputError(
            f"bad version field {first[:9]!r}", file=path, line=1, expected="F9.2 version"
        ) from exc
    return version, first[20]


def _obs_types(path: Path, hdr: dict, version: float, lines) -> dict[str, list[str]]:
    """Observation types per constellation (RINEX 3 codes; RINEX 2 types are mapped)."""
    if version >= 3:
        rows = hdr.get("SYS / # / OBS TYPES")
        if not rows:
            raise InputError(
                "missing SYS / # / OBS TYPES", file=path, expected="RINEX 3 observation header"
            )
        types: dict[str, list[str]] = {}
        declared: dict[str, tuple[int, str]] = {}
        sys = None
        for row in rows:
            if row[0] != " ":
                sys = row[0]
                types[sys] = []
                try:
                    declared[sys] = (int(row[3:6]), row)
                except ValueError as exc:
                    raise _header_error(path, lines, row, "SYS / # / OBS TYPES", "the count "
                                        f"{row[3:6]!r} of {sys}", "I3 number of types") from exc
            elif sys is None:
                raise _header_error(path, lines, row, "SYS / # / OBS TYPES", "a continuation "
                                    "line before any system", "a line opening with the system")
            types[sys] += row[7:60].split()
        for sys, (n, row) in declared.items():
            if n != len(types[sys]):  # a lost or repeated continuation line shifts every field
                raise _header_error(path, lines, row, "SYS / # / OBS TYPES", f"{sys} declares "
                                    f"{n} types but lists {len(types[sys])}",
                                    f"{n} types on 13-type lines")
        return types
    rows = hdr.get("# / TYPES OF OBSERV")
    if not rows:
        raise InputError(
            "missing # / TYPES OF OBSERV", file=path, expected="RINEX 2 observation header"
        )
    t2: list[str] = []
    for row in rows:
        t2 += row[6:60].split()
    try:
        n2 = int(rows[0][:6])
    except ValueError as exc:
        raise _header_error(path, lines, rows[0], "# / TYPES OF OBSERV", f"the count "
                            f"{rows[0][:6]!r}", "I6 number of types") from exc
    if n2 != len(t2):
        raise _header_error(path, lines, rows[0], "# / TYPES OF OBSERV", f"{n2} types declared "
                            f"but {len(t2)} listed", f"{n2} types on 9-type lines")
    return {"v2": t2}


def _header_error(path, lines, row, label, what, expected) -> InputError:
    """InputError at the header line holding ``row`` under ``label``."""
    k = next((k for k, ln in enumerate(lines) if ln[:60] == row and label in ln), None)
    return InputError(f"{label}: {what}", file=path, line=None if k is None else k + 1,
                      expected=expected)


def _epoch_time(path: Path, line: str, i: int, version: float) -> tuple[np.datetime64, str, int]:
    """Parse an epoch line -> (time, flag, count)."""
    try:
        if version >= 3:
            y, mo, d, h, mi = (
                int(line[a:b]) for a, b in ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18))
            )
            sec = float(line[18:29])
            flag, n = line[31:32], int(line[32:35])
        else:
            y, mo, d, h, mi = (
                int(line[a:b]) for a, b in ((1, 3), (4, 6), (7, 9), (10, 12), (13, 15))
            )
            y += 2000 if y < 80 else 1900
            sec = float(line[15:26])
            flag, n = line[28:29], int(line[29:32])
        t = np.datetime64(_dt.datetime(y, mo, d, h, mi), "ns") + np.timedelta64(
            int(round(sec * 1e9)), "ns"
        )
    except (ValueError, IndexError, OverflowError) as exc:  # OverflowError: seconds "Infinity"
        raise InputError(
            f"unparsable epoch record {line[:40]!r}",
            file=path,
            line=i + 1,
            expected="an epoch record" + (" starting with '>'" if version >= 3 else ""),
        ) from exc
    return t, flag.strip() or "0", n


# Physical range of a value by observation type letter (RINEX 2 "P" is code): a pseudorange
# from the ground or a LEO to a GNSS satellite is 1.9e7-4.2e7 m, with room for a receiver clock
# offset of +-17 ms; a Doppler under 1e5 Hz covers orbital motion, any vehicle and a 10 ppm
# oscillator; C/N0 in dB-Hz is 0-99. Outside, a value is masked with a warning (some writers
# put 0.000 for "not tracked"). Carrier phase carries an arbitrary offset: finite only.
_RANGE = {"C": (1.0e7, 5.0e7), "P": (1.0e7, 5.0e7), "D": (-1.0e5, 1.0e5), "S": (0.0, 99.0)}


def _check_fields(path, line, i, sv, cols, t, names, out_of_range):
    """Check that the 14-character value fields at ``cols`` are blank or finite numbers; append
    (epoch, sv, type, line) to ``out_of_range`` for a value outside its type's physical range."""
    for c, name in zip(cols, names, strict=True):
        field = line[c : c + 14]
        if field.strip():
            try:
                v = float(field)
            except ValueError as exc:
                raise InputError(
                    f"unparsable observation value {field.strip()!r} for {sv}",
                    file=path,
                    line=i + 1,
                    epoch=str(t),
                    expected="F14.3 number or blanks",
                ) from exc
            if not math.isfinite(v):  # float() takes "nan" and "Infinity"; RINEX has neither
                raise InputError(
                    f"non-finite observation value {field.strip()!r} for {sv} {name}",
                    file=path,
                    line=i + 1,
                    epoch=str(t),
                    expected="F14.3 number or blanks",
                )
            lo, hi = _RANGE.get(name[0], (-math.inf, math.inf))
            if not lo <= v <= hi:
                out_of_range.append((t, sv, name, i + 1, v))


def _scan_obs(path, lines, start, version, types, check, tlim, out_of_range):
    """Walk the epoch records: structure, ordering; numeric check of requested fields in tlim.

    ``check`` maps constellation -> list of observation indices to validate. Returns the list of
    (time, line) of observation epochs; values outside their physical range are appended to
    ``out_of_range``. Raises InputError on truncation, bad order, a satellite twice in an epoch,
    a record longer than its declared types, tabs, unparsable or non-finite values.
    """
    n_lines = len(lines)
    epochs: list[tuple[np.datetime64, int]] = []
    i = start
    t0 = None if tlim is None else np.datetime64(tlim[0], "ns")
    t1 = None if tlim is None else np.datetime64(tlim[1], "ns")
    while i < n_lines:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        if "\t" in line:  # RINEX is fixed-column: a tab moves every field after it
            raise InputError("tab character in a record", file=path, line=i + 1,
                             expected="fixed-column ASCII without tabs")
        if version >= 3 and line[0] != ">":
            raise InputError(
                f"unexpected record {line[:40]!r}",
                file=path,
                line=i + 1,
                expected="an epoch record starting with '>' (previous epoch truncated?)",
            )
        t, flag, n = _epoch_time(path, line, i, version)
        if flag in "2345":  # special event: n header/comment lines follow
            i += 1 + n
            continue
        if flag not in "016":
            raise InputError(
                f"unknown epoch flag {flag!r}", file=path, line=i + 1, expected="flag 0-6"
            )
        if version >= 3:  # one record per satellite, the id opens the record
            body, per_sat, svs = i + 1, 1, [""] * n
        else:  # satellite list on the epoch line (12 per line), ceil(n_obs / 5) lines each
            n_list = max(1, -(-n // 12))
            svs = []
            for k in range(n_list):
                if i + k >= n_lines:
                    svs.append(None)
                    break
                ll = lines[i + k]
                svs += [ll[32 + 3 * j : 35 + 3 * j] for j in range(min(12, n - 12 * k))]
            body = i + n_list
            per_sat = max(1, -(-len(types["v2"]) // 5))
        end = body + n * per_sat
        if end > n_lines or any(s is None for s in svs):
            raise InputError(
                f"epoch declares {n} satellites but the file ends",
                file=path,
                line=i + 1,
                epoch=str(t),
                expected=f"{n * per_sat} observation lines (truncated record)",
            )
        in_window = (t0 is None or t >= t0) and (t1 is None or t <= t1)
        seen: set[str] = set()
        for k in range(n):
            j = body + k * per_sat
            if version >= 3:
                rec = lines[j]
                if "\t" in rec:
                    raise InputError("tab character in a record", file=path, line=j + 1,
                                     expected="fixed-column ASCII without tabs")
                if rec[:1] == ">" or not re.match(r"^[A-Z][ 0-9]\d$", rec[:3]):
                    raise InputError(
                        f"expected satellite record {k + 1} of {n}, found {rec[:40]!r}",
                        file=path,
                        line=j + 1,
                        epoch=str(t),
                        expected="a line starting with a satellite id like 'G05' (truncated?)",
                    )
                sys = rec[0]
                if sys not in types:
                    raise InputError(
                        f"satellite {rec[:3]} of a system without SYS / # / OBS TYPES",
                        file=path, line=j + 1, epoch=str(t),
                        expected=f"satellites of {''.join(types)}",
                    )
                if len(rec.rstrip()) > 3 + 16 * len(types[sys]):
                    raise InputError(
                        f"{rec[:3]} record is longer than its {len(types[sys])} declared types",
                        file=path, line=j + 1, epoch=str(t),
                        expected=f"at most {3 + 16 * len(types[sys])} characters",
                    )
                sv = f"{sys}{int(rec[1:3]):02d}"
                names = types[sys]
            else:
                if not re.match(r"^[A-Z ][ 0-9]\d$", svs[k]):
                    raise InputError(f"satellite id {svs[k]!r} in the epoch's list",
                                     file=path, line=i + 1, epoch=str(t),
                                     expected="A1,I2 satellite ids like 'G05'")
                sv = f"{svs[k][0].strip() or 'G'}{int(svs[k][1:3]):02d}"
                sys = sv[0]
                names = types["v2"]
            if sv in seen:  # georinex would keep one of the two records without a word
                raise InputError(f"satellite {sv} twice in one epoch", file=path,
                                 line=j + 1, epoch=str(t), expected="one record per satellite")
            seen.add(sv)
            if not (in_window and sys in check and flag != "6"):
                continue
            if version >= 3:
                _check_fields(path, rec, j, sv, [3 + 16 * q for q in check[sys]], t,
                              [names[q] for q in check[sys]], out_of_range)
            else:
                for q in check[sys]:
                    _check_fields(path, lines[j + q // 5], j + q // 5, sv, [16 * (q % 5)], t,
                                  [names[q]], out_of_range)
        epochs.append((t, i + 1))
        i = end
    return epochs


def _resolve(path, sys, request, available, priority):
    """Request (exact code or generic type+band) -> RINEX 3 code present in the file."""
    if _CODE_RE.match(request):
        band, attr = request[1], request[2]
        if attr not in VALID_ATTRIBUTES.get(sys, {}).get(band, ""):
            raise InputError(
                f"unknown observation code {request!r} for constellation {sys}",
                file=path,
                expected=f"one of the RINEX 3 codes for {sys}: band {band} attributes "
                f"{VALID_ATTRIBUTES.get(sys, {}).get(band, '(none)')!r}",
            )
        return request if request in available else None
    if not _GENERIC_RE.match(request):
        raise InputError(
            f"unknown observation request {request!r}",
            file=path,
            expected="a RINEX 3 code like 'C1C' or a type+band like 'C1'",
        )
    band = request[1]
    for attr in priority.get(sys, {}).get(band, ""):
        if request + attr in available:
            return request + attr
    return None


def read_rinex_obs(
    path: str | PathLike,
    signals: Mapping[str, Sequence[str]] | None = None,
    *,
    tlim: tuple[_dt.datetime, _dt.datetime] | None = None,
    priority: Mapping[str, Mapping[str, str]] | None = None,
    slots: Mapping[str, tuple[int, int]] | None = None,
    on_missing: str = "error",
    fill_gaps: bool = True,
    indicators: bool = False,
) -> RinexObs:
    """Read RINEX 2/3 observations into fixed PRN slots: obs[sys][req][t, prn - first_prn].

    ``signals`` maps constellation letter -> requests (default ``DEFAULT_SIGNALS``);
    ``tlim`` = (start, end) GPST datetimes, both inclusive (georinex semantics);
    ``on_missing``: "error" raises ``InputError`` when a request has no code in the file,
    "nan" returns an all-missing array with a warning; ``fill_gaps`` inserts missing epochs on
    the regular grid of the most common epoch spacing (all masked, ``epoch_present`` False)
    with a warning;
    ``indicators`` adds loss-of-lock indicators for phase requests. Exactly repeated epochs are
    dropped with a warning; epochs out of order, truncated or unparsable records raise.
    """
    import georinex as gr

    path = Path(path)
    signals = dict(DEFAULT_SIGNALS if signals is None else signals)
    prio = {**DEFAULT_PRIORITY, **(priority or {})}
    slot_map = {**SLOTS, **(slots or {})}
    if on_missing not in ("error", "nan"):
        raise ValueError('on_missing must be "error" or "nan"')
    for sys in signals:
        if sys not in slot_map:
            raise InputError(
                f"unknown constellation {sys!r}", file=path, expected=f"one of {list(slot_map)}"
            )

    text = _read_text(path)
    lines = text.splitlines()
    hdr, end_i = _header(path, lines)
    version, ftype = _version_type(path, hdr)
    if ftype != "O":
        raise InputError(
            f"file type {ftype!r} is not observation data",
            file=path,
            line=1,
            expected="RINEX observation file (type O)",
        )
    types = _obs_types(path, hdr, version, lines)

    # Map each constellation's requests onto the file's RINEX 3 codes (and georinex names).
    avail: dict[str, dict[str, str]] = {}  # sys -> {rinex3 code: name in georinex output}
    for sys in signals:
        if version >= 3:
            avail[sys] = {c: c for c in types.get(sys, [])}
        else:
            table = RINEX2_TO_3.get(sys, {})
            avail[sys] = {table[t]: t for t in types["v2"] if t in table}
    codes: dict[str, dict[str, str | None]] = {}
    for sys, reqs in signals.items():
        codes[sys] = {}
        for req in reqs:
            code = _resolve(path, sys, req, avail[sys], prio)
            if code is None:
                msg = f"no observation code for {sys} {req!r} in the file"
                exp = f"one of {sorted(avail[sys]) or 'no codes for this constellation'}"
                if on_missing == "error":
                    raise InputError(msg, file=path, expected=exp)
                warnings.warn(f"{path}: {msg}; returning it all-missing", stacklevel=2)
            codes[sys][req] = code

    # Structural scan, with numeric checks of the requested fields inside tlim.
    # (RINEX 2: every field of the used systems, since georinex parses them all.)
    check: dict[str, list[int]] = {}
    for sys in signals:
        wanted = {avail[sys][c] for c in codes[sys].values() if c is not None}
        names = types["v2"] if version < 3 else types.get(sys, [])
        check[sys] = [k for k, name in enumerate(names) if name in wanted or version < 3]
    out_of_range: list = []
    epochs = _scan_obs(path, lines, end_i + 1, version, types, check, tlim, out_of_range)
    ep_t = np.array([e[0] for e in epochs], dtype="datetime64[ns]")
    back = np.flatnonzero(np.diff(ep_t) < np.timedelta64(0, "ns"))
    if back.size:
        k = int(back[0]) + 1
        raise InputError(
            f"epoch out of order (after {ep_t[k - 1]})",
            file=path,
            line=epochs[k][1],
            epoch=str(ep_t[k]),
            expected="increasing epoch times",
        )

    # Load only what is needed with georinex.
    meas = sorted({avail[s][c] for s in signals for c in codes[s].values() if c is not None})
    use = set(signals)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        try:
            ds = gr.load(
                io.StringIO(text),
                use=use,
                meas=meas or None,
                tlim=tlim,
                useindicators=indicators,
            )
        except Exception as exc:  # noqa: BLE001 - georinex raises many types on bad input
            raise InputError(
                f"georinex failed: {type(exc).__name__}: {exc}", file=path, expected="valid RINEX"
            ) from exc
    if ds.sizes.get("time", 0) == 0:
        raise InputError(
            "no epochs in the requested time window",
            file=path,
            expected=f"epochs between {tlim[0]} and {tlim[1]}" if tlim else "epochs",
        )

    if out_of_range:
        ds = _mask_out_of_range(path, ds, out_of_range)

    # Time system -> GPS seconds.
    tsys = str(ds.attrs.get("time_system", "GPS")).strip().upper()
    if tsys not in _TIME_SYSTEM_TO_GPS_S:
        raise InputError(
            f"time system {tsys!r} not supported",
            file=path,
            expected=f"one of {sorted(k for k in _TIME_SYSTEM_TO_GPS_S if k)}",
        )
    t_dt = ds.time.values.astype("datetime64[ns]")

    # Exactly repeated epochs: keep the first; differing repeats are an error.
    uniq, first_idx = np.unique(t_dt, return_index=True)
    if uniq.size != t_dt.size:
        for t in uniq[np.bincount(np.searchsorted(uniq, t_dt)) > 1]:
            rows = np.flatnonzero(t_dt == t)
            a = ds.isel(time=rows[0])
            for r in rows[1:]:
                if not a.identical(ds.isel(time=r)):
                    raise InputError(
                        "repeated epoch with different observations",
                        file=path,
                        epoch=str(t),
                        expected="each epoch once",
                    )
        warnings.warn(
            f"{path}: dropping {t_dt.size - uniq.size} exactly repeated epoch(s), first "
            f"{uniq[np.bincount(np.searchsorted(uniq, t_dt)) > 1][0]}",
            stacklevel=2,
        )
        ds = ds.isel(time=np.sort(first_idx))
        t_dt = ds.time.values.astype("datetime64[ns]")
    t_gps = datetime64_to_gps_seconds(t_dt) + _TIME_SYSTEM_TO_GPS_S[tsys]

    interval = _interval(hdr, t_gps)
    row_of = np.arange(t_gps.size)
    present = np.ones(t_gps.size, bool)
    if fill_gaps and t_gps.size > 1 and np.isfinite(interval):
        k = (t_gps - t_gps[0]) / interval
        off = np.abs(k - np.round(k)) > 1e-3
        if np.any(off):
            j = int(np.flatnonzero(off)[0])
            raise InputError(
                f"epoch off the {interval:g} s grid",
                file=path,
                epoch=str(t_dt[j]),
                expected="epochs on the INTERVAL grid (or fill_gaps=False)",
            )
        k = np.round(k).astype(np.int64)
        n_t = int(k[-1]) + 1
        if n_t != t_gps.size:
            warnings.warn(
                f"{path}: {n_t - t_gps.size} missing epoch(s) on the {interval:g} s grid "
                "filled with masked rows",
                stacklevel=2,
            )
        row_of = k
        present = np.zeros(n_t, bool)
        present[k] = True
        t_gps = t_gps[0] + interval * np.arange(n_t)

    svs = [str(s) for s in ds.sv.values]
    systems = {}
    for sys in signals:
        first, n_slots = slot_map[sys]
        sv_cols, sv_slots = [], []
        for c, s in enumerate(svs):
            if s[0] != sys:
                continue
            prn = int(s[1:3])
            slot = prn - first
            if not 0 <= slot < n_slots:
                raise InputError(
                    f"satellite {s} outside the {n_slots} slots of {sys}",
                    file=path,
                    expected=f"PRN {first}..{first + n_slots - 1} (increase slots={{{sys!r}: "
                    "(first, n)}})",
                )
            sv_cols.append(c)
            sv_slots.append(slot)
        sv_cols_a, sv_slots_a = np.array(sv_cols, int), np.array(sv_slots, int)
        obs, mask, lli = {}, {}, {}
        for req, code in codes[sys].items():
            arr = np.full((t_gps.size, n_slots), np.nan)
            if code is not None and sv_cols:
                name = avail[sys][code]
                if name in ds:
                    vals = ds[name].values[:, sv_cols_a].astype(np.float64)
                    arr[np.ix_(row_of, sv_slots_a)] = vals
            obs[req] = arr
            mask[req] = np.isfinite(arr)
            if indicators and code is not None and code[0] == "L":
                ind = np.zeros((t_gps.size, n_slots), np.int8)
                name = avail[sys][code] + "lli"
                if name in ds and sv_cols:
                    v = ds[name].values[:, sv_cols_a]
                    ind[np.ix_(row_of, sv_slots_a)] = np.nan_to_num(v, nan=0.0).astype(np.int8)
                lli[req] = ind
        sv_names = np.array([f"{sys}{first + k:02d}" for k in range(n_slots)])
        systems[sys] = SystemObs(sv_names, obs, mask, lli, dict(codes[sys]))

    pos = ds.attrs.get("position")
    approx = np.asarray(pos, np.float64) if pos is not None else np.full(3, np.nan)
    return RinexObs(t_gps, present, systems, interval, approx, hdr)


def _mask_out_of_range(path, ds, found):
    """Mask the values outside their type's physical range (``_RANGE``), with one warning."""
    t_ds = ds.time.values.astype("datetime64[ns]")
    sv_ds = {str(s): c for c, s in enumerate(ds.sv.values)}
    for t, sv, name, _, _ in found:
        r = min(int(np.searchsorted(t_ds, t)), t_ds.size - 1)
        if name in ds and sv in sv_ds and abs(t_ds[r] - t) < np.timedelta64(1, "ms"):
            ds[name][{"time": r, "sv": sv_ds[sv]}] = np.nan
    t, sv, name, line, v = found[0]
    warnings.warn(
        f"{path}: {len(found)} observation(s) outside their physical range masked, first "
        f"{sv} {name} = {v:g} at line {line} (code 1e7-5e7 m, Doppler |D| <= 1e5 Hz, "
        "C/N0 0-99 dB-Hz)",
        stacklevel=3,
    )
    return ds


def _interval(hdr: dict, t_gps: np.ndarray) -> float:
    """Sampling interval: the most common epoch spacing (header INTERVAL for a single epoch)."""
    if t_gps.size > 1:
        d = np.round(np.diff(t_gps), 6)
        vals, counts = np.unique(d, return_counts=True)
        return float(vals[np.argmax(counts)])
    try:
        return float(hdr["INTERVAL"][0][:10])
    except (KeyError, ValueError):
        return float("nan")
