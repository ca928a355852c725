"""XLA:CPU fusion emitters: compile and run time of jaxnav's kernels with each, and their numbers.

``JAXNAV_XLA_FUSION_EMITTERS=0`` makes ``import jaxnav`` select XLA:CPU's older fusion emitters
(``--xla_cpu_use_fusion_emitters=false``, honoured on the jaxlib release this script measured);
the test suite does, users may. Each kernel is compiled and timed in a fresh
process (XLA reads its flags once, when the CPU backend starts), the two settings alternating
(A B A B ...) so that the machine's drift hits both alike; the persistent compilation cache is
off in the children, so every compilation is a real one. Kernels, on one simulated 5-min drive:

- ``realize``: the simulator (IMU, odometer, GNSS observations), vmapped over ``batch`` keys;
- ``tight_ins15``: float PPP tightly coupled with INS15, ``batch`` realisations;
- ``tight_riss``: float PPP with the RISS, ``batch`` realisations;
- ``sweep``: a small outage sweep through the production engine (``run_sweep``: full run and
  window evaluation compiled, 2 outage levels), wall time from the factory to the Dataset.

Reported per kernel: median compile time and median steady-state call time of each setting,
their ratios (older / default), and the largest position difference between the two settings'
outputs (the same computation compiled two ways differs only by rounding).

    python benchmarks/xla_emitters.py            # 3 rounds, batch 16
    python benchmarks/xla_emitters.py --quick    # 1 round, batch 4
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import benchutil as bu  # noqa: E402

SETTINGS = {"default": "--xla_cpu_use_fusion_emitters=true",
            "older": "--xla_cpu_use_fusion_emitters=false"}
KERNELS = ("realize", "tight_ins15", "tight_riss", "sweep")


def _child(kernel: str, batch: int, out_npz: str) -> dict:
    """One kernel in this (fresh) process: compile time, call times, outputs saved to npz."""
    import time

    import jax
    import numpy as np

    import jaxnav  # noqa: F401  (x64, threads)
    from jaxnav.filter import tight
    from jaxnav.sim import scenario
    from jaxnav.study.factory import SimFactory

    factory = SimFactory({"duration_s": 300.0})
    geo, cfg = factory.geo, factory.cfg
    keys = jax.random.split(jax.random.PRNGKey(1), batch)
    real = jax.jit(jax.vmap(lambda k: scenario.realize(k, geo, cfg, False)))
    if kernel == "sweep":
        from jaxnav.study import config as study_config
        from jaxnav.study.sweep import run_sweep

        scfg = study_config.from_dict({
            "study": {"name": "emitters", "modes": ["float_ppp"], "systems": ["ins15"],
                      "durations_s": [30], "satellites_kept": [0, 2], "realizations": 1,
                      "recovery_s": 10, "chunk_size": 8},
            "placement": {"kind": "grid", "convergence_s": 120, "spacing_s": 40},
        }, modes=factory.modes, systems=factory.systems)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = run_sweep(scfg, factory, Path(tmp) / "sweep", progress=False)
            wall = time.perf_counter() - t0
        compile_s = sum(v for k, v in res.stats.items() if k.startswith("compile_"))
        np.savez(out_npz, max_2d_m=np.asarray(res.dataset["max_2d_m"]))
        return {"compile_s": compile_s, "call_s": wall - compile_s, "wall_s": wall}
    if kernel == "realize":
        fn, args = real, (keys,)
    else:
        system = "ins15" if kernel == "tight_ins15" else "riss"
        tf = factory.filter("float_ppp", system)
        r = real(keys)
        inputs = r.ins_inputs if system == "ins15" else r.riss_inputs
        nav0 = (scenario.initial_ins_state(geo) if system == "ins15"
                else scenario.initial_riss_state(geo))

        def one(obs0, inp):
            return tight.run(tf, tight.initial_carry(tf, nav0, obs0), inp)[1].llh

        fn, args = jax.jit(jax.vmap(one)), (r.obs0, inputs)
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    calls = bu.time_calls(compiled, args, calls=3, min_s=2.0)
    out = compiled(*args)
    if kernel == "realize":
        np.savez(out_npz, code_m=np.asarray(out.ins_inputs.obs.code_m))
    else:
        np.savez(out_npz, llh=np.asarray(out))
    return {"compile_s": compile_s, "call_s": float(np.median(calls))}


def _difference(kernel: str, a: Path, b: Path) -> tuple[str, float]:
    import numpy as np

    with np.load(a) as za, np.load(b) as zb:
        (name,) = za.files
        x, y = za[name], zb[name]
    if name == "llh":  # radians -> metres (north / east), metres up
        scale = np.array([6.378e6, 6.378e6 * np.cos(x[..., :1, 0].mean()), 1.0])
        return "position [m]", float(np.nanmax(np.abs((x - y) * scale)))
    label = {"code_m": "code [m]", "max_2d_m": "max 2D error [m]"}[name]
    return label, float(np.nanmax(np.abs(x - y)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 round, batch 4 (for a smoke run)")
    ap.add_argument("--rounds", type=int, default=None, help="A/B rounds per kernel")
    ap.add_argument("--results", type=Path, default=bu.RESULTS_MD, help="RESULTS.md to append to")
    ap.add_argument("--child", nargs=3, metavar=("KERNEL", "BATCH", "NPZ"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        kernel, batch, npz = args.child
        bu.print_json_line(_child(kernel, int(batch), npz))
        return 0
    rounds = args.rounds or (1 if args.quick else 3)
    batch = 4 if args.quick else 16
    res: dict = {k: {s: [] for s in SETTINGS} for k in KERNELS}
    diffs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kernel in KERNELS:
            for r in range(rounds):
                for setting, flag in SETTINGS.items():
                    env = dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false",
                               XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " " + flag).strip())
                    npz = str(Path(tmp) / f"{kernel}-{setting}.npz")
                    p = subprocess.run([sys.executable, __file__, "--child", kernel, str(batch),
                                        npz], env=env, capture_output=True, text=True)
                    if p.returncode != 0:
                        print(p.stderr[-3000:], file=sys.stderr)
                        return 1
                    fig = json.loads(p.stdout.strip().splitlines()[-1])
                    res[kernel][setting].append(fig)
                    print(f"{kernel} round {r} {setting}: compile {fig['compile_s']:.2f} s, "
                          f"call {fig['call_s']:.4f} s", flush=True)
            diffs[kernel] = _difference(kernel, Path(tmp) / f"{kernel}-default.npz",
                                        Path(tmp) / f"{kernel}-older.npz")

    import numpy as np

    figures: dict = {"rounds": rounds, "batch": batch}
    rows = []
    for kernel in KERNELS:
        med = {s: {q: float(np.median([f[q] for f in res[kernel][s]]))
                   for q in ("compile_s", "call_s")} for s in SETTINGS}
        c_ratio = med["older"]["compile_s"] / med["default"]["compile_s"]
        r_ratio = med["older"]["call_s"] / med["default"]["call_s"]
        label, diff = diffs[kernel]
        figures.update({f"compile_ratio_{kernel}": round(c_ratio, 3),
                        f"call_ratio_{kernel}": round(r_ratio, 3),
                        f"max_difference_{kernel}": diff})
        rows.append(f"| {kernel} | {med['default']['compile_s']:.2f} | "
                    f"{med['older']['compile_s']:.2f} | {c_ratio:.2f} | "
                    f"{med['default']['call_s']:.4f} | {med['older']['call_s']:.4f} | "
                    f"{r_ratio:.2f} | {label} {diff:.1e} |")
    md = [
        f"Median of {rounds} alternating fresh-process run(s) per setting, batch {batch}, "
        "5-min drive; compile cache off. `default` = XLA's MLIR fusion emitters, `older` = "
        "`--xla_cpu_use_fusion_emitters=false` (`JAXNAV_XLA_FUSION_EMITTERS=0`). For `sweep` "
        "the call column is the sweep's wall time less its compilation.",
        "",
        "| kernel | compile default [s] | compile older [s] | ratio | call default [s] | "
        "call older [s] | ratio | largest difference |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
    ]
    bu.finish("xla_emitters", args.quick, md, figures, args.results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
