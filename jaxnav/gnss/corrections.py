"""Propagation and geometry corrections shared by the simulator and the filter (pure JAX).

Every function is elementwise/broadcasting over leading axes unless stated, float64, and
differentiable (``jax.jacfwd`` works through all of them). Angles in radians, heights in metres,
delays in metres unless the name says seconds.

Contents
- Troposphere: Berg pressure, Saastamoinen zenith hydrostatic delay (S002 eq 2.3), Saastamoinen
  zenith wet delay from a standard atmosphere, Marini continued fraction (S002 eq 2.4) and the
  Niell (1996) hydrostatic and wet mapping functions with their coefficient tables.
- Ionosphere: Klobuchar broadcast model (IS-GPS-200 20.3.3.5.2.5), thin-shell (single-layer)
  pierce point and mapping function, TEC <-> delay.
- Geometry: elevation/azimuth, Earth rotation during the signal travel time (Sagnac), periodic
  relativistic satellite clock correction (S000 eq 2.42).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from jaxnav import geodesy
from jaxnav.geodesy import C_LIGHT, OMEGA_E

# ------------------------------------------------------------------------------------------------
# Troposphere
# ------------------------------------------------------------------------------------------------

# Standard atmosphere at mean sea level (Berg 1948 as quoted in S002 2.3; ISA lapse rate).
P0_HPA = 1013.25
T0_K = 288.15
TEMP_LAPSE_K_M = 0.0065


def berg_pressure_hpa(h_m):
    """Berg's standard pressure P = 1013.25 (1 - 2.2557e-5 h)^5.2568 [hPa] (S002 after eq 2.3)."""
    return P0_HPA * (1.0 - 2.2557e-5 * h_m) ** 5.2568


def saastamoinen_zhd_m(lat_rad, h_m, pressure_hpa=None):
    """Zenith hydrostatic delay Z_h = 0.0022768 P / (1 - 0.00266 cos 2 lat - 2.8e-7 h) (S002 2.3).

    P defaults to :func:`berg_pressure_hpa` (S002: adequate for cm-level PPP). ~2.3 m at sea level.
    """
    p = berg_pressure_hpa(h_m) if pressure_hpa is None else pressure_hpa
    return 0.0022768 * p / (1.0 - 0.00266 * jnp.cos(2.0 * lat_rad) - 2.8e-7 * h_m)


def saturation_vapour_pressure_hpa(temp_k):
    """Magnus-Tetens e_s = 6.1078 exp(17.27 T_c / (T_c + 237.3)) [hPa], T_c in Celsius."""
    tc = temp_k - 273.15
    return 6.1078 * jnp.exp(17.27 * tc / (tc + 237.3))


def saastamoinen_zwd_m(h_m, rel_humidity=0.5):
    """Zenith wet delay Z_w = 0.002277 (1255 / T + 0.05) e [m] (Saastamoinen 1972).

    Default meteorology (chosen, standard atmosphere): T = 288.15 - 0.0065 h [K] and
    e = rh e_s(T) with rh = 0.5, giving Z_w ~ 8.5 cm at sea level. Real ZWD differs by
    several cm, which is why PPP estimates it (S002 2.3); the simulator adds a residual.
    """
    temp_k = T0_K - TEMP_LAPSE_K_M * h_m
    e = rel_humidity * saturation_vapour_pressure_hpa(temp_k)
    return 0.002277 * (1255.0 / temp_k + 0.05) * e


def marini_mapping(sin_el, a, b, c):
    """Marini continued fraction normalised at zenith (S002 eq 2.4).

    M = (1 + a / (1 + b / (1 + c))) / (sin E + a / (sin E + b / (sin E + c))).
    """
    top = 1.0 + a / (1.0 + b / (1.0 + c))
    return top / (sin_el + a / (sin_el + b / (sin_el + c)))


