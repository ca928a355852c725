"""Shared plumbing of the seed-reproduction scripts in ``experiments/``.

Each script is ``python experiments/<name>.py [--quick] [--out DIR]``: it runs its study
(sweeps through ``jaxnav.study.sweep.run_sweep`` with ``resume=True``, so an interrupted run
continues where it stopped), then writes ``DIR/report.md`` and PNG figures. ``--quick`` is the
reduced form the test suite runs; it writes to ``DIR`` too, so tests pass a temporary one.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import platform
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxnav
from jaxnav.filter import tight
from jaxnav.study import metrics

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def parse_args(name: str, description: str, argv: Sequence[str] | None = None):
    """``--quick`` and ``--out`` (default ``experiments/results/<name>``); the dir is created."""
    ap = argparse.ArgumentParser(prog=f"experiments/{name}.py", description=description)
    ap.add_argument("--quick", action="store_true", help="reduced run (what the tests execute)")
    ap.add_argument("--out", type=Path, default=RESULTS_DIR / name, help="output directory")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    return args


def ratio(ours: float, seed: float) -> float:
    """ours / seed, NaN when the seed's figure is missing or zero."""
    if seed is None or ours is None or not math.isfinite(seed) or seed == 0.0:
        return math.nan
    return ours / seed


def fmt(x, digits: int = 2) -> str:
    """A number for a Markdown cell ('-' for None / NaN)."""
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    if isinstance(x, float) and not math.isfinite(x):
        return "-"
    return f"{x:.{digits}f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A GitHub Markdown table; floats through ``fmt``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        lines.append("| " + " | ".join(fmt(c) if not isinstance(c, str) else c for c in r) + " |")
    return "\n".join(lines)


def comparison_table(rows: Sequence[tuple[str, float | None, float | None]]) -> str:
    """Side by side: (quantity, seed's figure, ours) -> a table with the ratio ours/seed."""
    return markdown_table(
        ["quantity", "seed", "jaxnav", "ratio"],
        [(q, s, o, ratio(o, s) if s is not None and o is not None else None) for q, s, o in rows],
    )


def write_report(out: Path, title: str, sections: Sequence[tuple[str, str]], quick: bool) -> Path:
    """``out/report.md``: a title, a provenance line, then (heading, Markdown body) sections."""
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    head = [
        f"# {title}",
        "",
        f"Generated {stamp} by jaxnav {jaxnav.__version__} on {platform.machine()} "
        f"({'--quick: reduced run, numbers are not meaningful' if quick else 'full run'}).",
        "",
    ]
    body = []
    for heading, text in sections:
        body += [f"## {heading}", "", text.strip(), ""]
    path = out / "report.md"
    path.write_text("\n".join(head + body))
    return path


def full_availability_errors(factory, cfg, mode, system, seeds, cache: Path) -> np.ndarray:
    """ENU error [R, T, 3] (estimate - truth, m) of whole runs with every satellite, one
    vmapped ``tight.run`` over the realisations ``seeds`` of ``factory.build(cfg, mode, system,
    seed)``; cached in ``cache`` (.npz) under a key of everything that determines it."""
    key = hashlib.sha256(json.dumps(
        [factory.fingerprint(), mode, system, list(map(int, seeds)), jaxnav.__version__],
        sort_keys=True).encode()).hexdigest()
    if cache.exists():
        with np.load(cache) as z:
            if str(z["key"]) == key:
                return z["err_enu_m"]
    probs = [factory.build(cfg, mode, system, int(s)) for s in seeds]
    carry0 = jax.tree.map(lambda *a: jnp.stack(a), *[p.carry0 for p in probs])
    inputs = jax.tree.map(lambda *a: jnp.stack(a), *[p.inputs for p in probs])

    @eqx.filter_jit
    def run(tf, carry0, inputs):
        return jax.vmap(lambda c, i: tight.run(tf, c, i)[1].llh)(carry0, inputs)

    llh = run(probs[0].tf, carry0, inputs)
    err = np.stack([np.asarray(metrics.enu_errors(llh[i], p.truth.llh))
                    for i, p in enumerate(probs)])
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, key=key, err_enu_m=err)
    tmp.replace(cache)
    return err


def run_time_lines(timings: dict, stats: dict) -> list[str]:
    """Markdown bullets of a script's wall times ({step: s}) and its sweeps' engine statistics
    ({label: ``SweepResult.stats``})."""
    lines = [f"- {k}: {v:.0f} s" for k, v in timings.items()]
    for label, st in stats.items():
        lines.append(
            f"- sweep {label}: {st['scenarios']} scenarios, compile "
            f"{st['compile_full_s'] + st['compile_eval_s']:.0f} s, full runs "
            f"{st['full_run_s']:.0f} s, evaluation {st['eval_s']:.0f} s, chunks computed "
            f"{st['chunks_computed']} / reused {st['chunks_reused']}")
    return lines


def hand_written_discussion(path: Path, quick: bool) -> str:
    """A full report's 'What differs and why': the text beside the script, written by hand after
    reading the full run (a ``--quick`` report gets a pointer instead)."""
    if quick:
        return "(--quick: no discussion; see the full report.)"
    if path.exists():
        return path.read_text()
    return f"(no hand-written discussion: {path.name} is missing.)"
