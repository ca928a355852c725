"""Satellite states at signal transmission for every epoch and slot ([T, S], pure JAX).

t_sv = t_rx - P/c is the satellite-clock reading at transmission, t_tx = t_sv - dt^s(t_sv);
the orbit is evaluated at t_tx and dt^s again at t_tx (the receiver clock never enters: P/c
already contains it). Precise: SP3 Lagrange interpolation and RINEX-clock (or SP3-clock) linear
interpolation (``gnss/interp.py``); broadcast: IS-GPS-200 / GLONASS ICD (``gnss/ephemeris.py``).
The clock carries the periodic relativistic term -2 r.v / c^2 (IS-GPS-200; the GLONASS
broadcast clock already contains it); its rate is the time derivative of the same interpolant.
Earth rotation during the travel time is left to the filter's geometry (``gnss/models.py``).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import corrections, ephemeris, signals
from jaxnav.gnss.interp import ClockInterp, GridTable, clock_bias, sp3_position_velocity


def sub_grid(table: GridTable, cols) -> GridTable:
    """The table of the satellites in ``cols`` (one column per slot, in slot order)."""
    return GridTable(table.t0_gps_s, table.dt_s, table.values[:, cols], table.present[:, cols])


def _sp3_slots(table: GridTable, t, n_points, one_sided):
    """Position, velocity, valid of slot s at times t[:, s] ([T, S]); table columns = slots."""

    def one_slot(values_s, present_s, t_s):
        tab = GridTable(table.t0_gps_s, table.dt_s, values_s[:, None, :], present_s[:, None])
        p, v, ok = jax.vmap(lambda tt: sp3_position_velocity(tab, tt, n_points, one_sided))(t_s)
        return p[:, 0], v[:, 0], ok[:, 0]

    return jax.vmap(one_slot, in_axes=(1, 1, 1), out_axes=1)(table.values, table.present, t)


def _clock_slots(table: ClockInterp, t):
    """Clock [s], its rate [s/s] and valid of slot s at times t[:, s] ([T, S])."""

    def one_slot(values_s, prev_s, next_s, t_s):
        tab = ClockInterp(
            table.t0_gps_s,
            table.dt_s,
            values_s[:, None],
            prev_s[:, None],
            next_s[:, None],
            table.max_gap_s,
        )

        def f(tt):
            c, ok = clock_bias(tab, tt)
            return c[0], ok[0]

        def one(tt):
            (c, ok), (rate, _) = jax.jvp(f, (tt,), (jnp.ones_like(tt),))
            return c, rate, ok

        return jax.vmap(one)(t_s)

    return jax.vmap(one_slot, in_axes=(1, 1, 1, 1), out_axes=1)(
        table.values, table.prev_idx, table.next_idx, t
    )


def sub_clock(table: ClockInterp, cols) -> ClockInterp:
    """The clock table of the satellites in ``cols`` (one column per slot, in slot order)."""
    return ClockInterp(
        table.t0_gps_s,
        table.dt_s,
        table.values[:, cols],
        table.prev_idx[:, cols],
        table.next_idx[:, cols],
        table.max_gap_s,
    )


def _relativity_m(pos, vel):
    return C_LIGHT * corrections.relativistic_clock_s(pos, vel)


class SatStates(NamedTuple):
    pos: jnp.ndarray  # [T, S, 3]
    vel: jnp.ndarray
    clock_m: jnp.ndarray  # [T, S] c (dt^s + dt_rel)
    clock_rate_m_s: jnp.ndarray
    valid: jnp.ndarray  # [T, S]


@partial(jax.jit, static_argnames=("n_points", "one_sided"))
def precise_states(sp3_tab, clk_tab, t_rx, travel_s, n_points, one_sided) -> SatStates:
    """Precise orbit + clock at t_tx = t_rx - P/c - dt^s (two clock evaluations)."""
    t_sv = t_rx[:, None] - travel_s
    dts0, _, _ = _clock_slots(clk_tab, t_sv)
    t_tx = t_sv - dts0
    pos, vel, ok_orb = _sp3_slots(sp3_tab, t_tx, n_points, one_sided)
    dts, rate, ok_clk = _clock_slots(clk_tab, t_tx)
    rel = _relativity_m(pos, vel)
    # d(rel)/dt = -2 (v.v + r.a)/c^2 is < 1e-11 s/s x c = 3 mm/s: kept out of the clock rate.
    return SatStates(pos, vel, C_LIGHT * dts + rel, C_LIGHT * rate, ok_orb & ok_clk)


@jax.jit
def broadcast_states(eph_sub, t_rx, travel_s) -> SatStates:
    """Broadcast orbit + clock (one satellite of ``eph_sub`` per slot) at transmission."""

    def one_epoch(t, tau):
        t_src = t - tau - eph_sub.t_ref_gps_s
        st0 = ephemeris.satellite_state(eph_sub, t_src)
        st = ephemeris.satellite_state(eph_sub, t_src - st0.clock_s)
        return st

    st = jax.vmap(one_epoch)(jnp.asarray(t_rx), travel_s)
    is_glo = (eph_sub.system == signals.SYS_GLO)[None, :]
    rel = jnp.where(is_glo, 0.0, _relativity_m(st.pos_ecef, st.vel_ecef))
    return SatStates(
        st.pos_ecef, st.vel_ecef, C_LIGHT * st.clock_s + rel, C_LIGHT * st.clock_rate_s_s, st.ok
    )

