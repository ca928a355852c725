"""WGS-84 model against published values and exact round trips."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav import geodesy as g


def test_wgs84_derived_constants():
    assert g.E2_WGS84 == pytest.approx(0.00669437999014, abs=1e-14)
    assert g.B_WGS84 == pytest.approx(6356752.3142, abs=1e-4)


def test_normal_gravity_published_values():
    # WGS-84 normal gravity on the ellipsoid: equator 9.7803253359, pole 9.8321849378 (TR8350.2);
    # the polynomial of SEED_SPEC 1.1 reproduces them to ~1e-6 m/s^2.
    assert float(g.normal_gravity(0.0, 0.0)) == pytest.approx(9.7803253359, abs=2e-6)
    assert float(g.normal_gravity(np.pi / 2, 0.0)) == pytest.approx(9.8321849378, abs=2e-6)
    # Free-air gradient about -3.086e-6 s^-2.
    grad = (g.normal_gravity(0.8, 1000.0) - g.normal_gravity(0.8, 0.0)) / 1000.0
    assert float(grad) == pytest.approx(-3.086e-6, rel=2e-3)


def test_radii_published_values():
    r_m, r_n = g.radii(0.0)
    assert float(r_n) == pytest.approx(6378137.0, abs=1e-6)
    assert float(r_m) == pytest.approx(6335439.327, abs=1e-3)
    r_m, r_n = g.radii(np.pi / 2)
    assert float(r_m) == pytest.approx(float(r_n), abs=1e-6)  # polar radius of curvature
    assert float(r_n) == pytest.approx(6399593.626, abs=1e-3)


def test_known_ecef_point():
    # ESBC00DNK header APPROX position and its geodetic coordinates (computed independently with
    # the closed-form Heikkinen solution): lat 55.4948 deg, lon 8.4569 deg.
    xyz = jnp.array([3582105.2910, 532589.7313, 5232754.8054])
    lat, lon, h = g.ecef_to_llh(xyz)
    assert np.degrees(float(lon)) == pytest.approx(
        np.degrees(np.arctan2(532589.7313, 3582105.2910))
    )
    assert 55.0 < np.degrees(float(lat)) < 56.0
    assert 0.0 < float(h) < 100.0
    np.testing.assert_allclose(g.llh_to_ecef(jnp.stack([lat, lon, h])), xyz, atol=5e-9)


def test_llh_ecef_round_trip_everywhere():
    rng = np.random.default_rng(0)
    n = 20000
    llh = jnp.array(
        np.c_[
            rng.uniform(-np.pi / 2, np.pi / 2, n),
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(-500.0, 1e4, n),
        ]
    )
    llh = llh.at[:4, 0].set(jnp.array([np.pi / 2, -np.pi / 2, 0.0, 1e-12]))
    back = jax.vmap(g.ecef_to_llh)(jax.vmap(g.llh_to_ecef)(llh))
    err = np.abs(np.asarray(back - llh))
    # Angles to 1e-15 rad (6 nm). Height to 5e-9 m: one float64 ulp of an ECEF coordinate near
    # the surface is 0.93e-9 m, so "< 1e-9 m" is below the representation itself; we accept a few
    # ulp. Away from the poles longitude is exact.
    assert err[:, 0].max() < 1e-15
    assert err[4:, 1].max() < 1e-15
    assert err[:, 2].max() < 5e-9
    # Orbit altitudes: still within a few ulp of 2.6e7 m (3.7e-9 m).
    llh_sat = llh.at[:, 2].set(jnp.array(rng.uniform(1.9e7, 2.4e7, n)))
    back = jax.vmap(g.ecef_to_llh)(jax.vmap(g.llh_to_ecef)(llh_sat))
    assert np.abs(np.asarray(back - llh_sat))[:, 2].max() < 4e-8


def test_enu_rotation_orthonormal_and_axes():
    llh = jnp.array([0.9, -1.2, 50.0])
    C = g.C_l_e(llh[0], llh[1])
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-15)
    assert float(jnp.linalg.det(C)) == pytest.approx(1.0)
    # Up is the ellipsoid normal: a small height step moves ECEF along C[:, 2].
    d = g.llh_to_ecef(llh.at[2].add(1.0)) - g.llh_to_ecef(llh)
    np.testing.assert_allclose(d, C[:, 2], atol=1e-9)
    v = jnp.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(g.ecef_to_enu(g.enu_to_ecef(v, llh), llh), v, atol=1e-15)


def test_jacobians_match_autodiff():
    llh = jnp.array([0.7, 0.3, 2500.0])
    J = jax.jacfwd(g.llh_to_ecef)(llh)
    L = g.llh_to_ecef_jacobian(llh)
    # Exact, including dR_N/dlat (S000 eq 4.66's R_N + h in the latitude column is 0.5 % off).
    np.testing.assert_allclose(L, J, rtol=1e-12, atol=1e-6)
    # D^-1 maps ENU velocity to geodetic rates: compare with the ECEF velocity route.
    v_enu = jnp.array([12.0, -7.0, 0.4])
    rates = g.llh_rate_matrix(llh) @ v_enu
    np.testing.assert_allclose(J @ rates, g.enu_to_ecef(v_enu, llh), rtol=1e-12)


def test_earth_and_transport_rates():
    lat = 0.8
    w = g.earth_rate_enu(lat)
    assert float(jnp.linalg.norm(w)) == pytest.approx(g.OMEGA_E)
    # The Earth rate expressed in ECEF is along +z.
    np.testing.assert_allclose(g.C_l_e(lat, 0.4) @ w, [0, 0, g.OMEGA_E], atol=1e-19)
    llh = jnp.array([lat, 0.0, 0.0])
    r_m, r_n = g.radii(lat)
    # Driving north at v, the l-frame turns about east by -v/R_M.
    w_el = g.transport_rate_enu(llh, jnp.array([0.0, 20.0, 0.0]))
    np.testing.assert_allclose(w_el, [-20.0 / r_m, 0.0, 0.0])
