"""``sdf_code``: Hatch carrier-smoothed ionosphere-free code (S000 eqs 4.48-4.59).

The smoothing is a recursive growing window, capped at ``PppConfig.hatch_window`` epochs and
restarted whenever the slot rises, slips or returns (S000 gives no window or reset). The smoothed
code's variance falls as 1 / n down to ``sdf_sigma_floor_fraction`` of the raw IF code's.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Bool

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock
from jaxnav.gnss.ppp_data import KIND_CODE, Combos, HatchState


def hatch_update(
    cfg, state: HatchState, cmb: Combos, tracked: Bool[Array, " S"], restart: Bool[Array, " S"]
) -> HatchState:
    """Hatch: P_bar_k = P_k/n + (n-1)/n (P_bar_{k-1} + Phi_k - Phi_{k-1}), n = min(k, N) (SEED 2.4).

    ``tracked`` slots advance; ``restart`` (rise, slip, return after an outage) sets n = 1.
    Untracked slots keep count 0 so their next epoch restarts the window.
    """
    n = jnp.where(restart, 1.0, jnp.minimum(state.count + 1.0, cfg.hatch_window))
    propagated = state.smoothed_m + cmb.phase_if_m - state.prev_phase_m
    smoothed = cmb.code_if_m / n + (n - 1.0) / n * propagated
    return HatchState(
        jnp.where(tracked, smoothed, state.smoothed_m),
        jnp.where(tracked, cmb.phase_if_m, state.prev_phase_m),
        jnp.where(tracked, n, 0.0),
    )


class SdfCode(AbstractPppMode):
    name: ClassVar[str] = "sdf_code"
    uses_phase: ClassVar[bool] = False
    single_frequency: ClassVar[bool] = False
    uses_iono_model: ClassVar[bool] = False
    blocks: ClassVar[tuple[Block, ...]] = ()

    def update_memory(self, cfg, hatch, cmb, usable, restart):
        return hatch_update(cfg, hatch, cmb, usable, restart)

    def rows(self, cfg, ctx) -> list[RowBlock]:
        n = jnp.maximum(ctx.hatch.count, 1.0)
        frac = jnp.maximum(1.0 / jnp.sqrt(n), cfg.sdf_sigma_floor_fraction)
        var = (ctx.code_sigma * ctx.if_noise * frac) ** 2 + ctx.product_var
        dz = ctx.geo_pred - ctx.hatch.smoothed_m
        return [RowBlock(dz, ctx.H_common, var, ctx.usable, KIND_CODE)]
