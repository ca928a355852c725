"""RINEX navigation files: the records as georinex reads them, and as broadcast ephemerides.

- :func:`read_rinex_nav`: an ``xr.Dataset`` (dims time, sv) with georinex's variable names;
- :func:`read_broadcast_ephemeris`: the ``gnss.ephemeris.BroadcastEphemeris`` the GNSS models
  evaluate (IS-GPS-200 / GLONASS ICD), healthy records only;
- :func:`ephemeris_from_records`: the same from per-satellite record dicts with georinex's field
  names (what ``read_broadcast_ephemeris`` collects, and what ``io/ubx_nav.py`` decodes).

Both read the file through ``io/rinex.py`` (plain, gzip/Z/bz2/zip or Hatanaka; structural header
checks; ``InputError`` naming the file) and zero-fill blank "spare" fields before georinex:
georinex 1.16 drops a whole record when a field inside it is blank, which would lose every
Galileo record of files written by sbf2rin (the shared ESBC file).
"""

from __future__ import annotations

import datetime as _dt
import io
import math
import re
import warnings
from os import PathLike
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxnav.core.gpstime import GPS_UTC_LEAP_S, SECONDS_PER_WEEK, gps_seconds
from jaxnav.gnss import corrections
from jaxnav.gnss.ephemeris import (
    GLO_A_M,
    GM_GAL,
    GM_GLO,
    GM_GPS,
    GPS_A_M,
    BroadcastEphemeris,
    GlonassRecords,
    KeplerRecords,
)
from jaxnav.gnss.signals import SYS_GAL, SYS_GLO, SYS_GPS
from jaxnav.io.errors import InputError
from jaxnav.io.rinex import _header, _read_text, _version_type

# continuation lines per record (RINEX 3.04 A6-A16): GPS, Galileo, BeiDou, QZSS, NavIC 7;
# GLONASS, SBAS 3
_NAV_LINES = {"G": 7, "E": 7, "C": 7, "J": 7, "I": 7, "R": 3, "S": 3}
_FIELD = 19
_BLANK_FIELD = " 0.000000000000E+00"


def _patch_nav_text(text: str) -> str:
    """Zero-fill blank 19-character fields inside G/E/R records (legal RINEX "spare" fields).

    georinex 1.16 parses every field with float() and drops the whole record (all NaN) when a
    field inside the record is blank -- e.g. the spare field after the Galileo week in records
    written by sbf2rin -- so every Galileo record of the shared ESBC file would be lost.
    """
    out = []
    lines = text.splitlines()
    in_header = True
    remaining = 0
    for line in lines:
        if in_header:
            out.append(line)
            if "END OF HEADER" in line:
                in_header = False
            continue
        if remaining > 0:
            body = line[4:80].ljust(4 * _FIELD)
            fields = [body[i * _FIELD : (i + 1) * _FIELD] for i in range(4)]
            if remaining == 1:  # last line: keep trailing blanks (they tell georinex the length)
                last = max((i for i, f in enumerate(fields) if f.strip()), default=-1)
                fields = [
                    f if (f.strip() or i > last) else _BLANK_FIELD for i, f in enumerate(fields)
                ]
                out.append((line[:4] + "".join(fields)).rstrip())
            else:
                fields = [f if f.strip() else _BLANK_FIELD for f in fields]
                out.append(line[:4] + "".join(fields))
            remaining -= 1
            continue
        remaining = _NAV_LINES.get(line[:1], 0) if line[:1].strip() else 0
        out.append(line)
    return "\n".join(out) + "\n"


_RECORD_START = re.compile(r"[A-Z]\d\d \d{4}( [ \d]\d){5}")


def _field_ok(text: str) -> bool:
    """A 19-character RINEX field: blank, or a finite Fortran number (D or E exponent)."""
    t = text.strip()
    if not t:
        return True
    try:
        return math.isfinite(float(t.replace("D", "E").replace("d", "e")))
    except ValueError:
        return False


def _next_epoch_line(lines: list[str], i: int) -> int:
    """The first line at or after ``i`` that starts a record (where a scan resynchronises)."""
    while i < len(lines) and not _RECORD_START.match(lines[i]):
        i += 1
    return i


