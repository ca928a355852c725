"""Readers (and one writer) for real data: RINEX, SP3, CLK, IONEX, IMU logs, RTKLIB .pos.

Readers run on the host (numpy / georinex) and return NamedTuples of numpy arrays on fixed
shapes with masks; the product interpolators (``sp3_position``, ``clock_bias``, ``ionex_vtec``)
are pure JAX. All times are GPS seconds (since 1980-01-06 00:00:00 GPST). Bad input raises
``InputError`` naming the file, the line / record / epoch and what was expected.
"""

from jaxnav.core.gpstime import (
    GPS_EPOCH,
    datetime64_to_gps_seconds,
    gps_seconds_to_datetime64,
    gps_seconds_to_week_tow,
    week_tow_to_gps_seconds,
)
from jaxnav.io.errors import InputError
from jaxnav.io.imu import (
    ImuIncrements,
    ImuLog,
    TimeTag,
    imu_increments,
    read_imu_csv,
    read_timetag,
    sensor_to_body_dcm,
)
from jaxnav.io.nav import ephemeris_from_records, read_broadcast_ephemeris, read_rinex_nav
from jaxnav.io.pos import Q_OUTAGE, PosSolution, covariance_enu, read_pos, write_pos
from jaxnav.io.products import (
    ClockInterp,
    ClockTable,
    GridTable,
    IonexMaps,
    IonexTable,
    Sp3Orbit,
    clock_bias,
    clock_table,
    ionex_table,
    ionex_vtec,
    orbit_table,
    read_clk,
    read_code_dcb,
    read_ionex,
    read_sp3,
    sp3_position,
    sp3_position_velocity,
)
from jaxnav.io.rinex import (
    DEFAULT_PRIORITY,
    DEFAULT_SIGNALS,
    SLOTS,
    RinexObs,
    SystemObs,
    read_rinex_obs,
)
from jaxnav.io.ubx import read_ubx
from jaxnav.io.ubx_nav import ephemeris_from_sfrbx

__all__ = [
    "GPS_EPOCH",
    "DEFAULT_PRIORITY",
    "DEFAULT_SIGNALS",
    "Q_OUTAGE",
    "SLOTS",
    "ClockInterp",
    "ClockTable",
    "GridTable",
    "ImuIncrements",
    "ImuLog",
    "InputError",
    "IonexMaps",
    "IonexTable",
    "PosSolution",
    "RinexObs",
    "Sp3Orbit",
    "SystemObs",
    "TimeTag",
    "clock_bias",
    "clock_table",
    "covariance_enu",
    "datetime64_to_gps_seconds",
    "gps_seconds_to_datetime64",
    "gps_seconds_to_week_tow",
    "imu_increments",
    "ionex_table",
    "ionex_vtec",
    "orbit_table",
    "read_clk",
    "read_code_dcb",
    "read_imu_csv",
    "read_ionex",
    "read_pos",
    "read_broadcast_ephemeris",
    "ephemeris_from_records",
    "read_ubx",
    "ephemeris_from_sfrbx",
    "read_rinex_nav",
    "read_rinex_obs",
    "read_sp3",
    "read_timetag",
    "sensor_to_body_dcm",
    "sp3_position",
    "sp3_position_velocity",
    "week_tow_to_gps_seconds",
    "write_pos",
]
