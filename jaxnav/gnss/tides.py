"""Solid Earth tide site displacement and the low-precision Sun / Moon ephemerides it needs.

Pure JAX, float64, broadcasting over leading time axes. Times are GPS seconds (since
1980-01-06 00:00:00 GPST, the jaxnav time scale); positions are ECEF metres.

- Sun and Moon: the analytical low-precision series of Montenbruck & Gill, *Satellite Orbits*
  (2000), section 3.3.2 (eqs 3.43-3.49): Sun ~0.1-1 % in distance and ~0.01 deg in direction,
  Moon ~ 0.1 deg / 500 km. Ecliptic longitudes are taken in the mean equinox *of date* (the
  series' J2000 precession term is not applied), converted to mean equatorial coordinates with
  the obliquity of date, and rotated to ECEF with the Greenwich mean sidereal time; nutation
  (< 20") and polar motion (< 1") are neglected, which moves the tide by well under 1 mm.
- Solid tide: IERS Conventions 2010 eq 7.5 (step 1, degree 2, in phase) with the nominal Love and
  Shida numbers h2 = 0.6078, l2 = 0.0847 and their latitude dependence (IERS eq 7.2), plus the
  K1 radial term -0.025 sin(lat) cos(lat) sin(gmst + lon) of S002 eq 2.21 (IERS step 2, the only
  step-2 term above 5 mm). Degree 3 (< 2 mm) is neglected. The model yields positions in the
  conventional tide-free system of the ITRF / IGS frames (IERS 7.1.1). SEED_SPEC 4 (S002 item 3):
  S002 prints (l2, h2) = (0.609, 0.085), swapped; here h2 = 0.6078, l2 = 0.0847.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Real

from jaxnav import geodesy
from jaxnav.core.gpstime import GPS_UTC_LEAP_S

# GPS epoch (1980-01-06 00:00 GPST) as a Julian date, TT - GPST, and the J2000.0 epoch.
JD_GPS_EPOCH = 2444244.5
TT_MINUS_GPS_S = 51.184  # TT = TAI + 32.184 s, TAI = GPST + 19 s
JD_J2000 = 2451545.0

ASTRONOMICAL_UNIT_M = 149597870700.0  # IAU 2012
GM_EARTH = 3.986004418e14  # IERS 2010 table 1.1 [m^3/s^2]
GM_SUN_OVER_EARTH = 332946.0487  # IERS 2010 table 1.1 (GM_sun / GM_earth)
GM_MOON_OVER_EARTH = 0.0123000371  # IERS 2010 table 1.1 (mass ratio Moon / Earth)
R_EARTH_EQ_M = 6378136.6  # IERS 2010 table 1.1, the a_E of eq 7.5

H2_NOMINAL = 0.6078  # IERS 2010 eq 7.2 (SEED_SPEC 4, S002 item 3)
L2_NOMINAL = 0.0847
H2_LAT = -0.0006  # latitude dependence h2 = 0.6078 - 0.0006 (3 sin^2 lat - 1) / 2
L2_LAT = 0.0002  # l2 = 0.0847 + 0.0002 (3 sin^2 lat - 1) / 2
K1_RADIAL_M = -0.025  # S002 eq 2.21: -0.025 sin(lat) cos(lat) sin(gmst + lon) [m]

_ARCSEC = jnp.pi / (180.0 * 3600.0)
_DEG = jnp.pi / 180.0


def julian_centuries_tt(t_gps_s):
    """T = (JD_TT - 2451545.0) / 36525 with JD_TT = 2444244.5 + (t_GPS + 51.184 s) / 86400."""
    jd_tt = JD_GPS_EPOCH + (t_gps_s + TT_MINUS_GPS_S) / 86400.0
    return (jd_tt - JD_J2000) / 36525.0


def gmst_rad(t_gps_s, leap_seconds=GPS_UTC_LEAP_S):
    """Greenwich mean sidereal time [rad] (IAU 1982, Meeus eq 12.4), UT1 taken as UTC.

    theta = 280.46061837 + 360.98564736629 d + 0.000387933 T^2 - T^3 / 38710000 [deg],
    d = JD_UT1 - 2451545.0, T = d / 36525.
    """
    d = (JD_GPS_EPOCH - JD_J2000) + (t_gps_s - leap_seconds) / 86400.0
    T = d / 36525.0
    deg = 280.46061837 + 360.98564736629 * d + 0.000387933 * T**2 - T**3 / 38710000.0
    return jnp.mod(deg, 360.0) * _DEG


def _obliquity_rad(T):
    """Mean obliquity of the ecliptic of date, 23.43929111 deg - 46.8150" T (IAU 1980)."""
    return 23.43929111 * _DEG - 46.8150 * _ARCSEC * T


