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
    python benchmarks/sweep_throughput.py --workers 2   # + parallel efficiency, 1 vs 2 workers
    python benchmarks/sweep_throughput.py --workers 2 --scenarios 100000 --rounds 0

Workers (issue 18). With ``--workers N`` (N > 1) the script runs the sweep in fresh child
processes, alternating 1 worker (the in-process engine) and N Dask workers ``--rounds`` times,
each child with its own empty JAX compilation cache (so every wall time includes start-up,
the drive simulation and compilation), and reports ``parallel_efficiency`` = T1 / (N x TN)
from the median wall times. ``--rounds 0`` runs the N-worker sweep once, alone: for the long
sweep, whose figures are the workers' peak RSS, the sustained scenarios/s (chunks finished
after the first 10 %) and the projected time of a 10^6-scenario study.
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
    ap.add_argument("--workers", type=int, default=1,
                    help="Dask worker processes (N > 1: compare with 1, see --rounds)")
    ap.add_argument("--rounds", type=int, default=2,
                    help="with --workers N > 1: alternating 1 / N worker rounds (0: N only)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="64 scenarios, 1 NumPy scenario")
    ap.add_argument("--results", type=Path, default=HERE / "RESULTS.md",
                    help="Markdown file the figures are appended to")
    ap.add_argument("--no-append", action="store_true", help="print only, do not append")
    args = ap.parse_args(argv)
    if args.quick:
        args.scenarios, args.realizations, args.numpy_scenarios = 64, 1, 1
    if args.workers < 1 or args.rounds < 0:
        ap.error("--workers must be >= 1 and --rounds >= 0")
    if args.workers > 1 or args.child:
        args.numpy_scenarios = 0  # the NumPy ratio is a one-worker figure
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


def _worker_peak_rss_mb(client) -> list[float]:
    """Peak RSS of every Dask worker process so far [MB]."""
    import resource

    def rss():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    return sorted(round(v, 1) for v in client.run(rss).values())


def sweep_once():
    """The reference sweep in this process (with ``ARGS.workers`` Dask workers if > 1): its
    result, wall time from process start, per-worker peak RSS and chunk completion times."""
    devices = jax.devices()
    chunk = ARGS.chunk or 64 * len(devices)
    cfg = study(ARGS.scenarios, ARGS.realizations, chunk)
    factory = SimFactory(cfg.scenario_dict)
    done_at = []
    client = None
    if ARGS.workers > 1:
        from jaxnav.study import parallel

        client = parallel.local_client(ARGS.workers)
    try:
        with tempfile.TemporaryDirectory() as td:
            res = run_sweep(cfg, factory, Path(td) / "sweep", progress=sys.stderr.isatty(),
                            client=client,
                            on_chunk=lambda g, j: done_at.append(time.perf_counter()))
            wall = time.perf_counter() - T_START
        worker_rss = _worker_peak_rss_mb(client) if client is not None else []
    finally:
        if client is not None:
            cluster = client.cluster
            client.close()
            cluster.close()
    return res, factory, wall, chunk, worker_rss, done_at


def sustained(done_at: list[float], n: int) -> float:
    """Scenarios/s over the chunks finished after the first 10 % (compilation excluded)."""
    k = len(done_at) // 10
    if len(done_at) - k < 2:
        return float("nan")
    per_chunk = n / len(done_at)  # chunks are equal but the last
    return (len(done_at) - 1 - k) * per_chunk / (done_at[-1] - done_at[k])


def compare_workers() -> int:
    """Alternating child runs with 1 and ARGS.workers workers: the parallel efficiency."""
    import json
    import statistics
    import subprocess

    argv = [sys.executable, __file__, "--child", "--scenarios", str(ARGS.scenarios),
            "--realizations", str(ARGS.realizations), "--chunk", str(ARGS.chunk)]
    runs = {1: [], ARGS.workers: []}
    for _ in range(ARGS.rounds):
        for w in runs:
            with tempfile.TemporaryDirectory() as cache:  # cold compilation for every run
                env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=cache)
                out = subprocess.run([*argv, "--workers", str(w)], env=env, check=True,
                                     capture_output=True, text=True).stdout
            runs[w].append(json.loads(out.strip().splitlines()[-1]))
            print(f"workers {w}: wall {runs[w][-1]['wall_s']} s", file=sys.stderr)
    n = ARGS.workers

    def med(w, key):
        return statistics.median(r[key] for r in runs[w])

    t1, tn = med(1, "wall_s"), med(n, "wall_s")
    figures = {
        "scenarios": runs[1][0]["scenarios"], "workers": n, "rounds": ARGS.rounds,
        "wall_s_1_worker": [r["wall_s"] for r in runs[1]],
        f"wall_s_{n}_workers": [r["wall_s"] for r in runs[n]],
        "speedup": round(t1 / tn, 3),
        "parallel_efficiency": round(t1 / (n * tn), 3),
        "sustained_scenarios_per_s_1_worker": round(med(1, "sustained_scenarios_per_s"), 1),
        f"sustained_scenarios_per_s_{n}_workers": round(med(n, "sustained_scenarios_per_s"), 1),
        "sustained_efficiency": round(med(n, "sustained_scenarios_per_s")
                                      / (n * med(1, "sustained_scenarios_per_s")), 3),
        "compile_s_1_worker": med(1, "compile_s"),
        f"compile_s_{n}_workers_summed": med(n, "compile_s"),
        "peak_rss_mb_1_worker": med(1, "peak_rss_mb"),
        f"peak_rss_mb_per_worker_{n}_workers": max(max(r["worker_peak_rss_mb"])
                                                    for r in runs[n]),
        "identical_metrics": all(r["mean_max_2d_m_by_kept"] == runs[1][0]["mean_max_2d_m_by_kept"]
                                 for w in runs for r in runs[w]),
    }
    table = "\n".join(["| figure | value |", "|---|---|",
                       *(f"| {k} | {v} |" for k, v in figures.items())])
    body = (
        f"Reference sweep ({figures['scenarios']} scenarios, INS15 + float PPP, 12 GPS slots, "
        f"chunk {ARGS.chunk or 64}) in fresh processes, alternating 1 worker (in-process engine) "
        f"and {n} Dask LocalCluster workers, {ARGS.rounds} round(s), each with an empty "
        "compilation cache. Wall time from process start (cluster start-up, drive simulation "
        "and compilation included); parallel efficiency = T1 / (N x TN) from the medians; "
        "sustained = scenarios/s over the chunks finished after the first 10 %.\n\n" + table
    )
    print(body)
    if not ARGS.no_append:
        benchutil.append_results(f"sweep_throughput --workers {n}", body, figures, ARGS.results)
    benchutil.print_json_line(figures)
    return 0


