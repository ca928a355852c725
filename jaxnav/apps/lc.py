"""``jaxnav lc``: loosely coupled GNSS/INS on a recorded drive, with withheld-GNSS outages.

    jaxnav lc --imu IMU.csv --imu-tag IMU.csv.tag --gnss GNSS.pos --config CAR.toml
              [--outages SCHEDULE | --outage-grid START:STEP:LENGTH] [--duration S]
              --out OUT.pos [--sweep DIR [--overwrite]]

The filter is ``jaxnav.filter.loose`` (full IMU, 15/21/27 error states) aided by the positions
(and, with ``gnss.use_velocity``, velocities) of an RTKLIB ``.pos`` track, with the vehicle
constraints of ``jaxnav.filter.constraints`` (non-holonomic constraint; ZUPT + ZARU on detected
standstill, allowed only where the GNSS is withheld or slow, see ``epoch_inputs``; no
odometer). The car configuration (TOML, ``configs/car_gnss_imu_drive.toml`` documents every key)
gives the IMU mounting, lever arms, time offset, noise and the constraint switches.

Data flow (documented choices where the sources are silent):

- IMU: ``jaxnav.io.read_imu_csv`` (+ the RTKLIB time tag, + ``imu.time_offset_s``), rotated to
  the body frame with ``sensor_to_body_dcm(mounting + misalignment)``, trapezoidal increments.
  They are **resampled** onto a grid of ``imu.resample_hz`` aligned with the GNSS epochs (the
  loose filter needs K equal samples per epoch): the cumulative integrals of angular rate and
  specific force are interpolated linearly at the grid times and differenced, which keeps every
  integral over the drive (it spreads each sample over at most two grid intervals).
- GNSS: the ``.pos`` epochs on a regular grid (their median interval; a missing epoch is an
  invalid fix); the fix covariance is RTKLIB's sdn/sde/sdu (+ cross terms) with a floor
  ``gnss.pos_sigma_floor_m`` added in quadrature (lever-arm survey and IMU-GNSS timing errors
  that RTKLIB's cm-level sigmas do not contain), likewise for the velocity.
- Epochs: the first filter epoch ends at the second GNSS epoch inside the IMU log (the first one
  is the initial state's time), the last is the last GNSS epoch inside the log (or before
  ``--duration``).
- Initialisation (in-motion alignment, ``loose`` module docstring): position from the first
  fix, roll and pitch by levelling the mean specific force of the first ``alignment.level_s``
  seconds (the log should start at rest), heading unknown until the first fix faster than
  ``alignment.min_speed_m_s``, where it is set to the course over ground. ZUPT/ZARU calibrate
  the gyros while standing; the detector's reference variance is measured over the same
  levelling window (``constraints.zupt_ref_sigma_m_s2 = "start"``: an idling engine shakes the
  IMU far above its white noise). A log whose first fix is faster than the alignment speed is
  aligned at once from that fix's course.
- Outages: GNSS epochs t with start <= t - t_imu0 < start + length withheld (position and
  velocity), t_imu0 the first IMU sample time; from a schedule file (``id,start_s,length_s``,
  ``jaxnav.study.outages.read_schedule``, no overlaps) or a grid START:STEP:LENGTH (starts START,
  START + STEP, ... while the window ends inside the drive; STEP > LENGTH).
- Output: the INS solution **at the antenna** (IMU position + C_b^l l^b with the estimated
  attitude; velocity with the lever-arm rotation term) at every filter epoch, RTKLIB ``.pos``;
  outage epochs get Q = 7 (``jaxnav.io.Q_OUTAGE``), aided epochs keep the fix's Q and ns; sigmas
  from the filter covariance (position block rotated to ENU metres).
- Per-outage report: start [s after t_imu0], length, distance travelled (RTK track), maximum and
  final 2D error against the RTK track (``jaxnav.study.metrics.window_metrics``: the ``.pos``
  itself is the reference, cm-level when fixed).

Outage sweep (``--sweep DIR``): every start on a grid of ``sweep.spacing_s`` from
``sweep.convergence_s``, each of ``sweep.durations_s``, for each constraint mode in
``sweep.modes``, evaluated by the checkpoint-forking engine ``jaxnav.study.sweep.run_sweep``
(one full run per mode with checkpoints at the outage starts, then all outage windows as one
``vmap`` from their checkpoints, chunked): the drive is its "scenario factory" (``DriveFactory``)
with one pseudo-satellite slot whose keep mask is the GNSS fix's validity. Writes
``DIR/results.nc`` and the report's tables and plots (``jaxnav.study.report``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import math
import os
import sys
import time
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.core import states as st
from jaxnav.filter import constraints as cons
from jaxnav.filter import loose
from jaxnav.filter.systems import InsSystem, NavSigmas
from jaxnav.ins import errors as ins_errors
from jaxnav.ins import strapdown
from jaxnav.io import imu as imu_io
from jaxnav.io import pos as pos_io
from jaxnav.io.errors import InputError
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot

PROG = "jaxnav lc"
_LAYOUTS = {"ins15": st.INS15, "ins21": st.INS21, "ins27": st.INS27}
#: Sweep modes: which vehicle constraints the filter uses (ZUPT includes ZARU).
SWEEP_MODES = {"nhc_zupt": (True, True), "zupt": (False, True), "nhc": (True, False),
               "free": (False, False)}  # fmt: skip
# Body forward-right-down (the source configuration's lever arms) -> right-forward-up.
_FRD_TO_RFU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_DEG_H = math.pi / 180.0 / 3600.0  # rad/s per deg/h
_UG = imu_io.STANDARD_GRAVITY * 1e-6  # m/s^2 per micro-g


# ----------------------------------------------------------------------------------------------
# Car configuration (TOML)
# ----------------------------------------------------------------------------------------------
class CarConfigError(ValueError):
    """An invalid car configuration; the message names the file, section, key and expectation."""


@dataclasses.dataclass(frozen=True)
class CarConfig:
    """Everything ``jaxnav lc`` needs about the vehicle, its sensors and the filter.

    Field names are ``section_key`` of the TOML; units are in the names. Sources of the values
    are given in ``configs/car_gnss_imu_drive.toml``; the defaults here are only for the keys
    that are not sensor-specific (the mounting, lever arms and noise densities are required).
    """

    # [imu]
    imu_mounting_rpy_deg: tuple[float, float, float]
    imu_misalignment_rpy_deg: tuple[float, float, float]
    imu_time_offset_s: float
    imu_gyro_unit: str = "deg/s"
    imu_accel_unit: str = "g"
    imu_resample_hz: float = 100.0
    # [imu_errors]
    imu_errors_states: str = "ins27"
    imu_errors_gyro_noise_deg_s_sqrt_hz: float = float("nan")
    imu_errors_accel_noise_ug_sqrt_hz: float = float("nan")
    imu_errors_gyro_vibration_deg_s_sqrt_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu_errors_accel_vibration_ug_sqrt_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu_errors_gyro_bias_turn_on_deg_s: float = 0.5
    imu_errors_gyro_bias_gm_sigma_deg_h: float = 36.0
    imu_errors_gyro_bias_gm_tau_s: float = 300.0
    imu_errors_accel_bias_turn_on_mg: float = 40.0
    imu_errors_accel_bias_gm_sigma_mg: float = 0.5
    imu_errors_accel_bias_gm_tau_s: float = 300.0
    imu_errors_gyro_scale_ppm: float = 10000.0
    imu_errors_accel_scale_ppm: float = 10000.0
    # [lever_arms] body forward, right, down [m] from the vehicle reference point
    lever_arms_imu_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lever_arms_antenna_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lever_arms_nhc_point_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # [gnss]
    gnss_use_velocity: bool = True
    gnss_pos_sigma_floor_m: float = 0.05
    gnss_vel_sigma_floor_m_s: float = 0.02
    # [constraints]
    constraints_nhc: bool = True
    constraints_nhc_sigma_m_s: float = 1.0
    constraints_zupt: bool = True
    constraints_zaru: bool = True
    constraints_zupt_sigma_m_s: float = 0.02
    constraints_zupt_threshold: float = 2.5
    constraints_zupt_ref_sigma_m_s2: str | float = "start"
    constraints_zupt_max_speed_m_s: float = 1.0
    constraints_zupt_with_gnss_vel: bool = False
    constraints_zupt_gnss_speed_m_s: float = 0.1
    # [alignment]
    alignment_level_s: float = 1.0
    alignment_min_speed_m_s: float = 3.0
    alignment_heading_floor_deg: float = 1.15
    alignment_roll_pitch_sigma_deg: float = 3.0
    alignment_vel_sigma_m_s: float = 0.1
    # [filter]
    filter_cov_substeps: int = 5
    filter_gate_chi2: float = float("inf")
    # [sweep]
    sweep_modes: tuple[str, ...] = ("nhc_zupt", "zupt")
    sweep_durations_s: tuple[float, ...] = (10.0, 15.0, 30.0)
    sweep_spacing_s: float = 5.0
    sweep_convergence_s: float = 60.0
    sweep_recovery_s: float = 10.0
    sweep_chunk_size: int = 128

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


_REQUIRED = (
    "imu_mounting_rpy_deg", "imu_misalignment_rpy_deg", "imu_time_offset_s",
    "imu_errors_gyro_noise_deg_s_sqrt_hz", "imu_errors_accel_noise_ug_sqrt_hz",
    "lever_arms_imu_frd_m", "lever_arms_antenna_frd_m",
)  # fmt: skip
_SECTIONS = ("imu", "imu_errors", "lever_arms", "gnss", "constraints", "alignment", "filter",
             "sweep")  # fmt: skip
# Value checks per field kind: (predicate, expectation text).
_NONNEG = ("a number >= 0", lambda v: v >= 0)
_POS = ("a number > 0", lambda v: v > 0)
_ANY = ("a number", lambda v: True)
_CHECKS: dict[str, tuple[str, Any]] = {
    "imu_time_offset_s": _ANY,
    "imu_resample_hz": _POS,
    "imu_errors_gyro_noise_deg_s_sqrt_hz": _POS,
    "imu_errors_accel_noise_ug_sqrt_hz": _POS,
    "imu_errors_gyro_bias_gm_tau_s": _POS,
    "imu_errors_accel_bias_gm_tau_s": _POS,
    "constraints_nhc_sigma_m_s": _POS,
    "constraints_zupt_sigma_m_s": _POS,
    "constraints_zupt_threshold": _POS,
    "constraints_zupt_max_speed_m_s": _POS,
    "constraints_zupt_gnss_speed_m_s": _POS,
    "alignment_level_s": _POS,
    "alignment_min_speed_m_s": _POS,
    "filter_gate_chi2": _POS,
    "sweep_spacing_s": _POS,
    "sweep_convergence_s": _NONNEG,
    "sweep_recovery_s": _NONNEG,
}
_CHOICES = {
    "imu_gyro_unit": ("deg/s", "rad/s"),
    "imu_accel_unit": ("g", "m/s^2"),
    "imu_errors_states": tuple(_LAYOUTS),
}


def _is_num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _field_types() -> dict[str, Any]:
    return {f.name: f.type for f in dataclasses.fields(CarConfig)}


def _convert(source: str, name: str, value, ftype: str):
    section, key = next(
        (s, name[len(s) + 1 :]) for s in sorted(_SECTIONS, key=len, reverse=True)
        if name.startswith(s + "_")
    )
    where = f"{source}: [{section}] {key} = {value!r}"

    def fail(expected):
        raise CarConfigError(f"{where}: expected {expected}")

    if ftype == "bool":
        if not isinstance(value, bool):
            fail("true or false")
        return value
    if ftype == "str":
        allowed = _CHOICES.get(name)
        if not isinstance(value, str) or (allowed and value not in allowed):
            fail("one of " + ", ".join(map(repr, allowed)) if allowed else "a string")
        return value
    if ftype == "int":
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            fail("a whole number >= 1")
        return value
    if ftype == "float":
        text, ok = _CHECKS.get(name, _NONNEG)
        if name == "filter_gate_chi2" and value == "inf":
            return float("inf")
        if not _is_num(value) or not ok(value):
            fail(text + (' (or "inf")' if name == "filter_gate_chi2" else ""))
        return float(value)
    if ftype == "str | float":  # constraints.zupt_ref_sigma_m_s2
        if value == "start":
            return value
        if not _is_num(value) or value <= 0:
            fail('"start" or a number > 0')
        return float(value)
    if ftype == "tuple[float, float, float]":
        ok3 = isinstance(value, list) and len(value) == 3 and all(map(_is_num, value))
        if "vibration" in name and ok3 and min(value) < 0:
            ok3 = False
        if not ok3:
            fail("a list of 3 numbers" + (" >= 0" if "vibration" in name else ""))
        return tuple(float(v) for v in value)
    if ftype == "tuple[float, ...]":
        if not isinstance(value, list) or not value or not all(_is_num(v) and v > 0
                                                             for v in value):
            fail("a non-empty list of numbers > 0")
        if len(set(value)) != len(value):
            fail("distinct values")
        return tuple(float(v) for v in value)
    if ftype == "tuple[str, ...]":
        if (not isinstance(value, list) or not value
                or not all(isinstance(v, str) and v in SWEEP_MODES for v in value)):
            fail("a non-empty list of modes from " + ", ".join(map(repr, SWEEP_MODES)))
        if len(set(value)) != len(value):
            fail("distinct values")
        return tuple(value)
    raise AssertionError(ftype)  # pragma: no cover


def config_from_dict(data: Mapping, source: str = "<config>") -> CarConfig:
    """Validate the TOML tables and build a ``CarConfig`` (errors name file, section and key)."""
    types = _field_types()
    values: dict[str, Any] = {}
    for section, table in data.items():
        if section not in _SECTIONS:
            raise CarConfigError(
                f"{source}: unknown section [{section}]; allowed: "
                + ", ".join(f"[{s}]" for s in _SECTIONS)
            )
        if not isinstance(table, Mapping):
            raise CarConfigError(f"{source}: {section} = {table!r}: expected a [{section}] table")
        for key, value in table.items():
            name = f"{section}_{key}"
            allowed = [f[len(section) + 1 :] for f in types if f.startswith(section + "_")
                       and not any(f.startswith(s + "_") for s in _SECTIONS
                                   if len(s) > len(section) and s.startswith(section))]
            if name not in types or key not in allowed:
                raise CarConfigError(
                    f"{source}: unknown key [{section}] {key}; allowed keys in [{section}]: "
                    + ", ".join(allowed)
                )
            values[name] = _convert(source, name, value, types[name])
    missing = [n for n in _REQUIRED if n not in values]
    if missing:
        n = missing[0]
        section = next(s for s in sorted(_SECTIONS, key=len, reverse=True)
                       if n.startswith(s + "_"))
        raise CarConfigError(
            f"{source}: missing key [{section}] {n[len(section) + 1 :]} (sensor-specific, no "
            f"default)"
        )
    cfg = CarConfig(**values)
    k = cfg.imu_resample_hz
    if abs(k - round(k)) > 1e-9:
        raise CarConfigError(f"{source}: [imu] resample_hz = {k!r}: expected a whole number of Hz")
    return cfg


def load_config(path: str | os.PathLike) -> CarConfig:
    """Read and validate a car configuration TOML file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise CarConfigError(f"{path}: cannot read the configuration: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CarConfigError(f"{path}: not valid TOML: {exc}") from None
    return config_from_dict(data, str(path))


def _frd_to_rfu(v) -> np.ndarray:
    return _FRD_TO_RFU @ np.asarray(v, np.float64)


def lever_arms_b(cfg: CarConfig) -> tuple[np.ndarray, np.ndarray]:
    """(antenna, NHC point) offsets from the IMU in body right-forward-up axes [m]."""
    imu = np.asarray(cfg.lever_arms_imu_frd_m)
    ant = _frd_to_rfu(np.asarray(cfg.lever_arms_antenna_frd_m) - imu)
    nhc = _frd_to_rfu(np.asarray(cfg.lever_arms_nhc_point_frd_m) - imu)
    return ant, nhc


def imu_error_model(cfg: CarConfig) -> ins_errors.ImuErrorModel:
    """The filter's stochastic IMU model from the configuration.

    White noise density -> ARW / VRW (deg/s/sqrt(Hz) = deg/sqrt(s)); the sensor's own density
    and the installed vibration density (per body axis) add in quadrature.
    """
    gyro = np.hypot(cfg.imu_errors_gyro_noise_deg_s_sqrt_hz,
                    np.asarray(cfg.imu_errors_gyro_vibration_deg_s_sqrt_hz))
    accel = np.hypot(cfg.imu_errors_accel_noise_ug_sqrt_hz,
                     np.asarray(cfg.imu_errors_accel_vibration_ug_sqrt_hz))
    return ins_errors.ImuErrorModel(
        accel_vrw_m_s_sqrt_s=jnp.asarray(accel * _UG),
        gyro_arw_rad_sqrt_s=jnp.asarray(np.radians(gyro)),
        accel_bias_sigma_m_s2=cfg.imu_errors_accel_bias_gm_sigma_mg * 1e3 * _UG,
        accel_bias_tau_s=cfg.imu_errors_accel_bias_gm_tau_s,
        gyro_bias_sigma_rad_s=cfg.imu_errors_gyro_bias_gm_sigma_deg_h * _DEG_H,
        gyro_bias_tau_s=cfg.imu_errors_gyro_bias_gm_tau_s,
        accel_scale_sigma=cfg.imu_errors_accel_scale_ppm * 1e-6,
        gyro_scale_sigma=cfg.imu_errors_gyro_scale_ppm * 1e-6,
        accel_bias_ton_sigma_m_s2=cfg.imu_errors_accel_bias_turn_on_mg * 1e3 * _UG,
        gyro_bias_ton_sigma_rad_s=math.radians(cfg.imu_errors_gyro_bias_turn_on_deg_s),
    )


# ----------------------------------------------------------------------------------------------
# The drive: IMU + GNSS on one epoch grid
# ----------------------------------------------------------------------------------------------
class Drive(NamedTuple):
    """A recorded drive on the filter's epoch grid (host arrays; E epochs of K IMU samples)."""

    t_imu0_gps_s: float  # first IMU sample time (origin of outage start times)
    t_init_gps_s: float  # time of the initial state (end of epoch -1)
    epoch_dt_s: float
    imu_dt_s: float
    time_gps_s: np.ndarray  # [E] epoch end times
    samples: strapdown.ImuIncrements  # [E, K, 3] body-frame increments
    fixes: loose.GnssFix  # [E] GNSS aiding (validity = file epoch present and finite)
    fix_init: loose.GnssFix  # the fix at t_init
    ref_llh: np.ndarray  # [E, 3] RTK reference (the .pos, antenna)
    ref_vel_enu: np.ndarray  # [E, 3]
    q: np.ndarray  # [E] the .pos quality (0 where the epoch is missing)
    ns: np.ndarray  # [E]
    level_f_b: np.ndarray  # [3] mean specific force of the levelling window
    level_f_var: float  # detector statistic max(var f_fwd, var |f|) there, epoch mean [m^2/s^4]
    start_speed_m_s: float  # GNSS horizontal speed at t_init
    gnss_speed_m_s: np.ndarray  # [E] horizontal speed of the fix (inf where no valid fix)

    @property
    def n_epochs(self) -> int:
        return int(self.time_gps_s.size)

    @property
    def time_rel_s(self) -> np.ndarray:
        """Epoch times relative to the first IMU sample (outage schedules use this origin)."""
        return self.time_gps_s - self.t_imu0_gps_s


def resample_increments(inc: imu_io.ImuIncrements, t0_gps_s: float, dt_s: float, n: int):
    """Increments over the grid (t0 + (j-1) dt, t0 + j dt], j = 1..n: differences of the linearly
    interpolated cumulative integrals (module docstring). Returns (dtheta [n, 3], dv [n, 3])."""
    t = np.concatenate([[inc.time_gps_s[0] - inc.dt_s[0]], inc.time_gps_s])
    grid = t0_gps_s + dt_s * np.arange(n + 1)
    if grid[0] < t[0] - 1e-9 or grid[-1] > t[-1] + 1e-9:
        raise ValueError(
            f"resampling grid [{grid[0]:.3f}, {grid[-1]:.3f}] leaves the IMU log "
            f"[{t[0]:.3f}, {t[-1]:.3f}] (GPS s)"
        )
    out = []
    for x in (inc.dtheta_b, inc.dv_b):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
        at = np.stack([np.interp(grid, t, cum[:, i]) for i in range(3)], axis=1)
        out.append(np.diff(at, axis=0))
    return out[0], out[1]


def gnss_fixes_from_pos(sol) -> loose.GnssFix:
    """``GnssFix`` epochs from an RTKLIB solution (``jaxnav.io.pos.PosSolution``).

    Outage epochs (Q = 7) and missing values are marked invalid (their values replaced by finite
    placeholders). Matching the solution epochs to the IMU epochs is the caller's job.
    """
    llh = np.asarray(sol.llh, np.float64)
    cov_p = pos_io.covariance_enu(sol.sd_neu_m, sol.sd_cross_m)
    vel = np.asarray(sol.vel_enu, np.float64)
    cov_v = pos_io.covariance_enu(sol.sd_vel_neu, sol.sd_vel_cross)
    ok_p = ~np.asarray(sol.outage) & np.isfinite(llh).all(-1) & np.isfinite(cov_p).all((-1, -2))
    ok_v = ~np.asarray(sol.outage) & np.isfinite(vel).all(-1) & np.isfinite(cov_v).all((-1, -2))
    eye = np.broadcast_to(np.eye(3), cov_p.shape)
    return loose.GnssFix(
        jnp.asarray(np.where(ok_p[:, None], llh, 0.0)),
        jnp.asarray(np.where(ok_p[:, None, None], cov_p, eye)),
        jnp.asarray(np.where(ok_v[:, None], vel, 0.0)),
        jnp.asarray(np.where(ok_v[:, None, None], cov_v, eye)),
        jnp.asarray(ok_p),
        jnp.asarray(ok_v),
    )


def _fix_covariances(sol: pos_io.PosSolution, cfg: CarConfig):
    cov_p = pos_io.covariance_enu(sol.sd_neu_m, sol.sd_cross_m)
    cov_v = pos_io.covariance_enu(sol.sd_vel_neu, sol.sd_vel_cross)
    eye = np.eye(3)
    cov_p = cov_p + cfg.gnss_pos_sigma_floor_m**2 * eye
    cov_v = cov_v + cfg.gnss_vel_sigma_floor_m_s**2 * eye
    return cov_p, cov_v


def load_drive(
    imu_path, tag_path, gnss_path, cfg: CarConfig, *, duration_s: float | None = None
) -> Drive:
    """Read the IMU log and the GNSS track and put them on the filter's epoch grid."""
    log = imu_io.read_imu_csv(
        imu_path, tag_path, gyro_unit=cfg.imu_gyro_unit, accel_unit=cfg.imu_accel_unit,
        time_offset_s=cfg.imu_time_offset_s,
    )
    sol = pos_io.read_pos(gnss_path)
    if not sol.has_velocity:
        raise InputError(
            "no velocity columns", file=gnss_path,
            expected="vn ve vu sdvn ... columns (RTKLIB output with velocity)",
        )
    rpy = np.add(cfg.imu_mounting_rpy_deg, cfg.imu_misalignment_rpy_deg)
    inc = imu_io.imu_increments(log, imu_io.sensor_to_body_dcm(*rpy))

    t_gnss = sol.time_gps_s
    dt_ep = round(float(np.median(np.diff(t_gnss))), 3)  # .pos times carry milliseconds
    k_f = dt_ep * cfg.imu_resample_hz
    K = int(round(k_f))
    if K < 1 or abs(k_f - K) > 1e-6:
        raise ValueError(
            f"GNSS epoch interval {dt_ep} s is not a whole number of IMU intervals at "
            f"[imu] resample_hz = {cfg.imu_resample_hz:g}"
        )
    t_imu0, t_imu1 = float(log.time_gps_s[0]), float(log.time_gps_s[-1])
    if duration_s is not None:
        t_imu1 = min(t_imu1, t_imu0 + float(duration_s))
    inside = np.flatnonzero((t_gnss >= t_imu0) & (t_gnss <= t_imu1))
    if inside.size < 2:
        raise InputError(
            f"fewer than two GNSS epochs inside the IMU log [{t_imu0:.3f}, {t_imu1:.3f}] GPS s",
            file=gnss_path, expected="a GNSS track overlapping the IMU log",
        )
    i0 = int(inside[0])
    t_init = float(t_gnss[i0])
    t_end = min(t_imu1, float(t_gnss[inside[-1]]))  # the last GNSS epoch inside the log
    n_ep = int(np.floor((t_end - t_init) / dt_ep + 1e-6))
    grid = t_init + dt_ep * np.arange(n_ep + 1)  # grid[0] = initial state, grid[1:] epochs
    # Map the file's epochs onto the grid (within 1 ms); missing grid epochs are invalid fixes.
    idx = np.rint((t_gnss - t_init) / dt_ep).astype(np.int64)
    on_grid = (idx >= 0) & (idx <= n_ep) & (np.abs(t_gnss - t_init - idx * dt_ep) < 1e-3)
    src = np.full(n_ep + 1, -1, np.int64)
    src[idx[on_grid]] = np.flatnonzero(on_grid)
    have = src >= 0
    s = np.where(have, src, 0)

    cov_p, cov_v = _fix_covariances(sol, cfg)
    llh = sol.llh[s]
    vel = sol.vel_enu[s]
    ok = have & np.isfinite(llh).all(1) & np.isfinite(vel).all(1) & (sol.q[s] != pos_io.Q_OUTAGE)
    eye = np.broadcast_to(np.eye(3), (n_ep + 1, 3, 3))
    fix_all = loose.GnssFix(
        np.where(ok[:, None], llh, 0.0),
        np.where(ok[:, None, None], cov_p[s], eye),
        np.where(ok[:, None], vel, 0.0),
        np.where(ok[:, None, None], cov_v[s], eye),
        ok,
        ok,  # the velocity rows are switched by LooseConfig.use_vel; the alignment needs it
    )
    if not ok[0]:
        raise InputError(
            "no valid GNSS fix at the first epoch inside the IMU log", file=gnss_path,
            epoch=f"{t_init:.3f} GPS s", expected="a fix to initialise the position",
        )
    # Reference for the metrics: the file's solution; missing epochs interpolated in time.
    ref_llh = np.stack([np.interp(grid, t_gnss, sol.llh[:, i]) for i in range(3)], 1)
    ref_vel = np.stack([np.interp(grid, t_gnss, sol.vel_enu[:, i]) for i in range(3)], 1)

    dth, dv = resample_increments(inc, t_init, dt_ep / K, n_ep * K)
    samples = strapdown.ImuIncrements(dth.reshape(n_ep, K, 3), dv.reshape(n_ep, K, 3))
    n_level = max(int(round(cfg.alignment_level_s * cfg.imu_resample_hz)), 1)
    level_f = dv.reshape(-1, 3)[:n_level].sum(0) / (n_level * dt_ep / K)
    n_lev_ep = min(max(int(round(cfg.alignment_level_s / dt_ep)), 1), n_ep)
    stat = jax.vmap(cons.stationarity_statistics, (0, None))(
        jnp.asarray(samples.dv_b[:n_lev_ep]), dt_ep / K
    )
    level_var = float(jnp.mean(jnp.maximum(stat.var_forward, stat.var_norm)))
    first = jax.tree.map(lambda a: a[0], fix_all)
    rest = jax.tree.map(lambda a: a[1:], fix_all)
    return Drive(
        t_imu0_gps_s=t_imu0, t_init_gps_s=t_init, epoch_dt_s=dt_ep, imu_dt_s=dt_ep / K,
        time_gps_s=grid[1:], samples=samples, fixes=rest, fix_init=first,
        ref_llh=ref_llh[1:], ref_vel_enu=ref_vel[1:],
        q=np.where(have, sol.q[s], 0)[1:], ns=np.where(have, sol.ns[s], 0)[1:],
        level_f_b=level_f, level_f_var=level_var,
        start_speed_m_s=float(np.hypot(*sol.vel_enu[s[0], :2])),
        gnss_speed_m_s=np.where(ok, np.hypot(vel[:, 0], vel[:, 1]), np.inf)[1:],
    )


def rest_noise(drive: Drive, max_speed_m_s: float = 0.1):
    """Installed IMU noise at the initial standstill: std of the epoch-mean rate and specific
    force x sqrt(epoch length), per body axis, over the epochs before the RTK speed first
    exceeds ``max_speed_m_s``. Returns (gyro [deg/s/sqrt(Hz)], accel [ug/sqrt(Hz)], seconds)
    or None when the standstill is shorter than 2 s. Uses the IMU alone (the GNSS only to
    find the standstill)."""
    speed = np.hypot(drive.ref_vel_enu[:, 0], drive.ref_vel_enu[:, 1])
    n = int(np.argmax(speed > max_speed_m_s)) if np.any(speed > max_speed_m_s) else speed.size
    if n * drive.epoch_dt_s < 2.0:
        return None
    dt = drive.epoch_dt_s
    w = drive.samples.dtheta_b[:n].sum(1) / dt
    f = drive.samples.dv_b[:n].sum(1) / dt
    scale = math.sqrt(dt)
    return np.degrees(w.std(0, ddof=1)) * scale, f.std(0, ddof=1) * scale / _UG, n * dt


# ----------------------------------------------------------------------------------------------
# Filter set-up
# ----------------------------------------------------------------------------------------------
def build_filter(
    cfg: CarConfig, drive: Drive, *, nhc: bool | None = None, zupt: bool | None = None
) -> loose.LooseFilter:
    """The ``LooseFilter`` of the configuration (``nhc`` / ``zupt`` override the switches)."""
    lever_ant, lever_nhc = lever_arms_b(cfg)
    system = InsSystem(
        layout=_LAYOUTS[cfg.imu_errors_states], model=imu_error_model(cfg),
        lever_b=jnp.asarray(lever_ant),
    )
    use_nhc = cfg.constraints_nhc if nhc is None else nhc
    use_zupt = cfg.constraints_zupt if zupt is None else zupt
    lcfg = loose.LooseConfig(
        use_pos=True,
        use_vel=cfg.gnss_use_velocity,
        use_nhc=use_nhc,
        use_zupt=use_zupt,
        use_zaru=use_zupt and cfg.constraints_zaru,
        zupt_without_gnss_vel=not cfg.constraints_zupt_with_gnss_vel,
        cov_substeps=cfg.filter_cov_substeps,
        align_in_motion=True,
        align_min_speed_m_s=cfg.alignment_min_speed_m_s,
        align_sigma_floor_rad=math.radians(cfg.alignment_heading_floor_deg),
        nhc_sigma_m_s=cfg.constraints_nhc_sigma_m_s,
        zupt_sigma_m_s=cfg.constraints_zupt_sigma_m_s,
        zupt_ref_var=(drive.level_f_var if cfg.constraints_zupt_ref_sigma_m_s2 == "start"
                      else cfg.constraints_zupt_ref_sigma_m_s2**2),
        detector=cons.ZuptDetector(
            threshold=cfg.constraints_zupt_threshold,
            max_ins_speed_m_s=cfg.constraints_zupt_max_speed_m_s,
        ),
        vehicle_lever_b=jnp.asarray(lever_nhc),
        gate_chi2=cfg.filter_gate_chi2,
    )
    K = drive.samples.dv_b.shape[1]
    if K % cfg.filter_cov_substeps:
        raise CarConfigError(
            f"[filter] cov_substeps = {cfg.filter_cov_substeps}: expected a divisor of the {K} "
            f"IMU samples per GNSS epoch"
        )
    return loose.LooseFilter(system, lcfg, drive.imu_dt_s, drive.epoch_dt_s)


def initial_carry(cfg: CarConfig, lf: loose.LooseFilter, drive: Drive) -> loose.Carry:
    """Levelled start at the first fix; heading from the course if already moving, else
    unknown until the in-motion alignment (module docstring)."""
    fix = drive.fix_init
    moving = drive.start_speed_m_s > cfg.alignment_min_speed_m_s
    euler0 = np.array(loose.align_from_gnss(fix.vel_enu, drive.level_f_b))
    if not moving:
        euler0[2] = 0.0  # arbitrary: the in-motion alignment sets it
    lever_l = np.asarray(attitude.dcm_from_euler(jnp.asarray(euler0))) @ np.asarray(
        lf.system.lever_b
    )
    llh0 = np.asarray(fix.llh) - np.asarray(geodesy.llh_rate_matrix(jnp.asarray(fix.llh))) @ lever_l
    sd_pos = float(np.sqrt(np.max(np.diag(np.asarray(fix.cov_pos_enu)))))
    sig = NavSigmas(
        pos_m=max(sd_pos, 1e-3),
        vel_m_s=cfg.alignment_vel_sigma_m_s,
        roll_pitch_rad=math.radians(cfg.alignment_roll_pitch_sigma_deg),
        azimuth_rad=(math.radians(cfg.alignment_heading_floor_deg) if moving
                     else lf.cfg.align_prior_sigma_rad),
    )
    vel0 = np.asarray(fix.vel_enu) if moving else np.zeros(3)
    carry = loose.initial_carry(lf, loose.initial_nav(llh0, vel0, euler0), sig)
    return carry._replace(aligned=jnp.asarray(bool(moving)))


def epoch_inputs(cfg: CarConfig, drive: Drive, withheld=None) -> loose.EpochInput:
    """Stacked filter inputs; ``withheld`` [E] bool removes the GNSS fix of those epochs.

    ZUPT/ZARU are allowed (``EpochInput.zupt_allowed``) where the GNSS is absent or its speed is
    below ``constraints.zupt_gnss_speed_m_s``: with GNSS a car moving off at walking pace, whose
    vibration is that of the idling engine, is not taken for standing (without GNSS velocity
    rows, S002's rule "no ZUPT while GNSS velocity is used" does not apply). A withheld fix
    says nothing, so the detector alone decides there (the sweep's ``with_keep`` does the same).
    """
    fix = jax.tree.map(jnp.asarray, drive.fixes)
    slow = drive.gnss_speed_m_s < cfg.constraints_zupt_gnss_speed_m_s
    allowed = ~fix.pos_valid | jnp.asarray(slow)
    if withheld is not None:
        keep = ~jnp.asarray(withheld, bool)
        fix = fix._replace(pos_valid=fix.pos_valid & keep, vel_valid=fix.vel_valid & keep)
        allowed = allowed | ~keep
    samples = jax.tree.map(jnp.asarray, drive.samples)
    return loose.epoch_inputs(samples, fix, zupt_allowed=allowed)


def antenna_track(lever_b, out: loose.EpochOutput):
    """Antenna llh [.., 3] of the filter outputs (IMU position + C_b^l l^b, estimated attitude)."""

    def one(llh, euler):
        return strapdown.antenna_llh(llh, attitude.dcm_from_euler(euler), lever_b)

    f = one
    for _ in range(out.llh.ndim - 1):
        f = jax.vmap(f)
    return f(out.llh, out.euler)


@jax.jit
def _antenna_outputs(lever_b, out: loose.EpochOutput, dtheta_last_b, imu_dt_s):
    """Antenna llh, ENU velocity and ENU position / velocity sigmas per epoch."""

    def one(llh, vel, euler, P, bias, scale, dth):
        C = attitude.dcm_from_euler(euler)
        w_b = (dth / imu_dt_s - bias) / (1.0 + scale)  # compensated rate of the last sample
        llh_a = strapdown.antenna_llh(llh, C, lever_b)
        vel_a = strapdown.antenna_vel_enu(llh, vel, C, w_b, lever_b)
        m = geodesy.metres_per_radian(llh)  # north, east, up per (lat, lon, h)
        S = jnp.array([[0.0, m[1], 0.0], [m[0], 0.0, 0.0], [0.0, 0.0, 1.0]])  # -> E, N, U
        pos, vel_sl = st.INS15.sl("pos"), st.INS15.sl("vel")
        P_pos = S @ P[pos, pos] @ S.T
        return llh_a, vel_a, P_pos, P[vel_sl, vel_sl]

    return jax.vmap(one)(
        out.llh, out.vel_enu, out.euler, out.P_nav, out.sensors.gyro_bias_rad_s,
        out.sensors.gyro_scale, dtheta_last_b,
    )


@eqx.filter_jit
def run_filter(lf: loose.LooseFilter, carry: loose.Carry, inputs: loose.EpochInput):
    """``loose.run`` compiled (one trace per filter configuration and drive length)."""
    return loose.run(lf, carry, inputs)


# ----------------------------------------------------------------------------------------------
# Outages
# ----------------------------------------------------------------------------------------------
class OutagePlan(NamedTuple):
    ids: tuple[str, ...]
    start_s: np.ndarray  # requested start after the first IMU sample [s]
    length_s: np.ndarray
    start_epoch: np.ndarray  # first withheld epoch
    n_epochs: np.ndarray  # withheld epochs
    withheld: np.ndarray  # [E] bool


def parse_grid(text: str) -> tuple[float, float, float]:
    """START:STEP:LENGTH in seconds (STEP > LENGTH > 0, START >= 0)."""
    try:
        start, step, length = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--outage-grid takes START:STEP:LENGTH in seconds, got {text!r}"
        ) from None
    if not (start >= 0 and length > 0 and step > length):
        raise argparse.ArgumentTypeError(
            f"--outage-grid {text!r}: expected START >= 0 and STEP > LENGTH > 0 (outages of one "
            f"run must not touch)"
        )
    return start, step, length


