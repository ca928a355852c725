"""The one measurement-row type of every filter: GNSS observations and vehicle constraints.

A ``Rows`` block holds the residual dz = h(x_hat) - z, the Jacobian H = dh/d(dx), the noise R
and a mask, plus per row the satellite slot it belongs to (``NO_SLOT`` for a constraint) and
its kind. The tight filter stacks its PPP rows and the NHC rows into one masked update; the
loose filter stacks GNSS fixes, NHC, ZUPT, ZARU and odometer rows the same way.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

#: Row kinds: GNSS code, carrier phase, Doppler, ionosphere pseudo-observation, and a vehicle
#: constraint or fix (NHC, ZUPT, ZARU, odometer, a GNSS position / velocity fix).
KIND_CODE, KIND_PHASE, KIND_DOPPLER, KIND_IONO, KIND_CONSTRAINT = 0, 1, 2, 3, 4
#: The GNSS kinds (the first four): per-kind counts of the filters' outputs have this length.
N_GNSS_KINDS = 4
#: Slot of a row that belongs to no satellite (scatters by slot must mask it out).
NO_SLOT = -1


class Rows(NamedTuple):
    """Stacked measurement rows: residual dz = h(x_hat) - z, H, R, mask, slot and kind."""

    dz: Float[Array, " m"]
    H: Float[Array, "m n"]
    R: Float[Array, "m m"]
    mask: Bool[Array, " m"]
    slot: Int[Array, " m"]  # slot of each row (NO_SLOT for none)
    kind: Int[Array, " m"]  # KIND_*

    @property
    def size(self) -> int:
        return self.dz.shape[0]


def constraint_rows(dz: Float[ArrayLike, " m"], H: Float[ArrayLike, "m n"],
                    R: Float[ArrayLike, "m m"], mask: Bool[ArrayLike, " m"]) -> Rows:
    """Rows of a constraint or fix: no satellite slot, kind ``KIND_CONSTRAINT``."""
    dz = jnp.asarray(dz)
    m = dz.shape[0]
    return Rows(dz, jnp.asarray(H), jnp.asarray(R), jnp.asarray(mask, bool),
                jnp.full(m, NO_SLOT), jnp.full(m, KIND_CONSTRAINT))


def stack_rows(*rows: Rows) -> Rows:
    """Concatenate row blocks (block-diagonal R: the blocks' noises are independent)."""
    dz = jnp.concatenate([r.dz for r in rows])
    m = dz.shape[0]
    R = jnp.zeros((m, m), dz.dtype)
    start = 0
    for r in rows:
        R = R.at[start : start + r.size, start : start + r.size].set(r.R)
        start += r.size
    return Rows(dz, jnp.concatenate([r.H for r in rows], axis=0), R,
                jnp.concatenate([r.mask for r in rows]), jnp.concatenate([r.slot for r in rows]),
                jnp.concatenate([r.kind for r in rows]))


def sanitize(rows: Rows) -> Rows:
    """Zero the residual and H of masked-out rows and give them unit variance, so that missing
    inputs (NaN in a withheld epoch) cannot leak into the update or its diagnostics."""
    m = rows.mask
    pair = m[:, None] & m[None, :]
    return rows._replace(
        dz=jnp.where(m, rows.dz, 0.0),
        H=jnp.where(m[:, None], rows.H, 0.0),
        R=jnp.where(pair, rows.R, 0.0) + jnp.diag(jnp.where(m, 0.0, 1.0)),
    )
