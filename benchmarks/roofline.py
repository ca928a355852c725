"""Roofline of the reference sweep's filter: FLOPs per epoch, achieved FLOP rate, dgemm peak.

Reference workload (as ``sweep_throughput.py``): tightly coupled float PPP (IF code + carrier) /
INS15, 100 Hz IMU, 1 Hz GNSS, 12 GPS slots, 60 s outages + 30 s recovery, one scenario = the
tight filter run from a checkpoint carry over that window (``scaling.py``'s harness), 64
scenarios per call (the engine's chunk).

FLOPs. ``compiled.cost_analysis()['flops']`` of the vmapped ``tight.epoch_step`` is XLA's count,
but (a) XLA counts a while loop's body once, whatever its trip count, so the 100-sample
mechanization scan inside the epoch is counted as one sample (and a whole-window ``run`` as one
epoch: printed below as a check), and (b) the Cholesky factorisations and triangular solves of
the update are LAPACK custom calls, which XLA counts as 0. So

    flops/epoch = XLA(epoch_step) + (K - 1) * XLA(one mechanization sample) + LAPACK(analytic)

with the per-sample body from XLA counts of ``system.propagate`` over 1, 10 and 100 samples
(body = P(1) - (P(100) - P(10)) / 90: the per-sample work outside the loop removed), and LAPACK
flops n^3/3 per potrf and n^2 k per trsm (n x n triangle, k right-hand sides), read from the
shapes of the custom calls in the compiled HLO.

Peak. A 2048 x 2048 float64 matrix product measured in the same run: NumPy (OpenBLAS, all
cores: the headline ``dgemm_gflops``) and ``jax.jit(jnp.dot)`` (XLA:CPU with jaxnav's
single-threaded Eigen: one core, the peak the filter itself could reach).

Profile: the epoch's sub-steps timed separately at the same batch (mechanization inner scan,
covariance propagation, and the rest = rows + resets + the update and its post-fit tests +
feedback), each as a
``lax.scan`` over the window's epochs so dispatch is amortised.

Times are the fastest of several calls (the machine is shared; medians are printed too).
Run ``python benchmarks/roofline.py`` (about 1-2 min on 2 idle cores) or ``--quick`` (< 45 s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

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
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import scaling as sc  # noqa: E402

from jaxnav.filter import tight  # noqa: E402

FULL = {"duration_s": 200.0, "ckpt_s": sc.CKPT_S, "outage_s": 60.0, "batch": 64, "dgemm_n": 2048,
        "calls": 5}
QUICK = {"duration_s": 90.0, "ckpt_s": 0.0, "outage_s": 10.0, "batch": 16, "dgemm_n": 1024,
         "calls": 3}


def _bcast(x, batch: int):
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a)), x)


def xla_cost(fn, *args, compiled_out: list | None = None) -> tuple[dict, str]:
    """(cost_analysis dict, compiled HLO text) of jit(fn) at these arguments."""
    compiled = jax.jit(fn).lower(*args).compile()
    if compiled_out is not None:
        compiled_out.append(compiled)
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    return cost, compiled.as_text()


_SHAPE = r"f64\[(\d+(?:,\d+)*)\]"


def lapack_flops(hlo: str) -> tuple[float, dict]:
    """Analytic FLOPs of the LAPACK custom calls XLA counts as 0: potrf n^3/3, trsm n^2 k."""
    total, counts = 0.0, {"potrf": 0, "trsm": 0, "max_n": 0}
    for line in hlo.splitlines():
        if "lapack_dpotrf" in line:
            dims = [int(d) for d in re.search(_SHAPE, line).group(1).split(",")]
            n, batch = dims[-1], int(np.prod(dims[:-2]))
            total += batch * n**3 / 3.0
            counts["potrf"] += 1
            counts["max_n"] = max(counts["max_n"], n)
        elif "lapack_dtrsm" in line:
            out = [int(d) for d in re.search(_SHAPE, line).group(1).split(",")]
            tri = re.search(r"operand_layout_constraints=\{" + _SHAPE, line)
            n = int(tri.group(1).split(",")[-1]) if tri else out[-2]
            k = out[-1] if out[-2] == n else out[-2]
            total += int(np.prod(out[:-2])) * n * n * k
            counts["trsm"] += 1
    return total, counts


def best_time(fn, args, calls: int) -> tuple[float, float]:
    """(fastest, median) wall time [s] of ``calls`` calls after a warm-up call."""
    ts = bu.time_calls(fn, args, calls)
    return float(min(ts)), float(np.median(ts))


_NUMPY_DGEMM = """
import json, sys, time
import numpy as np
n = int(sys.argv[1]); rng = np.random.default_rng(0)
a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
a @ b
ts = []
for _ in range(3):
    t0 = time.perf_counter(); a @ b; ts.append(time.perf_counter() - t0)