def _ecliptic_to_ecef(lon_rad, lat_rad, dist_m, T, gmst):
    """Mean-of-date ecliptic spherical coordinates -> ECEF: R3(gmst) R1(-eps) r_ecl."""
    cb = jnp.cos(lat_rad)
    x = dist_m * cb * jnp.cos(lon_rad)
    y = dist_m * cb * jnp.sin(lon_rad)
    z = dist_m * jnp.sin(lat_rad)
    eps = _obliquity_rad(T)
    ce, se = jnp.cos(eps), jnp.sin(eps)
    y_eq = ce * y - se * z
    z_eq = se * y + ce * z
    cg, sg = jnp.cos(gmst), jnp.sin(gmst)
    return jnp.stack([cg * x + sg * y_eq, -sg * x + cg * y_eq, z_eq], axis=-1)


def sun_ecliptic(T):
    """Sun's mean-of-date ecliptic longitude [rad] and distance [m] (Montenbruck & Gill 3.43-3.46).

    M = 357.5256 + 35999.049 T [deg]; lambda = 282.9400 deg + M + 6892" sin M + 72" sin 2M
    (+ 1.3972 deg T, the precession from the J2000 equinox to the equinox of date);
    r = (149.619 - 2.499 cos M - 0.021 cos 2M) 1e9 m; ecliptic latitude 0.
    """
    M = (357.5256 + 35999.049 * T) * _DEG
    lon = (
        (282.9400 + 1.3972 * T) * _DEG
        + M
        + 6892.0 * _ARCSEC * jnp.sin(M)
        + 72.0 * _ARCSEC * jnp.sin(2.0 * M)
    )
    r = (149.619 - 2.499 * jnp.cos(M) - 0.021 * jnp.cos(2.0 * M)) * 1e9
    return lon, r


def moon_ecliptic(T):
    """Moon's mean-of-date ecliptic longitude, latitude [rad] and distance [m] (M&G 3.47-3.49).

    Mean elements [deg]: L0 = 218.31617 + 481267.88088 T (equinox of date), l = 134.96292 +
    477198.86753 T, l' = 357.52543 + 35999.04944 T, F = 93.27283 + 483202.01873 T,
    D = 297.85027 + 445267.11135 T, with the periodic series of M&G eqs 3.48-3.49.
    """
    L0 = (218.31617 + 481267.88088 * T) * _DEG
    l = (134.96292 + 477198.86753 * T) * _DEG
    lp = (357.52543 + 35999.04944 * T) * _DEG
    F = (93.27283 + 483202.01873 * T) * _DEG
    D = (297.85027 + 445267.11135 * T) * _DEG
    s = jnp.sin
    dlon_arcsec = (
        22640.0 * s(l)
        + 769.0 * s(2 * l)
        - 4586.0 * s(l - 2 * D)
        + 2370.0 * s(2 * D)
        - 668.0 * s(lp)
        - 412.0 * s(2 * F)
        - 212.0 * s(2 * l - 2 * D)
        - 206.0 * s(l + lp - 2 * D)
        + 192.0 * s(l + 2 * D)
        - 165.0 * s(lp - 2 * D)
        + 148.0 * s(l - lp)
        - 125.0 * s(D)
        - 110.0 * s(l + lp)
        - 55.0 * s(2 * F - 2 * D)
    )
    lon = L0 + dlon_arcsec * _ARCSEC
    arg = F + (lon - L0) + (412.0 * s(2 * F) + 541.0 * s(lp)) * _ARCSEC
    lat_arcsec = (
        18520.0 * s(arg)
        - 526.0 * s(F - 2 * D)
        + 44.0 * s(l + F - 2 * D)
        - 31.0 * s(-l + F - 2 * D)
        - 25.0 * s(-2 * l + F)
        - 23.0 * s(lp + F - 2 * D)
        + 21.0 * s(-l + F)
        + 11.0 * s(-lp + F - 2 * D)
    )
    c = jnp.cos
    r_km = (
        385000.0
        - 20905.0 * c(l)
        - 3699.0 * c(2 * D - l)
        - 2956.0 * c(2 * D)
        - 570.0 * c(2 * l)
        + 246.0 * c(2 * l - 2 * D)
        - 205.0 * c(lp - 2 * D)
        - 171.0 * c(l + 2 * D)
        - 152.0 * c(l + lp - 2 * D)
    )
    return lon, lat_arcsec * _ARCSEC, r_km * 1e3


