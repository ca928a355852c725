"""Single-point positioning: epoch-wise weighted least squares from corrected pseudoranges
(the a-priori receiver track and clocks real-data PPP starts from, ``io/prepare.py``)."""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.gnss import corrections, models

SPP_MASK_RAD = math.radians(10.0)  # chosen: the filter's default mask (S000 QC)


class SppResult(NamedTuple):
    pos_ecef: jnp.ndarray  # [T, 3]
    clock_m: jnp.ndarray  # [T, n_sys] receiver clock per constellation
    ok: jnp.ndarray  # [T] bool
    n_used: jnp.ndarray  # [T]
    rms_m: jnp.ndarray  # [T] post-fit residual RMS


def spp(
    pr_m,
    sat_pos,
    sat_clock_m,
    usable,
    system,
    n_sys,
    day_of_year,
    x0=None,
    mask_rad=SPP_MASK_RAD,
    iono_l1_m=None,
    iterations=10,
):
    """Epoch-wise weighted least-squares SPP from corrected pseudoranges ([T, S] inputs).

    Model: pr = |R3(we tau) r^s - r| + c dt_sys - c dt^s + T(E) (+ I), with Saastamoinen +
    Niell troposphere once the iterate is within ~200 km of the surface, weights from S001
    eq 11, one clock per constellation (a weak 1e-6 prior keeps absent systems regular).
    Gauss-Newton from ``x0`` (default: the Earth's centre, from which least squares converges).
    """
    T, S = pr_m.shape
    iono = jnp.zeros((T, S)) if iono_l1_m is None else jnp.asarray(iono_l1_m)
    x_init = jnp.zeros(3) if x0 is None else jnp.asarray(x0, dtype=jnp.float64)
    out = _spp_batch(
        jnp.asarray(pr_m),
        sat_pos,
        sat_clock_m,
        jnp.asarray(usable),
        jnp.asarray(system),
        jnp.asarray(day_of_year),
        x_init,
        iono,
        jnp.asarray(mask_rad),
        n_sys=n_sys,
        iterations=iterations,
    )
    return SppResult(*out)


@partial(jax.jit, static_argnames=("n_sys", "iterations"))
def _spp_batch(
    pr_m,
    sat_pos,
    sat_clock_m,
    usable,
    system,
    day_of_year,
    x_init,
    iono,
    mask_rad,
    n_sys,
    iterations,
):
    onehot = (system[:, None] == jnp.arange(n_sys)[None, :]).astype(jnp.float64)  # [S, n_sys]
    prior = jnp.diag(jnp.concatenate([jnp.zeros(3), jnp.full(n_sys, 1e-6)]))

    def one(pr, sp, sc, use, doy, io):
        def body(state, _):
            x, clk = state
            sat = models.SatEpoch(sp, jnp.zeros_like(sp), sc, jnp.zeros_like(sc))
            geo = models.geometry(x, jnp.zeros(3), sat)
            # Troposphere and mask only once the iterate is near the surface (the first steps
            # from the Earth's centre pass through heights where Berg's pressure is undefined).
            r = jnp.linalg.norm(x)
            near = (r > 6.2e6) & (r < 6.6e6)
            llh = geodesy.ecef_to_llh(jnp.where(near, x, jnp.array([6378137.0, 0.0, 0.0])))
            el, _ = models.elevation_azimuth(geo.los_ecef, geodesy.C_l_e(llh[0], llh[1]).T)
            el_c = jnp.maximum(el, math.radians(3.0))
            h_c = jnp.clip(llh[2], -500.0, 9000.0)
            trop = corrections.tropo_slant_delay_m(el_c, llh[0], h_c, doy)
            trop = jnp.where(near, trop, 0.0)
            ok = use & jnp.where(near, el >= mask_rad, True)
            pred = geo.range_m + onehot @ clk - sc + trop + io
            dz = jnp.where(ok, pr - pred, 0.0)
            sig = models.elevation_sigma(1.0, jnp.where(near, el, 1.5))
            w = jnp.where(ok, 1.0 / sig**2, 0.0)
            H = jnp.concatenate([-geo.los_ecef, onehot], axis=1)
            N = H.T @ (H * w[:, None]) + prior
            dx = jnp.linalg.solve(N, H.T @ (w * dz))
            return (x + dx[:3], clk + dx[3:]), (ok, dz)

        (x, clk), (oks, dzs) = jax.lax.scan(body, (x_init, jnp.zeros(n_sys)), None, iterations)
        ok, dz = oks[-1], dzs[-1]
        n = jnp.sum(ok)
        rms = jnp.sqrt(jnp.sum(jnp.where(ok, dz * dz, 0.0)) / jnp.maximum(n, 1))
        n_sys_used = jnp.sum(jnp.any(ok[:, None] & (onehot > 0), axis=0))
        good = (n >= 3 + n_sys_used) & (rms < 30.0) & jnp.all(jnp.isfinite(x))
        return x, clk, good, n, rms

    return jax.vmap(one)(pr_m, sat_pos, sat_clock_m, usable, day_of_year, iono)


