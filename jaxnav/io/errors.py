"""The one exception every jaxnav reader raises on bad input, and the shared GPS time scale.

``InputError`` names the file, the place in it (line, record or epoch) and what was expected,
so a user can open the file at the right spot. It subclasses ``ValueError`` so generic callers
that catch ``ValueError`` keep working.

Time scale used by all readers: **GPS seconds** = seconds of GPS time (GPST, continuous, no
leap seconds) elapsed since the GPS epoch 1980-01-06 00:00:00 GPST, as float64. At today's
values (~1.4e9 s) float64 resolves 0.24 us, i.e. < 1 mm of satellite motion.
"""

from __future__ import annotations

from os import PathLike

import numpy as np

# The GPS epoch as a numpy datetime64; GPST calendar dates are read as if they were a
# leap-second-free scale (which GPST is), so datetime64 arithmetic is exact here.
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")
SECONDS_PER_WEEK = 604800.0
# RTKLIB's gtime_t counts GPST seconds from 1970-01-01 (the Unix origin on the GPST scale);
# the GPS epoch is 3657 days later.
GTIME_TO_GPS_SECONDS = -315964800.0


class InputError(ValueError):
    """Bad input file: says which file, where (line / record / epoch) and what was expected."""

    def __init__(
        self,
        message: str,
        *,
        file: str | PathLike | None = None,
        line: int | None = None,
        record: int | None = None,
        epoch: object | None = None,
        expected: str | None = None,
    ):
        self.file = None if file is None else str(file)
        self.line = line
        self.record = record
        self.epoch = epoch
        self.expected = expected
        self.message = message
        where = []
        if self.file is not None:
            where.append(self.file)
        if line is not None:
            where.append(f"line {line}")
        if record is not None:
            where.append(f"record {record}")
        if epoch is not None:
            where.append(f"epoch {epoch}")
        text = ", ".join(where)
        text = f"{text}: {message}" if text else message
        if expected:
            text += f" (expected {expected})"
        super().__init__(text)


def datetime64_to_gps_seconds(t) -> np.ndarray:
    """GPS seconds of GPST calendar times: t_gps = (t - 1980-01-06T00:00:00) [s], float64."""
    ns = (np.asarray(t, dtype="datetime64[ns]") - GPS_EPOCH).astype(np.int64)
    # Whole seconds and the fraction separately, so the float64 result is correctly rounded.
    return (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000) * 1e-9


def gps_seconds_to_datetime64(t_gps_s) -> np.ndarray:
    """Inverse of ``datetime64_to_gps_seconds`` (nanosecond resolution)."""
    ns = np.round(np.asarray(t_gps_s, dtype=np.float64) * 1e9).astype(np.int64)
    return GPS_EPOCH + ns.astype("timedelta64[ns]")


def gps_seconds_to_week_tow(t_gps_s):
    """GPS week number and time of week [s]: week = floor(t / 604800), tow = t - 604800 week."""
    t = np.asarray(t_gps_s, dtype=np.float64)
    week = np.floor(t / SECONDS_PER_WEEK).astype(np.int64)
    return week, t - week * SECONDS_PER_WEEK


def week_tow_to_gps_seconds(week, tow_s) -> np.ndarray:
    """GPS seconds from GPS week and time of week: t = 604800 week + tow."""
    return np.asarray(week, dtype=np.float64) * SECONDS_PER_WEEK + np.asarray(tow_s, np.float64)
