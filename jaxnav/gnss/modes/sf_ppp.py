"""``sf_ppp``: single-frequency PPP, GPS L1 C/A code and L1 carrier phase (S002 ch. 4).

Rows per slot: C1 = rho + c dt + T + I and L1 = rho + c dt + T - I + N1 (the ionosphere delays
the code and advances the phase by the same amount), with a float L1 ambiguity N1 and a slant
ionosphere I per slot. I restarts at the model value (Klobuchar / GIM) with the model's variance
whenever its slot rises, slips or returns, then follows a random walk (S001 eq 5 form), so the
model fixes I's level and the code-minus-phase divergence (2 dI) tracks its change over the
pass. ``PppConfig.iono_constraint = "epoch"`` adds the model as a white pseudo-observation
every epoch instead, as for ``ic_ppp``.

Chosen over S002's own form (the model subtracted from code and added to phase, the residual
left to the ambiguity and the noise), which has no state for the model error's drift over a
pass (0.3-0.55 m per 10 min in the simulator's truth): that drift would leak into position
through the phase rows. Chosen over GRAPHIC, (C1 + L1) / 2 (S002 §2.2.4, not used there): it
discards the model's information and keeps half the code noise per epoch. The receiver's code
bias is absorbed by the clock and its phase bias by the ambiguities; GLONASS and Galileo slots
get their ISB rows like every mode.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock, per_slot_columns
from jaxnav.gnss.modes.ic_ppp import (
    restart_slots,
    slant_iono_process_noise,
    slant_iono_pseudo_rows,
    slant_iono_reset_variance,
)
from jaxnav.gnss.ppp_data import KIND_CODE, KIND_PHASE


class SfPpp(AbstractPppMode):
    name: ClassVar[str] = "sf_ppp"
    uses_phase: ClassVar[bool] = True
    single_frequency: ClassVar[bool] = True
    uses_iono_model: ClassVar[bool] = True
    # Between-satellite differences of per-slot ionosphere rows are not implemented (as ic_ppp).
    supports_bssd: ClassVar[bool] = False
    blocks: ClassVar[tuple[Block, ...]] = (
        Block("amb1", True, "ambiguity_init_sigma_m", ambiguity=True),
        Block("iono", True, "iono_init_sigma_m"),
    )

    def clock_code(self, cmb):
        return cmb.code_corr_m[:, 0]

    def process_noise(self, cfg, layout, elevation: Float[Array, " S"],
                      q: Float[Array, " n"], obs) -> Float[Array, " n"]:
        """Slant ionosphere: a random walk (S001 eqs 4-5)."""
        return slant_iono_process_noise(cfg, layout, elevation, q)

    def reset_variance(self, cfg, obs, elevation):
        return slant_iono_reset_variance(cfg, obs, elevation)

    def reset_values(self, cfg, layout, obs, cmb, restart: Bool[Array, " S"],
                     gnss_est: Float[Array, " n"]) -> Float[Array, " n"]:
        """I = I_model, N1 = L1 - C1 + 2 I_model."""
        iono0 = obs.iono_model_l1_m
        new = {"iono": iono0, "amb1": obs.phase_m[:, 0] - cmb.code_corr_m[:, 0] + 2.0 * iono0}
        return restart_slots(layout, gnss_est, restart, new)

    def rows(self, cfg, ctx) -> list[RowBlock]:
        layout = ctx.layout
        S = ctx.usable.shape[0]
        iono = ctx.gnss_est[layout.sl("iono")]
        amb = ctx.gnss_est[layout.sl("amb1")]
        H_iono = per_slot_columns(layout, "iono", jnp.ones(S))
        H_amb = per_slot_columns(layout, "amb1", jnp.ones(S))
        code = RowBlock(ctx.geo_pred + iono - ctx.cmb.code_corr_m[:, 0], ctx.H_common + H_iono,
                        ctx.code_sigma**2 + ctx.product_var, ctx.usable, KIND_CODE)
        phase = RowBlock(ctx.geo_pred - iono + amb - ctx.obs.phase_m[:, 0],
                         ctx.H_common - H_iono + H_amb, ctx.phase_sigma**2,
                         ctx.usable, KIND_PHASE)
        return [code, phase]

    def pseudo_rows(self, cfg, ctx):
        return slant_iono_pseudo_rows(cfg, ctx)
