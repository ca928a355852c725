"""The PPP-mode interface: what one flavour of PPP declares and computes.

A mode (one module in this package, one line in its registry ``gnss/modes/__init__.py``) is a
final subclass of :class:`AbstractPppMode` (equinox's abstract/final pattern). It declares

- its own GNSS error-state blocks (:class:`Block`: size, initial / reset sigma, per slot or
  not), appended after the common ones (receiver clock, inter-system biases, ZWD) that
  ``gnss/ppp.py`` owns; per-slot blocks restart whenever their slot rises, slips or returns;
- whether it uses carrier phase (then the ZWD is estimated and a slot counts as tracked only
  while its phase is used), and whether it needs only the first frequency;
- its measurement rows at one epoch (residual dz = h(x_hat) - z, H, variance, mask, kind) from
  the quantities every mode shares (:class:`RowContext`);
- where it differs from the defaults: process noise of its blocks, the values its blocks restart
  at, the code that levels the receiver clock at the start, a per-slot memory (Hatch smoothing),
  and rows that are never between-satellite differenced (pseudo-observations of a state).

A concrete mode that leaves a class attribute or an abstract method undefined fails when its
class is defined, not later with a silent zero.
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxnav.gnss import models
from jaxnav.gnss.ppp_data import Combos, GnssObs, HatchState

if TYPE_CHECKING:
    from jaxnav.core.states import StateLayout
    from jaxnav.gnss.ppp import PppConfig


class Block(NamedTuple):
    """A GNSS error-state block a mode adds to the filter."""

    name: str  # the state name (core/states.py layout)
    per_slot: bool  # one state per satellite slot (restarted on rise / slip / return), else one
    init_sigma: str  # the PppConfig field holding its initial and reset sigma
    # a carrier ambiguity (metres): it also follows the products' residual over a pass
    ambiguity: bool = False
    # the PppConfig field holding its correlation time (first-order Gauss-Markov), or None
    tau: str | None = None


class RowBlock(NamedTuple):
    """S rows of one kind: residual, Jacobian, variance (uncorrelated), mask, kind."""

    dz: Float[Array, " S"]
    H: Float[Array, "S n"]
    var: Float[Array, " S"]
    mask: Bool[Array, " S"]
    kind: int  # ppp_data.KIND_*


class RowContext(NamedTuple):
    """Per-epoch quantities shared by every mode's rows (built by ``ppp.measurement_rows``)."""

    layout: StateLayout
    gnss_est: Float[Array, " n"]  # the GNSS states' totals (ambiguities, ionosphere, ...)
    obs: GnssObs
    cmb: Combos
    hatch: HatchState
    usable: Bool[Array, " S"]  # tracked, kept by the study, above the elevation mask
    geo_pred: Float[Array, " S"]  # range + receiver clock and ISB - satellite clock + troposphere
    H_common: Float[Array, "S n"]  # geometry, clock, ISB and ZWD columns
    # raw code / phase sigma at the slot's elevation, white + multipath (PppConfig.zenith_sigmas,
    # GLONASS scaled) [m]
    code_sigma: Float[Array, " S"]
    phase_sigma: Float[Array, " S"]
    if_noise: Float[Array, " S"]  # sqrt(alpha^2 + beta^2): IF noise amplification
    iono_var: Float[Array, " S"]  # variance of the model slant L1 ionosphere [m^2]
    product_var: Float[ArrayLike, ""]  # orbit + clock residual variance, common to code and phase


def per_slot_columns(layout: StateLayout, name: str, values: Float[Array, " S"]
                     ) -> Float[Array, "S n"]:
    """[S, n] block with values[i] at (i, first index of block ``name`` + i)."""
    S = values.shape[0]
    out = jnp.zeros((S, layout.size))
    start = layout.sl(name).start
    return out.at[jnp.arange(S), start + jnp.arange(S)].set(values)


def column(
    layout: StateLayout,
    name: str,
    n_rows: int,
    values: Float[ArrayLike, ""] | Float[ArrayLike, " r"] = 1.0,
) -> Float[Array, "r n"]:
    """[n_rows, n] block with ``values`` in column ``name`` (zeros if the layout lacks it)."""
    out = jnp.zeros((n_rows, layout.size))
    if layout.has(name):
        out = out.at[:, layout.i(name)].set(values)
    return out


