"""Least-squares receiver velocity from Doppler (gnss/spp.py doppler_velocity)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav import geodesy
from jaxnav.gnss import models
from jaxnav.gnss.spp import doppler_velocity


def _sky(n=8, seed=0):
    """n satellites at 26,560 km around a receiver in Boulder, with circular-orbit speeds."""
    rng = np.random.default_rng(seed)
    llh = np.array([math.radians(40.0), math.radians(-105.0), 1600.0])
    rx = np.asarray(geodesy.llh_to_ecef(jnp.asarray(llh)))
    C_l_e = np.asarray(geodesy.C_l_e(llh[0], llh[1]))
    el = rng.uniform(math.radians(15), math.radians(85), n)
    az = rng.uniform(0, 2 * math.pi, n)
    u_enu = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], 1)
    u = u_enu @ C_l_e.T
    rng_m = 2.2e7
    sat = rx + rng_m * u
    vel = np.cross(rng.normal(size=(n, 3)), sat)
    vel *= 3870.0 / np.linalg.norm(vel, axis=1, keepdims=True)
    return rx, C_l_e, sat, vel


def test_a_known_velocity_and_clock_drift_are_recovered_exactly():
    rx, C_l_e, sat, sat_vel = _sky()
    v_enu = np.array([1.2, -0.7, 0.05])
    v_rx = C_l_e @ v_enu
    drift, sat_drift = -61.3, np.linspace(-0.004, 0.003, sat.shape[0])
    geo = models.geometry(jnp.asarray(rx), jnp.asarray(v_rx), models.SatEpoch(
        jnp.asarray(sat), jnp.asarray(sat_vel), jnp.zeros(sat.shape[0]), jnp.zeros(sat.shape[0])))
    rr = np.asarray(geo.range_rate_m_s) + drift - sat_drift  # u . (v^s - v_r) + c dt_r' - c dt^s'
    out = doppler_velocity(rr[None], jnp.asarray(sat)[None], jnp.asarray(sat_vel)[None],
                           jnp.asarray(sat_drift)[None], jnp.asarray(rx)[None],
                           jnp.ones((1, sat.shape[0]), bool))
    np.testing.assert_allclose(np.asarray(out.vel_ecef[0]), v_rx, atol=2e-3)
    np.testing.assert_allclose(float(out.clock_rate_m_s[0]), drift, atol=2e-3)
    assert bool(out.ok[0])


def test_too_few_satellites_is_not_a_velocity():
    rx, _, sat, sat_vel = _sky(4)
    out = doppler_velocity(np.zeros((1, 4)), jnp.asarray(sat)[None], jnp.asarray(sat_vel)[None],
                           jnp.zeros((1, 4)), jnp.asarray(rx)[None], jnp.ones((1, 4), bool))
    assert not bool(out.ok[0])
