"""Troposphere, ionosphere, Earth rotation and relativity corrections (jaxnav.gnss.corrections)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (enables float64)
from jaxnav import geodesy
from jaxnav.geodesy import C_LIGHT, OMEGA_E
from jaxnav.gnss import corrections as K


def test_berg_pressure_and_saastamoinen_zhd():
    assert float(K.berg_pressure_hpa(0.0)) == pytest.approx(1013.25)
    # ICAO standard atmosphere: 898.76 hPa at 1000 m, 795.0 hPa at 2000 m
    assert float(K.berg_pressure_hpa(1000.0)) == pytest.approx(898.76, abs=0.3)
    assert float(K.berg_pressure_hpa(2000.0)) == pytest.approx(795.0, abs=0.5)
    # ZHD = 2.2768 mm/hPa * P at 45 deg, sea level: 2.307 m; ~2.3 m everywhere at sea level
    assert float(K.saastamoinen_zhd_m(math.radians(45.0), 0.0)) == pytest.approx(2.3070, abs=1e-4)
    for lat in (0.0, 30.0, 60.0, 90.0):
        assert 2.30 < float(K.saastamoinen_zhd_m(math.radians(lat), 0.0)) < 2.32
    # the hydrostatic delay scales with pressure: about -12 % per km near sea level
    ratio = K.saastamoinen_zhd_m(0.7, 1000.0) / K.saastamoinen_zhd_m(0.7, 0.0)
    assert float(ratio) == pytest.approx(898.76 / 1013.25, abs=2e-3)


def test_zenith_wet_delay_default():
    zwd0 = float(K.saastamoinen_zwd_m(0.0))
    assert 0.05 < zwd0 < 0.15  # mid-latitude wet delays are ~5-30 cm; 50 % RH standard atm.
    assert float(K.saastamoinen_zwd_m(2000.0)) < zwd0
    assert float(K.saastamoinen_zwd_m(0.0, rel_humidity=1.0)) == pytest.approx(2 * zwd0)


def _exponential_atmosphere_mapping(el, scale_height, radius=6371e3):
    """Straight-line slant/zenith ratio through a spherically stratified exp(-h/H) medium."""
    s = np.linspace(0.0, 60.0 * scale_height / max(np.sin(el), 0.05), 200001)
    h = np.sqrt(radius**2 + s**2 + 2.0 * radius * s * np.sin(el)) - radius
    return np.trapezoid(np.exp(-h / scale_height), s) / scale_height


@pytest.mark.parametrize("el_deg", [5.0, 7.0, 10.0, 15.0, 30.0, 60.0])
def test_niell_mapping_matches_exponential_atmosphere(el_deg):
    """Niell vs a physical atmosphere: hydrostatic scale height 8.4 km, wet 2 km."""
    el = math.radians(el_deg)
    m_h, m_w = K.niell_mapping(el, math.radians(45.0), 0.0, 180.0)
    assert float(m_h) == pytest.approx(_exponential_atmosphere_mapping(el, 8.4e3), rel=5e-3)
    assert float(m_w) == pytest.approx(_exponential_atmosphere_mapping(el, 2.0e3), rel=3e-2)
    assert float(m_h) < 1.0 / math.sin(el) + 1e-12  # Earth curvature lowers the flat-Earth value


def test_niell_zenith_unity_and_hemisphere_symmetry():
    for lat in (-80.0, -30.0, 0.0, 20.0, 52.0, 89.0):
        m_h, m_w = K.niell_mapping(math.pi / 2, math.radians(lat), 0.0, 100.0)
        assert float(m_h) == pytest.approx(1.0, abs=1e-12)
        assert float(m_w) == pytest.approx(1.0, abs=1e-12)
    el = math.radians(6.0)
    north = K.niell_mapping(el, math.radians(50.0), 300.0, 20.0)[0]
    south = K.niell_mapping(el, math.radians(-50.0), 300.0, 20.0 + 365.25 / 2)[0]
    assert float(north) == pytest.approx(float(south), rel=1e-12)
    winter = K.niell_mapping(el, math.radians(50.0), 0.0, 28.0)[0]
    summer = K.niell_mapping(el, math.radians(50.0), 0.0, 28.0 + 365.25 / 2)[0]
    assert float(winter) != pytest.approx(float(summer), rel=1e-4)  # seasonal term is active


def test_tropo_slant_delay_total():
    t90 = float(K.tropo_slant_delay_m(math.pi / 2, 0.8, 0.0, 180.0))
    assert t90 == pytest.approx(
        float(K.saastamoinen_zhd_m(0.8, 0.0) + K.saastamoinen_zwd_m(0.0)), rel=1e-12
    )
    t10 = float(K.tropo_slant_delay_m(math.radians(10.0), 0.8, 0.0, 180.0))
    assert 12.0 < t10 < 14.0  # ~2.4 m zenith x ~5.5


def test_klobuchar_night_and_day_values():
    alpha = (1.0e-8, 0.0, 0.0, 0.0)  # AMP = 10 ns everywhere
    beta = (86400.0, 0.0, 0.0, 0.0)  # PER = 1 day
    # vertical delay at the pierce point, local time 14:00 -> 5 ns + AMP; at 02:00 -> 5 ns
    day = K.klobuchar_vertical_delay_s(0.0, 0.0, 50400.0, alpha, beta)
    night = K.klobuchar_vertical_delay_s(0.0, 0.0, 7200.0, alpha, beta)
    assert float(day) == pytest.approx(15e-9, rel=1e-12)
    assert float(night) == pytest.approx(5e-9, rel=1e-12)
    # local time = 4.32e4 * lon[semicircles] + GPS time: 90 deg east at 08:00 GPS is 14:00 local
    east = K.klobuchar_vertical_delay_s(0.0, math.pi / 2, 50400.0 - 21600.0, alpha, beta)
    assert float(east) == pytest.approx(15e-9, rel=1e-12)
    # slant at zenith = obliquity (1 + 16 (0.53 - 0.5)^3) x vertical at the receiver
    z = K.klobuchar_delay_s(0.0, 0.0, 0.0, math.pi / 2, 50400.0, alpha, beta)
    assert float(z) == pytest.approx(15e-9 * (1 + 16 * 0.03**3), rel=1e-12)
    # metres at L1: 5 ns = 1.499 m
    assert float(C_LIGHT * night) == pytest.approx(1.499, abs=1e-3)


@pytest.mark.parametrize("el_deg", [5.0, 10.0, 20.0, 30.0, 60.0, 90.0])
def test_klobuchar_obliquity_approximates_thin_shell(el_deg):
    """IS-GPS-200's F = 1 + 16 (0.53 - E)^3 approximates the 350 km single-layer factor."""
    el = math.radians(el_deg)
    night = 5e-9
    f = float(K.klobuchar_delay_s(0.3, 0.2, 1.0, el, 7200.0)) / night  # night: vertical = 5 ns
    assert f == pytest.approx(float(K.thin_shell_mapping(el, 350e3)), rel=0.035)


