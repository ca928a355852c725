"""Scaling of the outage-scenario filter: wall time and memory versus batch size, outage length,
number of satellite slots and state size, for full-IMU and RISS systems.

Unit of work: one scenario = the tight filter (``jaxnav.filter.tight.run``) run from a checkpoint
carry over an outage window (outage epochs + recovery epochs) with a keep mask, i.e. what
``jaxnav.study.engine._one_scenario`` does without the engine's gathers and metrics. The harness
times ``jax.jit(jax.vmap(lambda carry, inputs: tight.run(tf, carry, inputs)))`` on B copies of one
window (the checkpoint carry is the filter state after ``CKPT_S`` seconds of the drive; the B
copies differ in their keep masks: scenario b keeps ``b % 4`` satellites during the outage).
Batches wider than ``CHUNK`` (64, the engine's default chunk) run as sequential chunks of 64
(one compiled shape); single calls wider than 64 run in a subprocess with a timeout, because
XLA:CPU has stalled on wide batched solves (reported "stalled", never a hang). The real engine
(``run_sweep``) is timed at two sizes to show its overhead over the bare filter.

Memory: per measurement, the XLA buffer footprint of the compiled call
(``compiled.memory_analysis()``: arguments + outputs + temporaries, in MB) - deterministic and
independent of what else the process did; the subprocess widths also report their process's peak
RSS (``ru_maxrss``), and the main process's peak RSS is printed at the end.

Compile time (``.lower().compile()``) is measured separately and never included in run times.
Run ``python benchmarks/scaling.py`` (about 5 min on 2 shared cores) or ``--quick`` (< 45 s).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

# jaxlib's LAPACK custom calls (the update's Cholesky and triangular solves) run in OpenBLAS,
# whose threads spin-wait for each other: on a shared, oversubscribed 2-core machine a 64 x 90
# window took 44-53 s with the default thread count and 0.13-0.18 s with one thread (measured
# 2026-11-22). One thread per process unless the caller sets OPENBLAS_NUM_THREADS explicitly;
# must precede the first import of numpy / jaxlib. README "OpenBLAS threads".
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import benchutil as bu  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import jaxnav  # noqa: E402, F401  (float64, XLA flags)
from jaxnav.filter import tight  # noqa: E402

CHUNK = 64  # the engine's default chunk size (wider vmaps of long scans stalled XLA:CPU)
CKPT_S = 90.0  # checkpoint: after the drives' 60 s standstill and 30 s of driving
RECOVERY_S = 30.0  # recovery epochs evaluated after the outage (as the reference sweep)
MODE = "float_ppp"  # the reference sweep's PPP mode (IF code + carrier)
SYSTEMS_MAIN = ("ins15", "riss")  # full IMU (100 Hz inputs) and RISS (1 Hz inputs)
MIN_TIMED_S = 0.3  # repeat small calls until at least this much time is measured
SAT_TOL = 0.10  # saturation: per-scenario cost within 10 % of the best at any larger batch
PLOTS = HERE / "plots"


# ----------------------------------------------------------------------------------------------
# Problems and windows
# ----------------------------------------------------------------------------------------------
class Window(NamedTuple):
    """One scenario's work: a filter, a checkpoint carry and a window of inputs."""

    tf: Any
    carry: Any  # unbatched checkpoint carry
    inputs: Any  # [W, ...] unbatched inputs (full availability in keep)
    outage_epochs: int
    system: str
    gps_slots: int

    @property
    def n_epochs(self) -> int:
        return int(self.inputs.keep.shape[0])

    @property
    def n_states(self) -> int:
        return int(self.tf.layout.size)


_FACTORIES: dict = {}
_CKPT: dict = {}


def factory(gps_slots: int, duration_s: float):
    """A simulated-drive factory (cached): GPS + 14 GLONASS/Galileo slots (unused: GPS only)."""
    from jaxnav.study.factory import SimFactory

    key = (gps_slots, duration_s)
    if key not in _FACTORIES:
        _FACTORIES[key] = SimFactory({"slots": [gps_slots, 14, 14], "duration_s": duration_s})
    return _FACTORIES[key]


