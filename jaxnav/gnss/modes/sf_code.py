"""``sf_code``: single-frequency code, C1 minus a model ionosphere (S000, S002 ch. 4).

z = C1 - b_C1 - I_model; the model's residual (``ppp.iono_model_var``) is added to the code
variance, since no state absorbs it.
"""

from __future__ import annotations

from typing import ClassVar

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock
from jaxnav.gnss.ppp_data import KIND_CODE


class SfCode(AbstractPppMode):
    name: ClassVar[str] = "sf_code"
    uses_phase: ClassVar[bool] = False
    single_frequency: ClassVar[bool] = True
    uses_iono_model: ClassVar[bool] = True
    blocks: ClassVar[tuple[Block, ...]] = ()

    def clock_code(self, cmb):
        return cmb.code_corr_m[:, 0]

    def rows(self, cfg, ctx) -> list[RowBlock]:
        z = ctx.cmb.code_corr_m[:, 0] - ctx.obs.iono_model_l1_m
        var = ctx.code_sigma**2 + ctx.iono_var + ctx.product_var
        return [RowBlock(ctx.geo_pred - z, ctx.H_common, var, ctx.usable, KIND_CODE)]