def test_pierce_point_geometry():
    lat, lon = math.radians(45.0), math.radians(10.0)
    p = K.ionosphere_pierce_point(lat, lon, 1.0, math.pi / 2)
    assert float(p[0]) == pytest.approx(lat, abs=1e-12) and float(p[1]) == pytest.approx(lon)
    # north at 30 deg elevation: central angle psi = 60 deg - asin(R cos30 / (R + H)) in latitude
    r, h = K.IONO_EARTH_RADIUS_M, K.IONO_SHELL_HEIGHT_M
    el = math.radians(30.0)
    psi = math.pi / 2 - el - math.asin(r * math.cos(el) / (r + h))
    p = K.ionosphere_pierce_point(lat, lon, 0.0, el)
    assert float(p[0]) == pytest.approx(lat + psi, abs=1e-12)
    assert float(p[1]) == pytest.approx(lon, abs=1e-12)
    # the pierce point is on the shell along the line of sight: check in Cartesian (sphere)
    az = math.radians(123.0)
    plat, plon = (float(x) for x in K.ionosphere_pierce_point(lat, lon, az, el))
    rcv = r * np.array(
        [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]
    )
    ipp = (r + h) * np.array(
        [math.cos(plat) * math.cos(plon), math.cos(plat) * math.sin(plon), math.sin(plat)]
    )
    up = rcv / r
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    north = np.cross(up, east)
    los = (ipp - rcv) / np.linalg.norm(ipp - rcv)
    expected = math.cos(el) * (math.sin(az) * east + math.cos(az) * north) + math.sin(el) * up
    np.testing.assert_allclose(los, expected, atol=1e-9)


def test_tec_delay_conversion():
    f_l1 = 1575.42e6
    assert float(K.iono_delay_m(K.TECU, f_l1)) == pytest.approx(0.16237, abs=1e-5)
    assert float(K.tec_from_delay(K.iono_delay_m(3.0e17, f_l1), f_l1)) == pytest.approx(3.0e17)