def sun_moon_ecef(
    t_gps_s: Real[ArrayLike, "*T"], leap_seconds=GPS_UTC_LEAP_S
) -> tuple[Float[Array, "*T 3"], Float[Array, "*T 3"]]:
    """ECEF positions [m] of the Sun and the Moon at GPS time(s) t (shape [..., 3] each)."""
    t = jnp.asarray(t_gps_s, dtype=jnp.float64)
    T = julian_centuries_tt(t)
    gmst = gmst_rad(t, leap_seconds)
    lon_s, r_s = sun_ecliptic(T)
    sun = _ecliptic_to_ecef(lon_s, jnp.zeros_like(lon_s), r_s, T, gmst)
    lon_m, lat_m, r_m = moon_ecliptic(T)
    moon = _ecliptic_to_ecef(lon_m, lat_m, r_m, T, gmst)
    return sun, moon


def _degree2_body(r_hat, body_ecef, gm_ratio, h2, l2, radius_m):
    """One body's term of IERS eq 7.5: (GM_j/GM_E)(a^4/R_j^3){h2 r [3/2 c^2 - 1/2]
    + 3 l2 c [R_j - c r]}, c = R_j . r (unit vectors)."""
    dist = jnp.linalg.norm(body_ecef, axis=-1, keepdims=True)
    b_hat = body_ecef / dist
    c = jnp.sum(b_hat * r_hat, axis=-1, keepdims=True)
    scale = gm_ratio * radius_m**4 / dist**3
    radial = h2 * r_hat * (1.5 * c * c - 0.5)
    tangential = 3.0 * l2 * c * (b_hat - c * r_hat)
    return scale * (radial + tangential)


def solid_tide_from_bodies(
    pos_ecef: Float[ArrayLike, "*#T 3"],
    sun_ecef: Float[ArrayLike, "*#T 3"],
    moon_ecef: Float[ArrayLike, "*#T 3"],
    gmst: Float[ArrayLike, "*#T"],
    k1_term: bool = True,
) -> Float[Array, "*#T 3"]:
    """Solid Earth tide displacement [m, ECEF] of a site, given the Sun and Moon (IERS eq 7.5).

    Degree-2 step 1 of both bodies with h2(lat), l2(lat) (IERS eq 7.2) and, if ``k1_term``, the
    S002 eq 2.21 radial K1 correction -0.025 sin(lat) cos(lat) sin(gmst + lon) [m].
    """
    pos = jnp.asarray(pos_ecef, dtype=jnp.float64)
    r_hat = pos / jnp.linalg.norm(pos, axis=-1, keepdims=True)
    sin_lat = r_hat[..., 2:3]  # geocentric latitude: the IERS formula is written with it
    p2 = 0.5 * (3.0 * sin_lat**2 - 1.0)
    h2 = H2_NOMINAL + H2_LAT * p2
    l2 = L2_NOMINAL + L2_LAT * p2
    dr = _degree2_body(r_hat, sun_ecef, GM_SUN_OVER_EARTH, h2, l2, R_EARTH_EQ_M)
    dr = dr + _degree2_body(r_hat, moon_ecef, GM_MOON_OVER_EARTH, h2, l2, R_EARTH_EQ_M)
    if k1_term:
        cos_lat = jnp.sqrt(jnp.maximum(1.0 - sin_lat**2, 0.0))
        lon = jnp.arctan2(pos[..., 1:2], pos[..., 0:1])
        gm = jnp.asarray(gmst)[..., None]
        dr = dr + K1_RADIAL_M * sin_lat * cos_lat * jnp.sin(gm + lon) * r_hat
    return dr


def solid_tide_ecef(
    pos_ecef: Float[ArrayLike, "*#T 3"],
    t_gps_s: Real[ArrayLike, "*#T"],
    leap_seconds=GPS_UTC_LEAP_S,
    k1_term: bool = True,
) -> Float[Array, "*#T 3"]:
    """Solid Earth tide displacement [m, ECEF] of a site at GPS time(s) t (IERS 2010 eq 7.5).

    Add it to the (tide-free) marker position to get the instantaneous position; subtract its
    line-of-sight projection from the observations to estimate the tide-free position.
    """
    t = jnp.asarray(t_gps_s, dtype=jnp.float64)
    sun, moon = sun_moon_ecef(t, leap_seconds)
    return solid_tide_from_bodies(pos_ecef, sun, moon, gmst_rad(t, leap_seconds), k1_term)


def displacement_enu(
    disp_ecef: Float[ArrayLike, "*T 3"], pos_ecef: Float[ArrayLike, "3"]
) -> Float[Array, "*T 3"]:
    """A site displacement [m] expressed in the site's ENU frame (east, north, up)."""
    llh = geodesy.ecef_to_llh(jnp.asarray(pos_ecef, dtype=jnp.float64))
    return disp_ecef @ geodesy.C_l_e(llh[0], llh[1])
