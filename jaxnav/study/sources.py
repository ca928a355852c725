"""The scenario sources a study's ``[scenario] source`` may name, and their factories.

``simulated`` (the default): a seeded random drive with every GNSS error simulated
(``study/factory.py``); ``replay``: a station's recorded observations moved onto a simulated
circuit around it (``study/replay.py``). Both give the sweep engine the same contract.
"""

from __future__ import annotations

import os

from jaxnav.core import schema
from jaxnav.study.config import ConfigError
from jaxnav.study.factory import SimFactory
from jaxnav.study.replay import ReplayFactory

SOURCES = {"simulated": SimFactory, "replay": ReplayFactory}


def factory_for(table: dict | None, base_dir: str | os.PathLike | None = None):
    """The factory of the ``[scenario]`` table's source; paths in it are relative to
    ``base_dir`` (the study TOML's folder)."""
    table = dict(table or {})
    source = table.get("source", "simulated")
    if source not in SOURCES:
        schema.fail("scenario.source", source, f"one of {', '.join(map(repr, SOURCES))}",
                    ConfigError)
    if source == "simulated":
        table.pop("source", None)
        return SimFactory(table)
    return ReplayFactory(table, base_dir)