def grid_schedule(drive: Drive, start: float, step: float, length: float) -> ot.Schedule:
    """Outages START + i STEP, LENGTH long, whose window ends inside the drive."""
    end = float(drive.time_rel_s[-1])
    starts = np.arange(start, end - length + 1e-9, step)
    if starts.size == 0:
        raise ValueError(f"--outage-grid: no {length:g} s outage fits after {start:g} s in the "
                         f"{end:.1f} s drive")
    return ot.Schedule(tuple(f"g{i:03d}" for i in range(starts.size)), starts,
                       np.full(starts.size, float(length)))


def plan_outages(drive: Drive, sched: ot.Schedule) -> OutagePlan:
    """Withheld epochs of a schedule: start <= t_rel < start + length (module docstring)."""
    t = drive.time_rel_s
    withheld = np.zeros(t.size, bool)
    first, count = [], []
    for oid, s0, n in zip(sched.id, sched.start_s, sched.length_s, strict=True):
        w = (t >= s0 - 1e-6) & (t < s0 + n - 1e-6)
        if not w.any():
            raise ValueError(
                f"outage {oid!r} ({s0:g} s + {n:g} s) holds no GNSS epoch of the drive "
                f"(epochs at {t[0]:.2f} ... {t[-1]:.2f} s after the first IMU sample)"
            )
        if s0 + n > t[-1] + drive.epoch_dt_s + 1e-6:
            raise ValueError(
                f"outage {oid!r} ends at {s0 + n:g} s, after the drive's last epoch "
                f"({t[-1]:.2f} s after the first IMU sample)"
            )
        idx = np.flatnonzero(w)
        first.append(int(idx[0]))
        count.append(int(idx.size))
        withheld |= w
    return OutagePlan(tuple(sched.id), np.asarray(sched.start_s), np.asarray(sched.length_s),
                      np.asarray(first), np.asarray(count), withheld)


