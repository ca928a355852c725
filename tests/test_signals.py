"""Frequencies, wavelengths, combination coefficients and fixed slots (jaxnav.gnss.signals)."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxnav  # noqa: F401  (enables float64)
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import signals as S


def test_gps_galileo_frequencies_and_wavelengths():
    f = np.asarray(S.carrier_frequency_hz(jnp.array([0, 0, 0, 2, 2, 2]), jnp.array([0, 1, 2] * 2)))
    np.testing.assert_allclose(
        f, [1575.42e6, 1227.60e6, 1176.45e6, 1575.42e6, 1176.45e6, 1207.14e6]
    )
    lam = np.asarray(S.wavelength_m(f[:2]))
    np.testing.assert_allclose(lam, [0.190293673, 0.244210213], rtol=1e-8)


@pytest.mark.parametrize("k", list(range(S.GLO_CHANNEL_MIN, S.GLO_CHANNEL_MAX + 1)))
def test_glonass_fdma_channels(k):
    f1 = float(S.carrier_frequency_hz(S.SYS_GLO, 0, k))
    f2 = float(S.carrier_frequency_hz(S.SYS_GLO, 1, k))
    assert f1 == pytest.approx(1602e6 + k * 0.5625e6, abs=1e-3)
    assert f2 == pytest.approx(1246e6 + k * 0.4375e6, abs=1e-3)
    assert f1 / f2 == pytest.approx(9.0 / 7.0, rel=1e-14)  # same ratio for every channel


def test_ionosphere_free_coefficients_gps():
    f1, f2 = S.BAND_BASE_HZ[0, 0], S.BAND_BASE_HZ[0, 1]
    a, b = S.if_coefficients(f1, f2)
    assert float(a) == pytest.approx(2.5457, abs=1e-4)  # SEED_SPEC 4 S000-10: 2.546 not 2.54
    assert float(b) == pytest.approx(-1.5457, abs=1e-4)
    assert float(a + b) == pytest.approx(1.0, abs=1e-14)  # geometry preserved
    # first-order ionosphere I_j = (f1/fj)^2 I_1 cancels
    assert float(a * 1.0 + b * S.iono_scale(f1, f2)) == pytest.approx(0.0, abs=1e-14)
    # noise ~3x a raw observable (SEED_SPEC 2.3)
    assert float(S.combination_noise_factor(a, b)) == pytest.approx(2.978, abs=1e-3)


def test_combination_wavelengths():
    f1, f2 = S.BAND_BASE_HZ[0, 0], S.BAND_BASE_HZ[0, 1]
    assert float(S.wl_wavelength_m(f1, f2)) == pytest.approx(0.862, abs=1e-3)  # 86.2 cm
    assert float(S.nl_wavelength_m(f1, f2)) == pytest.approx(0.107, abs=1e-3)  # 10.7 cm
    i1, i2 = S.if_integers(*S.BAND_MULTIPLIER[0, :2])
    assert (i1, i2) == (77, 60)
    assert float(S.if_wavelength_m(f1, f2, i1, i2)) == pytest.approx(0.0063, abs=5e-5)  # 6.3 mm
    g1 = float(S.carrier_frequency_hz(S.SYS_GLO, 0, 0))
    g2 = float(S.carrier_frequency_hz(S.SYS_GLO, 1, 0))
    assert S.if_integers(9, 7) == (9, 7)
    assert float(S.if_wavelength_m(g1, g2, 9, 7)) == pytest.approx(0.053, abs=5e-4)  # 5.3 cm


@settings(max_examples=60, deadline=None)
@given(
    st.integers(-(10**6), 10**6),
    st.integers(-(10**6), 10**6),
    st.sampled_from([0, 1, 2]),
    st.integers(-7, 6),
)
def test_if_ambiguity_is_integer_multiple_of_lambda_if(n1, n2, system, k):
    """alpha lambda1 N1 + beta lambda2 N2 == lambda_IF (i1 N1 - i2 N2) for integers N1, N2."""
    k = k if system == S.SYS_GLO else 0
    f1 = float(S.carrier_frequency_hz(system, 0, k))
    f2 = float(S.carrier_frequency_hz(system, 1, k))
    a, b = S.if_coefficients(f1, f2)
    i1, i2 = S.if_integers(*S.BAND_MULTIPLIER[system, :2])
    lhs = a * C_LIGHT / f1 * n1 + b * C_LIGHT / f2 * n2
    rhs = S.if_wavelength_m(f1, f2, i1, i2) * (i1 * n1 - i2 * n2)
    assert float(lhs) == pytest.approx(float(rhs), abs=1e-6 * (1 + abs(float(rhs))))


def test_melbourne_wubbena_removes_geometry_and_ionosphere():
    f1, f2 = S.BAND_BASE_HZ[0, 0], S.BAND_BASE_HZ[0, 1]
    lam1, lam2 = C_LIGHT / f1, C_LIGHT / f2
    rng = np.random.default_rng(0)
    geom = rng.uniform(2e7, 2.6e7, 50)  # range + clocks + troposphere
    i1 = rng.uniform(0.5, 30.0, 50)
    i2 = i1 * (f1 / f2) ** 2
    n1 = rng.integers(-1000, 1000, 50)
    n2 = rng.integers(-1000, 1000, 50)
    p1, p2 = geom + i1, geom + i2
    l1, l2 = geom - i1 + lam1 * n1, geom - i2 + lam2 * n2
    mw = np.asarray(S.melbourne_wubbena_m(l1, l2, p1, p2, f1, f2))
    np.testing.assert_allclose(mw, S.wl_wavelength_m(f1, f2) * (n1 - n2), atol=1e-6)
    gf = np.asarray(S.gf_combination(l1, l2))
    np.testing.assert_allclose(gf, -(i1 - i2) + lam1 * n1 - lam2 * n2, atol=1e-6)
    iff = np.asarray(S.if_combination(p1, p2, f1, f2))
    np.testing.assert_allclose(iff, geom, atol=1e-6)


def test_assign_slots_orders_pads_and_overflows():
    system = np.array([0, 0, 0, 1, 1, 2, 0])
    prn = np.array([7, 2, 30, 5, 3, 11, 1])
    chan = np.array([0, 0, 0, -4, 5, 0, 0])
    ever = np.array([True, True, False, True, True, True, True])
    slots = S.assign_slots(system, prn, chan, ever, slots_per_system=(4, 3, 2))
    assert slots.n_slots == 9
    assert S.slot_labels(slots) == ["G01", "G02", "G07", "---", "R03", "R05", "---", "E11", "---"]
    np.testing.assert_array_equal(
        np.asarray(slots.sat_index)[[0, 1, 2, 4, 5, 7]], [6, 1, 0, 4, 3, 5]
    )
    np.testing.assert_array_equal(np.asarray(slots.glo_channel)[4:6], [5, -4])
    assert not bool(slots.occupied[3]) and not bool(slots.occupied[8])
    with pytest.raises(ValueError, match="increase slots_per_system"):
        S.assign_slots(system, prn, chan, ever, slots_per_system=(2, 3, 2))


def test_slot_if_wavelength_is_per_satellite_for_glonass():
    slots = S.assign_slots(
        np.array([0, 1, 1, 2]), np.array([1, 1, 2, 1]), np.array([0, -7, 6, 0]),
        np.ones(4, bool), slots_per_system=(1, 2, 1),
    )  # fmt: skip
    lam_if = np.asarray(S.slot_if_wavelength_m(slots))
    assert lam_if[0] == pytest.approx(0.0063, abs=5e-5)
    assert lam_if[1] != pytest.approx(lam_if[2], rel=1e-4)  # FDMA: differs by channel
    assert lam_if[1] == pytest.approx(0.0532, abs=5e-4)
    assert lam_if[3] == pytest.approx(0.0028, abs=5e-5)  # Galileo E1/E5a
