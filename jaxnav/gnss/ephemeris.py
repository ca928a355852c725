"""Broadcast ephemerides: their records and the evaluation of the orbits and clocks.

:class:`BroadcastEphemeris` holds the records of a RINEX 3 navigation file (read by
``io.read_broadcast_ephemeris``). GPS and Galileo use the IS-GPS-200 Keplerian algorithm (table
20-IV) with the record nearest in toe; GLONASS integrates the broadcast state vector (GLONASS
ICD A.3.1.2, PZ-90 J2 model + broadcast luni-solar acceleration) with fixed-step RK4 from the
nearest tb. :func:`satellite_state` returns ECEF position and velocity (in the ECEF
frame of the evaluation instant, like SP3) and the clock polynomial at arbitrary times,
vectorised over satellites; ``sim/constellation.py`` adds nominal orbits behind the same API.

Time: ``t_ref_gps_s`` is the GPS second (``core/gpstime.py``) at which the source's own time axis
is zero; the evaluation takes seconds since that instant.

Clocks: ``clock_s`` is the satellite clock offset dt^s of the clock polynomial (referenced to the
P1/P2 (GPS, GLONASS) or E1/E5a (Galileo, F/NAV) ionosphere-free combination, like precise
products) *without* the periodic relativistic term, which the user adds with
corrections.relativistic_clock_s. Real GLONASS broadcast clocks (-tau_n + gamma_n dt) already
contain it, so a real-data user of GLONASS broadcast clocks must not add it again.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Real

from jaxnav.geodesy import OMEGA_E
from jaxnav.gnss.signals import SYS_GAL, SYS_GLO

GM_GPS = 3.986005e14  # IS-GPS-200 WGS-84 value used in the broadcast algorithm [m^3/s^2]
GM_GAL = 3.986004418e14  # Galileo OS SIS ICD 5.1.1
GM_GLO = 3.9860044e14  # GLONASS ICD (PZ-90)
AE_GLO = 6378136.0  # PZ-90 semi-major axis [m]
J2_GLO = 1.0826257e-3  # PZ-90 second zonal harmonic
OMEGA_E_GLO = 7.292115e-5  # PZ-90 Earth rotation rate [rad/s]
GPS_A_M = 26559.7e3  # SPS PS nominal semi-major axis
GLO_A_M = 25510.0e3  # GLONASS ICD nominal (19 100 km altitude)


class SatState(NamedTuple):
    """Satellite state per satellite at the evaluation times (leading axis = satellites)."""

    pos_ecef: Float[Array, "n 3"]  # m, ECEF frame of the evaluation instant
    vel_ecef: Float[Array, "n 3"]  # m/s, in that rotating frame
    clock_s: Float[Array, " n"]  # clock polynomial dt^s (no periodic relativity, see module doc)
    clock_rate_s_s: Float[Array, " n"]
    ok: Bool[Array, " n"]  # a usable (healthy, recent) record was found


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


def broadcast_position_clock(
    eph: BroadcastEphemeris, t: Float[Array, " n"]
) -> tuple[Float[Array, "n 3"], Float[Array, " n"], Bool[Array, " n"]]:
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


def state_from_position_clock(
    position_clock, n: int, t_s: Real[ArrayLike, ""] | Real[ArrayLike, " n"]
) -> SatState:
    """SatState of ``n`` satellites at t_s from ``position_clock(t [n]) -> (pos, clock, ok)``:
    velocity and clock rate are its exact time derivatives (forward-mode autodiff, jax.jvp)."""
    t = jnp.broadcast_to(jnp.asarray(t_s, dtype=jnp.float64), (n,))

    def f(tt):
        pos, clock, ok = position_clock(tt)
        return (pos, clock), ok

    (pos, clock), (vel, rate), ok = jax.jvp(f, (t,), (jnp.ones_like(t),), has_aux=True)
    return SatState(pos, vel, clock, rate, ok)


def satellite_state(
    eph: BroadcastEphemeris, t_s: Real[ArrayLike, ""] | Real[ArrayLike, " n"]
) -> SatState:
    """Position, velocity and clock of every satellite of ``eph`` at t_s (source time axis);
    ``t_s`` a scalar or one time per satellite [n]. Pure and jit/vmap-able. ``clock_s`` excludes
    the periodic relativistic term (module docstring)."""
    return state_from_position_clock(
        lambda tt: broadcast_position_clock(eph, tt), eph.system.shape[0], t_s
    )


def take_satellites(orbits, idx):
    """The sub-source of satellites ``idx`` (e.g. a SlotTable's sat_index), same type."""
    idx = jnp.asarray(idx)
    return jax.tree.map(lambda x: x if jnp.ndim(x) == 0 else x[idx], orbits)