def outage_metrics(drive: Drive, llh_ant, out: loose.EpochOutput, plan: OutagePlan):
    """window_metrics of every outage against the RTK track (vmapped over the outages)."""
    est = mt.Track(jnp.asarray(llh_ant), out.vel_enu, out.euler[:, 2])
    truth = reference_track(drive)

    def one(s, n):
        return mt.window_metrics(est, truth, out.P_nav, s, n, drive.epoch_dt_s)

    return jax.jit(jax.vmap(one))(jnp.asarray(plan.start_epoch), jnp.asarray(plan.n_epochs))


def reference_track(drive: Drive) -> mt.Track:
    """The RTK track as metrics truth; its azimuth is the course over ground (meaningless at a
    standstill, so the sweep's azimuth metric is not reported)."""
    v = drive.ref_vel_enu
    return mt.Track(jnp.asarray(drive.ref_llh), jnp.asarray(v),
                    jnp.asarray(np.arctan2(v[:, 0], v[:, 1])))


# ----------------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------------
def _signed_root(x):
    return np.sign(x) * np.sqrt(np.abs(x))


def solution_pos(drive: Drive, lf, out: loose.EpochOutput, withheld) -> pos_io.PosSolution:
    """The antenna solution as an RTKLIB ``PosSolution`` (Q of the fix, Q = 7 in outages)."""
    llh, vel, P_pos, P_vel = (
        np.asarray(a) for a in _antenna_outputs(
            lf.system.lever_b, out, jnp.asarray(drive.samples.dtheta_b[:, -1]), lf.imu_dt_s
        )
    )
    withheld = np.asarray(withheld, bool)
    # E, N, U covariance -> RTKLIB sdn, sde, sdu and signed roots of ne, eu, un
    def neu(P):
        sd = np.sqrt(np.stack([P[:, 1, 1], P[:, 0, 0], P[:, 2, 2]], 1))
        cross = _signed_root(np.stack([P[:, 1, 0], P[:, 0, 2], P[:, 2, 1]], 1))
        return sd, cross

    sd_p, cr_p = neu(P_pos)
    sd_v, cr_v = neu(P_vel)
    aided = np.asarray(drive.fixes.pos_valid) & ~withheld
    q = np.where(aided, drive.q, pos_io.Q_OUTAGE)
    n = drive.n_epochs
    return pos_io.PosSolution(
        time_gps_s=drive.time_gps_s, llh=llh, q=q.astype(np.int64),
        ns=np.where(aided, drive.ns, 0).astype(np.int64), sd_neu_m=sd_p, sd_cross_m=cr_p,
        age_s=np.zeros(n), ratio=np.zeros(n), vel_enu=vel, sd_vel_neu=sd_v, sd_vel_cross=cr_v,
    )


