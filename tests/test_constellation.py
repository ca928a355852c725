"""Satellite geometry: nominal constellations, broadcast ephemerides, visibility and slots."""

import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (enables float64)
from jaxnav import geodesy
from jaxnav.core import gpstime
from jaxnav.geodesy import OMEGA_E
from jaxnav.gnss import signals
from jaxnav.io import read_broadcast_ephemeris
from jaxnav.sim import constellation as C

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "esbc_static"
NAV = DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"
SP3 = DATA / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"
SIDEREAL_DAY_S = 86164.0905
ESBC_ECEF = np.array([3582105.2910, 532589.7313, 5232754.8054])  # RINEX header APPROX POSITION


def _inertial(pos_ecef, t):
    """Undo the Earth rotation of the ECEF frame: r_i = R3(-we t) r_e."""
    c, s = np.cos(OMEGA_E * t), np.sin(OMEGA_E * t)
    x, y = pos_ecef[..., 0], pos_ecef[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, pos_ecef[..., 2]], axis=-1)


@pytest.mark.parametrize(
    "maker, a_m",
    [(C.nominal_gps, 26559.7e3), (C.nominal_glonass, 25510e3), (C.nominal_galileo, 29600e3)],
)
def test_nominal_orbit_radius_and_period(maker, a_m):
    orb = maker()
    t = np.linspace(0.0, 2 * 86400.0, 4001)
    pos = np.asarray(jax.vmap(lambda tt: C.satellite_state(orb, tt).pos_ecef)(jnp.asarray(t)))
    np.testing.assert_allclose(np.linalg.norm(pos, axis=-1), a_m, rtol=1e-12)
    # inertial angle swept per second = mean motion; period from the motion itself
    r_i = _inertial(pos[:, 0], t)
    normal = np.cross(r_i[0], r_i[1])
    normal /= np.linalg.norm(normal)
    ang = np.unwrap(np.arctan2(np.cross(r_i[0], r_i) @ normal, r_i @ r_i[0]))
    period = 2 * math.pi * t[-1] / ang[-1]
    assert period == pytest.approx(2 * math.pi * math.sqrt(a_m**3 / float(orb.gm[0])), rel=1e-9)
    if maker is C.nominal_gps:
        # GPS: half a sidereal day (ground track repeats daily), 43077 s vs 43082 s
        assert period == pytest.approx(SIDEREAL_DAY_S / 2, rel=3e-4)


def test_velocity_is_derivative_of_position():
    orb = C.nominal_constellation()
    t0, h = 1234.5, 0.5
    st = C.satellite_state(orb, t0)
    fd = (C.satellite_state(orb, t0 + h).pos_ecef - C.satellite_state(orb, t0 - h).pos_ecef) / (
        2 * h
    )
    np.testing.assert_allclose(np.asarray(st.vel_ecef), np.asarray(fd), atol=1e-4)
    speed_inertial = np.linalg.norm(
        np.asarray(st.vel_ecef) + np.cross([0, 0, OMEGA_E], np.asarray(st.pos_ecef)), axis=-1
    )
    np.testing.assert_allclose(
        speed_inertial, np.sqrt(np.asarray(orb.gm) / np.asarray(orb.a_m)), rtol=1e-10
    )


def test_glonass_channel_sharing_satellites_are_antipodal():
    orb = C.nominal_glonass()
    pos = np.asarray(C.satellite_state(orb, 5000.0).pos_ecef)
    ch = np.asarray(orb.glo_channel)
    assert ch.min() >= signals.GLO_CHANNEL_MIN and ch.max() <= signals.GLO_CHANNEL_MAX
    for k in np.unique(ch):
        i, j = np.flatnonzero(ch == k)
        cosang = pos[i] @ pos[j] / (np.linalg.norm(pos[i]) * np.linalg.norm(pos[j]))
        assert cosang == pytest.approx(-1.0, abs=1e-12)


def _cap_fraction(radius_sat, mask_rad, r_earth=6371e3):
    """Fraction of a satellite shell seen above ``mask`` from a point of a sphere (closed form)."""
    psi = math.pi / 2 - mask_rad - math.asin(r_earth * math.cos(mask_rad) / radius_sat)
    return (1 - math.cos(psi)) / 2


