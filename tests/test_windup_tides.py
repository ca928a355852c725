"""Phase wind-up (S002 eqs 2.14-2.19) and solid Earth tides (IERS 2010 eq 7.5) vs closed forms.

No data files needed. Numbers checked here:
- wind-up of a satellite (or receiver antenna) rotated about the boresight = minus the angle;
- continuity (eq 2.18): a receiver spinning 3.3 turns accumulates 3.3 x 2 pi exactly;
- yaw-steering axes: orthonormal, z to the Earth centre, the Sun in the x-z half plane x > 0;
- Sun/Moon ephemerides vs published events of June-July 2020 and GMST vs IAU 1982 examples;
- tide of a single body at zenith / horizon / 45 deg vs eq 7.5 in closed form;
- the two-year mean tide vs the IERS permanent-tide formulas (eqs 7.14a-b), and the amplitude
  envelope (S002: up to 30 cm vertical, 5 cm horizontal).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav import geodesy
from jaxnav.core.gpstime import datetime64_to_gps_seconds
from jaxnav.gnss import tides, windup


def _utc(iso: str, leap: float = 18.0) -> float:
    """GPS seconds of a UTC calendar instant (GPS - UTC = ``leap``)."""
    return float(datetime64_to_gps_seconds(np.datetime64(iso))) + leap


def _rotate(v, axis, angle):
    """Rodrigues rotation of v about the unit ``axis`` by ``angle`` (right-handed)."""
    v, axis = np.asarray(v, float), np.asarray(axis, float)
    return (
        v * math.cos(angle)
        + np.cross(axis, v) * math.sin(angle)
        + axis * np.dot(axis, v) * (1.0 - math.cos(angle))
    )


@pytest.fixture(scope="module")
def zenith_geometry():
    llh = jnp.array([math.radians(55.5), math.radians(8.46), 60.0])
    rcv = np.asarray(geodesy.llh_to_ecef(llh))
    up = rcv / np.linalg.norm(rcv)
    sat = rcv + 2.02e7 * up  # straight overhead: boresight and line of sight coincide
    x_r, y_r = (np.asarray(a) for a in windup.receiver_axes(llh))
    return llh, rcv, sat, up, x_r, y_r


@pytest.mark.parametrize("angle", [0.3, 1.0, 2.5, -1.2, -3.0])
def test_satellite_rotation_about_boresight_gives_the_angle(zenith_geometry, angle):
    _, rcv, sat, up, x_r, y_r = zenith_geometry
    k = -up  # satellite -> receiver = the satellite boresight z_s
    x0 = x_r  # start aligned with the receiver dipole: zero wind-up
    x_s = _rotate(x0, k, angle)
    y_s = _rotate(np.cross(k, x0), k, angle)  # y_s = z_s x x_s (right-handed body frame)
    base = windup.windup_fraction_rad(sat, rcv, x0, np.cross(k, x0), x_r, y_r)
    got = windup.windup_fraction_rad(sat, rcv, x_s, y_s, x_r, y_r)
    assert float(base) == pytest.approx(0.0, abs=1e-12)
    # A rotation by +angle about the propagation direction retards the RHCP phase by angle.
    assert float(got) == pytest.approx(-angle, abs=1e-9)


@pytest.mark.parametrize("angle", [0.7, -2.2])
def test_receiver_rotation_about_vertical_gives_the_angle(zenith_geometry, angle):
    _, rcv, sat, up, x_r, y_r = zenith_geometry
    k = -up
    x_s, y_s = x_r, np.cross(k, x_r)
    xr2, yr2 = _rotate(x_r, up, angle), _rotate(y_r, up, angle)
    got = windup.windup_fraction_rad(sat, rcv, x_s, y_s, xr2, yr2)
    assert float(got) == pytest.approx(-angle, abs=1e-9)


def test_windup_continuity_counts_full_turns(zenith_geometry):
    _, rcv, sat, up, x_r, y_r = zenith_geometry
    k = -up
    x_s, y_s = x_r, np.cross(k, x_r)
    turns = 3.3
    angles = np.linspace(0.0, turns * 2.0 * math.pi, 400)  # < pi per step: unambiguous
    fr = np.array(
        [
            windup.windup_fraction_rad(sat, rcv, x_s, y_s, _rotate(x_r, up, a), _rotate(y_r, up, a))
            for a in angles
        ]
    )
    series = np.asarray(windup.windup_series_rad(jnp.asarray(fr)))
    assert np.all(np.abs(fr) <= math.pi + 1e-12)  # the fractional part wraps ...
    np.testing.assert_allclose(series, -angles, atol=1e-9)  # ... the continuous one does not


def test_yaw_steering_axes(zenith_geometry):
    _, rcv, _, up, _, _ = zenith_geometry
    sat = np.array([1.5e7, -1.2e7, 1.8e7])
    sun = np.array([1.2e11, 8.0e10, 2.0e10])
    x_s, y_s = (np.asarray(a) for a in windup.satellite_axes(sat, sun))
    z_s = np.cross(x_s, y_s)
    np.testing.assert_allclose(
        np.stack([x_s, y_s, z_s]) @ np.stack([x_s, y_s, z_s]).T, np.eye(3), atol=1e-12
    )
    np.testing.assert_allclose(z_s, -sat / np.linalg.norm(sat), atol=1e-12)  # S002 eq 2.6
    e_sun = (sun - sat) / np.linalg.norm(sun - sat)
    assert abs(np.dot(y_s, e_sun)) < 1e-12  # y_s is the solar-panel axis, normal to the Sun
    assert np.dot(x_s, e_sun) > 0.0


def test_sun_moon_against_published_events():
    # June solstice 2020-06-20 21:43 UTC: solar declination = obliquity 23.4365 deg.
    sun, _ = tides.sun_moon_ecef(_utc("2020-06-20T21:43"))
    dec = math.degrees(math.asin(float(sun[2] / jnp.linalg.norm(sun))))
    assert dec == pytest.approx(23.4365, abs=0.01)
    # Aphelion 2020-07-04 11:35 UTC at 1.016694 au.
    sun, _ = tides.sun_moon_ecef(_utc("2020-07-04T11:35"))
    assert float(jnp.linalg.norm(sun)) / tides.ASTRONOMICAL_UNIT_M == pytest.approx(
        1.016694, abs=5e-5
    )
    # Annular solar eclipse 2020-06-21, greatest eclipse 06:40 UTC: geocentric conjunction.
    sun, moon = tides.sun_moon_ecef(_utc("2020-06-21T06:40"))
    cos_a = float(jnp.dot(sun, moon) / (jnp.linalg.norm(sun) * jnp.linalg.norm(moon)))
    assert math.degrees(math.acos(cos_a)) < 0.5
    assert 356e6 < float(jnp.linalg.norm(moon)) < 407e6
    # 2020-06-25 12:00 UTC: equation of time -2.5 min puts the Sun 0.6 deg east of Greenwich.
    sun, _ = tides.sun_moon_ecef(_utc("2020-06-25T12:00"))
    assert math.degrees(math.atan2(float(sun[1]), float(sun[0]))) == pytest.approx(0.62, abs=0.1)


def test_gmst_iau1982_examples():
    # Meeus, Astronomical Algorithms, example 12.a: 1987-04-10 0h UT -> 13h10m46.3668s.
    got = math.degrees(float(tides.gmst_rad(_utc("1987-04-10T00:00", 4.0), 4.0)))
    assert got == pytest.approx((13 + 10 / 60 + 46.3668 / 3600) * 15.0, abs=1e-6)
    # J2000.0 (2000-01-01 12:00 UT1): 280.46061837 deg by definition of the series.
    got = math.degrees(float(tides.gmst_rad(_utc("2000-01-01T12:00", 13.0), 13.0)))
    assert got == pytest.approx(280.46061837, abs=1e-7)


def _site(lat_deg, lon_deg=20.0):
    # A point on a sphere: geocentric = geodetic latitude, so r_hat is exactly "up".
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    r_hat = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    return r_hat * 6371e3, r_hat


@pytest.mark.parametrize("zenith_deg", [0.0, 45.0, 90.0])
def test_single_body_closed_form(zenith_deg):
    pos, r_hat = _site(40.0)
    east = np.cross([0.0, 0.0, 1.0], r_hat)
    east /= np.linalg.norm(east)
    z = math.radians(zenith_deg)
    dist = 384400e3
    moon = dist * (math.cos(z) * r_hat + math.sin(z) * east)
    far_sun = np.array([1e30, 0.0, 0.0])  # GM/R^3 -> 0: only the Moon acts
    d = np.asarray(tides.solid_tide_from_bodies(pos, far_sun, moon, 0.0, k1_term=False))
    p2 = 0.5 * (3.0 * math.sin(math.radians(40.0)) ** 2 - 1.0)
    h2 = tides.H2_NOMINAL + tides.H2_LAT * p2
    l2 = tides.L2_NOMINAL + tides.L2_LAT * p2
    scale = tides.GM_MOON_OVER_EARTH * tides.R_EARTH_EQ_M**4 / dist**3
    c = math.cos(z)
    radial = scale * h2 * (1.5 * c * c - 0.5)
    horizontal = scale * 3.0 * l2 * c * math.sin(z)  # towards the body
    assert float(d @ r_hat) == pytest.approx(radial, abs=1e-12)
    assert float(d @ east) == pytest.approx(horizontal, abs=1e-12)
    if zenith_deg == 0.0:
        assert radial == pytest.approx(0.2177, abs=5e-4)  # the Moon's zenith bulge: ~22 cm


@pytest.mark.parametrize("lat_deg", [0.0, 30.0, 55.0, 80.0])
def test_mean_tide_is_the_iers_permanent_tide(lat_deg):
    """Two-year mean of eq 7.5 = permanent tide, IERS 2010 eqs 7.14a-b:
    dr = (-0.1206 + 0.0001 P2) P2, dn = (-0.0252 - 0.0001 P2) sin 2 lat, P2 = (3 sin^2 - 1)/2."""
    pos, r_hat = _site(lat_deg)
    t = _utc("2010-01-01T00:00") + np.arange(0.0, 2 * 365.25 * 86400.0, 3 * 3600.0 + 17.0)
    d = np.asarray(tides.solid_tide_ecef(pos, jnp.asarray(t)))
    enu = np.asarray(tides.displacement_enu(d, pos))
    s = math.sin(math.radians(lat_deg))
    p2 = 1.5 * s * s - 0.5
    assert enu[:, 2].mean() == pytest.approx((-0.1206 + 0.0001 * p2) * p2, abs=0.003)
    dn = (-0.0252 - 0.0001 * p2) * math.sin(2.0 * math.radians(lat_deg))
    assert enu[:, 1].mean() == pytest.approx(dn, abs=0.002)
    # Envelope over two years (S002 §2.1.8.1: "up to 30 cm vertical and 5 cm horizontal").
    assert np.abs(enu[:, 2]).max() < 0.40
    assert np.hypot(enu[:, 0], enu[:, 1]).max() < 0.09
    if lat_deg <= 30.0:
        assert np.ptp(enu[:, 2]) > 0.40  # low latitudes see the full semidiurnal bulge