# ----------------------------------------------------------------------------------------------
# The sweep on the real drive (jaxnav.study.sweep engine)
# ----------------------------------------------------------------------------------------------
@functools.cache
def lc_ops(lever_b: tuple[float, float, float]):
    """``sweep.FilterOps`` of the loose filter: one pseudo-satellite slot = the GNSS fix, the
    estimate read out at the antenna (the RTK reference is the antenna track)."""
    from jaxnav.study.sweep import FilterOps

    lever = jnp.asarray(lever_b)

    def readout(out):
        # No covariance: the sweep's NEES is a batched LU (jnp.linalg.solve) over chunk x epochs
        # matrices, and jaxlib's parallel batched LU kernel deadlocked (0 % CPU, all threads
        # parked, the caller in jax::ParallelBatchMap) on this 2-core machine from chunks of
        # ~108 scenarios (at 256 even with single-threaded Eigen and synchronous dispatch).
        # NEES is therefore NaN in the sweep.
        llh = antenna_track(lever, out)
        return mt.track(llh, out.vel_enu, out.euler), None

    def with_keep(inp, keep):
        k = keep[..., 0]
        g = inp.gnss._replace(pos_valid=inp.gnss.pos_valid & k, vel_valid=inp.gnss.vel_valid & k)
        # a withheld fix cannot veto ZUPT/ZARU (epoch_inputs)
        return inp._replace(gnss=g, zupt_allowed=inp.zupt_allowed | ~k)

    return FilterOps(
        run=loose.run, readout=readout,
        get_keep=lambda inp: inp.gnss.pos_valid[..., None], with_keep=with_keep,
    )


