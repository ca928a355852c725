"""Models evaluated along a receiver track, per epoch and slot ([T, S], jitted and vmapped).

Geometry (line of sight, elevation, azimuth, receiver llh), the model ionosphere (broadcast
Klobuchar, IS-GPS-200 20.3.3.5.2.5, or an IONEX thin-shell map), phase wind-up (S002 eqs
2.14-2.19, continuous over the series), the solid Earth tide (IERS 2010) and the local ENU axes,
at approximate receiver positions [T, 3] (``io/prepare.py`` uses the single-point solution).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxnav import geodesy
from jaxnav.core import gpstime
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import corrections, models, signals, tides, windup
from jaxnav.gnss.interp import ionex_table, ionex_vtec


def klobuchar_slots(nav, rx_pos, sat_pos, t_rx, f1):
    """Klobuchar L1 slant delay [m] scaled to each slot's f1: (f_L1 / f1)^2 c T_iono."""
    d = _klobuchar_batch(
        jnp.asarray(rx_pos), sat_pos, jnp.asarray(t_rx), nav.iono_alpha, nav.iono_beta
    )
    return d * jnp.asarray((signals.GPS_L1_HZ / f1) ** 2)[None, :]


@jax.jit
def _klobuchar_batch(rx_pos, sat_pos, t_rx, alpha, beta):
    def one(rx, sp, t):
        llh = geodesy.ecef_to_llh(rx)
        el, az = corrections.elevation_azimuth(rx, sp, llh)
        sow = gpstime.gps_seconds_of_week(t)
        return C_LIGHT * corrections.klobuchar_delay_s(llh[0], llh[1], az, el, sow, alpha, beta)

    return jax.vmap(one)(rx_pos, sat_pos, t_rx)


def ionex_slots(maps, llh, el, az, t_rx, f1):
    """IONEX slant delay on f1 [m] from ``io.IonexMaps``: M(E) 40.3 VTEC / f1^2 at the
    thin-shell pierce point, and whether the maps cover the pierce point and epoch ([T, S])."""
    tec, ok = _ionex_batch(
        ionex_table(maps),
        llh,
        el,
        az,
        jnp.asarray(t_rx),
        maps.height_km * 1e3,
        maps.base_radius_km * 1e3,
    )
    return corrections.IONO_K * tec / jnp.asarray(f1)[None, :] ** 2, ok


@jax.jit
def _ionex_batch(table, llh, el, az, t_rx, h, r):
    def one(l, e, a, t):
        lat_p, lon_p = corrections.ionosphere_pierce_point(l[0], l[1], a, e, h, r)
        vtec, ok = jax.vmap(lambda la, lo: ionex_vtec(table, t, la, lo))(lat_p, lon_p)
        m = corrections.thin_shell_mapping(e, h, r)
        return jnp.where(ok, m * vtec * corrections.TECU, 0.0), ok

    return jax.vmap(one)(llh, el, az, t_rx)


@jax.jit
def geometry_series(rx_pos, sat_pos, sat_clock_m):
    """Per epoch: LOS [S, 3], elevation, azimuth [S], receiver llh [3], rotated satellites."""

    def one(rx, pos, clk):
        se = models.SatEpoch(pos, jnp.zeros_like(pos), clk, jnp.zeros_like(clk))
        geo = models.geometry(rx, jnp.zeros(3), se)
        llh = geodesy.ecef_to_llh(rx)
        el, az = models.elevation_azimuth(geo.los_ecef, geodesy.C_l_e(llh[0], llh[1]).T)
        return geo.los_ecef, el, az, llh, geo.sat_pos_ecef

    return jax.vmap(one)(rx_pos, sat_pos, sat_clock_m)


@jax.jit
def windup_series(sat_pos, rx_pos, llh, t_rx, leap_seconds):
    """Continuous wind-up [rad] per epoch and slot (nominal yaw steering, north-aligned antenna)."""
    sun, _ = tides.sun_moon_ecef(t_rx, leap_seconds)
    frac = jax.vmap(windup.windup_rad)(sat_pos, rx_pos, sun, llh)
    return windup.windup_series_rad(frac)


@jax.jit
def tide_series(rx_pos, t_rx, leap_seconds):
    return jax.vmap(lambda p, t: tides.solid_tide_ecef(p, t, leap_seconds))(rx_pos, t_rx)


@jax.jit
def enu_axes_series(llh):
    return jax.vmap(lambda l: geodesy.C_l_e(l[0], l[1]))(llh)

