"""Tightly coupled GNSS/INS on a recorded IMU log and a receiver's raw observations.

The data flow of ``jaxnav ins`` with ``[coupling] kind = "tight"`` (choices where the sources
are silent are marked):

- GNSS: ``io.ubx.read_ubx`` (RXM-RAWX code / carrier / Doppler with loss of lock from the lock
  time, RXM-SFRBX subframes, NAV-PVT), the broadcast ephemerides decoded from the subframes
  (``io.ubx_nav``: GPS LNAV, Galileo I/NAV, Klobuchar), then ``io.prepare.prepare_gnss`` as for
  a RINEX file: dual-frequency ionosphere-free GPS L1 C/A + L2C and Galileo E1 + E5a, the
  geometry-free / Melbourne-Wuebbena slip detectors beside the lock-time flags, the SPP
  position and clock a priori.
- IMU: ``io.imu.read_imu_csv`` + time tag, rotated to the body frame (``[imu]``), resampled
  onto ``imu.resample_hz`` samples inside each GNSS epoch (``apps.lc_drive.resample_increments``).
- Start (chosen; the filter has no in-motion alignment of its own): the first GNSS epoch whose
  Doppler speed (``gnss.spp.doppler_velocity``) exceeds ``[alignment] min_speed_m_s``. Roll and
  pitch level the mean specific force of the log's first ``alignment.level_s`` seconds, where
  the gyro biases are calibrated too (``InsSystem.calibrate_static``; the log must start at
  rest); heading = the course over ground of the Doppler velocity at the start (the body's
  forward axis along the walking or driving direction), with ``[tight] heading_sigma_deg``;
  position = the SPP at the start epoch (``[tight] start_sigma_m``), velocity the Doppler one.
- Filter: ``filter.tight.TightFilter`` over ``filter.systems.InsSystem`` in the PPP mode of
  ``[tight] mode`` with the recorded-data stochastic model (``PppConfig.for_recorded_data``).
  Its loose counterpart on the same observations (``[tight] compare_loose``) is the cascade of
  ``filter.cascade``: the GNSS-only PPP filter of the same mode feeding ``filter.loose``; with
  fewer than four satellites kept it has no fix and coasts.
- Outages: every (start, length, satellites kept) of the schedule withholds all but the kept
  satellites (highest elevation at the outage start, ``study.outages.keep_mask``); the runs
  are one ``vmap`` over the keep masks. Errors are against the reference track (RTKLIB
  ``.pos``; statistics on its fixed epochs, Q = 1).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.apps.car_config import LAYOUTS, CarConfig, imu_error_model, lever_arms_b
from jaxnav.apps.lc_drive import resample_increments
from jaxnav.core import states as st
from jaxnav.filter import cascade, loose, ppp_only, tight
from jaxnav.filter.systems import InsSystem, NavSigmas
from jaxnav.gnss import modes as ppp_modes
from jaxnav.gnss import ppp
from jaxnav.gnss.spp import doppler_velocity
from jaxnav.ins import strapdown
from jaxnav.io import imu as imu_io
from jaxnav.io import pos as pos_io
from jaxnav.io import prepare as prep_mod
from jaxnav.io.errors import InputError
from jaxnav.io.ubx import read_ubx
from jaxnav.io.ubx_nav import ephemeris_from_sfrbx
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot

#: Signals of a u-blox multi-band receiver per constellation: (code f1, code f2, phase f1,
#: phase f2, Doppler f1). GPS L2C (CL) rather than L5: every GPS satellite since block IIR-M
#: sends L2C, and L2 is the frequency the broadcast clock's P1/P2 pair refers to.
UBLOX_SIGNALS = {"G": ("C1C", "C2L", "L1C", "L2L", "D1C"), "E": ("C1C", "C5Q", "L1C", "L5Q", "D1C")}
LETTERS = {"gps": "G", "galileo": "E"}
#: Clock-drift PSD of the filters [m^2/s^3]: (10 m/s)^2 per 0.25-s epoch, i.e. free from epoch
#: to epoch (the a-priori drift removed from the range rates comes from every satellite, see
#: load_recording), as ``ppp.RECORDED_CLOCK_PSD_M2_S`` frees the clock.
FREE_DRIFT_PSD_M2_S3 = 400.0
#: Largest Doppler speed [m/s] accepted in the levelling window (chosen: a person standing).
REST_SPEED_M_S = 0.2


class TightOptions(NamedTuple):
    """``[tight]`` of the ``jaxnav ins`` configuration."""

    mode: str = "float_ppp"
    constellations: tuple[str, ...] = ("gps", "galileo")
    elevation_mask_deg: float = 10.0
    doppler: bool = True
    heading_sigma_deg: float = 15.0
    start_sigma_m: float = 3.0
    compare_loose: bool = True
    # the reference track's heights: "ellipsoidal", or "msl" (heights above the geoid, as a
    # .pos made from the receiver's own RTK output, NMEA-style: moved to the ellipsoid with the
    # receiver's geoid separation, NAV-PVT height - hMSL)
    reference_height: str = "ellipsoidal"
    # "spp_median": measure against the reference moved by ``reference_offset`` (an RTK
    # reference carries its base station's coordinate error); "none": as it is
    reference_offset: str = "none"


class Recording(NamedTuple):
    """A recorded run on the filter's epoch grid (E epochs after the start epoch)."""

    prep: prep_mod.PreparedGnss  # every epoch of the receiver log
    k0: int  # index in prep of the initial state's epoch
    time_gps_s: np.ndarray  # [E] epoch end times
    t_imu0_gps_s: float  # first IMU sample (origin of the outage start times)
    imu_dt_s: float
    samples: strapdown.ImuIncrements  # [E, K, 3]
    level_f_b: np.ndarray  # [3] mean specific force of the levelling window
    gyro_bias0_rad_s: np.ndarray  # [3] static calibration
    vel0_enu: np.ndarray  # [3] Doppler velocity at the start
    pos0_ecef: np.ndarray  # [3] SPP at the start
    ref_llh: np.ndarray | None  # [E, 3] reference track at the epochs (antenna)
    ref_q: np.ndarray | None  # [E] reference quality (1 fixed, 2 float; 0 no reference)
    ubx_counts: dict
    nav_report: object

    @property
    def epochs(self) -> slice:
        """The filter epochs' indices in ``prep`` (those after the initial state's)."""
        return slice(self.k0 + 1, self.k0 + 1 + self.time_gps_s.size)

    @property
    def epoch_dt_s(self) -> float:
        return float(np.median(np.diff(self.time_gps_s)))