class DriveFactory:
    """Scenario factory of ``jaxnav.study.sweep.run_sweep`` for one recorded drive.

    Modes are the constraint sets of ``SWEEP_MODES``; the system label is the error-state
    layout of the configuration; realizations are meaningless on recorded data (use 1).
    """

    def __init__(self, cfg: CarConfig, drive: Drive, fingerprint: str):
        self.cfg, self.drive, self._fp = cfg, drive, fingerprint
        self.modes = tuple(SWEEP_MODES)
        self.systems = (cfg.imu_errors_states,)
        lever_ant, _ = lever_arms_b(cfg)
        self.ops = lc_ops(tuple(float(x) for x in lever_ant))

    def fingerprint(self) -> str:
        return self._fp

    def timeline(self, study):
        from jaxnav.study.sweep import Timeline

        return Timeline(self.drive.n_epochs, self.drive.epoch_dt_s)

    def build(self, study, mode: str, system: str, seed: int):
        from jaxnav.study.sweep import Problem

        nhc, zupt = SWEEP_MODES[mode]
        lf = build_filter(self.cfg, self.drive, nhc=nhc, zupt=zupt)
        carry0 = initial_carry(self.cfg, lf, self.drive)
        inputs = epoch_inputs(self.cfg, self.drive)
        T = self.drive.n_epochs
        return Problem(
            tf=lf, carry0=carry0, inputs=inputs, truth=reference_track(self.drive),
            elevation=jnp.full((T, 1), 0.5 * math.pi), available=inputs.gnss.pos_valid[:, None],
        )


