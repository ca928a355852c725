"""The GPS time scale every jaxnav module uses, and its conversions.

**GPS seconds** = seconds of GPS time (GPST, continuous, no leap seconds) elapsed since the GPS
epoch 1980-01-06 00:00:00 GPST, as float64. At today's values (~1.4e9 s) float64 resolves
0.24 us, i.e. < 1 mm of satellite motion. GPST calendar dates are handled as a leap-second-free
scale (which GPST is), so datetime64 arithmetic is exact.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")
SECONDS_PER_WEEK = 604800.0
# RTKLIB's gtime_t counts GPST seconds from 1970-01-01 (the Unix origin on the GPST scale);
# the GPS epoch is 3657 days later.
GTIME_TO_GPS_SECONDS = -315964800.0
GPS_UTC_LEAP_S = 18.0  # GPST - UTC since 2017-01-01 (IERS Bulletin C); UT1 ~ UTC to < 1 s


def datetime64_to_gps_seconds(t) -> np.ndarray:
    """GPS seconds of GPST calendar times: t_gps = (t - 1980-01-06T00:00:00) [s], float64."""
    ns = (np.asarray(t, dtype="datetime64[ns]") - GPS_EPOCH).astype(np.int64)
    # Whole seconds and the fraction separately, so the float64 result is correctly rounded.
    return (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000) * 1e-9


def gps_seconds(when) -> float:
    """GPS seconds of one GPST calendar time (datetime64 or ISO string), as a host float."""
    return float(datetime64_to_gps_seconds(np.datetime64(when, "ns")))


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


def gps_seconds_of_week(t_gps_s):
    """Seconds of the GPS week, t mod 604800 (traceable)."""
    return jnp.mod(t_gps_s, SECONDS_PER_WEEK)


def day_of_year(t_gps_s) -> float:
    """Fractional day of year (1.0 = Jan 1 00:00) of a GPS time (host side; no leap seconds)."""
    when = GPS_EPOCH + np.timedelta64(int(round(float(t_gps_s) * 1e9)), "ns")
    year_start = when.astype("datetime64[Y]").astype("datetime64[ns]")
    return 1.0 + float((when - year_start).astype(np.int64)) * 1e-9 / 86400.0
