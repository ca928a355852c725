"""Real GNSS errors on a simulated trajectory: a static receiver's observations moved.

A static receiver at the known (tide-free marker) coordinate r_sta records, per slot,
z = rho(r_sta) + c dt_r - c dt^s + T + I + biases + multipath + noise (+ N for the phase).
Everything but the geometric range belongs to the real signal and stays; moving the receiver
to the simulated antenna r_a(t) changes only the range:

    z_replay(t) = z(t) + rho(r_a(t)) - rho(r_sta)                      (code and phase, both bands)
    rho_dot_replay(t) = rho_dot(t) + rho_dot(r_a, v_a) - rho_dot(r_sta, 0)        (f1 Doppler)

with rho and rho_dot those of the filter's own observation model (``models.geometry``: Earth
rotation during the signal travel, the satellite state at transmission as the products give it).
So the filter meets the station's receiver clock, troposphere, ionosphere, product errors,
multipath, noise, data gaps and slips along a trajectory whose truth is exact.

What the move leaves as it was (their sizes are in docs/validation.md): the slant troposphere
and ionosphere at the station instead of the antenna (the pierce points and mapping shift with
the distance from the station), the satellite position at the station's transmission time (a
range change d rho shifts it by v_s d rho / c, 4 mm per km), the receiver's antenna wind-up
(a vehicle turning by psi adds psi / 2 pi cycles to every phase; the simulator does not model it
either), and the site's multipath: a choke ring on a mast, not a car roof.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxnav import geodesy
from jaxnav.gnss import models
from jaxnav.gnss.ppp_data import GnssObs


def _range_and_rate(rx_pos, rx_vel, sat: models.SatEpoch):
    geo = models.geometry(rx_pos, rx_vel, sat)
    return geo.range_m, geo.range_rate_m_s, geo.los_ecef


def geometry_change(
    sat: models.SatEpoch,
    station_ecef: Float[Array, "3"],
    ant_pos_ecef: Float[Array, "T 3"],
    ant_vel_ecef: Float[Array, "T 3"],
) -> tuple[Float[Array, "T S"], Float[Array, "T S"]]:
    """rho(r_a) - rho(r_sta) and rho_dot(r_a, v_a) - rho_dot(r_sta, 0) per epoch and slot [m, m/s].

    ``sat`` holds [T, S] leaves (the products at the station's transmission times).
    """
    zero = jnp.zeros(3)

    def one(p, v, s):
        rho_a, rate_a, _ = _range_and_rate(p, v, s)
        rho_s, rate_s, _ = _range_and_rate(station_ecef, zero, s)
        return rho_a - rho_s, rate_a - rate_s

    return jax.vmap(one)(ant_pos_ecef, ant_vel_ecef, sat)


@jax.jit
def move_observations(
    obs: GnssObs,
    station_ecef: Float[Array, "3"],
    ant_pos_ecef: Float[Array, "T 3"],
    ant_vel_ecef: Float[Array, "T 3"],
) -> GnssObs:
    """The station's observations [T, S] as the antenna at ``ant_pos_ecef`` would have made them.

    Code and phase of both bands get d rho, the f1 range rate d rho_dot (module docstring);
    unavailable slots keep their values (they are masked anyway).
    """
    d_rho, d_rate = geometry_change(obs.sat, station_ecef, ant_pos_ecef, ant_vel_ecef)
    return obs._replace(
        code_m=obs.code_m + d_rho[..., None],
        phase_m=obs.phase_m + d_rho[..., None],
        range_rate_m_s=obs.range_rate_m_s + d_rate,
    )


@jax.jit
def sky(
    sat: models.SatEpoch, ant_pos_ecef: Float[Array, "T 3"]
) -> tuple[Float[Array, "T S"], Float[Array, "T S"]]:
    """Elevation and azimuth [rad] of every slot seen from the antenna, per epoch."""

    def one(p, s):
        _, _, los = _range_and_rate(p, jnp.zeros(3), s)
        llh = geodesy.ecef_to_llh(p)
        return models.elevation_azimuth(los, geodesy.C_l_e(llh[0], llh[1]).T)

    return jax.vmap(one)(ant_pos_ecef, sat)