def _enu_velocity(prep, dv) -> np.ndarray:
    llh = np.asarray(jax.vmap(geodesy.ecef_to_llh)(jnp.asarray(prep.approx_pos_ecef)))
    C = np.asarray(jax.vmap(lambda p: geodesy.C_l_e(p[0], p[1]))(jnp.asarray(llh)))
    return np.einsum("tji,tj->ti", C, np.asarray(dv.vel_ecef))  # C_l_e^T v_e


def load_recording(cfg: CarConfig, opts: TightOptions, paths: dict,
                   sched: ot.Schedule | None = None) -> Recording:
    """Read the IMU log, the UBX log, its ephemerides and the reference; find the start.

    The IMU log is read first (a fraction of a second) so that outages of ``sched`` past its
    end are refused before the UBX log is decoded (``plan_outages`` checks them exactly)."""
    imu_log = imu_io.read_imu_csv(paths["imu"], paths.get("imu_tag"),
                                  gyro_unit=cfg.imu_gyro_unit, accel_unit=cfg.imu_accel_unit,
                                  time_offset_s=cfg.imu_time_offset_s)
    span_s = float(imu_log.time_gps_s[-1] - imu_log.time_gps_s[0])
    if sched is not None:
        for oid, start, length in zip(sched.id, sched.start_s, sched.length_s, strict=True):
            if start + length > span_s:
                raise InputError(f"outage {oid!r} ({start:g} s + {length:g} s) ends after the "
                                 f"IMU log ({span_s:.2f} s long)", file=paths["imu"],
                                 expected="outages inside the log, start_s after its first "
                                 "sample")
    letters = tuple(LETTERS[c] for c in opts.constellations)
    log = read_ubx(paths["ubx"], systems="".join(letters))
    eph, nav_report = ephemeris_from_sfrbx(log.subframes)
    if ppp_modes.get(opts.mode).uses_iono_model and nav_report.klobuchar_alpha is None:
        raise InputError(f"[tight] mode = {opts.mode!r} needs a model ionosphere, and the log "
                         "holds no Klobuchar page (GPS subframe 4 page 18, sent every 12.5 min)",
                         file=paths["ubx"], expected="a mode without the ionosphere model "
                         "(df_code, sdf_code, float_ppp) or a longer log")
    kinds = {}
    for key in nav_report.ephemerides:
        sat, kind = key.split(":")
        kinds.setdefault(sat, set()).add(kind)
    inav_only = sorted(s for s, k in kinds.items() if s[0] == "E" and "fnav" not in k)
    if inav_only:  # their clocks refer to E1/E5b, not the E1/E5a pair used here (~dm)
        warnings.warn(f"{paths['ubx']}: Galileo {', '.join(inav_only)} have I/NAV (E1/E5b) "
                      "clocks only; used with the E1/E5a pair", stacklevel=2)
    opt = prep_mod.PrepareOptions(freq="dual", systems=letters, iono="klobuchar",
                                  signals={k: UBLOX_SIGNALS[k] for k in letters},
                                  spp_mask_rad=math.radians(opts.elevation_mask_deg))
    prep = prep_mod.prepare_gnss(log.obs, prep_mod.Products(nav=eph), opt)
    t_gnss = prep.time_gps_s
    dt_ep = float(np.round(np.median(np.diff(t_gnss)), 6))

    obs = prep.obs
    dv = doppler_velocity(obs.range_rate_m_s, obs.sat.pos_ecef, obs.sat.vel_ecef,
                          obs.sat.clock_rate_m_s, prep.approx_pos_ecef,
                          obs.available & obs.doppler_ok)
    # A-priori receiver clock drift, removed from the range rates as the SPP clock is from the
    # code and phase: a consumer receiver's TCXO drifts by tens of m/s (here -60 to -81 m/s),
    # which the Doppler gate would reject before the filter's drift state could learn it. Both
    # come from every satellite of the epoch, so the filter keeps its clock and drift states
    # free from epoch to epoch (ppp_config): they take no information from the satellites an
    # outage withholds.
    drift = np.where(np.asarray(dv.ok), np.asarray(dv.clock_rate_m_s), np.nan)
    drift = np.interp(np.arange(drift.size), np.flatnonzero(np.isfinite(drift)),
                      drift[np.isfinite(drift)])
    obs = obs._replace(range_rate_m_s=obs.range_rate_m_s - jnp.asarray(drift)[:, None])
    prep = prep._replace(obs=obs)
    vel_enu = _enu_velocity(prep, dv)
    speed = np.where(np.asarray(dv.ok) & prep.spp_ok, np.hypot(vel_enu[:, 0], vel_enu[:, 1]), 0)

    rpy = np.add(cfg.imu_mounting_rpy_deg, cfg.imu_misalignment_rpy_deg)
    inc = imu_io.imu_increments(imu_log, imu_io.sensor_to_body_dcm(*rpy))
    t_imu0 = float(imu_log.time_gps_s[0])
    t_imu1 = float(imu_log.time_gps_s[-1])
    K = int(round(dt_ep * cfg.imu_resample_hz))
    if K < 1 or abs(dt_ep * cfg.imu_resample_hz - K) > 1e-6:
        raise InputError(f"GNSS epoch interval {dt_ep} s is not a whole number of IMU "
                         f"intervals at [imu] resample_hz = {cfg.imu_resample_hz:g}",
                         file=paths["ubx"])
    level_end = t_imu0 + cfg.alignment_level_s
    moving = np.flatnonzero((speed > cfg.alignment_min_speed_m_s) & (t_gnss > level_end))
    if moving.size == 0:
        raise InputError(f"the receiver never moves faster than [alignment] min_speed_m_s = "
                         f"{cfg.alignment_min_speed_m_s} m/s after the levelling window",
                         file=paths["ubx"], expected="a log that starts at rest, then moves")
    k0 = int(moving[0])
    last = np.flatnonzero(t_gnss <= t_imu1)
    n_ep = int(last[-1]) - k0 if last.size else 0
    if n_ep < 2:
        raise InputError("fewer than two GNSS epochs inside the IMU log after the start",
                         file=paths["imu"], expected="IMU and GNSS logs of the same run")

    # levelling and gyro calibration over the log's first seconds, which must be at rest
    lev = (t_gnss <= level_end) & np.asarray(dv.ok)
    if not lev.any() or speed[lev].max() > REST_SPEED_M_S:
        raise InputError(f"the receiver is not at rest during the first [alignment] level_s = "
                         f"{cfg.alignment_level_s:g} s (Doppler speed up to "
                         f"{speed[lev].max() if lev.any() else float('nan'):.2f} m/s)",
                         file=paths["ubx"], expected=f"a log that starts with {REST_SPEED_M_S}"
                         " m/s or less for level_s seconds (levelling and gyro calibration)")
    n_lev = max(int(round(cfg.alignment_level_s * cfg.imu_resample_hz)), 2)
    dth_l, dv_l = resample_increments(inc, t_imu0 + 1e-6, 1.0 / cfg.imu_resample_hz, n_lev)
    level_f = dv_l.sum(0) / (n_lev / cfg.imu_resample_hz)
    euler_lev = np.asarray(loose.align_from_gnss(jnp.zeros(3), jnp.asarray(level_f)))
    llh0 = np.asarray(geodesy.ecef_to_llh(jnp.asarray(prep.spp_pos_ecef[k0])))
    nav_lev = loose.initial_nav(llh0, np.zeros(3), euler_lev)
    sensors = InsSystem(layout=LAYOUTS[cfg.imu_errors_states]).calibrate_static(
        nav_lev, strapdown.ImuIncrements(jnp.asarray(dth_l), jnp.asarray(dv_l)),
        1.0 / cfg.imu_resample_hz)

    dth, dvv = resample_increments(inc, float(t_gnss[k0]), dt_ep / K, n_ep * K)
    samples = strapdown.ImuIncrements(jnp.asarray(dth.reshape(n_ep, K, 3)),
                                      jnp.asarray(dvv.reshape(n_ep, K, 3)))
    t_ep = t_gnss[k0 + 1: k0 + 1 + n_ep]
    ref_llh = ref_q = None
    if paths.get("reference"):
        ref = pos_io.read_pos(paths["reference"])
        ref_llh = np.stack([np.interp(t_ep, ref.time_gps_s, ref.llh[:, i]) for i in range(3)], 1)
        if opts.reference_height == "msl":  # to ellipsoidal with the receiver's geoid model
            sep = log.pvt.llh[:, 2] - log.pvt.h_msl_m
            ref_llh[:, 2] += np.interp(t_ep, log.pvt.time_gps_s, sep)
        j = np.clip(np.searchsorted(ref.time_gps_s, t_ep), 1, ref.q.size - 1)
        j = np.where(np.abs(ref.time_gps_s[j - 1] - t_ep) < np.abs(ref.time_gps_s[j] - t_ep),
                     j - 1, j)
        ref_q = np.where(np.abs(ref.time_gps_s[j] - t_ep) < 0.05, ref.q[j], 0)  # same epoch
        if not np.any(ref_q == 1):
            raise InputError("no fixed (Q = 1) epoch of the reference inside the run",
                             file=paths["reference"], expected="an RTK track of the same run")
    return Recording(prep, k0, t_ep, t_imu0, dt_ep / K, samples, level_f,
                     np.asarray(sensors.gyro_bias_rad_s), vel_enu[k0], prep.spp_pos_ecef[k0],
                     ref_llh, ref_q, log.counts, nav_report)


