"""A complete simulated scenario: truth, sensor outputs, GNSS observables and masks.

``build_geometry`` does the host-side set-up once per drive (trajectory truth at the IMU rate,
satellite slots); ``realize`` draws one noise realisation from a PRNG key (IMU and odometer
errors, every GNSS error source) and packs it into the stacked ``tight.EpochInput`` the filters
scan over. ``realize`` is pure in its key, so ``jax.vmap(realize)`` over keys gives independent
Monte-Carlo realisations of the same drive; ``iterate_realizations`` does it in chunks so memory
stays bounded for any number of keys.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import attitude, geodesy
from jaxnav.core import gpstime
from jaxnav.gnss import corrections, models, ppp, signals, slips
from jaxnav.gnss.ppp_data import EpochInput
from jaxnav.ins import riss, strapdown
from jaxnav.sim import constellation, drives, observations, sensors, trajectory


class ScenarioConfig(eqx.Module):
    """What to simulate. Defaults: a seed-000-like 10-minute mixed drive, GPS only, 1 Hz GNSS."""

    drive_seed: int = eqx.field(static=True, default=0)
    drive_style: str = eqx.field(static=True, default="mixed")
    duration_s: float = eqx.field(static=True, default=600.0)
    imu_rate_hz: float = eqx.field(static=True, default=100.0)
    # RISS input rate: IMU averaged and the odometer read at this rate (S002 §3.2.1 averages to
    # 1 Hz; an OBD-II speed is a ~1 Hz integer-km/h reading, whose difference at 100 Hz would
    # make a_od, and so the pitch, meaningless).
    riss_rate_hz: float = eqx.field(static=True, default=1.0)
    epoch_interval_s: float = eqx.field(static=True, default=1.0)
    systems: tuple[int, ...] = eqx.field(static=True, default=(signals.SYS_GPS,))
    slots_per_system: tuple[int, ...] = eqx.field(static=True, default=(16, 14, 14))
    lever_b_m: tuple[float, float, float] = eqx.field(static=True, default=(0.0, 0.0, 1.5))
    imu_grade: str = eqx.field(static=True, default="crossbow_imu300cc")
    odometer: str = eqx.field(static=True, default="obd2_odometer")
    obs_params: observations.ObsParams = eqx.field(static=True, default=observations.ObsParams())
    # "detector": the filter's slip flags are the receiver's LLI plus, for dual frequency, the
    # GF / MW detector of real data (gnss/slips.py); "oracle": the simulator's true arc starts
    # (isolates other effects from detection misses and false alarms).
    slip_flags: str = eqx.field(static=True, default="detector")
    # GPS time of the scenario's t = 0 (orbits, ionosphere, day of year)
    t0_gps_s: float = eqx.field(static=True, default=constellation.DEFAULT_T0_GPS_S)


class Geometry(NamedTuple):
    """Deterministic part of a scenario (same for every realisation)."""

    truth: trajectory.Truth  # IMU rate
    truth_ep: trajectory.Truth  # GNSS epochs (t = 0, interval, ...)
    ant_pos_ecef: jnp.ndarray  # [T, 3] true antenna position at the epochs
    ant_vel_ecef: jnp.ndarray  # [T, 3]
    slot_table: signals.SlotTable
    slots: ppp.SlotInfo
    orbits: constellation.NominalOrbits
    day_of_year: float


class Realization(NamedTuple):
    """One noise realisation packed for the filters (epochs 1..T-1; epoch 0 initialises)."""

    ins_inputs: EpochInput  # samples: strapdown.ImuIncrements [T-1, K, 3]
    riss_inputs: EpochInput  # samples: riss.RissInput [T-1, K]
    obs0: ppp.GnssObs  # epoch 0 (initialisation)
    imu_errors: sensors.ImuErrors


def antenna_track(truth_ep: trajectory.Truth, lever_b):
    """True antenna ECEF position and velocity at the epochs (lever arm through the attitude)."""

    def one(llh, vel, q, w_ib_b):
        C = attitude.dcm_from_quat(q)
        llh_ant = strapdown.antenna_llh(llh, C, lever_b)
        vel_ant = strapdown.antenna_vel_enu(llh, vel, C, w_ib_b, lever_b)
        return geodesy.llh_to_ecef(llh_ant), geodesy.enu_to_ecef(vel_ant, llh_ant)

    return jax.vmap(one)(truth_ep.llh, truth_ep.vel_enu, truth_ep.q_b_l, truth_ep.w_ib_b)


def build_geometry(
    cfg: ScenarioConfig, profile: trajectory.Profile | None = None, orbits=None
) -> Geometry:
    """Truth trajectory, antenna track and the fixed satellite slots of a drive.

    ``profile``: a purpose-built trajectory (``trajectory.compile_profile``) instead of the
    seeded random drive of ``cfg.drive_style`` / ``cfg.drive_seed``; ``orbits``: another orbit
    source (e.g. a broadcast ephemeris) instead of the nominal constellations of ``cfg.systems``.
    """
    if profile is None and cfg.drive_style == "airborne":
        profile = drives.random_airborne(cfg.drive_seed, cfg.duration_s)
    elif profile is None and cfg.drive_style == "circuit":
        profile = drives.circuit_drive(cfg.drive_seed, cfg.duration_s)
    elif profile is None:
        profile = drives.random_drive(cfg.drive_seed, cfg.drive_style, cfg.duration_s)
    truth = trajectory.generate_truth(profile, cfg.imu_rate_hz, cfg.duration_s)
    truth_ep = trajectory.truth_at_epochs(truth, cfg.epoch_interval_s)
    lever = jnp.asarray(cfg.lever_b_m, jnp.float64)
    pos, vel = antenna_track(truth_ep, lever)
    if orbits is None:
        orbits = constellation.nominal_constellation(cfg.systems)
    slots_per = tuple(n if s in cfg.systems else 0 for s, n in enumerate(cfg.slots_per_system))
    table = constellation.build_slots(
        orbits,
        truth_ep.time_s,
        pos,
        cfg.t0_gps_s,
        mask_rad=cfg.obs_params.elevation_mask_rad,
        slots_per_system=slots_per,
    )
    freq = signals.slot_frequencies_hz(table)
    slots = ppp.SlotInfo(table.system, freq[:, 0], freq[:, 1])
    doy = gpstime.day_of_year(cfg.t0_gps_s)
    return Geometry(truth, truth_ep, pos, vel, table, slots, orbits, float(doy))


SLIP_FLAGS = ("detector", "oracle")


def slip_flags(
    obs: observations.Observations, code_band0: int, how: str = "detector"
) -> jnp.ndarray:
    """The filter's slip flags [T, S]: ``obs.lli`` | GF | MW (dual frequency), ``obs.lli`` |
    the carrier-Doppler test (single frequency, ``code_band0`` = C1), as ``io/prepare.py``
    does on recorded data; or the truth (``"oracle"``)."""
    if how == "oracle":
        return obs.slip
    if how != "detector":
        raise ValueError(f"unknown slip_flags {how!r}; use {' or '.join(SLIP_FLAGS)}")
    if code_band0 == signals.CODE_C1:
        return obs.lli | slips.detect_slips_doppler(
            obs.phase_cyc[..., 0] * obs.wavelength_m[:, 0],
            -obs.wavelength_m[:, 0] * obs.doppler_hz[..., 0],
            obs.valid,
            obs.elevation_rad,
            obs.t_s,
        )
    gf, mw = slips.detect_slips_dual(
        obs.phase_cyc * obs.wavelength_m,
        jnp.stack([obs.code_m[..., code_band0], obs.code_m[..., signals.CODE_P2]], axis=-1),
        obs.valid,
        obs.elevation_rad,
        obs.freq_hz[:, 0],
        obs.freq_hz[:, 1],
    )
    return obs.lli | gf | mw


def _gnss_obs(
    obs: observations.Observations, code_band0: int, broadcast: bool, how_slips: str = "detector"
) -> ppp.GnssObs:
    """Filter-side view of simulated observables (stacked over epochs).

    The satellite code biases the user knows (precise-clock convention, S002 §2.1.4) are
    returned so the filter removes them; the periodic relativistic clock term is added to the
    product clocks as a precise-product user does.
    """
    a, b = signals.if_coefficients(obs.freq_hz[:, 0], obs.freq_hz[:, 1])
    d = obs.sat_dcb_p1p2_m
    bias_p1 = b * d
    bias_c1 = bias_p1 - obs.sat_dcb_p1c1_m
    bias0 = bias_c1 if code_band0 == signals.CODE_C1 else bias_p1
    # The observation holds -B^s_c; removing "code_bias_m" (= -B^s_c) corrects it.
    code_bias = jnp.stack([-bias0, a * d], axis=-1)
    code = jnp.stack([obs.code_m[..., code_band0], obs.code_m[..., signals.CODE_P2]], axis=-1)
    pos = obs.sat_pos_brdc_ecef if broadcast else obs.sat_pos_ecef
    clock = obs.sat_clock_brdc_m if broadcast else obs.sat_clock_m
    rel = geodesy.C_LIGHT * corrections.relativistic_clock_s(pos, obs.sat_vel_ecef)
    sat = models.SatEpoch(pos, obs.sat_vel_ecef, clock + rel, obs.sat_clock_rate_m_s)
    return ppp.GnssObs(
        code_m=code,
        phase_m=obs.phase_cyc * obs.wavelength_m,
        range_rate_m_s=-obs.wavelength_m[:, 0] * obs.doppler_hz[..., 0],
        available=obs.valid,
        slip=slip_flags(obs, code_band0, how_slips),
        code_bias_m=jnp.broadcast_to(code_bias, code.shape),
        iono_model_l1_m=obs.iono_model_l1_m,
        sat=sat,
        doppler_ok=obs.valid,  # the simulated receiver measures Doppler wherever it tracks
        iono_model_ok=jnp.ones_like(obs.valid),  # the simulated model covers the globe
    )


def realize(
    key,
    geo: Geometry,
    cfg: ScenarioConfig,
    single_frequency: bool = False,
    broadcast: bool = False,
) -> Realization:
    """One Monte-Carlo realisation: sensor errors + GNSS errors, packed per epoch.

    ``single_frequency`` puts the C/A code (C1) in band 0 instead of P1 (S000's SF user, who
    also used IGS precise products); ``broadcast`` gives the filter broadcast-quality orbits and
    clocks instead of precise ones (S002 ch. 4 real-time users).
    """
    k_imu, k_odo, k_obs = jax.random.split(key, 3)
    obs = observations.simulate_observations(
        k_obs,
        geo.truth_ep.time_s,
        geo.ant_pos_ecef,
        geo.ant_vel_ecef,
        geo.orbits,
        geo.slot_table,
        cfg.obs_params,
        cfg.t0_gps_s,
        with_truth=False,
    )
    band0 = signals.CODE_C1 if single_frequency else signals.CODE_P1
    gobs = _gnss_obs(obs, band0, broadcast, cfg.slip_flags)
    doy = jnp.full(geo.truth_ep.time_s.shape[0] - 1, geo.day_of_year)
    return with_sensors(k_imu, k_odo, geo, cfg, gobs, doy)


def with_sensors(k_imu, k_odo, geo: Geometry, cfg: ScenarioConfig, gobs: ppp.GnssObs, doy):
    """A ``Realization``: the IMU and odometer simulated along ``geo``'s truth (keys ``k_imu``,
    ``k_odo``) beside the GNSS observations ``gobs`` [T] of the epochs (``doy`` [T - 1])."""
    truth = geo.truth
    dt = 1.0 / cfg.imu_rate_hz
    grade = sensors.imu_grade(cfg.imu_grade)
    odo = sensors.odometer(cfg.odometer)
    dth, dv, imu_err = sensors.simulate_imu(k_imu, truth.dtheta_b[1:], truth.dv_b[1:], dt, grade)
    m = int(round(cfg.imu_rate_hz / cfg.riss_rate_hz))
    dt_riss = 1.0 / cfg.riss_rate_hz
    v_od, _ = sensors.simulate_odometer(k_odo, truth.odo_speed_mps[m::m], dt_riss, odo)

    n_ep = geo.truth_ep.time_s.shape[0] - 1
    k = int(round(cfg.epoch_interval_s * cfg.imu_rate_hz))

    def per_epoch(x):
        return x[: n_ep * k].reshape(n_ep, k, *x.shape[1:])

    ins_samples = strapdown.ImuIncrements(per_epoch(dth), per_epoch(dv))
    n_lo = v_od.shape[0]
    f_x, f_y, w_z = riss.rates_from_increments(dth, dv, dt)

    def block_mean(x):
        return x[: n_lo * m].reshape(n_lo, m).mean(axis=1)

    riss_lo = riss.RissInput(
        block_mean(f_x),
        block_mean(f_y),
        block_mean(w_z),
        v_od,
        riss.odometer_acceleration(v_od, dt_riss, truth.odo_speed_mps[0]),
    )
    k_riss = int(round(cfg.epoch_interval_s * cfg.riss_rate_hz))
    riss_samples = jax.tree.map(
        lambda x: x[: n_ep * k_riss].reshape(n_ep, k_riss, *x.shape[1:]), riss_lo
    )
    rest = jax.tree.map(lambda x: x[1:], gobs)
    keep = jnp.ones_like(rest.available)
    obs0 = jax.tree.map(lambda x: x[0], gobs)
    return Realization(
        EpochInput(ins_samples, rest, keep, doy),
        EpochInput(riss_samples, rest, keep, doy),
        obs0,
        imu_err,
    )


def initial_riss_state(geo: Geometry) -> riss.RissState:
    """RISS state at epoch 0 from the truth (the filter's initial uncertainty covers GNSS init)."""
    t = geo.truth_ep
    roll, pitch, az = t.euler[0]
    return riss.riss_state_from(t.llh[0], az, t.odo_speed_mps[0], pitch, roll)


def initial_ins_state(geo: Geometry):
    """``InsNav`` (NavState, previous sample) at epoch 0 from the truth."""
    t = geo.truth_ep
    nav = strapdown.NavState(t.llh[0], t.vel_enu[0], t.q_b_l[0])
    prev = strapdown.ImuIncrements(geo.truth.dtheta_b[1], geo.truth.dv_b[1])
    return strapdown.InsNav(nav, prev)


def iterate_realizations(
    keys,
    geo: Geometry,
    cfg: ScenarioConfig,
    chunk: int = 64,
    single_frequency: bool = False,
    broadcast: bool = False,
    summarize: Callable[[Realization], Any] | None = None,
) -> Iterator[Any]:
    """Yield vmapped realisations ``chunk`` keys at a time (memory bounded by one chunk).

    ``summarize`` (one realisation -> small pytree) is applied per key inside the same jitted
    vmap, so only its output is materialised and whatever it does not use (e.g. the per-sample
    IMU error record) is never computed: a 30-min drive at 100 Hz is ~56 MB per realisation
    but ~140 MB per key while being generated, so pick ``chunk`` for that peak.
    """

    def one(k):
        real = realize(k, geo, cfg, single_frequency, broadcast)
        return real if summarize is None else summarize(real)

    fn = jax.jit(jax.vmap(one))
    keys = np.asarray(keys)
    for start in range(0, keys.shape[0], chunk):
        yield fn(jnp.asarray(keys[start : start + chunk]))