def main() -> int:
    if ARGS.workers > 1 and ARGS.rounds > 0 and not ARGS.child:
        return compare_workers()
    devices = jax.devices()
    res, factory, wall, chunk, worker_rss, done_at = sweep_once()
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
        "workers": ARGS.workers,
        "worker_peak_rss_mb": worker_rss,
        "sustained_scenarios_per_s": round(sustained(done_at, n), 2),
        "projected_1e6_scenarios_h": round(
            (wall - n / sustained(done_at, n) + 1e6 / sustained(done_at, n)) / 3600, 2),
        "mean_max_2d_m_by_kept": {
            int(k): round(float(ds["max_2d_m"].sel(satellites_kept=k).mean()), 3)
            for k in ds["satellites_kept"].values
        },
    }
    table = "\n".join(
        [
            "| figure | value |",
            "|---|---|",
            *(f"| {k} | {v} |" for k, v in figures.items() if not isinstance(v, dict | list)),
        ]
    )
    body = (
        f"Reference sweep: INS15 (SPAN-CPT class, 100 Hz) + float PPP (IF code+carrier, Doppler, "
        f"ZWD), 12 GPS slots, {OUTAGE_S}-s outages keeping {list(KEPT)} satellites + "
        f"{RECOVERY_S} s recovery, {ARGS.realizations} realisation(s), chunk {chunk}, "
        f"{len(devices)} CPU device(s), {ARGS.workers} worker(s). Wall time from process start "
        f"(drive simulation and compilation included). NumPy: {ARGS.numpy_scenarios} scenario "
        f"window(s) of the same filter from the same checkpoint.\n\n{table}\n\nMean max 2D "
        f"error by satellites kept [m]: {figures['mean_max_2d_m_by_kept']}"
    )
    print(body)
    if worker_rss:
        body += f"\n\nPeak RSS per worker [MB]: {worker_rss}"
    if not ARGS.no_append and not ARGS.child:
        title = "sweep_throughput" + (f" --workers {ARGS.workers}" if ARGS.workers > 1 else "")
        benchutil.append_results(title, body, figures, ARGS.results)
    benchutil.print_json_line(figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
