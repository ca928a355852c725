"""Satellite geometry: nominal constellations or real broadcast ephemerides, and fixed slots.

Two orbit sources share one evaluation API, :func:`satellite_state`, which returns ECEF position
and velocity (in the ECEF frame of the evaluation instant, like SP3 or a broadcast evaluation at
the transmission time) and the satellite clock polynomial at arbitrary times, vectorised over
satellites:

- :class:`NominalOrbits`: circular two-body orbits from the nominal constellation designs (no
  files needed): GPS 24-slot plan (SPS Performance Standard table 3.1-1), GLONASS 24 satellites
  in 3 planes with the FDMA channel plan (antipodal satellites share a channel), Galileo Walker
  24/3/1. Adequate for geometry, visibility and DOP studies; not an orbit-determination model.
- :class:`BroadcastEphemeris`: records from a RINEX 3 navigation file
  (``io.read_broadcast_ephemeris``); the IS-GPS-200 / GLONASS ICD evaluation lives in
  ``gnss/ephemeris.py`` (real data needs it without the simulator) and is re-exported here.

Time: every source has ``t_ref_gps_s`` (GPS seconds since 1980-01-06 00:00:00 GPS at which its
own time axis is zero); :func:`satellite_state` takes seconds since that instant. Scenarios use
seconds since their own start ``t0_gps_s`` and convert with :func:`orbit_time`.

Clocks: ``clock_s`` is the satellite clock offset dt^s of the clock polynomial (referenced to the
P1/P2 (GPS, GLONASS) or E1/E5a (Galileo, F/NAV) ionosphere-free combination, like precise
products) *without* the periodic relativistic term, which the user adds with
corrections.relativistic_clock_s (GLONASS broadcast clocks already contain it; see
:func:`satellite_state`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.gpstime import gps_seconds
from jaxnav.geodesy import OMEGA_E
from jaxnav.gnss import corrections, ephemeris, signals
from jaxnav.gnss.ephemeris import (  # noqa: F401  (re-exported: one API for both orbit sources)
    GLO_A_M,
    GM_GAL,
    GM_GLO,
    GM_GPS,
    GPS_A_M,
    BroadcastEphemeris,
    SatState,
    take_satellites,
)
from jaxnav.gnss.signals import SYS_GAL, SYS_GLO, SYS_GPS

DEFAULT_T0_GPS_S = gps_seconds("2020-06-25T00:00:00")  # day of the shared ESBC data set

# ------------------------------------------------------------------------------------------------
# Nominal orbits
# ------------------------------------------------------------------------------------------------


class NominalOrbits(NamedTuple):
    """Circular two-body orbits; angles at t = 0 of the source's time axis (arrays [n])."""

    system: jnp.ndarray  # int32
    prn: jnp.ndarray  # int32
    glo_channel: jnp.ndarray  # int32
    a_m: jnp.ndarray
    inc_rad: jnp.ndarray
    lan0_rad: jnp.ndarray  # Earth-fixed longitude of the ascending node at t = 0
    arglat0_rad: jnp.ndarray  # argument of latitude at t = 0
    gm: jnp.ndarray
    clock_af0_s: jnp.ndarray
    clock_af1_s_s: jnp.ndarray
    t_ref_gps_s: jnp.ndarray  # scalar


# ------------------------------------------------------------------------------------------------
# Nominal constellations
# ------------------------------------------------------------------------------------------------

# GPS SPS Performance Standard (2008/2020) table 3.1-1: baseline 24-slot constellation, RAAN and
# argument of latitude [deg] at 1 July 1993 00:00 UTC (Greenwich hour angle 18h36m14.4s).
_GPS_SLOTS_DEG = (
    (272.847, 268.126), (272.847, 161.786), (272.847, 11.676), (272.847, 41.806),  # A1-A4
    (332.847, 80.956), (332.847, 173.336), (332.847, 309.976), (332.847, 204.376),  # B1-B4
    (32.847, 111.876), (32.847, 11.796), (32.847, 339.666), (32.847, 241.556),  # C1-C4
    (92.847, 135.226), (92.847, 265.446), (92.847, 35.156), (92.847, 167.356),  # D1-D4
    (152.847, 197.046), (152.847, 302.596), (152.847, 66.066), (152.847, 333.686),  # E1-E4
    (212.847, 238.886), (212.847, 345.226), (212.847, 105.206), (212.847, 135.346),  # F1-F4
)  # fmt: skip
_GPS_GHA_DEG = (18.0 + 36.0 / 60.0 + 14.4 / 3600.0) * 15.0
GPS_INC_DEG = 55.0
GLO_INC_DEG = 64.8
GAL_A_M = 29600.0e3  # Galileo nominal (29 599.8 km)
GAL_INC_DEG = 56.0

