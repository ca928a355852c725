"""``float_ppp``: IF code + IF carrier, a float ambiguity per slot (S002-S004, S000's CC).

S000 calls it "code-carrier"; the ambiguity is in metres.

Phase row: Phi_IF = rho + c dt + T + N_IF; N_IF restarts at Phi_IF - P_IF (sigma
``ambiguity_init_sigma_m``) whenever its slot rises, slips or returns, and follows a random walk
with the products' residual (``PppConfig.ambiguity_psd_m2_s``).
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock, per_slot_columns
from jaxnav.gnss.modes.df_code import if_code_row
from jaxnav.gnss.ppp_data import KIND_PHASE


class FloatPpp(AbstractPppMode):
    name: ClassVar[str] = "float_ppp"
    uses_phase: ClassVar[bool] = True
    single_frequency: ClassVar[bool] = False
    uses_iono_model: ClassVar[bool] = False
    blocks: ClassVar[tuple[Block, ...]] = (
        Block("amb", True, "ambiguity_init_sigma_m", ambiguity=True),
    )

    def reset_values(self, cfg, layout, obs, cmb, restart: Bool[Array, " S"],
                     gnss_est: Float[Array, " n"]) -> Float[Array, " n"]:
        amb = jnp.where(restart, cmb.phase_if_m - cmb.code_if_m, gnss_est[layout.sl("amb")])
        return gnss_est.at[layout.sl("amb")].set(amb)

    def rows(self, cfg, ctx) -> list[RowBlock]:
        S = ctx.usable.shape[0]
        amb = ctx.gnss_est[ctx.layout.sl("amb")]
        H_phase = ctx.H_common + per_slot_columns(ctx.layout, "amb", jnp.ones(S))
        var = (ctx.phase_sigma * ctx.if_noise) ** 2  # products: the ambiguity's random walk
        dz = ctx.geo_pred + amb - ctx.cmb.phase_if_m
        return [if_code_row(ctx), RowBlock(dz, H_phase, var, ctx.usable, KIND_PHASE)]
