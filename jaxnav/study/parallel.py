"""The sweep's chunks on Dask distributed workers: every core of a machine, or a cluster.

A group's chunks are independent given the plan, so each becomes one Dask task that returns its
metric arrays to the client, which writes them with the same atomic chunk files and manifest as
the in-process path (no shared file system; ``resume`` unchanged, whatever the worker count).
A chunk's numbers depend only on (plan, group, chunk): the worker rebuilds the same full runs
and evaluates the same compiled programs, so the dataset is bit-identical for any worker count
and any assignment of chunks to workers, including chunks Dask resubmits after a worker dies.

Locality. A chunk needs the full-availability runs of the realisations it touches, which a
worker computes once and keeps while its next chunk needs them (``_GroupRunner``'s cache). The
pending chunks are therefore cut into one contiguous block per worker, and each block's tasks
are submitted with a loose preference for its worker (``allow_other_workers``: a dead or busy
worker's chunks may run elsewhere) and a priority that runs them in order.

Workers are single-threaded processes (XLA:CPU runs these small-matrix scans on one thread).
``LocalCluster`` workers share JAX's persistent compilation cache (``JAX_COMPILATION_CACHE_DIR``,
default ``~/.cache/jaxnav/jax-compilation-cache``), so a later run loads what an earlier one
compiled. The factory and plan are sent once per worker (``Client.scatter``); a factory must be
picklable (the simulator's pickles as its ``[scenario]`` table and its simulated drive; compiled
functions are rebuilt). Measured speed-ups and the ``"auto"`` threshold: docs/parallel.md.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

#: Worker-process state: {"key": config hash, "runner": (group, _GroupRunner)}. One study and
#: one group at a time, so a worker holds at most one group's realisations.
_STATE: dict = {}

_STAT_KEYS = ("compile_full_s", "compile_eval_s", "full_run_s", "eval_s", "full_runs")


class WorkerError(RuntimeError):
    """A chunk that no worker could finish (Dask gave up after repeated worker deaths)."""


def default_workers() -> int:
    """The cores this process may use (``os.sched_getaffinity``; ``os.cpu_count`` elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


#: Below this many scenarios ``workers = "auto"`` runs in-process. Every worker pays its own
#: start-up and compilation (with a cold cache, 2 workers compiling at once on 2 cores take
#: ~35 s each against ~18 s alone) and two busy workers run ~1.6x slower each on this 2-core
#: machine (shared L3), so the reference sweep breaks even near 5,000 scenarios
#: (benchmarks/RESULTS.md, "sweep_throughput --workers 2").
AUTO_MIN_SCENARIOS = 10_000


def auto_workers(n_scenarios: int) -> int:
    """``workers = "auto"``: every core for a study of at least ``AUTO_MIN_SCENARIOS``, else 1."""
    return default_workers() if n_scenarios >= AUTO_MIN_SCENARIOS else 1


def _worker_env() -> dict[str, str]:
    """Environment of LocalCluster workers: the shared compilation cache, single-threaded BLAS."""
    cache = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(
        Path.home() / ".cache" / "jaxnav" / "jax-compilation-cache")
    return {
        "JAX_COMPILATION_CACHE_DIR": cache,
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": os.environ.get(
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5"),
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
    }


def local_client(workers: int):
    """A ``LocalCluster`` of ``workers`` single-threaded worker processes and its client."""
    from distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
        env=_worker_env(), silence_logs=40,  # logging.ERROR: no worker start-up chatter
    )
    return Client(cluster)


class StartingClient:
    """A ``local_client(workers)`` started in a thread, so that the worker processes boot (and
    import JAX) while the client checks the study and simulates the drive."""

    def __init__(self, workers: int):
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(1, thread_name_prefix="jaxnav-cluster")
        self._future = self._pool.submit(local_client, workers)

    def get(self):
        """The client, once its cluster is up (start-up errors are raised here)."""
        return self._future.result()

    def close(self) -> None:
        """Close the client and its cluster (waiting for a start still under way)."""
        try:
            client = self._future.result()
        except Exception:  # noqa: BLE001  (a cluster that never started has nothing to close)
            client = None
        if client is not None:
            cluster = client.cluster
            client.close()
            cluster.close()
        self._pool.shutdown()


def _chunk_task(job: dict, g: int, j: int, mode: str, system: str) -> tuple[dict, dict]:
    """On a worker: chunk ``j`` of group ``g``; returns its arrays and the timing deltas."""
    import jax
    from jax.sharding import Mesh

    from jaxnav.study.sweep import _GroupRunner, group_ops

    if _STATE.get("key") != job["config_hash"]:
        _STATE.clear()
        _STATE["key"] = job["config_hash"]
    held = _STATE.get("runner")
    if held is None or held[0] != g:
        _STATE.pop("runner", None)  # free the previous group's realisations first
        factory, plan = job["factory"], job["plan"]
        stats = dict.fromkeys(_STAT_KEYS, 0.0) | {"full_runs": 0, "max_realizations_held": 0,
                                                   "shards": 0}
        mesh = Mesh(np.array(jax.local_devices()[:1]), ("batch",))
        held = (g, _GroupRunner(plan, factory, group_ops(factory, mode, system), mode, system,
                                mesh, stats))
        _STATE["runner"] = held
    runner = held[1]
    before = {k: runner.stats[k] for k in _STAT_KEYS}
    out = runner.chunk(j)
    delta = {k: runner.stats[k] - before[k] for k in _STAT_KEYS}
    delta["realizations_held"] = runner.stats["max_realizations_held"]
    return out, delta


def blocks(todo: list, n_workers: int) -> list[list]:
    """``todo`` cut into ``n_workers`` contiguous blocks of near-equal length (order kept)."""
    edges = np.linspace(0, len(todo), n_workers + 1).round().astype(int)
    return [todo[a:b] for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def run_chunks(client, job: dict, todo: list, groups: list, on_result):
    """Compute the chunks ``todo`` [(g, j)] on ``client``'s workers; ``on_result(g, j, out,
    delta)`` is called on the client for each as it finishes (any order)."""
    from distributed import KilledWorker, as_completed

    workers = sorted(client.scheduler_info()["workers"])
    if not workers:
        raise RuntimeError("the Dask cluster has no workers")
    job_f = client.scatter(job, broadcast=True, hash=False)
    futures = {}
    for w, block in zip(workers, blocks(todo, len(workers)), strict=False):
        for k, (g, j) in enumerate(block):
            mode, system = groups[g]
            f = client.submit(
                _chunk_task, job_f, g, j, mode, system, key=f"jaxnav-chunk-{job['config_hash']}"
                f"-{g}-{j}", workers=[w], allow_other_workers=True, priority=-k, pure=False,
            )
            futures[f] = (g, j)
    try:
        for f in as_completed(futures):
            g, j = futures[f]
            try:
                out, delta = f.result()
            except KilledWorker as e:
                raise WorkerError(
                    f"chunk {j} of group {groups[g][0]}/{groups[g][1]} killed its worker "
                    "repeatedly (out of memory?): lower study.chunk_size or the worker count"
                ) from e
            on_result(g, j, out, delta)
    finally:
        for f in futures:
            f.cancel()