def ppp_config(opts: TightOptions, rec: Recording) -> ppp.PppConfig:
    """The PPP part of both filters (recorded-data stochastic model)."""
    sys_ids = tuple(sorted({prep_mod.LETTER_TO_SYS[LETTERS[c]] for c in opts.constellations}))
    # No zenith wet delay state (chosen): over a two-minute run a few-cm ZWD error is a
    # near-constant common offset that the metre-level broadcast orbits and clocks swamp.
    cfg = ppp.PppConfig(mode=opts.mode, systems=sys_ids, n_slots=len(rec.prep.sv),
                        doppler=opts.doppler, estimate_zwd=False,
                        elevation_mask_rad=math.radians(opts.elevation_mask_deg)
                        ).for_recorded_data()
    return dataclasses.replace(cfg, clock_drift_psd_m2_s3=FREE_DRIFT_PSD_M2_S3)


def _ins_system(cfg: CarConfig) -> InsSystem:
    lever_ant, _ = lever_arms_b(cfg)
    return InsSystem(layout=LAYOUTS[cfg.imu_errors_states], model=imu_error_model(cfg),
                     lever_b=jnp.asarray(lever_ant), gyro_calibration_s=cfg.alignment_level_s)


def _start(cfg: CarConfig, opts: TightOptions, rec: Recording, system: InsSystem):
    """Initial INS state, its sigmas and the calibrated sensors (module docstring)."""
    euler = np.asarray(loose.align_from_gnss(jnp.asarray(rec.vel0_enu),
                                             jnp.asarray(rec.level_f_b)))
    llh_ant = np.asarray(geodesy.ecef_to_llh(jnp.asarray(rec.pos0_ecef)))
    lever_l = np.asarray(attitude.dcm_from_euler(jnp.asarray(euler))) @ np.asarray(system.lever_b)
    llh0 = llh_ant - np.asarray(geodesy.llh_rate_matrix(jnp.asarray(llh_ant))) @ lever_l
    nav0 = loose.initial_nav(llh0, rec.vel0_enu, euler)
    sig = NavSigmas(pos_m=opts.start_sigma_m, vel_m_s=cfg.alignment_vel_sigma_m_s,
                    roll_pitch_rad=math.radians(cfg.alignment_roll_pitch_sigma_deg),
                    azimuth_rad=math.radians(opts.heading_sigma_deg),
                    gyro_calibration_s=cfg.alignment_level_s)
    sensors0 = system.zero_sensors()._replace(gyro_bias_rad_s=jnp.asarray(rec.gyro_bias0_rad_s))
    return nav0, sig, sensors0


