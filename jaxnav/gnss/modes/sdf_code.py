"""``sdf_code``: Hatch carrier-smoothed ionosphere-free code (S000 eqs 4.48-4.59).

The smoothing is a recursive growing window, capped at ``PppConfig.hatch_window`` epochs and
restarted whenever the slot rises, slips or returns (S000 gives no window or reset).

Weight: the raw IF code's variance. Smoothing lowers the noise of one epoch (about 1 / n for
the white part) but correlates it over the window, and its gain at zero frequency is one: the
smoothed code's white-equivalent variance (``models.white_equivalent_var``) is the raw code's.
A filter that weighted it by the per-epoch variance was over-confident (issue 16: position
NEES 3.5 against a 2.7-3.3 band even with white simulated noise). The benefit of smoothing is
a quieter position where the filter's memory is short (after an outage, under dynamics).
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
        var = (ctx.code_sigma * ctx.if_noise) ** 2 + ctx.product_var
        dz = ctx.geo_pred - ctx.hatch.smoothed_m
        return [RowBlock(dz, ctx.H_common, var, ctx.usable, KIND_CODE)]
