"""The PPP-mode registry: the names used in study TOML, sweeps and on the command line, mapped
to their classes (``gnss/modes/base.py`` is the interface; one module per mode)."""

from __future__ import annotations

from jaxnav.gnss.modes.base import AbstractPppMode, Block, RowBlock, RowContext
from jaxnav.gnss.modes.df_code import DfCode
from jaxnav.gnss.modes.float_ppp import FloatPpp
from jaxnav.gnss.modes.ic_ppp import IcPpp
from jaxnav.gnss.modes.sdf_code import SdfCode
from jaxnav.gnss.modes.sf_code import SfCode
from jaxnav.gnss.modes.sf_ppp import SfPpp

#: name -> mode class, in the order tables and help texts list them.
REGISTRY: dict[str, type[AbstractPppMode]] = {
    cls.name: cls for cls in (SfCode, DfCode, SdfCode, FloatPpp, IcPpp, SfPpp)
}
#: The registered names (SEED_SPEC 2.2-2.5).
MODES: tuple[str, ...] = tuple(REGISTRY)


def get(name: str) -> AbstractPppMode:
    """The mode registered as ``name``; ValueError naming the allowed ones otherwise."""
    try:
        return REGISTRY[name]()
    except KeyError:
        raise ValueError(f"unknown PPP mode {name!r}; allowed: {', '.join(MODES)}") from None


__all__ = ["MODES", "REGISTRY", "AbstractPppMode", "Block", "RowBlock", "RowContext", "get"]