def fill_positions(pos, ok):
    """Replace failed epochs by the nearest good one (host numpy)."""
    good = np.flatnonzero(ok)
    if good.size == 0:
        raise ValueError("single-point positioning failed at every epoch (check products/signals)")
    idx = np.arange(pos.shape[0])
    nearest = good[np.clip(np.searchsorted(good, idx), 0, good.size - 1)]
    before = good[np.clip(np.searchsorted(good, idx) - 1, 0, good.size - 1)]
    pick = np.where(np.abs(before - idx) < np.abs(nearest - idx), before, nearest)
    return np.where(ok[:, None], pos, pos[pick])


class DopplerVelocity(NamedTuple):
    vel_ecef: jnp.ndarray  # [T, 3] receiver velocity [m/s]
    clock_rate_m_s: jnp.ndarray  # [T] receiver clock drift c dt_r' [m/s]
    ok: jnp.ndarray  # [T] bool: at least 5 Doppler rows above the mask, post-fit RMS < 1 m/s
    rms_m_s: jnp.ndarray  # [T] post-fit residual RMS


@jax.jit
def doppler_velocity(range_rate_m_s, sat_pos, sat_vel, sat_clock_rate_m_s, rx_pos, usable,
                     mask_rad=SPP_MASK_RAD) -> DopplerVelocity:
    """Epoch-wise least-squares receiver velocity from the range rates -lambda D ([T, S]).

    Model: rr = u . (v^s - v_r) + c dt_r' - c dt^s', u the unit vector receiver -> satellite at
    the (SPP) position ``rx_pos`` [T, 3] and v^s rotated by the Earth's rotation during the
    travel time (``models.geometry``); rows weighted by S001 eq 11's elevation law.
    """

    def one(rr, sp, sv, scr, x, use):
        sat = models.SatEpoch(sp, sv, jnp.zeros_like(scr), scr)
        geo = models.geometry(x, jnp.zeros(3), sat)
        llh = geodesy.ecef_to_llh(x)
        el, _ = models.elevation_azimuth(geo.los_ecef, geodesy.C_l_e(llh[0], llh[1]).T)
        ok = use & (el >= mask_rad) & jnp.isfinite(rr)
        u = geo.los_ecef  # with the satellite velocity rotated as the filter's model does
        y = jnp.where(ok, rr + scr - jnp.sum(u * geo.sat_vel_ecef, axis=1), 0.0)
        H = jnp.concatenate([-u, jnp.ones((u.shape[0], 1))], axis=1)
        w = jnp.where(ok, 1.0 / models.elevation_sigma(1.0, el) ** 2, 0.0)
        N = H.T @ (H * w[:, None]) + 1e-9 * jnp.eye(4)
        sol = jnp.linalg.solve(N, H.T @ (w * y))
        res = jnp.where(ok, y - H @ sol, 0.0)
        n = jnp.sum(ok)
        rms = jnp.sqrt(jnp.sum(res**2) / jnp.maximum(n - 4, 1))
        return sol[:3], sol[3], (n >= 5) & (rms < 1.0), rms

    out = jax.vmap(one)(jnp.asarray(range_rate_m_s), sat_pos, sat_vel, sat_clock_rate_m_s,
                        jnp.asarray(rx_pos), jnp.asarray(usable))
    return DopplerVelocity(*out)
