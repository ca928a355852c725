"""Cost of the tight update's building blocks at the engine's batch (64 scenarios, one core):
batched LAPACK calls (Cholesky, triangular solves) against XLA matrix products of the same
sizes (S 36 x 36, 30 states). Prints microseconds per scenario-epoch (best of 200 calls).
Run: ``python benchmarks/lapack_batch_cost.py`` (< 1 min; ``--quick``: 20 calls each).
Issue 19's measurement; appends its table to RESULTS.md like every benchmark.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# one OpenBLAS thread, as roofline.py (must precede the first numpy / jaxlib import)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import jax.scipy.linalg as jsl  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchutil as bu  # noqa: E402

jax.config.update("jax_enable_x64", True)
BATCH, M_ROWS, N_STATES = 64, 36, 30


def per_epoch_us(fn, *args, calls: int = 200) -> float:
    """Best time of one vmapped call over the batch, per batch element [us]."""
    g = jax.jit(jax.vmap(fn))
    jax.block_until_ready(g(*args))
    best = np.inf
    for _ in range(calls):
        t0 = time.perf_counter()
        jax.block_until_ready(g(*args))
        best = min(best, time.perf_counter() - t0)
    return best / BATCH * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="20 calls per case instead of 200")
    ap.add_argument("--results", type=Path, default=bu.RESULTS_MD, help="RESULTS.md to append to")
    args = ap.parse_args(argv)
    calls = 20 if args.quick else 200
    rng = np.random.default_rng(0)
    A = rng.normal(size=(BATCH, M_ROWS, M_ROWS))
    S = A @ A.transpose(0, 2, 1) + M_ROWS * np.eye(M_ROWS)
    L = np.linalg.cholesky(S)
    HP = rng.normal(size=(BATCH, M_ROWS, N_STATES))
    H = rng.normal(size=(BATCH, M_ROWS, N_STATES))
    P = rng.normal(size=(BATCH, N_STATES, N_STATES))
    P = P @ P.transpose(0, 2, 1)
    nu = rng.normal(size=(BATCH, M_ROWS))
    eye_n = jnp.eye(N_STATES)
    cases = {
        "Cholesky factorisation 36x36": (lambda s: jsl.cho_factor(s, lower=True)[0], S),
        "Cholesky solve, 30 rhs": (lambda c, b: jsl.cho_solve((c, True), b), L, HP),
        "triangular solve, 30 rhs": (lambda c, b: jsl.solve_triangular(c, b, lower=True), L, HP),
        "triangular solve, 1 rhs": (lambda c, b: jsl.solve_triangular(c, b, lower=True), L, nu),
        "inverse by Cholesky solve of I": (
            lambda c: jsl.cho_solve((c, True), jnp.eye(M_ROWS)), L),
        "product 36x30 @ 30x30 (H P)": (lambda h, p: h @ p, H, P),
        "product 36x30 @ 30x36 (S)": (lambda hp, h: hp @ h.T, HP, H),
        "Joseph (I - K H) P (I - K H)^T": (
            lambda p, k, h: (eye_n - k.T @ h) @ p @ (eye_n - k.T @ h).T, P, HP, H),
    }
    md = ["| operation (batch 64) | us per scenario-epoch |", "|---|---|"]
    figures = {}
    for name, (fn, *operands) in cases.items():
        us = per_epoch_us(fn, *operands, calls=calls)
        print(f"{name:34s} {us:7.2f} us per scenario-epoch", flush=True)
        md.append(f"| {name} | {us:.1f} |")
        figures[name] = round(us, 2)
    bu.finish("LAPACK calls vs matrix products at batch 64", args.quick, md, figures,
              args.results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