print(json.dumps({"gflops": 2.0 * n**3 / min(ts) / 1e9}))
"""


def dgemm(n: int, reps: int = 3) -> dict:
    """GFLOP/s of an n x n float64 product: NumPy/OpenBLAS on all cores (a subprocess with
    OPENBLAS_NUM_THREADS = cores, since this process pins OpenBLAS to one thread) and XLA:CPU
    (``jnp.dot``, single-threaded Eigen) in this process."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS=str(len(os.sched_getaffinity(0))))
    try:
        r = subprocess.run([sys.executable, "-c", _NUMPY_DGEMM, str(n)], capture_output=True,
                           text=True, timeout=120, env=env)
        np_gflops = json.loads(r.stdout.strip().splitlines()[-1])["gflops"]
    except (subprocess.TimeoutExpired, IndexError, json.JSONDecodeError):
        np_gflops = float("nan")
    rng = np.random.default_rng(0)
    ja, jb = jnp.asarray(rng.standard_normal((n, n))), jnp.asarray(rng.standard_normal((n, n)))
    t_min, _ = best_time(jax.jit(jnp.dot), (ja, jb), reps)
    return {"numpy_gflops": np_gflops, "xla_gflops": 2.0 * n**3 / t_min / 1e9}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (< 45 s), for the tests")
    ap.add_argument("--results", type=Path, default=bu.RESULTS_MD, help="RESULTS.md to append to")
    args = ap.parse_args(argv)
    cfg = QUICK if args.quick else FULL
    t_start = time.perf_counter()
    m = bu.machine()
    B = cfg["batch"]
    print(f"roofline{' --quick' if args.quick else ''}: {m['cores']} cores, {m['cpu']}, jax "
          f"{m['jax']}; OPENBLAS_NUM_THREADS {os.environ.get('OPENBLAS_NUM_THREADS')}; load "
          f"average {os.getloadavg()[0]:.1f}", flush=True)

    # Peak first and last (the machine is shared: the better of the two is kept).
    peak0 = dgemm(cfg["dgemm_n"])
    print(f"dgemm {cfg['dgemm_n']}^2 float64: NumPy/OpenBLAS {peak0['numpy_gflops']:.1f} "
          f"GFLOP/s, XLA:CPU jnp.dot {peak0['xla_gflops']:.1f} GFLOP/s", flush=True)

    win = sc.make_window("ins15", 12, cfg["outage_s"], duration_s=cfg["duration_s"],
                         ckpt_s=cfg["ckpt_s"])
    tf, W = win.tf, win.n_epochs
    K = int(win.inputs.samples.dv_b.shape[1])
    carry_b, inputs_b = sc.batched(win, B)
    inp0 = jax.tree.map(lambda a: a[:, 0], inputs_b)

    # --- FLOPs ---------------------------------------------------------------------------------
    cost_e, hlo_e = xla_cost(jax.vmap(lambda c, i: tight.epoch_step(tf, c, i)), carry_b, inp0)
    lap, lap_counts = lapack_flops(hlo_e)
    prop = {}
    for k in (1, 10, 100):
        s_k = jax.tree.map(lambda a, k=k: a[:, 0, :k], inputs_b.samples)
        prop[k], _ = xla_cost(
            jax.vmap(lambda c, s: tf.system.propagate(c.nav, c.sensors, s, tf.imu_dt_s)),
            carry_b, s_k)
    per_sample_outside = (prop[100]["flops"] - prop[10]["flops"]) / 90.0
    body = prop[1]["flops"] - per_sample_outside
    body_bytes = prop[1]["bytes accessed"] - (prop[100]["bytes accessed"]
                                              - prop[10]["bytes accessed"]) / 90.0
    xla_epoch = cost_e["flops"] / B
    flops_epoch = (cost_e["flops"] + (K - 1) * body + lap) / B
    bytes_epoch = (cost_e["bytes accessed"] + (K - 1) * max(body_bytes, 0.0)) / B
    mech_flops = (prop[K]["flops"] + (K - 1) * body) / B if K in prop else K * body / B
    window_compiled: list = []
    cost_w, _ = xla_cost(jax.vmap(lambda c, i: tight.run(tf, c, i)), carry_b, inputs_b,
                         compiled_out=window_compiled)
    print(f"\nFLOPs per scenario-epoch: XLA epoch_step {xla_epoch:,.0f} (inner loop counted "
          f"once) + {K - 1} x {body / B:,.0f} (mechanization samples) + LAPACK "
          f"{lap / B:,.0f} ({lap_counts['potrf']} potrf, {lap_counts['trsm']} trsm) = "
          f"{flops_epoch:,.0f}", flush=True)
    print(f"  check: XLA count of the whole {W}-epoch window / scenario = "
          f"{cost_w['flops'] / B:,.0f} (~ one epoch: the epoch loop is counted once too)")
    print(f"  bytes accessed per scenario-epoch (XLA) {bytes_epoch:,.0f}; arithmetic intensity "
          f"{flops_epoch / bytes_epoch:.2f} FLOP/byte", flush=True)

    # --- achieved rate of the reference window -------------------------------------------------
    t_min, t_med = best_time(window_compiled[0], (carry_b, inputs_b), cfg["calls"])
    work = B * W * flops_epoch
    achieved, achieved_med = work / t_min / 1e9, work / t_med / 1e9
    print(f"\nreference window: {B} scenarios x {W} epochs in {t_min:.3f} s best "
          f"({t_med:.3f} s median) -> {achieved:.2f} GFLOP/s best ({achieved_med:.2f} median)",
          flush=True)

    # --- profile: sub-steps, each a scan over the window's epochs ------------------------------
    layout = tf.layout
    mean_b = jax.vmap(lambda c, s: tf.system.propagate(c.nav, c.sensors, s, tf.imu_dt_s))(
        carry_b, inp0.samples)
    nav_b, mean_in_b = mean_b

    def mech(c, samples):
        def body_fn(nav, s):
            nav, mean_in = tf.system.propagate(nav, c.sensors, s, tf.imu_dt_s)
            return nav, (nav, mean_in)
        return jax.lax.scan(body_fn, c.nav, samples)[1]  # per-epoch (nav, mean inputs)

    # The covariance scan consumes each epoch's own (nav, mean inputs): with fixed ones XLA hoists
    # F, G, Qc, Phi and Qd out of the loop and times only Phi P Phi^T + Qd.
    def cov(c, navs, means, obs):
        def body_fn(P, x):
            nav, mean_in, ob = x
            return tight._propagate_covariance(tf, layout, c._replace(P=P), nav, mean_in,
                                               ob), None
        return jax.lax.scan(body_fn, c.P, (navs, means, obs))[0]

    mech_fn = jax.jit(jax.vmap(mech))
    t_mech, _ = best_time(mech_fn, (carry_b, inputs_b.samples), cfg["calls"])
    navs_b, means_b = mech_fn(carry_b, inputs_b.samples)
    t_cov, _ = best_time(jax.jit(jax.vmap(cov)), (carry_b, navs_b, means_b, inputs_b.obs),
                         cfg["calls"])
    cost_cov, _ = xla_cost(
        jax.vmap(lambda c, nv, mi, ob: tight._propagate_covariance(tf, layout, c, nv, mi, ob)),
        carry_b, nav_b, mean_in_b, inp0.obs)
    cov_flops = cost_cov["flops"] / B
    t_rest = max(t_min - t_mech - t_cov, 0.0)
    # Shares of the sum of the parts (the sub-steps are timed after the window, so on a loaded
    # machine mechanization + covariance can exceed the window's time; shares stay in [0, 1]).
    t_parts = max(t_min, t_mech + t_cov)
    rest_flops = flops_epoch - mech_flops - cov_flops
    parts = [("mechanization (100 Hz inner scan)", t_mech, mech_flops),
             ("covariance propagation (Phi P Phi^T + Qd)", t_cov, cov_flops),
             ("rows, resets, update + post-fit tests, feedback", t_rest, rest_flops)]
    rows = ["| sub-step | time share | FLOP share | GFLOP/s | us per scenario-epoch |",
            "|---|---|---|---|---|"]
    print("\nprofile (sub-steps timed separately, same batch):")
    for name, t, f in parts:
        g = B * W * f / t / 1e9 if t > 0 else float("nan")
        us = 1e6 * t / (B * W)
        rows.append(f"| {name} | {t / t_parts:.0%} | {f / flops_epoch:.0%} | {g:.2f} | {us:.1f} |")
        print(f"  {name:45s} time {t / t_parts:5.0%}  FLOPs {f / flops_epoch:5.0%}  "
              f"{g:6.2f} GFLOP/s  {us:7.1f} us/scenario-epoch", flush=True)

    # --- what would make it faster: the same window with a cheaper filter configuration ------
    # (each variant changes the filter, so its numbers are not the reference's; the speed-up is
    # what that feature costs).
    variants = [("no post-fit test (postfit_sigma=None)",
                 "no_postfit", {"postfit_sigma": None}),
                ("no Doppler rows", "no_doppler", {"doppler": False}),
                ("neither", "no_postfit_no_doppler", {"postfit_sigma": None, "doppler": False})]
    ablation_rows = ["| variant | ms per scenario (window) | speed-up vs reference |",
                     "|---|---|---|", f"| reference (float PPP, post-fit, Doppler) | "
                     f"{1e3 * t_min / B:.2f} | 1.00 |"]
    speedups = {}
    print("\nwhat each feature costs (same window, cheaper filter):")
    for label, key, change in variants:
        tf_v = eqx.tree_at(lambda t: t.cfg, tf, dataclasses.replace(tf.cfg, **change))
        comp_v = jax.jit(jax.vmap(lambda c, i, tf_v=tf_v: tight.run(tf_v, c, i))).lower(
            carry_b, inputs_b).compile()
        t_v, _ = best_time(comp_v, (carry_b, inputs_b), cfg["calls"])
        speedups[key] = t_min / t_v
        ablation_rows.append(f"| {label} | {1e3 * t_v / B:.2f} | {t_min / t_v:.2f} |")
        print(f"  {label:60s} {1e3 * t_v / B:7.2f} ms/scenario, speed-up {t_min / t_v:.2f}",
              flush=True)

    peak1 = dgemm(cfg["dgemm_n"])
    np_peak = float(np.nanmax([peak0["numpy_gflops"], peak1["numpy_gflops"]]))
    xla_peak = max(peak0["xla_gflops"], peak1["xla_gflops"])
    frac = achieved / np_peak
    n_states = layout.size
    limits = []
    mech_t = t_mech / t_parts
    if mech_t > 0.15:
        limits.append(f"control flow: the 100 Hz mechanization is {mech_t:.0%} of the time for "
                      f"{mech_flops / flops_epoch:.0%} of the FLOPs ({K} sequential dependent "
                      "steps of 3-vector/quaternion work per epoch: latency, not throughput)")
    n_rows = lap_counts["max_n"]
    limits.append(f"small matrices: P is {n_states}x{n_states}, S is {n_rows}x{n_rows} (every "
                  "row slot, unused rows masked); batched per scenario they "
                  f"run at {B * W * (cov_flops + rest_flops) / max(t_cov + t_rest, 1e-9) / 1e9:.2f}"
                  f" GFLOP/s vs {xla_peak:.1f} for a large single-core dgemm")
    if flops_epoch / bytes_epoch < 2.0:
        limits.append(f"memory traffic: {flops_epoch / bytes_epoch:.2f} FLOP/byte (XLA bytes "
                      "accessed): the many small fusions move as much as they compute")
    limits.append("one core: jaxnav runs XLA:CPU with single-threaded Eigen and one device, so "
                  f"the filter can use 1 of {m['cores']} cores (fraction of the one-core XLA "
                  f"dgemm: {achieved / xla_peak:.0%})")
    print(f"\ndgemm peak (best of start and end): NumPy {np_peak:.1f} GFLOP/s (all cores), "
          f"XLA:CPU {xla_peak:.1f} GFLOP/s (one core)")
    print(f"fraction of peak: {frac:.1%} of the all-core dgemm (target >= 25%), "
          f"{achieved / xla_peak:.1%} of the one-core XLA dgemm")
    print("what limits it:\n  - " + "\n  - ".join(limits), flush=True)

    figures = {
        "flops_per_epoch": round(flops_epoch),
        "xla_flops_per_epoch_uncorrected": round(xla_epoch),
        "bytes_per_epoch": round(bytes_epoch),
        "achieved_gflops": round(achieved, 3),
        "achieved_gflops_median": round(achieved_med, 3),
        "dgemm_gflops": round(np_peak, 2),
        "dgemm_gflops_one_core_xla": round(xla_peak, 2),
        "fraction_of_peak": round(frac, 4),
        "fraction_of_one_core_peak": round(achieved / xla_peak, 4),
        # issue 19's name for the same figure (the filter runs on one core: XLA's dgemm there)
        "fraction_of_core_peak": round(achieved / xla_peak, 4),
        "time_share_mechanization": round(t_mech / t_parts, 3),
        "time_share_covariance": round(t_cov / t_parts, 3),
        "time_share_update_rest": round(t_rest / t_parts, 3),
        **{f"speedup_{k}": round(v, 3) for k, v in speedups.items()},
        "batch": B, "window_epochs": W, "states": n_states,
        "total_s": round(time.perf_counter() - t_start, 1),
        "quick": bool(args.quick),
    }
    md = [
        f"Reference window: ins15 / float_ppp, 12 GPS slots, {cfg['outage_s']:g} s outage + "
        f"{sc.RECOVERY_S:g} s recovery = {W} epochs, {B} scenarios per call, {n_states} states. "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}. Load average at start "
        f"{os.getloadavg()[0]:.1f}.",
        "",
        f"- FLOPs per scenario-epoch: {flops_epoch:,.0f} = XLA epoch_step {xla_epoch:,.0f} "
        f"(inner loop counted once) + {K - 1} x {body / B:,.0f} (mechanization samples) + "
        f"{lap / B:,.0f} (LAPACK potrf/trsm, analytic); XLA's count for the whole window is "
        f"{cost_w['flops'] / B:,.0f} (loops counted once).",
        f"- Achieved: {achieved:.2f} GFLOP/s (fastest call; median {achieved_med:.2f}).",
        f"- dgemm {cfg['dgemm_n']}^2 float64: {np_peak:.1f} GFLOP/s NumPy/OpenBLAS all cores, "
        f"{xla_peak:.1f} GFLOP/s XLA:CPU one core.",
        f"- Fraction of peak: **{frac:.1%}** (target >= 25%); of the one-core XLA dgemm "
        f"{achieved / xla_peak:.1%}.",
        "",
        *rows,
        "",
        "What limits it:",
        *[f"- {x}" for x in limits],
        "",
        "What each feature costs (the same window with a cheaper filter; its results differ):",
        "",
        *ablation_rows,
        "",
        "The machine is shared with other jobs: the times are pessimistic.",
    ]
    bu.finish("roofline", args.quick, md, figures, args.results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
