"""Carrier-phase wind-up of right-hand circularly polarised signals (S002 eqs 2.14-2.19).

Both antennas are crossed dipoles (Wu et al. 1993, the effective-dipole model S002 uses). With
k the unit vector from the satellite to the receiver:

- satellite effective dipole  D_s = x_s - k (k . x_s) - k x y_s   (S002 eq 2.14, sign fixed),
- receiver effective dipole   D_r = x_r - k (k . x_r) + k x y_r   (S002 eq 2.15),
- fractional wind-up          dphi = sign(k . (D_s x D_r)) acos(D_s . D_r / (|D_s| |D_r|))
                              (S002 eqs 2.16-2.17),
- continuity                  phi_w = 2 pi N + dphi, N = nint((phi_prev - dphi) / 2 pi)
                              (S002 eqs 2.18-2.19).

Typo fix (S002 eq 2.14): the seed prints the satellite dipole with "+ k x y_s", the receiver's
sign. For a satellite the boresight z_s points along k (to the Earth), so k x y_s ~ z_s x y_s =
-x_s and "+" would cancel the dipole to zero; the physically correct satellite form (Wu et al.
1993; Kouba, IGS products guide) has "- k x y_s", which gives D_s ~ 2 x_s. The receiver's
boresight points along -k, where "+ k x y_r" ~ +x_r is correct as printed.

Satellite axes: nominal yaw steering, z_s = -r_s/|r_s|, y_s = z_s x e_sun / |z_s x e_sun|,
x_s = y_s x z_s with e_sun the unit vector satellite -> Sun (S002 eqs 2.6-2.8); eclipse and
noon/midnight turn manoeuvres are not modelled (their arcs get a wind-up error of up to a
cycle, absorbed by the float ambiguity after an arc reset). Receiver axes: an antenna aligned to
north (x_r = north, y_r = west), as for a geodetic monument.

The correction is *subtracted* from the carrier phase: Phi_corrected = Phi - lambda phi_w / 2 pi
(S002 after eq 2.19). All functions broadcast over leading axes and are jit/vmap/scan friendly.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav import geodesy


def _unit(v):
    return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def satellite_axes(
    sat_pos_ecef: Float[ArrayLike, "*S 3"], sun_pos_ecef: Float[ArrayLike, "*#S 3"]
) -> tuple[Float[Array, "*S 3"], Float[Array, "*S 3"]]:
    """Nominal yaw-steering dipole axes (x_s, y_s) of a satellite (S002 eqs 2.6-2.8), ECEF."""
    z_s = -_unit(sat_pos_ecef)
    e_sun = _unit(sun_pos_ecef - sat_pos_ecef)
    y_s = _unit(jnp.cross(z_s, e_sun))
    x_s = jnp.cross(y_s, z_s)
    return x_s, y_s


def receiver_axes(llh: Float[ArrayLike, "3"]) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
    """Dipole axes of a north-aligned receiver antenna at one ``llh``: x_r = north, y_r = west."""
    C = geodesy.C_l_e(llh[0], llh[1])  # columns: east, north, up in ECEF
    return C[:, 1], -C[:, 0]


def windup_fraction_rad(
    sat_pos_ecef: Float[ArrayLike, "*#S 3"],
    rcv_pos_ecef: Float[ArrayLike, "*#S 3"],
    x_s: Float[ArrayLike, "*#S 3"],
    y_s: Float[ArrayLike, "*#S 3"],
    x_r: Float[ArrayLike, "*#S 3"],
    y_r: Float[ArrayLike, "*#S 3"],
) -> Float[Array, "*#S"]:
    """Fractional wind-up dphi in (-pi, pi] [rad] (S002 eqs 2.14-2.17, eq 2.14 sign fixed).

    ``x_s, y_s`` are the satellite dipole axes, ``x_r, y_r`` the receiver's (all ECEF unit
    vectors, broadcast against each other).
    """
    k = _unit(rcv_pos_ecef - sat_pos_ecef)
    kxs = jnp.sum(k * x_s, axis=-1, keepdims=True)
    kxr = jnp.sum(k * x_r, axis=-1, keepdims=True)
    d_s = x_s - k * kxs - jnp.cross(k, y_s)
    d_r = x_r - k * kxr + jnp.cross(k, y_r)
    cos_p = jnp.sum(d_s * d_r, axis=-1) / (
        jnp.linalg.norm(d_s, axis=-1) * jnp.linalg.norm(d_r, axis=-1)
    )
    angle = jnp.arccos(jnp.clip(cos_p, -1.0, 1.0))
    zeta = jnp.sum(k * jnp.cross(d_s, d_r), axis=-1)
    return jnp.where(zeta < 0.0, -angle, angle)


def continue_windup(prev_rad, fraction_rad):
    """Continuous wind-up phi = 2 pi N + dphi, N = nint((phi_prev - dphi) / 2 pi) (S002 2.18-19)."""
    n = jnp.round((prev_rad - fraction_rad) / (2.0 * jnp.pi))
    return 2.0 * jnp.pi * n + fraction_rad


def windup_series_rad(
    fraction_rad: Float[Array, " T *S"], initial_rad: Float[ArrayLike, "*#S"] | None = None
) -> Float[Array, " T *S"]:
    """Continuous wind-up [rad] of a time series of fractions [T, ...] (lax.scan of eq 2.18).

    The first epoch keeps its fraction (N initialised with zero, S002) unless ``initial_rad``
    is given.
    """
    first = fraction_rad[0]
    if initial_rad is not None:
        first = continue_windup(initial_rad, first)

    def step(prev, frac):
        cur = continue_windup(prev, frac)
        return cur, cur

    _, rest = jax.lax.scan(step, first, fraction_rad[1:])
    return jnp.concatenate([first[None], rest], axis=0)


def windup_rad(
    sat_pos_ecef: Float[ArrayLike, "*S 3"],
    rcv_pos_ecef: Float[ArrayLike, "*#S 3"],
    sun_pos_ecef: Float[ArrayLike, "*#S 3"],
    rcv_llh: Float[ArrayLike, "3"],
) -> Float[Array, "*S"]:
    """Fractional wind-up [rad] for nominal yaw-steering satellites and a north-aligned antenna.

    Shapes: satellites [..., S, 3], receiver [3] (or broadcastable), Sun [3], llh [3].
    """
    x_s, y_s = satellite_axes(sat_pos_ecef, sun_pos_ecef)
    x_r, y_r = receiver_axes(rcv_llh)
    return windup_fraction_rad(sat_pos_ecef, rcv_pos_ecef, x_s, y_s, x_r, y_r)