# Niell (1996) coefficient tables, latitudes 15, 30, 45, 60, 75 deg (J. Geophys. Res. 101(B2),
# table 3; also IERS Conventions / navipedia "Mapping of Niell").
_NIELL_H_AVG = np.array(
    [
        [1.2769934e-3, 2.9153695e-3, 62.610505e-3],
        [1.2683230e-3, 2.9152299e-3, 62.837393e-3],
        [1.2465397e-3, 2.9288445e-3, 63.721774e-3],
        [1.2196049e-3, 2.9022565e-3, 63.824265e-3],
        [1.2045996e-3, 2.9024912e-3, 64.258455e-3],
    ]
)
_NIELL_H_AMP = np.array(
    [
        [0.0, 0.0, 0.0],
        [1.2709626e-5, 2.1414979e-5, 9.0128400e-5],
        [2.6523662e-5, 3.0160779e-5, 4.3497037e-5],
        [3.4000452e-5, 7.2562722e-5, 84.795348e-5],
        [4.1202191e-5, 11.723375e-5, 170.37206e-5],
    ]
)
_NIELL_H_HT = (2.53e-5, 5.49e-3, 1.14e-3)  # height correction coefficients (a_ht, b_ht, c_ht)
_NIELL_W = np.array(
    [
        [5.8021897e-4, 1.4275268e-3, 4.3472961e-2],
        [5.6794847e-4, 1.5138625e-3, 4.6729510e-2],
        [5.8118019e-4, 1.4572752e-3, 4.3908931e-2],
        [5.9727542e-4, 1.5007428e-3, 4.4626982e-2],
        [6.1641693e-4, 1.7599082e-3, 5.4736038e-2],
    ]
)
_NIELL_DOY_PHASE = 28.0  # day of year of the hydrostatic seasonal extreme (Niell 1996)


_NIELL_TABLE = np.concatenate([_NIELL_H_AVG, _NIELL_H_AMP, _NIELL_W], axis=1)  # [5 lat, 9]


def _niell_coefficients(abs_lat_deg):
    """The 9 Niell coefficients linearly interpolated in |latitude| on the 15-deg grid (constant
    beyond 15 / 75 deg): (a, b, c) average hydrostatic, amplitude hydrostatic, wet."""
    x = jnp.clip((abs_lat_deg - 15.0) / 15.0, 0.0, 4.0)
    i = jnp.minimum(jnp.floor(x), 3.0)
    w = x - i
    table = jnp.asarray(_NIELL_TABLE)
    i = i.astype(jnp.int32)
    return table[i] * (1.0 - w)[..., None] + table[i + 1] * w[..., None]


def niell_mapping(
    el_rad: Float[ArrayLike, "*#S"],
    lat_rad: Float[ArrayLike, "*#S"],
    h_m: Float[ArrayLike, "*#S"],
    day_of_year: Real[ArrayLike, "*#S"],
) -> tuple[Float[Array, "*#S"], Float[Array, "*#S"]]:
    """Niell (1996) hydrostatic and wet mapping functions (m_h, m_w).

    m_h = M(E; a_h, b_h, c_h) + (1/sin E - M(E; a_ht, b_ht, c_ht)) h[km], with
    p = p_avg(lat) - p_amp(lat) cos(2 pi (doy - 28) / 365.25) (half a year later in the southern
    hemisphere); m_w = M(E; a_w, b_w, c_w); M is the Marini fraction (:func:`marini_mapping`).
    Accuracy vs ray tracing: < 1 cm of slant delay above 5 deg, a few cm at 3 deg (Niell 1996).
    """
    abs_lat_deg = jnp.abs(jnp.degrees(lat_rad))
    season = jnp.cos(2.0 * jnp.pi * (day_of_year - _NIELL_DOY_PHASE) / 365.25)
    season = jnp.where(lat_rad < 0.0, -season, season)
    coef = _niell_coefficients(abs_lat_deg)
    a_h, b_h, c_h = (coef[..., j] - coef[..., 3 + j] * season for j in range(3))
    s = jnp.sin(el_rad)
    m_h = marini_mapping(s, a_h, b_h, c_h)
    m_h = m_h + (1.0 / s - marini_mapping(s, *_NIELL_H_HT)) * (h_m * 1e-3)
    m_w = marini_mapping(s, coef[..., 6], coef[..., 7], coef[..., 8])
    return m_h, m_w


def tropo_slant_delay_m(
    el_rad: Float[ArrayLike, "*#S"],
    lat_rad: Float[ArrayLike, "*#S"],
    h_m: Float[ArrayLike, "*#S"],
    day_of_year: Real[ArrayLike, "*#S"],
    zwd_m: Float[ArrayLike, "*#S"] | None = None,
) -> Float[Array, "*#S"]:
    """Slant troposphere T = m_h(E) Z_h + m_w(E) Z_w (S002 eq 2.2 without gradients).

    Z_h from :func:`saastamoinen_zhd_m` (Berg pressure); Z_w defaults to
    :func:`saastamoinen_zwd_m`; m_h, m_w from :func:`niell_mapping`.
    """
    zhd = saastamoinen_zhd_m(lat_rad, h_m)
    zwd = saastamoinen_zwd_m(h_m) if zwd_m is None else zwd_m
    m_h, m_w = niell_mapping(el_rad, lat_rad, h_m, day_of_year)
    return m_h * zhd + m_w * zwd