def _gnss_inputs(rec: Recording) -> tight.EpochInput:
    obs = jax.tree.map(lambda a: a[rec.epochs], rec.prep.obs)
    return tight.EpochInput(samples=rec.samples, obs=obs,
                            keep=jnp.ones(obs.available.shape, bool),
                            day_of_year=rec.prep.day_of_year[rec.epochs])


def build_tight(cfg: CarConfig, opts: TightOptions, rec: Recording):
    """(TightFilter, initial carry, inputs) of the recording."""
    system = _ins_system(cfg)
    tf = tight.TightFilter(system=system, cfg=ppp_config(opts, rec), slots=rec.prep.slots,
                           imu_dt_s=rec.imu_dt_s, epoch_dt_s=rec.epoch_dt_s)
    nav0, sig, sensors0 = _start(cfg, opts, rec, system)
    obs0 = jax.tree.map(lambda a: a[rec.k0], rec.prep.obs)
    carry = tight.initial_carry(tf, nav0, obs0, sig, sensors0)
    return tf, carry, _gnss_inputs(rec)


def build_loose(cfg: CarConfig, opts: TightOptions, rec: Recording):
    """(CascadeFilter, initial carry, inputs): GNSS-only PPP of the same mode feeding the LC."""
    system = _ins_system(cfg)
    lcfg = loose.LooseConfig(use_pos=True, use_vel=True, use_nhc=False, use_zupt=False,
                             use_zaru=False, cov_substeps=cfg.filter_cov_substeps,
                             gate_chi2=cfg.filter_gate_chi2)
    lf = loose.LooseFilter(system, lcfg, rec.imu_dt_s, rec.epoch_dt_s)
    pcfg = ppp_config(opts, rec)
    cf = cascade.make_filter(pcfg, rec.prep.slots, lf)
    nav0, sig, sensors0 = _start(cfg, opts, rec, system)
    obs0 = jax.tree.map(lambda a: a[rec.k0], rec.prep.obs)
    ppp_nav0 = ppp_only.GnssNav(np.asarray(geodesy.ecef_to_llh(jnp.asarray(rec.pos0_ecef))),
                                jnp.asarray(rec.vel0_enu))
    carry = cascade.initial_carry(cf, nav0, obs0, sig, sensors0, ppp_nav0)
    return cf, carry, cascade.epoch_inputs(_gnss_inputs(rec), nhc_valid=False,
                                           zupt_allowed=False)


