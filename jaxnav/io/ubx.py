"""u-blox UBX logs: raw observations (RXM-RAWX), navigation subframes (RXM-SFRBX), NAV-PVT.

:func:`read_ubx` frames the byte stream itself and hands every complete frame to pyubx2 (the
parser); a frame is kept only when its Fletcher-8 checksum (u-blox Interface Description,
"UBX checksum") is right. A damaged frame (bad checksum, or a length that runs past the end
of the file) and bytes that are neither UBX nor NMEA are counted and skipped with one warning
per kind that names the file and the first byte offsets, never silently.

The observations become a ``io.rinex.RinexObs`` in the fixed PRN slots of ``io.rinex.SLOTS``,
with RINEX 3 codes (``SIGNAL_CODES``) and RINEX units (code m, phase cycles, Doppler Hz,
C/N0 dB-Hz), so ``io.prepare.prepare_gnss`` treats them like a RINEX file:

- a code is kept where ``prValid``; a phase where ``cpValid`` and the half-cycle ambiguity
  is resolved (``halfCyc``; before that the phase may be off by half a cycle, RTKLIB marks
  such a phase with LLI bit 1, here it is not used at all);
- loss of lock (RINEX LLI bit 0) on a phase: the lock time (ms) is shorter than the time
  since the previous epoch or went down, the phase was missing at the previous epoch, the
  receiver reset its clock (``clkReset``: every phase restarts), or its sub-half-cycle flag
  changed (the receiver moved the phase by half a cycle, as RTKLIB also flags);
- missing epochs of the log's regular interval are put back empty (``epoch_present`` False,
  with a warning); an epoch off that grid by more than 1 ms is an ``InputError``;
- epoch time = week * 604800 + ``rcvTow``: the receiver's time of measurement (GPST plus the
  receiver clock offset, which the SPP estimates like for any RINEX file).
"""

from __future__ import annotations

import math
import warnings
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav.core.gpstime import SECONDS_PER_WEEK
from jaxnav.io.errors import InputError
from jaxnav.io.rinex import SLOTS, RinexObs, SystemObs, _interval
from jaxnav.io.ubx_nav import SfrbxWords

_SYNC = b"\xb5\x62"
_MAX_PAYLOAD = 8192  # larger than any message of the classes read here (RAWX: 16 + 32 * 255)
#: (class, id) of the messages read; the rest are framed and checked but not parsed.
RAWX, SFRBX, NAV_PVT = (0x02, 0x15), (0x02, 0x13), (0x01, 0x07)

#: u-blox gnssId -> RINEX constellation letter.
GNSS_LETTER = {0: "G", 1: "S", 2: "E", 3: "C", 5: "J", 6: "R", 7: "I"}
#: (gnssId, sigId) -> RINEX 3 band + attribute (u-blox Interface Description, "Signal
#: identifiers"; RINEX 3.05 table 4-13). C/D/L/S prefixes make the codes.
SIGNAL_CODES = {
    (0, 0): "1C", (0, 3): "2L", (0, 4): "2S", (0, 6): "5I", (0, 7): "5Q",
    (1, 0): "1C",
    (2, 0): "1C", (2, 1): "1B", (2, 3): "5I", (2, 4): "5Q", (2, 5): "7I", (2, 6): "7Q",
    (2, 8): "6B", (2, 9): "6C",
    (3, 0): "2I", (3, 1): "2I", (3, 2): "7I", (3, 3): "7I", (3, 4): "6I", (3, 10): "6I",
    (3, 5): "1P", (3, 6): "1D", (3, 7): "5P", (3, 8): "5D",
    (5, 0): "1C", (5, 1): "1Z", (5, 4): "2S", (5, 5): "2L", (5, 8): "5I", (5, 9): "5Q",
    (6, 0): "1C", (6, 2): "2C",
    (7, 0): "5A",
}  # fmt: skip


class NavPvt(NamedTuple):
    """The receiver's own solutions (UBX-NAV-PVT), one row per message."""

    time_gps_s: np.ndarray  # [N]
    llh: np.ndarray  # [N, 3] rad, rad, m (ellipsoidal height)
    h_msl_m: np.ndarray  # [N] height above mean sea level (the receiver's geoid model)
    vel_enu: np.ndarray  # [N, 3] m/s
    h_acc_m: np.ndarray  # [N] receiver's horizontal accuracy estimate
    v_acc_m: np.ndarray  # [N]
    fix_type: np.ndarray  # [N] 0 none ... 3 3D, 4 GNSS + dead reckoning
    carr_soln: np.ndarray  # [N] 0 none, 1 float RTK, 2 fixed RTK
    num_sv: np.ndarray  # [N]


