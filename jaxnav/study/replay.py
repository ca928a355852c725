"""The replay scenario source: a static station's real GNSS errors on a simulated drive.

``[scenario] source = "replay"`` runs a study on a station's recorded observations moved onto a
simulated vehicle that laps a circuit around the station (``gnss/replay.py``: the code, carrier
and Doppler get the change of geometric range and range rate; everything else is the real
signal). The IMU and odometer are simulated along the same trajectory, with the noise of the
realisation's seed, exactly as on a simulated drive (the same keys: the IMU noise of seed k is
the same in both sources); the truth is exact. Every system, PPP mode, outage policy and the
engine work unchanged: this factory only supplies other GNSS inputs and the recorded-data
stochastic model (``PppConfig.for_recorded_data``).

``[scenario]`` keys (paths relative to the study TOML)::

    source = "replay"
    obs = "../data/STATION.crx.gz"        # RINEX 3 observations (Hatanaka / gzip allowed)
    nav = "../data/BRDC.rnx.gz"           # broadcast navigation (TGD, Klobuchar, SF modes)
    sp3 = ["day-1.SP3.gz", "day.SP3.gz"]  # precise orbits covering the window
    clk = "day.CLK.gz"                    # precise clocks
    station_ecef_m = [X, Y, Z]            # the marker's coordinate in the products' frame
    start = "2020-06-25T01:00:00"         # GPS time of the first epoch
    duration_s = 7200                     # window length (the file's interval must divide it)
    epoch_interval_s = 30                 # must equal the file's observation interval
    drive_seed = 0                        # the circuit's seed (sim.drives.circuit_drive)
    drive_style = "circuit"               # the only style that stays near the station
    constellations = ["gps"]              # gps and/or galileo
    imu_grade, ins_grade, odometer, bssd  # as on simulated drives (study/factory.py)

Single-frequency modes level the C/A code with the P1-C1 biases measured from the file's own
C1W - C1C (``prepare.p1c1_from_observations``) and use the broadcast TGD and Klobuchar model.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import os
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.core import gpstime, schema
from jaxnav.gnss import ppp, replay
from jaxnav.io import prepare
from jaxnav.io.nav import read_broadcast_ephemeris
from jaxnav.io.products import read_clk, read_sp3
from jaxnav.io.rinex import read_rinex_obs
from jaxnav.sim import constellation, drives, observations, scenario, sensors, trajectory
from jaxnav.study.config import ConfigError
from jaxnav.study.factory import IONO_MODELS, TC_NHC_SYSTEMS, SimFactory

_LETTERS = {"gps": "G", "galileo": "E"}
#: The [scenario] table of a replay study (``core/schema.py`` rules).
REPLAY_SCHEMA = {
    "source": schema.literal("replay"),
    "obs": schema.text(),
    "nav": schema.text(),
    "sp3": schema.items(schema.text()),
    "clk": schema.text(),
    "station_ecef_m": schema.items(schema.number(), length=3, unique=False),
    "start": schema.text(),
    "duration_s": schema.number(0, strict=True, unit="seconds"),
    "epoch_interval_s": schema.number(0, strict=True, unit="seconds"),
    "drive_seed": schema.whole(0),
    "drive_style": schema.choice(("circuit",), "the replay keeps the vehicle near the station"),
    "constellations": schema.items(schema.choice(_LETTERS)),
    "imu_grade": schema.choice(sensors.IMU_GRADES, "RISS sensor presets"),
    "ins_grade": schema.choice(sensors.IMU_GRADES, "full-IMU presets"),
    "odometer": schema.choice(sensors.ODOMETERS),
    "bssd": schema.boolean(),
}
_REQUIRED = ("source", "obs", "nav", "sp3", "clk", "station_ecef_m", "start", "duration_s")
#: Largest distance [m] between the simulated antenna and the station the replay accepts: the
#: slant troposphere and ionosphere are the station's (docs/validation.md quantifies what a
#: larger distance changes). The circuit stays within ~0.5 km.
MAX_DISTANCE_M = 1000.0


def _fail(key, value, expected):
    schema.fail(f"scenario.{key}", value, expected, ConfigError)


class _RecordedFilter:
    """The filters of a replay study: the recorded-data stochastic model, and covariance steps
    of one second inside the 30-s epochs. Shared by the replay and its simulated twin, so the
    two differ only in the GNSS errors."""

    def _ppp_config(self, mode: str) -> ppp.PppConfig:
        return super()._ppp_config(mode).for_recorded_data()

    def _covariance_steps(self, system_name: str) -> int:
        """One covariance step per second for RISS16 and the tightly coupled INS: a 30-s epoch
        holds whole corners of the circuit, which one F per epoch cannot follow (RISS16 with
        one step diverged: docs/validation.md). RISS9's odometer noise is defined per epoch
        and the loose and GNSS-only systems step on their own: one step."""
        if system_name == "riss" or system_name in ("ins15", "ins21", *TC_NHC_SYSTEMS):
            return max(1, round(self.cfg.epoch_interval_s))
        return 1

    def _system(self, name: str):
        """As on a simulated drive, but RISS16's own receiver-clock states get the recorded
        data's clock PSD (``PppConfig.for_recorded_data``: the single-point clock removed, a
        metre-level residual free from epoch to epoch)."""
        system = super()._system(name)
        if name == "riss":
            params = dataclasses.replace(system.params,
                                         clock_bias_psd_m2_s=ppp.RECORDED_CLOCK_PSD_M2_S)
            system = dataclasses.replace(system, params=params)
        return system


class ReplayFactory(_RecordedFilter, SimFactory):
    """Sweep problems on a station's real observations moved onto a simulated circuit."""

    def __init__(self, table: dict, base_dir: str | os.PathLike | None = None):
        t = schema.check_section("scenario", dict(table), REPLAY_SCHEMA, required=_REQUIRED,
                                 error=ConfigError)
        base = Path(base_dir) if base_dir is not None else Path.cwd()
        self._init_args = (dict(table), base.resolve())  # what a Dask worker rebuilds it from
        self.paths = {}
        for key in ("obs", "nav", "sp3", "clk"):
            names = t[key] if key == "sp3" else (t[key],)
            paths = [(base / n).resolve() for n in names]
            for n, p in zip(names, paths, strict=True):
                if not p.is_file():
                    _fail(key, n, f"an existing file (resolved to {p})")
            self.paths[key] = paths if key == "sp3" else paths[0]
        try:
            self.t0 = dt.datetime.fromisoformat(t["start"])
        except ValueError:
            _fail("start", t["start"], "an ISO date and time in GPST, e.g. '2020-06-25T01:00:00'")
        interval = t.get("epoch_interval_s", 30.0)
        if not float(t["duration_s"] / interval).is_integer():
            _fail("duration_s", t["duration_s"], f"a whole number of {interval:g}-s epochs")
        self.station_ecef = np.asarray(t["station_ecef_m"], np.float64)
        if not 6.3e6 < np.linalg.norm(self.station_ecef) < 6.4e6:
            _fail("station_ecef_m", list(t["station_ecef_m"]),
                  "an ECEF coordinate on the Earth's surface [m]")
        names = t.get("constellations", ("gps",))
        if "gps" not in names:
            _fail("constellations", list(names), "a list containing 'gps' (the reference system)")
        self.letters = tuple(sorted((_LETTERS[n] for n in names),
                                    key=lambda s: prepare.LETTER_TO_SYS[s]))
        self.table = {k: list(v) if isinstance(v, tuple) else v for k, v in t.items()}
        self._realize_fns = {}
        self.iono_model_fraction = IONO_MODELS["klobuchar"][1]  # the nav file's broadcast model
        self.bssd = t.get("bssd", False)
        self.lc_fix_correlated = False
        self.cfg = scenario.ScenarioConfig(
            drive_seed=t.get("drive_seed", 0),
            drive_style="circuit",
            duration_s=float(t["duration_s"]),
            epoch_interval_s=float(interval),
            imu_grade=t.get("imu_grade", "crossbow_imu300cc"),
            odometer=t.get("odometer", "obd2_odometer"),
            systems=tuple(prepare.LETTER_TO_SYS[s] for s in self.letters),
            obs_params=observations.ObsParams(),
        )
        self.ins_grade = t.get("ins_grade", "span_cpt")

    @property
    def start_gps_s(self) -> float:
        return gpstime.gps_seconds(self.t0)

    # -- the recorded data ------------------------------------------------------------------------
    @functools.cached_property
    def _recorded(self):
        """The observation window and the products, read once."""
        cfg = self.cfg
        end = self.t0 + dt.timedelta(seconds=cfg.duration_s + 0.5 * cfg.epoch_interval_s)
        requests = {}
        for freq, extra in (("dual", False), ("single", True)):
            for s, codes in prepare.rinex_requests(freq, self.letters, p1_codes=extra).items():
                requests[s] = tuple(dict.fromkeys(requests.get(s, ()) + codes))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            obs = read_rinex_obs(self.paths["obs"], requests, tlim=(self.t0, end),
                                 on_missing="nan", indicators=True)
        n = round(cfg.duration_s / cfg.epoch_interval_s) + 1
        t_start = gpstime.gps_seconds(self.t0)
        grid = t_start + cfg.epoch_interval_s * np.arange(n)
        if obs.time_gps_s.size != n or not np.allclose(obs.time_gps_s, grid, atol=1e-3):
            _fail("start", self.table["start"],
                  f"a window of {n} epochs at {cfg.epoch_interval_s:g} s that "
                  f"{self.paths['obs'].name} covers (it has {obs.time_gps_s.size} there, "
                  f"interval {obs.interval_s:g} s)")
        products = prepare.Products(
            nav=read_broadcast_ephemeris(self.paths["nav"], systems="".join(self.letters)),
            sp3=read_sp3(self.paths["sp3"]),
            clk=read_clk(self.paths["clk"], systems=set(self.letters)),
        )
        return obs, products

    @functools.cache  # noqa: B019  (one factory, two frequency plans)
    def _prepared(self, single_frequency: bool) -> prepare.PreparedGnss:
        obs, products = self._recorded
        if single_frequency:
            opt = prepare.PrepareOptions(freq="single", systems=self.letters,
                                         p1c1_m=prepare.p1c1_from_observations(obs))
        else:
            opt = prepare.PrepareOptions(freq="dual", systems=self.letters)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            return prepare.prepare_gnss(obs, products, opt, static_receiver=True)

    @functools.cached_property
    def sv(self) -> tuple[str, ...]:
        """The slots: every satellite the dual-frequency data make available in the window."""
        prep = self._prepared(False)
        used = np.asarray(prep.obs.available).any(axis=0)
        return tuple(s for s, u in zip(prep.sv, used, strict=True) if u)

    def station_obs(self, single_frequency: bool) -> ppp.GnssObs:
        """The station's prepared observations [T, S] on the slots ``sv`` (a satellite the
        frequency plan lacks is unavailable in its slot)."""
        prep = self._prepared(single_frequency)
        where = {s: i for i, s in enumerate(prep.sv)}
        idx = np.array([where.get(s, 0) for s in self.sv])
        have = jnp.asarray([s in where for s in self.sv])

        def take(x):
            return jnp.asarray(x)[:, idx]

        obs = jax.tree.map(take, prep.obs)
        return obs._replace(available=obs.available & have[None, :],
                            doppler_ok=obs.doppler_ok & have[None, :])

    # -- the factory contract ---------------------------------------------------------------------
    def profile(self) -> trajectory.Profile:
        """The circuit around the station (``sim.drives.circuit_drive`` of ``drive_seed``)."""
        llh0 = tuple(float(v) for v in geodesy.ecef_to_llh(jnp.asarray(self.station_ecef)))
        return drives.circuit_drive(self.cfg.drive_seed, self.cfg.duration_s, llh0=llh0)

    @functools.cached_property
    def geo(self) -> scenario.Geometry:
        cfg = self.cfg
        truth = trajectory.generate_truth(self.profile(), cfg.imu_rate_hz, cfg.duration_s)
        truth_ep = trajectory.truth_at_epochs(truth, cfg.epoch_interval_s)
        pos, vel = scenario.antenna_track(truth_ep, jnp.asarray(cfg.lever_b_m, jnp.float64))
        far = float(np.max(np.linalg.norm(np.asarray(pos) - self.station_ecef, axis=1)))
        if far > MAX_DISTANCE_M:
            raise ConfigError(f"the drive goes {far:.0f} m from the station (replay allows "
                              f"{MAX_DISTANCE_M:.0f} m)")
        prep = self._prepared(False)
        keep = [prep.sv.index(s) for s in self.sv]
        slots = ppp.SlotInfo(*(jnp.asarray(x)[np.array(keep)] for x in prep.slots))
        doy = float(prep.day_of_year[0])
        return scenario.Geometry(truth, truth_ep, pos, vel, None, slots, None, doy)

    @functools.cached_property
    def _sky(self):
        obs = self.station_obs(False)
        sat = jax.tree.map(lambda x: x[1:], obs.sat)
        return replay.sky(sat, self.geo.ant_pos_ecef[1:])

    def _realization(self, seed: int, single_frequency: bool, imu_grade: str):
        """The replayed observations with the IMU and odometer of ``seed`` (the same keys as
        ``scenario.realize``: k_imu, k_odo, k_obs = split(key, 3); k_obs is unused)."""
        fn = self._realize_fns.get((single_frequency, imu_grade))
        if fn is None:
            geo = self.geo
            cfg = _with_grade(self.cfg, imu_grade)
            moved = replay.move_observations(self.station_obs(single_frequency),
                                             jnp.asarray(self.station_ecef),
                                             geo.ant_pos_ecef, geo.ant_vel_ecef)
            doy = jnp.asarray(self._prepared(single_frequency).day_of_year[1:])

            def one(key):
                k_imu, k_odo, _ = jax.random.split(key, 3)
                return scenario.with_sensors(k_imu, k_odo, geo, cfg, moved, doy)

            fn = self._realize_fns[(single_frequency, imu_grade)] = jax.jit(one)
        return fn(jax.random.PRNGKey(seed))


