"""``sf_code``: single-frequency code, C1 minus a model ionosphere (S000, S002 ch. 4).

z = C1 - b_C1 - I_model = rho + c dt + T + dI + e: the model's residual dI is a per-slot state,
first-order Gauss-Markov with the model's sigma (``ppp.iono_model_var``) and correlation time
(``PppConfig.iono_model_residual_tau_s``), restarted at 0 with that variance whenever its slot
rises or returns (S001 models its slant delays as states in the same way).

Chosen over adding the model's variance to each epoch's code as white noise (before issue 16):
a residual correlated over tens of minutes was then averaged down as if independent at every
epoch, and the filter was over-confident (median position NEES 23, 2.2 without the residual).
The state is observable only through its prior and its decay, so what it does is keep the
residual's correlation across epochs.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxnav.gnss.modes.base import (
    AbstractPppMode,
    Block,
    RowBlock,
    iono_model_var,
    per_slot_columns,
)
from jaxnav.gnss.modes.ic_ppp import restart_slots
from jaxnav.gnss.ppp_data import KIND_CODE


class SfCode(AbstractPppMode):
    name: ClassVar[str] = "sf_code"
    uses_phase: ClassVar[bool] = False
    single_frequency: ClassVar[bool] = True
    uses_iono_model: ClassVar[bool] = True
    blocks: ClassVar[tuple[Block, ...]] = (
        Block("iono_res", True, "iono_init_sigma_m", tau="iono_model_residual_tau_s"),
    )

    def clock_code(self, cmb):
        return cmb.code_corr_m[:, 0]

    def process_noise(self, cfg, layout, elevation: Float[Array, " S"],
                      q: Float[Array, " n"], obs) -> Float[Array, " n"]:
        """dI' = -dI / tau + w, PSD(w) = 2 sigma^2 / tau (stationary variance sigma^2)."""
        var = iono_model_var(cfg, obs.iono_model_l1_m, elevation)
        return q.at[layout.sl("iono_res")].set(2.0 * var / cfg.iono_model_residual_tau_s)

    def reset_variance(self, cfg, obs, elevation):
        return {"iono_res": iono_model_var(cfg, obs.iono_model_l1_m, elevation)}

    def reset_values(self, cfg, layout, obs, cmb, restart: Bool[Array, " S"],
                     gnss_est: Float[Array, " n"]) -> Float[Array, " n"]:
        """dI = 0: the model is the best guess of a new slot's ionosphere."""
        return restart_slots(layout, gnss_est, restart, {"iono_res": jnp.zeros_like(restart,
                                                                                     float)})

    def rows(self, cfg, ctx) -> list[RowBlock]:
        S = ctx.usable.shape[0]
        d_iono = ctx.gnss_est[ctx.layout.sl("iono_res")]
        z = ctx.cmb.code_corr_m[:, 0] - ctx.obs.iono_model_l1_m
        H = ctx.H_common + per_slot_columns(ctx.layout, "iono_res", jnp.ones(S))
        var = ctx.code_sigma**2 + ctx.product_var
        return [RowBlock(ctx.geo_pred + d_iono - z, H, var, ctx.usable, KIND_CODE)]