def study_config(cfg: CarConfig, drive: Drive):
    """The ``StudyConfig`` of the [sweep] section: complete outages (0 of 1 slot kept) on a
    grid; the grid origin is the first filter epoch (t_imu0 + ``drive.time_rel_s[0]``)."""
    from jaxnav.study.config import PlacementConfig, StudyConfig, validate

    return validate(StudyConfig(
        name="lc_real_drive", modes=cfg.sweep_modes, systems=(cfg.imu_errors_states,),
        durations_s=cfg.sweep_durations_s, satellites_kept=(0,), recovery_s=cfg.sweep_recovery_s,
        chunk_size=cfg.sweep_chunk_size, max_traces=8,
        placement=PlacementConfig(kind="grid", convergence_s=cfg.sweep_convergence_s,
                                  spacing_s=cfg.sweep_spacing_s),
    ))


def run_drive_sweep(cfg: CarConfig, drive: Drive, out_dir, fingerprint: str, *,
                    overwrite: bool = False, progress: bool = True):
    """Run the outage sweep of the [sweep] section into ``out_dir`` (results.nc + report)."""
    from jaxnav.study import report
    from jaxnav.study.sweep import run_sweep

    study = study_config(cfg, drive)
    factory = DriveFactory(cfg, drive, fingerprint)
    res = run_sweep(study, factory, out_dir, resume=not overwrite, overwrite=overwrite,
                    progress=progress)
    report.write_report(res.dataset, out_dir)
    return res


