"""Per-group and per-scenario costs of the sweep engine: the figures ``jaxnav sweep --dry-run``
turns into a time estimate (``jaxnav.study.costs.COSTS``).

For each (mode, system) cell, one small study (900-s default drive, 60-s outages keeping 0
satellites or all, a grid every 60 s from 300 s, 4 realizations, chunk 64) in this process on
one worker, after a warm-up study that simulates the drive (so the drive simulation is timed
once, apart). From the engine's stats: compilation (full run + window evaluation) per group,
the full-availability run per realization and drive epoch, the window evaluation per
scenario and window epoch. Each cell's study has its own folder; the compilation cache is
this process's (so each cell compiles; cells with the same shapes would share it in a real
study, which makes the estimate conservative).

    python benchmarks/sweep_costs.py                 # the default cells, ~8 min
    python benchmarks/sweep_costs.py --cells float_ppp/riss,df_code/ins15

The last printed line is JSON ``{"<mode>/<system>": {"compile_s": .., "full_epoch_s": ..,
"scenario_epoch_s": .., "other_per_realization_s": ..}, "drive_s_per_s": ..}``; the table and
the JSON go to RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

DEFAULT_CELLS = (
    ("sf_code", "riss"), ("df_code", "riss"), ("float_ppp", "riss"), ("float_ppp", "riss9"),
    ("sf_code", "ins15"), ("df_code", "ins15"), ("float_ppp", "ins15"), ("float_ppp", "ins21"),
    ("float_ppp", "lc_ins15"), ("float_ppp", "ppp_alone"), ("float_ppp", "ins15_nhc"),
)


def _study(mode: str, system: str, name: str):
    from jaxnav.study import config
    from jaxnav.study.factory import SimFactory

    return config.from_dict({
        "study": {"name": name, "modes": [mode], "systems": [system], "durations_s": [60],
                  "satellites_kept": [0, "all"], "realizations": 4, "recovery_s": 30,
                  "chunk_size": 64, "max_traces": 0},
        "placement": {"kind": "grid", "convergence_s": 300, "spacing_s": 60},
        "scenario": {"duration_s": 900},
    }, modes=SimFactory.modes, systems=SimFactory.systems)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", help="comma-separated mode/system cells (default: a set)")
    ap.add_argument("--no-append", action="store_true", help="do not append to RESULTS.md")
    a = ap.parse_args(argv)
    cells = (tuple(tuple(c.split("/", 1)) for c in a.cells.split(",")) if a.cells
             else DEFAULT_CELLS)

    import benchutil as bu

    from jaxnav.study import sweep
    from jaxnav.study.factory import SimFactory

    factory = SimFactory({"duration_s": 900})
    t0 = time.perf_counter()
    factory.geo  # noqa: B018  (simulates the drive: timed apart)
    drive_s = time.perf_counter() - t0
    out = {"drive_s_per_s": drive_s / 900.0}
    rows = ["| mode / system | compile [s] | full run [us / drive epoch] | window [us / "
            "scenario epoch] | other [s / realization] | scenarios | wall [s] |",
            "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for mode, system in cells:
            cfg = _study(mode, system, f"{mode}-{system}")
            plan = sweep.make_plan(cfg, factory.timeline(cfg))
            t = time.perf_counter()
            res = sweep.run_sweep(cfg, factory, Path(tmp) / f"{mode}-{system}", progress=False,
                                  workers=1)
            wall = time.perf_counter() - t
            st = res.stats
            n_real = len(plan.seeds)
            parts = (st["compile_full_s"] + st["compile_eval_s"] + st["full_run_s"]
                     + st["eval_s"])
            cell = {
                "compile_s": st["compile_full_s"] + st["compile_eval_s"],
                "full_epoch_s": st["full_run_s"] / (n_real * plan.timeline.n_epochs),
                "scenario_epoch_s": st["eval_s"] / (st["scenarios"] * plan.window),
                # the rest: each realization's simulation (and its compilation), chunk files,
                # the Dataset; counted per realization (conservative for long studies)
                "other_per_realization_s": max(wall - parts, 0.0) / n_real,
            }
            out[f"{mode}/{system}"] = cell
            rows.append(f"| {mode} / {system} | {cell['compile_s']:.1f} | "
                        f"{1e6 * cell['full_epoch_s']:.0f} | {1e6 * cell['scenario_epoch_s']:.0f}"
                        f" | {cell['other_per_realization_s']:.2f} | {st['scenarios']} | "
                        f"{wall:.1f} |")
            print(rows[-1], flush=True)
    body = (f"Drive simulation: {drive_s:.1f} s for the 900-s drive. Per cell, 4 realizations, "
            "60-s outages keeping 0 or all, grid every 60 s from 300 s, one worker.\n\n"
            + "\n".join(rows))
    print(body)
    if not a.no_append:
        bu.append_results("Sweep costs per group and scenario (jaxnav sweep --dry-run)", body, out)
    print(json.dumps(out, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
