"""Filter consistency on the realistic simulator: ANEES and NIS against their chi-square bands.

Every default error source of the simulator is on (correlated code and phase multipath, orbit
and clock residuals, ionosphere and its broadcast-model residual, the ZWD residual, the IMU
grade's turn-on biases, Gauss-Markov drifts and scale factors): the question is whether the
sigmas the filters claim are true for the world they will meet, not for the white-noise world
they assume (that is ``tests/test_consistency.py``).

For each cell (PPP mode x navigation system; loose coupling as the cascade ``lc_ins15``), N
realisations (seeds 0..N-1) of the default drive, started at the truth with the filter's
initial covariance (so the first minutes are under-dispersed by construction and are left out:
``--settle``). Reported per cell:

- ANEES of position and of velocity (3 dof each): the mean over runs and over the epochs after
  the settling time of e^T P^-1 e. Consecutive epochs are correlated, so the band is the
  two-sided 95 % band of chi2(N n) / N for the N runs (not an N x T one), as in
  tests/test_consistency.py. It is exact for one epoch; for the time average it is
  conservative (averaging over correlated epochs narrows the spread), so a consistent filter
  lies inside it at least 95 % of the time.
- ANIS: the sum of the used rows' normalised innovations squared over the sum of their number
  (innovations of a consistent filter are white, so the band is chi2(D) / D for the D rows
  used after the settling time). Only the rows that pass the pre- and post-fit tests count, so
  the ANIS is biased low by the gates. Tight systems: the tight filter's; the cascade: its loose
  filter's (position / velocity fixes).

With ``--smooth`` every cell also reports the RTS-smoothed solution's position and velocity ANEES
over the same epochs (``anees_pos_smoothed``, ``anees_vel_smoothed``; same band), from
``FilterOps.smooth`` over the whole drive (the cascade: its LC filter smoothed over the forward
PPP fixes).

The last line printed is JSON ``{"<mode>/<system>": {"anees_pos": .., "anees_vel": ..,
"anis": .., "dof": 3, "runs": N, "lo": .., "hi": .., "nis_lo": .., "nis_hi": ..}, ...}``.

    python benchmarks/consistency.py            # 200 runs x 900 s, every cell (hours)
    python benchmarks/consistency.py --quick    # 16 runs x 420 s, a few cells (minutes)
    python benchmarks/consistency.py --environment urban --cells float_ppp/riss,df_code/riss
    python benchmarks/consistency.py --lc-fix-errors correlated --cells float_ppp/lc_ins15
    python benchmarks/consistency.py --quick --smooth --cells float_ppp/riss,float_ppp/ins15
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchutil  # noqa: E402

import jaxnav  # noqa: E402, F401  (float64)
from jaxnav.sim.observations import SLIP_ENVIRONMENTS  # noqa: E402
from jaxnav.study import metrics as mt  # noqa: E402
from jaxnav.study.factory import LC_SYSTEMS, SimFactory  # noqa: E402

FULL_MODES = ("sf_code", "df_code", "sdf_code", "float_ppp", "ic_ppp", "sf_ppp")
FULL_SYSTEMS = ("riss", "ins15")
QUICK_CELLS = (("sf_code", "riss"), ("float_ppp", "riss"), ("float_ppp", "ins15"),
               ("float_ppp", "lc_ins15"))


def _vel_nees(est: mt.Track, true: mt.Track, P_nav):
    """Velocity NEES e_v^T P_vv^-1 e_v per epoch [T] (3 dof)."""
    e = est.vel_enu - true.vel_enu
    P = P_nav[:, mt._VEL, mt._VEL]
    return jnp.einsum("ti,ti->t", e, jnp.linalg.solve(P, e[..., None])[..., 0])


def cell(factory: SimFactory, mode: str, system: str, n_runs: int, settle_s: float,
         smooth: bool = False) -> dict:
    """ANEES (position, velocity) and ANIS of one (mode, system) over seeds 0..n_runs-1; with
    ``smooth`` also the smoothed solution's ANEES (cells whose FilterOps has a smoother)."""
    ops = factory.ops_for(mode, system)
    smooth = smooth and ops.smooth is not None
    acc = [[] for _ in range(6 if smooth else 4)]
    run = None
    for seed in range(n_runs):
        prob = factory.build(None, mode, system, seed)
        if run is None:
            def nees(out, truth):
                est, P_nav = ops.readout(out)
                return mt.nees(est, truth, P_nav)[0], _vel_nees(est, truth, P_nav)

            def one(tf, carry0, inputs, truth):
                if smooth:
                    out, smo = ops.smooth(tf, carry0, inputs)
                else:
                    out = ops.run(tf, carry0, inputs)[1]
                part = out.lc if system in LC_SYSTEMS else out
                r = (*nees(out, truth), part.nis, part.dof)
                return r + nees(smo, truth) if smooth else r
            run = jax.jit(one)
        r = run(prob.tf, prob.carry0, prob.inputs, prob.truth)
        for a, v in zip(acc, r, strict=True):
            a.append(np.asarray(v))
    k0 = int(round(settle_s / factory.cfg.epoch_interval_s))
    arrays = [np.stack(a)[:, k0:] for a in acc]
    q_pos, q_vel, nis, dof = arrays[:4]
    lo, hi = (float(b) for b in mt.chi2_interval(3, n_runs))
    d = float(dof.sum())
    out = {
        "anees_pos": float(q_pos.mean()),
        "anees_vel": float(q_vel.mean()),
        "median_nees_pos": float(np.median(q_pos)),
        "dof": 3,
        "runs": n_runs,
        "lo": lo,
        "hi": hi,
    }
    if smooth:
        out |= {"anees_pos_smoothed": float(arrays[4].mean()),
                "anees_vel_smoothed": float(arrays[5].mean())}
    if d > 0:
        nis_lo, nis_hi = mt.chi2_interval(1, int(d))  # chi2(D) / D
        out |= {"anis": float(nis.sum() / d), "nis_lo": float(nis_lo), "nis_hi": float(nis_hi)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="16 runs x 420 s of four cells")
    p.add_argument("--runs", type=int, help="realisations per cell (default 200, quick 16)")
    p.add_argument("--duration", type=float, help="drive length [s] (default 900, quick 420)")
    p.add_argument("--settle", type=float, default=300.0,
                   help="seconds left out at the start (default 300)")
    p.add_argument("--lc-fix-errors", default="white", choices=["white", "correlated"],
                   help="the LC cells' model of the PPP fix error (study.factory key)")
    p.add_argument("--environment", default="open_sky", choices=list(SLIP_ENVIRONMENTS),
                   help="cycle-slip / loss-of-lock rates of the simulated receiver (default "
                        "open_sky); the filters get LLI + the GF / MW detector's flags")
    p.add_argument("--cells", help="comma-separated mode/system cells instead of the default set")
    p.add_argument("--smooth", action="store_true",
                   help="also the RTS-smoothed solution's ANEES (cells with a smoother)")
    p.add_argument("--results", type=Path, default=benchutil.RESULTS_MD)
    a = p.parse_args(argv)
    n_runs = a.runs or (16 if a.quick else 200)
    duration = a.duration or (420.0 if a.quick else 900.0)
    if duration <= a.settle:
        p.error(f"--duration {duration} must exceed --settle {a.settle}")
    if a.cells:
        cells = tuple(tuple(c.split("/", 1)) for c in a.cells.split(","))
        bad = [c for c in cells if len(c) != 2]
        if bad:
            p.error(f"--cells {a.cells!r}: each cell is mode/system, e.g. float_ppp/riss")
    elif a.quick:
        cells = QUICK_CELLS
    else:
        cells = tuple((m, s) for m in FULL_MODES for s in FULL_SYSTEMS) + (
            ("float_ppp", "lc_ins15"),)
    factory = SimFactory({"duration_s": duration, "environment": a.environment,
                          "lc_fix_errors": a.lc_fix_errors})
    figures, lines = {}, []
    lines.append(f"{n_runs} runs x {duration:.0f} s per cell (default drive, every simulated "
                 f"error source on, slip environment {a.environment}, detected slips, LC fix "
                 f"errors {a.lc_fix_errors}), epochs "
                 f"after {a.settle:.0f} s; bands two-sided 95 %.")
    lines.append("")
    smo_head = " smoothed ANEES pos / vel |" if a.smooth else ""
    lines.append("| mode / system | ANEES pos | ANEES vel | band (3 dof) | median NEES pos | ANIS "
                 f"| NIS band |{smo_head} s |")
    lines.append("|---|---|---|---|---|---|---|---|" + ("---|" if a.smooth else ""))
    for mode, system in cells:
        t0 = time.time()
        c = cell(factory, mode, system, n_runs, a.settle, a.smooth)
        figures[f"{mode}/{system}"] = c
        nis = (f"{c['anis']:.2f} | {c['nis_lo']:.2f}-{c['nis_hi']:.2f}" if "anis" in c
               else "- | -")
        smo = ""
        if a.smooth:
            smo = (f" {c['anees_pos_smoothed']:.2f} / {c['anees_vel_smoothed']:.2f} |"
                   if "anees_pos_smoothed" in c else " - |")
        row = (f"| {mode} / {system} | {c['anees_pos']:.2f} | {c['anees_vel']:.2f} | "
               f"{c['lo']:.2f}-{c['hi']:.2f} | {c['median_nees_pos']:.2f} | {nis} |{smo} "
               f"{time.time() - t0:.0f} |")
        lines.append(row)
        print(row, flush=True)
    inside = sum(c["lo"] <= c["anees_pos"] <= c["hi"] and c["lo"] <= c["anees_vel"] <= c["hi"]
                 for c in figures.values())
    lines.append("")
    lines.append(f"Cells with both ANEES inside the band: {inside} of {len(figures)}.")
    benchutil.finish("Consistency on the realistic simulator", a.quick, lines, figures,
                     a.results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