def test_mean_satellites_in_view_matches_spherical_cap():
    """Averaged over uniform random sites, E[#visible] = N x cap fraction (any constellation)."""
    orb = C.nominal_constellation()
    rng = np.random.default_rng(7)
    n_site = 400
    z = rng.uniform(-1, 1, n_site)
    lon = rng.uniform(-math.pi, math.pi, n_site)
    lat = np.arcsin(z)  # uniform on the sphere (geocentric ~ geodetic to 0.2 deg)
    llh = jnp.stack([jnp.asarray(lat), jnp.asarray(lon), jnp.zeros(n_site)], axis=-1)
    pos = jax.vmap(geodesy.llh_to_ecef)(llh)
    times = jnp.asarray(rng.uniform(0, 86400, n_site))
    el, _ = C.elevations(orb, times, pos)
    vis = np.asarray(C.visible(el, math.radians(10.0)))
    system = np.asarray(orb.system)
    for s, a in (
        (signals.SYS_GPS, C.GPS_A_M),
        (signals.SYS_GLO, C.GLO_A_M),
        (signals.SYS_GAL, C.GAL_A_M),
    ):  # noqa: E501
        expected = 24 * _cap_fraction(a, math.radians(10.0))
        mean = vis[:, system == s].sum(axis=1).mean()
        assert mean == pytest.approx(expected, rel=0.05), (s, mean, expected)


def test_mid_latitude_gps_counts():
    """45 N over a day: the 24-slot GPS plan keeps 5-11 satellites above 10 deg (mean ~7.2)."""
    orb = C.nominal_gps()
    t = jnp.arange(0.0, 86400.0, 60.0)
    r = geodesy.llh_to_ecef(jnp.array([math.radians(45.0), math.radians(7.0), 200.0]))
    el, _ = C.elevations(orb, t, jnp.tile(r, (t.size, 1)))
    n = np.asarray(C.visible(el)).sum(axis=1)
    assert n.min() >= 4 and n.max() <= 12
    assert 6.5 < n.mean() < 8.5


def test_build_slots_keeps_every_visible_satellite():
    orb = C.nominal_constellation()
    t = jnp.arange(0.0, 3600.0, 30.0)
    r = geodesy.llh_to_ecef(jnp.array([math.radians(52.0), math.radians(4.0), 0.0]))
    pos = jnp.tile(r, (t.size, 1))
    slots = C.build_slots(orb, t, pos)
    assert slots.n_slots == sum(signals.DEFAULT_SLOTS_PER_SYSTEM)
    el, _ = C.elevations(orb, t, pos)
    ever = np.flatnonzero(np.any(np.asarray(el) >= C.DEFAULT_ELEVATION_MASK_RAD, axis=0))
    occ = np.asarray(slots.occupied)
    assert sorted(np.asarray(slots.sat_index)[occ].tolist()) == sorted(ever.tolist())
    sys_slots = np.asarray(slots.system)
    assert np.all(np.diff(sys_slots) >= 0)  # GPS, then GLONASS, then Galileo
    for s in range(3):  # PRN order inside a system
        prn = np.asarray(slots.prn)[(sys_slots == s) & occ]
        assert np.all(np.diff(prn) > 0)
    with pytest.raises(ValueError):
        C.build_slots(orb, t, pos, slots_per_system=(3, 14, 14))


def test_time_helpers():
    assert C.DEFAULT_T0_GPS_S == 2111 * 604800 + 345600  # 2020-06-25 = GPS week 2111, Thursday
    assert float(gpstime.gps_seconds_of_week(C.DEFAULT_T0_GPS_S)) == 345600.0
    # file name ..._20201770000
    assert gpstime.day_of_year(C.DEFAULT_T0_GPS_S) == pytest.approx(177.0)


# ------------------------------------------------------------------------------------------------
# Real broadcast ephemerides vs precise orbits (shared ESBC data)
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nav():
    if not NAV.exists():
        pytest.skip(f"shared data not present: {NAV} (tests on real data need ../shared/data)")
    return read_broadcast_ephemeris(NAV)


