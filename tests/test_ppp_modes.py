"""The PPP-mode interface and registry (gnss/modes): a mode is complete or it is not a class."""

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.core.states import StateLayout
from jaxnav.gnss import modes, ppp
from jaxnav.gnss.modes.base import AbstractPppMode, Block


def test_registry_names_are_the_classes_names():
    assert modes.MODES == ("sf_code", "df_code", "sdf_code", "float_ppp", "ic_ppp", "sf_ppp")
    for name, cls in modes.REGISTRY.items():
        assert cls.name == name and issubclass(cls, AbstractPppMode)


def test_unknown_mode_names_the_allowed_ones():
    with pytest.raises(ValueError, match="unknown PPP mode 'if_ppp'; allowed: sf_code, df_code"):
        ppp.PppConfig(mode="if_ppp")


def test_mode_without_rows_fails_when_defined():
    with pytest.raises(TypeError, match="does not implement rows"):

        class NoRows(AbstractPppMode):
            name: ClassVar[str] = "no_rows"
            uses_phase: ClassVar[bool] = False
            single_frequency: ClassVar[bool] = False
            uses_iono_model: ClassVar[bool] = False
            blocks: ClassVar[tuple] = ()


def test_mode_without_a_declaration_fails_when_defined():
    missing = "single_frequency, uses_iono_model, blocks"
    with pytest.raises(TypeError, match=f"does not define {missing}"):

        class Undeclared(AbstractPppMode):
            name: ClassVar[str] = "undeclared"
            uses_phase: ClassVar[bool] = True

            def rows(self, cfg, ctx):
                return []


def test_block_naming_no_config_sigma_fails_with_the_config():
    class Typo(AbstractPppMode):
        name: ClassVar[str] = "typo"
        uses_phase: ClassVar[bool] = True
        single_frequency: ClassVar[bool] = False
        uses_iono_model: ClassVar[bool] = False
        blocks: ClassVar[tuple] = (Block("amb", True, "ambiguity_sigma_m"),)

        def rows(self, cfg, ctx):
            return []

    modes.REGISTRY["typo"] = Typo
    try:
        with pytest.raises(ValueError, match="'ambiguity_sigma_m', which is not a PppConfig"):
            ppp.PppConfig(mode="typo")
    finally:
        del modes.REGISTRY["typo"]


def test_bssd_refused_where_the_mode_says_so():
    with pytest.raises(ValueError, match="ic_ppp with between-satellite differences"):
        ppp.PppConfig(mode="ic_ppp", bssd=True)
    for name, cls in modes.REGISTRY.items():
        if cls.supports_bssd:
            ppp.PppConfig(mode=name, bssd=True)


@pytest.mark.parametrize("name", modes.MODES)
def test_every_block_has_a_positive_initial_sigma_and_per_slot_blocks_restart(name):
    """The two silent failures of string branches: a block missing from the initial sigmas
    (sigma 0: the state can never move) or from the per-slot resets (never restarted)."""
    S = 5
    cfg = ppp.PppConfig(mode=name, n_slots=S)
    layout = StateLayout((("pos", 3),) + ppp.gnss_blocks(cfg))
    std = np.asarray(ppp.gnss_initial_std(cfg, layout))
    assert np.all(std[3:] > 0), dict(zip(layout.names, [std[layout.sl(n)] for n in layout.names],
                                         strict=True))
    restart = jnp.array([True, False, True, False, False])
    flags, var = ppp.slot_state_resets(cfg, layout, restart)
    flags, var = np.asarray(flags), np.asarray(var)
    for b in cfg.model.blocks:
        f = flags[layout.sl(b.name)]
        if b.per_slot:
            np.testing.assert_array_equal(f, np.asarray(restart))
            np.testing.assert_allclose(var[layout.sl(b.name)][f], getattr(cfg, b.init_sigma) ** 2)
        else:
            assert not f.any()
    not_mode = np.ones(layout.size, bool)
    for b in cfg.model.blocks:
        not_mode[layout.sl(b.name)] = False
    assert not flags[not_mode].any()  # position, clock, ISB, ZWD never restart with a slot
