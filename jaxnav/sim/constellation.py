"""Satellite geometry: nominal constellations or real broadcast ephemerides, and fixed slots.

Two orbit sources share one evaluation API, :func:`satellite_state`, which returns ECEF position
and velocity (in the ECEF frame of the evaluation instant, like SP3 or a broadcast evaluation at
the transmission time) and the satellite clock polynomial at arbitrary times, vectorised over
satellites:

- :class:`NominalOrbits`: circular two-body orbits from the nominal constellation designs (no
  files needed): GPS 24-slot plan (SPS Performance Standard table 3.1-1), GLONASS 24 satellites
  in 3 planes with the FDMA channel plan (antipodal satellites share a channel), Galileo Walker
  24/3/1. Adequate for geometry, visibility and DOP studies; not an orbit-determination model.
- :class:`BroadcastEphemeris`: records from a RINEX 3 navigation file (:func:`read_rinex_nav`,
  via georinex). GPS and Galileo use the IS-GPS-200 Keplerian algorithm (table 20-IV) with the
  record nearest in toe; GLONASS integrates the broadcast state vector (GLONASS ICD A.3.1.2,
  PZ-90 J2 model + broadcast luni-solar acceleration) with fixed-step RK4 from the nearest tb.

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

import gzip
import io
import math
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.geodesy import OMEGA_E
from jaxnav.gnss import corrections, signals
from jaxnav.gnss.signals import SYS_GAL, SYS_GLO, SYS_GPS

# ------------------------------------------------------------------------------------------------
# Time
# ------------------------------------------------------------------------------------------------

GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")
SECONDS_PER_WEEK = 604800.0
GPS_UTC_LEAP_SECONDS_2017 = 18  # GPS - UTC since 2017-01-01 (IERS Bulletin C)


def gps_seconds(when) -> float:
    """GPS seconds since 1980-01-06 00:00:00 of a datetime64 / ISO string given in GPS time."""
    dt = np.datetime64(when, "ns") - GPS_EPOCH
    return float(dt.astype("timedelta64[ns]").astype(np.int64)) * 1e-9


DEFAULT_T0_GPS_S = gps_seconds("2020-06-25T00:00:00")  # day of the shared ESBC data set


def gps_seconds_of_week(t_gps_s):
    """Seconds of the GPS week, t mod 604800."""
    return jnp.mod(t_gps_s, SECONDS_PER_WEEK)


def day_of_year(t_gps_s) -> float:
    """Fractional day of year (1.0 = Jan 1 00:00) of a GPS time (host side; no leap seconds)."""
    when = GPS_EPOCH + np.timedelta64(int(round(float(t_gps_s) * 1e9)), "ns")
    year_start = when.astype("datetime64[Y]").astype("datetime64[ns]")
    return 1.0 + float((when - year_start).astype(np.int64)) * 1e-9 / 86400.0


# ------------------------------------------------------------------------------------------------
# Orbit-source containers
# ------------------------------------------------------------------------------------------------

GM_GPS = 3.986005e14  # IS-GPS-200 WGS-84 value used in the broadcast algorithm [m^3/s^2]
GM_GAL = 3.986004418e14  # Galileo OS SIS ICD 5.1.1
GM_GLO = 3.9860044e14  # GLONASS ICD (PZ-90)
AE_GLO = 6378136.0  # PZ-90 semi-major axis [m]
J2_GLO = 1.0826257e-3  # PZ-90 second zonal harmonic
OMEGA_E_GLO = 7.292115e-5  # PZ-90 Earth rotation rate [rad/s]


class SatState(NamedTuple):
    """Satellite state per satellite at the evaluation times (leading axis = satellites)."""

    pos_ecef: jnp.ndarray  # [n, 3] m, ECEF frame of the evaluation instant
    vel_ecef: jnp.ndarray  # [n, 3] m/s, in that rotating frame
    clock_s: jnp.ndarray  # [n] clock polynomial dt^s (no periodic relativity, see module doc)
    clock_rate_s_s: jnp.ndarray  # [n]
    ok: jnp.ndarray  # [n] bool: a usable (healthy, recent) record was found


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


class KeplerRecords(NamedTuple):
    """IS-GPS-200 / Galileo ephemeris records, arrays [n_sat, n_rec] (angles rad, times s)."""

    valid: jnp.ndarray
    toe_s: jnp.ndarray  # seconds on the source time axis
    toc_s: jnp.ndarray
    sqrt_a: jnp.ndarray
    ecc: jnp.ndarray
    i0: jnp.ndarray
    idot: jnp.ndarray
    omega0: jnp.ndarray
    omega_dot: jnp.ndarray
    omega: jnp.ndarray
    m0: jnp.ndarray
    delta_n: jnp.ndarray
    cuc: jnp.ndarray
    cus: jnp.ndarray
    crc: jnp.ndarray
    crs: jnp.ndarray
    cic: jnp.ndarray
    cis: jnp.ndarray
    af0: jnp.ndarray
    af1: jnp.ndarray
    af2: jnp.ndarray
    tgd_s: jnp.ndarray  # GPS TGD / Galileo BGD(E1,E5a) (single-frequency users)
    toe_week_s: jnp.ndarray  # toe as GPS seconds of week (for the Omega_e toe term)
    gm: jnp.ndarray


class GlonassRecords(NamedTuple):
    """GLONASS broadcast state vectors, arrays [n_sat, n_rec] (+ [3] for vectors), PZ-90 ECEF."""

    valid: jnp.ndarray
    tb_s: jnp.ndarray  # seconds on the source time axis (GPS time scale)
    pos: jnp.ndarray  # [n, r, 3] m
    vel: jnp.ndarray  # [n, r, 3] m/s
    acc: jnp.ndarray  # [n, r, 3] m/s^2 luni-solar acceleration
    clock_bias_s: jnp.ndarray  # -tau_n
    rel_freq_bias: jnp.ndarray  # +gamma_n


class BroadcastEphemeris(NamedTuple):
    """Broadcast ephemerides of GPS, GLONASS and Galileo satellites (per-satellite arrays [n])."""

    system: jnp.ndarray  # int32
    prn: jnp.ndarray  # int32
    glo_channel: jnp.ndarray  # int32
    kepler: KeplerRecords
    glonass: GlonassRecords
    t_ref_gps_s: jnp.ndarray  # scalar
    iono_alpha: jnp.ndarray  # [4] Klobuchar (file header, or defaults)
    iono_beta: jnp.ndarray  # [4]
    max_age_kepler_s: float = 7200.0  # half the 4 h GPS fit interval (IS-GPS-200 20.3.4.4)
    max_age_glonass_s: float = 1800.0  # chosen: records every 30 min, integrate <= 30 min


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
GPS_A_M = 26559.7e3  # SPS PS nominal semi-major axis
GPS_INC_DEG = 55.0
GLO_A_M = 25510.0e3  # GLONASS ICD nominal (19 100 km altitude)
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


# ------------------------------------------------------------------------------------------------
# Broadcast evaluation
# ------------------------------------------------------------------------------------------------


def _select(valid, t_rec, t, max_age):
    """Index of the valid record nearest in time per satellite, and whether it is recent enough."""
    age = jnp.where(valid, jnp.abs(t[:, None] - t_rec), jnp.inf)
    idx = jnp.argmin(age, axis=1)
    ok = jnp.take_along_axis(age, idx[:, None], axis=1)[:, 0] <= max_age
    return idx, ok


def _gather(rec, idx):
    """Pick record ``idx[i]`` of satellite i from every [n, r, ...] field."""

    def pick(x):
        ix = idx.reshape(idx.shape + (1,) * (x.ndim - 1))
        return jnp.take_along_axis(x, ix, axis=1)[:, 0]

    return jax.tree.map(pick, rec)


# Record selection: the record with the nearest toe is used within +-max_age_kepler_s. GPS
# broadcast fits are centred on toe (IS-GPS-200 20.3.4.4). Galileo ones are not: against the GRG
# precise orbit of 2020-06-25 (shared ESBC data) the error is < 1.3 m RMS from toe - 1 h to
# toe + 3 h and 6 m RMS at toe - 2 h, so its window is centred on toe + 1 h (chosen from that
# measurement; a real-time receiver only ever uses past toe's anyway).
GALILEO_FIT_CENTRE_S = 3600.0

_KEPLER_ITERATIONS = 10  # Newton on E - e sin E = M: e < 0.03 converges to 1e-15 in < 5


def _kepler_position(k: KeplerRecords, t):
    """IS-GPS-200 table 20-IV: ECEF position and eccentric anomaly of the selected records.

    tk = t - toe; n = sqrt(GM/A^3) + dn; M = M0 + n tk; E - e sin E = M;
    nu = atan2(sqrt(1-e^2) sin E, cos E - e); Phi = nu + w; u = Phi + Cus s2 + Cuc c2;
    r = A(1 - e cos E) + Crs s2 + Crc c2; i = i0 + IDOT tk + Cis s2 + Cic c2;
    Omega = Omega0 + (Omegadot - we) tk - we toe (toe in seconds of week).
    """
    a = k.sqrt_a**2
    tk = t - k.toe_s
    n = jnp.sqrt(k.gm / a**3) + k.delta_n
    m = k.m0 + n * tk
    e_anom = m
    for _ in range(_KEPLER_ITERATIONS):
        e_anom = e_anom - (e_anom - k.ecc * jnp.sin(e_anom) - m) / (1.0 - k.ecc * jnp.cos(e_anom))
    nu = jnp.arctan2(jnp.sqrt(1.0 - k.ecc**2) * jnp.sin(e_anom), jnp.cos(e_anom) - k.ecc)
    phi = nu + k.omega
    s2, c2 = jnp.sin(2.0 * phi), jnp.cos(2.0 * phi)
    u = phi + k.cus * s2 + k.cuc * c2
    r = a * (1.0 - k.ecc * jnp.cos(e_anom)) + k.crs * s2 + k.crc * c2
    inc = k.i0 + k.idot * tk + k.cis * s2 + k.cic * c2
    node = k.omega0 + (k.omega_dot - OMEGA_E) * tk - OMEGA_E * k.toe_week_s
    xp, yp = r * jnp.cos(u), r * jnp.sin(u)
    cn, sn, ci = jnp.cos(node), jnp.sin(node), jnp.cos(inc)
    pos = jnp.stack([xp * cn - yp * ci * sn, xp * sn + yp * ci * cn, yp * jnp.sin(inc)], axis=-1)
    return pos, e_anom


def _kepler_clock(k: KeplerRecords, t):
    dt = t - k.toc_s
    return k.af0 + k.af1 * dt + k.af2 * dt * dt


def _glonass_accel(pos, vel, acc_ls):
    """GLONASS ICD A.3.1.2 equations of motion in the rotating PZ-90 frame (J2 + luni-solar)."""
    x, y, z = pos[..., 0], pos[..., 1], pos[..., 2]
    vx, vy = vel[..., 0], vel[..., 1]
    r2 = x * x + y * y + z * z
    r = jnp.sqrt(r2)
    mu_r3 = GM_GLO / (r2 * r)
    j2 = 1.5 * J2_GLO * GM_GLO * AE_GLO**2 / (r2 * r2 * r)
    z2r2 = 5.0 * z * z / r2
    w2 = OMEGA_E_GLO**2
    ax = -mu_r3 * x - j2 * x * (1.0 - z2r2) + w2 * x + 2.0 * OMEGA_E_GLO * vy
    ay = -mu_r3 * y - j2 * y * (1.0 - z2r2) + w2 * y - 2.0 * OMEGA_E_GLO * vx
    az = -mu_r3 * z - j2 * z * (3.0 - z2r2)
    return jnp.stack([ax, ay, az], axis=-1) + acc_ls


_GLONASS_RK4_STEPS = 20  # <= 90 s steps for |t - tb| <= 30 min (position error < 0.1 m)


def _glonass_position(g: GlonassRecords, t):
    """RK4 integration of the broadcast state from tb to t in a fixed number of steps."""
    h = ((t - g.tb_s) / _GLONASS_RK4_STEPS)[:, None]

    def f(state):
        p, v = state
        return v, _glonass_accel(p, v, g.acc)

    def step(state, _):
        k1 = f(state)
        k2 = f(jax.tree.map(lambda s, d: s + 0.5 * h * d, state, k1))
        k3 = f(jax.tree.map(lambda s, d: s + 0.5 * h * d, state, k2))
        k4 = f(jax.tree.map(lambda s, d: s + h * d, state, k3))
        new = jax.tree.map(
            lambda s, a, b, c, d: s + h / 6.0 * (a + 2.0 * b + 2.0 * c + d), state, k1, k2, k3, k4
        )
        return new, None

    (pos, _), _ = jax.lax.scan(step, (g.pos, g.vel), None, length=_GLONASS_RK4_STEPS)
    return pos


def _glonass_clock(g: GlonassRecords, t):
    return g.clock_bias_s + g.rel_freq_bias * (t - g.tb_s)


def _broadcast_pos_clock(eph: BroadcastEphemeris, t):
    """Position [n, 3], clock [n], ok [n] at times t [n] (seconds on the source axis)."""
    # Galileo fits are forward-looking: centre their window on toe + 1 h (GALILEO_FIT_CENTRE_S).
    centre = jnp.where(eph.system == SYS_GAL, GALILEO_FIT_CENTRE_S, 0.0)
    ik, ok_k = _select(eph.kepler.valid, eph.kepler.toe_s, t - centre, eph.max_age_kepler_s)
    ig, ok_g = _select(eph.glonass.valid, eph.glonass.tb_s, t, eph.max_age_glonass_s)
    k = _gather(eph.kepler, ik)
    g = _gather(eph.glonass, ig)
    is_glo = eph.system == SYS_GLO
    pos = jnp.where(is_glo[:, None], _glonass_position(g, t), _kepler_position(k, t)[0])
    clock = jnp.where(is_glo, _glonass_clock(g, t), _kepler_clock(k, t))
    return pos, clock, jnp.where(is_glo, ok_g, ok_k)


def satellite_position_clock(orbits, t):
    """(pos_ecef [n, 3], clock_s [n], ok [n]) at times t [n] without velocities (cheaper)."""
    if isinstance(orbits, NominalOrbits):
        return _nominal_position(orbits, t), _nominal_clock(orbits, t), jnp.ones(t.shape, bool)
    if isinstance(orbits, BroadcastEphemeris):
        return _broadcast_pos_clock(orbits, t)
    raise TypeError(f"unknown orbit source {type(orbits).__name__}")


def satellite_state(orbits, t_s) -> SatState:
    """Position, velocity and clock of every satellite of ``orbits`` at t_s (source time axis).

    ``t_s`` is a scalar or one time per satellite [n]. Velocity and clock rate are exact time
    derivatives of the evaluated models (forward-mode autodiff, jax.jvp). Works for
    :class:`NominalOrbits` and :class:`BroadcastEphemeris`; pure and jit/vmap-able.
    ``clock_s`` excludes the periodic relativistic term for every system; note that real
    GLONASS broadcast clocks (-tau_n + gamma_n dt) already contain it, so a real-data user of
    GLONASS broadcast clocks must not add it again (the simulator treats every source alike).
    """
    n = orbits.system.shape[0]
    t = jnp.broadcast_to(jnp.asarray(t_s, dtype=jnp.float64), (n,))

    def f(tt):
        pos, clock, ok = satellite_position_clock(orbits, tt)
        return (pos, clock), ok

    (pos, clock), (vel, rate), ok = jax.jvp(f, (t,), (jnp.ones_like(t),), has_aux=True)
    return SatState(pos, vel, clock, rate, ok)


def take_satellites(orbits, idx):
    """The sub-source of satellites ``idx`` (e.g. a SlotTable's sat_index), same type."""
    idx = jnp.asarray(idx)
    return jax.tree.map(lambda x: x if jnp.ndim(x) == 0 else x[idx], orbits)


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


# ------------------------------------------------------------------------------------------------
# RINEX navigation reader (georinex)
# ------------------------------------------------------------------------------------------------

_NAV_LINES = {"G": 7, "E": 7, "R": 3}  # continuation lines per record (RINEX 3)
_FIELD = 19
_BLANK_FIELD = " 0.000000000000E+00"


def _patch_nav_text(text: str) -> str:
    """Zero-fill blank 19-character fields inside G/E/R records (legal RINEX "spare" fields).

    georinex 1.16 parses every field with float() and drops the whole record (all NaN) when a
    field inside the record is blank -- e.g. the spare field after the Galileo week in records
    written by sbf2rin -- so every Galileo record of the shared ESBC file would be lost.
    """
    out = []
    lines = text.splitlines()
    in_header = True
    remaining = 0
    for line in lines:
        if in_header:
            out.append(line)
            if "END OF HEADER" in line:
                in_header = False
            continue
        if remaining > 0:
            body = line[4:80].ljust(4 * _FIELD)
            fields = [body[i * _FIELD : (i + 1) * _FIELD] for i in range(4)]
            if remaining == 1:  # last line: keep trailing blanks (they tell georinex the length)
                last = max((i for i, f in enumerate(fields) if f.strip()), default=-1)
                fields = [
                    f if (f.strip() or i > last) else _BLANK_FIELD for i, f in enumerate(fields)
                ]
                out.append((line[:4] + "".join(fields)).rstrip())
            else:
                fields = [f if f.strip() else _BLANK_FIELD for f in fields]
                out.append(line[:4] + "".join(fields))
            remaining -= 1
            continue
        remaining = _NAV_LINES.get(line[:1], 0) if line[:1].strip() else 0
        out.append(line)
    return "\n".join(out) + "\n"


def _read_text(path: Path) -> str:
    with open(path, "rb") as fh:
        magic = fh.read(2)
    if magic == b"\x1f\x8b":
        with gzip.open(path, "rt", encoding="ascii", errors="replace") as fh:
            return fh.read()
    return path.read_text(encoding="ascii", errors="replace")


def _leap_seconds(header, default):
    raw = header.get("LEAP SECONDS")
    if raw:
        try:
            return int(str(raw).split()[0])
        except (ValueError, IndexError):
            pass
    return default


def read_rinex_nav(
    path,
    systems="GRE",
    galileo_source="fnav",
    leap_seconds=None,
    t_ref_gps_s=None,
) -> BroadcastEphemeris:
    """Read a RINEX 3 navigation file (plain or gzipped) into a :class:`BroadcastEphemeris`.

    - ``systems``: RINEX letters to load (G, R, E).
    - ``galileo_source``: "fnav" keeps F/NAV records (clocks for E1/E5a, the PPP pair here),
      "inav" keeps I/NAV (E1/E5b); a satellite without the preferred kind keeps the other.
    - ``leap_seconds``: GPS - UTC for GLONASS epochs (UTC in RINEX 3); default from the header,
      else 18 s.
    - ``t_ref_gps_s``: the returned time axis origin; default 00:00 GPS of the first record's day.
    Only healthy records (health == 0) are marked valid.
    """
    import georinex

    path = Path(path)
    text = _patch_nav_text(_read_text(path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        header = georinex.rinexheader(io.StringIO(text))
        nav = georinex.load(io.StringIO(text), use=set(systems))
    leap = (
        _leap_seconds(header, GPS_UTC_LEAP_SECONDS_2017) if leap_seconds is None else leap_seconds
    )

    # Collect records per satellite (georinex splits same-epoch duplicates into "E01_1" columns).
    recs: dict[str, list[dict]] = {}
    times = nav["time"].values
    names = list(nav.data_vars)
    data = {k: nav[k].values for k in names}  # [time, sv]
    present = np.any([np.isfinite(v) for v in data.values()], axis=0)
    for j, sv in enumerate(nav["sv"].values):
        base = str(sv)[:3]
        for i in np.flatnonzero(present[:, j]):
            row = {k: data[k][i, j] for k in names}
            row["_toc"] = gps_seconds(times[i])
            recs.setdefault(base, []).append(row)
    if not recs:
        raise ValueError(f"{path}: no GPS/GLONASS/Galileo navigation records for systems {systems}")

    letter_to_sys = {"G": SYS_GPS, "R": SYS_GLO, "E": SYS_GAL}
    sats = sorted(recs, key=lambda s: (letter_to_sys[s[0]], int(s[1:])))
    if galileo_source not in ("fnav", "inav"):
        raise ValueError(f"galileo_source must be 'fnav' or 'inav', got {galileo_source!r}")
    want_bit = 2 if galileo_source == "fnav" else 1 | 4  # DataSrc bits (RINEX 3.05 table A8)
    for s in sats:
        if s[0] == "E":
            pref = [r for r in recs[s] if int(r.get("DataSrc", 0)) & want_bit]
            if pref:
                recs[s] = pref
        recs[s].sort(key=lambda r: r["_toc"])
    n_rec = max(len(recs[s]) for s in sats)
    n = len(sats)

    all_toc = [r["_toc"] for s in sats for r in recs[s]]
    if t_ref_gps_s is None:
        t_ref_gps_s = math.floor(min(all_toc) / 86400.0) * 86400.0

    def arr(fill=0.0):
        return np.full((n, n_rec), fill, dtype=np.float64)

    kf = {name: arr() for name in KeplerRecords._fields}
    kf["valid"] = np.zeros((n, n_rec), bool)
    kf["sqrt_a"][:] = math.sqrt(GPS_A_M)  # benign padding (finite orbit) for unused entries
    gf = {name: arr() for name in ("tb_s", "clock_bias_s", "rel_freq_bias")}
    g_valid = np.zeros((n, n_rec), bool)
    g_pos = np.zeros((n, n_rec, 3))
    g_pos[..., 0] = GLO_A_M  # benign padding
    g_vel = np.zeros((n, n_rec, 3))
    g_vel[..., 1] = math.sqrt(GM_GLO / GLO_A_M)
    g_acc = np.zeros((n, n_rec, 3))
    system = np.zeros(n, np.int32)
    prn = np.zeros(n, np.int32)
    channel = np.zeros(n, np.int32)

    for i, s in enumerate(sats):
        system[i] = letter_to_sys[s[0]]
        prn[i] = int(s[1:])
        for j, r in enumerate(recs[s]):
            healthy = float(r.get("health", 0.0)) == 0.0
            if s[0] == "R":
                tb = r["_toc"] + leap - t_ref_gps_s
                gf["tb_s"][i, j] = tb
                gf["clock_bias_s"][i, j] = r["SVclockBias"]
                gf["rel_freq_bias"][i, j] = r["SVrelFreqBias"]
                g_pos[i, j] = [r["X"], r["Y"], r["Z"]]
                g_vel[i, j] = [r["dX"], r["dY"], r["dZ"]]
                g_acc[i, j] = [r["dX2"], r["dY2"], r["dZ2"]]
                g_valid[i, j] = healthy and all(np.isfinite([r["X"], r["dX"], r["SVclockBias"]]))
                channel[i] = int(r["FreqNum"])
                continue
            week = r["GPSWeek"] if s[0] == "G" else r["GALWeek"]
            toe_abs = week * SECONDS_PER_WEEK + r["Toe"]
            # A toc/toe pair straddling a week rollover: move toe to the week nearest toc.
            toe_abs += SECONDS_PER_WEEK * round((r["_toc"] - toe_abs) / SECONDS_PER_WEEK)
            vals = {
                "toe_s": toe_abs - t_ref_gps_s,
                "toc_s": r["_toc"] - t_ref_gps_s,
                "sqrt_a": r["sqrtA"],
                "ecc": r["Eccentricity"],
                "i0": r["Io"],
                "idot": r["IDOT"],
                "omega0": r["Omega0"],
                "omega_dot": r["OmegaDot"],
                "omega": r["omega"],
                "m0": r["M0"],
                "delta_n": r["DeltaN"],
                "cuc": r["Cuc"],
                "cus": r["Cus"],
                "crc": r["Crc"],
                "crs": r["Crs"],
                "cic": r["Cic"],
                "cis": r["Cis"],
                "af0": r["SVclockBias"],
                "af1": r["SVclockDrift"],
                "af2": r["SVclockDriftRate"],
                "tgd_s": r["TGD"] if s[0] == "G" else r.get("BGDe5a", 0.0),
                "toe_week_s": r["Toe"],
                "gm": GM_GPS if s[0] == "G" else GM_GAL,
            }
            finite = all(np.isfinite(v) for v in vals.values())
            for key, v in vals.items():
                kf[key][i, j] = v if np.isfinite(v) else kf[key][i, j]
            kf["valid"][i, j] = healthy and finite

    alpha, beta = _klobuchar_from_header(nav.attrs)
    return BroadcastEphemeris(
        system=jnp.asarray(system),
        prn=jnp.asarray(prn),
        glo_channel=jnp.asarray(channel),
        kepler=KeplerRecords(**{k: jnp.asarray(v) for k, v in kf.items()}),
        glonass=GlonassRecords(
            valid=jnp.asarray(g_valid),
            tb_s=jnp.asarray(gf["tb_s"]),
            pos=jnp.asarray(g_pos),
            vel=jnp.asarray(g_vel),
            acc=jnp.asarray(g_acc),
            clock_bias_s=jnp.asarray(gf["clock_bias_s"]),
            rel_freq_bias=jnp.asarray(gf["rel_freq_bias"]),
        ),
        t_ref_gps_s=jnp.asarray(float(t_ref_gps_s)),
        iono_alpha=jnp.asarray(alpha),
        iono_beta=jnp.asarray(beta),
    )


def _klobuchar_from_header(attrs):
    """Klobuchar (alpha, beta) from georinex attributes, or the corrections module defaults."""
    coeffs = attrs.get("ionospheric_corr_GPS")
    if coeffs is not None and len(coeffs) == 8:
        c = np.asarray(coeffs, dtype=np.float64)
        return c[:4], c[4:]
    return (
        np.asarray(corrections.KLOBUCHAR_ALPHA_DEFAULT),
        np.asarray(corrections.KLOBUCHAR_BETA_DEFAULT),
    )