# GLONASS FDMA channel per slot 1..24 (the operational plan, as broadcast in the 2020-06-25 ESBC
# navigation file): slots j and j + 4 of a plane are antipodal and share a channel.
GLONASS_CHANNELS = (
    1, -4, 5, 6, 1, -4, 5, 6,
    -2, -7, 0, -1, -2, -7, 0, -1,
    4, -3, 3, 2, 4, -3, 3, 2,
)  # fmt: skip

# Nominal satellite clocks (chosen): |af0| <= 0.3 ms and |af1| <= 5e-12 like real broadcast
# values, from a fixed seed so the constellation is reproducible.
_CLOCK_AF0_MAX_S = 3e-4
_CLOCK_AF1_MAX = 5e-12


def _nominal(system, prn, channel, a_m, inc_deg, lan_deg, arglat_deg, gm, t_ref_gps_s, seed):
    rng = np.random.default_rng(seed)
    n = len(prn)
    return NominalOrbits(
        system=jnp.full(n, system, dtype=jnp.int32),
        prn=jnp.asarray(prn, dtype=jnp.int32),
        glo_channel=jnp.asarray(channel, dtype=jnp.int32),
        a_m=jnp.full(n, a_m),
        inc_rad=jnp.full(n, math.radians(inc_deg)),
        lan0_rad=jnp.asarray(np.radians(lan_deg)),
        arglat0_rad=jnp.asarray(np.radians(arglat_deg)),
        gm=jnp.full(n, gm),
        clock_af0_s=jnp.asarray(rng.uniform(-_CLOCK_AF0_MAX_S, _CLOCK_AF0_MAX_S, n)),
        clock_af1_s_s=jnp.asarray(rng.uniform(-_CLOCK_AF1_MAX, _CLOCK_AF1_MAX, n)),
        t_ref_gps_s=jnp.asarray(float(t_ref_gps_s)),
    )


def nominal_gps(t_ref_gps_s=DEFAULT_T0_GPS_S, seed=1) -> NominalOrbits:
    """GPS 24-slot nominal constellation (SPS PS table 3.1-1), PRN 1..24 = slots A1..F4.

    Earth-fixed node longitude = RAAN - GHA(epoch); the table geometry holds at t_ref_gps_s.
    """
    raan, arglat = np.array(_GPS_SLOTS_DEG).T
    prn = np.arange(1, 25)
    return _nominal(
        SYS_GPS, prn, np.zeros(24, int), GPS_A_M, GPS_INC_DEG, raan - _GPS_GHA_DEG, arglat,
        GM_GPS, t_ref_gps_s, seed,
    )  # fmt: skip


def _walker_24_3_1(lan_offset_deg):
    """Walker 24/3/1: planes 120 deg apart, 8 satellites 45 deg apart, 15 deg inter-plane phase."""
    plane = np.repeat(np.arange(3), 8)
    j = np.tile(np.arange(8), 3)
    return lan_offset_deg + 120.0 * plane, 45.0 * j + 15.0 * plane


def nominal_glonass(t_ref_gps_s=DEFAULT_T0_GPS_S, seed=2) -> NominalOrbits:
    """GLONASS 24 satellites, 3 planes (slots 1-8, 9-16, 17-24), i = 64.8 deg, a = 25 510 km."""
    lan, arglat = _walker_24_3_1(lan_offset_deg=10.0)  # node offset chosen
    return _nominal(
        SYS_GLO, np.arange(1, 25), np.array(GLONASS_CHANNELS), GLO_A_M, GLO_INC_DEG, lan, arglat,
        GM_GLO, t_ref_gps_s, seed,
    )  # fmt: skip


def nominal_galileo(t_ref_gps_s=DEFAULT_T0_GPS_S, seed=3) -> NominalOrbits:
    """Galileo Walker 24/3/1 (56 deg, a = 29 600 km), PRN 1..24 (planes: 1-8, 9-16, 17-24)."""
    lan, arglat = _walker_24_3_1(lan_offset_deg=50.0)  # node offset chosen
    return _nominal(
        SYS_GAL, np.arange(1, 25), np.zeros(24, int), GAL_A_M, GAL_INC_DEG, lan, arglat,
        GM_GAL, t_ref_gps_s, seed,
    )  # fmt: skip


def concat_orbits(*sources):
    """Concatenate orbit sources of the same type along the satellite axis (same t_ref)."""
    return jax.tree.map(
        lambda *xs: xs[0] if jnp.ndim(xs[0]) == 0 else jnp.concatenate(xs, axis=0), *sources
    )


def nominal_constellation(
    systems=(SYS_GPS, SYS_GLO, SYS_GAL), t_ref_gps_s=DEFAULT_T0_GPS_S
) -> NominalOrbits:
    """The nominal constellations of ``systems`` in one source (GPS, GLONASS, Galileo order)."""
    makers = {SYS_GPS: nominal_gps, SYS_GLO: nominal_glonass, SYS_GAL: nominal_galileo}
    return concat_orbits(*(makers[s](t_ref_gps_s) for s in sorted(systems)))