class UbxLog(NamedTuple):
    """What a UBX file holds for jaxnav."""

    obs: RinexObs
    subframes: list[SfrbxWords]  # t_gps_s: the RAWX epoch before the subframe in the file
    pvt: NavPvt
    counts: dict  # frames per message identity, plus "damaged", "unrecognised_bytes",
    # "duplicate_epochs" and the observations dropped per reason


def _checksum(frame: bytes) -> bytes:
    """UBX 8-bit Fletcher checksum over class, id, length and payload."""
    a = b = 0
    for byte in frame:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def _frames(data: bytes):
    """Yield (offset, class, id, frame bytes) of every UBX frame with a correct checksum, and
    (offset, None, kind, b"") for a damaged frame or a run of unrecognised bytes. The bytes
    after a damaged frame's header, up to the next frame, belong to that frame."""
    p, n = 0, len(data)
    junk_start = None  # start of a run of bytes that are neither UBX nor NMEA
    damaged = False  # inside the rest of a damaged frame

    def flush():
        nonlocal junk_start
        if junk_start is not None and not damaged:
            yield junk_start, None, "unrecognised_bytes", b""
        junk_start = None

    while p < n:
        if data.startswith(_SYNC, p) and p + 6 <= n:
            length = data[p + 4] | (data[p + 5] << 8)
            end = p + 8 + length
            body_ok = length <= _MAX_PAYLOAD and end <= n
            yield from flush()
            if body_ok and _checksum(data[p + 2 : end - 2]) == data[end - 2 : end]:
                damaged = False
                yield p, data[p + 2], data[p + 3], data[p:end]
                p = end
                continue
            damaged = True
            yield p, None, "damaged", b""
            p += 2  # resynchronise on the next sync pair
            continue
        if data[p] == 0x24:  # "$": an NMEA sentence up to its line end (not read here)
            end = data.find(b"\n", p)
            if end != -1 and end - p <= 100 and data[p + 1 : p + 3].isalpha():
                yield from flush()
                damaged = False
                p = end + 1
                continue
        if junk_start is None:
            junk_start = p
        p += 1
    yield from flush()


def _warn_skipped(path: Path, kind: str, offsets: list[int], what: str):
    if offsets:
        first = ", ".join(str(o) for o in offsets[:5])
        more = f" (and {len(offsets) - 5} more)" if len(offsets) > 5 else ""
        warnings.warn(f"{path}: {len(offsets)} {what} skipped at byte offset {first}{more}",
                      stacklevel=3)


def read_ubx(path: str | PathLike, *, systems: str = "GREJ") -> UbxLog:
    """Read a UBX log: RXM-RAWX as fixed-slot RINEX-like observations of the constellations
    ``systems`` (RINEX letters), RXM-SFRBX as navigation words, NAV-PVT as the receiver's own
    solution. Raises ``InputError`` when the file holds no RXM-RAWX epoch."""
    from pyubx2 import UBXReader  # the parser; framing and checksums are checked here as well

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read the file: {exc}", file=path) from None
    counts: dict = {"damaged": 0, "unrecognised_bytes": 0}
    skipped: dict[str, list[int]] = {"damaged": [], "unrecognised_bytes": []}
    rawx, sfrbx, pvt = [], [], []
    for offset, cls, mid, frame in _frames(data):
        if cls is None:
            counts[mid] += 1
            skipped[mid].append(offset)
            continue
        key = (cls, mid)
        if key not in (RAWX, SFRBX, NAV_PVT):
            counts["other"] = counts.get("other", 0) + 1
            continue
        try:
            msg = UBXReader.parse(frame)
        except Exception:  # noqa: BLE001  (pyubx2's errors: a checksummed frame it cannot read)
            counts["damaged"] += 1
            skipped["damaged"].append(offset)
            continue
        counts[msg.identity] = counts.get(msg.identity, 0) + 1
        (rawx if key == RAWX else sfrbx if key == SFRBX else pvt).append((offset, msg))
    _warn_skipped(path, "damaged", skipped["damaged"],
                  "damaged UBX frame(s) (bad checksum, truncated, or unreadable payload)")
    _warn_skipped(path, "unrecognised_bytes", skipped["unrecognised_bytes"],
                  "run(s) of bytes that are neither UBX nor NMEA")
    if not rawx:
        raise InputError("no UBX-RXM-RAWX message", file=path,
                         expected="a u-blox log with raw measurements (RXM-RAWX enabled)")
    obs, week_of = _observations(path, rawx, set(systems), counts)
    # SFRBX carries no time: a subframe arrived after the RAWX epoch before it in the file
    raw_off = np.array([off for off, _ in rawx])
    raw_t = np.array([m.week * SECONDS_PER_WEEK + m.rcvTow for _, m in rawx])
    subframes = []
    for off, m in sfrbx:
        k = max(int(np.searchsorted(raw_off, off)) - 1, 0)
        words = tuple(int(getattr(m, f"dwrd_{i:02d}")) for i in range(1, m.numWords + 1))
        subframes.append(SfrbxWords(int(m.gnssId), int(m.svId), int(m.sigId), words,
                                    float(raw_t[k]), off))
    return UbxLog(obs, subframes, _nav_pvt(pvt, week_of), counts)