def _screen_records(lines: list[str], start: int, use, version: float) -> tuple[list[str], dict]:
    """Check every RINEX 3 record after the header (line ``start``) before georinex reads it.

    A record is its epoch line and the continuation lines its system has (``_NAV_LINES``),
    each field blank or a finite number. A damaged record (junk or a blank line inside it, a
    field that is no number, a truncated last record) is dropped and counted with its line and
    reason; the scan resumes at the next epoch line. Blank lines between records are counted.
    Returns the kept body lines and the accounting {system: kept, "rejected": [(line, why)],
    "blank": n}.
    """
    kept: list[str] = []
    tally: dict = {"rejected": [], "blank": 0, "skipped": 0}
    i = start
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            tally["blank"] += 1
            i += 1
            continue
        sys_letter = line[:1]
        if not _RECORD_START.match(line) or sys_letter not in _NAV_LINES:
            tally["rejected"].append((i + 1, f"not a record's epoch line: {line[:30]!r}"))
            i = _next_epoch_line(lines, i + 1)
            continue
        # RINEX 3.05 added a fourth GLONASS line (status flags, group delay, accuracy)
        n = 4 if sys_letter == "R" and version >= 3.05 else _NAV_LINES[sys_letter]
        record = lines[i : i + 1 + n]
        why = None
        if len(record) < 1 + n:
            why = f"truncated: {len(record) - 1} of {n} continuation lines"
        else:
            for k, cont in enumerate(record[1:], 1):
                if _RECORD_START.match(cont) or not cont.startswith("    "):
                    why = f"continuation line {k} of {n} is {cont[:30]!r}"
                    break
            fields = [record[0][23 + 19 * j : 42 + 19 * j] for j in range(3)] + [
                c[4 + 19 * j : 23 + 19 * j] for c in record[1:] for j in range(4)
            ]
            bad = next((f for f in fields if not _field_ok(f)), None)
            if why is None and bad is not None:
                why = f"field {bad.strip()!r} is not a finite number"
        if why is None:
            if use is None or sys_letter in use:
                tally[sys_letter] = tally.get(sys_letter, 0) + 1
            else:
                tally["skipped"] += 1
            kept.extend(record)
            i += 1 + n
        else:
            tally["rejected"].append((i + 1, f"{line[:3]} record: {why}"))
            i = _next_epoch_line(lines, i + 1)
    return kept, tally


def _records_read(ds) -> int:
    """Records georinex returned: (time, satellite column) cells with any finite value."""
    cells = None
    for v in ds.data_vars.values():
        finite = np.isfinite(np.asarray(v.values, dtype=float))
        cells = finite if cells is None else cells | finite
    return 0 if cells is None else int(cells.sum())