# ------------------------------------------------------------------------------------------------
# Ionosphere
# ------------------------------------------------------------------------------------------------

IONO_K = 40.3  # first-order ionospheric constant: I = 40.3 TEC / f^2 [m, el/m^2, Hz]
TECU = 1e16  # electrons / m^2
IONO_SHELL_HEIGHT_M = 350e3  # thin-shell height (chosen: Klobuchar's implied 350 km)
IONO_EARTH_RADIUS_M = 6371e3  # spherical Earth of the single-layer model

# A real broadcast Klobuchar set (the ESBC 2020-06-25 mixed navigation header, GPSA/GPSB):
# alpha [s, s/sc, s/sc^2, s/sc^3], beta [s, s/sc, s/sc^2, s/sc^3].
KLOBUCHAR_ALPHA_DEFAULT = (4.6566e-09, 1.4901e-08, -5.9605e-08, -1.1921e-07)
KLOBUCHAR_BETA_DEFAULT = (81920.0, 98304.0, -65536.0, -524290.0)


def iono_delay_m(tec_el_m2, freq_hz):
    """First-order group delay I = 40.3 TEC / f^2 [m] (TEC in electrons / m^2)."""
    return IONO_K * tec_el_m2 / freq_hz**2


def tec_from_delay(delay_m, freq_hz):
    """Inverse of :func:`iono_delay_m`: TEC = I f^2 / 40.3 [electrons / m^2]."""
    return delay_m * freq_hz**2 / IONO_K


def _semicircles(x_rad):
    return x_rad / jnp.pi


def klobuchar_vertical_delay_s(
    lat_rad: Float[ArrayLike, "*#S"],
    lon_rad: Float[ArrayLike, "*#S"],
    t_gps_sow: Real[ArrayLike, "*#S"],
    alpha: Float[ArrayLike, "4"] | tuple[float, ...] | None = None,
    beta: Float[ArrayLike, "4"] | tuple[float, ...] | None = None,
) -> Float[Array, "*#S"]:
    """Klobuchar vertical L1 delay [s] at an ionospheric point (IS-GPS-200 20.3.3.5.2.5).

    With phi_m = phi + 0.064 cos(lambda - 1.617) (geomagnetic latitude, semicircles), local time
    t = 4.32e4 lambda + t_GPS (mod 86400), AMP = max(sum alpha_n phi_m^n, 0),
    PER = max(sum beta_n phi_m^n, 72000), x = 2 pi (t - 50400) / PER:
    delay = 5e-9 + AMP (1 - x^2/2 + x^4/24) for |x| < 1.57, else 5e-9.
    """
    alpha = jnp.asarray(KLOBUCHAR_ALPHA_DEFAULT if alpha is None else alpha)
    beta = jnp.asarray(KLOBUCHAR_BETA_DEFAULT if beta is None else beta)
    phi_i = _semicircles(lat_rad)
    lam_i = _semicircles(lon_rad)
    phi_m = phi_i + 0.064 * jnp.cos(jnp.pi * (lam_i - 1.617))
    t_local = jnp.mod(4.32e4 * lam_i + t_gps_sow, 86400.0)
    powers = jnp.stack([jnp.ones_like(phi_m), phi_m, phi_m**2, phi_m**3], axis=-1)
    amp = jnp.maximum(powers @ alpha, 0.0)
    per = jnp.maximum(powers @ beta, 72000.0)
    x = 2.0 * jnp.pi * (t_local - 50400.0) / per
    day = 5e-9 + amp * (1.0 - x**2 / 2.0 + x**4 / 24.0)
    return jnp.where(jnp.abs(x) < 1.57, day, 5e-9)


