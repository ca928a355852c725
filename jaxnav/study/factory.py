"""The simulated scenario factory the sweep engine drives (``study.sweep.run_sweep``).

A factory turns a study's ``[scenario]`` table into (a) one drive (geometry, truth, satellite
slots), shared by every mode, system and realisation, and (b) per (mode, system, seed) a filter,
its initial carry and the realisation's stacked inputs (``sweep.Problem``).

``[scenario]`` keys (all optional; ``source = "replay"`` selects ``study/replay.py`` instead,
``study/sources.py``):

    drive_seed = 0            # random drive generator seed
    drive_style = "mixed"     # mixed | urban | suburban | highway | circuit (laps of a
                              # 400 m x 200 m rectangle, sim.drives.circuit_drive)
    duration_s = 900          # drive length
    imu_grade = "crossbow_imu300cc"   # RISS sensors (S000); "ins" systems use ins_grade
    ins_grade = "span_cpt"
    odometer = "obd2_odometer"
    iono_scale = 1.0          # multiplies the simulated ionosphere (1 = 2020 solar minimum)
    iono_model = "klobuchar"  # the ionosphere model the filters get (SF rows, IC-PPP prior):
                              # "klobuchar" (30 % residual) or "gim" (a GIM-grade map, S001)
    constellations = ["gps"]  # any of gps, glonass, galileo (S004 multi-GNSS, with ISB states)
    slots = [16, 14, 14]      # fixed satellite slots per constellation (GPS, GLONASS, Galileo)
    bssd = false              # between-satellite single differences (S004) instead of UD
    environment = "open_sky"  # cycle-slip and loss-of-lock rates: none | open_sky | suburban |
                              # urban (sim.observations.SLIP_ENVIRONMENTS)
    slip_flags = "detector"   # the filter's slips: LLI + GF / MW detector (as on real data),
                              # or "oracle" (the simulator's true arc starts)
    lc_fix_errors = "white"   # LC systems: the PPP fix's error as independent per epoch, or
                              # "correlated" (fix-bias states, LC_FIX_BIAS_TAU_S; not yet the
                              # default: docs/models.md)
    drive_style = "airborne"  # also allowed: a seeded random flight (S001) instead of a drive

Systems: ``riss`` (S000's 16-state RISS, 1 Hz inputs), ``riss9`` (S002's 9 + GNSS states),
``ins15`` and ``ins21`` (full IMU at 100 Hz), all tightly coupled (``ins15_nhc`` /
``ins21_nhc``: with the tight filter's optional NHC update, sigma 1 m/s, S003); and the loosely
coupled ``lc_ins15`` / ``lc_ins21`` (``filter.cascade``: a GNSS-only constant-velocity PPP
filter of the same mode whose position / velocity fix, valid with >= 4 satellites used, aids a
15 / 21-state INS). A ``_nhc`` suffix (``lc_ins15_nhc``, ``lc_ins21_nhc``) adds the
non-holonomic constraint (lateral and vertical body velocity 0, sigma 1 m/s, S003) to the LC
filter at every epoch; ``lc_ins15_nhc_zupt`` also applies ZUPT and ZARU at standstills found by
the IMU variance detector (S002 ch. 4). The engine asks ``ops_for(mode, system)`` for the
filter contract (``cascade_ops`` for ``lc_*``).
"""

from __future__ import annotations

import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.core import schema
from jaxnav.core.states import INS15, INS21, RISS9, RISS16
from jaxnav.filter import cascade, loose, ppp_only, systems, tight
from jaxnav.gnss import modes as ppp_modes
from jaxnav.gnss import ppp, signals
from jaxnav.sim import constellation, observations, scenario, sensors
from jaxnav.study import metrics
from jaxnav.study.config import ConfigError
from jaxnav.study.sweep import Problem, Timeline, tight_ops

