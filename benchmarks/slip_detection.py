"""Cycle-slip detection on the simulator: missed-detection and false-alarm rates per environment.

For each environment of ``sim.observations.SLIP_ENVIRONMENTS`` (slip and loss-of-lock rates per
satellite-hour), N realisations of the default scenario's drive (GPS, 1 Hz) are simulated and
the filter's slip flags are taken exactly as a Monte-Carlo study takes them
(``sim.scenario.slip_flags``): LLI plus the geometry-free and Melbourne-Wuebbena detector of
real data for dual frequency, LLI alone for single frequency. Against the simulator's truth, on
the slot-epochs of continuing arcs (tracked now and at the previous epoch):

- missed-detection rate = undetected slips / slips;
- false-alarm rate = flags without a slip / slip-free continuing slot-epochs.

A missed slip corrupts a carrier-phase mode's ambiguity until the post-fit test or the slot's
next restart; a false alarm restarts an ambiguity for nothing (re-convergence).
The last line printed is JSON ``{"<environment>/<df|sf>": {"slips": .., "missed": ..,
"md_rate": .., "tested": .., "false_alarms": .., "fa_rate": .., "runs": N}, ...}``.

    python benchmarks/slip_detection.py            # 32 runs x 900 s per environment
    python benchmarks/slip_detection.py --runs 8   # quicker
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp

import jaxnav  # noqa: F401  (float64)
from jaxnav.gnss import signals, slips
from jaxnav.sim import observations, scenario


def counts(cfg: scenario.ScenarioConfig, geo: scenario.Geometry, params, runs: int, band0: int):
    """Summed ``slips.detection_counts`` over ``runs`` realisations (seeds 0..runs-1)."""

    def one(key):
        obs = observations.simulate_observations(
            key, geo.truth_ep.time_s, geo.ant_pos_ecef, geo.ant_vel_ecef, geo.orbits,
            geo.slot_table, params, with_truth=False,
        )
        flags = scenario.slip_flags(obs, band0, cfg.slip_flags)
        prev = jnp.concatenate([jnp.zeros_like(obs.valid[:1]), obs.valid[:-1]], axis=0)
        return slips.detection_counts(obs.cycle_slip, flags, obs.valid & prev)

    keys = jnp.stack([jax.random.PRNGKey(s) for s in range(runs)])
    c = jax.jit(jax.vmap(one))(keys)
    return {k: int(v.sum()) for k, v in c.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=32)
    ap.add_argument("--duration", type=float, default=900.0)
    args = ap.parse_args(argv)
    cfg = scenario.ScenarioConfig(duration_s=args.duration)
    geo = scenario.build_geometry(cfg)
    out = {}
    print(f"{'environment':>10} {'freq':>4} {'slips':>6} {'missed':>6} {'MD rate':>8} "
          f"{'tested':>8} {'false':>6} {'FA rate':>9}   ({args.runs} runs x {args.duration:.0f} s)")
    for env in observations.SLIP_ENVIRONMENTS:
        params = observations.slip_environment(cfg.obs_params, env, cfg.epoch_interval_s)
        for freq, band0 in (("df", signals.CODE_P1), ("sf", signals.CODE_C1)):
            t0 = time.perf_counter()
            c = counts(cfg, geo, params, args.runs, band0)
            c["md_rate"] = c["missed"] / c["slips"] if c["slips"] else None
            c["fa_rate"] = c["false_alarms"] / max(c["tested"] - c["slips"], 1)
            c["runs"] = args.runs
            out[f"{env}/{freq}"] = c
            md = "-" if c["md_rate"] is None else f"{c['md_rate']:.4f}"
            print(f"{env:>10} {freq:>4} {c['slips']:6d} {c['missed']:6d} {md:>8} "
                  f"{c['tested']:8d} {c['false_alarms']:6d} {c['fa_rate']:9.2e}"
                  f"   {time.perf_counter() - t0:.1f} s", flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