def klobuchar_delay_s(
    lat_rad: Float[ArrayLike, "*#S"],
    lon_rad: Float[ArrayLike, "*#S"],
    az_rad: Float[ArrayLike, "*#S"],
    el_rad: Float[ArrayLike, "*#S"],
    t_gps_sow: Real[ArrayLike, "*#S"],
    alpha: Float[ArrayLike, "4"] | tuple[float, ...] | None = None,
    beta: Float[ArrayLike, "4"] | tuple[float, ...] | None = None,
) -> Float[Array, "*#S"]:
    """Klobuchar slant L1 (1575.42 MHz) group delay [s] (IS-GPS-200 20.3.3.5.2.5).

    Pierce point (semicircles): psi = 0.0137/(E + 0.11) - 0.022,
    phi_i = clip(phi_u + psi cos A, +-0.416), lambda_i = lambda_u + psi sin A / cos phi_i;
    obliquity F = 1 + 16 (0.53 - E)^3; delay = F * :func:`klobuchar_vertical_delay_s` at
    (phi_i, lambda_i), evaluated at the receiver's GPS seconds of week (mod 86400 inside).
    Multiply by c for metres; scale by (f_L1/f)^2 for another frequency.
    """
    e_sc = _semicircles(el_rad)
    psi = 0.0137 / (e_sc + 0.11) - 0.022
    phi_i = jnp.clip(_semicircles(lat_rad) + psi * jnp.cos(az_rad), -0.416, 0.416)
    lam_i = _semicircles(lon_rad) + psi * jnp.sin(az_rad) / jnp.cos(jnp.pi * phi_i)
    obliquity = 1.0 + 16.0 * (0.53 - e_sc) ** 3
    vertical = klobuchar_vertical_delay_s(
        jnp.pi * phi_i, jnp.pi * lam_i, t_gps_sow, alpha=alpha, beta=beta
    )
    return obliquity * vertical


def ionosphere_pierce_point(
    lat_rad: Float[ArrayLike, "*#S"],
    lon_rad: Float[ArrayLike, "*#S"],
    az_rad: Float[ArrayLike, "*#S"],
    el_rad: Float[ArrayLike, "*#S"],
    shell_height_m: Float[ArrayLike, ""] = IONO_SHELL_HEIGHT_M,
    radius_m: Float[ArrayLike, ""] | None = None,
) -> tuple[Float[Array, "*#S"], Float[Array, "*#S"]]:
    """Thin-shell pierce point (lat, lon) [rad] on a sphere of radius R + H.

    sin z' = R cos E / (R + H); Earth-central angle psi = pi/2 - E - z';
    lat_p = asin(sin lat cos psi + cos lat sin psi cos A);
    lon_p = lon + atan2(sin psi sin A cos lat, cos psi - sin lat sin lat_p).
    """
    r = IONO_EARTH_RADIUS_M if radius_m is None else radius_m
    z_ipp = jnp.arcsin(r * jnp.cos(el_rad) / (r + shell_height_m))
    psi = 0.5 * jnp.pi - el_rad - z_ipp
    sl, cl = jnp.sin(lat_rad), jnp.cos(lat_rad)
    lat_p = jnp.arcsin(sl * jnp.cos(psi) + cl * jnp.sin(psi) * jnp.cos(az_rad))
    lon_p = lon_rad + jnp.arctan2(
        jnp.sin(psi) * jnp.sin(az_rad) * cl, jnp.cos(psi) - sl * jnp.sin(lat_p)
    )
    return lat_p, lon_p


def thin_shell_mapping(
    el_rad: Float[ArrayLike, "*S"],
    shell_height_m: Float[ArrayLike, ""] = IONO_SHELL_HEIGHT_M,
    radius_m: Float[ArrayLike, ""] | None = None,
) -> Float[Array, "*S"]:
    """Single-layer slant/vertical factor M = 1 / sqrt(1 - (R cos E / (R + H))^2) = 1 / cos z'."""
    r = IONO_EARTH_RADIUS_M if radius_m is None else radius_m
    s = r * jnp.cos(el_rad) / (r + shell_height_m)
    return 1.0 / jnp.sqrt(1.0 - s * s)


# ------------------------------------------------------------------------------------------------
# Geometry, Earth rotation, relativity
# ------------------------------------------------------------------------------------------------


def los_enu(
    pos_rcv_ecef: Float[ArrayLike, "3"],
    pos_sat_ecef: Float[ArrayLike, "*S 3"],
    llh_rcv: Float[ArrayLike, "3"] | None = None,
) -> Float[Array, "*S 3"]:
    """Receiver -> satellite vectors in the receiver's ENU frame, shape [..., 3] (unnormalised)."""
    llh = geodesy.ecef_to_llh(pos_rcv_ecef) if llh_rcv is None else llh_rcv
    d = pos_sat_ecef - pos_rcv_ecef
    return d @ geodesy.C_l_e(llh[0], llh[1])  # row-vector form of C_e_l d