class OutagePlan(NamedTuple):
    ids: tuple[str, ...]
    start_s: np.ndarray  # [n] after the first IMU sample
    length_s: np.ndarray
    kept: np.ndarray  # [n] satellites kept
    start_epoch: np.ndarray  # [n] first withheld epoch (index into the filter epochs)
    n_epochs: np.ndarray


def plan_outages(rec: Recording, sched: ot.Schedule) -> OutagePlan:
    """Outage windows on the filter epochs: epochs t with start <= t - t_imu0 < start + length
    (the rule of ``jaxnav lc``); each must lie inside the run after the start epoch."""
    t_rel = rec.time_gps_s - rec.t_imu0_gps_s
    kept = (np.zeros(len(sched.id), np.int64) if sched.satellites_kept is None
            else np.asarray(sched.satellites_kept))
    first, count = [], []
    for i, oid in enumerate(sched.id):
        inside = np.flatnonzero((t_rel >= sched.start_s[i] - 1e-6)
                                & (t_rel < sched.start_s[i] + sched.length_s[i] - 1e-6))
        if inside.size == 0 or inside[-1] == t_rel.size - 1 or sched.start_s[i] < t_rel[0]:
            raise InputError(f"outage {oid!r} ({sched.start_s[i]:g} s + {sched.length_s[i]:g} "
                             "s) is not inside the run", expected=f"start_s in "
                             f"[{t_rel[0]:.2f}, {t_rel[-1]:.2f}) s after the first IMU sample "
                             "and an end before the last epoch")
        first.append(int(inside[0]))
        count.append(int(inside.size))
    return OutagePlan(tuple(sched.id), np.asarray(sched.start_s), np.asarray(sched.length_s),
                      kept, np.asarray(first), np.asarray(count))