def checkpoint(system: str, gps_slots: int, duration_s: float, ckpt_s: float = CKPT_S,
               mode: str = MODE):
    """(tf, carry at ckpt_s, full inputs, epoch interval) of one problem (cached). The carry is
    the full-availability filter run up to ``ckpt_s`` (0: the problem's initial carry)."""
    key = (system, gps_slots, duration_s, ckpt_s, mode)
    if key not in _CKPT:
        fac = factory(gps_slots, duration_s)
        prob = fac.build(None, mode, system, 0)
        c = round(ckpt_s / fac.cfg.epoch_interval_s)
        carry = prob.carry0
        if c > 0:
            head = jax.tree.map(lambda a: a[:c], prob.inputs)
            carry, _ = jax.jit(tight.run)(prob.tf, prob.carry0, head)
        _CKPT[key] = (prob.tf, jax.block_until_ready(carry), prob.inputs,
                      fac.cfg.epoch_interval_s)
    return _CKPT[key]


def make_window(system: str, gps_slots: int = 12, outage_s: float = 60.0,
                recovery_s: float = RECOVERY_S, duration_s: float = 360.0,
                ckpt_s: float = CKPT_S, mode: str = MODE) -> Window:
    """The window [ckpt_s, ckpt_s + outage + recovery) of a drive, from its checkpoint."""
    tf, carry, inputs, dt = checkpoint(system, gps_slots, duration_s, ckpt_s, mode)
    c = round(ckpt_s / dt)
    n_out = round(outage_s / dt)
    w = n_out + round(recovery_s / dt)
    if c + w > inputs.keep.shape[0]:
        raise ValueError(f"window of {w} epochs after {c} does not fit a {duration_s} s drive")
    win = jax.tree.map(lambda a: a[c:c + w], inputs)
    return Window(tf, carry, win, n_out, system, gps_slots)


def keep_masks(base_keep, n_outage: int, batch: int) -> np.ndarray:
    """[B, W, S] masks: scenario b keeps its first ``b % 4`` available slots during the outage."""
    base = np.asarray(base_keep, bool)
    rank = np.cumsum(base, axis=-1)  # 1-based rank of each available slot
    n_keep = (np.arange(batch) % 4)[:, None, None]
    in_outage = (np.arange(base.shape[0]) < n_outage)[None, :, None]
    return base[None] & (~in_outage | (rank[None] <= n_keep))


def batched(win: Window, batch: int):
    """(carry, inputs) with a leading batch axis: copies of the window, varying keep masks."""
    carry = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a)), win.carry)
    inputs = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), win.inputs)
    inputs = inputs._replace(keep=jnp.asarray(keep_masks(win.inputs.keep, win.outage_epochs,
                                                         batch)))
    return jax.device_put(carry), jax.device_put(inputs)


def window_fn(tf):
    """The timed function: vmap of the filter over a batch of (carry, window inputs)."""
    return jax.jit(jax.vmap(lambda carry, inputs: tight.run(tf, carry, inputs)))


def memory_mb(compiled) -> float:
    """XLA buffer footprint of a compiled call: arguments + outputs + temporaries [MB]."""
    m = compiled.memory_analysis()
    total = (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
             - m.alias_size_in_bytes)
    return total / 2**20


def compile_window(win: Window, width: int):
    """(compiled call, its arguments, compile time [s])."""
    args = batched(win, width)
    with bu.Timer() as t:
        compiled = window_fn(win.tf).lower(*args).compile()
    return compiled, args, t.s