def test_elevation_azimuth_cardinal_directions():
    llh = jnp.array([math.radians(40.0), math.radians(-75.0), 50.0])
    r = geodesy.llh_to_ecef(llh)
    C = geodesy.C_l_e(llh[0], llh[1])
    d = 2.0e7
    sats = jnp.stack(
        [
            r + d * C[:, 2],  # up
            r + d * (C[:, 1] * math.cos(0.5) + C[:, 2] * math.sin(0.5)),  # north, 0.5 rad up
            r + d * (C[:, 0] * math.cos(0.2) + C[:, 2] * math.sin(0.2)),  # east, 0.2 rad up
            r + d * (-C[:, 0] * math.cos(0.1) + C[:, 2] * math.sin(0.1)),  # west
        ]
    )
    el, az = K.elevation_azimuth(r, sats)
    np.testing.assert_allclose(np.asarray(el), [math.pi / 2, 0.5, 0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(np.asarray(az)[1:], [0.0, math.pi / 2, 1.5 * math.pi], atol=1e-12)


def test_earth_rotation_and_sagnac_closed_form():
    """|R3(we tau) r_s - r_r| - |r_s - r_r| equals we (x_s y_r - y_s x_r) / c to < 1 mm."""
    rng = np.random.default_rng(3)
    rcv = geodesy.llh_to_ecef(jnp.array([0.3, 1.2, 100.0]))
    for _ in range(20):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        if u @ np.asarray(rcv) < 0:
            u = -u
        sat = jnp.asarray(u * 2.656e7)
        rho, rot = K.geometric_range_m(rcv, sat)
        # the rotated position is consistent with the travel time it implies
        np.testing.assert_allclose(
            np.asarray(rot), np.asarray(K.earth_rotation_correct(sat, rho / C_LIGHT)), atol=1e-6
        )
        flat = float(jnp.linalg.norm(sat - rcv))
        assert float(rho) - flat == pytest.approx(
            float(K.sagnac_range_correction_m(rcv, sat)), abs=1e-3
        )
    # magnitude bound: we |r_s| |r_r| / c ~ 41 m
    assert OMEGA_E * 2.656e7 * 6.378e6 / C_LIGHT == pytest.approx(41.2, abs=0.5)


def _rotation(a, b, c):
    """R3(a) R1(b) R3(c): an arbitrary proper rotation."""

    def r3(x):
        return np.array([[math.cos(x), -math.sin(x), 0], [math.sin(x), math.cos(x), 0], [0, 0, 1]])

    r1 = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    return r3(a) @ r1 @ r3(c)


def test_relativistic_clock_matches_kepler_form():
    """-2 r.v/c^2 == F e sqrt(A) sin E for a Keplerian orbit (IS-GPS-200, S000 eq 2.42)."""
    gm = 3.986005e14
    a, e = 26560e3, 0.02
    n = math.sqrt(gm / a**3)
    for ecc_anom in np.linspace(0.0, 2 * math.pi, 13):
        # perifocal position and velocity, then an arbitrary rotation (r.v is invariant)
        r = a * np.array([math.cos(ecc_anom) - e, math.sqrt(1 - e * e) * math.sin(ecc_anom), 0.0])
        edot = n / (1 - e * math.cos(ecc_anom))
        v = a * edot * np.array([-math.sin(ecc_anom), math.sqrt(1 - e * e) * math.cos(ecc_anom), 0])
        rot = _rotation(0.3, 0.9, 1.7)
        dt = float(K.relativistic_clock_s(jnp.asarray(rot @ r), jnp.asarray(rot @ v)))
        ref = float(K.relativistic_clock_kepler_s(e, math.sqrt(a), ecc_anom))
        assert dt == pytest.approx(ref, rel=1e-6, abs=1e-15)
    assert abs(K.F_REL_S_SQRT_M * 0.02 * math.sqrt(a)) * C_LIGHT == pytest.approx(13.7, abs=0.2)


def test_corrections_are_differentiable():
    g = jax.grad(lambda el: K.niell_mapping(el, 0.8, 100.0, 50.0)[0])(0.3)
    assert np.isfinite(float(g)) and float(g) < 0.0
    g = jax.grad(lambda el: K.klobuchar_delay_s(0.8, 0.1, 1.0, el, 40000.0))(0.3)
    assert np.isfinite(float(g)) and float(g) < 0.0