#: Loosely coupled systems (``filter.cascade``): INS layout, NHC rows, ZUPT / ZARU at detected
#: standstills (``loose.LooseConfig.use_zupt``: the IMU variance detector, S002 ch. 4).
LC_SYSTEMS = {
    "lc_ins15": (INS15, False, False),
    "lc_ins21": (INS21, False, False),
    "lc_ins15_nhc": (INS15, True, False),
    "lc_ins21_nhc": (INS21, True, False),
    "lc_ins15_nhc_zupt": (INS15, True, True),
}
#: Tightly coupled full-IMU systems with the NHC update (``TightFilter.nhc_sigma_m_s``).
TC_NHC_SYSTEMS = ("ins15_nhc", "ins21_nhc")
# Correlation time [s] of the stand-alone PPP solution's position error per mode: with
# [scenario] lc_fix_errors = "correlated" the LC filter models its fix error as a Gauss-Markov
# process with it (filter.loose fix_bias_tau_s). Measured
# in the realistic simulator, 8 runs x 900 s after 300 s (1/e lag of the error autocorrelation,
# benchmarks/ppp_error_correlation.py, RESULTS.md 2026-12-03), rounded.
LC_FIX_BIAS_TAU_S = {"sf_code": 315.0, "df_code": 55.0, "sdf_code": 62.0, "float_ppp": 400.0,
                     "ic_ppp": 600.0, "sf_ppp": 600.0}
NHC_SIGMA_M_S = 1.0  # S003: NHC noise 1 m/s (a 2-3 deg misalignment at 18-20 m/s)
#: PPP alone: the tight filter's PPP rows and resets on a GNSS-only receiver
#: (``ppp_only.GnssOnlySystem``), scored against the true ANTENNA track (the receiver estimates
#: the antenna; the other systems are scored at the IMU), on the same GNSS realisation (seed).
PPP_ALONE = "ppp_alone"
# Constant velocity (Doppler-observed ENU velocity, white acceleration 1 m/s^2/sqrt(Hz)): with
# the random-walk model (S002 5.2.3, position held between epochs) a 25-50 m/s vehicle moves
# more than the 20 m code pre-fit test between epochs and most satellites are rejected
# (measured: 2 of 7 used, the error grows with the distance flown).
PPP_ALONE_MODEL = "constant_velocity"
SYSTEMS = ("riss", "riss9", "ins15", "ins21", *LC_SYSTEMS, *TC_NHC_SYSTEMS, PPP_ALONE)
#: [scenario] iono_model -> (simulator GIM error fraction, the filters' model residual fraction).
#: The filters' fraction is the simulated residual's sigma (0.3 x the GM residual, times 0.25
#: for the GIM), rounded up.
IONO_MODELS = {"klobuchar": (None, 0.3), "gim": (0.25, 0.1)}
_CONSTELLATIONS = {"gps": signals.SYS_GPS, "glonass": signals.SYS_GLO, "galileo": signals.SYS_GAL}
#: Simulated drive styles (``jaxnav.sim.drives``), as ``jaxnav list drives`` describes them.
DRIVE_STYLES = {
    "mixed": "urban -> suburban -> highway -> suburban -> urban, 30-100 km/h (default; the "
             "seeds' Kingston drives)",
    "urban": "30-60 km/h, stop-and-go at lights, sharp turns of 10-25 m radius",
    "suburban": "50-80 km/h, intersections, curves and hills",
    "highway": "80-100 km/h, gentle curves of 0.5-2 km radius",
    "circuit": "laps of a closed rectangular circuit, left corners",
    "airborne": "a flight at 45-50 m/s with banked turns, climbs and descents (seed 001)",
}
_DRIVE_STYLES = tuple(DRIVE_STYLES)
#: The [scenario] table of a study on simulated drives (``core/schema.py`` rules).
SCENARIO_SCHEMA = {
    "drive_seed": schema.whole(0),
    "drive_style": schema.choice(_DRIVE_STYLES),
    "duration_s": schema.number(0, strict=True, unit="seconds"),
    "imu_grade": schema.choice(sensors.IMU_GRADES, "RISS sensor presets"),
    "ins_grade": schema.choice(sensors.IMU_GRADES, "full-IMU presets"),
    "odometer": schema.choice(sensors.ODOMETERS),
    # daytime mid-latitude VTEC: 10-15 TECU at solar minimum, 40-60 at maximum, ~200 in the
    # strongest storms recorded (October 2003)
    "iono_scale": schema.number(0, hi=20, why="the strongest recorded storms"),
    "constellations": schema.items(schema.choice(_CONSTELLATIONS)),
    "slots": schema.items(schema.whole(1), length=3, unique=False),
    "bssd": schema.boolean(),
    "iono_model": schema.choice(IONO_MODELS),
    "environment": schema.choice(observations.SLIP_ENVIRONMENTS, "cycle-slip rates"),
    "slip_flags": schema.choice(scenario.SLIP_FLAGS),
    "lc_fix_errors": schema.choice(("white", "correlated"), "LC fix-error models"),
}
#: What a study gets for a key its [scenario] table leaves out (``jaxnav init`` writes them).
SCENARIO_DEFAULTS = {
    "drive_seed": 0,
    "drive_style": "mixed",
    "duration_s": 900.0,
    "imu_grade": "crossbow_imu300cc",
    "ins_grade": "span_cpt",
    "odometer": "obd2_odometer",
    "iono_scale": 1.0,
    "constellations": ("gps",),
    "slots": (16, 14, 14),
    "bssd": False,
    "iono_model": "klobuchar",
    "environment": "open_sky",
    "slip_flags": "detector",
    "lc_fix_errors": "white",
}
# Peak-memory model (benchmarks/RESULTS.md, "Memory model", peak RSS of jaxnav sweep): the fixed
# part (XLA, compiled programs; 1.29-1.37 GB measured), bytes per second of drive held (RISS
# 72 kB/s, INS15 31 kB/s measured: the larger is used for both) and per scenario-window epoch of
# a chunk (INS15 9.6 kB measured; RISS, whose inputs are a third of INS15's, gets the same).
_MEMORY_FIXED_BYTES = 1.4e9
_DRIVE_BYTES_PER_S = 72e3
_WINDOW_EPOCH_BYTES = 9.6e3
_STATIC_CALIBRATION_S = 30.0  # the drives start with a 60 s standstill


