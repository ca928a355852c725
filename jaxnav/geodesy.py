"""WGS-84 Earth model: radii, normal gravity, LLH<->ECEF, ENU<->ECEF, Earth and transport rates.

Conventions: geodetic position ``llh = (lat_rad, lon_rad, h_m)``; the local-level frame l is
ENU; every vector is float64. All functions are pure and broadcast-free (one point at a time):
use ``jax.vmap`` for batches.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# WGS-84 defining constants (NIMA TR8350.2).
A_WGS84 = 6378137.0  # semi-major axis [m]
F_WGS84 = 1.0 / 298.257223563  # flattening
E2_WGS84 = F_WGS84 * (2.0 - F_WGS84)  # first eccentricity squared (0.00669437999014)
B_WGS84 = A_WGS84 * (1.0 - F_WGS84)  # semi-minor axis [m]
OMEGA_E = 7.2921151467e-5  # Earth rotation rate [rad/s] (IS-GPS-200; seed 000 App. A)
GM_WGS84 = 3.986004418e14  # Earth gravitational constant [m^3/s^2]
C_LIGHT = 299792458.0  # speed of light [m/s]

# Normal-gravity polynomial coefficients (SEED_SPEC 1.1, after Schwarz & Wei):
# g(lat, h) = a1 (1 + a2 s^2 + a3 s^4) + (a4 + a5 s^2) h + a6 h^2,  s = sin(lat).
_G_A1 = 9.7803267715
_G_A2 = 0.0052790414
_G_A3 = 0.0000232718
_G_A4 = -3.087691089e-6
_G_A5 = 4.397731e-9
_G_A6 = 7.21e-13

# Fixed-point iterations for ECEF->LLH; each gains a factor ~e^2 (7e-3), so 8 reach 1e-17 rad.
_LLH_ITERATIONS = 8


# Functions called on host arrays (tests, post-processing) are jitted: one compiled kernel per
# argument shape instead of one per primitive (inside another jit they are inlined).
@jax.jit
def radii(lat_rad):
    """Meridian and prime-vertical radii: R_M = a(1-e^2)/(1-e^2 s^2)^1.5, R_N = a/(1-e^2 s^2)^.5."""
    s2 = jnp.sin(lat_rad) ** 2
    w = jnp.sqrt(1.0 - E2_WGS84 * s2)
    r_n = A_WGS84 / w
    r_m = A_WGS84 * (1.0 - E2_WGS84) / w**3
    return r_m, r_n


def normal_gravity(lat_rad, h_m):
    """Magnitude of normal gravity [m/s^2] at latitude and ellipsoidal height (SEED_SPEC 1.1)."""
    s2 = jnp.sin(lat_rad) ** 2
    return (
        _G_A1 * (1.0 + _G_A2 * s2 + _G_A3 * s2 * s2)
        + (_G_A4 + _G_A5 * s2) * h_m
        + _G_A6 * h_m * h_m
    )


def gravity_enu(llh):
    """Normal gravity vector in ENU: g^l = [0, 0, -g(lat, h)]."""
    g = normal_gravity(llh[0], llh[2])
    return jnp.array([0.0, 0.0, -g], dtype=jnp.float64) * jnp.ones_like(g)


def llh_to_ecef(llh):
    """Geodetic to ECEF: x, y = (R_N+h) cos(lat) (cos, sin)(lon), z = (R_N(1-e^2)+h) sin(lat)."""
    lat, lon, h = llh[0], llh[1], llh[2]
    _, r_n = radii(lat)
    cl = jnp.cos(lat)
    return jnp.stack(
        [
            (r_n + h) * cl * jnp.cos(lon),
            (r_n + h) * cl * jnp.sin(lon),
            (r_n * (1.0 - E2_WGS84) + h) * jnp.sin(lat),
        ]
    )


def ecef_to_llh(pos_ecef):
    """ECEF to geodetic by the fixed point lat = atan2(z + e^2 R_N sin(lat), p).

    Height uses h = p cos(lat) + z sin(lat) - a sqrt(1 - e^2 sin^2 lat), which is well conditioned
    at every latitude (including the poles). Round trip error < 1e-9 m from the surface to GNSS
    orbit altitude.
    """
    x, y, z = pos_ecef[0], pos_ecef[1], pos_ecef[2]
    p = jnp.hypot(x, y)
    lat = jnp.arctan2(z, p * (1.0 - E2_WGS84))
    for _ in range(_LLH_ITERATIONS):
        _, r_n = radii(lat)
        lat = jnp.arctan2(z + E2_WGS84 * r_n * jnp.sin(lat), p)
    s = jnp.sin(lat)
    h = p * jnp.cos(lat) + z * s - A_WGS84 * jnp.sqrt(1.0 - E2_WGS84 * s * s)
    lon = jnp.arctan2(y, x)
    return jnp.stack([lat, lon, h])


def C_l_e(lat_rad, lon_rad):
    """Rotation ENU (l) -> ECEF (e): columns are the east, north and up unit vectors (S002 2.12)."""
    sp, cp = jnp.sin(lat_rad), jnp.cos(lat_rad)
    sl, cl = jnp.sin(lon_rad), jnp.cos(lon_rad)
    z = jnp.zeros_like(sp)
    return jnp.array(
        [
            [-sl, -sp * cl, cp * cl],
            [cl, -sp * sl, cp * sl],
            [z, cp, sp],
        ]
    )


def enu_to_ecef(vec_enu, llh):
    """Rotate a vector from ENU at ``llh`` into ECEF: v^e = C_l^e v^l."""
    return C_l_e(llh[0], llh[1]) @ vec_enu


def ecef_to_enu(vec_ecef, llh):
    """Rotate a vector from ECEF into ENU at ``llh``: v^l = (C_l^e)^T v^e."""
    return C_l_e(llh[0], llh[1]).T @ vec_ecef


def enu_offset(pos_ecef, ref_llh):
    """ENU coordinates [m] of an ECEF point relative to a geodetic reference point."""
    return ecef_to_enu(pos_ecef - llh_to_ecef(ref_llh), ref_llh)


def llh_rate_matrix(llh):
    """D^-1 of S002 eq 3.4: d(lat, lon, h)/dt = D^-1 v_enu."""
    lat, h = llh[0], llh[2]
    r_m, r_n = radii(lat)
    z = jnp.zeros_like(lat)
    return jnp.array(
        [
            [z, 1.0 / (r_m + h), z],
            [1.0 / ((r_n + h) * jnp.cos(lat)), z, z],
            [z, z, z + 1.0],
        ]
    )


def llh_to_ecef_jacobian(llh):
    """Jacobian L = d(pos_ecef)/d(lat, lon, h), exact.

    S000 eq 4.66 (= S002 5.25) prints R_N + h in the latitude column; differentiating R_N(lat)
    too gives R_M + h (0.5 % different at mid latitudes): the physically correct form is used.
    """
    lat, lon, h = llh[0], llh[1], llh[2]
    r_m, r_n = radii(lat)
    sp, cp = jnp.sin(lat), jnp.cos(lat)
    sl, cl = jnp.sin(lon), jnp.cos(lon)
    z = jnp.zeros_like(sp)
    return jnp.array(
        [
            [-(r_m + h) * sp * cl, -(r_n + h) * cp * sl, cp * cl],
            [-(r_m + h) * sp * sl, (r_n + h) * cp * cl, cp * sl],
            [(r_m + h) * cp, z, sp],
        ]
    )


def earth_rate_enu(lat_rad):
    """Earth rotation rate in ENU: w_ie^l = [0, we cos(lat), we sin(lat)]."""
    return jnp.stack(
        [jnp.zeros_like(lat_rad), OMEGA_E * jnp.cos(lat_rad), OMEGA_E * jnp.sin(lat_rad)]
    )


def transport_rate_enu(llh, vel_enu):
    """Transport rate w_el^l = [-vn/(R_M+h), ve/(R_N+h), ve tan(lat)/(R_N+h)]."""
    lat, h = llh[0], llh[2]
    r_m, r_n = radii(lat)
    ve, vn = vel_enu[0], vel_enu[1]
    return jnp.stack([-vn / (r_m + h), ve / (r_n + h), ve * jnp.tan(lat) / (r_n + h)])


@jax.jit
def metres_per_radian(llh):
    """Scale from (d_lat, d_lon, d_h) [rad, rad, m] to local (north, east, up) metres."""
    lat, h = llh[0], llh[2]
    r_m, r_n = radii(lat)
    return jnp.stack([r_m + h, (r_n + h) * jnp.cos(lat), jnp.ones_like(h)])


def llh_error_to_enu_matrix(llh):
    """T [3, 3] with (east, north, up) = T (d_lat, d_lon, d_h): ``metres_per_radian`` laid out
    for covariances, T P_llh T^T."""
    m_north, m_east, _ = metres_per_radian(llh)
    z = jnp.zeros_like(m_north)
    return jnp.array([[z, m_east, z], [m_north, z, z], [z, z, z + 1.0]])


@jax.jit
def llh_error_to_enu(dllh, llh):
    """Convert a small geodetic error (d_lat, d_lon, d_h) into ENU metres."""
    north, east, up = metres_per_radian(llh) * dllh
    return jnp.stack([east, north, up])