def duration_table(ds) -> str:
    """Markdown: max 2D error per duration (rows) and mode (columns): mean / median / p90."""
    lines = ["| duration | outages | " + " | ".join(
        f"{m}: mean / median / p90 [m]" for m in ds["mode"].values) + " |"]
    lines.append("|---|---|" + "---|" * ds.sizes["mode"])
    sys_label = ds["system"].values[0]
    for d in ds["duration"].values:
        cells, n = [], 0
        for m in ds["mode"].values:
            x = ds["max_2d_m"].sel(mode=m, system=sys_label, duration=d).values.ravel()
            x = x[np.isfinite(x)]
            n = x.size
            cells.append(f"{x.mean():.2f} / {np.median(x):.2f} / {np.percentile(x, 90):.2f}")
        lines.append(f"| {d:g} s | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--imu", required=True, help="IMU CSV log (acc [g], gyro, tick [ms])")
    p.add_argument("--imu-tag", help="RTKLIB time-tag file of the IMU log (default IMU.tag)")
    p.add_argument("--gnss", required=True, help="RTKLIB .pos with velocities (aiding + reference)")
    p.add_argument("--config", required=True, help="car configuration TOML")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--outages", help="schedule file id,start_s,length_s (start after 1st IMU)")
    g.add_argument("--outage-grid", type=parse_grid, metavar="START:STEP:LENGTH",
                   help="outages START, START+STEP, ... of LENGTH seconds")
    p.add_argument("--duration", type=float, help="process only the first DURATION s of the log")
    p.add_argument("--out", required=True, help="output .pos (INS at the antenna)")
    p.add_argument("--sweep", metavar="DIR", help="also run the outage sweep of [sweep] into DIR")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sweep in DIR")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _fingerprint(args, cfg: CarConfig) -> str:
    h = hashlib.sha256(cfg.to_json().encode())
    for f in (args.imu, args.imu_tag or args.imu + ".tag", args.gnss):
        st_ = os.stat(f)
        h.update(f"{Path(f).name}:{st_.st_size}".encode())
    h.update(f"duration={args.duration}".encode())
    return h.hexdigest()


