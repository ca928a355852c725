"""A navigation history at the GNSS epochs, as the metrics and the sweep engine read it."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class Track(NamedTuple):
    """A navigation history: estimate or truth at the GNSS epochs."""

    llh: jnp.ndarray  # [T, 3] lat [rad], lon [rad], h [m]
    vel_enu: jnp.ndarray  # [T, 3] [m/s]
    azimuth: jnp.ndarray  # [T] [rad], clockwise from north


def track(llh, vel_enu, euler) -> Track:
    """Track from llh, vel_enu and Euler angles (roll, pitch, azimuth), e.g. an EpochOutput or a
    sim.trajectory.Truth at the epochs."""
    return Track(jnp.asarray(llh), jnp.asarray(vel_enu), jnp.asarray(euler)[..., 2])