def _rawx_rows(msg):
    """The measurements of one RXM-RAWX as tuples."""
    rows = []
    for i in range(1, msg.numMeas + 1):
        s = f"_{i:02d}"
        rows.append(tuple(getattr(msg, k + s) for k in (
            "gnssId", "svId", "sigId", "prMes", "cpMes", "doMes", "cno", "locktime",
            "prValid", "cpValid", "halfCyc", "subHalfCyc")))
    return rows


def _observations(path: Path, rawx, systems: set, counts: dict):
    times, epochs, resets, offsets = [], [], [], []
    last_t = -math.inf
    dup = 0
    for offset, msg in rawx:
        t = msg.week * SECONDS_PER_WEEK + msg.rcvTow
        if t <= last_t:
            if abs(t - last_t) < 1e-6:
                dup += 1
                continue
            raise InputError(f"epoch {t:.3f} GPS s goes back in time (previous {last_t:.3f})",
                             file=path, record=offset, expected="RXM-RAWX epochs in time order")
        last_t = t
        times.append(t)
        epochs.append(_rawx_rows(msg))
        resets.append(bool(msg.clkReset))
        offsets.append(offset)
    if dup:
        warnings.warn(f"{path}: {dup} repeated RXM-RAWX epoch(s) dropped", stacklevel=3)
    counts["duplicate_epochs"] = dup
    # Missing epochs (a damaged frame, a receiver hiccup) are put back on the regular grid,
    # empty (epoch_present False), as io.rinex.read_rinex_obs does: the filters' IMU samples
    # cover (t_k-1, t_k] of consecutive grid epochs.
    t_read = np.asarray(times)
    interval = _interval({}, t_read)
    if t_read.size > 1:
        idx = np.rint((t_read - t_read[0]) / interval).astype(np.int64)
        off = np.abs(t_read - t_read[0] - idx * interval)
        if np.any(off > 1e-3):
            k = int(np.argmax(off > 1e-3))
            raise InputError(f"epoch {t_read[k]:.4f} GPS s is {off[k] * 1e3:.1f} ms off the "
                             f"{interval:g}-s grid of the log", file=path, record=offsets[k],
                             expected="RXM-RAWX epochs on one regular interval")
    else:
        idx = np.zeros(1, np.int64)
    T = int(idx[-1]) + 1
    t_gps = t_read[0] + interval * np.arange(T)
    t_gps[idx] = t_read
    present = np.zeros(T, bool)
    present[idx] = True
    counts["missing_epochs"] = int(T - t_read.size)
    if T > t_read.size:
        warnings.warn(f"{path}: {T - t_read.size} missing RXM-RAWX epoch(s) of the "
                      f"{interval:g}-s grid left empty", stacklevel=3)
    # every (letter, code) that occurs, in the fixed slots of io.rinex.SLOTS
    present_codes: dict[str, set[str]] = {}
    for rows in epochs:
        for g, _, sig, *_ in rows:
            letter = GNSS_LETTER.get(g)
            if letter in systems and (g, sig) in SIGNAL_CODES:
                present_codes.setdefault(letter, set()).add(SIGNAL_CODES[(g, sig)])
    arrays = {}
    for letter, bands in present_codes.items():
        first, n = SLOTS[letter]
        arrays[letter] = {
            f"{kind}{b}": np.full((T, n), np.nan) for b in bands for kind in "CLDS"
        } | {f"{aux}{b}": np.full((T, n), np.nan) for b in bands for aux in ("lock", "sub")}
    dropped = {"unknown_signal": 0, "slot_out_of_range": 0, "half_cycle_unresolved": 0}
    for k_read, rows in enumerate(epochs):
        k = int(idx[k_read])
        for g, sv, sig, pr, cp, dop, cno, lock, pr_ok, cp_ok, half, sub in rows:
            letter = GNSS_LETTER.get(g)
            if letter not in systems:
                continue
            band = SIGNAL_CODES.get((g, sig))
            if band is None:
                dropped["unknown_signal"] += 1
                continue
            prn = sv - 100 if letter == "S" else sv
            first, n = SLOTS[letter]
            j = prn - first
            if not 0 <= j < n:
                dropped["slot_out_of_range"] += 1
                continue
            a = arrays[letter]
            if pr_ok:
                a[f"C{band}"][k, j] = pr
            if cp_ok and half:
                a[f"L{band}"][k, j] = cp
                a[f"lock{band}"][k, j] = lock
                a[f"sub{band}"][k, j] = sub
            elif cp_ok:
                dropped["half_cycle_unresolved"] += 1
            a[f"D{band}"][k, j] = dop
            a[f"S{band}"][k, j] = cno
    counts.update(dropped)
    if dropped["unknown_signal"] or dropped["slot_out_of_range"]:
        warnings.warn(f"{path}: measurements not read: {dropped['unknown_signal']} of signals "
                      f"without a RINEX code, {dropped['slot_out_of_range']} of satellites "
                      "outside the PRN slots", stacklevel=3)
    reset = np.zeros(T, bool)
    reset[idx] = resets
    dt_ms = np.concatenate([[np.inf], np.diff(t_gps) * 1e3])
    out = {}
    for letter, a in arrays.items():
        first, n = SLOTS[letter]
        obs, mask, lli, codes = {}, {}, {}, {}
        for name, v in a.items():
            if name.startswith(("lock", "sub")):
                continue
            obs[name] = v
            mask[name] = np.isfinite(v)
            codes[name] = name
            if name[0] == "L":
                lock, sub = a[f"lock{name[1:]}"], a[f"sub{name[1:]}"]
                prev = np.vstack([np.full((1, n), np.nan), lock[:-1]])
                prev_sub = np.vstack([np.full((1, n), np.nan), sub[:-1]])
                # a changed sub-half-cycle flag: the receiver moved the phase by half a cycle
                slip = np.isfinite(lock) & (
                    ~np.isfinite(prev) | (lock < prev) | (lock < dt_ms[:, None]) | reset[:, None]
                    | (np.isfinite(prev_sub) & (sub != prev_sub))
                )
                lli[name] = slip.astype(np.int8)
        sv = np.array([f"{letter}{p:02d}" for p in range(first, first + n)])
        out[letter] = SystemObs(sv, obs, mask, lli, codes)
    week0 = int(t_gps[0] // SECONDS_PER_WEEK)
    obs = RinexObs(t_gps, present, out, interval,
                   np.full(3, np.nan), {"PROGRAM": ["read_ubx"]})

    def week_of(tow_s: float) -> float:
        """GPS seconds of a time of week, in the week nearest the first epoch."""
        t = week0 * SECONDS_PER_WEEK + tow_s
        return t + SECONDS_PER_WEEK * round((t_gps[0] - t) / SECONDS_PER_WEEK)

    return obs, week_of


def _nav_pvt(pvt, week_of) -> NavPvt:
    n = len(pvt)
    llh = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    cols = {k: np.zeros(n) for k in ("t", "h", "v", "fix", "carr", "nsv", "msl")}
    for i, (_, m) in enumerate(pvt):
        cols["t"][i] = week_of(m.iTOW / 1e3)  # GPS time of week of the solution [ms]
        llh[i] = (math.radians(m.lat), math.radians(m.lon), m.height / 1e3)
        vel[i] = (m.velE / 1e3, m.velN / 1e3, -m.velD / 1e3)
        cols["h"][i], cols["v"][i], cols["msl"][i] = m.hAcc / 1e3, m.vAcc / 1e3, m.hMSL / 1e3
        cols["fix"][i], cols["carr"][i], cols["nsv"][i] = m.fixType, m.carrSoln, m.numSV
    return NavPvt(cols["t"], llh, cols["msl"], vel, cols["h"], cols["v"], cols["fix"].astype(int),
                  cols["carr"].astype(int), cols["nsv"].astype(int))

