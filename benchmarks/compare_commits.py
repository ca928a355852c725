"""Per-scenario time of a sweep at another commit against this checkout, alternating in one run.

Issue 19's measurement: the engine's time per scenario at BASE (a git worktree of that
revision, made in a temporary folder) and here (this checkout as it is, uncommitted changes
included; or ``--head REV``, a second worktree), each in a fresh subprocess whose ``import
jaxnav`` resolves to that tree (PYTHONPATH), alternating BASE / HEAD ``--rounds`` times so the
machine's drift (+-30 %) hits both alike. The child runs the production engine
(``jaxnav.study.sweep.run_sweep``, an API both sides share) on a study of ``--case``:

- ``reference``: INS15 (SPAN-CPT, 100 Hz) + float PPP, 12 GPS slots (issue 5's reference sweep);
- ``riss_sf``: RISS16 + single-frequency code, 12 GPS slots;
- ``gnss24``: INS15 + float PPP, 12 GPS + 12 Galileo slots.

60-s outages keeping 0-3 satellites + 30 s of recovery at random placements on a 15-min drive.
Time per scenario = (window evaluation + full-availability runs) / scenarios, compilation
excluded (the engine's own stats, ``scenarios_per_s_steady`` of sweep_throughput.py). The child
also reports the mean maximum 2D error per satellites kept so a speed-up that changes the
numbers is visible. The last line printed is JSON with ``speedup`` = BASE time / HEAD time
(medians).

    python benchmarks/compare_commits.py 1117dff                     # reference case, 1,000 scen.
    python benchmarks/compare_commits.py 1117dff --case riss_sf --scenarios 2000
    python benchmarks/compare_commits.py A --head B --rounds 1       # two commits (bisecting)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CASES = {
    "reference": {"mode": "float_ppp", "system": "ins15", "constellations": ["gps"],
                  "slots": [12, 14, 14]},
    "riss_sf": {"mode": "sf_code", "system": "riss", "constellations": ["gps"],
                "slots": [12, 14, 14]},
    "gnss24": {"mode": "float_ppp", "system": "ins15", "constellations": ["gps", "galileo"],
               "slots": [12, 14, 12]},
}
KEPT = [0, 1, 2, 3]


def _parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base", help="the revision to compare against (e.g. 1117dff)")
    ap.add_argument("--head", default=None,
                    help="a second revision instead of this checkout as it is")
    ap.add_argument("--case", choices=sorted(CASES), default="reference",
                    help="the study timed (default: reference)")
    ap.add_argument("--scenarios", type=int, default=1000,
                    help="scenarios per run (approximate; default 1000)")
    ap.add_argument("--realizations", type=int, default=2, help="noise realisations (default 2)")
    ap.add_argument("--rounds", type=int, default=2,
                    help="alternating BASE / HEAD rounds (default 2)")
    ap.add_argument("--results", type=Path, default=HERE / "RESULTS.md",
                    help="Markdown file the figures are appended to")
    ap.add_argument("--no-append", action="store_true", help="print only, do not append")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.scenarios < len(KEPT) or args.realizations < 1 or args.rounds < 1:
        ap.error("--scenarios must be >= 4, --realizations and --rounds >= 1")
    return args


def child(args) -> int:
    """Run the case's sweep with whatever jaxnav PYTHONPATH gives; print one JSON line."""
    import jaxnav  # noqa: F401  (float64)
    from jaxnav.study import config
    from jaxnav.study.factory import SimFactory
    from jaxnav.study.sweep import run_sweep

    case = CASES[args.case]
    placements = max(1, round(args.scenarios / (len(KEPT) * args.realizations)))
    d = {
        "study": {"name": "compare_commits", "modes": [case["mode"]],
                  "systems": [case["system"]], "durations_s": [60], "satellites_kept": KEPT,
                  "realizations": args.realizations, "recovery_s": 30, "chunk_size": 64,
                  "max_traces": 0},
        "placement": {"kind": "random", "count": placements, "convergence_s": 300},
        "scenario": {"duration_s": 900.0, "slots": case["slots"], "ins_grade": "span_cpt",
                     "constellations": case["constellations"]},
    }
    cfg = config.from_dict(d, modes=SimFactory.modes, systems=SimFactory.systems)
    factory = SimFactory(cfg.scenario_dict)
    with tempfile.TemporaryDirectory() as td:
        kw = {"workers": 1} if "workers" in run_sweep.__code__.co_varnames else {}
        res = run_sweep(cfg, factory, Path(td) / "sweep", progress=False, **kw)
    st, ds = res.stats, res.dataset
    n = int(st["scenarios"])
    print(json.dumps({
        "jaxnav": str(Path(jaxnav.__file__).resolve().parent),
        "scenarios": n,
        "s_per_scenario": (st["eval_s"] + st["full_run_s"]) / n,
        "compile_s": st["compile_full_s"] + st["compile_eval_s"],
        "mean_max_2d_m_by_kept": {
            str(int(k)): round(float(ds["max_2d_m"].sel(satellites_kept=k).mean()), 4)
            for k in ds["satellites_kept"].values},
    }))
    return 0


