"""Cycle-slip detection, the same on real and simulated observations: geometry-free and
Melbourne-Wuebbena tests per slot for two bands (a ``lax.scan`` over epochs), and for one band
the carrier's change against the Doppler's integral."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxnav.gnss import models, signals


class SlipThresholds(NamedTuple):
    """Thresholds of the dual-frequency slip detector (the same on real and simulated data)."""

    gf_m: float = 0.05  # chosen: RTKLIB's default geometry-free slip threshold (5 cm)
    mw_sigmas: float = 4.0  # chosen: 4-sigma Melbourne-Wuebbena jump
    mw_floor_cycles: float = 0.25  # chosen: floor 0.25 WL cycles: 4 sigma >= 1 cycle (86 cm)
    # single band (detect_slips_doppler): the Doppler noise at zenith the filters assume
    # (S001 eq 11, PppConfig.doppler_sigma_m_s; the simulator's too), a 5-sigma test, a floor
    # for the carrier noise and what the trapezoid misses, dt^3 / 12 times the range jerk,
    # with a vehicle's 0.5 m/s^3 (chosen: hard braking onset; 0.04 m at 1 Hz, 1.1 km at 30 s,
    # where the test is off: a receiver's motion is unknown to it)
    doppler_sigma0_m_s: float = 0.1
    doppler_sigmas: float = 5.0
    doppler_floor_m: float = 0.01
    doppler_jerk_m_s3: float = 0.5


DEFAULT_SLIP_THRESHOLDS = SlipThresholds()


@jax.jit
def detect_slips(gf_m, mw_m, have, mw_floor_m, gf_threshold_m, mw_sigmas, min_arc=10):
    """Geometry-free and Melbourne-Wuebbena slip flags per epoch and slot ([T, S] inputs).

    GF: |GF_k - GF_prev| > threshold, prev = the slot's previous epoch with data. MW: running
    arc mean m and variance v (Welford); slip if |MW_k - m| > n_sigma max(s, floor_k) where
    s = sqrt(v) once the arc has ``min_arc`` epochs (a short arc's sample std is unreliable,
    so the floor alone is used before). ``mw_floor_m`` [T, S] is the noise floor in metres. A
    slot without data at k-1 starts a new arc (the filter restarts it anyway).
    Returns (gf_slip, mw_slip), both [T, S] bool.
    """
    S = gf_m.shape[1]

    def step(c, x):
        prev_gf, mean, m2, n, prev_have = c
        gf, mw, hv, floor = x
        cont = hv & prev_have
        gf_slip = cont & (jnp.abs(gf - prev_gf) > gf_threshold_m)
        std = jnp.where(n >= min_arc, jnp.sqrt(m2 / jnp.maximum(n - 1.0, 1.0)), 0.0)
        mw_slip = cont & (n >= 1.0) & (jnp.abs(mw - mean) > mw_sigmas * jnp.maximum(std, floor))
        restart = ~cont | gf_slip | mw_slip
        n_new = jnp.where(restart, 1.0, n + 1.0)
        delta = mw - mean
        mean_new = jnp.where(restart, mw, mean + delta / n_new)
        m2_new = jnp.where(restart, 0.0, m2 + delta * (mw - mean_new))
        keep = ~hv  # no data: hold the memory, mark the gap
        new = (
            jnp.where(keep, prev_gf, gf),
            jnp.where(keep, mean, mean_new),
            jnp.where(keep, m2, m2_new),
            jnp.where(keep, n, n_new),
            hv,
        )
        return new, (gf_slip, mw_slip)

    z = jnp.zeros(S)
    init = (z, z, z, z, jnp.zeros(S, bool))
    _, (gf_slip, mw_slip) = jax.lax.scan(step, init, (gf_m, mw_m, have, mw_floor_m))
    return gf_slip, mw_slip


def detect_slips_dual(
    phase_m: Float[ArrayLike, "T S 2"],
    code_m: Float[ArrayLike, "T S 2"],
    have: Bool[ArrayLike, "T S"],
    elevation_rad: Float[ArrayLike, "T S"],
    f1_hz: Float[ArrayLike, " S"],
    f2_hz: Float[ArrayLike, " S"],
    thresholds: SlipThresholds = DEFAULT_SLIP_THRESHOLDS,
) -> tuple[Bool[Array, "T S"], Bool[Array, "T S"]]:
    """GF and MW slip flags from two-band phase and code in metres (S002 §5.3; S002 2.29).

    GF = Phi1 - Phi2 (geometry-free, ambiguity jump lambda1 dN1 - lambda2 dN2); MW = Phi_WL -
    P_NL (wide-lane cycles dN1 - dN2). The MW floor is ``mw_floor_cycles`` lambda_WL at zenith
    with the S001 eq 11 elevation law of the code noise it comes from. Entries where ``have``
    is False are ignored (NaNs there are harmless). Returns (gf_slip, mw_slip) [T, S].
    """
    phase_m = jnp.asarray(phase_m)
    code_m = jnp.asarray(code_m)
    have = jnp.asarray(have, bool)
    gf = phase_m[..., 0] - phase_m[..., 1]
    mw = signals.melbourne_wubbena_m(
        phase_m[..., 0], phase_m[..., 1], code_m[..., 0], code_m[..., 1], f1_hz, f2_hz
    )
    floor = (
        thresholds.mw_floor_cycles
        * signals.wl_wavelength_m(jnp.asarray(f1_hz), jnp.asarray(f2_hz))[None, :]
        * models.elevation_sigma(1.0, jnp.asarray(elevation_rad))
    )
    return detect_slips(
        jnp.where(have, gf, 0.0),
        jnp.where(have, mw, 0.0),
        have,
        floor,
        thresholds.gf_m,
        thresholds.mw_sigmas,
    )


@jax.jit
def detect_slips_doppler(
    phase_m: Float[ArrayLike, "T S"],
    range_rate_m_s: Float[ArrayLike, "T S"],
    have: Bool[ArrayLike, "T S"],
    elevation_rad: Float[ArrayLike, "T S"],
    time_s: Float[ArrayLike, " T"],
    thresholds: SlipThresholds = DEFAULT_SLIP_THRESHOLDS,
) -> Bool[Array, "T S"]:
    """Single-band slip flags: the carrier's change against the integral of the Doppler.

    r_k = (Phi_k - Phi_k-1) - (rr_k + rr_k-1) dt / 2 (trapezoid; rr = -lambda D, both in metres
    and both holding the receiver clock, whose change and drift cancel), minus its median over
    the slots tracked at both epochs (a clock step common to all). Slip if |r_k| > n sigma_k,
    sigma_k^2 = sigma_D(E)^2 dt^2 / 2 + floor^2 + (j dt^3 / 12)^2, sigma_D(E) the S001 eq 11
    Doppler noise, j a bound on the range jerk (the trapezoid's error). Tested where the slot
    has data at k and k-1 (a gap starts a new arc anyway). The power falls with the interval:
    at 1 Hz 5 sigma is ~2 L1 cycles at zenith with 0.1 m/s Doppler noise, at 30 s the test is
    off (kilometres).
    """
    phase_m = jnp.asarray(phase_m)
    rr = jnp.asarray(range_rate_m_s)
    have = jnp.asarray(have, bool)
    dt = jnp.diff(jnp.asarray(time_s, jnp.float64))[:, None]  # [T-1, 1]
    both = have[1:] & have[:-1]
    r = (phase_m[1:] - phase_m[:-1]) - 0.5 * (rr[1:] + rr[:-1]) * dt
    r = jnp.where(both, r, jnp.nan)
    n = jnp.sum(both, axis=1, keepdims=True)
    med = jnp.where(n >= 3, jnp.nanmedian(r, axis=1, keepdims=True), 0.0)
    sig_d = models.elevation_sigma(thresholds.doppler_sigma0_m_s, jnp.asarray(elevation_rad)[1:])
    trapezoid = thresholds.doppler_jerk_m_s3 * dt**3 / 12.0
    sigma = jnp.sqrt(0.5 * (sig_d * dt) ** 2 + thresholds.doppler_floor_m**2 + trapezoid**2)
    slip = both & (jnp.abs(jnp.where(both, r - med, 0.0)) > thresholds.doppler_sigmas * sigma)
    return jnp.concatenate([jnp.zeros_like(have[:1]), slip], axis=0)


def detection_counts(
    true_slip: Bool[ArrayLike, "*TS"],
    flags: Bool[ArrayLike, "*TS"],
    continuing: Bool[ArrayLike, "*TS"],
) -> dict[str, Array]:
    """Counts of a detector against the truth on the slot-epochs of continuing arcs.

    ``true_slip``: a slip happened at that epoch; ``flags``: the detector fired;
    ``continuing``: tracked at this and the previous epoch (where a detector can act).
    Missed-detection rate = missed / slips; false-alarm rate = false_alarms / (tested - slips).
    """
    s = jnp.asarray(true_slip) & jnp.asarray(continuing)
    f = jnp.asarray(flags) & jnp.asarray(continuing)
    return {
        "tested": jnp.sum(jnp.asarray(continuing)),
        "slips": jnp.sum(s),
        "missed": jnp.sum(s & ~f),
        "false_alarms": jnp.sum(f & ~s),
    }
