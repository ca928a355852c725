"""``jaxnav lc``'s car configuration: the TOML file (``configs/car_gnss_imu_drive.toml``
documents every key), checked key by key before any work, and the lever arms and IMU error model
it gives."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav.core import schema
from jaxnav.core import states as st
from jaxnav.ins import errors as ins_errors
from jaxnav.io import imu as imu_io

LAYOUTS = {"ins15": st.INS15, "ins21": st.INS21, "ins27": st.INS27}
#: Sweep modes: which vehicle constraints the filter uses (ZUPT includes ZARU).
SWEEP_MODES = {"nhc_zupt": (True, True), "zupt": (False, True), "nhc": (True, False),
               "free": (False, False)}  # fmt: skip
# Body forward-right-down (the source configuration's lever arms) -> right-forward-up.
_FRD_TO_RFU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_DEG_H = math.pi / 180.0 / 3600.0  # rad/s per deg/h
UG_M_S2 = imu_io.STANDARD_GRAVITY * 1e-6  # m/s^2 per micro-g


# ----------------------------------------------------------------------------------------------
# Car configuration (TOML)
# ----------------------------------------------------------------------------------------------
class CarConfigError(schema.SchemaError):
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
    sweep_smooth: bool = False
    sweep_chunk_size: int = 128

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


_REQUIRED = (
    "imu_mounting_rpy_deg", "imu_misalignment_rpy_deg", "imu_time_offset_s",
    "imu_errors_gyro_noise_deg_s_sqrt_hz", "imu_errors_accel_noise_ug_sqrt_hz",
    "lever_arms_imu_frd_m", "lever_arms_antenna_frd_m",
)  # fmt: skip
_NUM, _NONNEG, _POS = schema.number(), schema.number(0), schema.number(0, strict=True)
_VEC3 = schema.items(_NUM, length=3, unique=False)
_VIB3 = schema.items(_NONNEG, length=3, unique=False)
#: [section] -> key -> rule; the keys are the ``CarConfig`` fields ``section_key``.
SCHEMA: dict[str, dict[str, schema.Rule]] = {
    "imu": {"mounting_rpy_deg": _VEC3, "misalignment_rpy_deg": _VEC3, "time_offset_s": _NUM,
            "gyro_unit": schema.choice(("deg/s", "rad/s")),
            "accel_unit": schema.choice(("g", "m/s^2")), "resample_hz": _POS},
    "imu_errors": {
        "states": schema.choice(LAYOUTS),
        "gyro_noise_deg_s_sqrt_hz": _POS, "accel_noise_ug_sqrt_hz": _POS,
        "gyro_vibration_deg_s_sqrt_hz": _VIB3, "accel_vibration_ug_sqrt_hz": _VIB3,
        "gyro_bias_turn_on_deg_s": _NONNEG, "gyro_bias_gm_sigma_deg_h": _NONNEG,
        "gyro_bias_gm_tau_s": _POS, "accel_bias_turn_on_mg": _NONNEG,
        "accel_bias_gm_sigma_mg": _NONNEG, "accel_bias_gm_tau_s": _POS,
        "gyro_scale_ppm": _NONNEG, "accel_scale_ppm": _NONNEG,
    },
    "lever_arms": {"imu_frd_m": _VEC3, "antenna_frd_m": _VEC3, "nhc_point_frd_m": _VEC3},
    "gnss": {"use_velocity": schema.boolean(), "pos_sigma_floor_m": _NONNEG,
             "vel_sigma_floor_m_s": _NONNEG},
    "constraints": {
        "nhc": schema.boolean(), "nhc_sigma_m_s": _POS, "zupt": schema.boolean(),
        "zaru": schema.boolean(), "zupt_sigma_m_s": _POS, "zupt_threshold": _POS,
        "zupt_ref_sigma_m_s2": schema.either(schema.literal("start"), _POS),
        "zupt_max_speed_m_s": _POS, "zupt_with_gnss_vel": schema.boolean(),
        "zupt_gnss_speed_m_s": _POS,
    },
    "alignment": {"level_s": _POS, "min_speed_m_s": _POS, "heading_floor_deg": _NONNEG,
                  "roll_pitch_sigma_deg": _NONNEG, "vel_sigma_m_s": _NONNEG},
    "filter": {"cov_substeps": schema.whole(1),
               "gate_chi2": schema.number(0, strict=True, specials={"inf": float("inf")})},
    "sweep": {"modes": schema.items(schema.choice(SWEEP_MODES)),
              "durations_s": schema.items(_POS), "spacing_s": _POS, "convergence_s": _NONNEG,
              "recovery_s": _NONNEG, "chunk_size": schema.whole(1),
              "smooth": schema.boolean()},
}


def config_from_dict(data: Mapping, source: str = "<config>") -> CarConfig:
    """Validate the TOML tables and build a ``CarConfig`` (errors name file, section and key)."""
    try:
        schema.check_sections(data, SCHEMA, CarConfigError)
        values: dict[str, Any] = {}
        for section, rules in SCHEMA.items():
            required = [n[len(section) + 1:] for n in _REQUIRED
                        if n.startswith(section + "_") and n[len(section) + 1:] in rules]
            got = schema.check_section(section, data.get(section, {}), rules,
                                       required=required, error=CarConfigError,
                                       note="sensor-specific, no default")
            values.update({f"{section}_{k}": v for k, v in got.items()})
        k = values.get("imu_resample_hz", CarConfig.imu_resample_hz)
        if abs(k - round(k)) > 1e-9:
            schema.fail("imu.resample_hz", k, "a whole number of Hz", CarConfigError)
    except CarConfigError as e:
        raise CarConfigError(f"{source}: {e}") from None
    return CarConfig(**values)


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
    # jnp throughout: ``jaxnav tune`` traces this with the fitted values as JAX arrays
    gyro = jnp.hypot(cfg.imu_errors_gyro_noise_deg_s_sqrt_hz,
                     jnp.asarray(cfg.imu_errors_gyro_vibration_deg_s_sqrt_hz))
    accel = jnp.hypot(cfg.imu_errors_accel_noise_ug_sqrt_hz,
                      jnp.asarray(cfg.imu_errors_accel_vibration_ug_sqrt_hz))
    return ins_errors.ImuErrorModel(
        accel_vrw_m_s_sqrt_s=accel * UG_M_S2,
        gyro_arw_rad_sqrt_s=jnp.radians(gyro),
        accel_bias_sigma_m_s2=cfg.imu_errors_accel_bias_gm_sigma_mg * 1e3 * UG_M_S2,
        accel_bias_tau_s=cfg.imu_errors_accel_bias_gm_tau_s,
        gyro_bias_sigma_rad_s=cfg.imu_errors_gyro_bias_gm_sigma_deg_h * _DEG_H,
        gyro_bias_tau_s=cfg.imu_errors_gyro_bias_gm_tau_s,
        accel_scale_sigma=cfg.imu_errors_accel_scale_ppm * 1e-6,
        gyro_scale_sigma=cfg.imu_errors_gyro_scale_ppm * 1e-6,
        accel_bias_ton_sigma_m_s2=cfg.imu_errors_accel_bias_turn_on_mg * 1e3 * UG_M_S2,
        gyro_bias_ton_sigma_rad_s=jnp.radians(cfg.imu_errors_gyro_bias_turn_on_deg_s),
    )