def main(argv=None) -> int:
    """Entry point of ``jaxnav lc``; returns a process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        return _main(args)
    except (InputError, ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2


def _main(args) -> int:
    t_start = time.perf_counter()
    cfg = load_config(args.config)
    sched = ot.read_schedule(args.outages, allow_overlap=False) if args.outages else None
    drive = load_drive(args.imu, args.imu_tag, args.gnss, cfg, duration_s=args.duration)
    if args.outage_grid is not None:
        sched = grid_schedule(drive, *args.outage_grid)
    plan = plan_outages(drive, sched) if sched is not None else None
    t_read = time.perf_counter()

    lf = build_filter(cfg, drive)
    carry = initial_carry(cfg, lf, drive)
    withheld = plan.withheld if plan is not None else np.zeros(drive.n_epochs, bool)
    _, out = run_filter(lf, carry, epoch_inputs(cfg, drive, withheld))
    jax.block_until_ready(out)
    t_run = time.perf_counter()
    sol = solution_pos(drive, lf, out, withheld)
    pos_io.write_pos(
        args.out, sol, outage=withheld,
        comments=(
            f"jaxnav lc: loosely coupled INS ({cfg.imu_errors_states}) at the antenna; "
            f"config {Path(args.config).name}",
            f"first IMU sample {drive.t_imu0_gps_s:.3f} GPS s (origin of outage start times)",
        ),
        program=f"jaxnav {jaxnav.__version__}",
    )

    err = np.asarray(mt.enu_errors(jnp.asarray(sol.llh), jnp.asarray(drive.ref_llh)))
    e2 = np.hypot(err[:, 0], err[:, 1])
    aligned = np.asarray(out.aligned)
    aided = ~withheld & np.asarray(drive.fixes.pos_valid)
    sel = aided & aligned
    print(f"{PROG}: {drive.n_epochs} epochs of {drive.epoch_dt_s:g} s "
          f"({drive.time_rel_s[0]:.2f}-{drive.time_rel_s[-1]:.2f} s after the first IMU sample), "
          f"{drive.samples.dv_b.shape[1]} IMU samples each; states {cfg.imu_errors_states}")
    noise = rest_noise(drive)
    if noise is not None:
        model = imu_error_model(cfg)
        gyro_model = np.degrees(np.asarray(model.gyro_arw_rad_sqrt_s))
        accel_model = np.asarray(model.accel_vrw_m_s_sqrt_s) / _UG
        print(f"IMU noise at the initial {noise[2]:.0f} s standstill (x, y, z): gyro "
              f"{np.array2string(noise[0], precision=4)} deg/s/sqrt(Hz), accel "
              f"{np.array2string(noise[1], precision=0)} ug/sqrt(Hz); filter model: gyro "
              f"{np.array2string(gyro_model, precision=4)}, accel "
              f"{np.array2string(accel_model, precision=0)}")
    if aligned.any():
        i = int(np.argmax(aligned))
        print(f"in-motion alignment at {drive.time_rel_s[i]:.2f} s "
              f"(GNSS speed {np.hypot(*drive.ref_vel_enu[i, :2]):.1f} m/s)")
    else:
        print("never aligned: the vehicle did not exceed [alignment] min_speed_m_s")
    if sel.any():
        print(f"with GNSS (aligned, {int(sel.sum())} epochs): 2D error vs the RTK track RMS "
              f"{np.sqrt(np.mean(e2[sel] ** 2)):.3f} m, max {e2[sel].max():.3f} m; "
              f"up RMS {np.sqrt(np.mean(err[sel, 2] ** 2)):.3f} m; NIS per row "
              f"{np.sum(np.asarray(out.nis)[sel]) / max(np.sum(np.asarray(out.dof)[sel]), 1):.2f}"
              f" (1 = consistent)")
    if plan is not None:
        m = outage_metrics(drive, sol.llh, out, plan)
        print(f"{'outage':>8} {'start_s':>8} {'length_s':>8} {'dist_m':>8} {'max_2d_m':>9} "
              f"{'final_2d_m':>10}")
        for k, oid in enumerate(plan.ids):
            print(f"{oid:>8} {plan.start_s[k]:8.2f} {plan.length_s[k]:8.2f} "
                  f"{float(m.distance_m[k]):8.1f} {float(m.max_2d_m[k]):9.3f} "
                  f"{float(m.end_2d_m[k]):10.3f}")
    print(f"wrote {args.out}; read {t_read - t_start:.1f} s, filter {t_run - t_read:.1f} s "
          f"(incl. compilation)")

    if args.sweep:
        t0 = time.perf_counter()
        res = run_drive_sweep(cfg, drive, args.sweep, _fingerprint(args, cfg),
                              overwrite=args.overwrite, progress=not args.quiet)
        print(f"sweep: {res.stats['scenarios']} outages in {time.perf_counter() - t0:.1f} s "
              f"(full runs {res.stats['full_run_s']:.1f} s, windows {res.stats['eval_s']:.1f} s, "
              f"compilation {res.stats['compile_full_s'] + res.stats['compile_eval_s']:.1f} s); "
              f"{res.path}")
        print("max 2D error per outage duration (all grid starts):")
        print(duration_table(res.dataset))
    return 0


if __name__ == "__main__":
    sys.exit(main())
