"""Predicted GNSS observables and their Jacobian rows, per fixed satellite slot.

Everything here is in ECEF metres and works on all slots at once ([S] and [S, 3] arrays); slots
without a satellite carry any finite values and are masked by the caller. Jacobians are taken
with respect to the receiver antenna's ECEF position and velocity; the navigation system maps
them to its own error states with the antenna Jacobians (``H_nav = dz/dr_e @ dr_e/ddx``).

Sign conventions (core/states.py): residual dz = h(x_hat) - z and H = dh/dx.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int

from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import corrections


class SatEpoch(NamedTuple):
    """Satellite states at one epoch as the user's products give them, per slot.

    ``pos_ecef`` is the antenna phase centre at signal transmission, in the ECEF frame of the
    transmission instant (as SP3/broadcast evaluation gives it); Earth rotation during the travel
    time is applied by :func:`geometry`. Clocks are c * dt^s [m] and its rate [m/s].
    """

    pos_ecef: Float[Array, "S 3"]
    vel_ecef: Float[Array, "S 3"]
    clock_m: Float[Array, " S"]
    clock_rate_m_s: Float[Array, " S"]


class Geometry(NamedTuple):
    """Receiver-satellite geometry per slot."""

    range_m: Float[Array, " S"]  # geometric range including the Earth-rotation (Sagnac) term
    los_ecef: Float[Array, "S 3"]  # unit vector receiver -> satellite
    range_rate_m_s: Float[Array, " S"]  # d(range)/dt
    sat_pos_ecef: Float[Array, "S 3"]  # satellite position rotated into the reception frame
    sat_vel_ecef: Float[Array, "S 3"]


def geometry(
    rx_pos_ecef: Float[ArrayLike, "3"], rx_vel_ecef: Float[ArrayLike, "3"], sat: SatEpoch
) -> Geometry:
    """Range and range rate with Earth rotation during the travel time tau = rho / c.

    r_s' = R3(w_e tau) r_s (corrections.geometric_range_m), rho = |r_s' - r_r|,
    u = (r_s' - r_r) / rho and rho_dot = u . (v_s' - v_r) with v_s' = R3(w_e tau) v_s.
    """
    rho, pos_s = corrections.geometric_range_m(rx_pos_ecef, sat.pos_ecef)
    vel_s = corrections.earth_rotation_correct(sat.vel_ecef, rho / C_LIGHT)
    los = (pos_s - rx_pos_ecef) / rho[:, None]
    rate = jnp.sum(los * (vel_s - rx_vel_ecef), axis=-1)
    return Geometry(rho, los, rate, pos_s, vel_s)


def elevation_azimuth(
    los_ecef: Float[Array, "S 3"], C_e_l: Float[Array, "3 3"]
) -> tuple[Float[Array, " S"], Float[Array, " S"]]:
    """Elevation and azimuth [rad] of unit line-of-sight vectors, given C_e_l = (C_l^e)^T."""
    los_enu = los_ecef @ C_e_l.T
    el = jnp.arcsin(jnp.clip(los_enu[:, 2], -1.0, 1.0))
    az = jnp.arctan2(los_enu[:, 0], los_enu[:, 1])
    return el, az


def range_jacobian(geo: Geometry) -> Float[Array, "S 3"]:
    """d(range)/d(r_rx) = -u^T, one row per slot ([S, 3]).

    The same rows give d(range_rate)/d(v_rx); the position dependence of the range rate through
    u (|dv|/rho ~ 1e-4 of it) is neglected, as in every seed.
    """
    return -geo.los_ecef


class ModelTerms(NamedTuple):
    """Everything a code/phase/Doppler prediction adds to the geometry, per slot [m] or [m/s]."""

    clock_m: Float[Array, " S"]  # receiver clock (+ inter-system bias) minus satellite clock
    trop_m: Float[Array, " S"]  # slant troposphere (a-priori + estimated wet part)
    iono_l1_m: Float[Array, " S"]  # L1 slant ionosphere used by the model (0 for IF combinations)
    clock_rate_m_s: Float[Array, " S"]  # receiver clock drift minus satellite clock rate


def predict_code(geo: Geometry, terms: ModelTerms, iono_scale):
    """P = rho + c(dt_r - dt^s) + T + (f1/fj)^2 I_1 (S002 eq 2.25, corrections applied)."""
    return geo.range_m + terms.clock_m + terms.trop_m + iono_scale * terms.iono_l1_m


def predict_phase(geo: Geometry, terms: ModelTerms, iono_scale, ambiguity_m):
    """Phi = rho + c(dt_r - dt^s) + T - (f1/fj)^2 I_1 + lambda N (S002 eq 2.26), in metres."""
    return geo.range_m + terms.clock_m + terms.trop_m - iono_scale * terms.iono_l1_m + ambiguity_m


def predict_range_rate(geo: Geometry, terms: ModelTerms):
    """D = rho_dot + c(dt_r' - dt^s') (S002 eq 5.5; troposphere and ionosphere rates neglected)."""
    return geo.range_rate_m_s + terms.clock_rate_m_s


def elevation_sigma(
    sigma_zenith: Float[ArrayLike, ""], elevation_rad: Float[ArrayLike, "*S"]
) -> Float[Array, "*S"]:
    """S001 eq 11 [recon]: sigma = sigma0 above 30 deg, sigma0 / (2 sin E) below (continuous)."""
    s = jnp.sin(jnp.maximum(elevation_rad, 1e-3))
    return jnp.where(elevation_rad >= jnp.pi / 6, sigma_zenith, sigma_zenith / (2.0 * s))


def white_equivalent_var(
    sigma: Float[ArrayLike, "*S"], tau_s: Float[ArrayLike, ""], dt_s: Float[ArrayLike, ""]
) -> Float[Array, "*S"]:
    """sigma^2 (1 + rho) / (1 - rho), rho = exp(-dt / tau): the variance per update of the white
    sequence whose spectral density at zero frequency equals that of the first-order
    Gauss-Markov error (sigma, tau) sampled every dt (sum of its autocovariance over all lags).

    A filter that weights each epoch as independent averages an error of this kind as if it
    were white; with this variance its time averages carry the right uncertainty
    (-> 2 tau / dt sigma^2 for dt << tau, -> sigma^2 for dt >> tau)."""
    rho = jnp.exp(-jnp.asarray(dt_s) / tau_s)
    return jnp.square(sigma) * (1.0 + rho) / (1.0 - rho)


def single_difference_matrix(n_slots: int, ref_slot: Int[ArrayLike, ""]) -> Float[Array, "S S"]:
    """Between-satellite differencing D = I - e_ref 1^T restricted to rows != ref (S004, S002 2.39).

    Returned square ([S, S]) with the reference row zeroed, so fixed shapes survive: the caller
    masks the reference row out. The differenced covariance is D R D^T (correlated rows).
    """
    eye = jnp.eye(n_slots)
    D = eye - jnp.zeros((n_slots, n_slots)).at[:, ref_slot].set(1.0)
    return jnp.where((jnp.arange(n_slots) == ref_slot)[:, None], 0.0, D)