def _git(*a: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *a], check=True, capture_output=True,
                          text=True).stdout.strip()


def _time_tree(tree: Path, args) -> dict:
    """One child run with ``import jaxnav`` resolving to ``tree``; its JSON line."""
    env = dict(os.environ, PYTHONPATH=str(tree), JAXNAV_WORKERS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "unused", "--child",
           "--case", args.case, "--scenarios", str(args.scenarios),
           "--realizations", str(args.realizations)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        sys.stderr.write(out.stderr[-4000:])
        raise SystemExit(f"compare_commits: the child in {tree} failed (exit {out.returncode})")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    if Path(res["jaxnav"]) != (tree / "jaxnav").resolve():
        raise SystemExit(f"compare_commits: the child imported {res['jaxnav']}, not {tree}")
    return res


def main() -> int:
    args = _parse()
    if args.child:
        return child(args)
    sys.path.insert(0, str(HERE))
    import benchutil

    base_rev = _git("rev-parse", "--short", args.base)
    head_rev = _git("rev-parse", "--short", args.head) if args.head else (
        _git("rev-parse", "--short", "HEAD") + ("+changes" if _git("status", "--porcelain",
                                                                  "--untracked-files=no") else ""))
    with tempfile.TemporaryDirectory(prefix="jaxnav-compare-") as td:
        trees = {"base": Path(td) / "base"}
        _git("worktree", "add", "--detach", str(trees["base"]), base_rev)
        if args.head:
            trees["head"] = Path(td) / "head"
            _git("worktree", "add", "--detach", str(trees["head"]), args.head)
        else:
            trees["head"] = ROOT
        runs: dict[str, list[dict]] = {"base": [], "head": []}
        try:
            for r in range(args.rounds):
                for side in ("base", "head"):
                    t0 = time.perf_counter()
                    res = _time_tree(trees[side], args)
                    runs[side].append(res)
                    print(f"round {r + 1} {side}: {1e3 * res['s_per_scenario']:.2f} ms/scenario "
                          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
        finally:
            for side in ("base", "head"):
                if trees[side] != ROOT:
                    _git("worktree", "remove", "--force", str(trees[side]))
    med = {s: statistics.median(x["s_per_scenario"] for x in runs[s]) for s in runs}
    figures = {
        "case": args.case,
        "base": base_rev,
        "head": head_rev,
        "scenarios": runs["head"][0]["scenarios"],
        "rounds": args.rounds,
        "ms_per_scenario_base": [round(1e3 * x["s_per_scenario"], 3) for x in runs["base"]],
        "ms_per_scenario_head": [round(1e3 * x["s_per_scenario"], 3) for x in runs["head"]],
        "compile_s_base": round(statistics.median(x["compile_s"] for x in runs["base"]), 1),
        "compile_s_head": round(statistics.median(x["compile_s"] for x in runs["head"]), 1),
        "mean_max_2d_m_base": runs["base"][0]["mean_max_2d_m_by_kept"],
        "mean_max_2d_m_head": runs["head"][0]["mean_max_2d_m_by_kept"],
        "speedup": round(med["base"] / med["head"], 3),
    }
    table = "\n".join(["| figure | value |", "|---|---|",
                       *(f"| {k} | {v} |" for k, v in figures.items())])
    case = CASES[args.case]
    body = (
        f"Case `{args.case}`: {case['system']} + {case['mode']}, slots {case['slots']} of "
        f"{case['constellations']}, 60-s outages keeping {KEPT} + 30 s recovery, random "
        f"placements, {args.realizations} realisation(s), chunk 64, one process. Alternating "
        f"BASE / HEAD in fresh subprocesses, {args.rounds} round(s); time per scenario = "
        "(window evaluation + full runs) / scenarios, compilation excluded; speedup = "
        "median BASE / median HEAD.\n\n" + table
    )
    print(body)
    if not args.no_append:
        benchutil.append_results(f"compare_commits {base_rev}..{head_rev}", body, figures,
                                 args.results)
    benchutil.print_json_line(figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
