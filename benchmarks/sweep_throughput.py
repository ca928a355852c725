"""The reference outage sweep: throughput of jaxnav against a plain NumPy loop of the same filter.

Reference sweep (issue 5): tightly coupled IF code + carrier PPP (float ambiguities, Doppler,
ZWD) with a full INS (INS15, SPAN-CPT-class IMU at 100 Hz), 1 Hz GNSS, 12 GPS satellite slots,
60-s outages keeping 0, 1, 2 or 3 satellites at random placements along a 15-minute simulated
drive, 30 s of recovery evaluated after each outage, noise realisations until the scenario count
is reached (default 4,000). Everything goes through the production engine
(``jaxnav.study.sweep.run_sweep``: full-availability run per realisation, checkpoint forking,
chunks written to disk, xarray Dataset at the end) across all local CPU devices.

Reported: wall time from an empty process to the written Dataset (including the drive
simulation and compilation), compile time (engine: full run + window evaluation), scenarios/s,
navigation-seconds/s (scenarios x 90 s window / wall), peak RSS. The NumPy reference
(``benchmarks/numpy_filter.py``, Python loops over epochs and IMU samples, NumPy per operation)
runs a few of the same scenario windows from the same checkpoint; its outputs are checked
against jaxnav's and its scenarios/s gives ``numpy_ratio`` = jaxnav / NumPy (wall-clock,
jaxnav's compile included).

    python benchmarks/sweep_throughput.py               # the reference sweep (4,000 scenarios)
    python benchmarks/sweep_throughput.py --quick       # 64 scenarios, 1 NumPy scenario
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

T_START = time.perf_counter()
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", type=int, default=4000, help="scenario count (approximate)")
    ap.add_argument("--realizations", type=int, default=4, help="noise realisations")
    ap.add_argument("--numpy-scenarios", type=int, default=3, help="NumPy reference scenarios")
    # Default one device: with 2 forced host devices the sharded evaluation deadlocks on this
    # machine (jaxlib 0.10.2; every thread parked, sync or async dispatch alike).
    ap.add_argument("--devices", type=int, default=1,
                    help="CPU devices to shard the scenarios over (default 1, see comment)")
    ap.add_argument("--chunk", type=int, default=0,
                    help="scenarios per engine chunk (default 64 per device)")
    ap.add_argument("--quick", action="store_true", help="64 scenarios, 1 NumPy scenario")
    ap.add_argument("--results", type=Path, default=HERE / "RESULTS.md",
                    help="Markdown file the figures are appended to")
    ap.add_argument("--no-append", action="store_true", help="print only, do not append")
    args = ap.parse_args(argv)
    if args.quick:
        args.scenarios, args.realizations, args.numpy_scenarios = 64, 1, 1
    return args


ARGS = _parse()
# Host devices must be fixed before JAX initialises its backend (i.e. before importing jaxnav).
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}"
)

import benchutil  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxnav  # noqa: E402, F401  (float64)
from jaxnav.filter import tight  # noqa: E402
from jaxnav.study import config, outages  # noqa: E402
from jaxnav.study import metrics as mt  # noqa: E402
from jaxnav.study.factory import SimFactory  # noqa: E402
from jaxnav.study.sweep import run_sweep  # noqa: E402

SCENARIO = {"duration_s": 900.0, "slots": [12, 14, 14], "ins_grade": "span_cpt"}
OUTAGE_S, RECOVERY_S, KEPT = 60, 30, (0, 1, 2, 3)


def study(n_scenarios: int, realizations: int, chunk: int) -> config.StudyConfig:
    """The reference study: random placements so that kept x placements x realisations ~ N."""
    placements = max(1, round(n_scenarios / (len(KEPT) * realizations)))
    d = {
        "study": {
            "name": "sweep_throughput", "modes": ["float_ppp"], "systems": ["ins15"],
            "durations_s": [OUTAGE_S], "satellites_kept": list(KEPT),
            "realizations": realizations, "recovery_s": RECOVERY_S, "chunk_size": chunk,
            "max_traces": 0,
        },
        "placement": {"kind": "random", "count": placements, "convergence_s": 300},
        "scenario": SCENARIO,
    }
    return config.from_dict(d, modes=SimFactory.modes, systems=SimFactory.systems)


def numpy_reference(factory: SimFactory, n: int, seed: int = 0):
    """Run n scenario windows with jaxnav (single, jitted) and with the NumPy loop from the same
    checkpoint; returns NumPy seconds per scenario and the largest position difference [m]."""
    import numpy_filter

    prob = factory.build(None, "float_ppp", "ins15", seed)
    window = OUTAGE_S + RECOVERY_S
    rng = np.random.default_rng(seed)
    starts = rng.integers(300, prob.elevation.shape[0] - window, size=n)
    run = jax.jit(tight.run)
    np_filter = numpy_filter.NumpyTightFilter.from_jax(prob.tf)

    @jax.jit
    def carries(carry0, inputs):  # the carry before every epoch (the engine's checkpoints)
        return jax.lax.scan(lambda c, i: (tight.epoch_step(prob.tf, c, i)[0], c), carry0, inputs)[1]

    all_carries = carries(prob.carry0, prob.inputs)
    t_np, max_diff = 0.0, 0.0
    for i, start in enumerate(int(x) for x in starts):
        carry = jax.tree.map(lambda a, k=start: a[k], all_carries)
        outage = outages.Outage(start, OUTAGE_S, KEPT[i % len(KEPT)], 0)
        keep = outages.keep_mask(prob.elevation, prob.available, outage, azimuth=prob.azimuth)
        win = jax.tree.map(lambda a, k=start: a[k : k + window], prob.inputs)
        win = win._replace(keep=win.keep & keep[start : start + window])
        _, out = run(prob.tf, carry, win)
        t0 = time.perf_counter()
        ref = numpy_filter.run(np_filter, carry, win)
        t_np += time.perf_counter() - t0
        d = mt.enu_errors(jnp.asarray(ref["llh"]), out.llh)
        max_diff = max(max_diff, float(jnp.max(jnp.abs(d))))
    return t_np / n, max_diff


def main() -> int:
    devices = jax.devices()
    chunk = ARGS.chunk or 64 * len(devices)
    cfg = study(ARGS.scenarios, ARGS.realizations, chunk)
    factory = SimFactory(cfg.scenario_dict)
    with tempfile.TemporaryDirectory() as td:
        res = run_sweep(cfg, factory, Path(td) / "sweep", progress=sys.stderr.isatty())
        wall = time.perf_counter() - T_START
    st = res.stats
    n = int(st["scenarios"])
    ds = res.dataset
    compile_s = st["compile_full_s"] + st["compile_eval_s"]
    window_s = OUTAGE_S + RECOVERY_S
    jax_scen_s = n / wall
    steady = n / max(st["eval_s"] + st["full_run_s"], 1e-9)
    if ARGS.numpy_scenarios > 0:
        np_s_per, max_diff = numpy_reference(factory, ARGS.numpy_scenarios)
    else:
        np_s_per, max_diff = float("nan"), float("nan")
    figures = {
        "scenarios": n,
        "devices": len(devices),
        "wall_s": round(wall, 2),
        "compile_s": round(compile_s, 2),
        "engine_eval_s": round(st["eval_s"], 2),
        "engine_full_runs_s": round(st["full_run_s"], 2),
        "scenarios_per_s": round(jax_scen_s, 2),
        "scenarios_per_s_steady": round(steady, 2),
        "nav_seconds_per_s": round(n * window_s / wall, 1),
        "numpy_s_per_scenario": round(np_s_per, 3),
        "numpy_ratio": round(jax_scen_s * np_s_per, 1),
        "numpy_ratio_steady": round(steady * np_s_per, 1),
        "numpy_max_pos_diff_m": float(f"{max_diff:.3g}"),
        "peak_rss_mb": round(benchutil.peak_rss_mb(), 1),
        "mean_max_2d_m_by_kept": {
            int(k): round(float(ds["max_2d_m"].sel(satellites_kept=k).mean()), 3)
            for k in ds["satellites_kept"].values
        },
    }
    table = "\n".join(
        [
            "| figure | value |",
            "|---|---|",
            *(f"| {k} | {v} |" for k, v in figures.items() if not isinstance(v, dict)),
        ]
    )
    body = (
        f"Reference sweep: INS15 (SPAN-CPT class, 100 Hz) + float PPP (IF code+carrier, Doppler, "
        f"ZWD), 12 GPS slots, {OUTAGE_S}-s outages keeping {list(KEPT)} satellites + "
        f"{RECOVERY_S} s recovery, {ARGS.realizations} realisation(s), chunk {chunk}, "
        f"{len(devices)} CPU device(s). Wall time from process start (drive simulation and "
        f"compilation included). NumPy: {ARGS.numpy_scenarios} scenario window(s) of the same "
        f"filter from the same checkpoint.\n\n{table}\n\nMean max 2D error by satellites kept "
        f"[m]: {figures['mean_max_2d_m_by_kept']}"
    )
    print(body)
    if not ARGS.no_append:
        benchutil.append_results("sweep_throughput", body, figures, ARGS.results)
    benchutil.print_json_line(figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