def _nominal_position(orb: NominalOrbits, t):
    """Circular orbit: r = a [cu cO - su ci sO, cu sO + su ci cO, su si], u = u0 + n t,
    O = O0 - we t (Earth-fixed node), n = sqrt(GM / a^3)."""
    n = jnp.sqrt(orb.gm / orb.a_m**3)
    u = orb.arglat0_rad + n * t
    node = orb.lan0_rad - OMEGA_E * t
    cu, su = jnp.cos(u), jnp.sin(u)
    cn, sn = jnp.cos(node), jnp.sin(node)
    ci, si = jnp.cos(orb.inc_rad), jnp.sin(orb.inc_rad)
    return orb.a_m[:, None] * jnp.stack(
        [cu * cn - su * ci * sn, cu * sn + su * ci * cn, su * si], axis=-1
    )


def _nominal_clock(orb: NominalOrbits, t):
    return orb.clock_af0_s + orb.clock_af1_s_s * t


def satellite_position_clock(orbits, t):
    """(pos_ecef [n, 3], clock_s [n], ok [n]) at times t [n] without velocities (cheaper)."""
    if isinstance(orbits, NominalOrbits):
        return _nominal_position(orbits, t), _nominal_clock(orbits, t), jnp.ones(t.shape, bool)
    if isinstance(orbits, BroadcastEphemeris):
        return ephemeris.broadcast_position_clock(orbits, t)
    raise TypeError(f"unknown orbit source {type(orbits).__name__}")


def satellite_state(orbits, t_s) -> SatState:
    """Position, velocity and clock of every satellite of ``orbits`` at t_s (source time axis):
    :func:`gnss.ephemeris.satellite_state` for either source (nominal or broadcast)."""
    return ephemeris.state_from_position_clock(
        lambda tt: satellite_position_clock(orbits, tt), orbits.system.shape[0], t_s
    )


def orbit_time(orbits, t0_gps_s, t_s):
    """Seconds on the source's time axis for scenario time t_s (scenario starts at t0_gps_s)."""
    return t_s + (t0_gps_s - orbits.t_ref_gps_s)


# ------------------------------------------------------------------------------------------------
# Visibility and slots
# ------------------------------------------------------------------------------------------------

DEFAULT_ELEVATION_MASK_RAD = math.radians(10.0)  # chosen (S000 QC used 10 deg, S002 ch.5 7 deg)


def elevations(orbits, t_s, pos_rcv_ecef, t0_gps_s=DEFAULT_T0_GPS_S):
    """Elevation and azimuth [n_t, n_sat] of every satellite from receiver positions [n_t, 3].

    Geometry at the reception time (the light-time shift changes elevations by < 1e-5 rad).
    """
    t_orbit = jnp.asarray(t_s, dtype=jnp.float64) + (float(t0_gps_s) - float(orbits.t_ref_gps_s))
    return _elevations(orbits, t_orbit, jnp.asarray(pos_rcv_ecef, dtype=jnp.float64))


@jax.jit
def _elevations(orbits, t_orbit, pos_rcv_ecef):
    def one(t, r):
        pos, _, ok = satellite_position_clock(orbits, jnp.broadcast_to(t, orbits.system.shape))
        el, az = corrections.elevation_azimuth(r, pos)
        return jnp.where(ok, el, -jnp.pi / 2), az

    return jax.vmap(one)(t_orbit, pos_rcv_ecef)


def visible(elevation_rad, mask_rad=DEFAULT_ELEVATION_MASK_RAD):
    """Elevation-mask test E >= mask."""
    return elevation_rad >= mask_rad


def build_slots(
    orbits,
    t_s,
    pos_rcv_ecef,
    t0_gps_s=DEFAULT_T0_GPS_S,
    mask_rad=DEFAULT_ELEVATION_MASK_RAD,
    slots_per_system=signals.DEFAULT_SLOTS_PER_SYSTEM,
):
    """Fixed slot table of a scenario: satellites above the mask at any epoch, in PRN order.

    ``t_s`` [n_t] scenario seconds and ``pos_rcv_ecef`` [n_t, 3] the antenna trajectory (pass all
    epochs, or a dense enough subsample). Host-side set-up; see signals.assign_slots.
    """
    el, _ = elevations(orbits, t_s, pos_rcv_ecef, t0_gps_s)
    ever = np.asarray(jnp.any(visible(el, mask_rad), axis=0))
    return signals.assign_slots(
        np.asarray(orbits.system),
        np.asarray(orbits.prn),
        np.asarray(orbits.glo_channel),
        ever,
        slots_per_system,
    )