def keep_masks(rec: Recording, plan: OutagePlan) -> jnp.ndarray:
    """[n + 1, E, S] keep masks: no outage first, then every planned outage."""
    inp_avail = jnp.asarray(rec.prep.obs.available[rec.epochs])
    el = jnp.asarray(rec.prep.elevation_rad[rec.epochs])
    masks = [jnp.ones(inp_avail.shape, bool)]
    for k in range(len(plan.ids)):
        o = ot.Outage(jnp.asarray(plan.start_epoch[k]), jnp.asarray(plan.n_epochs[k]),
                      jnp.asarray(plan.kept[k]))
        masks.append(ot.keep_mask(el, inp_avail, o))
    return jnp.stack(masks)


@eqx.filter_jit
def run_tight(tf, carry, inputs, keeps):
    """The tight filter over every keep mask (one vmap)."""
    return jax.vmap(lambda k: tight.run(tf, carry, inputs._replace(keep=k))[1])(keeps)


@eqx.filter_jit
def run_tight_smoothed(tf, carry, inputs, keeps):
    """``run_tight`` with the RTS smoother: (forward, smoothed) outputs, each [keeps, T]. The
    forward records of every keep mask are held at once: K x T x 3 n^2 float64 (the walk's 25
    masks x 481 epochs, n ~ 34: about 0.3 GB)."""
    return jax.vmap(lambda k: tight.run_smoother(tf, carry, inputs._replace(keep=k)))(keeps)