def _load(path: Path, use, tlim):
    """(georinex Dataset, header labels) of a navigation file (see :func:`read_rinex_nav`)."""
    import georinex as gr

    path = Path(path)
    raw_lines = _read_text(path).splitlines()
    hdr, _ = _header(path, raw_lines)
    version, ftype = _version_type(path, hdr)
    tally = None
    if version >= 3 and ftype in ("N", "G", "H", "L"):
        end = next(i for i, ln in enumerate(raw_lines) if "END OF HEADER" in ln) + 1
        body, tally = _screen_records(raw_lines, end, use, version)
        raw_lines = raw_lines[:end] + body
    text = _patch_nav_text("\n".join(raw_lines) + "\n")
    if ftype not in ("N", "G", "H", "L"):
        raise InputError(
            f"file type {ftype!r} is not navigation data",
            file=path,
            line=1,
            expected="RINEX navigation file (type N/G/H)",
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        try:
            ds = gr.load(io.StringIO(text), use=use, tlim=tlim)
        except Exception as exc:  # noqa: BLE001
            raise InputError(
                f"georinex failed: {type(exc).__name__}: {exc}",
                file=path,
                expected="valid RINEX navigation records",
            ) from exc
    if ds.sizes.get("time", 0) == 0 or ds.sizes.get("sv", 0) == 0:
        raise InputError("no navigation records", file=path, expected="records for " + str(use))
    if tally is not None:
        _account(path, ds, tally, tlim)
    t = ds.time.values.astype("datetime64[ns]")
    if np.any(np.diff(t) < np.timedelta64(0, "ns")):
        ds = ds.sortby("time")
    return ds, hdr


def _account(path: Path, ds, tally: dict, tlim) -> None:
    """Every record parsed or reported: rejected records and blank lines are warned with a
    count and the first line; georinex returning fewer records than were kept is an error."""
    rejected = tally["rejected"]
    if rejected:
        line, why = rejected[0]
        warnings.warn(
            f"{path}: {len(rejected)} damaged navigation record(s) dropped, the first at line "
            f"{line} ({why})",
            stacklevel=4,
        )
    if tally["blank"]:
        warnings.warn(f"{path}: {tally['blank']} blank line(s) between records ignored",
                      stacklevel=4)
    kept = sum(v for k, v in tally.items() if len(k) == 1)
    got = _records_read(ds)
    if tlim is None and got < kept:
        raise InputError(
            f"georinex read {got} of the {kept} navigation records that passed the checks",
            file=path,
            expected="every well-formed record read (a georinex limitation: report it)",
        )


def read_rinex_nav(
    path: str | PathLike,
    *,
    use: set[str] | None = None,
    tlim: tuple[_dt.datetime, _dt.datetime] | None = None,
):
    """Read a RINEX 2/3 navigation file with georinex (FutureWarnings filtered) -> xr.Dataset.

    The dataset has dims (time, sv) with georinex's variable names (``sqrtA``, ``Toe``,
    ``SVclockBias``...). Satellites with several message types (Galileo I/NAV and F/NAV) appear
    as ``E01``, ``E01_1``... as georinex names them. Records that are entirely missing are
    dropped; an ``InputError`` names the file if it is not navigation data or has no records.
    """
    return _load(Path(path), use, tlim)[0]


def _leap_seconds(hdr: dict, default):
    """GPS - UTC from the header's LEAP SECONDS line (its first field), else ``default``."""
    rows = hdr.get("LEAP SECONDS")
    if rows:
        try:
            return int(rows[0].split()[0])
        except (ValueError, IndexError):
            pass
    return default


def read_broadcast_ephemeris(
    path: str | PathLike,
    systems: str = "GRE",
    galileo_source: str = "fnav",
    leap_seconds: float | None = None,
    t_ref_gps_s: float | None = None,
) -> BroadcastEphemeris:
    """Read a RINEX 3 navigation file into a ``gnss.ephemeris.BroadcastEphemeris``.

    - ``systems``: RINEX letters to load (G, R, E).
    - ``galileo_source``: "fnav" keeps F/NAV records (clocks for E1/E5a, the PPP pair here),
      "inav" keeps I/NAV (E1/E5b); a satellite without the preferred kind keeps the other.
    - ``leap_seconds``: GPS - UTC for GLONASS epochs (UTC in RINEX 3); default from the header,
      else 18 s.
    - ``t_ref_gps_s``: the returned time axis origin; default 00:00 GPS of the first record's day.
    Only healthy records (health == 0) are marked valid.
    """
    path = Path(path)
    if galileo_source not in ("fnav", "inav"):
        raise ValueError(f"galileo_source must be 'fnav' or 'inav', got {galileo_source!r}")
    nav, hdr = _load(path, set(systems), None)
    leap = _leap_seconds(hdr, GPS_UTC_LEAP_S) if leap_seconds is None else leap_seconds

    # Collect records per satellite (georinex splits same-epoch duplicates into "E01_1" columns).
    recs: dict[str, list[dict]] = {}
    times = nav["time"].values
    names = list(nav.data_vars)
    data = {k: nav[k].values for k in names}  # [time, sv]
    present = np.any([np.isfinite(v) for v in data.values()], axis=0)
    for j, sv in enumerate(nav["sv"].values):
        base = str(sv)[:3]
        for i in np.flatnonzero(present[:, j]):
            row = {k: data[k][i, j] for k in names}
            row["_toc"] = gps_seconds(times[i])
            recs.setdefault(base, []).append(row)
    if not recs:
        raise ValueError(f"{path}: no GPS/GLONASS/Galileo navigation records for systems {systems}")

    alpha, beta = _klobuchar_from_header(nav.attrs)
    return ephemeris_from_records(
        recs,
        t_ref_gps_s=t_ref_gps_s,
        leap_seconds=leap,
        iono_alpha=alpha,
        iono_beta=beta,
        galileo_source=galileo_source,
    )


def ephemeris_from_records(
    recs: dict[str, list[dict]],
    *,
    t_ref_gps_s: float | None = None,
    leap_seconds: float = GPS_UTC_LEAP_S,
    iono_alpha=None,
    iono_beta=None,
    galileo_source: str = "fnav",
) -> BroadcastEphemeris:
    """Per-satellite navigation records -> ``BroadcastEphemeris`` (IS-GPS-200 / GLONASS ICD).

    ``recs`` maps a RINEX satellite name ("G05", "R12", "E11") to its records, each a dict with
    georinex's field names of RINEX 3.04 tables A6-A10 (``sqrtA``, ``Eccentricity``, ``Io``,
    ``IDOT``, ``Omega0``, ``OmegaDot``, ``omega``, ``M0``, ``DeltaN``, ``Cuc`` ... ``Cis``,
    ``SVclockBias/Drift/DriftRate``, ``TGD`` / ``BGDe5a``, ``GPSWeek`` / ``GALWeek``, ``Toe``,
    ``health``, ``DataSrc``; GLONASS ``X`` ... ``dZ2``, ``SVrelFreqBias``, ``FreqNum``) plus
    ``_toc``: the record's epoch (toc; GLONASS tb in UTC) in GPS seconds. Angles in rad, times
    in s (RINEX units). ``galileo_source`` as in :func:`read_broadcast_ephemeris`;
    ``leap_seconds`` = GPS - UTC for GLONASS epochs; ``iono_alpha/beta``: Klobuchar
    coefficients [4] (default ``corrections.KLOBUCHAR_*_DEFAULT``); ``t_ref_gps_s``: the time
    axis origin, default 00:00 GPS of the first record's day. Only healthy records (health ==
    0) with a finite orbit and clock are marked valid. The input is not modified.
    """
    if galileo_source not in ("fnav", "inav"):
        raise ValueError(f"galileo_source must be 'fnav' or 'inav', got {galileo_source!r}")
    letter_to_sys = {"G": SYS_GPS, "R": SYS_GLO, "E": SYS_GAL}
    recs = {s: list(r) for s, r in recs.items() if r}
    unknown = sorted(s for s in recs if s[:1] not in letter_to_sys)
    if unknown:
        raise ValueError(f"only GPS/GLONASS/Galileo records are supported, got {unknown}")
    if not recs:
        raise ValueError("no navigation records")
    sats = sorted(recs, key=lambda s: (letter_to_sys[s[0]], int(s[1:])))
    want_bit = 2 if galileo_source == "fnav" else 1 | 4  # DataSrc bits (RINEX 3.05 table A8)
    for s in sats:
        if s[0] == "E":
            pref = [r for r in recs[s] if int(r.get("DataSrc", 0)) & want_bit]
            if pref:
                recs[s] = pref
        recs[s].sort(key=lambda r: r["_toc"])
    n_rec = max(len(recs[s]) for s in sats)
    n = len(sats)

    all_toc = [r["_toc"] for s in sats for r in recs[s]]
    if t_ref_gps_s is None:
        t_ref_gps_s = math.floor(min(all_toc) / 86400.0) * 86400.0

    def arr(fill=0.0):
        return np.full((n, n_rec), fill, dtype=np.float64)

    kf = {name: arr() for name in KeplerRecords._fields}
    kf["tgd_s"][:] = np.nan  # no record, no group delay
    kf["valid"] = np.zeros((n, n_rec), bool)
    kf["sqrt_a"][:] = math.sqrt(GPS_A_M)  # benign padding (finite orbit) for unused entries
    gf = {name: arr() for name in ("tb_s", "clock_bias_s", "rel_freq_bias")}
    g_valid = np.zeros((n, n_rec), bool)
    g_pos = np.zeros((n, n_rec, 3))
    g_pos[..., 0] = GLO_A_M  # benign padding
    g_vel = np.zeros((n, n_rec, 3))
    g_vel[..., 1] = math.sqrt(GM_GLO / GLO_A_M)
    g_acc = np.zeros((n, n_rec, 3))
    system = np.zeros(n, np.int32)
    prn = np.zeros(n, np.int32)
    channel = np.zeros(n, np.int32)

    for i, s in enumerate(sats):
        system[i] = letter_to_sys[s[0]]
        prn[i] = int(s[1:])
        for j, r in enumerate(recs[s]):
            healthy = float(r.get("health", 0.0)) == 0.0
            if s[0] == "R":
                tb = r["_toc"] + leap_seconds - t_ref_gps_s
                gf["tb_s"][i, j] = tb
                gf["clock_bias_s"][i, j] = r["SVclockBias"]
                gf["rel_freq_bias"][i, j] = r["SVrelFreqBias"]
                g_pos[i, j] = [r["X"], r["Y"], r["Z"]]
                g_vel[i, j] = [r["dX"], r["dY"], r["dZ"]]
                g_acc[i, j] = [r["dX2"], r["dY2"], r["dZ2"]]
                g_valid[i, j] = healthy and all(np.isfinite([r["X"], r["dX"], r["SVclockBias"]]))
                channel[i] = int(r["FreqNum"])
                continue
            week = r["GPSWeek"] if s[0] == "G" else r["GALWeek"]
            toe_abs = week * SECONDS_PER_WEEK + r["Toe"]
            # A toc/toe pair straddling a week rollover: move toe to the week nearest toc.
            toe_abs += SECONDS_PER_WEEK * round((r["_toc"] - toe_abs) / SECONDS_PER_WEEK)
            vals = {
                "toe_s": toe_abs - t_ref_gps_s,
                "toc_s": r["_toc"] - t_ref_gps_s,
                "sqrt_a": r["sqrtA"],
                "ecc": r["Eccentricity"],
                "i0": r["Io"],
                "idot": r["IDOT"],
                "omega0": r["Omega0"],
                "omega_dot": r["OmegaDot"],
                "omega": r["omega"],
                "m0": r["M0"],
                "delta_n": r["DeltaN"],
                "cuc": r["Cuc"],
                "cus": r["Cus"],
                "crc": r["Crc"],
                "crs": r["Crs"],
                "cic": r["Cic"],
                "cis": r["Cis"],
                "af0": r["SVclockBias"],
                "af1": r["SVclockDrift"],
                "af2": r["SVclockDriftRate"],
                # a missing group delay stays NaN (never 0): io/prepare then drops the slot
                "tgd_s": r["TGD"] if s[0] == "G" else r.get("BGDe5a", np.nan),
                "toe_week_s": r["Toe"],
                "gm": GM_GPS if s[0] == "G" else GM_GAL,
            }
            # the orbit and clock must be finite; the group delay is for SF users only
            finite = all(np.isfinite(v) for k, v in vals.items() if k != "tgd_s")
            for key, v in vals.items():
                kf[key][i, j] = v if np.isfinite(v) or key == "tgd_s" else kf[key][i, j]
            kf["valid"][i, j] = healthy and finite

    if iono_alpha is None:
        iono_alpha = corrections.KLOBUCHAR_ALPHA_DEFAULT
    if iono_beta is None:
        iono_beta = corrections.KLOBUCHAR_BETA_DEFAULT
    return BroadcastEphemeris(
        system=jnp.asarray(system),
        prn=jnp.asarray(prn),
        glo_channel=jnp.asarray(channel),
        kepler=KeplerRecords(**{k: jnp.asarray(v) for k, v in kf.items()}),
        glonass=GlonassRecords(
            valid=jnp.asarray(g_valid),
            tb_s=jnp.asarray(gf["tb_s"]),
            pos=jnp.asarray(g_pos),
            vel=jnp.asarray(g_vel),
            acc=jnp.asarray(g_acc),
            clock_bias_s=jnp.asarray(gf["clock_bias_s"]),
            rel_freq_bias=jnp.asarray(gf["rel_freq_bias"]),
        ),
        t_ref_gps_s=jnp.asarray(float(t_ref_gps_s)),
        iono_alpha=jnp.asarray(np.asarray(iono_alpha, dtype=np.float64)),
        iono_beta=jnp.asarray(np.asarray(iono_beta, dtype=np.float64)),
    )


def _klobuchar_from_header(attrs):
    """Klobuchar (alpha, beta) from georinex attributes, or the corrections module defaults."""
    coeffs = attrs.get("ionospheric_corr_GPS")
    if coeffs is not None and len(coeffs) == 8:
        c = np.asarray(coeffs, dtype=np.float64)
        return c[:4], c[4:]
    return (
        np.asarray(corrections.KLOBUCHAR_ALPHA_DEFAULT),
        np.asarray(corrections.KLOBUCHAR_BETA_DEFAULT),
    )
