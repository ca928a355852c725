"""The PPP models' inputs and outputs: satellite slots, one epoch of observations, their
combinations, the carrier-smoothing memory, the predicted antenna and the stacked rows.

Shared by the generic assembly (``gnss/ppp.py``), every PPP mode (``gnss/modes/``) and the
filters. All per-slot arrays are [S]; masks select what is used.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Real

from jaxnav.core.rows import (  # noqa: F401  (the filters' one row type, re-exported)
    KIND_CODE,
    KIND_DOPPLER,
    KIND_IONO,
    KIND_PHASE,
    Rows,
)
from jaxnav.gnss import models, signals


class SlotInfo(NamedTuple):
    """Static description of the satellite slots of a scenario (one entry per slot)."""

    system: Int[Array, " S"]  # signals.SYS_GPS / SYS_GLO / SYS_GAL
    f1_hz: Float[Array, " S"]  # first PPP frequency (GLONASS: FDMA channel dependent)
    f2_hz: Float[Array, " S"]  # second PPP frequency


class GnssObs(NamedTuple):
    """One epoch of observations and products, per slot [S] (band index 0 = f1, 1 = f2)."""

    code_m: Float[Array, "S 2"]  # pseudoranges (C1 or P1, P2) [m]
    phase_m: Float[Array, "S 2"]  # carrier phase times wavelength [m]
    range_rate_m_s: Float[Array, " S"]  # f1 Doppler as range rate, -lambda1 * D_Hz [m/s]
    available: Bool[Array, " S"]  # all signals of the slot tracked this epoch
    slip: Bool[Array, " S"]  # loss of lock / cycle slip flagged this epoch
    code_bias_m: Float[Array, "S 2"]  # known satellite code biases w.r.t. the clock datum [m]
    iono_model_l1_m: Float[Array, " S"]  # model (broadcast / GIM) slant f1 ionosphere [m]
    sat: models.SatEpoch
    doppler_ok: Bool[Array, " S"]  # the f1 Doppler was measured (else no Doppler row)
    iono_model_ok: Bool[Array, " S"]  # the model covers the pierce point and epoch (else a mode
    # that needs the model cannot use the slot)


class EpochInput(NamedTuple):
    """Everything one GNSS epoch of a tightly coupled filter consumes (``filter/tight.py``)."""

    samples: Any  # system IMU/RISS samples over (t_{k-1}, t_k] ([K, ...])
    obs: GnssObs
    keep: Bool[Array, " S"]  # False withholds the slot (outage / availability policy)
    day_of_year: Real[Array, ""]  # for the mapping function


class Combos(NamedTuple):
    """Per-slot observation combinations shared by the row builders."""

    alpha: Float[Array, " S"]  # IF weight of f1
    beta: Float[Array, " S"]  # IF weight of f2 (alpha + beta = 1)
    gamma: Float[Array, " S"]  # (f1/f2)^2
    code_if_m: Float[Array, " S"]
    phase_if_m: Float[Array, " S"]
    code_corr_m: Float[Array, "S 2"]  # bias-corrected raw codes


def combos(slots: SlotInfo, obs: GnssObs) -> Combos:
    """Ionosphere-free code and phase after removing the known satellite code biases."""
    alpha, beta = signals.if_coefficients(slots.f1_hz, slots.f2_hz)
    code = obs.code_m - obs.code_bias_m
    return Combos(
        alpha,
        beta,
        (slots.f1_hz / slots.f2_hz) ** 2,
        alpha * code[:, 0] + beta * code[:, 1],
        alpha * obs.phase_m[:, 0] + beta * obs.phase_m[:, 1],
        code,
    )


class HatchState(NamedTuple):
    """Per-slot carrier-smoothing memory (S000 eqs 4.48-4.59 as a recursive Hatch filter)."""

    smoothed_m: Float[Array, " S"]  # smoothed IF code
    prev_phase_m: Float[Array, " S"]  # IF phase at the previous epoch
    count: Float[Array, " S"]  # epochs in the current window (0 = restart)

    @classmethod
    def empty(cls, n_slots: int):
        z = jnp.zeros(n_slots)
        return cls(z, z, z)


class Receiver(NamedTuple):
    """The antenna as the navigation system predicts it, with Jacobians w.r.t. the full dx."""

    pos_ecef: Float[Array, "3"]
    vel_ecef: Float[Array, "3"]
    llh: Float[Array, "3"]
    J_pos: Float[Array, "3 n"]  # d(pos_ecef)/d(dx)
    J_vel: Float[Array, "3 n"]  # d(vel_ecef)/d(dx)