@eqx.filter_jit
def run_loose(cf, carry, inputs, keeps):
    """The cascade (PPP -> LC) over every keep mask (one vmap)."""

    def one(k):
        gnss = inputs.gnss._replace(keep=k)
        return cascade.run(cf, carry, inputs._replace(gnss=gnss))[1]

    return jax.vmap(one)(keeps)


def horizontal_errors(rec: Recording, llh_ant, offset_enu_m=None):
    """([..., E] horizontal error [m], [..., E, 3] ENU error) of antenna tracks against the
    reference (shifted by ``offset_enu_m``, see :func:`reference_offset`)."""
    ref = jnp.asarray(rec.ref_llh)
    f = lambda x: mt.enu_errors(x, ref)
    for _ in range(np.ndim(llh_ant) - 2):
        f = jax.vmap(f)
    e = np.asarray(f(jnp.asarray(llh_ant)))
    if offset_enu_m is not None:
        e = e - np.asarray(offset_enu_m)
    return np.hypot(e[..., 0], e[..., 1]), e


def reference_offset(rec: Recording) -> np.ndarray:
    """Median over the run's fixed reference epochs of (epoch-wise SPP - reference), ENU [m].

    A reference made by RTK is only as absolute as its base station's coordinate; the walk's
    is off from every solution made with the broadcast orbits of either constellation alone
    by the same ~6 m (docs/validation.md). This median, independent of the filters, moves
    the reference into the broadcast orbits' frame, so the outage errors measure the drift
    of the filters, not the base's coordinate.
    """
    ok = rec.prep.spp_ok[rec.epochs] & (rec.ref_q == 1)
    spp_llh = jax.vmap(geodesy.ecef_to_llh)(jnp.asarray(rec.prep.spp_pos_ecef[rec.epochs][ok]))
    e = np.asarray(mt.enu_errors(spp_llh, jnp.asarray(rec.ref_llh[ok])))
    return np.median(e, axis=0)


def pos_solution(rec: Recording, llh_ant, P_nav, n_sat, withheld) -> pos_io.PosSolution:
    """A ``.pos`` solution of one run (sigmas from the navigation covariance)."""
    m = np.asarray(jax.vmap(geodesy.metres_per_radian)(jnp.asarray(llh_ant)))
    pos = st.INS15.sl("pos")
    P = np.asarray(P_nav)[:, pos, pos] * m[:, :, None] * m[:, None, :]
    sd = np.sqrt(np.maximum(np.stack([P[:, 0, 0], P[:, 1, 1], P[:, 2, 2]], -1), 0.0))
    n = sd.shape[0]
    nan3 = np.full((n, 3), np.nan)
    q = np.where(np.asarray(withheld), pos_io.Q_OUTAGE, pos_io.Q_PPP)
    return pos_io.PosSolution(rec.time_gps_s, np.asarray(llh_ant), q, np.asarray(n_sat),
                              sd, np.zeros((n, 3)), np.zeros(n), np.zeros(n), nan3, nan3, nan3)


__all__ = ["Recording", "TightOptions", "OutagePlan", "load_recording", "build_tight",
           "build_loose", "plan_outages", "keep_masks", "run_tight", "run_loose",
           "horizontal_errors", "pos_solution"]