def _with_grade(cfg: scenario.ScenarioConfig, imu_grade: str) -> scenario.ScenarioConfig:
    return dataclasses.replace(cfg, imu_grade=imu_grade)


class SimulatedTwin(_RecordedFilter, SimFactory):
    """The replay's circuit, IMU noise, satellites (their broadcast orbits), epochs and filters,
    with the simulator's GNSS errors instead of the station's: what the simulator predicts for
    the same study (``experiments/real_vs_simulated_errors.py``)."""

    def __init__(self, replay: ReplayFactory):
        keep = ("drive_seed", "imu_grade", "ins_grade", "odometer", "bssd", "constellations")
        super().__init__({k: v for k, v in replay.table.items() if k in keep})
        self._init_args = (replay,)
        self.replay = replay
        self.table = {"twin_of": replay.table}
        # as many slots per constellation as the window has satellites above the mask
        _, products = replay._recorded
        cfg = dataclasses.replace(
            self.cfg, drive_style="circuit", duration_s=replay.cfg.duration_s,
            epoch_interval_s=replay.cfg.epoch_interval_s, t0_gps_s=gpstime.gps_seconds(replay.t0),
            lever_b_m=replay.cfg.lever_b_m)
        t = replay.geo.truth_ep
        el, _ = constellation.elevations(products.nav, t.time_s, replay.geo.ant_pos_ecef,
                                         cfg.t0_gps_s)
        seen = np.asarray(constellation.visible(el, cfg.obs_params.elevation_mask_rad).any(0))
        system = np.asarray(products.nav.system)
        counts = tuple(int(np.sum(seen & (system == s))) for s in range(len(cfg.slots_per_system)))
        self.cfg = dataclasses.replace(cfg, slots_per_system=counts)

    @functools.cached_property
    def geo(self) -> scenario.Geometry:
        _, products = self.replay._recorded
        return scenario.build_geometry(self.cfg, self.replay.profile(), orbits=products.nav)