def iono_model_var(
    cfg: PppConfig, iono_model_l1_m: Float[Array, " S"], elevation_rad: Float[Array, " S"]
) -> Float[Array, " S"]:
    """Variance [m^2] of the model (broadcast / GIM) slant L1 ionosphere:
    (fraction * I_model)^2 + (floor * s(E))^2, s(E) the S001 eq 11 elevation factor."""
    floor = models.elevation_sigma(cfg.iono_model_residual_floor_m, elevation_rad)
    return (cfg.iono_model_residual_fraction * iono_model_l1_m) ** 2 + floor**2


_REQUIRED_CLASS_VARS = ("name", "uses_phase", "single_frequency", "uses_iono_model",
                        "blocks")


class AbstractPppMode(eqx.Module):
    """One PPP flavour (module docstring). Subclasses are final and hold no fields."""

    name: ClassVar[str]  # the name used in study TOML, on the command line and in results
    uses_phase: ClassVar[bool]  # carrier-phase rows with per-slot ambiguities
    single_frequency: ClassVar[bool]  # only f1 observables (simulated C/A code, L1)
    uses_iono_model: ClassVar[bool]  # its rows or restarts need the model ionosphere
    blocks: ClassVar[tuple[Block, ...]]  # the mode's own blocks, in layout order
    supports_bssd: ClassVar[bool] = True  # rows may be between-satellite differenced (S004)

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.__name__.startswith("Abstract"):
            return
        missing = [k for k in _REQUIRED_CLASS_VARS if not hasattr(cls, k)]
        if missing:
            raise TypeError(f"PPP mode {cls.__name__} does not define {', '.join(missing)}")
        # ABCMeta sets __abstractmethods__ only after __init_subclass__ returns: look directly.
        abstract = sorted(k for k in dir(cls) if getattr(getattr(cls, k, None),
                                                          "__isabstractmethod__", False))
        if abstract:
            raise TypeError(f"PPP mode {cls.__name__} does not implement {', '.join(abstract)}")
        for b in cls.blocks:
            if not isinstance(b, Block):
                raise TypeError(f"PPP mode {cls.__name__}: blocks must be Block, got {b!r}")

    @abc.abstractmethod
    def rows(self, cfg: PppConfig, ctx: RowContext) -> list[RowBlock]:
        """The mode's code / phase rows at one epoch (Doppler rows are added by ppp.py)."""

    def check(self, cfg: PppConfig) -> None:
        """Raise ValueError for a configuration the mode cannot run (called by PppConfig)."""
        if cfg.bssd and not self.supports_bssd:
            raise ValueError(f"{self.name} with between-satellite differences is not supported")
        for b in self.blocks:
            if not hasattr(cfg, b.init_sigma):
                raise ValueError(f"PPP mode {self.name}: block {b.name!r} names init_sigma "
                                 f"{b.init_sigma!r}, which is not a PppConfig field")

    def clock_code(self, cmb: Combos) -> Float[Array, " S"]:
        """[S] code whose median residual levels the receiver clock at the start."""
        return cmb.code_if_m

    def process_noise(self, cfg: PppConfig, layout: StateLayout, elevation: Float[Array, " S"],
                      q: Float[Array, " n"], obs: GnssObs) -> Float[Array, " n"]:
        """Diagonal PSD q with the mode's blocks filled in (default: constants, q unchanged)."""
        return q

    def reset_variance(self, cfg: PppConfig, obs: GnssObs, elevation: Float[Array, " S"]
                       ) -> dict[str, Float[Array, " S"]]:
        """{block: [S] variance} replacing the initial one when a slot restarts (default none)."""
        return {}

    def reset_values(self, cfg: PppConfig, layout: StateLayout, obs: GnssObs, cmb: Combos,
                     restart: Bool[Array, " S"], gnss_est: Float[Array, " n"]
                     ) -> Float[Array, " n"]:
        """``gnss_est`` with the restarted slots' blocks at their new values (default: as is)."""
        return gnss_est

    def update_memory(self, cfg: PppConfig, hatch: HatchState, cmb: Combos,
                      usable: Bool[Array, " S"], restart: Bool[Array, " S"]) -> HatchState:
        """The per-slot memory after this epoch's observations (default: unused, unchanged)."""
        return hatch

    def pseudo_rows(self, cfg: PppConfig, ctx: RowContext) -> list[RowBlock]:
        """Rows appended after any between-satellite differencing (default none)."""
        return []