class SimFactory:
    """Builds sweep problems from simulated drives (module docstring)."""

    modes = ppp_modes.MODES
    systems = SYSTEMS

    def __init__(self, table: dict | None = None):
        table = dict(table or {})
        self._init_args = (dict(table),)
        t = schema.check_section("scenario", table, SCENARIO_SCHEMA, error=ConfigError)
        if "gps" not in t.get("constellations", ("gps",)):
            schema.fail("scenario.constellations", table["constellations"],
                        "a list containing 'gps' (the reference system)", ConfigError)
        self.table = {k: list(v) if isinstance(v, tuple) else v for k, v in t.items()}
        # compiled simulators by (single frequency, IMU grade): one per factory (``_realize``)
        self._realize_fns: dict[tuple[bool, str], object] = {}
        d = SCENARIO_DEFAULTS | t
        gim_fraction, self.iono_model_fraction = IONO_MODELS[d["iono_model"]]
        self.bssd = d["bssd"]
        self.lc_fix_correlated = d["lc_fix_errors"] == "correlated"
        self.cfg = scenario.ScenarioConfig(
            drive_seed=d["drive_seed"],
            drive_style=d["drive_style"],
            duration_s=d["duration_s"],
            imu_grade=d["imu_grade"],
            odometer=d["odometer"],
            systems=tuple(sorted(_CONSTELLATIONS[c] for c in set(d["constellations"]))),
            slots_per_system=tuple(d["slots"]),
            obs_params=observations.slip_environment(
                observations.ObsParams(
                    iono_scale=d["iono_scale"], gim_error_fraction=gim_fraction
                ),
                d["environment"],
            ),
            slip_flags=d["slip_flags"],
        )
        self.ins_grade = d["ins_grade"]

    def __reduce__(self):
        # A factory crosses to Dask workers as its [scenario] table and, once simulated, its
        # drive (~20 MB that take ~9 s to simulate: sent, not rebuilt on every worker). The
        # compiled simulators do not pickle and are compiled there.
        return _restore_sim_factory, (self._init_args, self.__dict__.get("geo"))

    def fingerprint(self) -> str:
        return json.dumps(self.table, sort_keys=True)

    @functools.cached_property
    def geo(self) -> scenario.Geometry:
        return scenario.build_geometry(self.cfg)

    @functools.cached_property
    def _sky(self):
        """Elevation, azimuth [T, S] of the slots along the true antenna track (epochs 1..)."""
        g = self.geo
        el, az = constellation.elevations(g.orbits, g.truth_ep.time_s[1:], g.ant_pos_ecef[1:],
                                          self.cfg.t0_gps_s)
        idx = g.slot_table.sat_index
        occ = g.slot_table.occupied[None, :]
        return jnp.where(occ, el[:, idx], -jnp.pi / 2), jnp.where(occ, az[:, idx], 0.0)

    def memory_bytes(self, study_cfg, *, rows: int, chunk_epochs: int) -> dict[str, float]:
        """Peak memory of a sweep [bytes]: fixed + rows x drive + chunk (measured model).

        drive = duration_s x the per-second cost (the drive's truth, IMU and GNSS inputs, the
        full run's outputs and checkpoints); chunk =
        chunk_size x window epochs x the per-epoch cost of a scenario window. The figures are
        peak-RSS slopes measured on this simulator (benchmarks/RESULTS.md, "Memory model").
        With ``smooth`` each window epoch also holds the smoother's record, 3 n^2 float64 for
        the study's largest filter (n error states; computed, jaxnav.filter.smoother).
        """
        drive = rows * self.cfg.duration_s * _DRIVE_BYTES_PER_S
        per_epoch = _WINDOW_EPOCH_BYTES
        if getattr(study_cfg, "smooth", False):
            n = max(self.filter(m, s).layout.size for m in study_cfg.modes
                    for s in study_cfg.systems if s not in LC_SYSTEMS)
            per_epoch += 3 * 8 * n * n
        chunk = chunk_epochs * per_epoch
        return {"drive": drive, "chunk": chunk, "total": _MEMORY_FIXED_BYTES + drive + chunk}

    @property
    def n_slots(self) -> int:
        """Satellite slots of the scenario (the most a study can keep in an outage)."""
        return int(self.geo.slots.system.shape[0])

    def timeline(self, study_cfg) -> Timeline:
        t_s = self.geo.truth_ep.time_s  # [n + 1]: the initial state, then the filter epochs
        return Timeline(int(t_s.shape[0]) - 1, self.cfg.epoch_interval_s,
                        np.asarray(self.geo.truth_ep.event[1:]),
                        self.start_gps_s + float(t_s[1]))

    @property
    def start_gps_s(self) -> float:
        """GPS time of the scenario start (time_s = 0)."""
        return float(self.cfg.t0_gps_s)

    def ops_for(self, mode: str, system_name: str):
        """The sweep engine's ``FilterOps`` for a (mode, system) group."""
        return cascade.cascade_ops() if system_name in LC_SYSTEMS else tight_ops()

    def _system(self, name: str):
        cfg = self.cfg
        if name == PPP_ALONE:
            return ppp_only.GnssOnlySystem(model=PPP_ALONE_MODEL)
        if name.startswith("riss"):
            return systems.RissSystem.for_sensors(
                sensors.imu_grade(cfg.imu_grade),
                sensors.odometer(cfg.odometer),
                cfg.lever_b_m,
                1.0 / cfg.riss_rate_hz,
                # RISS16 reads the interval of one covariance step (its odometer-scale rate)
                cfg.epoch_interval_s / self._covariance_steps(name),
                layout=RISS16 if name == "riss" else RISS9,
            )
        if name in LC_SYSTEMS:
            layout = LC_SYSTEMS[name][0]
        else:
            layout = INS15 if name.startswith("ins15") else INS21
        model = loose.imu_error_model(sensors.imu_grade(self.ins_grade))
        return systems.InsSystem(layout, model, jnp.asarray(cfg.lever_b_m, jnp.float64),
                                 gyro_calibration_s=self._calibration_s())

    def _calibration_s(self) -> float | None:
        """Seconds of the standstill gyro calibration ``start`` does (a flight has none)."""
        if self.cfg.drive_style == "airborne":
            return None
        return self._calibration_epochs() * self.cfg.epoch_interval_s

    def _calibration_epochs(self) -> int:
        return max(1, round(_STATIC_CALIBRATION_S / self.cfg.epoch_interval_s))

    def _ppp_config(self, mode: str) -> ppp.PppConfig:
        """The PPP rows' configuration of ``mode`` (the simulator's stochastic model)."""
        return ppp.PppConfig(
            mode=mode,
            systems=self.cfg.systems,
            n_slots=int(self.geo.slots.system.shape[0]),
            estimate_zwd=ppp_modes.get(mode).uses_phase,
            bssd=self.bssd,
            iono_model_residual_fraction=self.iono_model_fraction,
        )

    def _realization(self, seed: int, single_frequency: bool, imu_grade: str):
        """One noise realisation of the drive (IMU of ``imu_grade``, GNSS of the frequency plan)."""
        return _realize(self, seed, single_frequency, imu_grade)

    def filter(self, mode: str, system_name: str) -> tight.TightFilter | cascade.CascadeFilter:
        cfg, geo = self.cfg, self.geo
        system = self._system(system_name)
        rate = cfg.riss_rate_hz if system_name.startswith("riss") else cfg.imu_rate_hz
        pcfg = self._ppp_config(mode)
        if system_name in LC_SYSTEMS:
            _, nhc, zupt = LC_SYSTEMS[system_name]
            lcfg = loose.LooseConfig(
                use_nhc=nhc, nhc_sigma_m_s=NHC_SIGMA_M_S, use_zupt=zupt, use_zaru=zupt,
                fix_bias_tau_s=LC_FIX_BIAS_TAU_S.get(mode) if self.lc_fix_correlated else None,
            )
            lf = loose.LooseFilter(system, lcfg, 1.0 / rate, cfg.epoch_interval_s)
            return cascade.make_filter(pcfg, geo.slots, lf)
        if system_name == PPP_ALONE:  # no inertial samples: one "sample" per epoch
            return tight.TightFilter(system, pcfg, geo.slots, cfg.epoch_interval_s,
                                     cfg.epoch_interval_s)
        nhc = NHC_SIGMA_M_S if system_name in TC_NHC_SYSTEMS else None
        return tight.TightFilter(
            system, pcfg, geo.slots, 1.0 / rate, cfg.epoch_interval_s, nhc_sigma_m_s=nhc,
            covariance_steps=self._covariance_steps(system_name),
        )

    def _covariance_steps(self, system_name: str) -> int:
        """``TightFilter.covariance_steps`` of a system: one per epoch on the 1-Hz drives."""
        return 1

    def start(self, tf, system_name: str, real: scenario.Realization):
        """Initial carry: truth-initialised navigation state, standstill sensor calibration
        with the gyro-bias prior it earns (``NavSigmas.gyro_calibration_s``; LC systems: the
        PPP filter starts at the true antenna position and velocity)."""
        geo = self.geo
        if system_name.startswith("riss"):
            nav0, inputs = scenario.initial_riss_state(geo), real.riss_inputs
        else:
            nav0, inputs = scenario.initial_ins_state(geo), real.ins_inputs
        sigmas = systems.NavSigmas()
        if self.cfg.drive_style == "airborne":  # a flight starts moving: nothing to calibrate
            sens0 = None
        else:
            head = jax.tree.map(
                lambda x: x[: self._calibration_epochs()].reshape(-1, *x.shape[2:]),
                inputs.samples,
            )
            ins = tf.lc if system_name in LC_SYSTEMS else tf
            sens0 = ins.system.calibrate_static(nav0, head, ins.imu_dt_s)
            sigmas = systems.NavSigmas(gyro_calibration_s=self._calibration_s())
        if system_name in LC_SYSTEMS:
            carry0 = cascade.initial_carry(tf, nav0, real.obs0, sigmas, sensors0=sens0)
            return carry0, cascade.epoch_inputs(inputs)
        return tight.initial_carry(tf, nav0, real.obs0, sigmas, sensors0=sens0), inputs

    def build(self, study_cfg, mode: str, system_name: str, seed: int) -> Problem:
        geo = self.geo
        tf = self.filter(mode, system_name)
        if system_name == PPP_ALONE:
            return self._ppp_alone(tf, mode, seed)
        grade = self.cfg.imu_grade if system_name.startswith("riss") else self.ins_grade
        real = self._realization(int(seed), ppp_modes.get(mode).single_frequency, grade)
        carry0, inputs = self.start(tf, system_name, real)
        t = geo.truth_ep
        truth = metrics.track(t.llh[1:], t.vel_enu[1:], t.euler[1:])
        el, az = self._sky
        obs = inputs.gnss.obs if system_name in LC_SYSTEMS else inputs.obs
        return Problem(tf, carry0, inputs, truth, el, obs.available, az)


    def _ppp_alone(self, tf, mode: str, seed: int) -> Problem:
        """PPP alone's problem (``PPP_ALONE``): truth and start at the antenna."""
        geo = self.geo
        sf = ppp_modes.get(mode).single_frequency
        # The GNSS noise depends only on the seed: reuse a simulator already compiled for this
        # frequency plan (any IMU grade) instead of compiling another one.
        done = [g for (f, g) in self._realize_fns if f == sf]
        real = self._realization(int(seed), sf, done[0] if done else self.ins_grade)
        T = int(real.ins_inputs.keep.shape[0])
        inputs = real.ins_inputs._replace(samples=ppp_only.dummy_samples(T))
        llh_ant = jax.vmap(geodesy.ecef_to_llh)(geo.ant_pos_ecef)
        vel_ant = jax.vmap(lambda v, p: geodesy.C_l_e(p[0], p[1]).T @ v)(geo.ant_vel_ecef, llh_ant)
        carry0 = tight.initial_carry(tf, ppp_only.GnssNav(llh_ant[0], vel_ant[0]), real.obs0)
        truth = metrics.track(llh_ant[1:], vel_ant[1:], geo.truth_ep.euler[1:])
        el, az = self._sky
        return Problem(tf, carry0, inputs, truth, el, inputs.obs.available, az)


def _restore_sim_factory(init_args: tuple, geo: scenario.Geometry | None) -> SimFactory:
    """A pickled ``SimFactory``: rebuilt from its table, with its drive if it had one."""
    factory = SimFactory(*init_args)
    if geo is not None:
        factory.__dict__["geo"] = geo  # functools.cached_property's slot
    return factory


def _realize(factory: SimFactory, seed: int, single_frequency: bool, imu_grade: str):
    """One noise realisation with the IMU of ``imu_grade``. The simulator is compiled once per
    factory, frequency plan and grade (a fresh ``jit`` per seed recompiled it: ~4 s each)."""
    cache = factory._realize_fns
    fn = cache.get((single_frequency, imu_grade))
    if fn is None:
        geo = factory.geo
        cfg = dataclasses.replace(factory.cfg, imu_grade=imu_grade)
        fn = cache[(single_frequency, imu_grade)] = jax.jit(
            lambda k: scenario.realize(k, geo, cfg, single_frequency)
        )
    return fn(jax.random.PRNGKey(seed))
