"""Shared plumbing of the benchmark scripts: machine facts, peak memory, RESULTS.md, JSON line.

Every benchmark prints its figures, appends them to ``benchmarks/RESULTS.md`` with the command,
the date, the machine (cores, CPU model) and the package versions, and prints one JSON object of
its headline figures as its last line (so CI and scripts can track it).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import resource
import shlex
import sys
import time
from importlib import metadata
from pathlib import Path

RESULTS_MD = Path(__file__).resolve().parent / "RESULTS.md"
_PACKAGES = ("jax", "jaxlib", "numpy", "equinox", "jaxnav")


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (or platform.processor())."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict:
    """Cores usable by this process, CPU model, Python and package versions."""
    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "absent"
    return {
        "cores": len(os.sched_getaffinity(0)),
        "cpu": cpu_model(),
        "python": platform.python_version(),
        **versions,
    }


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far [MB] (ru_maxrss is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Timer:
    """``with Timer() as t: ...`` then ``t.s`` is the elapsed wall time [s]."""

    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.s = time.perf_counter() - self.t0


def time_calls(fn, args, calls: int, min_s: float = 0.0, min_reps: int = 1,
               max_s: float = float("inf")):
    """Wall times [s] (NumPy array) of single calls ``fn(*args)`` after one warm-up call: at least
    ``max(calls, min_reps)`` calls, repeated until ``min_s`` seconds were measured (but no more
    than ``max(calls, 25)`` calls); stops early once ``max_s`` seconds were spent and ``min_reps``
    calls made."""
    import jax  # here, not at the top: scripts import benchutil before fixing JAX's devices
    import numpy as np

    jax.block_until_ready(fn(*args))  # warm (first-call allocation)
    times: list[float] = []
    while len(times) < max(calls, min_reps) or sum(times) < min_s:
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
        if len(times) >= max(calls, 25) or (sum(times) >= max_s and len(times) >= min_reps):
            break
    return np.asarray(times)


def command_line() -> str:
    """The command that ran this script, as a user would type it from the project root."""
    return "python " + " ".join(shlex.quote(a) for a in [_relative(sys.argv[0]), *sys.argv[1:]])


def _relative(path: str) -> str:
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path(__file__).resolve().parent.parent))
    except ValueError:
        return path


def append_results(title: str, body_md: str, figures: dict, path: Path = RESULTS_MD) -> None:
    """Append one dated section (command, machine, Markdown body, JSON figures) to RESULTS.md."""
    m = machine()
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    versions = ", ".join(f"{k} {m[k]}" for k in _PACKAGES)
    text = [
        f"\n## {title} — {stamp}",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {m['cores']} cores, {m['cpu']}; Python {m['python']}; {versions}",
        "",
        body_md.strip(),
        "",
        "```json",
        json.dumps(figures, sort_keys=True),
        "```",
        "",
    ]
    if not path.exists():
        path.write_text("# Benchmark results\n\nAppended by the scripts in `benchmarks/` "
                        "(newest at the end). See `benchmarks/README.md`.\n")
    with path.open("a") as f:
        f.write("\n".join(text))


def print_json_line(figures: dict) -> None:
    """The last line a benchmark prints: one JSON object of its headline figures."""
    print(json.dumps(figures, sort_keys=True), flush=True)


def finish(name: str, quick: bool, md_lines: list[str], figures: dict, path: Path) -> None:
    """Append the section ``name`` (`` (quick)`` added for a quick run) to ``path`` and print the
    JSON line: how a benchmark ends."""
    append_results(name + (" (quick)" if quick else ""), "\n".join(md_lines), figures, path=path)
    print_json_line(figures)
