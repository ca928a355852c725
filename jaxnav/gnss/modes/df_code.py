"""``df_code``: dual-frequency ionosphere-free code, P_IF = alpha P1 + beta P2 (S000 eq 4.45)."""

from __future__ import annotations

from typing import ClassVar

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock, RowContext
from jaxnav.gnss.ppp_data import KIND_CODE


def if_code_row(ctx: RowContext) -> RowBlock:
    """The IF code row; its noise is the raw code's times sqrt(alpha^2 + beta^2), the products'
    residual added after the combination (it is common to both frequencies)."""
    var = (ctx.code_sigma * ctx.if_noise) ** 2 + ctx.product_var
    return RowBlock(ctx.geo_pred - ctx.cmb.code_if_m, ctx.H_common, var, ctx.usable, KIND_CODE)


class DfCode(AbstractPppMode):
    name: ClassVar[str] = "df_code"
    uses_phase: ClassVar[bool] = False
    single_frequency: ClassVar[bool] = False
    uses_iono_model: ClassVar[bool] = False
    blocks: ClassVar[tuple[Block, ...]] = ()

    def rows(self, cfg, ctx) -> list[RowBlock]:
        return [if_code_row(ctx)]
