"""How far from the station may a replayed trajectory go? (issue 17: the replay's limits)

The replay (``jaxnav/gnss/replay.py``) keeps the station's slant troposphere and ionosphere.
A vehicle at distance d sees every satellite at another elevation and azimuth, through other
pierce points: its slant delays differ from the station's by dT and dI, which the replayed
observations do not contain while the filter's models (troposphere a priori, Klobuchar for the
single-frequency and ionosphere-constrained modes) do follow the vehicle. This script measures
that difference with the filters' own models, for the ESBC window and satellites of
``configs/esbc_replay.toml``, at d = 1, 10, 50 km north and east of the station:

- dT: Saastamoinen + Niell slant troposphere (``corrections.tropo_slant_delay_m``), same height;
- dI: broadcast Klobuchar slant L1 delay (mapping and pierce-point change; the real
  ionosphere's horizontal gradient is of the same order as the model's);
- each also minus its per-epoch mean over the satellites, the part a receiver clock cannot take.

Run: ``python experiments/replay_limits.py`` (needs ../shared/data; ~40 s). Writes
``experiments/results/replay_limits/report.md``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401
from jaxnav import geodesy
from jaxnav.gnss import corrections, series
from jaxnav.study import config
from jaxnav.study.sources import factory_for

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "configs" / "esbc_replay.toml"
OUT = ROOT / "experiments" / "results" / "replay_limits"
DISTANCES_KM = (1.0, 10.0, 50.0)
MASK_DEG = 10.0


def _slant(pos, sat_pos, sat_clock, t_rx, nav, doy):
    """Model slant troposphere and Klobuchar L1 ionosphere [m] per epoch and slot at ``pos``."""
    T = sat_pos.shape[0]
    rx = jnp.broadcast_to(jnp.asarray(pos), (T, 3))
    _, el, _, llh, _ = series.geometry_series(rx, sat_pos, sat_clock)
    tropo = corrections.tropo_slant_delay_m(el, llh[:, 0:1], llh[:, 2:3],
                                            jnp.asarray(doy)[:, None])
    f1 = jnp.full(sat_pos.shape[1], 1575.42e6)
    iono = series.klobuchar_slots(nav, rx, sat_pos, t_rx, f1)
    return np.asarray(el), np.asarray(tropo), np.asarray(iono)


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__).parse_args(argv)
    cfg = config.load(STUDY)
    factory = factory_for(cfg.scenario_dict, STUDY.parent)
    prep = factory._prepared(False)
    _, products = factory._recorded
    obs = factory.station_obs(False)
    sat_pos, sat_clock = obs.sat.pos_ecef, obs.sat.clock_m
    avail = np.asarray(obs.available)
    t_rx = jnp.asarray(prep.time_gps_s)
    doy = np.asarray(prep.day_of_year)
    station = factory.station_ecef
    llh0 = geodesy.ecef_to_llh(jnp.asarray(station))
    C = np.asarray(geodesy.C_l_e(llh0[0], llh0[1]))  # ENU -> ECEF columns
    el0, trop0, iono0 = _slant(station, sat_pos, sat_clock, t_rx, products.nav, doy)
    rows = []
    for d_km in DISTANCES_KM:
        for name, enu in (("north", (0.0, 1.0, 0.0)), ("east", (1.0, 0.0, 0.0))):
            pos = station + C @ (1e3 * d_km * np.asarray(enu))
            _, trop, iono = _slant(pos, sat_pos, sat_clock, t_rx, products.nav, doy)
            use = avail & (el0 > math.radians(MASK_DEG))
            low = use & (el0 < math.radians(20.0))
            out = [d_km, name]
            for dx in (trop - trop0, iono - iono0):
                dx = np.where(use, dx, np.nan)
                dc = dx - np.nanmean(dx, axis=1, keepdims=True)
                out += [np.sqrt(np.nanmean(dx**2)), np.nanmax(np.abs(dx[low])),
                        np.sqrt(np.nanmean(dc**2))]
            rows.append(out)
    head = ("| distance | direction | dT RMS | dT max (10-20 deg) | dT RMS, clock part removed | "
            "dI L1 RMS | dI max (10-20 deg) | dI RMS, clock part removed |")
    lines = [
        "# The replay's distance limit (`python experiments/replay_limits.py`)",
        "",
        f"ESBC00DNK, {cfg.scenario_dict['start']} GPST + {cfg.scenario_dict['duration_s']} s, "
        f"{len(factory.sv)} GPS satellites above {MASK_DEG:g} deg. Model slant delay at a point "
        "d km from the station (same height) minus at the station, in millimetres.",
        "",
        head,
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r[0]:g} km | {r[1]} | " + " | ".join(f"{1e3 * v:.1f}" for v in r[2:])
                     + " |")
    text = "\n".join(lines) + "\n"
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "report.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