def elevation_azimuth(
    pos_rcv_ecef: Float[ArrayLike, "3"],
    pos_sat_ecef: Float[ArrayLike, "*S 3"],
    llh_rcv: Float[ArrayLike, "3"] | None = None,
) -> tuple[Float[Array, "*S"], Float[Array, "*S"]]:
    """Elevation E = asin(u_up) and azimuth A = atan2(u_east, u_north) in [0, 2 pi) [rad].

    ``pos_sat_ecef`` may be [..., 3] for many satellites; ``llh_rcv`` (lat, lon, h) saves the
    ECEF->LLH iteration when already known.
    """
    v = los_enu(pos_rcv_ecef, pos_sat_ecef, llh_rcv)
    rng = jnp.linalg.norm(v, axis=-1)
    el = jnp.arcsin(jnp.clip(v[..., 2] / rng, -1.0, 1.0))
    az = jnp.mod(jnp.arctan2(v[..., 0], v[..., 1]), 2.0 * jnp.pi)
    return el, az


def earth_rotation_correct(
    vec_ecef: Float[ArrayLike, "*S 3"], tau_s: Float[ArrayLike, "*#S"]
) -> Float[Array, "*S 3"]:
    """Express a transmit-time ECEF vector in the receive-time ECEF frame: R3(we tau) v.

    R3(theta) v = [c x + s y, -s x + c y, z], theta = we tau (the Earth turns by theta while the
    signal travels; S000 eq 2.43). Works on positions and velocities, shape [..., 3].
    """
    theta = OMEGA_E * jnp.asarray(tau_s)
    c, s = jnp.cos(theta), jnp.sin(theta)
    x, y, z = vec_ecef[..., 0], vec_ecef[..., 1], vec_ecef[..., 2]
    return jnp.stack([c * x + s * y, -s * x + c * y, z], axis=-1)


def sagnac_range_correction_m(
    pos_rcv_ecef: Float[ArrayLike, "*#S 3"], pos_sat_ecef: Float[ArrayLike, "*#S 3"]
):
    """First-order Sagnac term we (x_s y_r - y_s x_r) / c [m] added to |r_s - r_r| (S000 2.43)."""
    return (
        OMEGA_E
        * (
            pos_sat_ecef[..., 0] * pos_rcv_ecef[..., 1]
            - pos_sat_ecef[..., 1] * pos_rcv_ecef[..., 0]
        )
        / C_LIGHT
    )


def geometric_range_m(
    pos_rcv_ecef: Float[ArrayLike, "*#S 3"],
    pos_sat_tx_ecef: Float[ArrayLike, "*#S 3"],
    n_iter: int = 2,
) -> tuple[Float[Array, "*#S"], Float[Array, "*#S 3"]]:
    """Range |R3(we tau) r_s - r_r| with tau = range / c iterated; returns (range, rotated r_s).

    ``pos_sat_tx_ecef`` is the satellite at transmission in the ECEF frame of that instant (what
    SP3 / broadcast evaluation at t_tx returns). Two iterations reach < 1 um.
    """
    rho = jnp.linalg.norm(pos_sat_tx_ecef - pos_rcv_ecef, axis=-1)
    rot = pos_sat_tx_ecef
    for _ in range(n_iter):
        rot = earth_rotation_correct(pos_sat_tx_ecef, rho / C_LIGHT)
        rho = jnp.linalg.norm(rot - pos_rcv_ecef, axis=-1)
    return rho, rot


def relativistic_clock_s(
    pos_sat_ecef: Float[ArrayLike, "*#S 3"], vel_sat_ecef: Float[ArrayLike, "*#S 3"]
) -> Float[Array, "*#S"]:
    """Periodic relativistic satellite clock term dt_rel = -2 r . v / c^2 [s] (IS-GPS-200).

    Added to the satellite clock of precise products (which exclude it); equals
    F e sqrt(A) sin E_k of :func:`relativistic_clock_kepler_s` for a Keplerian orbit. The ECEF
    r . v equals the inertial one (the Earth-rotation term w x r is orthogonal to r).
    """
    return -2.0 * jnp.sum(pos_sat_ecef * vel_sat_ecef, axis=-1) / C_LIGHT**2


F_REL_S_SQRT_M = -4.442807633e-10  # F = -2 sqrt(mu) / c^2 [s / sqrt(m)] (IS-GPS-200; S000 2.42)


def relativistic_clock_kepler_s(ecc, sqrt_a_sqrt_m, ecc_anomaly_rad):
    """Periodic relativistic term dt_r = F e sqrt(A) sin E_k [s] (S000 eq 2.42, IS-GPS-200)."""
    return F_REL_S_SQRT_M * ecc * sqrt_a_sqrt_m * jnp.sin(ecc_anomaly_rad)
