"""Cycle-slip detection on real observations: geometry-free and Melbourne-Wuebbena tests per
slot (a ``lax.scan`` over epochs)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


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
