"""What the sweep engine needs from a filter: ``FilterOps`` (a filter layer module provides
one, ``study/sweep.py`` drives it)."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple


class FilterOps(NamedTuple):
    """How the engine drives a filter (any filter with the ``tight.run`` contract)."""

    run: Callable  # (tf, carry, inputs [T, ...]) -> (carry, outputs [T, ...])
    readout: Callable  # outputs [T, ...] -> (core.track.Track, P_nav [T, k, k] or None)
    get_keep: Callable  # inputs -> keep [T, S] bool
    with_keep: Callable  # (inputs, keep [T, S]) -> inputs
    # (tf, carry, inputs [T, ...], n_valid) -> (forward outputs, RTS-smoothed outputs), both
    # [T, ...], the smoother over the first n_valid epochs only (traced int; filter.smoother's
    # cut_after); None: the filter has no smoother (a study with ``smooth = true`` is refused)
    smooth: Callable | None = None