class Point(NamedTuple):
    """One measurement: ``batch`` scenarios as ceil(batch / width) calls of ``width``."""

    system: str
    batch: int
    width: int  # scenarios per call
    epochs: int
    gps_slots: int
    states: int
    compile_s: float
    call_min_s: float  # fastest call (least disturbed by the other jobs on the machine)
    call_median_s: float
    xla_mb: float
    calls_timed: int = 0  # calls actually timed (fewer than ``calls``: wall extrapolated)

    @property
    def calls(self) -> int:
        return -(-self.batch // self.width)

    @property
    def per_scenario_ms(self) -> float:
        """Best-case cost per scenario: fastest call / width (the figure the curves use)."""
        return 1e3 * self.call_min_s / self.width

    @property
    def per_scenario_median_ms(self) -> float:
        return 1e3 * self.call_median_s / self.width

    @property
    def wall_s(self) -> float:
        """Wall time of the whole batch at the median call time."""
        return self.calls * self.call_median_s

    @property
    def per_epoch_us(self) -> float:
        return 1e3 * self.per_scenario_ms / self.epochs


def measure(win: Window, batches, chunk: int = CHUNK, cache: dict | None = None,
            max_s: float = float("inf")) -> list[Point]:
    """Time each batch size as calls of width min(batch, chunk); compiled calls cached."""
    cache = {} if cache is None else cache
    pts = []
    for b in batches:
        w = min(b, chunk)
        if w not in cache:
            cache[w] = compile_window(win, w)
        compiled, args, comp_s = cache[w]
        t = bu.time_calls(compiled, args, -(-b // w), min_s=MIN_TIMED_S, min_reps=3, max_s=max_s)
        p = Point(win.system, b, w, win.n_epochs, win.gps_slots, win.n_states, comp_s,
                  float(t.min()), float(np.median(t)), memory_mb(compiled), int(t.size))
        pts.append(p)
        print(f"  {win.system:6s} B={b:5d} width={w:3d} W={win.n_epochs:4d} "
              f"slots={win.gps_slots:2d} n={win.n_states:3d}: {p.per_scenario_ms:8.2f} "
              f"ms/scenario "
              f"(median {p.per_scenario_median_ms:8.2f}; {t.size} calls timed, batch = {p.calls}), "
              f"batch wall {p.wall_s:6.2f} s, compile {comp_s:5.1f} s, XLA {p.xla_mb:7.1f} MB",
              flush=True)
    return pts


def saturation(points: list[Point]) -> tuple[int, bool, float]:
    """(first batch whose per-scenario cost is within SAT_TOL of the best at any batch >= it,
    flat afterwards?, worst ratio of a later cost to the saturated cost)."""
    cost = [p.per_scenario_ms for p in points]
    sat = points[-1].batch
    for i, p in enumerate(points):
        if cost[i] <= (1.0 + SAT_TOL) * min(cost[i:]):
            sat = p.batch
            i_sat = i
            break
    worst = max(cost[i_sat:]) / cost[i_sat]
    return sat, worst <= 1.25, worst


# ----------------------------------------------------------------------------------------------
# Guarded subprocess points (wide single calls, two devices)
# ----------------------------------------------------------------------------------------------
def run_guarded(cmd: list[str], timeout_s: float, env: dict | None = None) -> dict:
    """Run ``cmd``; its last stdout line is JSON. {"status": "ok" | "stalled" | "failed", ...}.

    A stalled XLA:CPU call never returns, so the child is killed after ``timeout_s``
    (``subprocess.run`` kills only the process it started)."""
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env)
    except subprocess.TimeoutExpired:
        return {"status": "stalled", "elapsed_s": time.perf_counter() - t0}
    lines = r.stdout.strip().splitlines()
    if r.returncode != 0 or not lines:
        return {"status": "failed", "returncode": r.returncode, "stderr": r.stderr[-400:]}
    try:
        out = json.loads(lines[-1])
    except json.JSONDecodeError:
        return {"status": "failed", "returncode": r.returncode, "stdout": lines[-1][-400:]}
    return {"status": "ok", **out, "elapsed_s": time.perf_counter() - t0}


def save_window(win: Window, path: Path) -> None:
    host = jax.device_get((win.carry, win.inputs))
    with path.open("wb") as f:
        pickle.dump((win.tf, host, win.outage_epochs, win.system, win.gps_slots), f)


def worker(path: str, width: int, devices: int, min_s: float = 0.0) -> None:
    """Subprocess: one call of ``width`` scenarios (on ``devices`` devices), printed as JSON;
    calls repeat until ``min_s`` seconds were timed."""
    with open(path, "rb") as f:
        tf, (carry, inputs), n_out, system, slots = pickle.load(f)
    win = Window(tf, carry, inputs, n_out, system, slots)
    args = batched(win, width)
    fn = jax.vmap(lambda c, i: tight.run(tf, c, i))
    if devices > 1:
        from jax.sharding import Mesh, NamedSharding
        from jax.sharding import PartitionSpec as Spec

        devs = jax.local_devices()[:devices]
        if len(devs) < devices:
            raise SystemExit(f"{len(devs)} devices, {devices} asked")
        mesh = Mesh(np.array(devs), ("batch",))
        fn = jax.shard_map(fn, mesh=mesh, in_specs=Spec("batch"), out_specs=Spec("batch"),
                           check_vma=False)
        args = jax.device_put(args, NamedSharding(mesh, Spec("batch")))
    with bu.Timer() as tc:
        compiled = jax.jit(fn).lower(*args).compile()
    t = bu.time_calls(compiled, args, 1, min_s=min_s, min_reps=3)
    print(json.dumps({"width": width, "devices": devices, "compile_s": tc.s,
                      "call_min_s": float(t.min()), "call_median_s": float(np.median(t)),
                      "per_scenario_ms": 1e3 * float(t.min()) / width,
                      "per_scenario_median_ms": 1e3 * float(np.median(t)) / width,
                      "xla_mb": memory_mb(compiled),
                      "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def guarded_point(win_path: Path, width: int, devices: int = 1, timeout_s: float = 120.0,
                  openblas_default: bool = False, min_s: float = 0.0):
    """One subprocess point; ``openblas_default``: without OPENBLAS_NUM_THREADS (all cores)."""
    env = dict(os.environ)
    if openblas_default:
        env.pop("OPENBLAS_NUM_THREADS", None)
    if devices > 1:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "")
                            + f" --xla_force_host_platform_device_count={devices}").strip()
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(win_path),
           "--width", str(width), "--devices", str(devices), "--min-s", str(min_s)]
    r = run_guarded(cmd, timeout_s, env)
    tag = (f"width {width}" + (f" on {devices} devices" if devices > 1 else "")
           + (", OpenBLAS default threads" if openblas_default else ""))
    if r["status"] == "ok":
        print(f"  subprocess {tag}: {r['per_scenario_ms']:.2f} ms/scenario, compile "
              f"{r['compile_s']:.1f} s, XLA {r['xla_mb']:.1f} MB, RSS {r['rss_mb']:.0f} MB",
              flush=True)
    else:
        print(f"  subprocess {tag}: {r['status'].upper()} "
              f"({r.get('elapsed_s', 0):.0f} s; {r.get('stderr', '')[-200:]})", flush=True)
    return r


def processes_point(win_path: Path, width: int, n_procs: int, timeout_s: float = 240.0,
                    min_s: float = 15.0) -> dict:
    """``n_procs`` worker processes at once, each timing calls of ``width`` scenarios for
    ``min_s`` s: the throughput of running the engine's chunks in one process per core.
    Aggregate ms/scenario = slowest process's median call / (width x n_procs)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(win_path),
           "--width", str(width), "--devices", "1", "--min-s", str(min_s)]
    with ThreadPoolExecutor(n_procs) as pool:
        runs = list(pool.map(lambda _: run_guarded(cmd, timeout_s, dict(os.environ)),
                             range(n_procs)))
    if any(r["status"] != "ok" for r in runs):
        bad = next(r for r in runs if r["status"] != "ok")
        print(f"  {n_procs} processes x width {width}: {bad['status'].upper()}", flush=True)
        return {"status": bad["status"]}
    med = max(r["call_median_s"] for r in runs)
    out = {"status": "ok", "per_process_ms": [1e3 * r["call_median_s"] / width for r in runs],
           "aggregate_ms": 1e3 * med / (width * n_procs),
           "rss_mb": sum(r["rss_mb"] for r in runs)}
    print(f"  {n_procs} processes x width {width} at once: "
          + ", ".join(f"{v:.2f}" for v in out["per_process_ms"])
          + f" ms/scenario each (median call) -> {out['aggregate_ms']:.2f} ms/scenario aggregate",
          flush=True)
    return out


# ----------------------------------------------------------------------------------------------
# The real engine
# ----------------------------------------------------------------------------------------------
def engine_point(system: str, realizations: int, spacing_s: float, duration_s: float,
                 out_dir: Path) -> dict:
    """run_sweep of a 60 s outage study (4 satellites-kept levels, grid placements)."""
    from jaxnav.study import config, sweep
    from jaxnav.study.factory import SimFactory

    fac = factory(12, duration_s)
    d = {
        "study": {"name": "bench_scaling", "modes": [MODE], "systems": [system],
                  "durations_s": [60], "satellites_kept": [0, 1, 2, 3], "policies": ["highest"],
                  "realizations": realizations, "seed": 0, "recovery_s": RECOVERY_S,
                  "chunk_size": CHUNK, "max_traces": 0},
        "placement": {"kind": "grid", "convergence_s": CKPT_S, "spacing_s": spacing_s},
        "scenario": dict(fac.table),
    }
    cfg = config.from_dict(d, modes=SimFactory.modes, systems=SimFactory.systems)
    with bu.Timer() as t:
        res = sweep.run_sweep(cfg, fac, out_dir, overwrite=True, progress=False)
    st = res.stats
    n = int(st["scenarios"])
    compile_s = st["compile_full_s"] + st["compile_eval_s"]
    out = {"scenarios": n, "wall_s": t.s, "compile_s": compile_s,
           "full_run_s": st["full_run_s"], "eval_s": st["eval_s"],
           "per_scenario_ms": 1e3 * (t.s - compile_s) / n,
           "eval_per_scenario_ms": 1e3 * st["eval_s"] / n}
    print(f"  engine {system} {n:5d} scenarios: wall {t.s:.1f} s (compile {compile_s:.1f} s, "
          f"full runs {st['full_run_s']:.1f} s, chunk evaluation {st['eval_s']:.1f} s) -> "
          f"{out['per_scenario_ms']:.2f} ms/scenario excl. compile", flush=True)
    return out


# ----------------------------------------------------------------------------------------------
# Plots and tables
# ----------------------------------------------------------------------------------------------
def plot_curve(path: Path, title: str, xlabel: str, series: dict, logx: bool = False) -> None:
    """Two panels: ms per scenario and XLA MB versus x, one line per system."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    for name, (x, ms, mb) in series.items():
        a1.plot(x, ms, "o-", label=name)
        a2.plot(x, mb, "o-", label=name)
    for a, yl in ((a1, "wall time per scenario [ms]"), (a2, "XLA buffers per call [MB]")):
        a.set_xlabel(xlabel)
        a.set_ylabel(yl)
        a.grid(True, alpha=0.3)
        if logx:
            a.set_xscale("log", base=2)
        a.legend()
    a1.set_ylim(bottom=0)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def table(points: list[Point], key: str) -> str:
    head = (f"| system | {key} | states | epochs | width x calls | ms/scenario (best) | "
            "ms/scenario (median) | us/scenario-epoch | batch wall s | compile s | XLA MB |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for p in points:
        x = {"batch": p.batch, "slots": p.gps_slots, "epochs": p.epochs,
             "states": p.states}[key]
        extra = "" if p.calls_timed >= p.calls else f" ({p.calls_timed} timed)"
        rows.append(f"| {p.system} | {x} | {p.states} | {p.epochs} | "
                    f"{p.width} x {p.calls}{extra} | "
                    f"{p.per_scenario_ms:.2f} | {p.per_scenario_median_ms:.2f} | "
                    f"{p.per_epoch_us:.1f} | {p.wall_s:.2f} | {p.compile_s:.1f} | "
                    f"{p.xla_mb:.1f} |")
    return head + "\n" + "\n".join(rows)


def _series(groups: dict, x_of) -> dict:
    return {k: ([x_of(p) for p in v], [p.per_scenario_ms for p in v], [p.xla_mb for p in v])
            for k, v in groups.items() if v}


# ----------------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------------
FULL = {
    "duration_s": 360.0, "ckpt_s": CKPT_S, "chunk": CHUNK, "ref_len_s": 60.0,
    "batches": [1, 4, 16, 64, 256, 1024, 4096], "lengths_s": [10.0, 30.0, 60.0, 120.0],
    "slots": [8, 12, 16], "states": ["ins15", "ins21", "riss", "riss9"],
    "wide": [128, 256], "engine": [(1, 12.0), (4, 12.0)],  # (realizations, spacing): 64, 256
    # A batch point stops timing after 15 s (wall extrapolated, flagged): its calls all have the
    # engine's width, so more calls only repeat the per-call cost (measured 2026-12-01: the
    # 4096-scenario points gave 22.07 ms after 40 calls vs 22.35 ms for one call of 64).
    "max_point_s": 15.0,
}
QUICK = {  # compile-bound: 6 compiled shapes; chunk 16 so that B = 32 runs as 2 chunks
    "duration_s": 90.0, "ckpt_s": 0.0, "chunk": 16, "ref_len_s": 10.0,
    "batches": [1, 16, 32], "lengths_s": [10.0, 20.0], "slots": [12],
    "states": ["ins15", "riss"], "wide": [], "engine": [], "max_point_s": 20.0,
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (< 45 s), for the tests")
    ap.add_argument("--results", type=Path, default=bu.RESULTS_MD, help="RESULTS.md to append to")
    ap.add_argument("--plots", type=Path, default=PLOTS, help="directory of the PNG plots")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--width", type=int, default=CHUNK, help=argparse.SUPPRESS)
    ap.add_argument("--devices", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--min-s", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(args.worker, args.width, args.devices, args.min_s)
        return 0

    t_start = time.perf_counter()
    cfg = QUICK if args.quick else FULL
    chunk, ref_len, dur, ck = cfg["chunk"], cfg["ref_len_s"], cfg["duration_s"], cfg["ckpt_s"]
    m = bu.machine()
    print(f"scaling{' --quick' if args.quick else ''}: {m['cores']} cores, {m['cpu']}, jax "
          f"{m['jax']}, devices {jax.local_devices()}; chunk {chunk}; mode {MODE}; XLA_FLAGS "
          f"{os.environ.get('XLA_FLAGS', '')!r}; OPENBLAS_NUM_THREADS "
          f"{os.environ.get('OPENBLAS_NUM_THREADS')}; load average {os.getloadavg()[0]:.1f}",
          flush=True)

    def window(system, slots=12, length=ref_len):
        return make_window(system, slots, length, duration_s=dur, ckpt_s=ck)

    figures: dict = {"chunk": chunk, "batch_max": cfg["batches"][-1]}
    md: list[str] = [
        f"Unit: one scenario = `tight.run` from a checkpoint carry (t = {ck:g} s) over an outage "
        f"window + {RECOVERY_S:g} s recovery, mode {MODE}; batches wider than {chunk} run as "
        f"sequential calls of {chunk}. ms/scenario (best) = fastest call / width (least "
        "disturbed by the other jobs); median = median call / width. OPENBLAS_NUM_THREADS="
        f"{os.environ.get('OPENBLAS_NUM_THREADS')}. Load average at start "
        f"{os.getloadavg()[0]:.1f} on {m['cores']} cores.", ""]

    # 1. batch size (full IMU and RISS), reference window
    print(f"\n[batch size] window = {ref_len:g} s outage + {RECOVERY_S:g} s recovery, 12 GPS "
          f"slots", flush=True)
    batch_pts: dict[str, list[Point]] = {}
    for s in SYSTEMS_MAIN:
        cache: dict = {}
        batch_pts[s] = measure(window(s), cfg["batches"], chunk, cache, cfg["max_point_s"])
        sat, flat, worst = saturation(batch_pts[s])
        pts = batch_pts[s]
        figures[f"saturation_batch_{s}"] = sat
        figures[f"flat_after_saturation_{s}"] = flat
        figures[f"per_scenario_ms_{s}_b1"] = round(pts[0].per_scenario_ms, 3)
        figures[f"per_scenario_ms_{s}_bmax"] = round(pts[-1].per_scenario_ms, 3)
        figures[f"speedup_{s}_bmax_vs_b1"] = round(pts[0].per_scenario_ms
                                                   / pts[-1].per_scenario_ms, 2)
        figures[f"xla_mb_{s}_b1"] = round(pts[0].xla_mb, 3)
        figures[f"xla_mb_{s}_bmax"] = round(pts[-1].xla_mb, 3)
        figures[f"compile_s_{s}_w1"] = round(cache[1][2], 2)
        figures[f"compile_s_{s}_w{chunk}"] = round(cache[chunk][2], 2)
        print(f"  -> {s}: saturates at B = {sat} (cost within {SAT_TOL:.0%} of the best at any "
              f"larger batch); worst later/saturated ratio {worst:.2f} "
              f"({'flat' if flat else 'NOT flat'})", flush=True)
    plot_curve(args.plots / "scaling_batch.png",
               f"Cost per scenario vs batch ({ref_len:g}+{RECOVERY_S:g} s window, calls of "
               f"<= {chunk})", "scenarios per batch", _series(batch_pts, lambda p: p.batch),
               logx=True)
    md += ["### Batch size", "", table([p for v in batch_pts.values() for p in v], "batch"), "",
           f"Saturation (first batch within {SAT_TOL:.0%} of the best later cost): "
           + ", ".join(f"{s} B = {figures[f'saturation_batch_{s}']} (then "
                       f"{'flat' if figures[f'flat_after_saturation_{s}'] else 'NOT flat'})"
                       for s in SYSTEMS_MAIN), ""]
    ref = {s: next(p for p in batch_pts[s] if p.batch == chunk) for s in SYSTEMS_MAIN}

    # 2. single-call vmap width (subprocess with timeout) and two devices
    if cfg["wide"]:
        print(f"\n[vmap width] single calls wider than {chunk} and 2 devices, in subprocesses "
              "with a timeout", flush=True)
        rows = ["| call | status | ms/scenario (best) | ms/scenario (median) | compile s | "
                "XLA MB | process RSS MB |", "|---|---|---|---|---|---|---|"]
        p64 = ref["ins15"]
        rows.append(f"| ins15, width {chunk}, in process | ok | {p64.per_scenario_ms:.2f} | "
                    f"{p64.per_scenario_median_ms:.2f} | {p64.compile_s:.1f} | "
                    f"{p64.xla_mb:.1f} | - |")
        ok = []
        with tempfile.TemporaryDirectory() as tmp:
            wpath = Path(tmp) / "window.pkl"
            save_window(window("ins15"), wpath)
            for w, ndev, obd in ([(w, 1, False) for w in cfg["wide"]]
                                 + [(2 * chunk, 2, False), (chunk, 1, True)]):
                # a stalled call never returns: 60 s is 3x a healthy point's compile + calls
                r = guarded_point(wpath, w, ndev, timeout_s=180.0 if obd else 60.0,
                                  openblas_default=obd)
                key = (f"width_{w}" + (f"_dev{ndev}" if ndev > 1 else "")
                       + ("_openblas_default" if obd else ""))
                figures[f"vmap_{key}"] = r["status"]
                if r["status"] != "ok":
                    tag = f"ins15, width {w}, {ndev} device(s)" + " (OpenBLAS default)" * obd
                    rows.append(f"| {tag} | {r['status']} | - | - | - | - | - |")
                    continue
                figures[f"per_scenario_ms_ins15_{key}"] = round(r["per_scenario_ms"], 3)
                tag = f"ins15, width {w}, {ndev} device(s)" + " (OpenBLAS default)" * obd
                rows.append(f"| {tag} | ok | "
                            f"{r['per_scenario_ms']:.2f} | {r['per_scenario_median_ms']:.2f} | "
                            f"{r['compile_s']:.1f} | {r['xla_mb']:.1f} | {r['rss_mb']:.0f} |")
                if ndev == 1 and not obd:
                    ok.append((w, r))
            # Both cores without shard_map: one process per core, each with its own chunks.
            solo = guarded_point(wpath, chunk, 1, timeout_s=180.0, min_s=8.0)
            pair = processes_point(wpath, chunk, m["cores"], min_s=8.0)
            figures[f"processes_{m['cores']}"] = pair["status"]
            if solo["status"] == "ok" and pair["status"] == "ok":
                one = solo["per_scenario_median_ms"]
                figures[f"per_scenario_ms_ins15_{m['cores']}_processes"] = round(
                    pair["aggregate_ms"], 3)
                figures[f"speedup_{m['cores']}_processes"] = round(one / pair["aggregate_ms"], 2)
                rows.append(f"| ins15, 1 process alone, width {chunk} (8 s of calls) | ok | - | "
                            f"{one:.2f} | {solo['compile_s']:.1f} | {solo['xla_mb']:.1f} | "
                            f"{solo['rss_mb']:.0f} |")
                rows.append(f"| ins15, {m['cores']} processes at once, width {chunk} each "
                            f"(aggregate; x{one / pair['aggregate_ms']:.2f} vs 1 process) | ok | "
                            f"- | {pair['aggregate_ms']:.2f} | - | - | {pair['rss_mb']:.0f} |")
        if ok:
            plot_curve(args.plots / "scaling_width.png", "Single-call vmap width (ins15)",
                       "scenarios per call",
                       {"ins15": ([chunk] + [w for w, _ in ok],
                                  [p64.per_scenario_ms] + [r["per_scenario_ms"] for _, r in ok],
                                  [p64.xla_mb] + [r["xla_mb"] for _, r in ok])}, logx=True)
        md += ["### Single-call vmap width and devices (subprocesses with a timeout)", "",
               *rows, ""]

    # 3. outage length, 4. slots, 5. state size: one call of `chunk` scenarios each
    print(f"\n[outage length] B = {chunk}", flush=True)
    len_pts: dict[str, list[Point]] = {}
    for s in SYSTEMS_MAIN:
        len_pts[s] = [ref[s] if L == ref_len else measure(window(s, 12, L), [chunk], chunk)[0]
                      for L in cfg["lengths_s"]]
        v = len_pts[s]
        figures[f"us_per_epoch_{s}_longest_over_shortest"] = round(
            v[-1].per_epoch_us / v[0].per_epoch_us, 3)
    plot_curve(args.plots / "scaling_outage.png",
               f"Cost per scenario vs outage length (+{RECOVERY_S:g} s recovery, B = {chunk})",
               "window epochs (outage + recovery)", _series(len_pts, lambda p: p.epochs))
    md += [f"### Outage length (window = outage + {RECOVERY_S:g} s recovery)", "",
           table([p for v in len_pts.values() for p in v], "epochs"), ""]

    if len(cfg["slots"]) > 1:
        print(f"\n[satellite slots] B = {chunk}", flush=True)
        slot_pts: dict[str, list[Point]] = {}
        for s in SYSTEMS_MAIN:
            slot_pts[s] = [ref[s] if n == 12 else measure(window(s, n), [chunk], chunk)[0]
                           for n in cfg["slots"]]
        plot_curve(args.plots / "scaling_slots.png",
                   f"Cost per scenario vs GPS slots (B = {chunk})", "GPS satellite slots",
                   _series(slot_pts, lambda p: p.gps_slots))
        md += ["### Satellite slots", "", table([p for v in slot_pts.values() for p in v],
                                                "slots"), ""]
        for s in SYSTEMS_MAIN:
            figures[f"per_scenario_ms_{s}_slots{cfg['slots'][-1]}_over_slots{cfg['slots'][0]}"] = \
                round(slot_pts[s][-1].per_scenario_ms / slot_pts[s][0].per_scenario_ms, 3)

    print(f"\n[state size] B = {chunk}", flush=True)
    state_pts = [ref[s] if s in ref else measure(window(s), [chunk], chunk)[0]
                 for s in cfg["states"]]
    for p in state_pts:
        figures[f"per_scenario_ms_{p.system}_b{chunk}"] = round(p.per_scenario_ms, 3)
        figures[f"states_{p.system}"] = p.states
    fam = {"full IMU (100 Hz)": [p for p in state_pts if p.system.startswith("ins")],
           "RISS (1 Hz)": [p for p in state_pts if p.system.startswith("riss")]}
    plot_curve(args.plots / "scaling_state.png", f"Cost per scenario vs state size (B = {chunk})",
               "filter states (system + GNSS)", _series(fam, lambda p: p.states))
    md += ["### State size (12 GPS slots)", "", table(state_pts, "states"), ""]

    # 6. the real engine
    if cfg["engine"]:
        print("\n[engine] run_sweep (gathers, keep-mask policies, metrics, chunk files)",
              flush=True)
        rows = ["| scenarios | wall s | compile s | full runs s | chunk eval s | ms/scenario "
                "(excl. compile) | bare filter ms/scenario (median) |",
                "|---|---|---|---|---|---|---|"]
        bare = ref["ins15"].per_scenario_median_ms
        with tempfile.TemporaryDirectory() as tmp:
            for i, (n_real, spacing) in enumerate(cfg["engine"]):
                e = engine_point("ins15", n_real, spacing, dur, Path(tmp) / f"e{i}")
                rows.append(f"| {e['scenarios']} | {e['wall_s']:.1f} | {e['compile_s']:.1f} | "
                            f"{e['full_run_s']:.1f} | {e['eval_s']:.1f} | "
                            f"{e['per_scenario_ms']:.2f} | {bare:.2f} |")
                figures[f"engine_per_scenario_ms_{e['scenarios']}"] = round(
                    e["per_scenario_ms"], 3)
        figures["engine_over_bare_filter"] = round(e["per_scenario_ms"] / bare, 3)
        md += [f"### Engine (run_sweep, ins15, 60 s outages + {RECOVERY_S:g} s recovery, chunks "
               f"of {CHUNK}, one device)", "", *rows, ""]

    figures["peak_rss_mb"] = round(bu.peak_rss_mb(), 1)
    figures["total_s"] = round(time.perf_counter() - t_start, 1)
    figures["quick"] = bool(args.quick)
    md += [f"Process peak RSS {figures['peak_rss_mb']:.0f} MB; total {figures['total_s']:.0f} s. "
           "Memory columns: XLA buffers of one compiled call (arguments + outputs + "
           "temporaries, `memory_analysis()`); subprocess rows also give the process's peak RSS. "
           "The machine is shared with other jobs: the times are pessimistic."]
    print(f"\nprocess peak RSS {figures['peak_rss_mb']:.0f} MB; total {figures['total_s']:.0f} s",
          flush=True)
    bu.finish("scaling", args.quick, md, figures, args.results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