@pytest.fixture(scope="module")
def sp3():
    if not SP3.exists():
        pytest.skip(f"shared data not present: {SP3}")
    import georinex

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return georinex.load(SP3)


def test_read_rinex_nav_contents(nav):
    system = np.asarray(nav.system)
    assert (system == signals.SYS_GPS).sum() == 31
    assert (system == signals.SYS_GLO).sum() == 23
    assert (system == signals.SYS_GAL).sum() == 24
    # the blank-spare-field work-around keeps the Galileo records (georinex alone loses them)
    gal_valid = np.asarray(nav.kepler.valid)[system == signals.SYS_GAL].sum()
    assert gal_valid > 300
    # broadcast GLONASS channels = the nominal channel plan
    glo = system == signals.SYS_GLO
    prn = np.asarray(nav.prn)[glo]
    np.testing.assert_array_equal(
        np.asarray(nav.glo_channel)[glo], np.asarray(C.GLONASS_CHANNELS)[prn - 1]
    )
    np.testing.assert_allclose(np.asarray(nav.iono_alpha)[0], 4.6566e-09)


def test_broadcast_orbits_match_precise_orbits(nav, sp3):
    """Broadcast vs GRG final SP3 at the SP3 epochs: metre level (3D RMS, max)."""
    t = np.array([gpstime.gps_seconds(x) for x in sp3.time.values]) - float(nav.t_ref_gps_s)
    states = jax.jit(jax.vmap(lambda tt: C.satellite_state(nav, tt)))(jnp.asarray(t))
    letters = {0: "G", 1: "R", 2: "E"}
    names = [f"{letters[int(s)]}{int(p):02d}" for s, p in zip(nav.system, nav.prn, strict=True)]
    err = {0: [], 1: [], 2: []}
    clk = {0: [], 1: [], 2: []}
    for i, name in enumerate(names):
        if name not in sp3.sv.values:
            continue
        ref = sp3.position.sel(sv=name).values * 1e3
        ok = np.asarray(states.ok[:, i]) & np.all(np.isfinite(ref), axis=1)
        d = np.linalg.norm(np.asarray(states.pos_ecef[:, i]) - ref, axis=1)[ok]
        err[int(nav.system[i])].extend(d.tolist())
        ref_clk = sp3.clock.sel(sv=name).values * 1e-6
        good = ok & np.isfinite(ref_clk) & (np.abs(ref_clk) < 0.9)
        dc = (np.asarray(states.clock_s[:, i]) - ref_clk)[good] * 299792458.0
        clk[int(nav.system[i])].extend(dc.tolist())
    limits = {0: (2.5, 6.0), 1: (5.0, 12.0), 2: (2.0, 6.0)}  # (RMS, max) m
    for s, (rms_max, max_max) in limits.items():
        d = np.array(err[s])
        assert d.size > 500
        rms = math.sqrt(np.mean(d**2))
        assert rms < rms_max and d.max() < max_max, (s, rms, d.max())
    for s, lim in ((0, 1.5), (2, 1.0)):  # GPS / Galileo F/NAV clocks vs precise, RMS m
        c = np.array(clk[s])
        assert math.sqrt(np.mean(c**2)) < lim


def test_broadcast_satellites_in_view_at_esbc(nav):
    """Real 31-satellite GPS constellation at ESBC (55.5 N): 8-12 satellites above 10 deg."""
    t = jnp.arange(86400.0, 2 * 86400.0, 300.0)  # 2020-06-25 on the source time axis
    el, _ = C.elevations(
        nav, t, jnp.tile(jnp.asarray(ESBC_ECEF), (t.size, 1)), t0_gps_s=float(nav.t_ref_gps_s)
    )  # noqa: E501
    gps = np.asarray(nav.system) == signals.SYS_GPS
    n = np.asarray(C.visible(el))[:, gps].sum(axis=1)
    assert 8.0 <= n.mean() <= 12.0
    assert n.min() >= 5
