"""``ic_ppp``: ionosphere-constrained uncombined PPP (S001 eqs 1-9).

Rows P1, P2, L1, L2 per slot with a slant-ionosphere state I (on L1; gamma I on f2, opposite
sign on phase), L1 and L2 float ambiguities and a receiver DCB. With the clock absorbing the IF
receiver code bias, P1 keeps beta DCB and P2 -alpha DCB (DCB = b1 - b2); phase receiver biases
are absorbed by the ambiguities. The model ionosphere (GIM / broadcast) enters per
``PppConfig.iono_constraint``: "prior" initialises each restarted slant state at the model value
with the model's variance; "epoch" adds S001's white pseudo-observation I = I_model every epoch.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxnav.gnss import models
from jaxnav.gnss.modes.base import (
    AbstractPppMode,
    Block,
    RowBlock,
    RowContext,
    column,
    iono_model_var,
    per_slot_columns,
)
from jaxnav.gnss.ppp_data import KIND_CODE, KIND_IONO, KIND_PHASE

_SQRT_H = 60.0  # sqrt(3600 s): converts "per sqrt(hour)" to "per sqrt(second)"


def iono_rw_sigma(cfg, elevation_rad: Float[Array, " S"]) -> Float[Array, " S"]:
    """S001 eq 5: q_ion = sigma for E >= 30 deg, sigma / (2 sin E) below [m/sqrt(h)]."""
    return models.elevation_sigma(cfg.iono_sigma_m_sqrt_h, elevation_rad)


def slant_iono_process_noise(
    cfg, layout, elevation: Float[Array, " S"], q: Float[Array, " n"]
) -> Float[Array, " n"]:
    """The slant ionosphere's random-walk PSD (S001 eqs 4-5) set in q."""
    return q.at[layout.sl("iono")].set((iono_rw_sigma(cfg, elevation) / _SQRT_H) ** 2)


def restart_slots(
    layout,
    gnss_est: Float[Array, " n"],
    restart: Bool[Array, " S"],
    values: dict[str, Float[Array, " S"]],
) -> Float[Array, " n"]:
    """``gnss_est`` with each per-slot block in ``values`` ({name: [S]}) set where ``restart``."""
    for name, value in values.items():
        cur = gnss_est[layout.sl(name)]
        gnss_est = gnss_est.at[layout.sl(name)].set(jnp.where(restart, value, cur))
    return gnss_est


def slant_iono_reset_variance(cfg, obs, elevation: Float[Array, " S"]
                              ) -> dict[str, Float[Array, " S"]]:
    """"prior": a restarted slant ionosphere starts at the model's variance (else the initial)."""
    if cfg.iono_constraint != "prior":
        return {}
    return {"iono": iono_model_var(cfg, obs.iono_model_l1_m, elevation)}


def slant_iono_pseudo_rows(cfg, ctx: RowContext) -> list[RowBlock]:
    """"epoch": S001 eqs 6-7 as printed, I - I_model every epoch with the model's variance (its
    local-time / latitude term folded into the residual model; SEED_SPEC 2.5)."""
    if cfg.iono_constraint != "epoch":
        return []
    S = ctx.usable.shape[0]
    iono = ctx.gnss_est[ctx.layout.sl("iono")]
    H = per_slot_columns(ctx.layout, "iono", jnp.ones(S))
    return [RowBlock(iono - ctx.obs.iono_model_l1_m, H, ctx.iono_var, ctx.usable, KIND_IONO)]


class IcPpp(AbstractPppMode):
    name: ClassVar[str] = "ic_ppp"
    uses_phase: ClassVar[bool] = True
    single_frequency: ClassVar[bool] = False
    uses_iono_model: ClassVar[bool] = True
    supports_bssd: ClassVar[bool] = False
    blocks: ClassVar[tuple[Block, ...]] = (
        Block("amb1", True, "ambiguity_init_sigma_m", ambiguity=True),
        Block("amb2", True, "ambiguity_init_sigma_m", ambiguity=True),
        Block("iono", True, "iono_init_sigma_m"),
        Block("dcb", False, "dcb_init_sigma_m"),
    )

    def process_noise(self, cfg, layout, elevation: Float[Array, " S"],
                      q: Float[Array, " n"], obs) -> Float[Array, " n"]:
        """Slant ionosphere and DCB: random walks (S001 eqs 4-5, 8-9)."""
        q = slant_iono_process_noise(cfg, layout, elevation, q)
        return q.at[layout.i("dcb")].set((cfg.dcb_sigma_m_sqrt_h / _SQRT_H) ** 2)

    def reset_variance(self, cfg, obs, elevation):
        return slant_iono_reset_variance(cfg, obs, elevation)

    def reset_values(self, cfg, layout, obs, cmb, restart: Bool[Array, " S"],
                     gnss_est: Float[Array, " n"]) -> Float[Array, " n"]:
        """I = I_model; N1 = L1 - P1 + 2 I + beta DCB, N2 = L2 - P2 + 2 gamma I - alpha DCB
        (code and phase ionosphere of opposite sign; the codes carry the receiver DCB as in
        ``rows``, the current estimate is used)."""
        iono0 = obs.iono_model_l1_m
        dcb = gnss_est[layout.i("dcb")]
        new = {
            "iono": iono0,
            "amb1": obs.phase_m[:, 0] - cmb.code_corr_m[:, 0] + 2.0 * iono0 + cmb.beta * dcb,
            "amb2": (obs.phase_m[:, 1] - cmb.code_corr_m[:, 1] + 2.0 * cmb.gamma * iono0
                     - cmb.alpha * dcb),
        }
        return restart_slots(layout, gnss_est, restart, new)

    def rows(self, cfg, ctx) -> list[RowBlock]:
        layout, cmb = ctx.layout, ctx.cmb
        S = ctx.usable.shape[0]
        iono = ctx.gnss_est[layout.sl("iono")]
        dcb = ctx.gnss_est[layout.i("dcb")]
        H_iono = per_slot_columns(layout, "iono", jnp.ones(S))
        ones = jnp.ones(S)
        out = []
        for band, coef, dcb_coef in ((0, ones, cmb.beta), (1, cmb.gamma, -cmb.alpha)):
            pred = ctx.geo_pred + coef * iono + dcb_coef * dcb
            H = ctx.H_common + H_iono * coef[:, None] + column(layout, "dcb", S, dcb_coef)
            var = ctx.code_sigma**2 + ctx.product_var
            out.append(RowBlock(pred - cmb.code_corr_m[:, band], H, var, ctx.usable, KIND_CODE))
        for band, coef, amb_name in ((0, ones, "amb1"), (1, cmb.gamma, "amb2")):
            amb = ctx.gnss_est[layout.sl(amb_name)]
            pred = ctx.geo_pred - coef * iono + amb
            H = ctx.H_common - H_iono * coef[:, None] + per_slot_columns(layout, amb_name, ones)
            var = ctx.phase_sigma**2  # the products' residual: the ambiguities' random walk
            out.append(RowBlock(pred - ctx.obs.phase_m[:, band], H, var, ctx.usable, KIND_PHASE))
        return out

    def pseudo_rows(self, cfg, ctx):
        return slant_iono_pseudo_rows(cfg, ctx)
