"""Measured sweep costs and the run-time estimate of ``jaxnav sweep --dry-run``.

``COSTS`` holds, per (mode, system), what ``benchmarks/sweep_costs.py`` measured on this
project's 2-core CI machine (one worker, RESULTS.md "Sweep costs per group and scenario"):
the compilation of a group (full run + window evaluation), the full-availability run per
realization and drive epoch, and the window evaluation per scenario and window epoch. A study's
estimate (``estimate``) is the sum over its groups of

    compile_s + realizations x (drive epochs x full_epoch_s + other_per_realization_s)
              + scenarios x window x scenario_epoch_s

plus the drive simulation (``DRIVE_S_PER_S`` x drive seconds). A cell that was not measured
takes the same system's ``float_ppp`` figures (the most expensive PPP mode measured), else
the most expensive measured cell; the estimate says which cells were substituted. The
machine's speed drifts by about 30 %, and more workers divide only the evaluation part.
"""

from __future__ import annotations

from typing import NamedTuple


class Cost(NamedTuple):
    compile_s: float  # per group
    full_epoch_s: float  # per realization and drive epoch
    scenario_epoch_s: float  # per scenario and window epoch
    other_per_realization_s: float  # realization simulation (with its compilation), files


#: benchmarks/sweep_costs.py's JSON line, 2026-12-07 (RESULTS.md), rounded.
MEASURED = "2026-12-07, python benchmarks/sweep_costs.py (2 cores, one worker)"
COSTS: dict[tuple[str, str], Cost] = {
    ("df_code", "ins15"): Cost(10.4, 3.81e-04, 2.07e-04, 1.90),
    ("df_code", "riss"): Cost(8.9, 1.15e-04, 1.06e-04, 2.06),
    ("float_ppp", "ins15"): Cost(12.1, 3.98e-04, 4.18e-04, 0.59),
    ("float_ppp", "ins15_nhc"): Cost(15.2, 4.06e-04, 5.09e-04, 0.35),
    ("float_ppp", "ins21"): Cost(11.6, 5.39e-04, 4.06e-04, 0.67),
    ("float_ppp", "lc_ins15"): Cost(16.8, 4.44e-04, 3.87e-04, 0.99),
    ("float_ppp", "ppp_alone"): Cost(9.0, 1.75e-04, 2.04e-04, 0.49),
    ("float_ppp", "riss"): Cost(9.7, 1.93e-04, 2.76e-04, 0.54),
    ("float_ppp", "riss9"): Cost(9.6, 1.58e-04, 2.03e-04, 0.63),
    ("sf_code", "ins15"): Cost(10.7, 3.54e-04, 2.31e-04, 2.32),
    ("sf_code", "riss"): Cost(9.4, 1.44e-04, 1.47e-04, 3.04),
}
DRIVE_S_PER_S = 0.0056  # simulated drive: seconds per drive second


def cell_cost(mode: str, system: str) -> tuple[Cost, str | None]:
    """The cell's measured cost, or (substitute, the measured cell used instead)."""
    if (mode, system) in COSTS:
        return COSTS[(mode, system)], None
    if ("float_ppp", system) in COSTS:
        return COSTS[("float_ppp", system)], f"float_ppp/{system}"
    worst = max(COSTS, key=lambda k: COSTS[k].scenario_epoch_s)
    return COSTS[worst], "/".join(worst)


class Estimate(NamedTuple):
    seconds: float
    compile_s: float
    full_s: float
    eval_s: float
    other_s: float  # realization and drive simulation, files
    substituted: dict  # "mode/system" -> the measured cell used for it


def estimate(cfg, plan, drive_s: float) -> Estimate:
    """Wall time of a one-worker run of ``cfg`` with ``plan`` (module docstring)."""
    n_real = len(plan.seeds)
    comp = full = ev = other = 0.0
    substituted = {}
    for mode in cfg.modes:
        for system in cfg.systems:
            c, sub = cell_cost(mode, system)
            if sub is not None:
                substituted[f"{mode}/{system}"] = sub
            comp += c.compile_s
            full += n_real * plan.timeline.n_epochs * c.full_epoch_s
            ev += plan.n_per_group * plan.window * c.scenario_epoch_s
            other += n_real * c.other_per_realization_s
    drive = DRIVE_S_PER_S * drive_s
    return Estimate(comp + full + ev + other + drive, comp, full, ev, other + drive, substituted)
