"""``jaxnav`` command line: demo, sweep, init, list, tutorial, ppp, lc, ins, tune."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

from jaxnav.apps import existing_file

#: The built-in demo study: S000's four PPP/RISS modes, 60 s outages with 0-3 satellites kept
#: (and no outage), on a 15-minute simulated drive with a Crossbow-class RISS.
DEMO_STUDY = {
    "study": {
        "name": "demo",
        "modes": ["sf_code", "df_code", "sdf_code", "float_ppp"],
        "systems": ["riss"],
        "durations_s": [60],
        "satellites_kept": [0, 1, 2, 3, "all"],
        "policies": ["highest"],
        "realizations": 3,
        "seed": 0,
        "recovery_s": 30,
        "chunk_size": 64,
        "max_traces": 105,  # every run (7 placements x 3 realizations) at 5 levels
    },
    "placement": {"kind": "grid", "convergence_s": 300, "spacing_s": 75},
    "scenario": {"duration_s": 900},
}

DEMO_DESCRIPTION = (
    "The built-in outage study (seed 000's Table 5.2 shape): tightly coupled PPP/RISS in four "
    "PPP modes, 60-s outages keeping 0, 1, 2, 3 or all satellites at 7 placements of a 15-minute "
    "simulated drive, 3 noise realizations. Prints the table of mean maximum 2D error [m] and "
    "writes results.nc, table.md, CSV tables and plots into --out.")

SCHEDULER_TIMEOUT_S = 10  # a scheduler that does not answer in this time is a wrong address


def _run_study(cfg, factory, out: Path, resume: bool, overwrite: bool, force: bool = False,
               workers: int = 1, scheduler: str | None = None) -> int:
    from jaxnav.study import parallel, report, sweep

    client = None
    if scheduler is not None:
        from distributed import Client

        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except (OSError, TimeoutError) as e:
            print(f"jaxnav: --scheduler {scheduler}: cannot connect ({e})", file=sys.stderr)
            return 2
    try:  # the folder's state (existing result, other study, damaged files) is checked first
        result = sweep.run_sweep(cfg, factory, out, resume=resume, overwrite=overwrite,
                                 force=force, workers=workers, client=client)
    except KeyboardInterrupt:
        print(f"jaxnav: interrupted; the chunks finished so far are kept in {out} (run the same "
              "command with --resume to continue)", file=sys.stderr)
        _interrupted.append(True)
        return 2
    except (FileExistsError, sweep.StoreError) as e:
        text = str(e).replace("overwrite=True", "--overwrite").replace("resume=True", "--resume")
        print(f"jaxnav: {text}", file=sys.stderr)
        return 2
    except parallel.WorkerError as e:
        print(f"jaxnav: {e}; the chunks finished so far are kept (--resume)", file=sys.stderr)
        return 1
    finally:
        if client is not None:
            client.close()
    paths = report.write_report(result.dataset, out, overwrite=True)
    for solution, view in report.solution_views(result.dataset):
        if solution is not None:
            print(f"\n## {solution}\n")
        print(report.markdown_by_satellites(report.table_by_satellites(view),
                                            pooled=report.pooled_text(view)))
    stats = result.stats
    print(
        f"\n{stats['scenarios']} scenarios in {stats['wall_s']:.1f} s "
        f"(compile {stats['compile_full_s'] + stats['compile_eval_s']:.1f} s); "
        f"results: {result.path}"
    )
    for p in paths.values():
        print(f"  wrote {p}")
    return 0


def _demo(args) -> int:
    from jaxnav.study import config
    from jaxnav.study.factory import SimFactory

    cfg = config.from_dict(DEMO_STUDY, modes=SimFactory.modes, systems=SimFactory.systems)
    return _run_study(cfg, SimFactory(cfg.scenario_dict), Path(args.out), args.resume,
                      args.overwrite, workers=args.workers, scheduler=args.scheduler)


def _sweep(args) -> int:
    from jaxnav.study import config
    from jaxnav.study.factory import SimFactory
    from jaxnav.study.sources import factory_for

    try:
        cfg = config.load(args.config, modes=SimFactory.modes, systems=SimFactory.systems)
        try:  # the [scenario] table, checked by the factory's schema before any work
            factory = factory_for(cfg.scenario_dict, Path(args.config).parent)
        except config.ConfigError as e:
            raise config.ConfigError(f"{args.config}: {e}") from None
    except config.ConfigError as e:
        print(f"jaxnav sweep: invalid study: {e}", file=sys.stderr)
        return 2
    try:
        if args.check or args.dry_run:
            return _check_study(cfg, factory, args.config, args.force,
                                1 if args.scheduler else args.workers, plan_text=args.dry_run)
        if args.out is None:
            print("jaxnav sweep: --out is required (or --check / --dry-run to validate only)",
                  file=sys.stderr)
            return 2
        return _run_study(cfg, factory, Path(args.out), args.resume, args.overwrite, args.force,
                          workers=args.workers, scheduler=args.scheduler)
    except config.ConfigError as e:  # found when the plan turns seconds into epochs
        print(f"jaxnav sweep: invalid study: {args.config}: {e}", file=sys.stderr)
        return 2


def _dry_run_text(cfg, plan) -> str:
    """The plan of ``jaxnav sweep --dry-run``: axes, placements, sizes and the estimated time
    (``study.costs``)."""
    from jaxnav.study import costs
    from jaxnav.study.report import kept_label

    dt = plan.timeline.epoch_dt_s
    starts = plan.starts[0] * dt
    shown = ", ".join(f"{s:g}" for s in starts[:12]) + (" ..." if starts.size > 12 else "")
    lines = [
        f"  modes           : {', '.join(cfg.modes)}",
        f"  systems         : {', '.join(cfg.systems)}",
        f"  durations       : {', '.join(f'{d:g} s' for d in plan.duration_s)}",
        f"  satellites kept : {', '.join(kept_label(k) for k in plan.n_keep)}",
        f"  policies, ramps : {', '.join(cfg.policies)}; "
        f"{', '.join(f'{r * dt:g} s' for r in plan.ramps)}",
        f"  realizations    : {len(plan.seeds)} (seeds {plan.seeds[0]} .. {plan.seeds[-1]})",
        f"  placements      : {starts.size} ({cfg.placement.kind}), starts [s] {shown}",
        f"  scenarios       : {plan.n_per_group} per group x {len(cfg.modes) * len(cfg.systems)}"
        f" group(s), chunks of {cfg.chunk_size}; window {plan.window} epochs of {dt:g} s",
    ]
    est = costs.estimate(cfg, plan, plan.timeline.n_epochs * dt)
    lines.append(
        f"  estimated time  : about {est.seconds / 60:.1f} min on one worker (compilation "
        f"{est.compile_s:.0f} s, full runs {est.full_s:.0f} s, outage windows {est.eval_s:.0f} s,"
        f" simulation and files {est.other_s:.0f} s; costs measured {costs.MEASURED}, "
        "+-30 % machine drift; more workers divide the windows only)")
    if len(plan.seeds) > 1:
        lines.append("  (simulation per realization was measured on a first realization, with "
                     "the simulator's one-off compilation: many realizations are over-estimated)")
    if cfg.smooth:
        lines.append("  (smooth = true: the RTS smoother's passes are not in the measured costs; "
                     "expect a longer run)")
    if cfg.scenario_dict.get("source", "simulated") != "simulated":
        lines.append("  (a recorded drive: costs were measured on simulated drives)")
    if est.substituted:
        lines.append("  (not measured, estimated with another cell's costs: " + ", ".join(
            f"{k} as {v}" for k, v in est.substituted.items()) + ")")
    return "\n".join(lines)


def _check_study(cfg, factory, path, force: bool, workers: int | str,
                 plan_text: bool = False) -> int:
    """``jaxnav sweep --check`` (and ``--dry-run``, which adds the plan and its estimated
    time): every pre-work check, a summary, no file written."""
    from jaxnav.study import sweep

    plan, workers = sweep.plan_and_workers(cfg, factory, workers, force=force)  # as a run would
    groups = len(cfg.modes) * len(cfg.systems)
    line = (f"{path}: valid; {groups} group(s) ({', '.join(cfg.modes)} x "
            f"{', '.join(cfg.systems)}) x {plan.n_per_group} scenarios = "
            f"{groups * plan.n_per_group} scenarios in {plan.n_chunks} chunk(s) per group; "
            f"{plan.timeline.n_epochs} epochs, window {plan.window}")
    estimate = getattr(factory, "memory_bytes", None)
    if estimate is not None:
        need = estimate(cfg, rows=plan.max_rows, chunk_epochs=cfg.chunk_size * plan.window)
        line += f"; memory about {need['total'] / 1e9:.2f} GB per worker, {workers} worker(s)"
    print(line)
    if plan_text:
        print(_dry_run_text(cfg, plan))
    return 0


def _init(args) -> int:
    """``jaxnav init FILE``: write the commented study template (every key, its default)."""
    from jaxnav.study.template import study_template

    path = Path(args.file)
    if path.exists() and not args.overwrite:
        print(f"jaxnav init: {path} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    if not path.parent.is_dir():
        print(f"jaxnav init: {path.parent} is not a folder", file=sys.stderr)
        return 2
    path.write_text(study_template())
    print(f"wrote {path}: check it with `jaxnav sweep {path} --check`, run it with "
          f"`jaxnav sweep {path} --out DIR`")
    return 0


def _first_line(obj) -> str:
    return (obj.__doc__ or "").strip().splitlines()[0] if obj.__doc__ else ""


def _list(args) -> int:
    """Print what a registry holds: the names a study TOML or a command line may use."""
    if args.what == "modes":
        from jaxnav.gnss import modes

        for name, cls in modes.REGISTRY.items():
            doc = _first_line(importlib.import_module(cls.__module__))
            print(f"{name:10s} {doc.split(': ', 1)[-1]}")
    elif args.what == "systems":
        from jaxnav.study.factory import SimFactory

        for name in SimFactory.systems:
            print(name)
    elif args.what == "drives":
        from jaxnav.study.factory import DRIVE_STYLES

        for name, text in DRIVE_STYLES.items():
            print(f"{name:10s} {text}")
        print("(simulated: [scenario] drive_style; a recorded drive: [scenario] source = "
              "\"replay\", configs/esbc_replay.toml)")
    else:
        from jaxnav.sim import sensors

        for kind, table in (("imu", sensors.IMU_GRADES), ("odometer", sensors.ODOMETERS)):
            for name, make in table.items():
                print(f"{kind:8s} {name:18s} {make().name}")
    return 0


def _delegate(module: str):
    def run(args) -> int:
        return importlib.import_module(f"jaxnav.apps.{module}").main(args.rest)

    return run


def _workers(text: str) -> int | str:
    if text.strip() == "auto":
        return "auto"
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:  # also $JAXNAV_WORKERS: argparse converts a string default with this type
        raise argparse.ArgumentTypeError(
            f"{text!r} (from --workers or $JAXNAV_WORKERS): expected 'auto' or a whole number "
            ">= 1")
    return n


def _parallel_options(p):
    from jaxnav.study.parallel import AUTO_MIN_SCENARIOS, default_workers

    p.add_argument("--workers", type=_workers, default=os.environ.get("JAXNAV_WORKERS", "auto"),
                   help=f"worker processes on this machine: N (1 runs in this process) or auto "
                        f"(default, or $JAXNAV_WORKERS): every core, {default_workers()}, for "
                        f"studies of {AUTO_MIN_SCENARIOS:,} scenarios or more, else 1")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run the chunks on a running Dask cluster (docs/parallel.md; default: "
                        "this machine, --workers)")


def build_parser() -> argparse.ArgumentParser:
    """The ``jaxnav`` parser; the delegated subcommands' own parsers are their modules'
    ``build_parser`` (``jaxnav.apps.NAME``)."""
    from jaxnav import __version__

    parser = argparse.ArgumentParser(prog="jaxnav", description=__doc__)
    parser.add_argument("--version", action="version", version=f"jaxnav {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="outage sweep on a built-in simulated drive (no downloads)",
                       description=DEMO_DESCRIPTION)
    p.add_argument("--out", default="demo-out", help="output folder (default demo-out)")
    p.add_argument("--resume", action="store_true", help="reuse completed chunks in --out")
    p.add_argument("--overwrite", action="store_true", help="replace an existing result")
    _parallel_options(p)
    p.set_defaults(func=_demo)

    p = sub.add_parser("sweep", help="run a study defined in a TOML file",
                       description="Run the outage study a TOML file defines (`jaxnav init` "
                                   "writes a template) into --out: results.nc, table.md, CSV "
                                   "tables and plots. Invalid keys stop it before any work.")
    p.add_argument("config", type=existing_file, help="study TOML (see jaxnav/study/config.py)")
    p.add_argument("--out", help="output folder (required unless --check)")
    p.add_argument("--resume", action="store_true", help="reuse completed chunks in --out")
    p.add_argument("--overwrite", action="store_true", help="replace an existing result")
    p.add_argument("--force", action="store_true",
                   help="run a study whose memory estimate exceeds the memory available")
    p.add_argument("--check", action="store_true",
                   help="validate the study (schema, plan, memory) and print its size; no run")
    p.add_argument("--dry-run", action="store_true",
                   help="--check, then the plan (axes, placements, scenarios, chunks) and its "
                        "estimated run time from measured costs; no run")
    _parallel_options(p)
    p.set_defaults(func=_sweep)

    text = "write a study TOML template with every key, its default and its meaning"
    p = sub.add_parser("init", help=text, description=text[0].upper() + text[1:] + ".")
    p.add_argument("file", help="the TOML file to write (e.g. study.toml)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.set_defaults(func=_init)

    text = ("print what the registries hold: the names a study TOML or a command line "
            "accepts")
    p = sub.add_parser("list", help=text, description=text[0].upper() + text[1:] + ".")
    p.add_argument("what", choices=("modes", "systems", "presets", "drives"),
                   help="modes: PPP observation models; systems: navigation systems; presets: "
                        "IMU grades and odometers; drives: simulated drive styles")
    p.set_defaults(func=_list)

    for name, text in DELEGATED.items():
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=_delegate(name))
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        if argv and argv[0] in DELEGATED:  # their parsers take the rest
            return importlib.import_module(f"jaxnav.apps.{argv[0]}").main(argv[1:])
        args = parser.parse_args(argv)
        if getattr(args, "resume", False) and getattr(args, "overwrite", False):
            parser.error("--resume reuses what --out holds and --overwrite discards it: pass one")
        return args.func(args)
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback from inside compilation
        print("jaxnav: interrupted; outputs are written only when a run completes",
              file=sys.stderr)
        _interrupted.append(True)
        return 2


#: Subcommands whose own parser (``jaxnav.apps.NAME.main``) reads the rest of the line, and
#: their one-line help in ``jaxnav --help``.
DELEGATED = {
    "ppp": "post-processed PPP on RINEX data (see `jaxnav ppp --help`)",
    "lc": "loosely coupled INS on a recorded IMU + GNSS drive (see `jaxnav lc --help`)",
    "ins": "GNSS/INS on a recorded IMU log, loose (.pos) or tight (raw UBX observations) "
           "(see `jaxnav ins --help`)",
    "tune": "fit a car configuration's noise figures to a recorded drive by maximum likelihood "
            "(see `jaxnav tune --help`)",
    "tutorial": "copy the tutorial notebook (an outage study end to end) into a folder, as .py "
                "and, with jupytext, .ipynb (see `jaxnav tutorial --help`)",
}

#: Set when Ctrl-C ended the command (``entry``).
_interrupted: list = []


def entry() -> None:
    """The console script: ``main``, then exit with its code. After Ctrl-C the process leaves
    with ``os._exit``: an XLA compilation interrupted in another thread crashes the interpreter's
    normal shutdown (measured: SIGSEGV after the message), and nothing is left to clean up (the
    sweep store writes each chunk atomically)."""
    rc = main()
    if _interrupted:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    sys.exit(rc)


if __name__ == "__main__":
    entry()
